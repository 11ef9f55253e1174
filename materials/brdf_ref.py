"""Numpy reference of the material model (Deschaintre et al. 2018), vectorised.

This is the model the renderer's Mitsuba plugin (:mod:`pipeline.render.bsdf`)
implements, written for clarity and float64, so the plugin can be checked
against it. With ``d``, ``s`` the diffuse and specular albedo, ``r`` the
roughness, ``n`` the normal, ``l`` = ``wo`` (towards the light) and ``v`` = ``wi``
(towards the viewer), every dot product clamped at 0::

    alpha = r^2, r clipped to [0.001, 1];  h = normalize(l + v)
    f     = d (1 - s) / pi  +  F G D / 4
    D     = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)
    F     = s + (1 - s) 2^((-5.55473 (v.h) - 6.98316) (v.h))
    G     = G1(n.l) G1(n.v),  G1(x) = 1 / (x (1 - k) + k),  k = alpha / 2

``G`` is the Smith-Schlick masking already divided by ``n.l n.v``, hence the
``/ 4`` and no ``/ (4 n.l n.v)``.

Two models share these formulas (``model=``, :data:`MODELS`):

* ``"shaderball"`` (the default): the formulas as written. D integrates to 1,
  so a white furnace keeps all the light of a mirror-like metal.
* ``"deschaintre2018"``: the two floors of Deschaintre et al.'s own code,
  ``D = alpha^2 / (pi max(0.001, (n.h)^2 (alpha^2 - 1) + 1)^2)`` and
  ``G1(x) = 1 / max(0.001, x (1 - k) + k)``. The first acts for every
  ``r < 0.001^(1/4) = 0.178`` and caps the peak of D, which then no longer
  integrates to 1 (``shaderball figures albedo-table`` measures the
  loss); the second only for ``r < 0.045`` at cosines below ~1e-3.

Forms and floors that differ from the text above (each one is an exact
rewrite, or a floor that only acts where the text has no finite value); the
plugin uses the same ones, see docs/materials.md:

* D uses ``(n.h)^2 (alpha^2 - 1) + 1 = sin^2(theta_h) + alpha^2 cos^2(theta_h)``
  with ``sin^2(theta_h) = |n x h|^2``: no cancellation, finite down to
  ``alpha = 1e-6`` (the float32 text is ~40% off at alpha 3e-4 and +inf at
  alpha <= 1.7e-4).
* ``v.h`` is clamped to [0, 1] before Schlick's term (unclamped, a negative
  cosine makes F > 1).
* ``G1`` is used in the divided form above, finite at ``n.v = 0`` because
  ``k >= 5e-7``; the eval returns ``n.l G1(n.l)`` as one factor (<= 1).
* The albedos are clamped: ``d >= 0`` and ``s`` in [0, 1], so ``1 - s`` is
  never negative.
* The BRDF is one-sided: zero unless ``n.v > 0`` and ``n.l > 0`` (Mitsuba's
  convention; the text multiplies by ``n.l`` clamped at 0, which only covers
  the light side). A normal map never shows a viewer the back of its normal:
  :func:`mapped_normal` mirrors such a normal's tangential part, as Mitsuba's
  ``normalmap`` does in the renders, and :func:`eval_normal_mapped` evaluates
  the BRDF with it.
* Degenerate geometry gives 0, never NaN: a zero-length ``n``, ``wi`` or
  ``wo``, or ``|wi + wo|^2 < 1e-20`` (``wo = -wi``, only possible with both
  directions on the horizon, where the BRDF is zero anyway).

Frames: every direction and the normal are in one frame of the caller's
choice (world or tangent space); only dot products are used. Directions need
not be unit length.
"""

from __future__ import annotations

import numpy as np

from materials.errors import MaterialError

#: The material models (see the module docstring); the first is the default.
MODELS = ("shaderball", "deschaintre2018")
DEFAULT_MODEL = MODELS[0]
#: Deschaintre et al.'s floor on the denominators of GGX D and Smith-Schlick G1.
DESCHAINTRE_FLOOR = 0.001
#: Where the GGX floor acts, D is flat-topped with the tails of GGX: shaped like GGX with
#: alpha^2 = DESCHAINTRE_FLOOR. "deschaintre2018" samples and integrates with at least this alpha.
DESCHAINTRE_SAMPLING_ALPHA_MIN = DESCHAINTRE_FLOOR**0.5
#: Roughness is clipped to this range before alpha = roughness^2.
ROUGHNESS_MIN = 0.001
ROUGHNESS_MAX = 1.0
#: Schlick-Fresnel exponent coefficients of Deschaintre et al. (spherical-Gaussian fit).
FRESNEL_C1 = -5.55473
FRESNEL_C2 = -6.98316
#: |wi + wo|^2 below this is treated as an undefined half vector (BRDF = 0).
HALF_VECTOR_MIN_SQUARED = 1e-20


def check_model(model) -> str:
    """``model`` if it is one of :data:`MODELS`; else a MaterialError naming it and the choices."""
    if not isinstance(model, str) or model not in MODELS:
        raise MaterialError(f"model: {model!r} is not allowed; allowed: {', '.join(MODELS)}")
    return model


def _floored(model) -> bool:
    return check_model(model) == "deschaintre2018"


def sampling_alpha(alpha, model=DEFAULT_MODEL):
    """The GGX alpha whose distribution of half vectors the model is sampled and integrated with.

    ``alpha`` for "shaderball"; for "deschaintre2018" at least
    :data:`DESCHAINTRE_SAMPLING_ALPHA_MIN`, because its floored D is spread over
    that lobe's width however small alpha is.
    """
    if _floored(model):
        return np.maximum(alpha, DESCHAINTRE_SAMPLING_ALPHA_MIN)
    return alpha


def alpha_from_roughness(roughness):
    """GGX alpha of the model: roughness clipped to [0.001, 1], squared."""
    r = np.clip(np.asarray(roughness, dtype=np.float64), ROUGHNESS_MIN, ROUGHNESS_MAX)
    return r * r


def fresnel(specular, cos_vh):
    """Schlick's Fresnel with the spherical-Gaussian exponent; ``cos_vh`` clamped to [0, 1]."""
    c = np.clip(cos_vh, 0.0, 1.0)
    s = np.clip(specular, 0.0, 1.0)
    return s + (1.0 - s) * np.exp2((FRESNEL_C1 * c + FRESNEL_C2) * c)


def ggx_d(sin2_h, cos2_h, alpha, model=DEFAULT_MODEL):
    """GGX distribution in the cancellation-free form (see module docstring), floored per ``model``."""
    a2 = alpha * alpha
    denom = sin2_h + a2 * cos2_h
    if _floored(model):
        denom = np.maximum(DESCHAINTRE_FLOOR, denom)
    return a2 / (np.pi * denom * denom)


def g1_divided(cos_theta, alpha, model=DEFAULT_MODEL):
    """Smith-Schlick G1 divided by the cosine: 1 / (x (1 - k) + k), k = alpha / 2, floored per ``model``."""
    k = 0.5 * alpha
    x = np.clip(cos_theta, 0.0, 1.0)
    denom = x * (1.0 - k) + k
    if _floored(model):
        denom = np.maximum(DESCHAINTRE_FLOOR, denom)
    return 1.0 / denom


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    norm2 = np.sum(v * v, axis=-1, keepdims=True)
    ok = norm2 > 0.0
    return np.where(ok, v / np.sqrt(np.where(ok, norm2, 1.0)), 0.0), ok[..., 0]


def eval_brdf(
    wi,
    wo,
    n,
    diffuse,
    specular,
    roughness,
    *,
    lobes=("diffuse", "specular"),
    normalize=True,
    model=DEFAULT_MODEL,
):
    """Cosine-weighted BRDF ``f(wi, wo) * max(0, n.wo)``: what Mitsuba's ``BSDF.eval`` returns.

    ``wi`` points towards the viewer, ``wo`` towards the light, ``n`` is the
    (shading) normal; all (..., 3) in one frame of the caller's choice, need
    not be unit. ``diffuse`` and ``specular`` are (..., 3) linear albedos,
    ``roughness`` is (...). Arguments broadcast. Returns (..., 3) float64.
    ``lobes`` selects which terms are summed (both by default); ``model`` is one
    of :data:`MODELS`.

    ``normalize=False`` uses ``wi`` and ``wo`` as given (they must then be
    unit): for comparisons with the float32 plugin, which takes Mitsuba's unit
    directions as they are. Near the peak of a sharp lobe the result is
    ill-conditioned in the directions (relative sensitivity about
    ``2 |dtheta| / alpha``), so renormalising float32 input moves it by more
    than float32 arithmetic does.
    """
    if normalize:
        wi_u, wi_ok = _unit(wi)
        wo_u, wo_ok = _unit(wo)
    else:
        wi_u, wo_u = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        wi_ok = wo_ok = np.ones(np.broadcast_shapes(wi_u.shape, wo_u.shape)[:-1], dtype=bool)
    n_u, n_ok = _unit(n)
    cos_i = np.sum(n_u * wi_u, axis=-1)
    cos_o = np.sum(n_u * wo_u, axis=-1)
    valid = wi_ok & wo_ok & n_ok & (cos_i > 0.0) & (cos_o > 0.0)

    d = np.maximum(np.asarray(diffuse, dtype=np.float64), 0.0)
    s = np.clip(np.asarray(specular, dtype=np.float64), 0.0, 1.0)
    alpha = alpha_from_roughness(roughness)

    out = 0.0
    if "diffuse" in lobes:
        out = out + d * (1.0 - s) * (np.maximum(cos_o, 0.0) / np.pi)[..., None]
    if "specular" in lobes:
        h_raw = wi_u + wo_u
        len2 = np.sum(h_raw * h_raw, axis=-1)
        h_ok = len2 > HALF_VECTOR_MIN_SQUARED
        h = h_raw / np.sqrt(np.where(h_ok, len2, 1.0))[..., None]
        cos_h = np.sum(n_u * h, axis=-1)
        sin2_h = np.sum(np.cross(n_u, h) ** 2, axis=-1)
        cos_vh = np.sum(wi_u * h, axis=-1)
        d_term = ggx_d(sin2_h, cos_h * cos_h, alpha, model)
        g_i = g1_divided(cos_i, alpha, model)
        cos_g_o = np.clip(cos_o, 0.0, 1.0) * g1_divided(cos_o, alpha, model)
        spec = (d_term * g_i * cos_g_o / 4.0)[..., None] * fresnel(s, cos_vh[..., None])
        out = out + np.where(h_ok[..., None], spec, 0.0)
    out = np.broadcast_to(out, np.broadcast_shapes(np.shape(out), valid.shape + (3,)))
    return np.where(valid[..., None], out, 0.0)


def mapped_normal(wi, normal):
    """The shading normal a tangent-space normal map gives a viewer at ``wi``: the one convention.

    ``wi`` and ``normal`` (..., 3) are in the unperturbed shading frame (its
    normal is z). Where the viewer would see the back of the mapped normal,
    ``wi.z (wi . n) <= 0``, its tangential part is mirrored, ``(x, y, z) ->
    (-x, -y, z)``, which puts it on the viewer's side whenever ``z > 0`` and
    ``wi.z > 0``; a zero-length normal reads as (0, 0, 1). This is exactly what
    Mitsuba's ``normalmap`` does with ``flip_invalid_normals`` (after Schuessler
    et al. 2017), so renders, the plugin's tests and this reference agree.
    Returns unit normals, (..., 3) float64.
    """
    wi = np.asarray(wi, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    n, wi = np.broadcast_arrays(n, wi)
    behind = wi[..., 2] * np.sum(wi * n, axis=-1) <= 0.0
    n = np.where(behind[..., None], n * np.array([-1.0, -1.0, 1.0]), n)
    unit, ok = _unit(n)
    return np.where(ok[..., None], unit, np.array([0.0, 0.0, 1.0]))


def eval_normal_mapped(wi, wo, normal, diffuse, specular, roughness, **options):
    """:func:`eval_brdf` under a tangent-space normal map, as the renders evaluate it.

    ``wi``, ``wo`` and the map's ``normal`` are in the unperturbed shading frame
    (normal z). The BRDF is evaluated with :func:`mapped_normal`, and is zero
    where ``wo`` is below the unperturbed surface (``wo.z <= 0``), as in
    Mitsuba's wrapper. ``options`` are :func:`eval_brdf`'s.
    """
    wo = np.asarray(wo, dtype=np.float64)
    value = eval_brdf(wi, wo, mapped_normal(wi, normal), diffuse, specular, roughness, **options)
    return np.where((wo[..., 2] > 0.0)[..., None], value, 0.0)


def spec_albedo_quadrature(roughness, cos_theta_i, specular, *, n_theta=768, n_phi=256, model=DEFAULT_MODEL):
    """Directional albedo of the specular term, ``int F G D / 4 cos_o dwo``, for ``n = z``.

    Deterministic quadrature in half-vector space: the midpoint rule on the
    unit square mapped to half vectors by the inverse GGX CDF of ``D cos``, so
    the integrand there is ``F G1(i) cos_o G1(o) (wi.h) / cos_h``, bounded and
    smooth except where ``wo`` crosses the horizon. Scalar arguments; the
    specular albedo ``specular`` may be a scalar or an RGB triple.
    Accurate to about 1e-3 absolute at the default grid. For "deschaintre2018"
    the half vectors are those of :func:`sampling_alpha` and the integrand is
    multiplied by the (bounded) ratio of the floored D to that GGX D.
    """
    alpha = float(alpha_from_roughness(roughness))
    alpha_q = float(sampling_alpha(alpha, model))
    a2 = alpha_q * alpha_q
    cos_i = float(np.clip(cos_theta_i, 0.0, 1.0))
    if cos_i <= 0.0:
        return np.zeros(np.shape(specular))
    sin_i = np.sqrt(max(0.0, 1.0 - cos_i * cos_i))
    wi = np.array([sin_i, 0.0, cos_i])
    u = (np.arange(n_theta) + 0.5) / n_theta
    phi = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    tan2 = a2 * u / (1.0 - u)
    cos_h = 1.0 / np.sqrt(1.0 + tan2)
    sin_h = np.sqrt(tan2) * cos_h
    h = np.stack(
        [
            sin_h[:, None] * np.cos(phi)[None, :],
            sin_h[:, None] * np.sin(phi)[None, :],
            np.broadcast_to(cos_h[:, None], (n_theta, n_phi)),
        ],
        axis=-1,
    )
    cos_ih = h @ wi
    wo_z = 2.0 * cos_ih * h[..., 2] - cos_i
    ok = (wo_z > 0.0) & (cos_ih > 0.0)
    base = g1_divided(cos_i, alpha, model) * np.clip(wo_z, 0, 1) * g1_divided(wo_z, alpha, model) * cos_ih / h[..., 2]
    if _floored(model):
        sin2_h, cos2_h = (sin_h * sin_h)[:, None], (cos_h * cos_h)[:, None]
        base = base * ggx_d(sin2_h, cos2_h, alpha, model) / ggx_d(sin2_h, cos2_h, alpha_q)
    base = np.where(ok, base, 0.0)
    spec = np.atleast_1d(np.asarray(specular, dtype=np.float64))
    result = np.array([np.mean(base * fresnel(sv, cos_ih)) for sv in spec.ravel()])
    return result.reshape(np.shape(specular))


def directional_albedo(roughness, cos_theta_i, diffuse, specular, **grid):
    """Total directional albedo ``int f cos_o dwo`` for ``n = z`` (diffuse part is exact).

    ``grid`` goes to :func:`spec_albedo_quadrature` (its ``model`` too).
    """
    d = np.maximum(np.asarray(diffuse, dtype=np.float64), 0.0)
    s = np.clip(np.asarray(specular, dtype=np.float64), 0.0, 1.0)
    if cos_theta_i <= 0.0:
        return np.zeros(np.broadcast_shapes(d.shape, s.shape))
    return d * (1.0 - s) + spec_albedo_quadrature(roughness, cos_theta_i, s, **grid)
