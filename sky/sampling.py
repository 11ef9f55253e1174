"""Sampling sun directions and turbidities from a spec's ranges.

Every scheme maps points u in the unit cube [0, 1)^3 to lights the same way
(:func:`lights_from_unit_cube`), except ``uniform_angles`` which maps u_0 to the
elevation linearly. The schemes differ in how u is drawn: independently
(``uniform_*``), Latin-hypercube stratified, or from a scrambled Sobol' sequence.
All randomness comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from sky.lighting import Light, LightingRanges
from sky.portable import asin_deg, sin_deg


def sample_lights(rng: np.random.Generator, n: int, ranges: LightingRanges) -> list[Light]:
    """Draw ``n`` lights from ``ranges`` using ``ranges.scheme``; deterministic given ``rng``."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    u = unit_points(rng, n, ranges.scheme)
    return lights_from_unit_cube(u, ranges)


def unit_points(rng: np.random.Generator, n: int, scheme: str) -> np.ndarray:
    """(n, 3) points in [0, 1)^3 for ``scheme``."""
    if n == 0:
        return np.zeros((0, 3))
    if scheme in ("uniform_hemisphere", "uniform_angles"):
        return rng.random((n, 3))
    if scheme == "stratified":
        return latin_hypercube(rng, n, 3)
    if scheme == "sobol":
        return sobol_points(rng, n, 3)
    raise ValueError(f"unknown scheme {scheme!r}")


def latin_hypercube(rng: np.random.Generator, n: int, dims: int) -> np.ndarray:
    """One point in each of the n strata of every axis, jittered, axes paired at random."""
    strata = np.stack([rng.permutation(n) for _ in range(dims)], axis=1)
    return (strata + rng.random((n, dims))) / n


def sobol_points(rng: np.random.Generator, n: int, dims: int) -> np.ndarray:
    """The first n points of an Owen-scrambled Sobol' sequence seeded from ``rng``."""
    from scipy.stats import qmc

    sampler = qmc.Sobol(d=dims, scramble=True, seed=rng)
    m = max(0, math.ceil(math.log2(n)))
    with warnings.catch_warnings():
        # A prefix of a power-of-two block is still low-discrepancy; scipy warns anyway.
        warnings.simplefilter("ignore", UserWarning)
        points = sampler.random_base2(m)
    return points[:n]


def lights_from_unit_cube(u: np.ndarray, ranges: LightingRanges) -> list[Light]:
    """Map (n, 3) unit-cube points to lights for ``ranges`` (see module doc)."""
    el_lo, el_hi = ranges.elevation_deg
    az_lo, az_hi = ranges.azimuth_deg
    t_lo, t_hi = ranges.turbidity
    if ranges.scheme == "uniform_angles":
        elevation = el_lo + u[:, 0] * (el_hi - el_lo)
    else:
        # sin and arcsin with the same bits on every machine (sky.portable): a plan's
        # elevations must not depend on the CPU's SIMD kernels.
        z_lo, z_hi = sin_deg(float(el_lo)), sin_deg(float(el_hi))
        z = z_lo + u[:, 0] * (z_hi - z_lo)
        elevation = asin_deg(np.clip(z, -1.0, 1.0))
        # arcsin(sin(x)) can round a hair outside [lo, hi]; the range is a contract.
        elevation = np.clip(elevation, el_lo, el_hi)
    azimuth = az_lo + u[:, 1] * (az_hi - az_lo)
    turbidity = np.clip(t_lo + u[:, 2] * (t_hi - t_lo), t_lo, t_hi)
    return [
        Light(elevation_deg=float(e), azimuth_deg=float(a), turbidity=float(t))
        for e, a, t in zip(elevation, azimuth, turbidity)
    ]


def direction_pdf(elevation_deg, azimuth_deg, ranges: LightingRanges):
    """Density of the sun direction per steradian at (elevation, azimuth) under ``ranges``.

    ``uniform_hemisphere``, ``stratified`` and ``sobol`` share the density
    1 / (dphi (sin el_hi - sin el_lo)); ``uniform_angles`` has
    1 / (dphi del cos el). Zero outside the band.
    """
    el = np.asarray(elevation_deg, dtype=np.float64)
    az = np.asarray(azimuth_deg, dtype=np.float64)
    el_lo, el_hi = ranges.elevation_deg
    az_lo, az_hi = ranges.azimuth_deg
    inside = (el >= el_lo) & (el <= el_hi) & (az >= az_lo) & (az <= az_hi)
    d_phi = math.radians(az_hi - az_lo)
    if ranges.scheme == "uniform_angles":
        d_el = math.radians(el_hi - el_lo)
        with np.errstate(divide="ignore"):
            pdf = 1.0 / (d_phi * d_el * np.cos(np.radians(el)))
    else:
        pdf = np.full(el.shape, 1.0 / (d_phi * (math.sin(math.radians(el_hi)) - math.sin(math.radians(el_lo)))))
    return np.where(inside, pdf, 0.0)
