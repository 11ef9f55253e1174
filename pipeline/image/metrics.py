"""Image metrics of the evaluation, each in one documented form.

- PSNR and SSIM on 8-bit sRGB pictures (the paper's Table 1), over the whole image and
  all three channels. SSIM is Wang et al. 2004's standard form: Gaussian window 11x11,
  sigma 1.5, K1 = 0.01, K2 = 0.03, L = 255, population (not sample) covariances, the mean
  of the SSIM map over the pixels whose window lies inside the image, averaged over the
  channels. scikit-image reproduces it with ``gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False, data_range=255, channel_axis=-1`` (tests compare).
- relMSE on linear HDR: mean of (x - ref)^2 / (ref^2 + 0.01) over pixels and channels.
- HDR-FLIP (NVIDIA's ``flip-evaluator``), mean error on linear HDR, when installed.
"""

from __future__ import annotations

import contextlib
import io
import math

import numpy as np
from scipy import ndimage

SSIM_SIGMA = 1.5
SSIM_RADIUS = 5  # 11x11 window
SSIM_K1, SSIM_K2 = 0.01, 0.03
RELMSE_EPS = 0.01


def _as_float_u8(image: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise TypeError(f"{name}: the LDR metrics take 8-bit images, got {a.dtype}")
    return a.astype(np.float64)


def psnr8(test: np.ndarray, reference: np.ndarray) -> float:
    """PSNR in dB of two uint8 images of the same shape; inf when they are equal."""
    a, b = _as_float_u8(test, "test"), _as_float_u8(reference, "reference")
    mse = float(np.mean((a - b) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


def _gaussian_window() -> np.ndarray:
    x = np.arange(-SSIM_RADIUS, SSIM_RADIUS + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / SSIM_SIGMA) ** 2)
    return w / w.sum()


def _filter_valid(channel: np.ndarray) -> np.ndarray:
    w = _gaussian_window()
    out = ndimage.correlate1d(channel, w, axis=0, mode="reflect")
    out = ndimage.correlate1d(out, w, axis=1, mode="reflect")
    r = SSIM_RADIUS
    return out[r:-r, r:-r]


def ssim8(test: np.ndarray, reference: np.ndarray) -> float:
    """Standard SSIM of two uint8 images (H, W) or (H, W, C), H and W >= 11."""
    a, b = _as_float_u8(test, "test"), _as_float_u8(reference, "reference")
    if a.shape != b.shape:
        raise ValueError(f"shapes differ: {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    if min(a.shape[:2]) < 2 * SSIM_RADIUS + 1:
        raise ValueError(f"SSIM needs images of at least 11x11 pixels, got {a.shape[:2]}")
    c1, c2 = (SSIM_K1 * 255.0) ** 2, (SSIM_K2 * 255.0) ** 2
    values = []
    for c in range(a.shape[2]):
        x, y = a[..., c], b[..., c]
        mx, my = _filter_valid(x), _filter_valid(y)
        vx = _filter_valid(x * x) - mx * mx
        vy = _filter_valid(y * y) - my * my
        cxy = _filter_valid(x * y) - mx * my
        s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
        values.append(float(s.mean()))
    return float(np.mean(values))


def relmse(test: np.ndarray, reference: np.ndarray) -> float:
    """Relative MSE of linear HDR images: mean((x - r)^2 / (r^2 + 0.01))."""
    x = np.asarray(test, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    return float(np.mean((x - r) ** 2 / (r * r + RELMSE_EPS)))


def flip_available() -> bool:
    try:
        import flip_evaluator  # noqa: F401
    except ImportError:
        return False
    return True


def hdr_flip(test: np.ndarray, reference: np.ndarray) -> float | None:
    """Mean HDR-FLIP error of linear HDR images (negatives clamped to 0), or None when
    ``flip-evaluator`` is not installed. Its prints stay off stdout; its ``sys.exit`` on
    a bad argument becomes a ValueError."""
    try:
        import flip_evaluator
    except ImportError:
        return None
    ref = np.ascontiguousarray(np.maximum(np.nan_to_num(reference), 0.0), dtype=np.float32)
    tst = np.ascontiguousarray(np.maximum(np.nan_to_num(test), 0.0), dtype=np.float32)
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink):
            _, mean_error, _ = flip_evaluator.evaluate(ref, tst, "HDR", applyMagma=False)
    except SystemExit as exc:
        raise ValueError(f"flip-evaluator refused its input: {sink.getvalue().strip() or exc}") from None
    return float(mean_error)
