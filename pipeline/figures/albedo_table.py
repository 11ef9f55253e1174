"""Directional albedo of the model: ``shaderball figures albedo-table`` prints the docs' tables.

The directional albedo ``a(wi) = int f(wi, wo) cos(theta_o) dwo`` (the white
furnace value) is computed with the numpy reference by deterministic
quadrature (:func:`materials.brdf_ref.spec_albedo_quadrature`). Schlick's
term is linear in ``s`` per channel, ``F = s + (1 - s) E(v.h)``, so

    a = d (1 - s) + s A1(r, theta) + (1 - s) A0(r, theta)

with ``A1`` the specular albedo at F = 1 and ``A0`` the one at s = 0 (F = E).
Two numbers per (roughness, incidence) describe every material; the tables
print them, the total for the brightest materials, and how often the
samplers' materials exceed 1. Then the same for the "deschaintre2018" model
(:data:`materials.brdf_ref.MODELS`), whose floors lose light below roughness
0.001^(1/4) = 0.178: the two models side by side at normal incidence, and the
share of the samplers' materials (texels) where that floor acts.
``--models`` prints only the comparison of the models.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from materials.brdf_ref import DEFAULT_MODEL, DESCHAINTRE_FLOOR, MODELS, spec_albedo_quadrature
from materials.svbrdf import SVBRDF_FAMILIES, sample_svbrdf
from materials.uniform import UniformRanges, sample_uniform

ROUGHNESS = (0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0)
INCIDENCE_DEG = (0.0, 30.0, 60.0, 70.0, 75.0, 80.0, 85.0, 89.0)
#: Deschaintre et al.'s GGX floor acts for every roughness below this: alpha^2 < 0.001.
FLOOR_ROUGHNESS = DESCHAINTRE_FLOOR**0.25
#: Rows of the side-by-side table of the models (normal incidence).
MODEL_ROUGHNESS = (0.01, 0.03, 0.05, 0.075, 0.1, 0.125, 0.15, 0.17, FLOOR_ROUGHNESS, 0.2, 0.3)


@dataclass(frozen=True)
class AlbedoLUT:
    """A0 and A1 on a (roughness, incidence) grid, interpolated linearly in roughness."""

    roughness: np.ndarray  # (R,)
    incidence_deg: np.ndarray  # (T,)
    a0: np.ndarray  # (R, T) specular albedo with s = 0
    a1: np.ndarray  # (R, T) specular albedo with F = 1

    def lookup(self, roughness, theta_index: int) -> tuple[np.ndarray, np.ndarray]:
        r = np.asarray(roughness, dtype=np.float64)
        a0 = np.interp(r, self.roughness, self.a0[:, theta_index])
        a1 = np.interp(r, self.roughness, self.a1[:, theta_index])
        return a0, a1

    def total(self, diffuse, specular, roughness, theta_index: int) -> np.ndarray:
        """Per-channel total albedo of materials (arrays broadcast; roughness without channel axis)."""
        d = np.maximum(np.asarray(diffuse, dtype=np.float64), 0.0)
        s = np.clip(np.asarray(specular, dtype=np.float64), 0.0, 1.0)
        a0, a1 = self.lookup(roughness, theta_index)
        return d * (1.0 - s) + s * a1[..., None] + (1.0 - s) * a0[..., None]


def build_lut(
    roughness=None, incidence_deg=INCIDENCE_DEG, *, n_theta=512, n_phi=128, model: str = DEFAULT_MODEL
) -> AlbedoLUT:
    """Tabulate A0 and A1 of ``model`` (default roughness grid: 0.02 to 1 in 0.02 steps plus the table's values)."""
    if roughness is None:
        roughness = np.unique(np.concatenate([np.arange(0.02, 1.0001, 0.02), ROUGHNESS]))
    roughness = np.asarray(roughness, dtype=np.float64)
    a0 = np.zeros((len(roughness), len(incidence_deg)))
    a1 = np.zeros_like(a0)
    for i, r in enumerate(roughness):
        for t, theta in enumerate(incidence_deg):
            a0[i, t], a1[i, t] = spec_albedo_quadrature(
                r,
                np.cos(np.radians(theta)),
                np.array([0.0, 1.0]),
                n_theta=n_theta,
                n_phi=n_phi,
                model=model,
            )
    return AlbedoLUT(roughness, np.asarray(incidence_deg, dtype=np.float64), a0, a1)


def _table(title: str, values: np.ndarray, lut: AlbedoLUT, rows=ROUGHNESS, fmt="{:.3f}") -> str:
    head = "| r \\ theta_i | " + " | ".join(f"{t:g} deg" for t in lut.incidence_deg) + " |"
    rule = "|---|" + "---|" * len(lut.incidence_deg)
    lines = [f"**{title}**", "", head, rule]
    for r, row in zip(rows, values):
        lines.append(f"| {r:g} | " + " | ".join(fmt.format(v) for v in row) + " |")
    return "\n".join(lines)


def _rows(lut: AlbedoLUT, array: np.ndarray) -> np.ndarray:
    index = [int(np.argmin(np.abs(lut.roughness - r))) for r in ROUGHNESS]
    return array[index]


def sampler_exceedance(
    lut: AlbedoLUT, *, uniform_count: int = 4000, svbrdf_per_family: int = 3, svbrdf_resolution: int = 64, seed: int = 7
) -> dict[str, np.ndarray]:
    """Per incidence: fraction of materials (texels) whose total albedo exceeds 1 in any channel, and the max."""

    rng = np.random.default_rng(seed)
    mats = [sample_uniform(rng) for _ in range(uniform_count)]
    d = np.array([m.diffuse for m in mats])
    s = np.array([m.specular for m in mats])
    r = np.array([m.roughness for m in mats])
    result = {}
    for name, (dd, ss, rr) in {
        "uniform": (d, s, r),
        **{
            f"svbrdf:{family}": _texels(
                [sample_svbrdf(rng, family, svbrdf_resolution) for _ in range(svbrdf_per_family)]
            )
            for family in SVBRDF_FAMILIES
        },
    }.items():
        totals = np.stack([lut.total(dd, ss, rr, t).max(axis=-1) for t in range(len(lut.incidence_deg))])
        result[name] = np.stack([(totals > 1.0).mean(axis=1), totals.max(axis=1)])
    return result


def _texels(maps_list):
    d = np.concatenate([m.diffuse.reshape(-1, 3) for m in maps_list])
    s = np.concatenate([m.specular.reshape(-1, 3) for m in maps_list])
    r = np.concatenate([m.roughness.reshape(-1) for m in maps_list])
    return d, s, r


def model_comparison(roughness=MODEL_ROUGHNESS, *, n_theta=512, n_phi=128) -> dict[str, np.ndarray]:
    """A1 at normal incidence (specular albedo with F = 1, the white furnace of a mirror-like metal) per model."""
    return {model: build_lut(roughness, (0.0,), n_theta=n_theta, n_phi=n_phi, model=model).a1[:, 0] for model in MODELS}


def floor_share(*, svbrdf_per_family: int = 100, svbrdf_resolution: int = 32, seed: int = 7) -> dict[str, float]:
    """Share of the samplers' materials (uniform) or texels (SVBRDF) with r < FLOOR_ROUGHNESS.

    Uniform: exact, the sampler draws r uniformly in ``UniformRanges().roughness``.
    SVBRDF: estimated over ``svbrdf_per_family`` materials per family.
    """
    lo, hi = UniformRanges().roughness
    shares = {"uniform": float(np.clip((FLOOR_ROUGHNESS - lo) / (hi - lo), 0.0, 1.0))}
    rng = np.random.default_rng(seed)
    for family in SVBRDF_FAMILIES:
        _, _, r = _texels([sample_svbrdf(rng, family, svbrdf_resolution) for _ in range(svbrdf_per_family)])
        shares[f"svbrdf:{family}"] = float(np.mean(r < FLOOR_ROUGHNESS))
    return shares


def models_markdown() -> str:
    """The comparison of the material models: A1 at normal incidence, and where the GGX floor acts."""
    a1 = model_comparison()
    lines = [
        "**Models: A1 at normal incidence (specular albedo with F = 1, s = 1, d = 0), and the share "
        "the floored model loses**",
        "",
        "| r | " + " | ".join(MODELS) + " | lost |",
        "|---|" + "---|" * (len(MODELS) + 1),
    ]
    for i, r in enumerate(MODEL_ROUGHNESS):
        base, floored = a1[DEFAULT_MODEL][i], a1["deschaintre2018"][i]
        lines.append(
            f"| {r:.4g} | "
            + " | ".join(f"{a1[m][i]:.3f}" for m in MODELS)
            + f" | {round(100 * (1 - floored / base), 1) + 0.0:.1f}% |"
        )  # + 0.0: no "-0.0"
    shares = floor_share()
    lines += [
        "",
        f"**Where the GGX floor acts (r < {FLOOR_ROUGHNESS:.4f}): share of the samplers' materials "
        "(uniform with the default ranges, exact) or texels (SVBRDF, 100 materials of 32 x 32 per family)**",
        "",
        "| sampler | share |",
        "|---|---|",
        *[f"| {name} | {100 * share:.1f}% |" for name, share in shares.items()],
    ]
    return "\n".join(lines)


def markdown(lut: AlbedoLUT | None = None, *, with_samplers: bool = True, progress=None) -> str:
    """All tables of docs/results/albedo.md, as markdown; ``progress`` gets a line before each step."""
    say = progress or (lambda message: None)
    say("albedo of the model (quadrature) ...")
    lut = build_lut() if lut is None else lut
    parts = [
        _table("A1: specular albedo with F = 1 (s = 1, d = 0; a mirror-like metal)", _rows(lut, lut.a1), lut),
        _table("A0: specular albedo with s = 0 (Schlick's grazing term alone)", _rows(lut, lut.a0), lut),
    ]
    for d, s in ((0.89, 0.02), (1.0, 0.0), (0.18, 0.04)):
        total = d * (1.0 - s) + s * lut.a1 + (1.0 - s) * lut.a0
        parts.append(_table(f"total albedo, d = {d:g}, s = {s:g}", _rows(lut, total), lut))
    if with_samplers:
        say("the samplers' materials ...")
        stats = sampler_exceedance(lut)
        head = "| sampler | " + " | ".join(f"{t:g} deg" for t in lut.incidence_deg) + " |"
        lines = [
            "**Samplers: share of materials (uniform) or texels (SVBRDF) with total albedo > 1 "
            "in some channel, and the largest total**",
            "",
            head,
            "|---|" + "---|" * len(lut.incidence_deg),
        ]
        for name, (share, largest) in stats.items():
            cells = [f"{100 * p:.1f}% / {m:.2f}" for p, m in zip(share, largest)]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    say("the deschaintre2018 model ...")
    floored = build_lut(ROUGHNESS, lut.incidence_deg, model="deschaintre2018")
    parts += [
        _table("deschaintre2018: A1, specular albedo with F = 1", floored.a1, floored),
        _table("deschaintre2018: A0, specular albedo with s = 0", floored.a0, floored),
        models_markdown(),
    ]
    return "\n\n".join(parts)
