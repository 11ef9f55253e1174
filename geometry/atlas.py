"""Packing the material charts into one UV atlas with xatlas, and finding the seams.

The charts arrive already cut and parametrised (equal-area, in metres; see
:mod:`geometry.patches`); xatlas packs them into the unit square at one common scale.
xatlas's own charting (LSCM, conformal) would scatter seams over the visible front and
vary the texel density by a factor of several across a near-hemispherical chart.

Chart rotation is off: xatlas implements a 90-degree "rotation" as a swap of u and v,
which mirrors the chart and would flip a tangent-space normal map's y axis (measured
with xatlas 0.0.11).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.patches import Patch

#: Texels between charts at ATLAS_RESOLUTION.
ATLAS_PADDING = 4
#: Nominal atlas size xatlas packs for; charts are then scaled into [0, 1]^2.
ATLAS_RESOLUTION = 1024


@dataclass(frozen=True)
class Atlas:
    positions: np.ndarray  # (N, 3) float32
    normals: np.ndarray  # (N, 3) float32
    uv: np.ndarray  # (N, 2) float32 in [0, texture_repeats]
    faces: np.ndarray  # (M, 3) int32
    face_chart: np.ndarray  # (M,) int16: index into chart_names
    chart_names: tuple[str, ...]
    atlas_size: tuple[int, int]  # xatlas width, height in texels
    utilization: float


def pack_charts(charts: list[Patch], texture_repeats: int = 1) -> Atlas:
    """Pack ``charts`` (one UV chart each) with xatlas; isotropic scale into [0, 1]^2."""
    import xatlas

    positions = np.concatenate([c.positions for c in charts]).astype(np.float32)
    normals = np.concatenate([c.normals for c in charts])
    normals = (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)
    uv_m = np.concatenate([c.uv for c in charts])
    offsets = np.cumsum([0] + [len(c.positions) for c in charts])
    faces = np.concatenate([c.faces + o for c, o in zip(charts, offsets)]).astype(np.uint32)
    face_chart = np.concatenate([np.full(len(c.faces), i, np.int16) for i, c in enumerate(charts)])
    # Each chart starts at the origin of its own metres so xatlas sees small numbers.
    for lo, hi in zip(offsets[:-1], offsets[1:]):
        uv_m[lo:hi] -= uv_m[lo:hi].min(0)

    atlas = xatlas.Atlas()
    atlas.add_mesh(positions, faces, normals, uv_m.astype(np.float32))
    chart_options = xatlas.ChartOptions()
    chart_options.use_input_mesh_uvs = True
    pack_options = xatlas.PackOptions()
    pack_options.padding = ATLAS_PADDING
    pack_options.resolution = ATLAS_RESOLUTION
    pack_options.bilinear = True
    pack_options.rotate_charts = False
    pack_options.rotate_charts_to_axis = False
    atlas.generate(chart_options, pack_options)
    if atlas.chart_count != len(charts):
        raise RuntimeError(f"xatlas made {atlas.chart_count} charts from {len(charts)} input charts")
    vmapping, indices, uv01 = atlas[0]
    width, height = int(atlas.width), int(atlas.height)
    # xatlas normalises u by the width and v by the height; undo that so one texel is
    # square, then fit the longer side to 1.
    side = float(max(width, height))
    uv = uv01.astype(np.float64) * np.array([width / side, height / side]) * texture_repeats
    return Atlas(
        positions=positions[vmapping],
        normals=normals[vmapping],
        uv=uv.astype(np.float32),
        faces=indices.astype(np.int32),
        face_chart=face_chart,
        chart_names=tuple(c.name for c in charts),
        atlas_size=(width, height),
        utilization=float(np.ravel(atlas.utilization)[0]),
    )


def seam_edges(atlas: Atlas, crease_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Edges where the texture is discontinuous: every chart boundary edge, once.

    Returns ``(segments (E, 2, 3) float32, on_crease (E,) bool)``. An edge is on a crease
    when the normals on its two sides differ by more than ``crease_deg``: there the
    shading already changes, so a texture seam shows least.
    """
    faces = atlas.faces.astype(np.int64)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = edges[counts[inverse.ravel()] == 1]
    # Match boundary edges across charts by their exact endpoint positions.
    pos = atlas.positions
    a = pos[boundary[:, 0]]
    b = pos[boundary[:, 1]]
    ends = np.stack([a, b], 1)
    canon = np.where(_less(a, b)[:, None, None], ends, ends[:, ::-1])
    flat = canon.reshape(len(canon), 6)
    uniq, inverse, counts = np.unique(flat, axis=0, return_inverse=True, return_counts=True)
    if np.any(counts != 2):
        raise RuntimeError(f"{int(np.sum(counts != 2))} chart boundary edges are not shared by exactly two sides")
    inverse = inverse.ravel()
    # Normals of both sides at the canonical first endpoint and second endpoint.
    swapped = ~_less(a, b)
    n0 = np.where(swapped[:, None], atlas.normals[boundary[:, 1]], atlas.normals[boundary[:, 0]])
    n1 = np.where(swapped[:, None], atlas.normals[boundary[:, 0]], atlas.normals[boundary[:, 1]])
    side = np.argsort(inverse, kind="stable").reshape(-1, 2)
    cos_limit = np.cos(np.radians(crease_deg))
    dot0 = np.einsum("ij,ij->i", n0[side[:, 0]], n0[side[:, 1]])
    dot1 = np.einsum("ij,ij->i", n1[side[:, 0]], n1[side[:, 1]])
    on_crease = (dot0 < cos_limit) | (dot1 < cos_limit)
    segments = uniq.reshape(-1, 2, 3)
    return segments.astype(np.float32), on_crease


def _less(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Lexicographic a < b for rows of points."""
    result = np.zeros(len(a), bool)
    decided = np.zeros(len(a), bool)
    for k in range(a.shape[1]):
        lt = (a[:, k] < b[:, k]) & ~decided
        gt = (a[:, k] > b[:, k]) & ~decided
        result |= lt
        decided |= lt | gt
    return result
