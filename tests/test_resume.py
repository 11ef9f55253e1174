"""Resume: a second build finishes only what is missing or fails verification; another spec is
refused (docs/resume.md). Two builds at once on one directory (two users) give one committed
copy of every sample: one of them is refused while the other writes; two runs of one shard
(dask's at-least-once execution) write identical files.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from pipeline.dataset.spec_file import parse_spec, spec_to_toml
from pipeline.errors import ShaderballError
from pipeline.run.build import build, sweep_temp_files
from pipeline.run.cluster.options import ClusterOptions
from pipeline.run.out_folder import check_output_dir
from pipeline.store.layout import Layout

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"


from conftest import crash_module  # noqa: E402

from support import VARIANT  # noqa: E402

crash = crash_module()


def _spec_text(**changes) -> str:
    text = SMOKE.read_text()
    for key, value in changes.items():
        lines = [f"{key} = {value}" if line.split("=")[0].strip() == key else line for line in text.splitlines()]
        assert lines != text.splitlines(), key
        text = "\n".join(lines) + "\n"
    return text


def _snapshot(folder: Path) -> dict:
    return {
        p.relative_to(folder).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in folder.rglob("*")
        if p.is_file()
    }


def test_other_spec_is_refused_naming_the_fields_and_nothing_is_written(tmp_path):
    out = tmp_path / "ds"
    out.mkdir()
    (out / "spec.toml").write_text(spec_to_toml(parse_spec(SMOKE)))
    other = tmp_path / "other.toml"
    other.write_text(_spec_text(seed=7, spp=32))
    before = _snapshot(out)
    result = CliRunner().invoke(__import__("cli").main, ["build", str(other), "--out", str(out), "--workers", "0"])
    assert result.exit_code == 2, result.output
    message = result.output
    assert "different spec" in message and "dataset.seed = 20191117 in the dataset, 7 in the spec" in message
    assert "render.spp = 16 in the dataset, 32 in the spec" in message
    assert (
        "new directory" in message
        and "--allow-spec-change accepts a change of dataset.name or dataset.version only" in message
    )
    assert _snapshot(out) == before


def test_allow_spec_change_refuses_what_changes_samples(tmp_path):
    out = tmp_path / "ds"
    out.mkdir()
    (out / "spec.toml").write_text(spec_to_toml(parse_spec(SMOKE)))
    changed = parse_spec(_write(tmp_path / "s.toml", _spec_text(shard_size=4)))
    with pytest.raises(ShaderballError, match=r"dataset.shard_size = 2 in the dataset, 4 in the spec"):
        check_output_dir(str(out), changed, allow_spec_change=True)
    renamed = parse_spec(_write(tmp_path / "v.toml", _spec_text(version='"2"')))
    with pytest.raises(ShaderballError, match="pass allow_spec_change to accept them"):
        check_output_dir(str(out), renamed)
    assert check_output_dir(str(out), renamed, allow_spec_change=True) == "respec"


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_allow_spec_change_of_version_keeps_every_sample(tmp_path, reference):
    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    spec_path = _write(tmp_path / "v2.toml", _spec_text(version='"2"'))
    summary = build(str(spec_path), str(out), cluster=ClusterOptions(workers=0), allow_spec_change=True)
    assert summary.rendered == 0 and summary.skipped == 16
    assert parse_spec(out / "spec.toml").dataset.version == "2"
    for rel, path in crash.dataset_files(reference).items():
        if rel.endswith(".exr"):
            assert (out / rel).read_bytes() == path.read_bytes(), rel


def test_directory_with_only_temp_files_is_new(tmp_path):
    """A build killed inside its very first write leaves only a temporary file."""
    out = tmp_path / "ds"
    out.mkdir()
    (out / ".tmp-abc123-spec.toml").write_text("half a spe")
    assert check_output_dir(str(out), parse_spec(SMOKE)) == "new"
    (out / "stray.txt").write_text("x")
    with pytest.raises(ShaderballError, match="not a shaderball dataset"):
        check_output_dir(str(out), parse_spec(SMOKE))


def test_sweep_removes_only_temp_files_older_than_the_build(tmp_path):
    spec = parse_spec(SMOKE)
    from pipeline.dataset.plan import plan_dataset

    plans = plan_dataset(spec)
    shard = Path(Layout(str(tmp_path)).shard_dir(plans[0].shard_id))
    shard.mkdir(parents=True)
    old, new, keep = shard / ".tmp-old-x.exr", tmp_path / ".tmp-new-manifest.jsonl", shard / "m000000.maps.exr"
    for path in (old, new, keep):
        path.write_bytes(b"x")
    os.utime(old, (time.time() - 60, time.time() - 60))
    assert sweep_temp_files(str(tmp_path), plans, older_than=time.time() - 30) == 1
    assert not old.exists() and new.exists() and keep.exists()


def test_resume_renders_only_missing_or_unverified_samples_and_trusts_markers(tmp_path, reference):
    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    s1, s2 = out / "shards" / "s00001", out / "shards" / "s00002"
    (s1 / "COMPLETE.json").unlink()
    (s1 / "m000002_l1.render.exr").unlink()  # file gone: record fails to verify
    _flip_byte(s1 / "m000003_l0.render.exr")  # bytes changed: checksum fails
    (s1 / "m000003_l1.json").unlink()  # no record: not committed
    (out / "manifest.jsonl").unlink()
    _flip_byte(s2 / "m000004_l0.render.exr")  # inside a complete shard: trusted
    summary = build(str(SMOKE), str(out), cluster=ClusterOptions(workers=0))
    assert (summary.rendered, summary.skipped) == (3, 13)
    for name in os.listdir(reference / "shards" / "s00001"):
        if name.endswith(".exr"):
            assert (s1 / name).read_bytes() == (reference / "shards" / "s00001" / name).read_bytes(), name
    # The complete shard was not looked into (its marker is trusted); validate finds the damage.
    assert (s2 / "m000004_l0.render.exr").read_bytes() != (
        reference / "shards" / "s00002" / "m000004_l0.render.exr"
    ).read_bytes()
    from pipeline.check.validate import validate

    report = validate(str(out))
    assert {p.kind for p in report.problems} == {"checksum_mismatch"}
    assert all("m000004_l0" in p.message for p in report.problems)


def _flip_byte(path: Path, offset: int = -100) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.slow
def test_two_builds_at_once_on_one_directory_commit_one_copy_of_each_sample(tmp_path, reference):
    """Two users start the same build: one writes, the other is refused while it does (exit
    code 3, pipeline.store.lock) or, coming after it, finds the dataset complete. Two runs
    of one shard inside a build (dask's at-least-once execution) are the late-second-run
    tests below."""
    out = tmp_path / "ds"
    procs = [
        subprocess.Popen(
            crash.child_command(SMOKE, out, 0),
            cwd=REPO,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        for _ in range(2)
    ]
    try:
        outputs = [p.communicate(timeout=300)[0].decode(errors="replace") for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                crash.kill_group(p)
    assert sorted(p.returncode for p in procs) in ([0, 0], [0, 3]), outputs
    assert all("Traceback" not in text for text in outputs), outputs
    crash.check_complete(out, reference, use_validate=False)
    from pipeline.check.validate import validate

    # Everything validates: a record file whose copy in the marker holds the other run's
    # render time differs only in the run-dependent stats.time_s, which validate ignores.
    problems = validate(str(out)).problems
    assert not problems, [p.message for p in problems]


def _late_second_run(tmp_path, reference) -> Path:
    """The interleaving at-least-once execution allows: run X of a shard writes its marker,
    then a second run Y (started earlier, on a worker declared dead) writes one material's
    files and records again, after X's marker."""
    from pipeline.dataset.plan import plan_dataset
    from pipeline.run.shard import build_material, worker_context

    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    spec = parse_spec(out / "spec.toml")
    material = plan_dataset(spec)[1].materials[0]
    build_material(Layout(str(out)), spec, worker_context(spec, variant=VARIANT), material, [None] * material.n_lights)
    return out


def test_a_late_second_run_of_a_shard_rewrites_identical_files(tmp_path, reference):
    out = _late_second_run(tmp_path, reference)
    for rel, path in crash.dataset_files(reference).items():
        if rel.endswith(".exr"):
            assert (out / rel).read_bytes() == path.read_bytes(), rel
        elif rel.endswith(".json"):
            mine, theirs = (crash.without_timings(json.loads(p.read_text())) for p in (out / rel, path))
            assert mine == theirs, rel


def test_after_a_late_second_run_validate_passes(tmp_path, reference):
    from pipeline.check.validate import validate

    report = validate(str(_late_second_run(tmp_path, reference)))
    assert report.ok, [p.message for p in report.problems]


def _resume_is_refused(tmp_path, reference, change: dict, match: str) -> None:
    """A copy of the reference with ``change`` made to its dataset.json (a key whose value is
    "<drop>" taken out) and one shard's marker gone: its resume is refused (``match``) and
    changes nothing."""
    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    description = json.loads((out / "dataset.json").read_text())
    for key, value in change.items():
        if value == "<drop>":
            description.pop(key, None)
        else:
            description[key] = value
    (out / "dataset.json").write_text(json.dumps(description))
    (out / "shards" / "s00003" / "COMPLETE.json").unlink()
    before = _snapshot(out)
    with pytest.raises(ShaderballError, match=match):
        build(str(SMOKE), str(out), cluster=ClusterOptions(workers=0))
    assert _snapshot(out) == before


@pytest.mark.parametrize(
    "change,message",
    [
        ({"plan_digest": "0" * 64}, "this shaderball plans other samples for the same spec"),
        ({"libraries": {"mitsuba": "3.0.0", "drjit": "1.5.0"}}, "mitsuba 3.0.0 in dataset.json"),
        ({"variant": "cuda_ad_rgb"}, "Mitsuba variant cuda_ad_rgb in dataset.json"),
    ],
)
def test_resume_by_another_installation_is_refused(tmp_path, reference, change, message):
    """Same spec, but samples would be made differently: resuming would mix two datasets."""
    _resume_is_refused(tmp_path, reference, change, f"built by another installation: .*{message}.*new directory")


@pytest.mark.parametrize(
    "change,message",
    [
        ({"plan_format": 1, "shaderball": "0.1.0"}, r"planned with plan format 1 \(by shaderball 0\.1\.0\)"),
        ({"plan_format": None}, r"planned with plan format None \(by shaderball"),
        # a dataset.json from before plan formats were recorded: format 1
        ({"plan_format": "<drop>"}, r"planned with plan format 1 \(by shaderball"),
    ],
)
def test_resume_of_a_dataset_of_another_plan_format_is_refused(tmp_path, reference, change, message):
    """Plan format 1 planned CPU-dependent elevations: never mixed with format 2's."""
    _resume_is_refused(tmp_path, reference, change, f"{message}.*plans format 2.*build into a new directory")


def test_validate_names_another_plan_format_instead_of_every_record(tmp_path, reference):
    import json

    from pipeline.check.validate import validate

    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    description = json.loads((out / "dataset.json").read_text())
    description.pop("plan_format")
    (out / "dataset.json").write_text(json.dumps(description))
    report = validate(str(out))
    assert not report.ok
    messages = [p.message for p in report.problems]
    assert any("planned with plan format 1; this shaderball plans format 2" in m for m in messages), messages
    assert len(messages) <= 2, messages  # one clear problem, not one per record


def test_a_dataset_started_on_another_cpu_resumes(tmp_path, reference):
    """Renders of one plan from two CPU types are equally valid samples: the
    machine is recorded (dataset.json, each marker), never a reason to refuse a resume."""
    import json

    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    description = json.loads((out / "dataset.json").read_text())
    assert {"arch", "cpu_model", "llvm_target_cpu", "llvm_vector_width", "numpy_simd"} <= set(description["machine"])
    description["machine"] = {"arch": "aarch64", "cpu_model": "Neoverse-V2", "llvm_target_cpu": "neoverse-v2"}
    (out / "dataset.json").write_text(json.dumps(description))
    (out / "shards" / "s00003" / "COMPLETE.json").unlink()
    build(str(SMOKE), str(out), cluster=ClusterOptions(workers=0))
    marker = json.loads((out / "shards" / "s00003" / "COMPLETE.json").read_text())
    assert marker["machine"]["arch"] and marker["machine"]["numpy"]
