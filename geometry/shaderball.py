"""The shaderball: build it once per parameter set, cache it on disk, load it after.

A cache entry is a folder named by :meth:`ShaderballParams.digest` holding three PLY
files (what Mitsuba loads) and ``shaderball.npz`` (charts, seams, atlas facts), written
in that order, each atomically; the npz is the entry's completion mark.
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import os
import time
import zipfile
from dataclasses import dataclass, field

import numpy as np

from geometry.atlas import pack_charts, seam_edges
from geometry.cachefile import write_cache_file
from geometry.params import ShaderballParams
from geometry.patches import Patch, ground_patch, material_patches, neutral_patches
from geometry.ply import as_trimesh, read_ply, write_ply

log = logging.getLogger(__name__)

MESH_NAMES = ("material", "neutral", "ground")
INDEX_FILE = "shaderball.npz"


@dataclass(frozen=True, eq=False)
class Shaderball:
    """The built shaderball. Meshes are trimesh objects with ``process=False``.

    ``material_mesh``: the material-bearing surfaces (outer shell, its cut rims and end
    faces, the shell's inner surface, the core), with per-vertex UVs
    (``material_mesh.visual.uv``) and crease-split vertex normals.
    ``neutral_mesh``: pedestal and neck (neutral grey). ``ground_mesh``: z = 0 plane.
    """

    params: ShaderballParams
    digest: str
    material_mesh: object
    neutral_mesh: object
    ground_mesh: object
    #: (M,) chart index of each material face, into ``chart_names``.
    face_chart: np.ndarray
    chart_names: tuple[str, ...]
    #: (E, 2, 3) world-space segments along which the texture is discontinuous.
    seam_edges: np.ndarray
    #: (E,) True where a seam runs along a crease (normals differ across it).
    seam_on_crease: np.ndarray
    #: xatlas's atlas size in texels and the share of it the charts cover.
    atlas_size: tuple[int, int]
    atlas_utilization: float
    #: PLY files of the three meshes (name -> path), in the cache entry.
    mesh_files: dict[str, str]
    #: Seconds spent building (``construct``, ``unwrap``) or ``load`` from the cache.
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def material_uv(self) -> np.ndarray:
        return np.asarray(self.material_mesh.visual.uv, np.float32)

    # The attributes every scene object has (geometry.objects.SceneObject), as properties
    # so the shaderball's cache entry and digest stay what they are.
    @property
    def name(self) -> str:
        return "shaderball"

    @property
    def kind(self) -> str:
        return "shaderball"

    @property
    def uv_source(self) -> str:
        return "built-in"

    @property
    def source(self) -> None:
        return None

    @property
    def source_sha256(self) -> None:
        return None

    @property
    def bounds(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """The box the camera frames (ball and pedestal): |x|, |y| <= half width, 0 <= z <= top."""
        half = float(max(self.params.shell_radius_m, self.params.pedestal_radius_m))
        return (-half, -half, 0.0), (half, half, float(self.params.top_z_m))

    @property
    def material_normals(self) -> np.ndarray:
        return np.asarray(self.material_mesh.vertex_normals, np.float32)


def default_cache_dir() -> str:
    return os.environ.get("SHADERBALL_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "shaderball")


def entry_dir(params: ShaderballParams, cache_dir: str | None = None) -> str:
    return os.path.join(cache_dir or default_cache_dir(), "geometry", params.digest())


def build_shaderball(params: ShaderballParams | None = None, cache_dir: str | None = None) -> Shaderball:
    """The shaderball for ``params``: loaded from the cache, or built and cached."""
    params = params or ShaderballParams()
    folder = entry_dir(params, cache_dir)
    if _entry_complete(folder):
        try:
            return _load(params, folder)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # damaged: rebuild
            log.warning("rebuilding damaged geometry cache entry %s: %s", folder, exc)
    return _build_and_store(params, folder)


def _entry_complete(folder: str) -> bool:
    names = [INDEX_FILE] + [f"{n}.ply" for n in MESH_NAMES]
    return all(os.path.isfile(os.path.join(folder, n)) for n in names)


def _build_and_store(params: ShaderballParams, folder: str) -> Shaderball:
    t0 = time.perf_counter()
    charts = material_patches(params)
    neutral = _merge(neutral_patches(params))
    ground = _merge([ground_patch(params)])
    t1 = time.perf_counter()
    atlas = pack_charts(charts, params.texture_repeats)
    segments, on_crease = seam_edges(atlas)
    t2 = time.perf_counter()

    os.makedirs(folder, exist_ok=True)
    write_ply(os.path.join(folder, "material.ply"), atlas.positions, atlas.faces, atlas.normals, atlas.uv)
    write_ply(os.path.join(folder, "neutral.ply"), *neutral)
    write_ply(os.path.join(folder, "ground.ply"), *ground)
    index = {
        "face_chart": atlas.face_chart,
        "chart_names": np.array(atlas.chart_names),
        "seam_edges": segments,
        "seam_on_crease": on_crease,
        "atlas_size": np.array(atlas.atlas_size, np.int64),
        "atlas_utilization": np.array(atlas.utilization),
        "meta": np.array(json.dumps({"digest": params.digest(), "params": params.as_dict()}, sort_keys=True)),
    }
    buffer = io.BytesIO()
    np.savez(buffer, **index)
    write_cache_file(os.path.join(folder, INDEX_FILE), buffer.getvalue())
    ball = _load(params, folder)
    return _with_timings(ball, {"construct": t1 - t0, "unwrap": t2 - t1})


def _with_timings(ball: Shaderball, timings: dict[str, float]) -> Shaderball:
    return dataclasses.replace(ball, timings=timings)


def _merge(patches: list[Patch]):
    offsets = np.cumsum([0] + [len(p.positions) for p in patches])
    positions = np.concatenate([p.positions for p in patches]).astype(np.float32)
    normals = np.concatenate([p.normals for p in patches])
    normals = (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)
    faces = np.concatenate([p.faces + o for p, o in zip(patches, offsets)]).astype(np.int32)
    return positions, faces, normals


def _load(params: ShaderballParams, folder: str) -> Shaderball:
    t0 = time.perf_counter()
    files = {name: os.path.join(folder, f"{name}.ply") for name in MESH_NAMES}
    meshes = {name: as_trimesh(read_ply(path)) for name, path in files.items()}
    with np.load(os.path.join(folder, INDEX_FILE), allow_pickle=False) as index:
        meta = json.loads(str(index["meta"]))
        if meta["digest"] != params.digest():
            raise ValueError(f"cache entry digest {meta['digest']} does not match {params.digest()}")
        face_chart = index["face_chart"]
        if len(face_chart) != len(meshes["material"].faces):
            raise ValueError("cache entry: face_chart does not match material.ply")
        ball = Shaderball(
            params=params,
            digest=meta["digest"],
            material_mesh=meshes["material"],
            neutral_mesh=meshes["neutral"],
            ground_mesh=meshes["ground"],
            face_chart=face_chart,
            chart_names=tuple(str(n) for n in index["chart_names"]),
            seam_edges=index["seam_edges"],
            seam_on_crease=index["seam_on_crease"],
            atlas_size=tuple(int(v) for v in index["atlas_size"]),
            atlas_utilization=float(index["atlas_utilization"]),
            mesh_files=files,
            timings={"load": time.perf_counter() - t0},
        )
    return ball
