"""A dataset folder is untrusted input: paths named in records and markers, symbolic
links, FIFOs and malformed JSON. Every test spoils its own copy of the smoke dataset, runs the
commands that read folders (build's resume, validate, --repair, info, preview, the training
loader) and asserts the outcome: a clean message or problem, no traceback, nothing outside the
folder opened (inotify), read or written, and a resume that ends byte-identical to the
reference build."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import crash_module

from cli import main
from pipeline.run.build import build
from pipeline.run.cluster.options import ClusterOptions
from support.hostile import copy_dataset, snapshot, watch_opens

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
crash = crash_module()


def invoke(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise AssertionError(f"shaderball {' '.join(map(str, args))} raised {result.exception!r}") from result.exception
    return result


def cli(*args) -> tuple[int, str]:
    """Exit code and output (stdout and stderr) of the CLI, run in this process; a Python
    exception escaping the command (a traceback for the user) fails the test."""
    result = invoke(*args)
    return result.exit_code, result.output


def validate_json(*args) -> tuple[int, list[dict]]:
    """``shaderball validate ... --json``: exit code and the problems, parsed from stdout alone."""
    result = invoke("validate", *args, "--json")
    return result.exit_code, json.loads(result.stdout)["problems"]


def cli_process(*args, timeout: float = 180) -> subprocess.CompletedProcess:
    """The CLI in its own process, for inputs that could hang or exhaust memory (a hang fails at
    ``timeout``: ~60x a command's time on the smoke dataset on 2 idle cores, ample when busy)."""
    return subprocess.run(
        [sys.executable, "-m", "cli", *map(str, args)], cwd=REPO, capture_output=True, text=True, timeout=timeout
    )


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    data = change(data)
    path.write_text(json.dumps(data))


@pytest.fixture
def outside(tmp_path) -> Path:
    """A folder outside the dataset holding what a hostile record points to."""
    folder = tmp_path / "outside"
    folder.mkdir()
    (folder / "secret.txt").write_text("not yours")
    return folder


@pytest.mark.slow
def test_a_record_naming_a_file_outside_is_never_opened_and_resume_renders_it_again(tmp_path, reference, outside):
    """A record's ../../outside.txt is neither opened by build's resume nor written into
    COMPLETE.json and the manifest."""
    ds = copy_dataset(reference, tmp_path / "ds")
    secret = outside / "secret.txt"
    rel = os.path.relpath(secret, ds)  # ../outside/secret.txt
    record = ds / "shards" / "s00003" / "m000007_l1.json"
    forged = {
        "role": "render",
        "path": rel,
        "bytes": secret.stat().st_size,
        "sha256": hashlib.sha256(secret.read_bytes()).hexdigest(),
    }  # verifies, if followed
    edit_json(record, lambda r: {**r, "files": [forged] + r["files"][1:]})
    (ds / "shards" / "s00003" / "COMPLETE.json").unlink()
    (ds / "manifest.jsonl").unlink()
    with watch_opens(outside) as watch:
        code, problems = validate_json(ds)
        assert code == 1
        messages = [p["message"] for p in problems if p["id"] == "m000007_l1"]
        assert any(f"{rel!r} is not a path inside the dataset" in m for m in messages), messages
        summary = build(str(SMOKE), str(ds), cluster=ClusterOptions(workers=0))
        assert watch.opened() == [], "a command opened a file outside the dataset"
    assert summary.rendered == 1
    assert "outside" not in (ds / "manifest.jsonl").read_text()
    crash.check_complete(ds, reference)


def test_a_marker_naming_an_outside_picture_is_not_shown_by_preview_and_info_says_so(tmp_path, reference, outside):
    """preview never displays an outside file named in a marker."""
    ds = copy_dataset(reference, tmp_path / "ds")
    picture = outside / "picture.exr"
    shutil.copy(ds / "shards" / "s00001" / "m000002_l0.render.exr", picture)
    marker = ds / "shards" / "s00000" / "COMPLETE.json"
    edit_json(
        marker,
        lambda m: {
            **m,
            "records": [
                {
                    **m["records"][0],
                    "files": [{**m["records"][0]["files"][0], "path": "../../outside/picture.exr"}]
                    + m["records"][0]["files"][1:],
                }
            ]
            + m["records"][1:],
        },
    )
    with watch_opens(outside) as watch:
        code, output = cli("preview", ds, "--out", tmp_path / "sheet.png", "--rows", "16")
        assert code == 1, output  # the sheet written without it: validate's "problems found"
        assert "left out" in output and "shards/s00000/COMPLETE.json" in output and "leaves the folder" in output
        code, output = cli("info", ds)
        assert code == 0 and "NOT READ" in output and "shards/s00000/COMPLETE.json" in output, output
        code, problems = validate_json(ds)
        assert code == 1 and any(
            p["path"] == "shards/s00000/COMPLETE.json" and "m000000_l0" in p["message"] for p in problems
        ), problems
        assert watch.opened() == []


@pytest.mark.slow
@pytest.mark.parametrize(
    "what, spoil",
    [
        ("a marker [1]", lambda m: [1]),
        (
            "a record without bytes",
            lambda m: {
                **m,
                "records": [
                    {
                        **m["records"][0],
                        "files": [{k: v for k, v in e.items() if k != "bytes"} for e in m["records"][0]["files"]],
                    }
                ]
                + m["records"][1:],
            },
        ),
        (
            'a record with "files": []',
            lambda m: {**m, "records": [{**m["records"][0], "files": []}] + m["records"][1:]},
        ),
    ],
)
def test_a_malformed_marker_is_reported_and_treated_as_not_done(tmp_path, reference, what, spoil):
    ds = copy_dataset(reference, tmp_path / "ds")
    marker = ds / "shards" / "s00000" / "COMPLETE.json"
    edit_json(marker, spoil)
    code, problems = validate_json(ds)
    assert code == 1
    assert any(p["path"] == "shards/s00000/COMPLETE.json" for p in problems), problems
    code, output = cli("info", ds)
    assert code == 0 and "NOT READ" in output and "shards/s00000/COMPLETE.json" in output, output
    assert "3/4 shards complete" in output
    code, output = cli("preview", ds, "--out", tmp_path / "sheet.png")
    assert code == 1 and "left out" in output, output  # the sheet written: validate's "problems found"
    # build's resume: the shard is not done; its record files still verify, so nothing is
    # rendered and the marker is written again, whole.
    summary = build(str(SMOKE), str(ds), cluster=ClusterOptions(workers=0))
    assert summary.rendered == 0
    crash.check_complete(ds, reference)


@pytest.mark.slow
@pytest.mark.parametrize("content", [[1], {"id": "m000000_l0"}, "files-without-bytes"])
def test_a_malformed_record_file_is_rendered_again(tmp_path, reference, content):
    ds = copy_dataset(reference, tmp_path / "ds")
    record = ds / "shards" / "s00000" / "m000000_l0.json"
    if content == "files-without-bytes":
        edit_json(record, lambda r: {**r, "files": [{k: v for k, v in e.items() if k != "bytes"} for e in r["files"]]})
    else:
        record.write_text(json.dumps(content))
    (ds / "shards" / "s00000" / "COMPLETE.json").unlink()
    code, output = cli("info", ds)
    assert code == 0 and "shards/s00000/m000000_l0.json" in output, output
    assert build(str(SMOKE), str(ds), cluster=ClusterOptions(workers=0)).rendered == 1
    crash.check_complete(ds, reference)


def test_symlinks_inside_the_folder_are_reported_and_never_followed(tmp_path, reference, outside):
    """A symlink to a non-empty outside directory does not leave validate "valid"."""
    ds = copy_dataset(reference, tmp_path / "ds")
    (ds / "shards" / "s00000" / "evil").symlink_to(outside)
    (ds / "shards" / "s00001" / "notes.txt").symlink_to(outside / "secret.txt")
    before = snapshot(outside)
    with watch_opens(outside) as watch:
        code, problems = validate_json(ds)
        assert code == 1
        unsafe = {p["path"]: p["message"] for p in problems if p["kind"] == "unsafe_path"}
        assert set(unsafe) == {"shards/s00000/evil", "shards/s00001/notes.txt"}, problems
        assert f"a symbolic link (to {str(outside)!r})" in unsafe["shards/s00000/evil"]
        code, output = cli("info", ds)
        assert code == 0 and "shards/s00000/evil: a symbolic link" in output
        code, problems = validate_json(ds, "--repair")
        assert code == 0, problems
        assert watch.opened() == []
    assert not os.path.lexists(ds / "shards" / "s00000" / "evil")
    assert snapshot(outside) == before  # the links went, what they pointed to stayed
    crash.check_complete(ds, reference)


@pytest.mark.slow
def test_a_render_that_is_a_symlink_is_reported_with_its_sample_and_rendered_again(tmp_path, reference, outside):
    ds = copy_dataset(reference, tmp_path / "ds")
    render = ds / "shards" / "s00002" / "m000004_l1.render.exr"
    copy = outside / "m000004_l1.render.exr"
    shutil.move(render, copy)
    render.symlink_to(copy)  # the same bytes, through a link
    with watch_opens(outside) as watch:
        code, problems = validate_json(ds)
        assert code == 1
        found = [p for p in problems if p["kind"] == "unsafe_path"]
        assert [(p["id"], p["path"]) for p in found] == [("m000004_l1", "shards/s00002/m000004_l1.render.exr")]
        (ds / "shards" / "s00002" / "COMPLETE.json").unlink()
        assert build(str(SMOKE), str(ds), cluster=ClusterOptions(workers=0)).rendered == 1
        assert watch.opened() == []
    assert not render.is_symlink()
    crash.check_complete(ds, reference)


def test_a_shard_folder_that_is_a_symlink_is_not_written_through(tmp_path, reference, outside):
    ds = copy_dataset(reference, tmp_path / "ds")
    moved = outside / "s00003"
    shutil.move(ds / "shards" / "s00003", moved)
    (moved / "COMPLETE.json").unlink()
    (ds / "shards" / "s00003").symlink_to(moved)
    before = snapshot(outside)
    with watch_opens(moved) as watch:
        code, output = cli("build", SMOKE, "--out", ds, "--workers", "0")
        assert code == 2 and "\nerror: " in output and "shards/s00003: a symbolic link" in output, output
        code, problems = validate_json(ds)
        assert code == 1 and any(p["kind"] == "unsafe_path" and p["path"] == "shards/s00003" for p in problems), (
            problems
        )
        assert watch.opened() == []
    assert snapshot(outside) == before


@pytest.mark.parametrize("kind", ["dev-zero", "fifo", "huge"])
def test_a_manifest_that_is_not_a_regular_file_neither_hangs_nor_exhausts_memory(tmp_path, reference, kind):
    """manifest.jsonl -> /dev/zero must not end in MemoryError, nor a FIFO hang validate and info."""
    ds = copy_dataset(reference, tmp_path / "ds")
    manifest = ds / "manifest.jsonl"
    manifest.unlink()
    if kind == "dev-zero":
        manifest.symlink_to("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(manifest)
    else:  # a regular file far larger than 16 records can be
        with open(manifest, "wb") as fh:
            fh.truncate(16 * (1 << 20) + 8192)
    checked = cli_process("validate", ds, "--json")
    assert checked.returncode == 1 and "Traceback" not in checked.stderr, checked.stderr
    messages = [p["message"] for p in json.loads(checked.stdout)["problems"] if p["path"] == "manifest.jsonl"]
    assert any("cannot be read" in m for m in messages), messages
    info = cli_process("info", ds)
    assert info.returncode == 0 and "Traceback" not in info.stderr, info.stderr
    assert "manifest.jsonl" in info.stdout
    torch = pytest.importorskip("torch")
    assert torch
    from pipeline.errors import ShaderballError
    from pipeline.neural.data import open_dataset

    with pytest.raises(ShaderballError, match="manifest.jsonl cannot be read"):
        open_dataset(str(ds))


def test_a_spec_snapshot_that_is_a_fifo_does_not_hang_and_is_refused(tmp_path, reference):
    ds = copy_dataset(reference, tmp_path / "ds")
    (ds / "spec.toml").unlink()
    os.mkfifo(ds / "spec.toml")
    for args, code in (
        (["validate", ds], 1),
        (["info", ds], 2),
        (["build", SMOKE, "--out", ds, "--workers", "0"], 2),
        (["preview", ds, "--out", tmp_path / "p.png"], 2),
    ):
        done = cli_process(*args)
        assert done.returncode == code and "Traceback" not in done.stderr, (args, done.stderr)
        assert "spec.toml" in done.stdout + done.stderr and "FIFO" in done.stdout + done.stderr, (args, done)


def test_the_training_loader_refuses_a_manifest_path_outside_the_folder(tmp_path, reference, outside):
    pytest.importorskip("torch")
    from pipeline.errors import ShaderballError
    from pipeline.neural.data import open_dataset

    ds = copy_dataset(reference, tmp_path / "ds")
    lines = (ds / "manifest.jsonl").read_text().splitlines()
    record = json.loads(lines[0])
    record["files"][0]["path"] = "../outside/secret.txt"
    lines[0] = json.dumps(record)
    (ds / "manifest.jsonl").write_text("\n".join(lines) + "\n")
    with watch_opens(outside) as watch:
        with pytest.raises(ShaderballError, match="line 1: record m000000_l0: file path .* leaves the folder"):
            open_dataset(str(ds))
        (ds / "shards" / "s00000").rename(ds / "shards" / "real")
        (ds / "shards" / "s00000").symlink_to(ds / "shards" / "real")
        record["files"][0]["path"] = "shards/s00000/m000000_l0.render.exr"
        lines[0] = json.dumps(record)
        (ds / "manifest.jsonl").write_text("\n".join(lines) + "\n")
        with pytest.raises(ShaderballError, match="shards/s00000 is a symbolic link"):
            open_dataset(str(ds))
        assert watch.opened() == []
