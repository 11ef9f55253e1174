"""Render statistics recorded with every render (EXR header, manifest)."""

from __future__ import annotations

import numpy as np


def render_stats(image: np.ndarray, variance: np.ndarray | None = None, mask: np.ndarray | None = None) -> dict:
    """Counts of NaN, Inf and negative values, the finite min/max, and a noise estimate.

    ``variance`` is the per-pixel variance of the pixel estimate (the moment integrator's
    (m2 - m1^2) / spp). The noise estimate is the root-mean-square standard error over the
    pixels (over ``mask`` where given) — the expected RMSE of the image against its
    infinite-spp limit — and the same relative to the mean pixel value.
    """
    image = np.asarray(image, dtype=np.float32)
    # The common case (every value finite) skips the masked copies: the same elements in the
    # same order, so the same sums and the same bits as the general path.
    finite = np.isfinite(image)
    all_finite = bool(finite.all())
    values = image.reshape(-1) if all_finite else image[finite]
    lowest = values.min() if values.size else None
    stats = {
        "min": float(lowest) if values.size else None,
        "max": float(values.max()) if values.size else None,
        "mean": float(values.mean(dtype=np.float64)) if values.size else None,
        "nan": 0 if all_finite else int(np.isnan(image).sum()),
        "inf": 0 if all_finite else int(np.isinf(image).sum()),
        "negative": int(np.count_nonzero(values < 0)) if values.size and lowest < 0 else 0,
    }
    if variance is not None:
        var = np.clip(np.asarray(variance, dtype=np.float64), 0.0, None)
        if mask is not None:
            var = var[np.asarray(mask, bool)]
        var = var.reshape(-1)
        finite_var = np.isfinite(var)
        if not finite_var.all():
            var = var[finite_var]
        rmse = float(np.sqrt(var.mean())) if var.size else 0.0
        mean = stats["mean"] or 0.0
        stats["noise_rmse"] = rmse
        stats["noise_relative"] = rmse / mean if mean > 0 else None
    return stats


def is_bad(stats: dict) -> bool:
    """A render is bad when any value is NaN, infinite or negative."""
    return bool(stats["nan"] or stats["inf"] or stats["negative"])
