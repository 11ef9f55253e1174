"""Sampling distributions: chi-square tests against the documented densities (no Mitsuba)."""

import math

import numpy as np
import pytest
from scipy import stats

from sky import Light, LightingRanges, direction_pdf, sample_lights

FULL = dict(elevation_deg=(0.0, 90.0), azimuth_deg=(0.0, 360.0), turbidity=(1.0, 10.0))
BAND = dict(elevation_deg=(10.0, 60.0), azimuth_deg=(-30.0, 120.0), turbidity=(2.0, 6.0))


def _arrays(lights):
    el = np.array([l.elevation_deg for l in lights])
    az = np.array([l.azimuth_deg for l in lights])
    t = np.array([l.turbidity for l in lights])
    return el, az, t


def _bin_probabilities(ranges, el_edges, az_edges, sub=400):
    """Integrate the claimed density direction_pdf over (elevation, azimuth) bins (solid angle)."""
    probs = np.zeros((len(el_edges) - 1, len(az_edges) - 1))
    for i in range(len(el_edges) - 1):
        el = el_edges[i] + (np.arange(sub) + 0.5) / sub * (el_edges[i + 1] - el_edges[i])
        d_el = math.radians(el_edges[i + 1] - el_edges[i]) / sub
        for j in range(len(az_edges) - 1):
            az_mid = 0.5 * (az_edges[j] + az_edges[j + 1])
            d_az = math.radians(az_edges[j + 1] - az_edges[j])
            pdf = direction_pdf(el, np.full_like(el, az_mid), ranges)
            probs[i, j] = np.sum(pdf * np.cos(np.radians(el))) * d_el * d_az
    return probs


def _z_edges(ranges, k):
    """k elevation bins equally spaced in z = sin(elevation) over the band."""
    lo, hi = (math.sin(math.radians(e)) for e in ranges.elevation_deg)
    return np.degrees(np.arcsin(np.linspace(lo, hi, k + 1)))


def _chi2_pvalue(lights, ranges, claimed=None, n_el=10, n_az=12):
    claimed = claimed or ranges
    el, az, _ = _arrays(lights)
    el_edges = _z_edges(ranges, n_el)
    az_edges = np.linspace(*ranges.azimuth_deg, n_az + 1)
    counts, _, _ = np.histogram2d(el, az, bins=[el_edges, az_edges])
    probs = _bin_probabilities(claimed, el_edges, az_edges)
    assert probs.sum() == pytest.approx(1.0, abs=1e-4)
    expected = probs.ravel() * len(lights)
    return stats.chisquare(counts.ravel(), expected * counts.sum() / expected.sum()).pvalue


@pytest.mark.parametrize("band", [FULL, BAND], ids=["hemisphere", "band"])
@pytest.mark.parametrize("scheme", ["uniform_hemisphere", "uniform_angles", "stratified", "sobol"])
def test_chi_square_matches_claimed_density(scheme, band):
    ranges = LightingRanges(**band, scheme=scheme)
    lights = sample_lights(np.random.default_rng(12345), 20000, ranges)
    assert _chi2_pvalue(lights, ranges) > 1e-3


def test_chi_square_has_power_against_the_other_density():
    """uniform_angles samples must fail the uniform-solid-angle test (the test can fail)."""
    angles = LightingRanges(**FULL, scheme="uniform_angles")
    hemi = LightingRanges(**FULL, scheme="uniform_hemisphere")
    lights = sample_lights(np.random.default_rng(7), 20000, angles)
    assert _chi2_pvalue(lights, hemi, claimed=hemi) < 1e-6


def test_uniform_hemisphere_is_uniform_in_z_and_azimuth_marginals():
    ranges = LightingRanges(**FULL)
    el, az, t = _arrays(sample_lights(np.random.default_rng(3), 20000, ranges))
    z = np.sin(np.radians(el))
    assert stats.kstest(z, "uniform").pvalue > 1e-3
    assert stats.kstest(az / 360.0, "uniform").pvalue > 1e-3
    assert stats.kstest((t - 1.0) / 9.0, "uniform").pvalue > 1e-3
    # the paper's hemisphere: mean elevation is 32.7 deg (1 rad - ...), not 45 as for uniform angles
    assert np.degrees(np.mean(np.arcsin(z))) == pytest.approx(math.degrees(math.pi / 2 - 1), abs=0.5)


@pytest.mark.parametrize("scheme", ["stratified", "sobol"])
def test_low_discrepancy_schemes_fill_every_stratum(scheme):
    n = 64
    ranges = LightingRanges(**BAND, scheme=scheme)
    el, az, t = _arrays(sample_lights(np.random.default_rng(5), n, ranges))
    z = np.sin(np.radians(el))
    z_lo, z_hi = (math.sin(math.radians(e)) for e in BAND["elevation_deg"])
    for values, lo, hi in ((z, z_lo, z_hi), (az, *BAND["azimuth_deg"]), (t, *BAND["turbidity"])):
        counts, _ = np.histogram(values, bins=np.linspace(lo, hi, n + 1))
        assert np.all(counts == 1), counts
    # independent draws almost never do that
    el, _, _ = _arrays(sample_lights(np.random.default_rng(5), n, LightingRanges(**BAND)))
    counts, _ = np.histogram(np.sin(np.radians(el)), bins=np.linspace(z_lo, z_hi, n + 1))
    assert not np.all(counts == 1)


@pytest.mark.parametrize("scheme", ["uniform_hemisphere", "uniform_angles", "stratified", "sobol"])
def test_deterministic_given_the_generator_and_in_range(scheme):
    ranges = LightingRanges(**BAND, scheme=scheme)
    a = sample_lights(np.random.default_rng(99), 50, ranges)
    b = sample_lights(np.random.default_rng(99), 50, ranges)
    c = sample_lights(np.random.default_rng(100), 50, ranges)
    assert a == b and a != c
    assert all(isinstance(light, Light) for light in a)
    el, az, t = _arrays(a)
    assert el.min() >= 10.0 and el.max() <= 60.0
    assert az.min() >= -30.0 and az.max() <= 120.0
    assert t.min() >= 2.0 and t.max() <= 6.0


def test_sobol_with_non_power_of_two_n_is_a_prefix():
    ranges = LightingRanges(**FULL, scheme="sobol")
    assert len(sample_lights(np.random.default_rng(0), 5, ranges)) == 5
    assert sample_lights(np.random.default_rng(0), 0, ranges) == []


def test_rng_must_be_an_explicit_generator():
    with pytest.raises(TypeError, match="Generator"):
        sample_lights(np.random.RandomState(0), 3, LightingRanges())
    with pytest.raises(TypeError):
        sample_lights(None, 3, LightingRanges())


def test_degenerate_ranges_give_fixed_values():
    ranges = LightingRanges(elevation_deg=(30.0, 30.0), azimuth_deg=(45.0, 45.0), turbidity=(3.0, 3.0))
    for light in sample_lights(np.random.default_rng(1), 10, ranges):
        assert light == Light(30.0, 45.0, 3.0)
