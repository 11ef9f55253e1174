"""Directional albedo of the model: ``python -m pipeline.figures.albedo_table`` prints the docs' tables.

The directional albedo ``a(wi) = int f(wi, wo) cos(theta_o) dwo`` (the white
furnace value) is computed with the numpy reference by deterministic
quadrature (:func:`materials.brdf_ref.spec_albedo_quadrature`). Schlick's
term is linear in ``s`` per channel, ``F = s + (1 - s) E(v.h)``, so

    a = d (1 - s) + s A1(r, theta) + (1 - s) A0(r, theta)

with ``A1`` the specular albedo at F = 1 and ``A0`` the one at s = 0 (F = E).
Two numbers per (roughness, incidence) describe every material; the tables
print them, the total for the brightest materials, and how often the
samplers' materials exceed 1.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from materials.brdf_ref import spec_albedo_quadrature
from materials.svbrdf import SVBRDF_FAMILIES, sample_svbrdf
from materials.uniform import sample_uniform

ROUGHNESS = (0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0)
INCIDENCE_DEG = (0.0, 30.0, 60.0, 70.0, 75.0, 80.0, 85.0, 89.0)


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


def build_lut(roughness=None, incidence_deg=INCIDENCE_DEG, *, n_theta=512, n_phi=128) -> AlbedoLUT:
    """Tabulate A0 and A1 (default roughness grid: 0.02 to 1 in 0.02 steps plus the table's values)."""
    if roughness is None:
        roughness = np.unique(np.concatenate([np.arange(0.02, 1.0001, 0.02), ROUGHNESS]))
    roughness = np.asarray(roughness, dtype=np.float64)
    a0 = np.zeros((len(roughness), len(incidence_deg)))
    a1 = np.zeros_like(a0)
    for i, r in enumerate(roughness):
        for t, theta in enumerate(incidence_deg):
            a0[i, t], a1[i, t] = spec_albedo_quadrature(
                r, np.cos(np.radians(theta)), np.array([0.0, 1.0]), n_theta=n_theta, n_phi=n_phi
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


def sampler_exceedance(lut: AlbedoLUT, *, uniform_count: int = 4000, svbrdf_per_family: int = 3,
                       svbrdf_resolution: int = 64, seed: int = 7) -> dict[str, np.ndarray]:
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


def markdown(lut: AlbedoLUT | None = None, *, with_samplers: bool = True) -> str:
    """All tables of docs/materials.md, as markdown."""
    lut = build_lut() if lut is None else lut
    parts = [
        _table("A1: specular albedo with F = 1 (s = 1, d = 0; a mirror-like metal)", _rows(lut, lut.a1), lut),
        _table("A0: specular albedo with s = 0 (Schlick's grazing term alone)", _rows(lut, lut.a0), lut),
    ]
    for d, s in ((0.89, 0.02), (1.0, 0.0), (0.18, 0.04)):
        total = d * (1.0 - s) + s * lut.a1 + (1.0 - s) * lut.a0
        parts.append(_table(f"total albedo, d = {d:g}, s = {s:g}", _rows(lut, total), lut))
    if with_samplers:
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
    return "\n\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-samplers", action="store_true", help="skip the sampler statistics")
    args = parser.parse_args(argv)
    print(markdown(with_samplers=not args.no_samplers))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
