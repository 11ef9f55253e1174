"""`shaderball build`: determinism, worker-count independence, the recorded effect plan, bad input.

The smoke spec is built three times: twice in this process (workers=0, into two folders)
and once on a 2-worker dask LocalCluster (spawned processes, one render thread each).
Every EXR file of the three is byte-identical; records, markers and manifests are equal
but for the run-dependent values of pipeline.store.records.RUN_DEPENDENT_STATS (timings).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from pipeline.store.records import RUN_DEPENDENT_STATS, without_timings

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"


def _cli(*args):
    from cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


def _files(root: Path) -> dict[str, Path]:
    return {p.relative_to(root).as_posix(): p for p in sorted(root.rglob("*")) if p.is_file()}


def _snapshot(root: Path) -> dict[str, tuple]:
    """Every file with its bytes' hash, size and modification time."""
    return {
        rel: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_size, p.stat().st_mtime_ns)
        for rel, p in _files(root).items()
    }


def _diff_paths(a, b, prefix="") -> set[str]:
    """Dotted key paths where two JSON values differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = set()
        for key in set(a) | set(b):
            out |= _diff_paths(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        out = set()
        for x, y in zip(a, b):
            out |= _diff_paths(x, y, prefix)
        return out
    return set() if a == b else {prefix.rstrip(".")}


@pytest.fixture(scope="module")
def builds(tmp_path_factory):
    """{'a': in-process, 'b': in-process again, 'dask': 2-worker LocalCluster} smoke builds."""
    from pipeline.run.build import build
    from pipeline.run.cluster.options import ClusterOptions

    base = tmp_path_factory.mktemp("builds")
    out = {}
    for name, workers in (("a", 0), ("b", 0), ("dask", 2)):
        summary = build(str(SMOKE), str(base / name), cluster=ClusterOptions(workers=workers))
        assert summary.rendered == summary.total == 16
        out[name] = base / name
    return out


def _assert_same_dataset(x: Path, y: Path):
    fx, fy = _files(x), _files(y)
    assert set(fx) == set(fy)
    exr = [rel for rel in fx if rel.endswith(".exr")]
    assert len(exr) == 16 + 8 + 8  # renders, screen-space maps, texture-space maps
    differing = [rel for rel in exr if fx[rel].read_bytes() != fy[rel].read_bytes()]
    assert not differing, differing
    assert fx["spec.toml"].read_bytes() == fy["spec.toml"].read_bytes()
    assert fx["dataset.json"].read_bytes() == fy["dataset.json"].read_bytes()
    run_dependent = {f"stats.{k}" for k in RUN_DEPENDENT_STATS}
    for rel in fx:
        if rel.endswith(".json") and rel.startswith("shards/"):
            a, b = json.loads(fx[rel].read_text()), json.loads(fy[rel].read_text())
            records_a = a.get("records", [a])
            records_b = b.get("records", [b])
            assert [without_timings(r) for r in records_a] == [without_timings(r) for r in records_b], rel
            for ra, rb in zip(records_a, records_b):
                assert _diff_paths(ra, rb) <= run_dependent, rel
    ma = [json.loads(line) for line in fx["manifest.jsonl"].read_text().splitlines()]
    mb = [json.loads(line) for line in fy["manifest.jsonl"].read_text().splitlines()]
    assert len(ma) == 16
    assert all(r["stats"]["time_s"] > 0 for r in ma + mb)  # the render time is recorded
    assert [without_timings(r) for r in ma] == [without_timings(r) for r in mb]
    changed = set().union(*(_diff_paths(ra, rb) for ra, rb in zip(ma, mb)))
    assert changed <= run_dependent, changed


@pytest.mark.slow
def test_building_twice_gives_byte_identical_files(builds):
    _assert_same_dataset(builds["a"], builds["b"])


@pytest.mark.slow
def test_in_process_and_two_dask_workers_give_byte_identical_files(builds):
    _assert_same_dataset(builds["a"], builds["dask"])


@pytest.mark.slow
def test_every_record_carries_the_effect_plan_of_its_material(builds):
    from pipeline.dataset.materialize import make_material
    from pipeline.dataset.plan import plan_dataset
    from pipeline.dataset.spec_file import parse_spec
    from pipeline.render.renderer import plan_effects

    spec = parse_spec(SMOKE)
    materials = {m.material_id: m for shard in plan_dataset(spec) for m in shard.materials}
    records = [json.loads(line) for line in (builds["a"] / "manifest.jsonl").read_text().splitlines()]
    seen = set()
    for record in records:
        maps, _ = make_material(materials[record["material_id"]], spec)
        assert record["effects"] == plan_effects(maps).to_dict(), record["id"]
        seen.add(tuple(sorted(record["effects"].items())))
    kinds = {record["material"]["kind"]: record["effects"]["textured"] for record in records}
    assert kinds == {"uniform": False, "svbrdf": True}
    assert len(seen) >= 3  # the smoke spec exercises several plans, not one


# ---------------------------------------------------------------- bad input: exit 2, nothing written


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _smoke_with(**changes) -> str:
    lines = SMOKE.read_text().splitlines()
    for key, value in changes.items():
        hits = [i for i, line in enumerate(lines) if line.split("=")[0].strip() == key]
        assert len(hits) == 1, key
        lines[hits[0]] = f"{key} = {value}"
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    "key, value, field, allowed",
    [
        ("spp", "0", "render.spp", "an integer from 1 to 65536"),
        ("resolution", "8", "render.resolution", "an integer from 16 to 4096"),
        ("turbidity", "[0.5, 3.0]", "lighting.turbidity", "1 <= lo <= hi <= 10"),
        ("compression", '"lzma"', "storage.compression", '"zip"'),
    ],
)
def test_bad_spec_field_exits_2_naming_it_and_writes_nothing(tmp_path, key, value, field, allowed):
    spec = _write(tmp_path / "bad.toml", _smoke_with(**{key: value}))
    out = tmp_path / "new" / "dataset"
    result = _cli("build", spec, "--out", out, "--workers", "0")
    assert result.exit_code == 2, result.output
    message = result.output
    assert f"{field}: {value} is not allowed" in message and allowed in message, message
    assert not out.exists() and not out.parent.exists()


def test_missing_spec_file_exits_2_and_writes_nothing(tmp_path):
    out = tmp_path / "dataset"
    result = _cli("build", tmp_path / "nope.toml", "--out", out, "--workers", "0")
    assert result.exit_code == 2, result.output
    assert "nope.toml" in result.output and "does not exist" in result.output
    assert not out.exists()


@pytest.mark.slow
def test_another_spec_on_a_built_dataset_exits_2_and_changes_nothing(tmp_path, builds):
    out = tmp_path / "dataset"
    shutil.copytree(builds["a"], out)  # copy2: modification times kept
    before = _snapshot(out)
    other = _write(tmp_path / "other.toml", _smoke_with(seed=7))
    result = _cli("build", other, "--out", out, "--workers", "0")
    assert result.exit_code == 2, result.output
    assert "different spec" in result.output and str(out) in result.output
    assert _snapshot(out) == before
    assert not [p for p in os.listdir(out) if p.startswith(".tmp")]


@pytest.mark.slow
def test_build_is_byte_identical_at_the_papers_150_spp(tmp_path):
    """The determinism contract at the paper's spp. The smoke spec's 16 spp would hide a failure:
    a pixel's samples straddle drjit's work blocks only when spp does not divide the block
    (pipeline.render.renderer.render_in_passes renders power-of-two passes for that reason)."""
    from pipeline.run.build import build
    from pipeline.run.cluster.options import ClusterOptions

    spec = _write(tmp_path / "s150.toml", _smoke_with(materials=2, spp=150))
    for name in ("a", "b"):
        build(str(spec), str(tmp_path / name), cluster=ClusterOptions(workers=0))
    renders = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*.render.exr"))
    assert len(renders) == 4
    differing = [str(r) for r in renders if (tmp_path / "a" / r).read_bytes() != (tmp_path / "b" / r).read_bytes()]
    assert not differing, differing


def test_a_bad_map_made_beside_the_renders_stops_the_shard_naming_it(tmp_path, monkeypatch):
    """The next material's maps are made and checked on their own thread while the shard
    renders: a value out of range there raises the maps' own error in the build, before
    that material renders, and no marker claims the shard complete."""

    from materials.errors import MaterialError
    from materials.maps import MaterialMaps
    from pipeline.dataset.plan import plan_dataset
    from pipeline.run import shard as shard_mod
    from pipeline.run.out_folder import read_spec_text
    from pipeline.store.layout import Layout
    from support import VARIANT

    spec, _ = read_spec_text(str(SMOKE))
    plan = plan_dataset(spec)[0]
    bad_id = plan.materials[1].material_id
    real = shard_mod.make_material

    def one_bad_texel(material, spec):
        maps, description = real(material, spec)
        if material.material_id != bad_id:
            return maps, description
        roughness = maps.roughness.copy()
        roughness[0, 0] = 1.5
        return MaterialMaps(maps.diffuse, maps.specular, roughness, maps.normal), description

    monkeypatch.setattr(shard_mod, "make_material", one_bad_texel)
    with pytest.raises(MaterialError, match=r"material map roughness: value 1\.5 at \(0, 0\)"):
        shard_mod.run_shard(str(tmp_path), spec, plan, VARIANT)
    layout = Layout(str(tmp_path))
    assert not os.path.exists(layout.marker(plan.shard_id))
    bad = [s for s in plan.samples if s.material_id == bad_id]
    assert bad and not any(os.path.exists(layout.path(layout.record_rel(s.shard_id, s.sample_id))) for s in bad)
    good = [s for s in plan.samples if s.material_id == plan.materials[0].material_id]
    assert all(os.path.exists(layout.path(layout.record_rel(s.shard_id, s.sample_id))) for s in good)
