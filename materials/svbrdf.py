"""Procedural spatially varying materials: tileable, seeded, normals from height fields.

Deschaintre et al.'s SVBRDF set can't be downloaded here, so the spatially
varying half of the dataset is generated. Each family is a small material
"graph" of periodic noise (:mod:`materials.noise`) with its own random
palette and parameters:

``stains``
    a matte base (plaster, paper, concrete) with blotchy stains that are
    darker, glossier and edged like dried liquid; faint grain and relief.
``tiles``
    glossy square ceramic tiles in recessed grout, with per-tile colour,
    tilt and bevelled edges.
``bricks``
    rough running-bond bricks in mortar, the same construction as ``tiles``.
``brushed_metal``
    a metal (steel, aluminium, gold, copper, brass, titanium) brushed along
    one axis, with scratches cut into it.
``worn_paint``
    flecked paint over bare metal or rust, chipped away in patches.
``stones``
    irregular cobbles (cellular noise) in dark dirt, per stone colour.

Every map is a function of texture coordinates on the unit torus, so it
tiles at any resolution; heights are in units of the texture's side, so the
normals describe the same surface at any resolution. The same generator
state gives byte-identical maps (numpy float64 arithmetic, cast at the end).
"""

from __future__ import annotations

import numpy as np

from materials.colorspace import hsv_to_rgb, srgb_decode
from materials.errors import MaterialError
from materials.maps import MaterialMaps, _as_resolution, normals_from_height
from materials.noise import fbm, gradient_noise, periodic_segments, smoothstep, texel_uv, worley

SVBRDF_FAMILIES = ("stains", "tiles", "bricks", "brushed_metal", "worn_paint", "stones")
#: Smallest map side the families are designed for (features are a few texels wide at 64).
MIN_RESOLUTION = 16


def sample_svbrdf(rng: np.random.Generator, family: str, resolution) -> MaterialMaps:
    """One material of ``family`` at ``resolution`` (int or (H, W)), drawn from ``rng``."""
    if not isinstance(rng, np.random.Generator):
        raise MaterialError(f"sample_svbrdf: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if family not in SVBRDF_FAMILIES:
        raise MaterialError(f"svbrdf family: {family!r} is not one of {', '.join(SVBRDF_FAMILIES)}")
    shape = _as_resolution(resolution)
    if min(shape) < MIN_RESOLUTION:
        raise MaterialError(f"svbrdf resolution: {resolution!r} is below the minimum {MIN_RESOLUTION}")
    return _FAMILIES[family](rng, shape)


# ---- helpers ------------------------------------------------------------------------------


def _colour(hue, saturation, value_srgb) -> np.ndarray:
    """Linear RGB from HSV with V in sRGB-encoded units; broadcasts."""
    hsv = np.stack(np.broadcast_arrays(np.mod(hue, 1.0), saturation, value_srgb), axis=-1)
    return np.clip(srgb_decode(np.clip(hsv_to_rgb(hsv), 0.0, 1.0)), 0.0, 1.0)


def _lerp(a, b, t):
    t = np.asarray(t)
    if t.ndim == 2 and (np.ndim(a) == 3 or np.ndim(a) == 1 or np.ndim(b) == 3 or np.ndim(b) == 1):
        t = t[..., None]
    return a + (b - a) * t


def _finish(diffuse, specular, roughness, height, depth) -> MaterialMaps:
    specular = np.clip(specular, 0.0, 1.0)
    diffuse = np.clip(np.minimum(diffuse, 1.0 - specular), 0.0, 1.0)
    shape = np.shape(roughness)
    maps = MaterialMaps(
        diffuse=np.broadcast_to(diffuse, shape + (3,)),
        specular=np.broadcast_to(specular, shape + (3,)),
        roughness=np.clip(roughness, 0.0, 1.0),
        normal=normals_from_height(height, depth),
    )
    return maps.check()


# ---- families -----------------------------------------------------------------------------


def _stains(rng, shape):
    hue = rng.uniform()
    base = _colour(hue, rng.uniform(0.0, 0.3), rng.uniform(0.6, 0.9))
    stain_hue = hue + rng.uniform(-0.08, 0.08) if rng.uniform() < 0.5 else rng.uniform(0.04, 0.12)
    stain = _colour(stain_hue, rng.uniform(0.3, 0.75), rng.uniform(0.2, 0.5))
    cells = int(rng.integers(2, 5))
    field = fbm(rng, shape, cells, octaves=6, gain=0.55)
    threshold = rng.uniform(-0.15, 0.2)
    coverage = smoothstep(threshold - 0.02, threshold + 0.12, field)
    ring = np.exp(-(((field - threshold) / 0.025) ** 2))
    opacity = rng.uniform(0.6, 1.0)
    grain = fbm(rng, shape, 24, octaves=3)
    diffuse = _lerp(base, stain, coverage * opacity) * (1.0 + 0.12 * grain)[..., None]
    diffuse *= (1.0 - 0.35 * opacity * ring)[..., None]
    r_base, r_stain = rng.uniform(0.55, 0.9), rng.uniform(0.2, 0.5)
    roughness = _lerp(r_base, r_stain, coverage) + 0.06 * grain
    specular = _lerp(0.035, rng.uniform(0.04, 0.06), coverage)[..., None] * np.ones(3)
    height = 0.6 * fbm(rng, shape, 12, octaves=4) - 0.3 * coverage
    return _finish(diffuse, specular, roughness, height, rng.uniform(0.002, 0.005))


def _tiles(rng, shape):
    return _tiled(rng, shape, bricks=False)


def _bricks(rng, shape):
    return _tiled(rng, shape, bricks=True)


def _tiled(rng, shape, *, bricks: bool):
    u, v = texel_uv(shape)
    if bricks:
        cols = int(rng.integers(2, 5))
        rows = 2 * cols * int(rng.integers(1, 3))  # even, so the half-brick offset tiles
    else:
        cols = rows = int(rng.choice([2, 3, 4, 6, 8]))
    y = v * rows
    row = np.floor(y).astype(np.int64)
    x = u * cols + (0.5 * (row % 2) if bricks else 0.0)
    col = np.floor(x).astype(np.int64) % cols
    fx, fy = x - np.floor(x), y - row
    edge = np.minimum(np.minimum(fx, 1.0 - fx) / cols, np.minimum(fy, 1.0 - fy) / rows)
    tile_id = row * cols + col
    count = rows * cols

    grout_half = rng.uniform(0.004, 0.01)
    bevel = rng.uniform(0.003, 0.012)
    texel = 1.0 / max(shape)
    tile_mask = smoothstep(grout_half - 0.5 * texel, grout_half + 0.5 * texel, edge)
    plateau = smoothstep(grout_half, grout_half + bevel, edge)

    if bricks:
        hue = rng.uniform(0.0, 0.08) + rng.uniform(-0.02, 0.02, count)
        sat = rng.uniform(0.35, 0.7) + rng.uniform(-0.1, 0.1, count)
        val = rng.uniform(0.35, 0.6) + rng.uniform(-0.12, 0.12, count)
        r_tile = rng.uniform(0.6, 0.9) + rng.uniform(-0.05, 0.05, count)
    else:
        hue = rng.uniform() + rng.uniform(-0.015, 0.015, count)
        sat = rng.uniform(0.1, 0.8) + rng.uniform(-0.05, 0.05, count)
        val = rng.uniform(0.45, 0.9) + rng.uniform(-0.06, 0.06, count)
        r_tile = rng.uniform(0.08, 0.3) + rng.uniform(-0.03, 0.03, count)
    tile_colour = _colour(hue, np.clip(sat, 0, 1), np.clip(val, 0, 1))
    grout = _colour(rng.uniform(0.05, 0.15), rng.uniform(0.0, 0.15), rng.uniform(0.45, 0.8))
    slope = rng.normal(0.0, 0.15, size=(count, 2))

    detail = fbm(rng, shape, 8 * max(rows, cols) // 2, octaves=4)
    diffuse = _lerp(grout, tile_colour[tile_id] * (1.0 + 0.1 * detail)[..., None], tile_mask)
    roughness = _lerp(rng.uniform(0.85, 1.0), np.clip(r_tile, 0.02, 1)[tile_id] + 0.05 * detail, tile_mask)
    specular = np.full(shape + (3,), 0.04)
    tilt = slope[tile_id, 0] * (fx - 0.5) + slope[tile_id, 1] * (fy - 0.5)
    height = plateau * (1.0 + tilt) + (0.08 if bricks else 0.02) * detail
    return _finish(diffuse, specular, roughness, height, rng.uniform(0.006, 0.014))


_METALS = {  # hue, saturation, value (sRGB-encoded) of the specular albedo
    "steel": (0.6, 0.04, 0.78),
    "aluminium": (0.6, 0.02, 0.92),
    "gold": (0.12, 0.45, 0.97),
    "copper": (0.05, 0.5, 0.92),
    "brass": (0.14, 0.38, 0.9),
    "titanium": (0.62, 0.06, 0.66),
}


def _brushed_metal(rng, shape):
    name = list(_METALS)[int(rng.integers(len(_METALS)))]
    hue, sat, val = _METALS[name]
    specular = _colour(hue + rng.uniform(-0.01, 0.01), sat * rng.uniform(0.8, 1.2), val * rng.uniform(0.93, 1.0))
    along_u = bool(rng.uniform() < 0.5)
    fine = 96 if max(shape) >= 192 else 32
    cells = (fine, 2) if along_u else (2, fine)
    streaks = 0.6 * gradient_noise(rng, shape, cells) + 0.4 * gradient_noise(rng, shape, (2 * cells[0], 2 * cells[1]))
    smudge = fbm(rng, shape, 3, octaves=4)

    count = int(rng.integers(15, 60))
    start = rng.uniform(0.0, 1.0, size=(count, 2))
    angle = rng.uniform(0.0, np.pi, count)
    length = rng.uniform(0.05, 0.35, count)
    end = start + length[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    width_px = max(1.0, rng.uniform(0.002, 0.004) * max(shape))
    scratches = periodic_segments(shape, np.concatenate([start, end], axis=1), width_px)

    r0 = rng.uniform(0.15, 0.4)
    roughness = r0 + 0.06 * streaks + 0.05 * smudge + 0.15 * scratches
    spec = specular * (1.0 + 0.04 * streaks - 0.1 * scratches)[..., None]
    diffuse = np.repeat((0.015 * (1.0 + smudge))[..., None], 3, axis=-1)  # grey grime
    height = 0.1 * streaks - scratches
    return _finish(diffuse, spec, roughness, height, rng.uniform(0.001, 0.0025))


def _worn_paint(rng, shape):
    paint = _colour(rng.uniform(), rng.uniform(0.45, 0.9), rng.uniform(0.45, 0.9))
    fleck = _colour(rng.uniform(), rng.uniform(0.0, 0.3), rng.choice([0.15, 0.95]))
    rusty = bool(rng.uniform() < 0.35)
    if rusty:
        under_d = _colour(rng.uniform(0.02, 0.07), rng.uniform(0.5, 0.75), rng.uniform(0.3, 0.45))
        under_s, under_r = np.full(3, 0.04), rng.uniform(0.75, 0.95)
    else:
        under_s = _colour(0.6, rng.uniform(0.0, 0.05), rng.uniform(0.7, 0.85))
        under_d, under_r = 0.02 * (1.0 - under_s), rng.uniform(0.3, 0.55)

    wear_field = fbm(rng, shape, int(rng.integers(3, 6)), octaves=6) + 0.3 * fbm(rng, shape, 16, octaves=3)
    threshold = rng.uniform(0.15, 0.4)
    exposed = smoothstep(threshold, threshold + 0.03, wear_field)

    f1, _, ids = worley(rng, shape, int(rng.integers(30, 70)))
    keep = rng.uniform(size=ids.max() + 1) < rng.uniform(0.25, 0.6)
    radius = rng.uniform(0.12, 0.25)
    flecks = keep[ids] * smoothstep(radius, radius - 0.08, f1)

    grime = smoothstep(-0.2, 0.6, fbm(rng, shape, 4, octaves=5))
    paint_d = _lerp(paint, fleck, flecks) * (1.0 - 0.25 * grime)[..., None]
    r_paint = rng.uniform(0.25, 0.55)
    diffuse = _lerp(paint_d, under_d, exposed)
    specular = _lerp(np.full(3, 0.04), under_s, exposed)
    roughness = _lerp(r_paint + 0.1 * grime, under_r, exposed)
    height = (1.0 - exposed) + 0.05 * fbm(rng, shape, 32, octaves=2)
    return _finish(diffuse, specular, roughness, height, rng.uniform(0.002, 0.005))


def _stones(rng, shape):
    cells = int(rng.integers(4, 9))
    f1, f2, ids = worley(rng, shape, cells, jitter=0.8)
    border = f2 - f1
    gap = rng.uniform(0.04, 0.1)
    stone = smoothstep(gap, gap + 0.12, border)
    dome = np.sqrt(np.clip(border / 0.6, 0.0, 1.0))
    count = cells * cells
    hue = rng.uniform(0.05, 0.12) + rng.uniform(-0.03, 0.03, count)
    sat = rng.uniform(0.05, 0.35) + rng.uniform(-0.05, 0.05, count)
    val = rng.uniform(0.4, 0.75) + rng.uniform(-0.15, 0.15, count)
    stone_colour = _colour(hue, np.clip(sat, 0, 1), np.clip(val, 0, 1))
    dirt = _colour(rng.uniform(0.05, 0.1), rng.uniform(0.3, 0.6), rng.uniform(0.15, 0.3))
    detail = fbm(rng, shape, 4 * cells, octaves=4)
    r_stone = rng.uniform(0.35, 0.8) + rng.uniform(-0.1, 0.1, count)
    diffuse = _lerp(dirt, stone_colour[ids] * (1.0 + 0.15 * detail)[..., None], stone)
    roughness = _lerp(rng.uniform(0.85, 1.0), np.clip(r_stone, 0.05, 1.0)[ids] + 0.05 * detail, stone)
    specular = np.full(shape + (3,), 0.04)
    height = stone * (0.5 + 0.5 * dome) + 0.08 * detail
    return _finish(diffuse, specular, roughness, height, rng.uniform(0.015, 0.03))


_FAMILIES = {
    "stains": _stains,
    "tiles": _tiles,
    "bricks": _bricks,
    "brushed_metal": _brushed_metal,
    "worn_paint": _worn_paint,
    "stones": _stones,
}
