"""Error of a render against its sample's reference, and the reference's own error floor.

- relMSE on linear HDR: mean over pixels and channels of (x - r)^2 / (r^2 + eps),
  eps = 0.01 (:data:`pipeline.image.metrics.RELMSE_EPS`), on the ball (the G-buffer's
  mask) and on the whole frame.
- PSNR and SSIM (Gaussian 11x11, sigma 1.5) of the 8-bit sRGB pictures the network is
  trained on (:mod:`pipeline.image.tonemap`, fixed exposure); HDR-FLIP on linear HDR.
- Fireflies: relMSE on the ball without its brightest 0.1% of pixels (by the render's
  luminance); their share of the error is 1 - that / relMSE, their part of it (relMSE
  units, what the study compares between recipes) relMSE - that. On the frame the
  brightest pixels are the sky, so there a firefly is a pixel too bright for its
  reference: the 0.1% of the frame's pixels with the largest error among those brighter
  than the reference (:func:`frame_firefly_relmse`).
- Bias: the ball's mean luminance against the reference's, relative, with a z score
  from both renders' standard errors where the render has a variance.

**The floor.** The reference is a finite render too: measured relMSE is about the
render's own relMSE plus the reference's. The reference is rendered as two independent
halves; its floor is the larger of the moment integrator's estimate, mean(var_Y / (Y^2 +
eps)) over the pixels, and relMSE(half 1, half 2) / 4 (the variance of a difference of
two halves is four times that of their mean). A measured relMSE within
:data:`FLOOR_FACTOR` of the floor is below the reference's resolution: reported, never
ranked.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.image import metrics
from pipeline.image.tonemap import hdr_to_srgb8

RELMSE_EPS = metrics.RELMSE_EPS
FLOOR_FACTOR = 10.0
FIREFLY_SHARE = 0.001
#: Rec. 709 luminance weights (the renders' primaries).
LUMA = np.array([0.2126, 0.7152, 0.0722])


def luminance(image: np.ndarray) -> np.ndarray:
    return np.asarray(image, dtype=np.float64) @ LUMA


def relmse_terms(test: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Per-pixel relMSE (mean over channels), of the pixels in ``mask`` (all when None)."""
    x = np.asarray(test, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    terms = np.mean((x - r) ** 2 / (r * r + RELMSE_EPS), axis=-1)
    return terms.ravel() if mask is None else terms[np.asarray(mask, bool)]


def relmse(test, reference, mask=None) -> float:
    return float(relmse_terms(test, reference, mask).mean())


def reference_floor(
    reference: np.ndarray, variance_y: np.ndarray, half1: np.ndarray, half2: np.ndarray, mask: np.ndarray
) -> dict:
    """The reference's own relMSE, two ways, on the ball and the frame; ``floor_*`` the larger."""
    y = luminance(reference)
    moment = np.asarray(variance_y, dtype=np.float64) / (y * y + RELMSE_EPS)
    halves = relmse_terms(half1, half2) / 4.0
    out = {}
    for where, sel in (("ball", np.asarray(mask, bool).ravel()), ("frame", np.ones(moment.size, bool))):
        m = float(moment.ravel()[sel].mean())
        h = float(halves[sel].mean())
        out[f"floor_moment_{where}"] = m
        out[f"floor_halves_{where}"] = h
        out[f"floor_{where}"] = max(m, h)
    return out


def firefly_free_relmse(test: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """relMSE on the ball without its brightest :data:`FIREFLY_SHARE` of pixels (at least one)."""
    sel = np.asarray(mask, bool)
    terms = relmse_terms(test, reference, sel)
    y = luminance(test)[sel]
    drop = max(1, int(math.ceil(FIREFLY_SHARE * y.size)))
    keep = np.argsort(y, kind="stable")[: y.size - drop]
    return float(terms[keep].mean()) if keep.size else 0.0


def ball_firefly_relmse(test: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """The ball's relMSE carried by its brightest :data:`FIREFLY_SHARE` of pixels, per ball
    pixel (relMSE - the rest's sum over all ball pixels: never negative)."""
    sel = np.asarray(mask, bool)
    terms = relmse_terms(test, reference, sel)
    y = luminance(test)[sel]
    drop = max(1, int(math.ceil(FIREFLY_SHARE * y.size)))
    top = np.argsort(y, kind="stable")[y.size - drop :]
    return float(terms[top].sum() / terms.size) if terms.size else 0.0


def frame_firefly_relmse(test: np.ndarray, reference: np.ndarray) -> float:
    """The frame's relMSE carried by its :data:`FIREFLY_SHARE` of pixels (at least one) with
    the largest error among those brighter (in luminance) than the reference, per frame pixel."""
    terms = relmse_terms(test, reference)
    brighter = (luminance(test) > luminance(reference)).ravel()
    top = np.sort(terms[brighter])[::-1][: max(1, int(math.ceil(FIREFLY_SHARE * terms.size)))]
    return float(top.sum() / terms.size)


def ball_bias(
    test: np.ndarray,
    reference: np.ndarray,
    mask: np.ndarray,
    test_variance_y: np.ndarray | None,
    reference_variance_y: np.ndarray,
) -> tuple[float, float | None]:
    """(relative difference of the ball's mean luminance, its z score or None)."""
    sel = np.asarray(mask, bool)
    mt, mr = luminance(test)[sel].mean(), luminance(reference)[sel].mean()
    bias = float((mt - mr) / mr) if mr > 0 else math.nan
    if test_variance_y is None:
        return bias, None
    n = sel.sum()
    se = (
        math.sqrt(
            float(
                np.asarray(test_variance_y, np.float64)[sel].sum()
                + np.asarray(reference_variance_y, np.float64)[sel].sum()
            )
        )
        / n
    )
    return bias, float((mt - mr) / se) if se > 0 else None


def measure(
    test: np.ndarray, reference: dict, mask: np.ndarray, test_variance_y: np.ndarray | None = None, flip: bool = True
) -> dict:
    """Every metric of ``test`` against ``reference`` (a dict: image, variance, floor: reference_floor)."""
    ref = reference["image"]
    ball = relmse(test, ref, mask)
    frame = relmse(test, ref)
    free = firefly_free_relmse(test, ref, mask)
    bias, z = ball_bias(test, ref, mask, test_variance_y, reference["variance"])
    test8, ref8 = hdr_to_srgb8(test), reference.get("srgb8")
    if ref8 is None:
        ref8 = hdr_to_srgb8(ref)
    terms = relmse_terms(test, ref, mask)
    return {
        "relmse_ball": ball,
        "relmse_ball_se": float(terms.std() / math.sqrt(terms.size)) if terms.size > 1 else 0.0,
        "relmse_frame": frame,
        "relmse_ball_no_fireflies": free,
        "firefly_share": float(1.0 - free / ball) if ball > 0 else 0.0,
        "firefly_relmse_ball": ball_firefly_relmse(test, ref, mask),
        "firefly_relmse_frame": frame_firefly_relmse(test, ref),
        "psnr": metrics.psnr8(test8, ref8),
        "ssim": metrics.ssim8(test8, ref8),
        "flip": metrics.hdr_flip(test, ref) if flip else None,
        "bias_ball": bias,
        "bias_z": z,
        "below_resolution": bool(ball < FLOOR_FACTOR * reference["floor"]["floor_ball"]),
    }
