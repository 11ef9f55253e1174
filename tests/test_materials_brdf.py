"""The numpy reference BRDF: the formulas, the stable forms and what the textbook forms get wrong."""

import itertools

import numpy as np
import pytest
from scipy import integrate

from materials import brdf_ref
from materials.brdf_ref import eval_brdf, ggx_d, spec_albedo_quadrature
from support.material_cases import HARD_NORMALS, HARD_ROUGHNESS, hard_directions

Z = np.array([0.0, 0.0, 1.0])


def _dir(theta_deg, phi_deg=0.0):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def _textbook(wi, wo, d, s, r):
    """The issue's formulas verbatim, float64, for directions in the upper hemisphere."""
    alpha = np.clip(r, 0.001, 1.0) ** 2
    h = (wi + wo) / np.linalg.norm(wi + wo)
    nl, nv, nh, vh = wo[2], wi[2], h[2], wi @ h
    D = alpha**2 / (np.pi * (nh**2 * (alpha**2 - 1) + 1) ** 2)
    F = s + (1 - s) * 2 ** ((-5.55473 * vh - 6.98316) * vh)
    k = alpha / 2
    G = 1 / (nl * (1 - k) + k) / (nv * (1 - k) + k)
    return (d * (1 - s) / np.pi + F * G * D / 4) * nl


def test_reference_matches_textbook_formulas_where_they_are_well_conditioned():
    rng = np.random.default_rng(0)
    for _ in range(200):
        wi = _dir(rng.uniform(0, 85), rng.uniform(0, 360))
        wo = _dir(rng.uniform(0, 85), rng.uniform(0, 360))
        d, s = rng.uniform(0, 1, 3), rng.uniform(0, 1, 3)
        r = rng.uniform(0.05, 1)
        np.testing.assert_allclose(eval_brdf(wi, wo, Z, d, s, r), _textbook(wi, wo, d, s, r), rtol=1e-10)


def test_diffuse_lobe_alone_is_lambert_scaled_by_one_minus_specular():
    wi, wo = _dir(20, 10), _dir(50, 200)
    d, s = np.array([0.8, 0.5, 0.2]), np.array([0.1, 0.3, 0.9])
    value = eval_brdf(wi, wo, Z, d, s, 0.4, lobes=("diffuse",))
    np.testing.assert_allclose(value, d * (1 - s) * wo[2] / np.pi, rtol=1e-12)


@pytest.mark.parametrize("alpha", [1e-6, 1e-4, 3e-4, 0.05, 0.5, 1.0])
def test_stable_d_is_normalised(alpha):
    # int D cos(theta_h) dw_h = 1. With t = tan^2(theta_h), sin cos dtheta = cos^4 dt / 2; then
    # t = a^2 u / (1 - u) maps u in [0, 1) onto t in [0, inf) and resolves any alpha.
    a2 = alpha * alpha

    def integrand(u):
        t = a2 * u / (1 - u)
        cos2, sin2 = 1 / (1 + t), t / (1 + t)
        dt_du = a2 / (1 - u) ** 2
        return ggx_d(sin2, cos2, alpha) * np.pi * cos2**2 * dt_du

    total, _ = integrate.quad(integrand, 0.0, 1.0, limit=200, epsabs=1e-12, epsrel=1e-10)
    assert total == pytest.approx(1.0, rel=1e-6)


def test_textbook_d_fails_in_float32_where_the_stable_form_does_not():
    f32 = np.float32
    for alpha, naive_error in ((3e-4, 0.2), (1e-4, np.inf)):
        a2 = f32(alpha) * f32(alpha)
        theta_h = 0.3 * alpha  # inside the lobe
        cos_h, sin_h = f32(np.cos(theta_h)), f32(np.sin(theta_h))
        with np.errstate(divide="ignore"):
            naive = a2 / (f32(np.pi) * (cos_h * cos_h * (a2 - f32(1)) + f32(1)) ** 2)
        stable = ggx_d(sin_h * sin_h, cos_h * cos_h, a2**0.5).astype(np.float32)
        exact = ggx_d(np.sin(theta_h) ** 2, np.cos(theta_h) ** 2, alpha)
        assert abs(stable / exact - 1) < 1e-5
        error = abs(naive / exact - 1)
        assert error > naive_error if np.isfinite(naive_error) else not np.isfinite(naive)


def test_schlick_clamped_at_negative_cosine():
    # Unclamped, a negative v.h gives F > 1; clamped, F is in [s, 1].
    raw = 0.04 + 0.96 * 2 ** ((-5.55473 * -0.3 - 6.98316) * -0.3)
    assert raw > 1
    for c in (-0.3, -1e-3, 0.0, 0.5, 1.0, 1.3):
        assert 0.04 <= brdf_ref.fresnel(0.04, c) <= 1.0


def test_g_finite_at_grazing():
    for alpha in (1e-6, 0.01, 1.0):
        g = brdf_ref.g1_divided(0.0, alpha)
        assert np.isfinite(g) and g == pytest.approx(2 / alpha)


def test_reference_reciprocity():
    rng = np.random.default_rng(3)
    n = 5000
    wi = rng.normal(size=(n, 3))
    wo = rng.normal(size=(n, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    d, s, r = rng.uniform(size=(n, 3)), rng.uniform(size=(n, 3)), rng.uniform(size=n)
    forward = eval_brdf(wi, wo, Z, d, s, r) / wo[:, 2:3]
    backward = eval_brdf(wo, wi, Z, d, s, r) / wi[:, 2:3]
    np.testing.assert_allclose(forward, backward, rtol=1e-10)


def test_reference_hard_case_sweep_is_finite_and_non_negative():
    wi, wo = hard_directions()
    count = 0
    for r, s, d, n in itertools.product(HARD_ROUGHNESS, (0.0, 1.0), (0.0, 1.0), HARD_NORMALS):
        with np.errstate(all="raise"):
            try:
                value = eval_brdf(wi, wo, n, np.full(3, d), np.full(3, s), r)
            except FloatingPointError:
                # warnings are fine (masked lanes), results are what matters
                with np.errstate(all="ignore"):
                    value = eval_brdf(wi, wo, n, np.full(3, d), np.full(3, s), r)
        assert np.all(np.isfinite(value)), (r, s, d, n)
        assert np.all(value >= 0), (r, s, d, n)
        count += value.size
    assert count > 10000


def test_quadrature_albedo_known_values():
    # F = 1, smooth: GGX with height-correlated-like Schlick G loses almost nothing at normal incidence.
    assert spec_albedo_quadrature(0.05, 1.0, 1.0) == pytest.approx(1.0, abs=2e-3)
    # Diffuse part of the total is exactly d (1 - s).
    total = brdf_ref.directional_albedo(0.5, 0.7, np.array([0.6, 0.6, 0.6]), np.array([0.0, 0.5, 1.0]))
    spec = spec_albedo_quadrature(0.5, 0.7, np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(total - spec, [0.6, 0.3, 0.0], atol=1e-12)
    # Linear in s: A(s) = s A1 + (1 - s) A0.
    a0, a1, a_half = spec_albedo_quadrature(0.3, 0.2, np.array([0.0, 1.0, 0.5]))
    assert a_half == pytest.approx(0.5 * (a0 + a1), rel=1e-12)
