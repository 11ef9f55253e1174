"""HDR to 8-bit pictures for people (previews, contact sheets). Never used for data."""

from __future__ import annotations

import numpy as np


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] to the sRGB transfer curve (IEC 61966-2-1)."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def exposure_for(image: np.ndarray, mask: np.ndarray | None = None, key: float = 0.18) -> float:
    """Exposure that maps the log-average luminance (over ``mask``) to ``key``."""
    lum = 0.2126 * image[..., 0] + 0.7152 * image[..., 1] + 0.0722 * image[..., 2]
    sel = lum[mask] if mask is not None and mask.any() else lum
    sel = sel[np.isfinite(sel)]
    if sel.size == 0:
        return 1.0
    log_avg = float(np.exp(np.mean(np.log(np.maximum(sel, 1e-6)))))
    return key / log_avg if log_avg > 0 else 1.0


def tonemap(image: np.ndarray, exposure: float | None = None, mask: np.ndarray | None = None) -> np.ndarray:
    """Linear HDR (H, W, 3) -> uint8 sRGB with an automatic exposure and a Reinhard curve."""
    image = np.nan_to_num(np.asarray(image, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    image = np.maximum(image, 0.0)
    if exposure is None:
        exposure = exposure_for(image, mask)
    x = image * exposure
    mapped = x / (1.0 + x)
    return (srgb_encode(mapped) * 255.0 + 0.5).astype(np.uint8)


def to_uint8(linear01: np.ndarray, srgb: bool = True) -> np.ndarray:
    """A map in [0, 1] (albedo: linear, so sRGB-encode it; others: raw) to uint8."""
    x = srgb_encode(linear01) if srgb else np.clip(linear01, 0.0, 1.0)
    return (x * 255.0 + 0.5).astype(np.uint8)
