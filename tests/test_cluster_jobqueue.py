"""`--cluster slurm|pbs`: the dask-jobqueue job script, tested as text (there is no batch
system here). One contract, parametrised over both backends (as dask-jobqueue's own tests do).
"""

from __future__ import annotations

import shlex
import sys

import pytest
from click.testing import CliRunner

from pipeline.errors import ShaderballError
from pipeline.run.cluster.connection import WORKER_MEMORY_SHARE, job_script, jobqueue_cluster
from pipeline.run.cluster.options import ClusterOptions, walltime_seconds, worker_lifetime
from support.clusters import slurm_build_command, stand_in_slurm

pytest.importorskip("dask_jobqueue")

BACKENDS = {
    # kind: (cores directive, memory directive, walltime directive, queue, account)
    "slurm": (
        "#SBATCH --cpus-per-task=32",
        "#SBATCH --mem=64G",
        "#SBATCH -t 12:00:00",
        "#SBATCH -p render",
        "#SBATCH -A vision",
    ),
    "pbs": (
        "#PBS -l select=1:ncpus=32:mem=64GB",
        "#PBS -l select=1:ncpus=32:mem=64GB",
        "#PBS -l walltime=12:00:00",
        "#PBS -q render",
        "#PBS -A vision",
    ),
}


def _options(kind: str, **changes) -> ClusterOptions:
    base = dict(cluster=kind, jobs=100, cores=32, memory="64GiB", walltime="12:00:00", queue="render", account="vision")
    base.update(changes)
    return ClusterOptions(**base)


def _worker_command(script: str) -> list[str]:
    line = next(l for l in script.splitlines() if "distributed.cli.dask_worker" in l)
    return shlex.split(line)


@pytest.mark.parametrize("kind", sorted(BACKENDS))
def test_job_script_asks_for_the_job_and_starts_one_single_thread_worker(kind):
    script = job_script(_options(kind), "tcp://10.0.0.1:8786")
    for directive in BACKENDS[kind]:
        assert directive in script, (directive, script)
    argv = _worker_command(script)
    assert argv[:3] == [sys.executable, "-m", "distributed.cli.dask_worker"]
    assert argv[3] == "tcp://10.0.0.1:8786"
    args = dict(zip(argv[4::1], argv[5::1]))
    assert args["--nthreads"] == "1"  # one shard at a time; its renders use all 32 cores
    assert "--nworkers" not in argv
    assert args["--memory-limit"] == f"{WORKER_MEMORY_SHARE * 64:.2f}GiB"  # below the job's cgroup
    lifetime, stagger = worker_lifetime("12:00:00")
    assert (args["--lifetime"], args["--lifetime-stagger"]) == (f"{lifetime}s", f"{stagger}s")
    assert lifetime + stagger < 12 * 3600
    assert "--lifetime-restart" not in argv
    assert "--nanny" in argv


@pytest.mark.parametrize("kind,job_id", [("slurm", "SLURM_JOB_ID"), ("pbs", "PBS_JOBID")])
def test_job_script_gives_each_job_its_own_node_local_kernel_cache(kind, job_id):
    script = job_script(_options(kind, scratch="/local/scratch"))
    prologue = script.split("distributed.cli.dask_worker")[0]
    assert "export SHADERBALL_RENDER_THREADS=32" in prologue
    assert f'export DRJIT_CACHE_DIR="/local/scratch/shaderball-drjit-${{{job_id}:-$$}}"' in prologue
    assert 'mkdir -p "$DRJIT_CACHE_DIR"' in prologue
    argv = _worker_command(script)
    assert argv[argv.index("--local-directory") + 1] == f"/local/scratch/shaderball-dask-${{{job_id}:-$$}}"


def test_default_scratch_is_tmpdir_on_the_node():
    script = job_script(_options("slurm"))
    assert 'DRJIT_CACHE_DIR="${TMPDIR:-/tmp}/shaderball-drjit-${SLURM_JOB_ID:-$$}"' in script


def test_the_cluster_submits_the_script_we_print():
    """The real dask-jobqueue cluster (scheduler in this process, nothing submitted)."""
    cluster = jobqueue_cluster(_options("slurm"), adapt=False)
    try:
        theirs = cluster.job_script()
        ours = job_script(_options("slurm"), cluster.scheduler_address)
        strip = lambda s: [l for l in s.splitlines() if "--name" not in l]  # noqa: E731
        assert strip(theirs) == strip(ours)
        assert "--nthreads 1" in theirs
    finally:
        cluster.close()


def test_user_prologue_from_dask_config_comes_first():
    import dask

    with dask.config.set({"jobqueue.slurm.job-script-prologue": ["module load llvm/19"]}):
        script = job_script(_options("slurm"))
    assert script.index("module load llvm/19") < script.index("export DRJIT_CACHE_DIR")


@pytest.mark.parametrize(
    "changes,message",
    [
        ({"memory": None}, "memory: required with cluster slurm; for example: memory 64GiB"),
        ({"cores": None}, "cores: required with cluster slurm; for example: cores 32"),
        ({"walltime": None}, "walltime: required"),
        ({"walltime": "12h"}, 'walltime: "12h" is not allowed; HH:MM:SS from 00:01:00'),
        ({"walltime": "00:00:59"}, 'walltime: "00:00:59" is not allowed'),
        ({"start_timeout": 9}, r"start_timeout: 9 is not allowed; an integer from 10 to 10000000"),
        ({"memory": "lots"}, 'memory: "lots" is not allowed; an amount from 256MiB to 64TiB'),
        ({"memory": "100MB"}, 'memory: "100MB" is not allowed'),
        ({"cores": 0}, r"cores: 0 is not allowed; an integer from 1 to 1024"),
        ({"jobs": 0}, r"jobs: 0 is not allowed; an integer from 1 to 10000"),
        ({"queue": "a b"}, 'queue: "a b" is not allowed'),
        ({"account": "x;rm"}, 'account: "x;rm" is not allowed'),
        ({"scratch": "/tmp/a b"}, 'scratch: "/tmp/a b" is not allowed'),
        ({"workers": 4}, "workers: not allowed with cluster slurm; use jobs"),
        ({"scheduler": "tcp://h:1"}, "scheduler: not allowed with cluster slurm"),
        ({"recycle_after": -1}, r"recycle_after: -1 is not allowed; an integer from 0 to 10000000"),
    ],
)
def test_bad_options_name_option_value_and_range(changes, message):
    with pytest.raises(ShaderballError, match=message):
        _options("slurm", **changes)


@pytest.mark.parametrize(
    "option",
    [
        ["--jobs", "2"],
        ["--cores", "8"],
        ["--walltime", "01:00:00"],
        ["--queue", "q"],
        ["--account", "a"],
        ["--scratch", "/s"],
    ],
)
def test_jobqueue_options_are_refused_on_a_local_cluster(option):
    from pipeline.run.cluster.options import ClusterOptions

    name = option[0].lstrip("-").replace("-", "_")
    value = int(option[1]) if option[1].isdigit() else option[1]
    with pytest.raises(ShaderballError, match=f"{name}: only with cluster slurm or cluster pbs"):
        ClusterOptions(**{name: value})


def test_worker_lifetime_leaves_a_margin():
    assert worker_lifetime("01:00:00") == (3300, 150)
    assert worker_lifetime("24:00:00") == (86400 - 4320, 2160)
    assert worker_lifetime("00:15:00") == (600, 150)


@pytest.mark.parametrize(
    "walltime,expected",
    [("00:01:00", (30, 15)), ("00:02:00", (60, 30)), ("00:09:00", (270, 135)), ("00:10:00", (300, 150))],
)
def test_short_walltimes_retire_workers_in_the_second_half(walltime, expected):
    """dask staggers a lifetime by +-stagger: a worker retires 0.5 to 1.5 margins before the end."""
    lifetime, stagger = worker_lifetime(walltime)
    assert (lifetime, stagger) == expected
    total = walltime_seconds(walltime)
    assert total // 4 <= lifetime - stagger and lifetime + stagger < total


def _cli(args, tmp_path):
    import cli

    return CliRunner().invoke(cli.main, ["build", "manifests/smoke.toml", "--out", str(tmp_path / "ds")] + args)


def test_cli_prints_the_job_script_and_writes_nothing(tmp_path):
    result = _cli(
        [
            "--cluster",
            "pbs",
            "--jobs",
            "100",
            "--cores",
            "32",
            "--memory",
            "64GiB",
            "--walltime",
            "12:00:00",
            "--print-job-script",
        ],
        tmp_path,
    )
    assert result.exit_code == 0, result.output
    assert result.output.startswith("#!/usr/bin/env bash") and "#PBS -l walltime=12:00:00" in result.output
    assert not (tmp_path / "ds").exists()


def test_cli_bad_option_exits_2_and_writes_nothing(tmp_path):
    result = _cli(["--cluster", "slurm", "--cores", "32", "--walltime", "12:00:00"], tmp_path)
    assert result.exit_code == 2
    assert "error: --memory: required with --cluster slurm" in result.output
    assert not (tmp_path / "ds").exists()


FAKE_SBATCH = """# Stand-in for SLURM's sbatch: copy the job script (as sbatch does: dask-jobqueue deletes its
# file once sbatch returns), run it on this machine detached in its own session; the job id
# is its process id (= its process group, for scancel).
cp "$1" "$FAKE_SLURM_DIR/job-$$.sh"
setsid bash "$FAKE_SLURM_DIR/job-$$.sh" > "$FAKE_SLURM_DIR/job-$$.log" 2>&1 < /dev/null &
echo $! >> "$FAKE_SLURM_DIR/jobs"
echo "Submitted batch job $!"
"""
FAKE_SCANCEL = """for job in "$@"; do kill -TERM -- "-$job" 2>/dev/null; done
exit 0
"""


@pytest.mark.slow
def test_slurm_build_runs_its_job_scripts_end_to_end(tmp_path):
    """`--cluster slurm` with stand-ins for sbatch/scancel that run each job script here: the
    scheduler on 127.0.0.1, 2 jobs, each a worker with its own kernel cache in --scratch."""
    import os
    import signal
    import subprocess
    import time
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    bin_dir, slurm_dir, scratch = tmp_path / "bin", tmp_path / "slurm", tmp_path / "scratch"
    for folder in (bin_dir, slurm_dir, scratch):
        folder.mkdir()
    env = stand_in_slurm(bin_dir, slurm_dir, {"sbatch": FAKE_SBATCH, "scancel": FAKE_SCANCEL})
    out = tmp_path / "ds"
    cmd = slurm_build_command(out, "--cores", "1", "--scratch", str(scratch))
    try:
        result = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=400)
    finally:
        jobs = (slurm_dir / "jobs").read_text().split() if (slurm_dir / "jobs").exists() else []
        for job in jobs:
            try:
                os.killpg(int(job), signal.SIGKILL)
            except ProcessLookupError:
                pass
        time.sleep(0.5)
    logs = "\n".join(p.read_text(errors="replace")[-2000:] for p in slurm_dir.glob("job-*.log"))
    assert result.returncode == 0, result.stdout + result.stderr + logs
    assert "building with slurm cluster, 2 job(s) of 1 cores, 2GiB" in result.stderr
    assert "rendered 16, already present 0" in result.stdout
    assert 1 <= len(jobs) and all(j.isdigit() for j in jobs)
    caches = [p for p in scratch.glob("shaderball-drjit-*") if any(p.iterdir())]
    assert caches, "no job wrote kernels to its own cache under --scratch"
    from pipeline.check.validate import validate

    assert validate(str(out)).ok
