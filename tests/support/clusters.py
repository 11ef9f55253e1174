"""Helpers of the cluster tests: `shaderball` and dask as child processes of this interpreter,
each in its own process group (the caller kills the group), and stand-ins for SLURM's commands."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: `shaderball` as a child process of this interpreter (run from REPO: `cli` is imported from there).
SHADERBALL = [sys.executable, "-c", "import cli; cli.main()"]
DASK = str(Path(sys.executable).with_name("dask"))


def start_group(cmd: list[str], log: Path, env: dict | None = None) -> subprocess.Popen:
    """``cmd`` from REPO in a process group of its own, its output appended to ``log``."""
    return subprocess.Popen(
        cmd,
        cwd=REPO,
        stdin=subprocess.DEVNULL,
        stdout=open(log, "ab"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
        env=dict(os.environ, **(env or {})),
    )


def start_scheduler(folder: Path, procs: list[subprocess.Popen]) -> str:
    """A `dask scheduler` on 127.0.0.1 (a free port, no dashboard, its log in folder/scheduler.log),
    appended to ``procs`` at once; its address, once it has written it."""
    scheduler_file, log = folder / "scheduler.json", folder / "scheduler.log"
    cmd = [DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"]
    procs.append(start_group([*cmd, "--scheduler-file", str(scheduler_file)], log))
    deadline = time.monotonic() + 60
    while not scheduler_file.exists() or not scheduler_file.read_text().strip():
        assert time.monotonic() < deadline, log.read_text()
        assert procs[-1].poll() is None, log.read_text()
        time.sleep(0.1)
    return json.loads(scheduler_file.read_text())["address"]


def stand_in(folder: Path, name: str, text: str) -> None:
    """An executable bash script ``name`` in ``folder`` that runs ``text``."""
    (folder / name).write_text("#!/bin/bash\n" + text)
    (folder / name).chmod(0o755)


def stand_in_slurm(bin_dir: Path, slurm_dir: Path, scripts: dict[str, str]) -> dict[str, str]:
    """Stand-ins for SLURM's commands (name: bash text) in ``bin_dir``; the environment of a
    build that runs them first on its PATH, with FAKE_SLURM_DIR (their state) ``slurm_dir``
    and the dask scheduler on 127.0.0.1."""
    for name, text in scripts.items():
        stand_in(bin_dir, name, text)
    return dict(
        os.environ,
        PATH=f"{bin_dir}:{os.environ['PATH']}",
        FAKE_SLURM_DIR=str(slurm_dir),
        DASK_JOBQUEUE__SLURM__SCHEDULER_OPTIONS='{"host": "127.0.0.1"}',
    )


def slurm_build_command(out: Path, *options: str) -> list[str]:
    """`shaderball build` of the smoke spec into ``out`` on 2 SLURM jobs of 2 GiB for 30 minutes
    (run from REPO), with ``options`` (the jobs' cores among them)."""
    build = ["build", "manifests/smoke.toml", "--out", str(out), "--cluster", "slurm", "--jobs", "2"]
    return [*SHADERBALL, *build, "--memory", "2GiB", "--walltime", "00:30:00", *options]
