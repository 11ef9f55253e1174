"""Scene objects: the shaderball, built-in primitives, or a user's mesh file.

Every object other than the shaderball is normalised the same way: a uniform scale so it
fits the shaderball's own bounding box (half width ``max(shell_radius_m,
pedestal_radius_m)``, height ``top_z_m``, from :class:`ShaderballParams`), centred on
the z axis, and it stands on the ground (min z = 0): no pedestal. It is framed by the
shaderball's camera rule (:func:`geometry.camera.frame_box`) applied to its own box.

Mesh files pass :func:`geometry.meshfile.check_mesh_file` before trimesh reads them;
trimesh then gets the bytes already read (no path, so it cannot open anything else) and a
resolver that refuses every other file. glTF/GLB is y-up by its specification and is
turned z-up; OBJ, PLY and STL are taken as z-up. Normals in files are not used: every
object gets crease-split normals from its geometry (:func:`geometry.meshops.crease_normals`),
so the same surface gets the same normals from any format. UVs from a file are kept
when usable, otherwise xatlas makes an atlas (``uv_source`` says which).

Cache: ``default_cache_dir()/objects/<key>/`` holds ``material.ply``, ``ground.ply`` and
``object.npz`` (seams, facts, the canonical digest), written in that order, each
atomically; the npz marks the entry complete. The key hashes what the object is built
from (built-in name, or the file's SHA-256), OBJECTS_CODE_VERSION, the shaderball box
and the library versions; the entry holds the canonical-mesh digest, checked on load.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import logging
import os
import time
import zipfile
from dataclasses import dataclass, field

import numpy as np

from geometry.cachefile import write_cache_file
from geometry.camera import Camera, default_camera, frame_box
from geometry.errors import GeometryError
from geometry.meshfile import (
    MAX_MESH_FILE_BYTES,
    MESH_SUFFIXES,
    MeshFileError,
    MeshFileFacts,
    check_mesh_arrays,
    check_mesh_file,
    file_sha256,
    refuse,
)
from geometry.meshops import canonical_digest, crease_normals, fit_in_box, uv_seams, uv_usable, weld
from geometry.params import ShaderballParams
from geometry.patches import ground_patch
from geometry.ply import as_trimesh, read_ply, write_ply
from geometry.primitives import PRIMITIVES
from geometry.shaderball import Shaderball, build_shaderball, default_cache_dir
from geometry.unwrap import UnwrapError, unwrap

__all__ = [
    "BUILTIN_OBJECTS",
    "MESH_SUFFIXES",
    "MeshFileFacts",
    "SceneObject",
    "build_object",
    "check_mesh_file",
    "file_sha256",
    "object_camera",
]

log = logging.getLogger(__name__)

BUILTIN_OBJECTS = ("shaderball", "sphere", "rounded_cube", "torus")
#: Bump when normalisation, normals, UVs, seams or the cache layout change: old entries miss
#: and canonical digests change with it.
OBJECTS_CODE_VERSION = 1
MESH_NAMES = ("material", "ground")
INDEX_FILE = "object.npz"


@dataclass(frozen=True, eq=False)
class SceneObject:
    """A built object other than the shaderball, with what the renderer and G-buffer use.

    ``material_mesh``: trimesh (``process=False``) with per-vertex UVs
    (``visual.uv``) and crease-split vertex normals; it stands on the ground inside the
    shaderball's box. ``neutral_mesh`` is None (no pedestal). ``ground_mesh``: the
    shaderball's z = 0 plane. ``digest``: SHA-256 of the canonical mesh
    (:func:`geometry.meshops.canonical_digest`).
    """

    name: str
    kind: str  # "primitive" | "mesh"
    digest: str
    uv_source: str  # "built-in" | "file" | "xatlas"
    source: str | None
    source_sha256: str | None
    material_mesh: object
    neutral_mesh: object
    ground_mesh: object
    #: PLY files (name -> path) in the cache entry: "material" and "ground".
    mesh_files: dict[str, str]
    #: (E, 2, 3) world-space segments along which the texture is discontinuous.
    seam_edges: np.ndarray
    #: (E,) True where a seam runs along a crease (normals differ across it).
    seam_on_crease: np.ndarray
    #: ((xmin, ymin, zmin), (xmax, ymax, zmax)) of the material mesh, metres.
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]]
    #: Seconds spent building (``build``) or ``load`` from the cache.
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def material_uv(self) -> np.ndarray:
        return np.asarray(self.material_mesh.visual.uv, np.float32)

    @property
    def material_normals(self) -> np.ndarray:
        return np.asarray(self.material_mesh.vertex_normals, np.float32)


def build_object(name: str, cache_dir: str | None = None) -> SceneObject | Shaderball:
    """The object called ``name``: a built-in (BUILTIN_OBJECTS) or an absolute mesh file path.

    "shaderball" is :func:`geometry.build_shaderball` unchanged. Others are loaded from
    the cache or built, cached and loaded.
    """
    if name == "shaderball":
        return build_shaderball(cache_dir=cache_dir)
    if name in PRIMITIVES:
        folder = _entry_dir(_cache_key({"builtin": name}), cache_dir)
        return _cached(folder, name, "primitive", None, None, lambda: _primitive_arrays(name))
    if not isinstance(name, str) or not os.path.isabs(name):
        raise GeometryError(
            f"object: {name!r} is not allowed; allowed: one of {', '.join(BUILTIN_OBJECTS)}, "
            f"or an absolute path to a mesh file ({' '.join(MESH_SUFFIXES)})"
        )
    facts = check_mesh_file(name)
    data = _read_checked(facts)
    sha = hashlib.sha256(data).hexdigest()
    folder = _entry_dir(_cache_key({"file_sha256": sha}), cache_dir)
    base = os.path.basename(name)
    return _cached(folder, base, "mesh", name, sha, lambda: _file_arrays(facts, data))


def object_camera(obj) -> Camera:
    """The camera that frames ``obj``: :func:`default_camera` for the shaderball (same
    floats), the same rule (:func:`frame_box`) on the object's own box otherwise."""
    if getattr(obj, "kind", None) == "shaderball":
        return default_camera(obj.params)
    lo, hi = obj.bounds
    half_width = max(abs(lo[0]), abs(lo[1]), abs(hi[0]), abs(hi[1]))
    return frame_box(float(half_width), float(hi[2]))


def shaderball_box(params: ShaderballParams | None = None) -> tuple[float, float]:
    """(half width, top) of the box every object is fitted into: the shaderball's own."""
    params = params or ShaderballParams()
    return max(params.shell_radius_m, params.pedestal_radius_m), params.top_z_m


# --------------------------------------------------------------------------- building


def _primitive_arrays(name: str) -> dict:
    positions, faces, normals, uv = PRIMITIVES[name]()
    positions = fit_in_box(positions, *shaderball_box())
    return {"positions": positions, "faces": faces, "normals": normals, "uv": uv, "uv_source": "built-in"}


def _read_checked(facts: MeshFileFacts) -> bytes:
    """The file's bytes, read once: hashed and parsed from memory, so what was hashed is
    what is parsed; a file that changed size since the gate looked is refused."""
    with open(facts.path, "rb") as fh:
        data = fh.read(MAX_MESH_FILE_BYTES + 1)
    if len(data) != facts.size_bytes:
        raise refuse(
            facts.path, f"changed while being read ({len(data)} bytes, was {facts.size_bytes})", "a stable file"
        )
    return data


def _file_arrays(facts: MeshFileFacts, data: bytes) -> dict:
    positions, faces, uv = _trimesh_load(facts, data)
    faces = check_mesh_arrays(facts.path, positions, faces)
    if facts.suffix in (".gltf", ".glb"):
        positions = positions[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0])  # y-up -> z-up
    keep_uv = uv_usable(uv, len(positions), faces)
    positions, faces, uv = weld(positions, faces, uv if keep_uv else None)
    positions = fit_in_box(positions, *shaderball_box())
    source, faces, normals = crease_normals(positions, faces)
    positions = positions[source]
    if keep_uv:
        return {"positions": positions, "faces": faces, "normals": normals, "uv": uv[source], "uv_source": "file"}
    try:
        source, faces, uv = unwrap(positions, faces, normals)
    except UnwrapError as exc:
        raise refuse(facts.path, f"has no usable UVs and {exc}", "a mesh file with its own UVs") from None
    return {
        "positions": positions[source],
        "faces": faces,
        "normals": normals[source],
        "uv": uv,
        "uv_source": "xatlas",
    }


def _trimesh_load(facts: MeshFileFacts, data: bytes):
    import trimesh

    class RefuseResolver(trimesh.resolvers.Resolver):
        """Refuses every file a loader asks for (textures, .mtl, external buffers)."""

        def __init__(self):
            pass

        def get(self, name):
            raise refuse(facts.path, f"refers to another file {name!r}", "self-contained mesh files")

        def write(self, name, data):
            raise refuse(facts.path, f"asked to write {name!r}", "reading only")

        def namespaced(self, namespace):
            return self

        def keys(self):
            return iter(())

    try:
        mesh = trimesh.load(
            io.BytesIO(data), file_type=facts.suffix[1:], force="mesh", process=False, resolver=RefuseResolver()
        )
    except MeshFileError:
        raise
    except Exception as exc:  # trimesh's parsers raise anything on malformed input
        raise refuse(
            facts.path, f"trimesh could not read it ({type(exc).__name__}: {exc})", "a well-formed file"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh):
        raise refuse(facts.path, f"holds no triangle mesh ({type(mesh).__name__})", "a mesh with faces")
    uv = getattr(mesh.visual, "uv", None) if getattr(mesh.visual, "kind", None) == "texture" else None
    positions = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    return positions, faces, (None if uv is None else np.asarray(uv, np.float64))


# --------------------------------------------------------------------------- cache


def _cache_key(inputs: dict) -> str:
    import trimesh
    import xatlas

    doc = {
        "inputs": inputs,
        "code": OBJECTS_CODE_VERSION,
        "box": list(shaderball_box()),
        "versions": {
            "numpy": np.__version__,
            "trimesh": trimesh.__version__,
            "xatlas": getattr(xatlas, "__version__", "unknown"),
        },
    }
    return hashlib.sha256(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _entry_dir(key: str, cache_dir: str | None) -> str:
    return os.path.join(cache_dir or default_cache_dir(), "objects", key)


def _cached(folder: str, name: str, kind: str, source, source_sha256, make) -> SceneObject:
    facts = {"name": name, "kind": kind, "source": source, "source_sha256": source_sha256}
    if all(os.path.isfile(os.path.join(folder, n)) for n in [INDEX_FILE] + [f"{m}.ply" for m in MESH_NAMES]):
        try:
            return _load(folder, facts)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # damaged: rebuild
            log.warning("rebuilding damaged object cache entry %s: %s", folder, exc)
    t0 = time.perf_counter()
    arrays = make()
    build_s = time.perf_counter() - t0
    _store(folder, arrays)
    return dataclasses.replace(_load(folder, facts), timings={"build": build_s})


def _store(folder: str, arrays: dict) -> None:
    positions = arrays["positions"].astype(np.float32)
    faces = arrays["faces"].astype(np.int32)
    normals = arrays["normals"].astype(np.float32)
    uv = arrays["uv"].astype(np.float32)
    segments, on_crease = uv_seams(positions, faces, uv, normals)
    ground = ground_patch(ShaderballParams())
    os.makedirs(folder, exist_ok=True)
    write_ply(os.path.join(folder, "material.ply"), positions, faces, normals, uv)
    write_ply(
        os.path.join(folder, "ground.ply"),
        ground.positions.astype(np.float32),
        ground.faces.astype(np.int32),
        ground.normals.astype(np.float32),
    )
    meta = {
        "digest": canonical_digest(positions, faces, uv, normals, OBJECTS_CODE_VERSION),
        "uv_source": arrays["uv_source"],
        "code": OBJECTS_CODE_VERSION,
    }
    buffer = io.BytesIO()
    np.savez(buffer, seam_edges=segments, seam_on_crease=on_crease, meta=np.array(json.dumps(meta, sort_keys=True)))
    write_cache_file(os.path.join(folder, INDEX_FILE), buffer.getvalue())


def _load(folder: str, facts: dict) -> SceneObject:
    t0 = time.perf_counter()
    files = {name: os.path.join(folder, f"{name}.ply") for name in MESH_NAMES}
    arrays = {name: read_ply(path) for name, path in files.items()}
    material = arrays["material"]
    with np.load(os.path.join(folder, INDEX_FILE), allow_pickle=False) as index:
        meta = json.loads(str(index["meta"]))
        seams, on_crease = index["seam_edges"], index["seam_on_crease"]
    digest = canonical_digest(
        material["positions"], material["faces"], material["uv"], material["normals"], meta["code"]
    )
    if digest != meta["digest"] or meta["code"] != OBJECTS_CODE_VERSION:
        raise ValueError(f"cache entry digest {meta['digest']} does not match its mesh ({digest})")
    lo, hi = material["positions"].min(0), material["positions"].max(0)
    return SceneObject(
        digest=digest,
        uv_source=meta["uv_source"],
        material_mesh=as_trimesh(material),
        neutral_mesh=None,
        ground_mesh=as_trimesh(arrays["ground"]),
        mesh_files=files,
        seam_edges=seams,
        seam_on_crease=on_crease,
        bounds=(tuple(float(v) for v in lo), tuple(float(v) for v in hi)),
        timings={"load": time.perf_counter() - t0},
        **facts,
    )
