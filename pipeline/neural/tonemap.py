"""The one tone map between the renders (linear HDR) and the network's [0, 1] images.

    y = srgb_encode(reinhard(exposure * max(x, 0))),  reinhard(v) = v / (1 + v)

per RGB channel, with a fixed exposure (default 4.0) for a whole dataset: an automatic
per-image exposure would erase how bright a lighting is, which the network must learn.
4.0 maps the smoke spec's typical ball radiance (log-average about 0.05) to the middle of
the curve (0.2 -> 0.17 -> sRGB 0.45) and keeps highlights to about 20 distinguishable
below 1. y is sRGB-encoded (IEC 61966-2-1), so ``round(255 y)`` is the 8-bit sRGB
picture the paper's LDR metrics (PSNR, SSIM) are computed on.

The inverse, :func:`inverse_tonemap`, is exact for every y < 1 (up to float rounding)
and gives back the clamped radiance ``max(x, 0)``; y is clamped to ``1 - 1e-6`` first,
so y = 1 maps to ``1e6 / exposure``, not infinity. The accuracy study uses these same
functions for its LDR metrics.
"""

from __future__ import annotations

import numpy as np

#: Exposure of the training targets (a multiplier on linear radiance).
DEFAULT_EXPOSURE = 4.0
#: Largest y the inverse accepts before clamping: keeps 1.0 finite.
Y_MAX = 1.0 - 1e-6


def srgb_encode(linear01: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB transfer curve (IEC 61966-2-1); input clamped to [0, 1]."""
    x = np.clip(linear01, 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, np.power(x, 1 / 2.4) * 1.055 - 0.055).astype(x.dtype)


def srgb_decode(encoded01: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_encode` on [0, 1]."""
    y = np.clip(encoded01, 0.0, 1.0)
    return np.where(y <= 0.04045, y / 12.92, np.power((y + 0.055) / 1.055, 2.4))


def tonemap(hdr: np.ndarray, exposure: float = DEFAULT_EXPOSURE) -> np.ndarray:
    """Linear HDR radiance (any shape) -> [0, 1] network target, float32. NaN and
    negative values count as 0 (renders flagged in the manifest may hold them)."""
    # float32 throughout: this runs on every training target (the data loader's hot path)
    x = np.nan_to_num(np.asarray(hdr, dtype=np.float32), nan=0.0, posinf=np.finfo(np.float32).max)
    with np.errstate(over="ignore", invalid="ignore"):
        v = np.maximum(x, np.float32(0.0)) * np.float32(exposure)
        mapped = np.where(np.isinf(v), np.float32(1.0), v / (np.float32(1.0) + v))
    return srgb_encode(mapped).astype(np.float32)


def inverse_tonemap(y: np.ndarray, exposure: float = DEFAULT_EXPOSURE) -> np.ndarray:
    """[0, 1] image -> linear HDR radiance, float32; the inverse of :func:`tonemap`."""
    m = srgb_decode(np.asarray(y, dtype=np.float64))
    m = np.minimum(m, Y_MAX)
    return (m / (1.0 - m) / exposure).astype(np.float32)


def to_srgb8(y: np.ndarray) -> np.ndarray:
    """A [0, 1] sRGB-encoded image -> uint8 (round half up), as PNG files store it."""
    return np.floor(np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def hdr_to_srgb8(hdr: np.ndarray, exposure: float = DEFAULT_EXPOSURE) -> np.ndarray:
    """Linear HDR -> the 8-bit sRGB picture the LDR metrics compare."""
    return to_srgb8(tonemap(hdr, exposure))
