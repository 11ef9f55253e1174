"""Comparing two renders within their noise, from the ``moment`` integrator's variance.

Shared by the effects benchmark (:mod:`pipeline.bench.effects`) and the render tests:
two images agree when few pixels differ by more than :data:`Z_LIMIT` standard errors
of their difference and the summed difference is within :data:`Z_TOTAL_LIMIT`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from pipeline.errors import ShaderballError
from pipeline.render.renderer import render_whole

#: Z above which a pixel's difference counts as beyond noise (two-sided p ~ 6e-5 if normal).
Z_LIMIT = 4.0
#: Two renders agree within noise when at most this share of pixels exceeds Z_LIMIT ...
Z_FAIL_SHARE = 0.01
#: ... and the summed difference over the image is within this many standard errors.
Z_TOTAL_LIMIT = 5.0
#: Relative max difference below which two renders are "equal to float32 rounding".
ROUNDING_REL = 1e-5


@dataclass(frozen=True)
class MomentRender:
    """A render of the ``moment`` integrator: the RGB image and the variance of its luminance.

    The ``moment`` integrator's extra channels are CIE XYZ (``nested.X/Y/Z`` and
    ``m2_nested.X/Y/Z``), not RGB, and it keeps no cross moments, so the variance of each
    RGB channel can't be recovered; the luminance Y is the sRGB image's
    0.2126 R + 0.7152 G + 0.0722 B, and its variance is exact.
    """

    image: np.ndarray  # (H, W, 3) float32 linear RGB
    luminance: np.ndarray  # (H, W) float64, Y of the estimate
    luminance_variance: np.ndarray  # (H, W) float64, variance of the pixel estimate of Y
    seconds: float  # wall time of the render call, numpy conversion included
    cpu_seconds: float  # CPU time of this process (all render threads) over the same call


def render_moments(mi, scene, spp: int, seed: int) -> MomentRender:
    """Render a scene whose integrator is ``moment`` and split its channels."""
    names = list(scene.integrator().aov_names())
    if "nested.Y" not in names or "m2_nested.Y" not in names:
        raise ShaderballError(f"scene integrator: AOVs {names} are not the moment integrator's")
    start, cpu_start = time.perf_counter(), time.process_time()
    out = np.asarray(render_whole(mi, scene, spp, seed), dtype=np.float32)  # split over the launch limit
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    m1 = out[..., 3 + names.index("nested.Y")].astype(np.float64)
    m2 = out[..., 3 + names.index("m2_nested.Y")].astype(np.float64)
    variance = np.clip(m2 - m1 * m1, 0.0, None) / spp
    return MomentRender(np.ascontiguousarray(out[..., 0:3]), m1, variance, seconds, cpu_seconds)


def compare_renders(a: MomentRender, b: MomentRender) -> dict:
    """How two renders of (supposedly) the same image differ.

    ``identical``: bit for bit. ``rounding``: max |a - b| <= ROUNDING_REL x max |a|.
    ``z_share``: share of pixels whose luminance difference exceeds Z_LIMIT standard
    errors (sqrt(var_a + var_b)); ``z_total``: the summed luminance difference over the
    image in standard errors of the sum. ``within_noise``: z_share <= Z_FAIL_SHARE and
    |z_total| <= Z_TOTAL_LIMIT (two renders with different seeds pass; see
    tests/test_effects.py, which checks that calibration).
    """
    diff = a.image.astype(np.float64) - b.image.astype(np.float64)
    max_abs = float(np.abs(diff).max()) if diff.size else 0.0
    scale = float(np.abs(a.image).max()) if a.image.size else 0.0
    dy = a.luminance - b.luminance
    var = a.luminance_variance + b.luminance_variance
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(var > 0, dy / np.sqrt(np.where(var > 0, var, 1.0)), np.where(dy == 0, 0.0, np.inf))
    total_var = float(var.sum())
    z_total = float(dy.sum() / math.sqrt(total_var)) if total_var > 0 else (0.0 if not dy.any() else math.inf)
    z_share = float(np.mean(np.abs(z) > Z_LIMIT))
    return {
        "identical": bool(np.array_equal(a.image, b.image)),
        "max_abs": max_abs,
        "max_rel": max_abs / scale if scale > 0 else (0.0 if max_abs == 0 else math.inf),
        "rounding": max_abs <= ROUNDING_REL * scale,
        "z_share": z_share,
        "z_total": z_total,
        "within_noise": z_share <= Z_FAIL_SHARE and abs(z_total) <= Z_TOTAL_LIMIT,
    }


def describe_comparison(c: dict) -> str:
    if c["identical"]:
        return "bit-identical"
    if c["rounding"]:
        return f"equal to rounding (max |diff| {c['max_abs']:.2g}, {c['max_rel']:.2g} of max)"
    verdict = "within noise" if c["within_noise"] else "DIFFERENT beyond noise"
    return (
        f"{verdict}: {100 * c['z_share']:.2f}% of pixels |z| > {Z_LIMIT:g}, "
        f"summed z {c['z_total']:+.1f}, max |diff| {c['max_abs']:.2g}"
    )
