"""The plan: pure, deterministic, seeds keyed by ids only, exact SVBRDF split, cheap."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from pipeline.dataset.plan import (
    KIND_SVBRDF,
    KIND_UNIFORM,
    MaterialPlan,
    SamplePlan,
    ShardPlan,
    iter_samples,
    list_imported_maps,
    plan_dataset,
    plan_summary,
    render_seeds,
    seeded_rng,
)
from pipeline.dataset.spec_file import parse_spec, parse_spec_text
from pipeline.errors import ShaderballError
from support import PAPER, REPO, SMOKE


def make_spec(materials=8, lights=2, fraction=0.5, shard_size=2, seed=11, extra=""):
    return parse_spec_text(
        f'[dataset]\nname = "t"\nseed = {seed}\nmaterials = {materials}\n'
        f"lights_per_material = {lights}\nsvbrdf_fraction = {fraction}\n"
        f"shard_size = {shard_size}\n" + extra
    )


def all_samples(plans):
    return list(iter_samples(plans))


def without_shard(sample: SamplePlan) -> dict:
    d = sample.to_dict()
    del d["shard_index"]
    return d


# --------------------------------------------------------------------------- structure


def test_smoke_plan_structure():
    spec = parse_spec(SMOKE)
    plans = plan_dataset(spec)
    assert [p.shard_id for p in plans] == ["s00000", "s00001", "s00002", "s00003"]
    assert all(isinstance(p, ShardPlan) and len(p.materials) == 2 for p in plans)
    samples = all_samples(plans)
    assert [s.sample_id for s in samples[:3]] == ["m000000_l0", "m000000_l1", "m000001_l0"]
    assert len({s.sample_id for s in samples}) == 16
    for shard in plans:
        for material in shard.materials:
            assert isinstance(material, MaterialPlan)
            assert material.shard_index == shard.shard_index
            assert material.material_id == f"m{material.material_index:06d}"
            assert [s.light_index for s in material.samples] == [0, 1]
            assert all(s.shard_id == shard.shard_id for s in material.samples)
            assert shard.samples[0].material_id == shard.materials[0].material_id


def test_summary_counts():
    summary = plan_summary(plan_dataset(parse_spec(SMOKE)))
    assert summary["shards"] == 4
    assert summary["materials"] == 8
    assert summary["renders"] == 16
    assert summary["uniform"] == 4 and summary["svbrdf"] == 4
    assert sum(summary["svbrdf_sources"].values()) == 4


def test_last_shard_may_be_short():
    plans = plan_dataset(make_spec(materials=7, shard_size=3))
    assert [len(p.materials) for p in plans] == [3, 3, 1]


def test_records_are_plain_data():
    plans = plan_dataset(make_spec())
    sample = plans[0].materials[0].samples[1]
    assert json.loads(json.dumps(sample.to_dict())) == sample.to_dict()
    material = plans[0].materials[0].to_dict()
    assert json.loads(json.dumps(material)) == material


# --------------------------------------------------------------------------- determinism


def test_same_spec_same_plan():
    spec = parse_spec(SMOKE)
    assert plan_dataset(spec) == plan_dataset(spec)
    assert plan_dataset(spec) == plan_dataset(parse_spec(SMOKE))
    assert all_samples(plan_dataset(spec)) == all_samples(plan_dataset(spec))


def test_plan_is_the_same_in_a_fresh_interpreter():
    """No dependence on hash seeds, import order or process state."""
    code = (
        "import json, sys; from pipeline.dataset.spec_file import parse_spec; "
        "from pipeline.dataset.plan import plan_dataset, iter_samples; "
        "p = plan_dataset(parse_spec(sys.argv[1])); "
        "print(json.dumps([s.to_dict() for s in iter_samples(p)]))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, SMOKE],
        check=True,
        cwd=REPO,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONHASHSEED": "12345"},
    ).stdout
    here = [s.to_dict() for s in all_samples(plan_dataset(parse_spec(SMOKE)))]
    assert json.loads(out) == here


@pytest.mark.parametrize("shard_size", [1, 3, 8, 1000])
def test_shard_size_changes_grouping_only(shard_size):
    reference = [without_shard(s) for s in all_samples(plan_dataset(make_spec(shard_size=2)))]
    plans = plan_dataset(make_spec(shard_size=shard_size))
    assert [without_shard(s) for s in all_samples(plans)] == reference
    assert len(plans) == math.ceil(8 / shard_size)
    for shard in plans:
        assert all(m.material_index // shard_size == shard.shard_index for m in shard.materials)


def test_different_seed_different_everything():
    a = all_samples(plan_dataset(make_spec(seed=1)))
    b = all_samples(plan_dataset(make_spec(seed=2)))
    assert not {s.material_seed for s in a} & {s.material_seed for s in b}
    assert [s.elevation_deg for s in a] != [s.elevation_deg for s in b]


# --------------------------------------------------------------------------- seeds


def test_seeds_are_distinct_and_in_range():
    samples = all_samples(plan_dataset(make_spec(materials=300, lights=7, shard_size=16)))
    materials = {s.material_index: s for s in samples}
    assert len({s.material_seed for s in materials.values()}) == 300
    assert len({s.light_seed for s in materials.values()}) == 300
    assert len({s.render_seed for s in samples}) == 300 * 7
    assert not {s.material_seed for s in samples} & {s.light_seed for s in samples}
    assert all(0 <= s.material_seed < 2**63 and 0 <= s.light_seed < 2**63 for s in samples)
    assert all(0 <= s.render_seed < 2**32 for s in samples)
    assert all(type(s.render_seed) is int and type(s.material_seed) is int for s in samples)


def test_a_materials_seed_is_shared_by_its_lightings():
    for material in plan_dataset(make_spec(lights=4))[0].materials:
        assert {s.material_seed for s in material.samples} == {material.material_seed}
        assert {s.light_seed for s in material.samples} == {material.light_seed}
        assert len({s.render_seed for s in material.samples}) == 4


def test_material_seed_depends_on_seed_and_index_only():
    def seeds(spec):
        return [m.material_seed for p in plan_dataset(spec) for m in p.materials]

    base = seeds(make_spec(materials=6))
    assert (
        seeds(
            make_spec(
                materials=6,
                lights=5,
                fraction=0.0,
                shard_size=4,
                extra='[lighting]\nturbidity = [2, 3]\nscheme = "stratified"\n',
            )
        )
        == base
    )
    assert seeds(make_spec(materials=9))[:6] == base  # more materials keep the first ones


def test_render_seeds_of_existing_lights_survive_more_lights():
    two = [m.render_seeds for p in plan_dataset(make_spec(lights=2)) for m in p.materials]
    five = [m.render_seeds for p in plan_dataset(make_spec(lights=5)) for m in p.materials]
    assert [f[:2] for f in five] == two


def test_render_seeds_are_distinct_across_a_large_grid():
    # The packing m * 1000 + l is injective up to the limits (10^6 materials, 1000 lights),
    # and mix32 is a bijection: check both ends of the index range.
    for first in (0, 999_800):
        seeds = render_seeds(3, np.arange(first, first + 200)[:, None], np.arange(1000)[None, :])
        assert seeds.dtype == np.uint32
        assert len(np.unique(seeds)) == seeds.size


def test_seeded_rng_is_pcg64_from_the_seed():
    a = seeded_rng(123).random(4)
    b = np.random.Generator(np.random.PCG64(123)).random(4)
    assert np.array_equal(a, b)


# --------------------------------------------------------------------------- SVBRDF split


@pytest.mark.parametrize(
    "materials,fraction", [(8, 0.5), (7, 0.5), (1, 0.5), (10, 0.3), (10, 0.0), (10, 1.0), (1000, 0.123), (3, 0.25)]
)
def test_svbrdf_count_is_exact(materials, fraction):
    spec = make_spec(materials=materials, fraction=fraction, shard_size=5)
    kinds = Counter(m.kind for p in plan_dataset(spec) for m in p.materials)
    expected = math.floor(fraction * materials + 0.5)
    assert kinds[KIND_SVBRDF] == expected == spec.dataset.n_svbrdf
    assert kinds[KIND_UNIFORM] == materials - expected


def test_sources_are_balanced_and_exclusive():
    spec = make_spec(materials=1000, fraction=0.5, shard_size=50)
    materials = [m for p in plan_dataset(spec) for m in p.materials]
    families = Counter(m.svbrdf_family for m in materials if m.kind == KIND_SVBRDF)
    assert set(families) == set(spec.materials.svbrdf_families)
    assert max(families.values()) - min(families.values()) <= 1
    for m in materials:
        if m.kind == KIND_UNIFORM:
            assert m.svbrdf_family is None and m.svbrdf_file is None
        else:
            assert (m.svbrdf_family is None) != (m.svbrdf_file is None)


def test_svbrdf_materials_are_spread_not_clustered():
    kinds = [m.kind for p in plan_dataset(make_spec(materials=400, shard_size=400)) for m in p.materials]
    assert 50 <= kinds[:200].count(KIND_SVBRDF) <= 150  # a permutation, not a block


def test_raising_the_fraction_only_adds_svbrdf_materials():
    def svbrdf(fraction):
        return {
            m.material_index: m.svbrdf_family
            for p in plan_dataset(make_spec(materials=50, fraction=fraction))
            for m in p.materials
            if m.kind == KIND_SVBRDF
        }

    low, high = svbrdf(0.2), svbrdf(0.6)
    assert low.items() <= high.items()


def test_chosen_families_only():
    spec = make_spec(materials=20, fraction=1.0, extra='[materials]\nsvbrdf_families = ["tiles", "stones"]\n')
    families = Counter(m.svbrdf_family for p in plan_dataset(spec) for m in p.materials)
    assert families == {"tiles": 10, "stones": 10}


# --------------------------------------------------------------------------- imported maps


@pytest.fixture
def map_folder(tmp_path):
    folder = tmp_path / "deschaintre"
    folder.mkdir()
    for name in ["0003;b.png", "0001;a.png", "0002;c.PNG", "notes.txt", ".hidden.png"]:
        (folder / name).write_bytes(b"")
    return folder


def test_imported_files_are_each_used_before_any_repeats(map_folder):
    spec = make_spec(
        materials=8, fraction=1.0, extra=(f'[materials]\nsvbrdf_families = []\nsvbrdf_folders = ["{map_folder}"]\n')
    )
    inventory = list_imported_maps(spec)
    assert inventory == {str(map_folder): ("0001;a.png", "0002;c.PNG", "0003;b.png")}
    materials = [m for p in plan_dataset(spec) for m in p.materials]
    files = Counter(m.svbrdf_file for m in materials)
    assert sorted(files.values()) == [2, 3, 3]
    assert all(os.path.dirname(f) == str(map_folder) for f in files)
    assert all(m.svbrdf_family is None for m in materials)
    assert plan_dataset(spec, imported=inventory) == plan_dataset(spec)


def test_families_and_folders_share_svbrdf_materials(map_folder):
    spec = make_spec(
        materials=40,
        fraction=0.75,
        extra=(f'[materials]\nsvbrdf_families = ["tiles", "stones"]\nsvbrdf_folders = ["{map_folder}"]\n'),
    )
    summary = plan_summary(plan_dataset(spec))
    assert summary["svbrdf"] == 30
    assert summary["svbrdf_sources"] == {"family:stones": 10, "family:tiles": 10, f"folder:{map_folder}": 10}


def test_planning_with_an_empty_inventory_is_refused(map_folder):
    spec = make_spec(fraction=1.0, extra=(f'[materials]\nsvbrdf_families = []\nsvbrdf_folders = ["{map_folder}"]\n'))
    with pytest.raises(ShaderballError, match="holds no map file"):
        plan_dataset(spec, imported={str(map_folder): ()})


# --------------------------------------------------------------------------- lightings


@pytest.mark.parametrize("scheme", ["uniform_hemisphere", "uniform_angles", "stratified", "sobol"])
def test_lightings_are_skys_joint_draw_per_material(scheme):
    import sky

    spec = make_spec(
        materials=12,
        lights=5,
        extra=(
            f"[lighting]\nelevation_deg = [10, 80]\nazimuth_deg = [-90, 180]\n"
            f'turbidity = [2, 7]\nscheme = "{scheme}"\nturbidity_per = "light"\n'
        ),
    )
    ranges = spec.lighting.to_lighting_ranges()
    for shard in plan_dataset(spec):
        for material in shard.materials:
            lights = sky.sample_lights(seeded_rng(material.light_seed), 5, ranges)
            got = np.array([material.elevation_deg, material.azimuth_deg, material.turbidity])
            want = np.array(
                [[x.elevation_deg for x in lights], [x.azimuth_deg for x in lights], [x.turbidity for x in lights]]
            )
            # Same arithmetic, vectorised; 1e-12 leaves room for SIMD vs scalar libm.
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_lightings_are_in_range_and_stratified():
    spec = make_spec(
        materials=50,
        lights=5,
        shard_size=10,
        extra=(
            '[lighting]\nelevation_deg = [5, 90]\nazimuth_deg = [0, 360]\nturbidity = [1, 10]\nscheme = "stratified"\n'
        ),
    )
    z_lo = math.sin(math.radians(5.0))
    for shard in plan_dataset(spec):
        for m in shard.materials:
            assert all(5.0 <= e <= 90.0 for e in m.elevation_deg)
            assert all(0.0 <= a <= 360.0 for a in m.azimuth_deg)
            assert all(1.0 <= t <= 10.0 for t in m.turbidity)
            # Latin hypercube over the material's 5 lightings: one per stratum of each axis.
            z = [(math.sin(math.radians(e)) - z_lo) / (1.0 - z_lo) for e in m.elevation_deg]
            assert sorted(min(int(v * 5), 4) for v in z) == [0, 1, 2, 3, 4]
            assert sorted(min(int(a / 72.0), 4) for a in m.azimuth_deg) == [0, 1, 2, 3, 4]


# --------------------------------------------------------------------------- purity, cost


def test_planning_touches_no_files_without_folders(monkeypatch):
    spec = parse_spec(SMOKE)
    expected = plan_dataset(spec)  # imports done

    def refuse(*args, **kwargs):
        raise AssertionError("the plan touched the file system")

    monkeypatch.setattr("builtins.open", refuse)
    monkeypatch.setattr(os, "listdir", refuse)
    monkeypatch.setattr(os, "scandir", refuse)
    assert plan_dataset(spec) == expected


def test_plan_module_is_pure():
    code = (
        "import sys; from pipeline.dataset.spec_file import parse_spec; "
        "from pipeline.dataset.plan import plan_dataset; plan_dataset(parse_spec(%r)); "
        "bad = [m for m in ('mitsuba', 'drjit', 'dask', 'distributed') if m in sys.modules]; "
        "assert not bad, bad" % SMOKE
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)


def _python_calls(work) -> int:
    """Python and C function calls made while ``work()`` runs: a measure of its work that, unlike a
    clock, is the same on a busy machine."""
    calls = 0

    def count(frame, event, arg):
        nonlocal calls
        calls += event in ("call", "c_call")

    sys.setprofile(count)
    try:
        work()
    finally:
        sys.setprofile(None)
    return calls


def _plan_sum_and_open(spec) -> tuple:
    plans = plan_dataset(spec)
    plan_summary(plans)
    return plans[len(plans) // 2].samples  # a shard and its samples, made when asked for


def test_paper_plan_is_cheap():
    """Planning, summing up and opening a shard does no work per sample: the paper's 50,000
    renders take as many calls as a tenth of them (an eager plan: a call or more per render)."""
    spec = parse_spec(PAPER)
    tenth = parse_spec_text(Path(PAPER).read_text().replace("materials = 10000", "materials = 1000", 1), "tenth")
    assert tenth.dataset.n_renders == 5_000
    _plan_sum_and_open(make_spec())  # imports and first-call costs out of the way
    calls = {name: _python_calls(lambda s=s: _plan_sum_and_open(s)) for name, s in (("tenth", tenth), ("paper", spec))}
    assert calls["paper"] - calls["tenth"] < (50_000 - 5_000) / 10, calls
    plans = plan_dataset(spec)
    summary = plan_summary(plans)
    assert (summary["materials"], summary["renders"], summary["shards"]) == (10_000, 50_000, 500)
    assert (summary["uniform"], summary["svbrdf"]) == (5_000, 5_000)
    samples = all_samples(plans)
    assert len(samples) == 50_000
    assert len({s.render_seed for s in samples}) == 50_000


def test_plans_survive_dask_transport():
    """dask ships a ShardPlan to a worker by pickle (transport only; nothing is persisted so)."""
    import pickle

    plans = plan_dataset(make_spec())
    _ = plans[0].materials[0].samples  # a filled cache travels too
    again = pickle.loads(pickle.dumps(plans))
    assert again == plans
    assert all_samples(again) == all_samples(plans)


def test_turbidity_per_material_is_the_papers_default():
    import sky

    spec = make_spec(
        materials=12,
        lights=5,
        extra=('[lighting]\nelevation_deg = [10, 80]\nturbidity = [2, 7]\nscheme = "stratified"\n'),
    )
    assert spec.lighting.turbidity_per == "material"
    ranges = spec.lighting.to_lighting_ranges()
    turbidities = set()
    for shard in plan_dataset(spec):
        for material in shard.materials:
            lights = sky.sample_lights(seeded_rng(material.light_seed), 5, ranges)
            assert material.turbidity == (lights[0].turbidity,) * 5
            np.testing.assert_allclose(material.elevation_deg, [x.elevation_deg for x in lights], atol=1e-12)
            turbidities.add(material.turbidity[0])
    assert len(turbidities) == 12  # still random per material
