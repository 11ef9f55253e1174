"""`--json` means exactly one JSON document on stdout, whatever happens:
the command's result, or ``{"ok": false, "exit": N, "error": "..."}`` for exits 1, 2, 3, 4,
130 and an internal error (70); messages and library output go to stderr.

Real processes (``python -m cli``) on real files, so stdout is the process's file descriptor 1."""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

import cli
from pipeline.publish.request import PublishRequest
from pipeline.publish.writer import publish
from pipeline.store.lock import writer_lock
from pipeline.ui.command import Command
from scripts import cli_reference

pytestmark = pytest.mark.slow  # a smoke build (once per session)

REPO = Path(__file__).resolve().parents[1]
JSON_COMMANDS = (
    *("build", "render", "validate", "info", "plan", "publish", "verify", "unpack", "train", "infer", "study"),
    *("bench", "evaluate", "scene", "preview"),
)


@pytest.fixture(scope="module")
def pub(smoke, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cli-json") / "pub"
    publish(PublishRequest(str(smoke), str(out)))
    return out


def shaderball(*args: str, limit_file_kib: int | None = None, code: str | None = None):
    """`python -m cli ARGS` (or ``code`` run before cli.main) in a real process."""

    def limit():
        if limit_file_kib is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit_file_kib * 1024, resource.RLIM_INFINITY))

    command = [sys.executable, "-m", "cli", *args]
    if code is not None:
        command = [
            sys.executable,
            "-c",
            "import sys\n" + code + "\nimport cli\ncli.main(args=sys.argv[1:], prog_name='shaderball')",
            *args,
        ]
    return subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=REPO, preexec_fn=limit)


def one_document(done) -> dict:
    """stdout is one JSON document and nothing else; returns it."""
    doc = json.loads(done.stdout)  # raises on anything but exactly one document
    assert isinstance(doc, dict), done.stdout
    return doc


def assert_failure(done, code: int, words: str) -> dict:
    assert done.returncode == code, (done.returncode, done.stdout, done.stderr[-3000:])
    doc = one_document(done)
    assert doc["ok"] is False and doc["exit"] == code and words in doc["error"], doc
    assert words in done.stderr  # the same message for people
    assert "Traceback" not in done.stderr or code == cli.INTERNAL_EXIT
    return doc


def test_exit_2_bad_usage_is_json(smoke, pub, tmp_path):
    assert_failure(shaderball("validate", "/nonexistent", "--json"), 2, "does not exist")
    assert_failure(shaderball("info", str(tmp_path), "--json"), 2, "holds no spec.toml")
    assert_failure(shaderball("verify", str(tmp_path / "nope"), "--json"), 2, "PUB")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    assert_failure(shaderball("unpack", str(pub), "--out", str(tmp_path / "full"), "--json"), 2, "new or empty")
    assert_failure(shaderball("publish", str(smoke), "--out", str(pub), "--json"), 2, "new or empty")
    assert_failure(shaderball("validate", str(smoke), "--fast", "--repair", "--json"), 2, "not allowed with --repair")
    # click's own refusals, before the command runs
    assert_failure(shaderball("info", "--json"), 2, "DIR|SPEC: missing; ")
    assert_failure(
        shaderball("publish", str(smoke), "--out", str(tmp_path / "p"), "--json", "--shard-bytes", "x"), 2, "x"
    )


def test_unpack_below_a_file_is_bad_usage_like_build(pub, tmp_path):
    (tmp_path / "afile").write_text("x")
    target = str(tmp_path / "afile" / "sub")
    doc = assert_failure(shaderball("unpack", str(pub), "--out", target, "--json"), 2, "is a file, not a folder")
    build = CliRunner().invoke(cli.main, ["build", str(REPO / "manifests" / "smoke.toml"), "--out", target])
    assert build.exit_code == 2 and doc["error"] in build.output


def test_a_bad_spec_snapshot_is_json_for_info(smoke, tmp_path):
    folder = tmp_path / "ds"
    shutil.copytree(smoke, folder)
    (folder / "spec.toml").write_text("[dataset\n")
    assert_failure(shaderball("info", str(folder), "--json"), 2, "spec.toml")


def test_exit_1_refused_is_json_with_its_kind(smoke, tmp_path):
    doc = assert_failure(shaderball("verify", str(smoke), "--json"), 1, "a folder that is no part of a publication")
    assert doc["kind"] == "unlisted_file" and doc["message"] == doc["error"]
    broken = tmp_path / "ds"
    shutil.copytree(smoke, broken)
    (broken / "manifest.jsonl").unlink()
    doc = assert_failure(shaderball("publish", str(broken), "--out", str(tmp_path / "p"), "--json"), 1, "validate")
    done = shaderball("validate", str(broken), "--json")
    assert done.returncode == 1
    report = one_document(done)
    assert report["ok"] is False and report["exit"] == 1 and report["problems"]


def test_exit_3_another_writer_is_json(smoke, tmp_path):
    folder = tmp_path / "ds"
    shutil.copytree(smoke, folder)
    with writer_lock(str(folder), "build"):
        assert_failure(shaderball("validate", str(folder), "--repair", "--json"), 3, "build")


def test_exit_4_a_full_disk_is_json(pub, tmp_path):
    out = tmp_path / "out"
    done = shaderball("unpack", str(pub), "--out", str(out), "--json", limit_file_kib=24)
    assert_failure(done, 4, "EFBIG")
    assert not out.exists()


def test_an_internal_error_is_json_with_exit_70_and_library_output_stays_off_stdout(smoke):
    code = textwrap.dedent(
        """
        import os, sys
        import pipeline.check.info as info
        def broken(root):
            os.write(1, b"C library noise on fd 1\\n")
            print("a stray print")
            raise ZeroDivisionError("a bug")
        import pipeline.bench.info as _info
        _info.dataset_info = broken
        """
    )
    done = shaderball("info", str(smoke), "--json", code=code)
    doc = assert_failure(done, cli.INTERNAL_EXIT, "ZeroDivisionError: a bug")
    assert "internal error" in doc["error"]
    assert "C library noise" in done.stderr and "a stray print" in done.stderr and "Traceback" in done.stderr


def test_success_is_one_document(smoke, pub, tmp_path):
    assert one_document(shaderball("info", str(smoke), "--json"))["complete"] is True
    assert one_document(shaderball("verify", str(pub), "--json"))["ok"] is True
    report = one_document(shaderball("validate", str(smoke), "--json", "--fast"))
    assert report["ok"] is True and report["exit"] == 0


def test_build_and_render_report_what_they_wrote_as_one_document(tmp_path):
    built = shaderball("build", str(REPO / "manifests" / "smoke.toml"), "--out", str(tmp_path / "ds"), "--json")
    assert built.returncode == 0, built.stderr
    doc = one_document(built)
    assert doc["rendered"] == doc["total"] == 16 and doc["shards"] == 4 and doc["seconds"] > 0
    assert doc["manifest"] == str(tmp_path / "ds" / "manifest.jsonl") and os.path.isfile(doc["manifest"])
    out = tmp_path / "one.exr"
    rendered = shaderball("render", "--resolution", "16", "--spp", "1", "--out", str(out), "--json")
    assert rendered.returncode == 0, rendered.stderr
    doc = one_document(rendered)
    assert doc["out"] == str(out) and out.is_file() and doc["stats"]["time_s"] > 0 and doc["stats"]["spp"] == 1


def test_every_json_command_goes_through_the_wrapper():
    """Each command with a --json flag, subcommands of a group included, is a _Command (usage
    errors as JSON) wrapped by _friendly_errors (every other exit as JSON)."""
    flagged = []
    for name in cli_reference.command_names():
        command = cli_reference.command_for(name)
        if any(p.name == "as_json" for p in command.params):
            flagged.append(name)
            assert isinstance(command, Command), name
            assert getattr(command, "body", None) is not None, f"{name}: not generated from a request"
    assert set(JSON_COMMANDS) <= set(flagged)


def test_ctrl_c_is_json_too(smoke):
    code = textwrap.dedent(
        """
        import pipeline.bench.info as _info
        def interrupted(root):
            raise KeyboardInterrupt
        _info.dataset_info = interrupted
        """
    )
    done = shaderball("info", str(smoke), "--json", code=code)
    assert_failure(done, 130, "interrupted (Ctrl-C)")


@pytest.mark.parametrize("command", ["validate", "info"])
def test_without_json_nothing_changes(smoke, command):
    done = shaderball(command, "/nonexistent")
    assert done.returncode == 2 and done.stdout == "" and "error: " in done.stderr
    assert os.path.exists(smoke)
