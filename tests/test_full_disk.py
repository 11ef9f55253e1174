"""A full disk is exit code 4 and one line naming the file that could not be written, in
every command that writes: no traceback (from a library, or a dask worker's "Compute Failed"
log), and nothing partial left that looks complete.

The disk fills as it would for real: the command runs in a child process whose
RLIMIT_FSIZE (``ulimit -f``) makes every write past the limit fail with EFBIG, as ENOSPC
fails it on a full disk."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import main

pytestmark = pytest.mark.slow  # the shared smoke build; real processes

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"


def shaderball(*args, limit_file_kib: int) -> subprocess.CompletedProcess:
    """`python -m cli ARGS` in a process that cannot write a file past ``limit_file_kib``."""

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_file_kib * 1024, resource.RLIM_INFINITY))

    return subprocess.run(
        [sys.executable, "-m", "cli", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
        preexec_fn=limit,
    )


def full_disk_line(done: subprocess.CompletedProcess, inside: Path) -> str:
    """Exit code 4, no traceback or worker log, and a last line naming a file under ``inside``."""
    assert done.returncode == 4, (done.returncode, done.stderr[-3000:])
    assert "Traceback" not in done.stderr and "Compute Failed" not in done.stderr, done.stderr
    line = [line for line in done.stderr.splitlines() if line.strip()][-1]
    assert line.startswith("error: ") and "File too large (EFBIG)" in line, line
    assert "?:" not in line, line  # an OSError the command let out without its path
    named = line.removeprefix("error: ").split(": File too large")[0]
    assert Path(named).resolve().is_relative_to(inside.resolve()), line
    return line


@pytest.mark.parametrize(
    "limit_kib, args, file",
    [
        (24, [], "shards/renders-000000.tar"),  # a tar: written member by member
        (150, ["--shard-bytes", 65536], "preview.png"),  # small tars: the contact sheet is the largest file
    ],
)
def test_publish_on_a_full_disk_names_the_file_and_leaves_nothing(reference, tmp_path, limit_kib, args, file):
    pub = tmp_path / "pub"
    done = shaderball("publish", reference, "--out", pub, *args, limit_file_kib=limit_kib)
    line = full_disk_line(done, pub)
    assert line.startswith(f"error: {pub / file}: "), line
    assert not pub.exists()  # what it wrote, and the folder it made, are removed


def test_build_on_a_full_disk_with_a_dask_worker_prints_no_worker_traceback(tmp_path):
    """The worker's task hits EFBIG; the build reports it as its own one line (the worker logs
    nothing: the task returns the error, the driver raises it)."""
    ds = tmp_path / "ds"
    done = shaderball("build", SMOKE, "--out", ds, "--workers", 1, limit_file_kib=24)
    line = full_disk_line(done, ds / "shards")
    assert "run the same command again to resume" in line
    assert not list(ds.rglob(".tmp-*")) and not list(ds.rglob("COMPLETE.json"))


@pytest.fixture(scope="module")
def trained(reference, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("full-disk") / "run"
    args = ["--loss", "l1", "--resolution", "32", "--batch-size", "4", "--seed", "3", "--epochs", "1"]
    result = CliRunner().invoke(main, ["train", str(reference), "--out", str(out), *args])
    assert result.exit_code == 0, result.output
    return out


def test_evaluate_on_a_full_disk_writes_all_its_results_or_none(trained, reference, tmp_path):
    """grid.png (the largest) cannot be written: results.json and results.md are not left
    behind to look like a finished evaluation."""
    out = tmp_path / "ev"
    args = ["evaluate", trained, reference, "--split", "all", "--spp", "none", "--no-denoise", "--limit", 2]
    done = shaderball(*args, "--out", out, limit_file_kib=16)
    line = full_disk_line(done, out)
    assert line.startswith(f"error: {out / 'grid.png'}: "), line
    assert not out.exists() or list(out.iterdir()) == [], list(out.iterdir())
    again = shaderball(*args, "--out", out, limit_file_kib=1 << 20)
    assert again.returncode == 0, again.stderr[-3000:]
    assert sorted(p.name for p in out.iterdir()) == ["grid.png", "results.json", "results.md"]
