"""`shaderball validate`: faults injected into a copy of the smoke dataset, each found with its
own problem kind and a message naming the file, and repaired byte-identically.

The smoke spec is built once per test session (once per machine under xdist: a lock file
makes the second worker wait for, then reuse, the first one's build); every test that
changes a dataset works on its own copy.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cli import main
from pipeline.check import inspect as inspect_mod
from pipeline.check.validate import PROBLEM_KINDS, validate
from pipeline.run.repair import repair
from pipeline.store.records import without_timings

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
RENDER = "shards/s00000/m000000_l0.render.exr"
MAPS = "shards/s00001/m000002.maps.exr"
DELETED = "shards/s00002/m000004_l1.render.exr"
EXTRA = "shards/s00003/stray.exr"

slow = pytest.mark.slow  # the tests that use the built dataset


@pytest.fixture
def dataset(smoke, tmp_path) -> Path:
    copy = tmp_path / "ds"
    shutil.copytree(smoke, copy)
    return copy


def exr_digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*.exr"))}


def manifest_lines(root: Path) -> list[dict]:
    return [json.loads(line) for line in (root / "manifest.jsonl").read_text().splitlines()]


def write_manifest_lines(root: Path, records: list[dict]) -> None:
    (root / "manifest.jsonl").write_text(
        "".join(json.dumps(r, sort_keys=True, separators=(",", ":")) + "\n" for r in records)
    )


def invoke(*args: str):
    return CliRunner().invoke(main, ["validate", *args])


# --------------------------------------------------------------------------- faults


def flip_byte(root: Path) -> None:
    path = root / RENDER
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def truncate_maps(root: Path) -> None:
    path = root / MAPS
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def delete_render(root: Path) -> None:
    (root / DELETED).unlink()


def add_extra_file(root: Path) -> None:
    (root / EXTRA).write_bytes(b"not part of the dataset")


def duplicate_line(root: Path) -> None:
    records = manifest_lines(root)
    write_manifest_lines(root, records[:5] + [records[2]] + records[5:])


def edit_turbidity(root: Path) -> None:
    records = manifest_lines(root)
    records[0]["lighting"]["requested"]["turbidity"] = 9.5
    write_manifest_lines(root, records)


def edit_seed(root: Path) -> None:
    records = manifest_lines(root)
    records[3]["seeds"]["material"] += 1  # 63-bit: must be compared exactly
    write_manifest_lines(root, records)


# fault, expected kind, text the message must name, whether --fast sees it
FAULTS = {
    "flipped_byte": (flip_byte, "checksum_mismatch", RENDER, False),
    "truncated_maps": (truncate_maps, "size_mismatch", MAPS, True),
    "deleted_render": (delete_render, "missing_file", DELETED, True),
    "extra_file": (add_extra_file, "extra_file", EXTRA, True),
    "duplicate_record": (duplicate_line, "duplicate_record", "manifest.jsonl line 6", True),
    "edited_turbidity": (edit_turbidity, "edited_record", "manifest.jsonl line 1", True),
    "edited_seed": (edit_seed, "edited_record", "manifest.jsonl line 4", True),
}


@slow
def test_clean_dataset_is_valid(smoke):
    result = invoke(str(smoke), "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert (report["expected"], report["present"], report["valid"]) == (16, 16, 16)
    assert report["problems"] == [] and report["ok"] is True
    human = invoke(str(smoke))
    assert human.exit_code == 0 and "valid: no problems found" in human.stdout


@slow
@pytest.mark.parametrize("name", FAULTS)
def test_fault_gets_its_own_problem_naming_the_file(dataset, name):
    inject, kind, named, _fast = FAULTS[name]
    inject(dataset)
    result = invoke(str(dataset), "--json")
    assert result.exit_code == 1, result.output
    problems = json.loads(result.stdout)["problems"]
    assert [p["kind"] for p in problems] == [kind], problems
    assert named in problems[0]["message"]
    assert set(problems[0]) >= {"kind", "id", "path", "message"}
    human = invoke(str(dataset))
    assert human.exit_code == 1 and f"{kind}: " in human.stdout and named in human.stdout


@slow
def test_fast_finds_size_faults_without_reading(dataset, monkeypatch):
    truncate_maps(dataset)
    delete_render(dataset)
    flip_byte(dataset)  # same size: only the full check can see it
    decoded = []
    monkeypatch.setattr("pipeline.store.exr.read_exr", lambda *a, **k: decoded.append(a))
    fast = validate(str(dataset), fast=True)
    assert sorted(p.kind for p in fast.problems) == ["missing_file", "size_mismatch"]
    assert fast.bytes_read == 0 and decoded == []
    assert {p.path for p in fast.problems} == {MAPS, DELETED}
    monkeypatch.undo()
    full = validate(str(dataset))
    assert sorted(p.kind for p in full.problems) == ["checksum_mismatch", "missing_file", "size_mismatch"]
    assert full.bytes_read > 0


@slow
def test_fast_cli_exit_codes(dataset):
    assert invoke(str(dataset), "--fast").exit_code == 0
    delete_render(dataset)
    result = invoke(str(dataset), "--fast", "--json")
    assert result.exit_code == 1
    assert json.loads(result.stdout)["mode"] == "fast"


@slow
@pytest.mark.parametrize("name", FAULTS)
def test_repair_restores_byte_identical_files(smoke, dataset, name):
    FAULTS[name][0](dataset)
    result = invoke(str(dataset), "--repair", "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["problems"] == [] and report["valid"] == 16
    assert len(report["repair"]["before"]["problems"]) == 1 and report["repair"]["actions"]
    assert exr_digests(dataset) == exr_digests(smoke)
    assert [without_timings(r) for r in manifest_lines(dataset)] == [without_timings(r) for r in manifest_lines(smoke)]
    assert not (dataset / EXTRA).exists()


@slow
def test_repair_rewrites_only_what_is_bad(dataset):
    untouched = dataset / "shards/s00003/m000006_l0.render.exr"
    mtime = untouched.stat().st_mtime_ns
    edit_turbidity(dataset)
    _before, after, actions = repair(str(dataset))
    assert after.ok and [a.action for a in actions] == ["rewrite_manifest"]
    assert untouched.stat().st_mtime_ns == mtime


@slow
def test_usage_errors_exit_2(tmp_path, smoke):
    missing = invoke(str(tmp_path / "nope"))
    assert missing.exit_code == 2 and "does not exist" in missing.output
    (tmp_path / "notes.txt").write_text("hello")
    not_dataset = invoke(str(tmp_path))
    assert not_dataset.exit_code == 2 and "not a shaderball dataset" in not_dataset.output
    both = invoke(str(smoke), "--fast", "--repair")
    assert both.exit_code == 2


# --------------------------------------------------------------------------- deeper checks


def rewrite_consistently(root: Path, rel: str, layers: dict, meta: dict, half=()) -> None:
    """Replace a file and update every copy of its records: only content checks can tell."""
    from pipeline.store.exr import write_exr

    sha = write_exr(str(root / rel), layers, meta, half=half, compression="zip")
    size = (root / rel).stat().st_size

    def fix(record):
        for entry in record["files"]:
            if entry["path"] == rel:
                entry.update(sha256=sha, bytes=size)
        return record

    write_manifest_lines(root, [fix(r) for r in manifest_lines(root)])
    shard_dir = root / rel.rsplit("/", 1)[0]
    marker = json.loads((shard_dir / "COMPLETE.json").read_text())
    marker["records"] = [fix(r) for r in marker["records"]]
    (shard_dir / "COMPLETE.json").write_text(json.dumps(marker))
    for path in shard_dir.glob("m*_l*.json"):
        path.write_text(json.dumps(fix(json.loads(path.read_text()))))


@slow
def test_bad_map_values_found_and_regenerated(smoke, dataset):
    from pipeline.store.exr import read_exr

    image = read_exr(str(dataset / MAPS))
    layers = {k: v.astype(np.float32).copy() for k, v in image.layers.items()}
    inside = np.argwhere(layers["mask"][..., 0] > 0.5)
    (y0, x0), (y1, x1), (y2, x2) = inside[0], inside[1], inside[2]
    layers["roughness"][y0, x0] = np.nan
    layers["diffuse"][y1, x1] = 1.5
    layers["normal"][y2, x2] *= 1.1
    rewrite_consistently(dataset, MAPS, layers, image.meta, half=("diffuse", "specular", "roughness", "normal"))
    report = validate(str(dataset))
    assert sorted(p.kind for p in report.problems) == ["non_finite", "normal_not_unit", "out_of_range"]
    assert all(p.path == MAPS and MAPS in p.message for p in report.problems)
    assert report.valid == 14  # both lightings of the material
    _before, after, _actions = repair(str(dataset))
    assert after.ok and exr_digests(dataset) == exr_digests(smoke)


@slow
def test_negative_render_and_stats_against_pixels(dataset):
    from pipeline.store.exr import read_exr

    image = read_exr(str(dataset / RENDER))
    render = image.layers["render"].copy()
    render[10, 10, 0] = -0.5
    rewrite_consistently(dataset, RENDER, {"render": render}, image.meta)
    report = validate(str(dataset))
    kinds = {p.kind for p in report.problems}
    assert kinds == {"negative_render", "stats_mismatch"}
    stats = next(p for p in report.problems if p.kind == "stats_mismatch")
    assert "stats.negative is 0, the pixels give 1" in stats.message


@slow
def test_edited_statistic_is_a_stats_mismatch(dataset):
    records = manifest_lines(dataset)
    records[2]["stats"]["max"] *= 2
    write_manifest_lines(dataset, records)
    problems = validate(str(dataset)).problems
    assert [p.kind for p in problems] == ["stats_mismatch"]
    assert "stats.max" in problems[0].message and "m000001_l0" in problems[0].message


@slow
def test_unfinished_build_falls_back_to_shards_and_repair_finishes(smoke, dataset):
    (dataset / "manifest.jsonl").unlink()
    (dataset / "shards/s00003/COMPLETE.json").unlink()
    report = validate(str(dataset))
    assert sorted(p.kind for p in report.problems) == ["incomplete_shard", "missing_manifest"]
    assert (report.expected, report.present) == (16, 16)
    _before, after, actions = repair(str(dataset))
    assert after.ok and "rerender" not in [a.action for a in actions]
    assert exr_digests(dataset) == exr_digests(smoke)


@slow
def test_edited_spec_snapshot_is_kept_until_its_spec_is_given(dataset):
    spec = dataset / "spec.toml"
    original = spec.read_bytes()
    spec.write_text(spec.read_text().replace("spp = 16", "spp = 17"))
    before, after, actions = repair(str(dataset))
    assert "spec_snapshot" in {p.kind for p in before.problems}
    assert [a.action for a in actions] == ["unrepairable"] and not after.ok
    wrong = invoke(str(dataset), "--repair", "--spec", str(spec))
    assert wrong.exit_code == 2 and "not this dataset's spec" in wrong.output
    result = invoke(str(dataset), "--repair", "--spec", str(SMOKE), "--json")
    assert result.exit_code == 0, result.output
    assert [a["action"] for a in json.loads(result.stdout)["repair"]["actions"]] == ["restore_spec"]
    assert spec.read_bytes() == original


@slow
def test_progress_once_per_file_and_json_schema(smoke):
    seen = []
    report = validate(str(smoke), progress=seen.append)
    assert [p.done for p in seen] == list(range(1, report.files_checked + 1))
    assert report.files_checked == 32  # 16 renders + 8 maps + 8 texture files
    data = json.loads(report.to_json())
    assert {"expected", "present", "valid", "problems"} <= set(data)


# --------------------------------------------------------------------------- pure checks


def _maps(n=8):
    mask = np.zeros((n, n, 1), np.float32)
    mask[2:6, 2:6] = 1
    normal = np.zeros((n, n, 3), np.float32)
    normal[2:6, 2:6] = np.float16([0.6, 0.0, 0.8])  # rounded to half as stored
    layers = {
        "diffuse": 0.5 * mask.repeat(3, -1),
        "specular": 0.04 * mask.repeat(3, -1),
        "roughness": 0.3 * mask,
        "normal": normal,
        "mask": mask,
    }
    return layers


@pytest.mark.parametrize(
    "edit, kind",
    [
        (lambda m: m["specular"].__setitem__((3, 3, 1), np.inf), "non_finite"),
        (lambda m: m["roughness"].__setitem__((3, 3, 0), -0.1), "out_of_range"),
        (lambda m: m["mask"].__setitem__((0, 0, 0), 0.5), "out_of_range"),
        (lambda m: m["diffuse"].__setitem__((0, 7, 0), 0.2), "out_of_range"),  # outside the mask
        (lambda m: m["normal"].__setitem__((4, 4), [0.6, 0.0, 0.81]), "normal_not_unit"),
    ],
)
def test_map_value_checks(edit, kind):
    layers = _maps()
    assert inspect_mod.map_value_issues(layers, screen_space=True) == []
    edit(layers)
    assert [k for k, _ in inspect_mod.map_value_issues(layers, screen_space=True)] == [kind]


def test_layer_checks():
    expect = inspect_mod.Expect("maps", {"diffuse": (3, "float16"), "mask": (1, "float32")}, (8, 8))
    good = {"diffuse": np.zeros((8, 8, 3), np.float16), "mask": np.zeros((8, 8, 1), np.float32)}
    assert inspect_mod.layer_issues(good, expect) == []
    bad = {"diffuse": np.zeros((4, 8, 1), np.float32), "uv": np.zeros((4, 8, 2), np.float32)}
    messages = [m for _, m in inspect_mod.layer_issues(bad, expect)]
    assert any("mask missing" in m for m in messages) and any("unexpected layer(s) uv" in m for m in messages)
    assert any("1 channel(s), expected 3" in m for m in messages)
    assert any("8x4 pixels, expected 8x8" in m for m in messages)
    assert any("float32, expected float16" in m for m in messages)


def test_every_kind_is_documented():
    doc = (REPO / "docs" / "validate.md").read_text()
    assert all(f"`{kind}`" in doc for kind in PROBLEM_KINDS)
