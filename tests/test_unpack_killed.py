"""A `shaderball unpack` killed with SIGKILL at any point leaves a folder that every command
sees as incomplete: unpack writes what a build writes first (spec.toml,
dataset.json), then the data files (a sample's record after its render), then the shard
markers, and manifest.jsonl last.

The kill is real: the unpack runs in its own session through ``scripts/crash_test.py
--child``, whose hook SIGKILLs the process group inside the N-th atomic write of a kind of
file (the build's crash tests use the same hook).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import main
from pipeline.publish.request import PublishRequest
from pipeline.publish.writer import publish
from pipeline.store.layout import MANIFEST_FILE

pytestmark = pytest.mark.slow  # a smoke build (once per session)

REPO = Path(__file__).resolve().parents[1]
CRASH = REPO / "scripts" / "crash_test.py"


@pytest.fixture(scope="module")
def pub(smoke, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("killed-unpack") / "pub"
    publish(PublishRequest(str(smoke), str(out)))
    return out


def killed_unpack(pub: Path, out: Path, hook: str, validate: bool = True) -> None:
    """Run `shaderball unpack PUB --out OUT` in a new session, killed by ``hook``."""
    command = [sys.executable, str(CRASH), "--child", "--hook", hook, "--", "unpack", str(pub), "--out", str(out)]
    if not validate:
        command.append("--no-validate")
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, start_new_session=True, cwd=REPO)
    assert done.returncode == -signal.SIGKILL, (hook, done.returncode, done.stderr[-2000:])


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def exrs(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*.exr"))}


#: (hook, what was durable when the kill came)
KILL_POINTS = [
    ("spec:1:fsync", "nothing but a temporary file"),
    ("description:1:renamed", "spec.toml and dataset.json"),
    ("exr:1:write", "a torn first EXR"),
    ("exr:9:renamed", "some maps and renders"),
    ("record:3:rename", "some renders, two records"),
    ("marker:1:renamed", "every data file and one marker"),
    ("marker:4:renamed", "every data file and every marker"),
    ("manifest:1:fsync", "everything but manifest.jsonl (written, not yet renamed)"),
]


@pytest.mark.parametrize("hook, what", KILL_POINTS, ids=[k[0] for k in KILL_POINTS])
def test_a_killed_unpack_leaves_a_folder_every_command_sees_as_incomplete(pub, tmp_path, hook, what):
    out = tmp_path / "out"
    killed_unpack(pub, out, hook)
    assert not (out / MANIFEST_FILE).exists(), what
    if not (out / "spec.toml").exists():  # killed before the first whole file: not a dataset yet
        for args in (
            ["info", str(out)],
            ["validate", str(out)],
            ["preview", str(out), "--out", str(tmp_path / "p.png")],
        ):
            assert run(*args).exit_code == 2, args
        return
    info = run("info", str(out), "--json")
    assert info.exit_code == 0 and json.loads(info.stdout)["complete"] is False, info.output
    assert "completion: INCOMPLETE" in run("info", str(out)).output
    validated = run("validate", str(out), "--json")
    assert validated.exit_code == 1 and json.loads(validated.stdout)["ok"] is False
    assert run("validate", str(out), "--fast").exit_code == 1
    preview = run("preview", str(out), "--out", str(tmp_path / "p.png"))
    assert (preview.exit_code == 0 and "INCOMPLETE" in preview.output) or (
        preview.exit_code == 2 and "no finished render yet" in preview.output
    ), preview.output
    published = run("publish", str(out), "--out", str(tmp_path / "again"))
    assert published.exit_code == 1 and "does not pass `shaderball validate`" in published.output
    assert not (tmp_path / "again").exists()


@pytest.mark.parametrize("hook", ["exr:9:renamed", "marker:4:renamed"])
def test_build_finishes_a_killed_unpack_and_claims_nothing_it_lacks(pub, smoke, tmp_path, hook):
    """Build resumes the folder: it renders what is missing (deterministic: the same bytes as
    the source on this machine) and writes the markers and manifest; never "complete" over
    missing files."""
    out = tmp_path / "out"
    killed_unpack(pub, out, hook, validate=False)
    missing = len(exrs(smoke)) - len(exrs(out))
    built = run("build", str(out / "spec.toml"), "--out", str(out), "--workers", "0")
    assert built.exit_code == 0, built.output
    if hook.startswith("exr"):
        assert missing > 0 and "rendered 0," not in built.output, built.output
    assert run("validate", str(out)).exit_code == 0
    assert exrs(out) == exrs(smoke)


def test_an_unpack_that_finishes_is_complete(pub, smoke, tmp_path):
    out = tmp_path / "out"
    assert run("unpack", str(pub), "--out", str(out)).exit_code == 0
    info = json.loads(run("info", str(out), "--json").stdout)
    assert info["complete"] is True
    assert exrs(out) == exrs(smoke)
    assert (out / MANIFEST_FILE).read_bytes() == (smoke / MANIFEST_FILE).read_bytes()
