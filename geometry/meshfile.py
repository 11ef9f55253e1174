"""The gate for users' mesh files: what is checked before trimesh reads a byte, and after.

A mesh file is untrusted input: it may be huge, claim billions of elements, hold NaNs or
out-of-range indices, or point a loader at other files or URLs. :func:`check_mesh_file`
looks at the file's size and its header (PLY header, STL face count, glTF/GLB JSON,
OBJ ``v``/``f`` lines counted while streaming) before trimesh parses it;
:func:`check_mesh_arrays` checks what trimesh made of it.

Policy for degenerate (zero-area) faces: real files often carry a few (sliver
triangles, collapsed quads), so they are dropped; a file whose faces are ALL degenerate
has no surface and is refused.

Textures are refused, not ignored: an image inside a glTF/GLB would be decoded by an
image library (a second parser of untrusted bytes) for a texture the renderer never
uses (the material comes from the dataset's maps).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import struct
from dataclasses import dataclass

import numpy as np

from geometry.errors import GeometryError

#: File name suffixes (lower case) the gate and the loader accept.
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".gltf", ".glb")
#: Largest mesh file accepted, bytes (checked by stat before reading).
MAX_MESH_FILE_BYTES = 512 * 1024 * 1024
#: Most vertices a mesh file may declare or hold.
MAX_VERTICES = 4_000_000
#: Most triangles a mesh file may declare or hold (polygons count as their triangles).
MAX_FACES = 4_000_000
#: Largest PLY header read, bytes; a header is a few hundred bytes in practice.
MAX_PLY_HEADER_BYTES = 64 * 1024
#: Largest glTF JSON (a ``.gltf`` file, or a GLB's JSON chunk) parsed, bytes.
MAX_GLTF_JSON_BYTES = 16 * 1024 * 1024
#: Longest OBJ line read while counting, bytes (a longer one is refused, not buffered).
MAX_OBJ_LINE_BYTES = 64 * 1024

_STL_HEADER = 84
_STL_FACET = 50
_GLB_MAGIC = b"glTF"
_GLB_JSON = 0x4E4F534A


class MeshFileError(GeometryError):
    """A refused mesh file: the message names the file, the reason and what is allowed."""


@dataclass(frozen=True)
class MeshFileFacts:
    """What the gate learnt about a file before loading it.

    ``vertices``/``faces`` are the counts the file declares (PLY, binary STL, glTF) or
    that were counted (OBJ, ASCII STL); ``format`` says which reading gave them.
    """

    path: str
    suffix: str
    size_bytes: int
    format: str
    vertices: int
    faces: int


def file_sha256(path) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def refuse(path, reason: str, allowed: str) -> MeshFileError:
    return MeshFileError(f"mesh file {os.fspath(path)}: {reason}; allowed: {allowed}")


def check_mesh_file(path: str) -> MeshFileFacts:
    """Check ``path`` by its size and header before any loader reads it; raise MeshFileError."""
    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in MESH_SUFFIXES:
        raise refuse(path, f"unknown suffix {suffix or '(none)'!r}", " ".join(MESH_SUFFIXES))
    try:
        info = os.stat(path)
    except OSError as exc:
        raise refuse(path, f"cannot be read ({exc.strerror})", "an existing, readable file") from None
    if not os.path.isfile(path):
        raise refuse(path, "is not a regular file", "a regular file")
    if info.st_size > MAX_MESH_FILE_BYTES:
        raise refuse(path, f"{info.st_size} bytes", f"at most {MAX_MESH_FILE_BYTES} bytes (MAX_MESH_FILE_BYTES)")
    if info.st_size == 0:
        raise refuse(path, "is empty", "a mesh with faces")
    reader = {".ply": _ply_counts, ".stl": _stl_counts, ".obj": _obj_counts, ".gltf": _gltf_counts}
    fmt, vertices, faces = reader.get(suffix, _glb_counts)(path, info.st_size)
    _check_counts(path, vertices, faces)
    return MeshFileFacts(path, suffix, int(info.st_size), fmt, int(vertices), int(faces))


def _check_counts(path: str, vertices: int, faces: int) -> None:
    if vertices > MAX_VERTICES:
        raise refuse(path, f"{vertices} vertices", f"at most {MAX_VERTICES} (MAX_VERTICES)")
    if faces > MAX_FACES:
        raise refuse(path, f"{faces} faces", f"at most {MAX_FACES} triangles (MAX_FACES)")
    if faces == 0:
        raise refuse(path, "no faces", "a mesh with at least one triangle")


# --------------------------------------------------------------------------- headers


def _ply_counts(path: str, size: int) -> tuple[str, int, int]:
    with open(path, "rb") as fh:
        head = fh.read(MAX_PLY_HEADER_BYTES)
    if not head.startswith(b"ply"):
        raise refuse(path, "does not start with 'ply'", "a PLY file")
    end = head.find(b"end_header")
    if end < 0:
        raise refuse(path, f"no end_header in its first {MAX_PLY_HEADER_BYTES} bytes", "a PLY header")
    counts = {"vertex": 0, "face": 0}
    fmt = "ply"
    for line in head[:end].decode("ascii", "replace").splitlines():
        parts = line.split()
        if parts[:1] == ["format"] and len(parts) > 1:
            fmt = f"ply {parts[1]}"
        if parts[:1] == ["element"] and len(parts) == 3 and parts[1] in counts:
            if not parts[2].isdigit():
                raise refuse(path, f"header line {line.strip()!r}", "a non-negative element count")
            counts[parts[1]] = int(parts[2])
    # A PLY face may be a polygon: n-gons count as at least one triangle each here;
    # the loaded triangle count is checked again after loading.
    return fmt, counts["vertex"], counts["face"]


def _stl_counts(path: str, size: int) -> tuple[str, int, int]:
    with open(path, "rb") as fh:
        head = fh.read(_STL_HEADER)
    if len(head) == _STL_HEADER:
        (n,) = struct.unpack("<I", head[80:84])
        if size == _STL_HEADER + _STL_FACET * n:
            return "stl binary", 3 * n, n
    if not head.lstrip().lower().startswith(b"solid"):
        raise refuse(path, "neither a binary STL (size != 84 + 50 x faces) nor ASCII ('solid')", "an STL file")
    facets = 0
    for line in _bounded_lines(path):
        if line.lstrip().startswith(b"facet"):
            facets += 1
            if facets > MAX_FACES:
                break
    return "stl ascii", 3 * facets, facets


def _obj_counts(path: str, size: int) -> tuple[str, int, int]:
    """Count ``v`` lines and the triangles of ``f`` lines; check every face index refers to
    a vertex already defined (OBJ's rule; negative indices count back from the last)."""
    vertices = triangles = 0
    for number, line in enumerate(_bounded_lines(path), 1):
        head = line[:2]
        if head in (b"v ", b"v\t"):
            vertices += 1
        elif head in (b"f ", b"f\t"):
            corners = line.split()[1:]
            triangles += max(len(corners) - 2, 1)
            for corner in corners:
                _obj_index(path, number, corner.split(b"/")[0], vertices)
        if vertices > MAX_VERTICES or triangles > MAX_FACES:
            break  # over budget: counting further proves nothing more
    return "obj", vertices, triangles


def _obj_index(path: str, number: int, token: bytes, vertices: int) -> None:
    try:
        index = int(token)
    except ValueError:
        raise refuse(path, f"line {number}: face index {token[:20]!r}", "integers") from None
    if not (1 <= index <= vertices or -vertices <= index <= -1):
        raise refuse(
            path,
            f"line {number}: face index {index} is out of range ({vertices} vertices so far)",
            f"1 to {vertices} or -{vertices} to -1",
        )


def _bounded_lines(path: str):
    with open(path, "rb") as fh:
        while True:
            line = fh.readline(MAX_OBJ_LINE_BYTES + 1)
            if not line:
                return
            if len(line) > MAX_OBJ_LINE_BYTES:
                raise refuse(path, f"a line longer than {MAX_OBJ_LINE_BYTES} bytes", "shorter lines")
            yield line


def _gltf_counts(path: str, size: int) -> tuple[str, int, int]:
    if size > MAX_GLTF_JSON_BYTES:
        raise refuse(path, f"{size} bytes of glTF JSON", f"at most {MAX_GLTF_JSON_BYTES} (MAX_GLTF_JSON_BYTES)")
    with open(path, "rb") as fh:
        doc = _parse_json(path, fh.read())
    return ("gltf", *_gltf_doc_counts(path, doc, glb=False))


def _glb_counts(path: str, size: int) -> tuple[str, int, int]:
    with open(path, "rb") as fh:
        header = fh.read(20)
        if len(header) < 20 or header[:4] != _GLB_MAGIC:
            raise refuse(path, "no GLB header (magic 'glTF')", "a binary glTF 2.0 file")
        version, length, chunk_length, chunk_type = struct.unpack("<IIII", header[4:20])
        if version != 2:
            raise refuse(path, f"GLB version {version}", "version 2")
        if length > size or chunk_type != _GLB_JSON or 20 + chunk_length > size:
            raise refuse(path, "a GLB header whose lengths or first chunk do not fit the file", "a valid GLB")
        if chunk_length > MAX_GLTF_JSON_BYTES:
            raise refuse(path, f"a {chunk_length}-byte JSON chunk", f"at most {MAX_GLTF_JSON_BYTES} bytes")
        doc = _parse_json(path, fh.read(chunk_length))
    return ("glb", *_gltf_doc_counts(path, doc, glb=True))


def _parse_json(path: str, data: bytes) -> dict:
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise refuse(path, f"its glTF JSON does not parse ({type(exc).__name__})", "valid glTF 2.0 JSON") from None
    if not isinstance(doc, dict):
        raise refuse(path, "its glTF JSON is not an object", "valid glTF 2.0 JSON")
    return doc


def _gltf_doc_counts(path: str, doc: dict, *, glb: bool) -> tuple[int, int]:
    """Refuse external references and images; sum POSITION/indices counts over instances."""
    for i, buffer in enumerate(_list(path, doc, "buffers")):
        uri = buffer.get("uri") if isinstance(buffer, dict) else None
        if uri is None and glb and i == 0:
            continue  # the GLB's own binary chunk
        if not isinstance(uri, str) or not uri.startswith("data:"):
            raise refuse(path, f"buffers[{i}] refers to {uri!r}", "data: URIs only (no other files, no URLs)")
    images = _list(path, doc, "images")
    if images:
        first = images[0].get("uri", "(embedded)") if isinstance(images[0], dict) else "?"
        raise refuse(path, f"{len(images)} image(s), e.g. {str(first)[:60]!r}", "no textures (images)")
    accessors = _list(path, doc, "accessors")
    instances = _mesh_instances(path, doc)
    vertices = faces = 0
    for m, mesh in enumerate(_list(path, doc, "meshes")):
        for prim in mesh.get("primitives", []) if isinstance(mesh, dict) else []:
            n_vertices = _accessor_count(path, accessors, (prim.get("attributes") or {}).get("POSITION"))
            indices = prim.get("indices")
            n_faces = (_accessor_count(path, accessors, indices) if indices is not None else n_vertices) // 3
            vertices += n_vertices * instances.get(m, 1)
            faces += n_faces * instances.get(m, 1)
    return vertices, faces


def _mesh_instances(path: str, doc: dict) -> dict[int, int]:
    counts: dict[int, int] = {}
    for node in _list(path, doc, "nodes"):
        mesh = node.get("mesh") if isinstance(node, dict) else None
        if isinstance(mesh, int):
            counts[mesh] = counts.get(mesh, 0) + 1
    return counts


def _list(path: str, doc: dict, key: str) -> list:
    value = doc.get(key, [])
    if not isinstance(value, list):
        raise refuse(path, f"glTF {key!r} is not a list", "valid glTF 2.0 JSON")
    return value


def _accessor_count(path: str, accessors: list, index) -> int:
    if not isinstance(index, int) or not 0 <= index < len(accessors) or not isinstance(accessors[index], dict):
        raise refuse(path, f"a primitive refers to accessor {index!r}", f"an index below {len(accessors)}")
    count = accessors[index].get("count")
    if not isinstance(count, int) or count < 0:
        raise refuse(path, f"accessors[{index}].count is {count!r}", "a non-negative integer")
    return count


# --------------------------------------------------------------------------- loaded arrays


def check_mesh_arrays(path: str, positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Refuse non-finite vertices, out-of-range indices, no (or only degenerate) faces.

    Returns the faces with the degenerate (zero-area) ones dropped (see the module's policy).
    """
    positions = np.asarray(positions)
    faces = np.asarray(faces)
    if len(positions) > MAX_VERTICES or len(faces) > MAX_FACES:
        raise refuse(path, f"{len(positions)} vertices, {len(faces)} triangles", f"at most {MAX_VERTICES}/{MAX_FACES}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise refuse(path, "no triangle faces", "a mesh with at least one triangle")
    bad = ~np.isfinite(positions).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise refuse(path, f"{int(bad.sum())} non-finite vertices (first: #{i} {positions[i].tolist()})", "finite")
    if faces.min() < 0 or faces.max() >= len(positions):
        value = int(faces.min()) if faces.min() < 0 else int(faces.max())
        raise refuse(path, f"face index {value} with {len(positions)} vertices", f"0 to {len(positions) - 1}")
    p = positions[faces].astype(np.float64)
    area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    extent = float(np.ptp(positions, axis=0).max()) if len(positions) else 0.0
    keep = area2 > (extent * extent) * 1e-14 if math.isfinite(extent) and extent > 0 else np.zeros(len(faces), bool)
    if not keep.any():
        raise refuse(path, f"all {len(faces)} faces have zero area", "a mesh with a surface")
    return faces[keep]
