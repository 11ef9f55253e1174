"""Hard-case inputs for checking an implementation of the model (used by the tests).

Directions are in the local frame (n = z) unless a normal is given.
"""

from __future__ import annotations

import itertools

import numpy as np

Z = np.array([0.0, 0.0, 1.0])
#: Roughness values r (alpha = r^2 after clipping r to [0.001, 1]).
HARD_ROUGHNESS = (0.0, 1e-6, 1e-4, 3e-4, 1e-3, 0.01, 1.0)
HARD_COSINES = (1.0, 1e-2, 1e-6, 0.0, -1e-3)


def hard_directions() -> tuple[np.ndarray, np.ndarray]:
    """Pairs (wi, wo) with the hard cosines, mirror, v.h -> 0 and zero-length cases; n = z."""

    def at(cos, phi):
        sin = np.sqrt(max(0.0, 1 - cos * cos))
        return np.array([sin * np.cos(phi), sin * np.sin(phi), cos])

    pairs = []
    for ci, co in itertools.product(HARD_COSINES, HARD_COSINES):
        for dphi in (0.0, np.pi / 2, np.pi, np.pi - 1e-7):
            pairs.append((at(ci, 0.0), at(co, dphi)))
    for c in (1.0, 0.5, 1e-2, 1e-6, 0.0):
        wi = at(c, 0.3)
        pairs.append((wi, np.array([-wi[0], -wi[1], wi[2]])))  # mirror
        pairs.append((wi, -wi + np.array([0, 1e-7, 2e-7])))  # v.h -> 0
    pairs.append((np.zeros(3), Z))
    pairs.append((Z, np.zeros(3)))
    wi, wo = np.array(pairs).transpose(1, 0, 2)
    return wi, wo


#: Shading normals: flat, tangent to the surface, facing away, zero length, not unit length.
HARD_NORMALS = np.array(
    [
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],  # tangent to the surface
        [0.0, 0.0, -1.0],  # facing away
        [0.6, 0.0, -0.8],
        [0.0, 0.0, 0.0],  # zero length
        [0.3, 0.0, 0.4],  # not normalised
        [3.0, 0.0, 4.0],
    ]
)


def deschaintre_code_brdf(view, light, normal, diffuse, specular, roughness):
    """Deschaintre et al. 2018's rendering code transcribed to numpy, float64: ``f cos`` per RGB.

    From ``material_net.py`` of valentin-deschaintre/Single-Image-SVBRDF-Capture-rendering-loss
    (``render``, ``render_D_GGX_Substance``, ``render_G_GGX_Substance``, ``G1_Substance``,
    ``render_F_GGX_Substance``, ``render_diffuse_Substance``), without the lamp's intensity
    and distance factors. Their ``wi`` is the light, their ``wo`` the viewer; every dot
    product is clamped at 0 (``relu``) and nothing else is: a viewer below the normal
    gets ``G1(0) = 1 / max(0.001, k)``, not 0. Arrays (..., 3) broadcast; roughness (...).
    """

    def unit(v):
        v = np.asarray(v, dtype=np.float64)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def dot(a, b):
        return np.sum(a * b, axis=-1, keepdims=True)

    wi, wo, n = unit(light), unit(view), unit(normal)
    h = unit((wi + wo) / 2.0)
    diffuse = np.clip(np.asarray(diffuse, dtype=np.float64), 0.0, 1.0)
    specular = np.clip(np.asarray(specular, dtype=np.float64), 0.0, 1.0)
    roughness = np.maximum(np.clip(np.asarray(roughness, dtype=np.float64), 0.0, 1.0), 0.001)[..., None]
    n_dot_h = np.maximum(dot(n, h), 0.0)
    n_dot_l = np.maximum(dot(n, wi), 0.0)
    n_dot_v = np.maximum(dot(n, wo), 0.0)
    v_dot_h = np.maximum(dot(wo, h), 0.0)

    alpha = roughness**2
    under_d = 1.0 / np.maximum(0.001, n_dot_h**2 * (alpha**2 - 1.0) + 1.0)
    d_term = (alpha * under_d) ** 2 / np.pi
    k = alpha / 2.0

    def g1(n_dot_w):
        return 1.0 / np.maximum(n_dot_w * (1.0 - k) + k, 0.001)

    g_term = g1(n_dot_l) * g1(n_dot_v)
    f_term = specular + (1.0 - specular) * 2.0 ** ((-5.55473 * v_dot_h - 6.98316) * v_dot_h)
    result = f_term * (g_term * d_term * 0.25) + diffuse * (1.0 - specular) / np.pi
    return result * n_dot_l


def floor_cases(rng, count: int):
    """(wi, wo, roughness) in n = z where Deschaintre et al.'s floors act, plus a label per case.

    Half are near-mirror pairs (the half vector within a few lobe widths of n) with
    r < 0.178, where their GGX floor caps D; half have r < 0.045 and a cosine below
    1e-3, where their Smith floor acts. Both directions are above the surface.
    """
    half = count // 2

    def at(theta, phi):
        return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)

    r_ggx = rng.uniform(0.001, 0.177, half)
    theta_h = rng.uniform(0.0, 3.0, half) * np.maximum(r_ggx**2, 0.002)
    h = at(theta_h, rng.uniform(0, 2 * np.pi, half))
    wi_ggx = at(rng.uniform(0.0, 1.3, half), rng.uniform(0, 2 * np.pi, half))
    wo_ggx = 2.0 * np.sum(wi_ggx * h, axis=-1, keepdims=True) * h - wi_ggx

    rest = count - half
    r_smith = rng.uniform(0.0, 0.044, rest)
    grazing = at(np.arccos(rng.uniform(1e-6, 1e-3, rest)), rng.uniform(0, 2 * np.pi, rest))
    other = at(rng.uniform(0.0, 1.5, rest), rng.uniform(0, 2 * np.pi, rest))
    swap = rng.uniform(size=rest) < 0.5
    wi_smith = np.where(swap[:, None], grazing, other)
    wo_smith = np.where(swap[:, None], other, grazing)

    wi = np.concatenate([wi_ggx, wi_smith])
    wo = np.concatenate([wo_ggx, wo_smith])
    keep = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    labels = np.array(["ggx"] * half + ["smith"] * rest)
    return wi[keep], wo[keep], np.concatenate([r_ggx, r_smith])[keep], labels[keep]


def bsdf_chi2(vector3f, d: float, s: float, r: float, model: str, theta_deg: float, *, ires: int, seed: int):
    """Mitsuba's chi-square test of ``shaderball_ct``'s sampled directions against its pdf: a grey
    material (diffuse ``d``, specular ``s``, roughness ``r``) lit at ``theta_deg`` from the
    normal; ``vector3f`` is the variant's ``mi.Vector3f``. ``ires``: the pdf's integration
    resolution per cell."""
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    params = {
        "type": "shaderball_ct",
        "diffuse": {"type": "rgb", "value": [d] * 3},
        "specular": {"type": "rgb", "value": [s] * 3},
        "roughness": r,
        "model": model,
    }
    t = np.radians(theta_deg)
    sample, pdf = BSDFAdapter("shaderball_ct", params, wi=vector3f(float(np.sin(t)), 0.0, float(np.cos(t))))
    return ChiSquareTest(
        domain=SphericalDomain(),
        sample_func=sample,
        pdf_func=pdf,
        sample_dim=3,
        sample_count=1_000_000,
        res=101,
        ires=ires,
        seed=seed,
    )
