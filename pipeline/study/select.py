"""Which samples of a spec the study renders: spread over what changes error.

Pure and deterministic: the same spec gives the same selection. Candidates are the
spec's own planned samples (the first ``scan`` materials of its plan, all their
lightings); each is put in a material class (uniform dielectric, uniform metal, or its
SVBRDF family) and given three features: sun elevation, turbidity and mean roughness on
the material, each called low or high against the middle of its range in the spec.
Classes take turns (round robin); within a class, successive picks aim at the corners of
the (sun, turbidity, roughness) cube in Gray-code order, taking the unused candidate
nearest to the corner, preferring materials not chosen yet.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from pipeline.dataset.materialize import make_material
from pipeline.dataset.plan import KIND_UNIFORM, plan_dataset
from pipeline.dataset.spec import DatasetSpec

#: A uniform material whose specular albedo (max over RGB) exceeds this is a metal: the
#: model's dielectrics have 0.02-0.08, its metals >= ~0.26 (docs/materials.md).
METAL_SPECULAR = 0.2
#: Gray-code order of the (sun high, turbidity high, roughness high) corners.
CORNERS = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 0, 1), (0, 0, 1)]


@dataclass(frozen=True)
class StudySample:
    sample_id: str
    material_index: int
    light_index: int
    material_class: str  # uniform_dielectric, uniform_metal, svbrdf:<family or file>
    elevation_deg: float
    azimuth_deg: float
    turbidity: float
    roughness: float  # mean roughness of the material's maps
    render_seed: int
    corner: tuple[str, str, str]  # ("low"/"high" sun, turbidity, roughness)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["corner"] = list(self.corner)
        return d


def material_class(kind: str, maps, plan) -> str:
    if kind == KIND_UNIFORM:
        return "uniform_metal" if float(np.max(maps.specular)) > METAL_SPECULAR else "uniform_dielectric"
    return "svbrdf:" + (plan.svbrdf_family or "imported")


def candidates(spec: DatasetSpec, scan: int) -> list[tuple]:
    """(SamplePlan, class, mean roughness) for every lighting of the first ``scan`` materials."""
    out = []
    for shard in plan_dataset(spec):
        for plan in shard.materials:
            if plan.material_index >= scan:
                return out
            maps, _ = make_material(plan, spec)
            cls = material_class(plan.kind, maps, plan)
            rough = float(np.mean(maps.roughness))
            out.extend((sample, cls, rough) for sample in plan.samples)
    return out


def select_samples(spec: DatasetSpec, n: int, scan: int = 60) -> list[StudySample]:
    """``n`` study samples from the spec's plan (see the module's docstring)."""
    pool = candidates(spec, min(scan, spec.dataset.materials))
    lo_e, hi_e = spec.lighting.elevation_deg
    lo_t, hi_t = spec.lighting.turbidity
    lo_r, hi_r = spec.materials.roughness

    def features(item):
        s, _, rough = item
        norm = lambda v, lo, hi: 0.5 if hi <= lo else (v - lo) / (hi - lo)  # noqa: E731
        return np.array([norm(s.elevation_deg, lo_e, hi_e), norm(s.turbidity, lo_t, hi_t), norm(rough, lo_r, hi_r)])

    found = {c for _, c, _ in pool}
    classes = [c for c in ("uniform_dielectric", "uniform_metal") if c in found] + sorted(
        c for c in found if c.startswith("svbrdf:")
    )
    by_class = {c: [item for item in pool if item[1] == c] for c in classes}
    picks: list[StudySample] = []
    used_ids, used_materials = set(), set()
    turn = dict.fromkeys(classes, 0)
    while len(picks) < n:
        progress = False
        for c in classes:
            if len(picks) >= n:
                break
            free = [it for it in by_class[c] if it[0].sample_id not in used_ids]
            if not free:
                continue
            corner = np.array(CORNERS[turn[c] % len(CORNERS)], float)
            fresh = [it for it in free if it[0].material_index not in used_materials] or free
            best = min(fresh, key=lambda it: (float(np.abs(features(it) - corner).sum()), it[0].sample_id))
            s, _, rough = best
            f = features(best)
            picks.append(
                StudySample(
                    sample_id=s.sample_id,
                    material_index=s.material_index,
                    light_index=s.light_index,
                    material_class=c,
                    elevation_deg=float(s.elevation_deg),
                    azimuth_deg=float(s.azimuth_deg),
                    turbidity=float(s.turbidity),
                    roughness=rough,
                    render_seed=int(s.render_seed),
                    corner=tuple("high" if v >= 0.5 else "low" for v in f),
                )
            )
            used_ids.add(s.sample_id)
            used_materials.add(s.material_index)
            turn[c] += 1
            progress = True
        if not progress:
            break
    return picks
