"""Texture-space maps to screen space through the G-buffer, as Mitsuba would look them up.

:func:`bilinear_lookup` reproduces Mitsuba's ``bitmap`` texture with
``filter_type = "bilinear"``, ``wrap_mode = "repeat"``, ``raw = True`` (drjit's
``Texture.eval``, llvm backend) operation for operation in float32:

- texel (row i, col j) has its centre at ``u = (j + 0.5) / w``, ``v = (i + 0.5) / h``;
  no flip of v;
- ``x = fma(u, w, -0.5)``, ``x0 = floor(x)``, ``wx1 = x - x0``, ``wx0 = 1 - wx1`` (same in y);
- corners in the order (x0, y0), (x1, y0), (x0, y1), (x1, y1), indices wrapped by a
  Euclidean modulo, weight ``wx * wy``, accumulated with fused multiply-adds.

A fused multiply-add of float32 operands is evaluated in float64 and rounded once,
which equals the fused result except in double-rounding ties (at most 1 ulp).
Texture arrays are rounded to float32 first, as :func:`pipeline.render.scene.bitmap_texture`
does for Mitsuba.

Outside the G-buffer's mask every projected map is 0.
"""

from __future__ import annotations

import numpy as np

from materials.maps import encode_normal_map
from pipeline.render.gbuffer import GBuffer

F32 = np.float32


def _fma(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    return (a.astype(np.float64) * b.astype(np.float64) + c.astype(np.float64)).astype(F32)


def bilinear_lookup(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Look ``texture`` ((h, w) or (h, w, C)) up at ``uv`` ((..., 2)); returns (..., C) float32."""
    tex = np.asarray(texture, dtype=F32)
    if tex.ndim == 2:
        tex = tex[:, :, None]
    if tex.ndim != 3:
        raise ValueError(f"texture must be (h, w) or (h, w, C), got shape {np.shape(texture)}")
    h, w, channels = tex.shape
    uv = np.asarray(uv, dtype=F32)
    lead = uv.shape[:-1]
    u = uv[..., 0].ravel()
    v = uv[..., 1].ravel()

    x = _fma(u, F32(w), F32(-0.5))
    y = _fma(v, F32(h), F32(-0.5))
    x0 = np.floor(x)
    y0 = np.floor(y)
    wx1 = (x - x0).astype(F32)
    wy1 = (y - y0).astype(F32)
    wx0 = (F32(1.0) - wx1).astype(F32)
    wy0 = (F32(1.0) - wy1).astype(F32)
    ix0 = x0.astype(np.int64)
    iy0 = y0.astype(np.int64)

    flat = tex.reshape(h * w, channels)
    out = np.zeros((u.size, channels), F32)
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        weight = ((F32(1.0) * (wx1 if dx else wx0)).astype(F32) * (wy1 if dy else wy0)).astype(F32)
        index = ((iy0 + dy) % h) * w + (ix0 + dx) % w
        out = _fma(flat[index], weight[:, None], out)
    return out.reshape(lead + (channels,))


def project(texture: np.ndarray, gbuffer: GBuffer) -> np.ndarray:
    """Screen-space (H, W, C) float32 image of a texture-space map; 0 outside the mask."""
    tex = np.asarray(texture)
    channels = 1 if tex.ndim == 2 else tex.shape[2]
    out = np.zeros(gbuffer.mask.shape + (channels,), F32)
    out[gbuffer.mask] = bilinear_lookup(tex, gbuffer.uv[gbuffer.mask])
    return out


def encode_normal_texture(normal: np.ndarray) -> np.ndarray:
    """A unit tangent-space normal map (h, w, 3) as the [0, 1] texture Mitsuba's
    ``normalmap`` BSDF takes. The renderer's own encoding (materials.encode_normal_map),
    so the screen-space normals are computed from the very texels the renderer reads."""

    return encode_normal_map(normal)


def decode_normal(encoded: np.ndarray) -> np.ndarray:
    """Mitsuba's ``normalmap``: n = normalize(fma(t, 2, -1)); zero vectors stay zero."""
    n = _fma(np.asarray(encoded, F32), F32(2.0), np.full(np.shape(encoded), -1.0, F32))
    length = np.sqrt(np.sum(n.astype(np.float64) ** 2, axis=-1, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(length > 0, n / length, 0.0)
    return unit.astype(F32)


def project_material(maps, gbuffer: GBuffer, *, geometry: bool = False) -> dict[str, np.ndarray]:
    """Screen-space maps of a ``materials.MaterialMaps`` as the renderer sees them.

    Returns float32 arrays: ``diffuse`` (H, W, 3), ``specular`` (H, W, 3), ``roughness``
    (H, W), ``normal`` (H, W, 3) tangent-space, unit inside the mask, and ``mask``
    (H, W) in {0, 1}. The normal is looked up bilinearly in its encoded form
    (:func:`encode_normal_texture`), then decoded and renormalised as Mitsuba's
    ``normalmap`` does; the tangent frame is (dp/du, n x dp/du, n).

    ``geometry``: also the geometry the maps were projected through (:func:`geometry_layers`),
    so a dataset's maps file holds whichever of the lot its spec's ``storage.layers`` names;
    off, only the maps (what the network reads, what ``shaderball render`` writes).
    """
    mask = gbuffer.mask
    normal = project(encode_normal_texture(maps.normal), gbuffer)
    normal[mask] = decode_normal(normal[mask])
    screen = {
        "diffuse": project(maps.diffuse, gbuffer),
        "specular": project(maps.specular, gbuffer),
        "roughness": project(maps.roughness, gbuffer)[..., 0],
        "normal": normal,
        "mask": mask.astype(F32),
    }
    return {**screen, **geometry_layers(gbuffer)} if geometry else screen


def geometry_layers(gbuffer: GBuffer) -> dict[str, np.ndarray]:
    """The G-buffer's geometry as screen-space layers, 0 outside the mask (as the G-buffer is).

    ``geometry_normal`` (H, W, 3): the object's world-space shading normal (interpolated
    vertex normals, before any normal map), unit inside the mask; ``depth`` (H, W): metres
    from the camera plane along the view axis. Copies: a caller may change them.
    """
    return {
        "geometry_normal": np.array(gbuffer.normal, dtype=F32),
        "depth": np.array(gbuffer.depth, dtype=F32),
    }
