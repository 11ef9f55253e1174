"""Operations on any triangle mesh: weld, fit into a box, crease-split normals, UV
seams, and the canonical digest. Pure functions of arrays (the atlas: geometry.unwrap).
"""

from __future__ import annotations

import hashlib

import numpy as np

#: Faces meeting at more than this angle keep separate normals (a crease); below it the
#: normals are averaged (area-weighted), so a smooth surface shades smoothly.
CREASE_DEG = 40.0
#: Seams whose two sides' normals differ by more than this run along a crease.
SEAM_CREASE_DEG = 1.0
#: Corners whose crease normals are computed per block (bounds the pairs held at once).
_CORNER_BLOCK = 1 << 18


def weld(positions: np.ndarray, faces: np.ndarray, uv: np.ndarray | None = None):
    """Merge vertices with bit-identical positions (and UVs): one canonical, sorted order.

    A triangle soup (STL) becomes an indexed mesh, and the same mesh read from two
    formats gets the same vertex order. Returns ``(positions, faces, uv)``.
    """
    key = positions.astype(np.float32)
    if uv is not None:
        key = np.concatenate([key, uv.astype(np.float32)], 1)
    unique, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    faces = inverse.ravel()[faces]
    positions = positions[first]
    return positions, faces, (uv[first] if uv is not None else None)


def fit_in_box(positions: np.ndarray, half_width: float, top: float) -> np.ndarray:
    """Uniform scale and shift: centred on the z axis, min z = 0, inside |x|,|y| <= half_width, z <= top."""
    lo, hi = positions.min(0), positions.max(0)
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    extents = [half_width / half[0] if half[0] > 0 else np.inf, half_width / half[1] if half[1] > 0 else np.inf]
    extents.append(top / (hi[2] - lo[2]) if hi[2] > lo[2] else np.inf)
    scale = min(extents)
    out = (positions - np.array([centre[0], centre[1], lo[2]])) * scale
    out[:, 2] = np.maximum(out[:, 2], 0.0)  # -0.0 and last-bit noise: min z is exactly 0
    return out


def face_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted (unnormalised) face normals: twice the area times the unit normal."""
    p = positions[faces]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def crease_normals(positions: np.ndarray, faces: np.ndarray, crease_deg: float = CREASE_DEG):
    """Vertex normals smooth across gentle edges and split at creases.

    Each corner takes the area-weighted normal of the faces around its position that lie
    within ``crease_deg`` of the corner's own face: one smooth normal where no crease runs
    through the vertex, one per side where one does.
    Returns ``(source (N',), faces (M, 3), normals (N', 3))``: new vertex i copies old
    vertex ``source[i]`` with its own normal.
    """
    cross = face_normals(positions, faces)
    unit = _unit(cross)
    _, group = np.unique(positions.astype(np.float32), axis=0, return_inverse=True)
    group = group.ravel()
    corner_group = group[faces].ravel()
    corner_face = np.repeat(np.arange(len(faces)), 3)
    smooth = np.zeros((group.max() + 1, 3))
    np.add.at(smooth, corner_group, cross[corner_face])
    normals = _unit(smooth)[corner_group]
    cos_limit = np.cos(np.radians(crease_deg))
    # Where every face around a position is within crease_deg / 2 of the mean, every pair is
    # within crease_deg and the mean is the answer; elsewhere the faces are compared pairwise.
    dots = np.einsum("ij,ij->i", normals, unit[corner_face])
    group_min = np.full(len(smooth), np.inf)
    np.minimum.at(group_min, corner_group, dots)
    flagged = np.flatnonzero(group_min[corner_group] < np.cos(np.radians(0.5 * crease_deg)))
    if len(flagged):
        order = np.argsort(corner_group, kind="stable")
        starts = np.searchsorted(corner_group[order], np.arange(len(smooth)))
        counts = np.bincount(corner_group, minlength=len(smooth))
        for block in range(0, len(flagged), _CORNER_BLOCK):
            corners = flagged[block : block + _CORNER_BLOCK]
            normals[corners] = _within_crease(
                corners, corner_group, corner_face, order, starts, counts, cross, unit, cos_limit
            )
    normals = np.where(np.linalg.norm(normals, axis=1, keepdims=True) > 0, normals, unit[corner_face])
    key = np.zeros(len(normals), dtype=[("v", "<i8"), ("n", "<f4", (3,))])
    key["v"] = faces.ravel()
    key["n"] = normals
    unique, inverse = np.unique(key, return_inverse=True)
    return unique["v"], inverse.reshape(-1, 3), _unit(unique["n"].astype(np.float64))


def _within_crease(corners, corner_group, corner_face, order, starts, counts, cross, unit, cos_limit):
    g = corner_group[corners]
    k = counts[g]
    owner = np.repeat(np.arange(len(corners)), k)
    offset = np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)
    other = corner_face[order[np.repeat(starts[g], k) + offset]]
    mine = corner_face[corners][owner]
    take = np.einsum("ij,ij->i", unit[mine], unit[other]) >= cos_limit
    out = np.zeros((len(corners), 3))
    np.add.at(out, owner[take], cross[other[take]])
    return _unit(out)


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v, dtype=np.float64), where=norm > 0)


def uv_usable(uv, n_vertices: int, faces: np.ndarray) -> bool:
    """True when ``uv`` is one finite pair per vertex and some face has non-zero UV area."""
    if uv is None:
        return False
    uv = np.asarray(uv)
    if uv.ndim != 2 or uv.shape != (n_vertices, 2) or not np.isfinite(uv).all():
        return False
    t = uv[faces].astype(np.float64)
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return bool(np.any(np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) > 1e-12))


def uv_seams(positions, faces, uv, normals, crease_deg: float = SEAM_CREASE_DEG):
    """Edges where the texture is discontinuous, once each, and whether each is on a crease.

    An edge is a seam when the faces sharing it (matched by endpoint positions) give its
    endpoints different UVs; open boundaries are not seams (nothing lies across them).
    Returns ``(segments (E, 2, 3) float32, on_crease (E,) bool)`` like
    :func:`geometry.atlas.seam_edges`.
    """
    _, group = np.unique(positions.astype(np.float32), axis=0, return_inverse=True)
    group = group.ravel()
    a = faces[:, [0, 1, 2]].ravel()
    b = faces[:, [1, 2, 0]].ravel()
    swap = group[a] > group[b]
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    ga, gb = group[a], group[b]
    keep = ga != gb
    a, b, ga, gb = a[keep], b[keep], ga[keep], gb[keep]
    order = np.lexsort((gb, ga))
    a, b, ga, gb = a[order], b[order], ga[order], gb[order]
    new_edge = np.ones(len(a), bool)
    new_edge[1:] = (ga[1:] != ga[:-1]) | (gb[1:] != gb[:-1])
    edge_id = np.cumsum(new_edge) - 1
    first = np.flatnonzero(new_edge)[edge_id]
    uv_diff = np.any(uv[a] != uv[a[first]], axis=1) | np.any(uv[b] != uv[b[first]], axis=1)
    cos_limit = np.cos(np.radians(crease_deg))
    dots = np.minimum(
        np.einsum("ij,ij->i", normals[a], normals[a[first]]), np.einsum("ij,ij->i", normals[b], normals[b[first]])
    )
    n_edges = int(edge_id[-1]) + 1 if len(edge_id) else 0
    seam = np.zeros(n_edges, bool)
    crease = np.zeros(n_edges, bool)
    np.logical_or.at(seam, edge_id, uv_diff)
    np.logical_or.at(crease, edge_id, dots < cos_limit)
    heads = np.flatnonzero(new_edge)[seam]
    segments = np.stack([positions[a[heads]], positions[b[heads]]], 1)
    return segments.astype(np.float32), crease[seam]


def canonical_digest(positions, faces, uv, normals, code_version: int) -> str:
    """Hex SHA-256 of the canonical mesh: little-endian float32/int32 arrays and a code version."""
    digest = hashlib.sha256(f"shaderball-object:{code_version}".encode())
    for name, array, dtype in (
        ("positions", positions, "<f4"),
        ("faces", faces, "<i4"),
        ("uv", uv, "<f4"),
        ("normals", normals, "<f4"),
    ):
        data = np.ascontiguousarray(np.asarray(array).astype(dtype))
        digest.update(f"{name}{data.shape}".encode())
        digest.update(data.tobytes())
    return digest.hexdigest()
