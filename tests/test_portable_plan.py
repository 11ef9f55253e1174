"""A plan is a function of the spec alone, on every machine.

numpy's vectorised transcendental functions give other last bits on other CPUs (AVX-512
kernels vs AVX2 ones; measured here: ``np.arcsin`` of 100,000 values changes with
``NPY_DISABLE_CPU_FEATURES=X86_V4``). The planner's angles come from sky.portable instead;
these tests prove its sameness three ways: numpy's SIMD dispatch switched off in a fresh
process, a pure-Python scalar evaluation of every planned elevation, and golden digests
(support/plans.py) that every CI machine checks again.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from pipeline.dataset.plan import STREAM_LIGHTS, index_seeds, plan_dataset, seeded_rng
from pipeline.dataset.spec_file import parse_spec
from pipeline.run.out_folder import plan_digest
from sky.portable import DEG_PER_RAD, RAD_PER_DEG, asin_deg, asin_rad, asin_scalar, sin_deg, sin_rad, sin_scalar
from sky.sampling import unit_points
from support.plans import PAPER, PLAN_DIGESTS, REPO, SMOKE

SPECS = [SMOKE, PAPER]


def _ulps(got: np.ndarray, want: np.ndarray) -> np.ndarray:
    return np.abs(got - want) / np.spacing(np.maximum(np.abs(want), np.finfo(float).tiny))


def test_portable_asin_and_sin_are_within_a_few_ulp_of_numpy():
    z = np.linspace(-1.0, 1.0, 400_001)
    assert _ulps(asin_rad(z), np.arcsin(z)).max() <= 8
    x = np.linspace(-math.pi / 2, math.pi / 2, 400_001)
    assert _ulps(sin_rad(x), np.sin(x))[np.sin(x) != 0].max() <= 8
    assert asin_rad(0.0) == 0.0 and sin_rad(0.0) == 0.0
    assert abs(asin_deg(0.5) - 30.0) < 1e-12 and abs(sin_deg(90.0) - 1.0) < 1e-15


@pytest.mark.parametrize("bad", [1.0000001, -1.5, float("nan")])
def test_portable_asin_refuses_values_outside_its_domain(bad):
    with pytest.raises(ValueError, match=r"asin_rad: every value must lie in \[-1.0, 1.0\]"):
        asin_rad(np.array([0.0, bad]))


def test_the_numpy_path_and_the_scalar_path_give_the_same_bits():
    rng = np.random.default_rng(20)
    z = np.concatenate([rng.uniform(-1, 1, 50_000), [-1.0, 1.0, 0.0, -0.0, 5e-324, 1 - 2**-53, 0.5]])
    vector = asin_rad(z)
    assert all(asin_scalar(float(v)) == w for v, w in zip(z, vector))
    x = rng.uniform(-math.pi / 2, math.pi / 2, 50_000)
    assert all(sin_scalar(float(v)) == w for v, w in zip(x, sin_rad(x)))


@pytest.mark.parametrize("spec", SPECS, ids=["smoke", "paper"])
def test_every_planned_elevation_is_the_scalar_paths(spec):
    """Each elevation recomputed one Python float at a time, without a numpy ufunc on it."""
    parsed = parse_spec(spec)
    plan = plan_dataset(parsed)
    ranges = parsed.lighting.to_lighting_ranges()
    el_lo, el_hi = ranges.elevation_deg
    z_lo, z_hi = sin_scalar(el_lo * RAD_PER_DEG), sin_scalar(el_hi * RAD_PER_DEG)
    shards = range(len(plan)) if len(plan) <= 8 else sorted({0, len(plan) // 2, len(plan) - 1})
    checked = 0
    for index in shards:
        for material in plan[index].materials:
            seed = int(index_seeds(parsed.dataset.seed, STREAM_LIGHTS, [material.material_index])[0])
            u = unit_points(seeded_rng(seed), parsed.dataset.lights_per_material, ranges.scheme)
            for light, u0 in enumerate(u[:, 0].tolist()):
                z = min(max(z_lo + u0 * (z_hi - z_lo), -1.0), 1.0)
                want = min(max(asin_scalar(z) * DEG_PER_RAD, el_lo), el_hi)
                assert material.elevation_deg[light] == want, (material.material_id, light)
                checked += 1
    assert checked >= 16


DIGEST_SCRIPT = """
import json, sys
from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec_file import parse_spec
from pipeline.run.out_folder import plan_digest
import numpy._core._multiarray_umath as umath
enabled = [name for name in umath.__cpu_dispatch__ if umath.__cpu_features__.get(name)]
print(json.dumps({"enabled": enabled, "digests": [plan_digest(plan_dataset(parse_spec(p))) for p in sys.argv[1:]]}))
"""


def _digests_in_a_process(env_extra: dict[str, str]) -> dict:
    env = dict(os.environ, **env_extra)
    run = subprocess.run(
        [sys.executable, "-c", DIGEST_SCRIPT, *map(str, SPECS)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_the_digest_is_the_same_with_numpys_simd_dispatch_switched_off():
    """Every dispatch target this numpy has (AVX2, AVX-512, ... or NEON's, SVE's) disabled."""
    import numpy._core._multiarray_umath as umath

    dispatch = list(umath.__cpu_dispatch__)
    default = _digests_in_a_process({})
    baseline = _digests_in_a_process({"NPY_DISABLE_CPU_FEATURES": " ".join(dispatch)})
    assert baseline["enabled"] == [], baseline  # the switch took: only baseline kernels ran
    assert default["digests"] == baseline["digests"]
    assert default["digests"] == [PLAN_DIGESTS[p] for p in SPECS]


@pytest.mark.parametrize("spec", SPECS, ids=["smoke", "paper"])
def test_the_plan_digest_is_the_golden_one(spec):
    """The same value on every machine the suite runs on (support/plans.py)."""
    assert plan_digest(plan_dataset(parse_spec(spec))) == PLAN_DIGESTS[spec]
