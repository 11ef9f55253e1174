"""A minimal binary PLY writer and reader for triangle meshes with normals and UVs.

Written here rather than through trimesh's exporter so the bytes are fixed by the
arrays alone and the property names are the ones Mitsuba's ``ply`` plugin reads
(``x y z nx ny nz u v``; Mitsuba does not flip v on load, measured with 3.9.1).
"""

from __future__ import annotations

import numpy as np

from geometry.cachefile import write_cache_file


def encode_ply(
    positions: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None, uv: np.ndarray | None = None
) -> bytes:
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if uv is not None:
        fields += [("u", "<f4"), ("v", "<f4")]
    vertices = np.zeros(len(positions), dtype=fields)
    for i, axis in enumerate("xyz"):
        vertices[axis] = positions[:, i]
        if normals is not None:
            vertices["n" + axis] = normals[:, i]
    if uv is not None:
        vertices["u"], vertices["v"] = uv[:, 0], uv[:, 1]
    tris = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    tris["n"] = 3
    tris["i"] = faces
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(positions)}"]
    header += [f"property float {name}" for name, _ in fields]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header", ""]
    return "\n".join(header).encode("ascii") + vertices.tobytes() + tris.tobytes()


def write_ply(path: str, positions, faces, normals=None, uv=None) -> None:
    """Write a PLY atomically (a cache file: never torn, see geometry.cachefile)."""
    write_cache_file(path, encode_ply(positions, faces, normals, uv))


def read_ply(path: str) -> dict[str, np.ndarray]:
    """Read a PLY written by :func:`write_ply` into positions, faces, normals?, uv?."""
    with open(path, "rb") as fh:
        data = fh.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    n_vertices = n_faces = 0
    names: list[str] = []
    for line in lines:
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            n_vertices = int(parts[2])
        elif parts[:2] == ["element", "face"]:
            n_faces = int(parts[2])
        elif parts[:2] == ["property", "float"]:
            names.append(parts[2])
    vdtype = np.dtype([(name, "<f4") for name in names])
    vertices = np.frombuffer(data, vdtype, n_vertices, end)
    tris = np.frombuffer(data, [("n", "u1"), ("i", "<i4", (3,))], n_faces, end + vdtype.itemsize * n_vertices)
    out = {
        "positions": np.stack([vertices[a] for a in "xyz"], 1),
        "faces": tris["i"].astype(np.int64),
    }
    if "nx" in names:
        out["normals"] = np.stack([vertices["n" + a] for a in "xyz"], 1)
    if "u" in names:
        out["uv"] = np.stack([vertices["u"], vertices["v"]], 1)
    return out


def as_trimesh(arrays: dict[str, np.ndarray]):
    """A trimesh of :func:`read_ply`'s arrays as stored (``process=False``: no vertex merged or
    reordered), with its UVs and vertex normals where the file has them."""
    import trimesh

    visual = trimesh.visual.TextureVisuals(uv=arrays["uv"]) if "uv" in arrays else None
    return trimesh.Trimesh(
        vertices=arrays["positions"],
        faces=arrays["faces"],
        vertex_normals=arrays.get("normals"),
        visual=visual,
        process=False,
        validate=False,
    )
