"""A build waiting on workers says so, and --start-timeout bounds the wait (docs/cluster.md).

Unit tests of pipeline.run.cluster.watch.WorkerWatch with a fake clock and a fake queue; squeue's
output parsed through a stand-in `squeue`; and two builds end to end without a batch system:
`--cluster slurm` with stand-ins whose jobs stay pending (PartitionDown) for ever, and
`--scheduler` pointing at a dask scheduler without workers. The same against a real SLURM:
tests/test_slurm_real.py.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest
from conftest import crash_module

from pipeline.check.validate import validate
from pipeline.errors import ShaderballError
from pipeline.run.cluster.connection import _refusal_text
from pipeline.run.cluster.options import ClusterOptions
from pipeline.run.cluster.watch import QUEUE_POLL_S, JobState, WorkerWatch, describe_jobs, slurm_job_states
from pipeline.run.request import BuildRequest
from pipeline.store.atomic import TEMP_PREFIX
from pipeline.ui.command import label_for
from support.clusters import SHADERBALL, slurm_build_command, stand_in, stand_in_slurm, start_scheduler

REPO = Path(__file__).resolve().parents[1]
crash = crash_module()


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


def _slurm(**changes) -> ClusterOptions:
    base = dict(cluster="slurm", cores=2, memory="4GiB", walltime="00:30:00", start_timeout=30)
    base.update(changes)
    return ClusterOptions(**base)


def _jobqueue(*job_ids, refusals=()):
    """What WorkerWatch reads of a dask-jobqueue cluster: its jobs' ids and its job class."""
    return SimpleNamespace(
        workers={f"w{i}": SimpleNamespace(job_id=j) for i, j in enumerate(job_ids)},
        job_cls=SimpleNamespace(refusals=list(refusals)),
    )


def _watch(workers, states, options=None, jobqueue=None, clock=None):
    counts = iter(workers) if isinstance(workers, list) else None
    return WorkerWatch(
        (lambda: next(counts)) if counts else (lambda: workers),
        options or _slurm(),
        jobqueue if jobqueue is not None else _jobqueue("7", "8"),
        clock=clock or Clock(),
        job_states=lambda ids: [s for s in states if s.job_id in ids],
    )


PENDING = [JobState("7", "PENDING", "PartitionDown"), JobState("8", "PENDING", "PartitionDown")]


def test_status_shows_workers_jobs_and_why_they_wait():
    watch = _watch(0, [JobState("7", "RUNNING"), JobState("8", "PENDING", "Resources")])
    watch.poll()
    assert watch.status() == "0 worker(s); slurm jobs: 1 running, 1 pending (job 8: Resources)"


def test_status_before_any_job_is_submitted():
    watch = _watch(0, [], jobqueue=_jobqueue())
    watch.poll()
    assert watch.status() == "0 worker(s); slurm jobs: submitting"


def test_the_start_timeout_stops_with_the_jobs_and_their_reasons():
    clock = Clock()
    watch = _watch(0, PENDING, clock=clock)
    watch.poll()
    clock.now += 29.5
    watch.poll()
    watch.check()  # not yet
    clock.now += 1
    watch.poll()
    with pytest.raises(ShaderballError) as error:
        watch.check()
    assert str(error.value.labelled(label_for(BuildRequest))) == (
        "--start-timeout: no worker for 30 s since the build started; slurm jobs: 2 pending (job 7: "
        "PartitionDown, the partition is down; job 8: PartitionDown, the partition is down); the jobs are "
        "cancelled; what was rendered is kept: run the same command again to resume (a larger "
        "--start-timeout waits longer)"
    )


def test_the_clock_runs_only_while_there_is_no_worker():
    clock = Clock()
    watch = _watch([0, 1] + [0] * 8, PENDING, clock=clock)
    for step in (25, 10, 25, 4.5):  # 25 s without, a worker, then 29.5 s without again
        watch.poll()
        watch.check()
        clock.now += step
    watch.poll()
    watch.check()
    clock.now += 1
    with pytest.raises(ShaderballError, match=r"no worker for 30 s since the last one left"):
        watch.poll()
        watch.check()


def test_no_start_timeout_waits_for_ever():
    clock = Clock()
    watch = _watch(0, PENDING, options=_slurm(start_timeout=None), clock=clock)
    clock.now += 10**7
    watch.poll()
    watch.check()
    assert watch.status().startswith("0 worker(s); slurm jobs: 2 pending (job 7: PartitionDown")


def test_a_refused_job_stops_the_build_at_once():
    refusal = _refusal_text(
        "Command exited with non-zero exit code.\nExit code: 1\nCommand:\nsbatch /tmp/tmpab12cd.sh\nstdout:\n\n"
        "stderr:\nsbatch: error: invalid partition specified: nosuch\nsbatch: error: Batch job submission "
        "failed: Invalid partition name specified\n\n"
    )
    assert refusal == (
        "`sbatch JOB-SCRIPT` exited 1: sbatch: error: invalid partition specified: nosuch / "
        "sbatch: error: Batch job submission failed: Invalid partition name specified"
    )
    watch = _watch(0, [], jobqueue=_jobqueue(refusals=[refusal]))
    watch.poll()
    with pytest.raises(
        ShaderballError,
        match=r"^slurm: the batch system refused a job: `sbatch "
        r"JOB-SCRIPT` exited 1: sbatch: error: invalid partition",
    ):
        watch.check()


def test_a_failing_squeue_is_shown_not_fatal():
    def broken(ids):
        raise ShaderballError("`squeue --noheader` exited 1: slurm_load_jobs error: Unable to contact slurm controller")

    watch = WorkerWatch(lambda: 1, _slurm(), _jobqueue("7"), clock=Clock(), job_states=broken)
    watch.poll()
    watch.check()
    assert watch.status() == (
        "1 worker(s); slurm jobs unknown: `squeue --noheader` exited 1: slurm_load_jobs "
        "error: Unable to contact slurm controller"
    )


def test_pbs_jobs_are_counted_without_reasons():
    watch = WorkerWatch(
        lambda: 0,
        _slurm(cluster="pbs"),
        _jobqueue("12.pbs"),
        clock=Clock(),
        job_states=lambda ids: pytest.fail("no squeue for PBS"),
    )
    watch.poll()
    assert watch.status() == "0 worker(s); pbs jobs: 1 submitted"


def test_a_local_cluster_says_nothing_while_it_has_workers():
    watch = WorkerWatch(lambda: 2, ClusterOptions(), None, clock=Clock())
    watch.poll()
    assert watch.status() == ""


def test_describe_jobs_keeps_the_line_short():
    states = [JobState(str(i), "PENDING", "Priority") for i in range(5)] + [JobState("9", "RUNNING")]
    assert describe_jobs("slurm", states) == (
        "slurm jobs: 1 running, 5 pending (job 0: Priority; job 1: Priority; job 2: Priority; and 2 more)"
    )
    assert describe_jobs("slurm", []) == "slurm jobs: none in the queue"


@pytest.mark.parametrize(
    "changes,message",
    [
        ({"start_timeout": 9}, "start_timeout: 9 is not allowed; an integer from 10 to 10000000"),
        (
            {"cluster": "local", "cores": None, "memory": None, "walltime": None, "workers": 0},
            "start_timeout: not allowed with workers 0",
        ),
    ],
)
def test_bad_start_timeouts(changes, message):
    base = dict(cluster="slurm", cores=2, memory="4GiB", walltime="00:30:00", start_timeout=30)
    base.update(changes)
    with pytest.raises(ShaderballError, match=message):
        ClusterOptions(**base)


def test_squeue_output_is_read_for_our_jobs_only(tmp_path, monkeypatch):
    stand_in(
        tmp_path,
        "squeue",
        'echo "$@" > "$(dirname "$0")/args"\n'
        "printf '7|PENDING|PartitionDown\\n8|RUNNING|None\\n99|PENDING|Priority\\n'\n",
    )
    monkeypatch.setenv("PATH", f"{tmp_path}:{os.environ['PATH']}")
    assert slurm_job_states(["7", "8"]) == [JobState("7", "PENDING", "PartitionDown"), JobState("8", "RUNNING")]
    assert (tmp_path / "args").read_text().split() == ["--noheader", "--format=%i|%T|%r", f"--user={os.getuid()}"]
    stand_in(tmp_path, "squeue", "echo 'squeue: error: Unable to contact slurm controller' >&2; exit 1\n")
    with pytest.raises(
        ShaderballError,
        match=r"squeue --noheader --format=%i\|%T\|%r --user=\d+` exited 1: "
        r"squeue: error: Unable to contact slurm controller",
    ):
        slurm_job_states(["7"])


# Jobs that never start: sbatch queues them, squeue says PartitionDown, scancel removes them.
# dask-jobqueue submits and cancels jobs concurrently: one lock around each queue change.
PENDING_SBATCH = """exec 9>"$FAKE_SLURM_DIR/lock"; flock 9
n=$(( $(cat "$FAKE_SLURM_DIR/next" 2>/dev/null || echo 100) + 1 ))
echo $n > "$FAKE_SLURM_DIR/next"
echo $n >> "$FAKE_SLURM_DIR/queue"
echo "Submitted batch job $n"
"""
PENDING_SQUEUE = """echo "$@" >> "$FAKE_SLURM_DIR/squeue-calls"
while read -r job; do echo "$job|PENDING|PartitionDown"; done < "$FAKE_SLURM_DIR/queue"
"""
PENDING_SCANCEL = """exec 9>"$FAKE_SLURM_DIR/lock"; flock 9
for job in "$@"; do grep -vx "$job" "$FAKE_SLURM_DIR/queue" > "$FAKE_SLURM_DIR/q"; \
mv "$FAKE_SLURM_DIR/q" "$FAKE_SLURM_DIR/queue"; echo "$job" >> "$FAKE_SLURM_DIR/cancelled"; done
"""


@pytest.mark.slow
def test_a_build_whose_jobs_never_start_stops_at_the_start_timeout(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    scripts = {"sbatch": PENDING_SBATCH, "squeue": PENDING_SQUEUE, "scancel": PENDING_SCANCEL}
    env = stand_in_slurm(bin_dir, tmp_path, scripts)
    (tmp_path / "queue").touch()
    out = tmp_path / "ds"
    cmd = slurm_build_command(out, "--cores", "2", "--start-timeout", "10")
    # 300 s: ~12 s on 2 idle cores; only so a build that never stops fails instead of hanging
    result = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stdout + result.stderr
    assert "| 0 worker(s); slurm jobs: 2 pending (job 101: PartitionDown; job 102: PartitionDown)" in result.stderr
    assert (
        "error: --start-timeout: no worker for 10 s since the build started; slurm jobs: 2 pending (job "
        "101: PartitionDown, the partition is down; job 102: PartitionDown, the partition is down); the jobs "
        "are cancelled; what was rendered is kept"
    ) in result.stderr, result.stderr
    # It stopped at its timeout, counted, not timed (the start-up before the wait is the machine's):
    # the queue is looked at every QUEUE_POLL_S s of the wait and once more for the message, so
    # 10 s of waiting look at most 10 / 5 + 2 times (fewer on a busy machine); 40 s would look 9.
    calls = (tmp_path / "squeue-calls").read_text().splitlines()
    assert 1 <= len(calls) <= 10 / QUEUE_POLL_S + 2, calls
    assert (tmp_path / "queue").read_text().split() == []  # both cancelled
    assert sorted((tmp_path / "cancelled").read_text().split()) == ["101", "102"]
    assert {p.name for p in out.iterdir()} == {"spec.toml", "dataset.json"}


@pytest.mark.slow
def test_a_scheduler_without_workers_stops_at_the_start_timeout(tmp_path):
    procs = []
    try:
        address = start_scheduler(tmp_path, procs)
        build = ["build", "manifests/smoke.toml", "--out", str(tmp_path / "ds"), "--scheduler", address]
        cmd = [*SHADERBALL, *build, "--start-timeout", "10"]
        result = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    finally:
        for proc in procs:
            crash.kill_group(proc)
    assert result.returncode == 2, result.stdout + result.stderr
    assert "| waiting for a worker (none connected)" in result.stderr
    assert (
        "error: --start-timeout: no worker for 10 s since the build started; the scheduler has no worker; "
        "what was rendered is kept: run the same command again to resume"
    ) in result.stderr, result.stderr


@pytest.mark.slow
def test_a_temp_file_a_worker_killed_during_the_build_left_is_swept(tmp_path):
    """Seen on a real SLURM (a requeued job killed mid-write): the temp file of a write killed
    during the build, after its start, is gone when the build completes; the dataset validates."""
    from pipeline.run.build import build

    out = tmp_path / "ds"
    left = []

    def progress(p):
        if p.done and not left:
            left.append(next(out.glob("shards/s*")) / f"{TEMP_PREFIX}killed-m000000_l0.json")
            left[0].write_text("{")

    summary = build(
        str(REPO / "manifests" / "smoke.toml"), str(out), cluster=ClusterOptions(workers=0), progress=progress
    )
    assert left and not left[0].exists()
    assert summary.temp_removed == 1
    assert validate(str(out)).ok
