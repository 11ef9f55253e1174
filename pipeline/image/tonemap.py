"""The tone maps: linear HDR renders to [0, 1] images (the network's) and to 8-bit pictures (people's).

**The network's images** (:func:`tonemap`, :func:`inverse_tonemap`, :func:`hdr_to_srgb8`):

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

**Pictures for people** (:func:`preview_srgb8`, :func:`map_srgb8`: previews, contact
sheets, the docs' figures; never data): an automatic exposure (the log-average luminance
over a mask mapped to 0.18), the same Reinhard curve and sRGB encoding, to uint8.
"""

from __future__ import annotations

import numpy as np

from pipeline.image.srgb import srgb_decode, srgb_encode

#: Exposure of the training targets (a multiplier on linear radiance).
DEFAULT_EXPOSURE = 4.0
#: Largest y the inverse accepts before clamping: keeps 1.0 finite.
Y_MAX = 1.0 - 1e-6


def reinhard(v: np.ndarray) -> np.ndarray:
    """The curve of both tone maps: ``v / (1 + v)`` for ``v >= 0``, in ``v``'s float type; 1
    where ``v`` is +inf (its limit)."""
    one = v.dtype.type(1.0)
    with np.errstate(invalid="ignore"):
        return np.where(np.isinf(v), one, v / (one + v))


def tonemap(hdr: np.ndarray, exposure: float = DEFAULT_EXPOSURE) -> np.ndarray:
    """Linear HDR radiance (any shape) -> [0, 1] network target, float32. NaN and
    negative values count as 0 (renders flagged in the manifest may hold them)."""
    # float32 throughout: this runs on every training target (the data loader's hot path)
    x = np.nan_to_num(np.asarray(hdr, dtype=np.float32), nan=0.0, posinf=np.finfo(np.float32).max)
    with np.errstate(over="ignore"):
        v = np.maximum(x, np.float32(0.0)) * np.float32(exposure)
    return srgb_encode(reinhard(v)).astype(np.float32)


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


def exposure_for(image: np.ndarray, mask: np.ndarray | None = None, key: float = 0.18) -> float:
    """Exposure that maps the log-average luminance (over ``mask``) to ``key``."""
    lum = 0.2126 * image[..., 0] + 0.7152 * image[..., 1] + 0.0722 * image[..., 2]
    sel = lum[mask] if mask is not None and mask.any() else lum
    sel = sel[np.isfinite(sel)]
    if sel.size == 0:
        return 1.0
    log_avg = float(np.exp(np.mean(np.log(np.maximum(sel, 1e-6)))))
    return key / log_avg if log_avg > 0 else 1.0


def preview_srgb8(image: np.ndarray, exposure: float | None = None, mask: np.ndarray | None = None) -> np.ndarray:
    """Linear HDR (H, W, 3) -> uint8 sRGB picture with an automatic exposure and a Reinhard curve."""
    image = np.nan_to_num(np.asarray(image, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    image = np.maximum(image, 0.0)
    if exposure is None:
        exposure = exposure_for(image, mask)
    with np.errstate(over="ignore"):  # an exposed value past float32's range is white, by design
        exposed = image * exposure
    return (srgb_encode(reinhard(exposed)) * 255.0 + 0.5).astype(np.uint8)


def map_srgb8(linear01: np.ndarray, srgb: bool = True) -> np.ndarray:
    """A map in [0, 1] (albedo: linear, so sRGB-encode it; others: raw) to uint8."""
    x = srgb_encode(linear01) if srgb else np.clip(linear01, 0.0, 1.0)
    return (x * 255.0 + 0.5).astype(np.uint8)
