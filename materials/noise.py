"""Tileable noise on the unit torus, evaluated at texel centres (pure numpy, seeded).

Every function takes the (H, W) shape of the map and returns values at
``u = (j + 0.5) / W``, ``v = (i + 0.5) / H``. Lattices have an integer number
of cells per unit in each direction and wrap around, so every result tiles.
"""

from __future__ import annotations

import numpy as np


def texel_uv(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of texel centres, each (H, W) float64."""
    height, width = shape
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    return np.broadcast_to(u[None, :], shape), np.broadcast_to(v[:, None], shape)


def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def gradient_noise(rng: np.random.Generator, shape, cells: tuple[int, int]) -> np.ndarray:
    """Periodic Perlin gradient noise with ``cells = (rows, cols)`` lattice cells per unit; ~[-1, 1]."""
    cells_v, cells_u = int(cells[0]), int(cells[1])
    angle = rng.uniform(0.0, 2.0 * np.pi, size=(cells_v, cells_u))
    gx, gy = np.cos(angle), np.sin(angle)
    u, v = texel_uv(shape)
    x, y = u * cells_u, v * cells_v
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    x0 %= cells_u
    y0 %= cells_v
    x1, y1 = (x0 + 1) % cells_u, (y0 + 1) % cells_v

    def corner(yi, xi, dx, dy):
        return gx[yi, xi] * dx + gy[yi, xi] * dy

    n00 = corner(y0, x0, fx, fy)
    n10 = corner(y0, x1, fx - 1.0, fy)
    n01 = corner(y1, x0, fx, fy - 1.0)
    n11 = corner(y1, x1, fx - 1.0, fy - 1.0)
    sx, sy = _fade(fx), _fade(fy)
    top = n00 + sx * (n10 - n00)
    bottom = n01 + sx * (n11 - n01)
    return np.sqrt(2.0) * (top + sy * (bottom - top))


def fbm(
    rng: np.random.Generator,
    shape,
    cells: tuple[int, int] | int,
    octaves: int = 5,
    gain: float = 0.5,
) -> np.ndarray:
    """Fractal sum of :func:`gradient_noise`, cells doubling per octave; normalised to ~[-1, 1]."""
    if isinstance(cells, int):
        cells = (cells, cells)
    total = np.zeros(shape)
    amplitude, norm = 1.0, 0.0
    for octave in range(octaves):
        scale = 2**octave
        total += amplitude * gradient_noise(rng, shape, (cells[0] * scale, cells[1] * scale))
        norm += amplitude
        amplitude *= gain
    return total / norm


def worley(rng: np.random.Generator, shape, cells: int, jitter: float = 0.9):
    """Periodic cellular noise: distances to the nearest and second-nearest feature point and the nearest's id.

    One feature point per cell of a ``cells`` x ``cells`` lattice. Distances are
    in units of one cell. Returns (f1, f2, cell_id), each (H, W).
    """
    cells = int(cells)
    offset = 0.5 + jitter * (rng.uniform(size=(cells, cells, 2)) - 0.5)
    u, v = texel_uv(shape)
    x, y = u * cells, v * cells
    cx, cy = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    f1 = np.full(shape, np.inf)
    f2 = np.full(shape, np.inf)
    ids = np.zeros(shape, dtype=np.int64)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            nx, ny = cx + dx, cy + dy
            wx, wy = nx % cells, ny % cells
            px = nx + offset[wy, wx, 0]
            py = ny + offset[wy, wx, 1]
            dist = np.hypot(px - x, py - y)
            closer = dist < f1
            f2 = np.where(closer, f1, np.minimum(f2, dist))
            ids = np.where(closer, wy * cells + wx, ids)
            f1 = np.where(closer, dist, f1)
    return f1, f2, ids


def smoothstep(edge0, edge1, x):
    """Hermite step from 0 at ``edge0`` to 1 at ``edge1``."""
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def periodic_segments(shape, segments: np.ndarray, width_px: float) -> np.ndarray:
    """Coverage in [0, 1] of anti-aliased line segments on the torus.

    ``segments`` is (N, 4) of (u0, v0, u1, v1) in texture units; lines are
    ``width_px`` texels wide with a one-texel soft edge. Only a wrapped
    bounding box around each segment is touched, so many short segments are cheap.
    """
    height, width = shape
    cover = np.zeros(shape)
    half = 0.5 * width_px + 1.0
    for u0, v0, u1, v1 in np.asarray(segments, dtype=np.float64):
        x0, y0, x1, y1 = u0 * width, v0 * height, u1 * width, v1 * height
        j_lo, j_hi = int(np.floor(min(x0, x1) - half)), int(np.ceil(max(x0, x1) + half))
        i_lo, i_hi = int(np.floor(min(y0, y1) - half)), int(np.ceil(max(y0, y1) + half))
        jj = np.arange(j_lo, j_hi + 1)
        ii = np.arange(i_lo, i_hi + 1)
        px, py = jj[None, :] + 0.5, ii[:, None] + 0.5
        dx, dy = x1 - x0, y1 - y0
        length2 = dx * dx + dy * dy
        t = np.clip(((px - x0) * dx + (py - y0) * dy) / max(length2, 1e-12), 0.0, 1.0)
        dist = np.hypot(px - (x0 + t * dx), py - (y0 + t * dy))
        value = np.clip(0.5 * width_px + 0.5 - dist, 0.0, 1.0)
        rows, cols = ii % height, jj % width
        # Unbuffered max: wrapped indices repeat when a box is wider than the map.
        np.maximum.at(cover, np.ix_(rows, cols), value)
    return cover
