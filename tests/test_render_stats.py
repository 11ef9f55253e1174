"""`render_stats` and the sky's check directions: the fast paths give the bits of the direct
computation (same machine, same numpy), with and without NaN, Inf, negatives and masks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.image.stats import is_bad, render_stats
from sky.directions import sun_direction
from sky.emitter import hemisphere_check_directions


def _direct_stats(image, variance=None, mask=None) -> dict:
    """The statistics by masked copies, every time (what the fast path must equal)."""
    image = np.asarray(image, dtype=np.float32)
    finite = np.isfinite(image)
    values = image[finite]
    stats = {
        "min": float(values.min()) if values.size else None,
        "max": float(values.max()) if values.size else None,
        "mean": float(values.mean(dtype=np.float64)) if values.size else None,
        "nan": int(np.isnan(image).sum()),
        "inf": int(np.isinf(image).sum()),
        "negative": int((values < 0).sum()),
    }
    if variance is not None:
        var = np.clip(np.asarray(variance, dtype=np.float64), 0.0, None)
        var = var[np.isfinite(var)] if mask is None else var[mask][np.isfinite(var[mask])]
        rmse = float(np.sqrt(var.mean())) if var.size else 0.0
        stats["noise_rmse"] = rmse
        stats["noise_relative"] = rmse / stats["mean"] if (stats["mean"] or 0.0) > 0 else None
    return stats


@pytest.mark.parametrize("seed", range(40))
def test_render_stats_equal_the_direct_computation_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    h, w = (int(x) for x in rng.integers(1, 80, 2))
    image = (rng.standard_normal((h, w, 3)) * rng.uniform(0.1, 2e4)).astype(np.float32)
    if seed % 2:
        image = np.abs(image)  # the common case: every value finite and non-negative
    variance = (rng.random((h, w)) * rng.uniform(0.0, 10.0)).astype(np.float32)
    if seed % 5 == 1:
        image[rng.integers(h), rng.integers(w), 0] = np.nan
    if seed % 7 == 2:
        image[0, 0, 1], variance[0, 0] = np.inf, np.inf
    if seed % 11 == 3:
        image[:] = np.nan
    mask = rng.random((h, w)) < 0.5 if seed % 3 else None
    for args in ((image,), (image, variance), (image, variance, mask)):
        got, want = render_stats(*args), _direct_stats(*args)
        assert repr(got) == repr(want), (seed, got, want)  # repr: NaN == NaN, and every bit of each float
    assert is_bad(render_stats(image)) == bool(np.isnan(image).any() or np.isinf(image).any() or (image < 0).any())


def test_render_stats_of_a_400px_render_equal_the_direct_computation():
    rng = np.random.default_rng(400)
    image = np.abs(rng.standard_normal((400, 400, 3))).astype(np.float32) * 3.0
    variance = rng.random((400, 400)).astype(np.float32)
    mask = rng.random((400, 400)) < 0.4
    assert repr(render_stats(image, variance, mask)) == repr(_direct_stats(image, variance, mask))


def _direct_check_directions(sun_dir):
    sun_az = math.atan2(sun_dir[1], sun_dir[0])
    horizon = np.concatenate([[0.0], np.geomspace(1e-4, 0.5, 24)])
    elevations = np.concatenate([horizon, np.linspace(0.75, 90.0, 120)])
    azimuths = sun_az + np.radians(np.linspace(0.0, 180.0, 181))
    el, az = np.meshgrid(np.radians(elevations), azimuths, indexing="ij")
    dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    return np.concatenate([dirs, sun_dir[None, :]])


def test_check_directions_from_the_cached_grid_equal_the_direct_computation():
    rng = np.random.default_rng(7)
    for _ in range(50):
        sun = sun_direction(rng.uniform(-5.0, 90.0), rng.uniform(0.0, 360.0))
        got, want = hemisphere_check_directions(sun), _direct_check_directions(sun)
        assert got.shape == want.shape == (145 * 181 + 1, 3) and got.tobytes() == want.tobytes()
