"""`shaderball build --cluster slurm` against a real SLURM on this machine (docs/cluster.md,
"Measured on a real SLURM").

The module starts munged, slurmctld and two slurmd (nodes sb1 and sb2, both this host, each
with all its CPUs: ``support.slurm``) in a temporary folder and stops them, and every process
of their jobs, at the end, even when a test fails or times out. Without Debian's
`slurm-wlm`/`munge` or root, every test is skipped with the reason (`make setup` installs them
where it can). Cases: a plain build; a job cancelled mid-build; a job SLURM kills at its
walltime while the other job's worker retires before it; a node drained mid-build with its
job requeued; jobs that cannot start (partition down) under --start-timeout, at the start and
as a replacement; a job sbatch refuses. Each build is checked byte for byte against an in-process build and validated.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest
from conftest import crash_module

from support.clusters import SHADERBALL
from support.slurm import LocalSlurm, die_with_parent, unavailable_reason

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
UNAVAILABLE = unavailable_reason()
pytestmark = [pytest.mark.slow, pytest.mark.skipif(UNAVAILABLE is not None, reason=UNAVAILABLE or "")]

crash = crash_module()


@pytest.fixture(scope="module")
def slurm():
    cluster = LocalSlurm(nodes=2)
    try:
        cluster.start()
        yield cluster
    finally:
        cluster.stop()
        left = cluster.processes()
        cluster.cleanup()
        assert not left, f"processes of the test SLURM survived its stop: {left}"


@pytest.fixture
def idle(slurm):
    """The cluster with no job, both nodes idle and the partition up, before and after a test."""
    _wait_idle(slurm)
    yield slurm
    slurm.scontrol("update", f"PartitionName={slurm.partition}", "State=UP", check=False)
    for name in slurm.node_names:
        if slurm.node_state(name).startswith(("drain", "down")):
            slurm.scontrol("update", f"NodeName={name}", "State=RESUME", check=False)
    slurm.run("scancel", "--user", str(os.getuid()), check=False)
    _wait_idle(slurm)


def _wait_idle(slurm, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while slurm.queue() or any(slurm.node_state(n) != "idle" for n in slurm.node_names):
        assert time.monotonic() < deadline, f"test SLURM not idle: {slurm.queue()}\n{slurm.logs_tail()}"
        time.sleep(0.5)


class Build:
    """`shaderball build --cluster slurm` as a child process (its own process group, killed at the end)."""

    def __init__(self, slurm: LocalSlurm, tmp_path: Path, out: Path, *options: str):
        self.out, self.cwd = out, tmp_path
        # --scratch: each test's jobs compile their kernels afresh, in a folder pytest removes.
        self.command = [
            *SHADERBALL,
            "build",
            str(SMOKE),
            "--out",
            str(out),
            "--cluster",
            "slurm",
            "--queue",
            slurm.partition,
            "--memory",
            "2GiB",
            "--scratch",
            str(tmp_path / "scratch"),
            *options,
        ]
        self.stdout, self.stderr = tmp_path / "build.out", tmp_path / "build.err"
        # cwd: the jobs' slurm-<id>.out files land where sbatch runs.
        self.proc = subprocess.Popen(
            self.command,
            cwd=tmp_path,
            env=slurm.env,
            stdin=subprocess.DEVNULL,
            stdout=open(self.stdout, "w"),
            stderr=open(self.stderr, "w"),
            start_new_session=True,
            preexec_fn=die_with_parent,
        )

    def wait(self, timeout_s: float = 600.0) -> int:
        """The build's exit code; ``timeout_s`` only gives up on a build that never ends (a plain
        build takes ~30 s on 2 idle cores, the walltime case ~3 min)."""
        try:
            self.proc.wait(timeout=timeout_s)
        finally:
            if self.proc.poll() is None:
                crash.kill_group(self.proc)
        return self.proc.returncode

    def output(self) -> str:
        return self.stdout.read_text(errors="replace") + self.stderr.read_text(errors="replace")

    def job_logs(self) -> str:
        return "\n".join(
            f"--- {p.name}\n{p.read_text(errors='replace')[-1500:]}" for p in sorted(self.cwd.glob("slurm-*.out"))
        )

    def explain(self, slurm: LocalSlurm) -> str:
        return f"{' '.join(self.command)}\n{self.output()}\n{self.job_logs()}\n{slurm.logs_tail(1500)}"

    def records(self) -> int:
        return len(list(self.out.glob("shards/*/m*_l*.json")))

    def until(self, condition, what: str, slurm: LocalSlurm, timeout_s: float = 300.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not condition():
            assert self.proc.poll() is None, f"build ended before {what}:\n{self.explain(slurm)}"
            assert time.monotonic() < deadline, f"no {what} within {timeout_s:.0f} s:\n{self.explain(slurm)}"
            time.sleep(0.2)


@pytest.fixture
def builds():
    started: list[Build] = []
    yield started
    for build in started:
        if build.proc.poll() is None:
            crash.kill_group(build.proc)


def _run(builds, *args) -> Build:
    build = Build(*args)
    builds.append(build)
    return build


def _running(slurm) -> list[str]:
    return [job for job, state, _ in slurm.queue() if state == "RUNNING"]


def _job_processes(slurm, job_id: str) -> list[int]:
    """This cluster's processes of job ``job_id`` (the job script, dask's nanny and worker)."""
    marker = f"SLURM_JOB_ID={job_id}".encode()
    pids = []
    for pid in slurm.processes():
        with contextlib.suppress(OSError):
            if marker in Path(f"/proc/{pid}/environ").read_bytes().split(b"\0"):
                pids.append(pid)
    return pids


def _job_log(folder: Path, job_id: str) -> str:
    path = folder / f"slurm-{job_id}.out"
    return path.read_text(errors="replace") if path.exists() else ""


def _seconds(duration: str) -> int:
    """SLURM's [DAYS-]HH:MM:SS (RunTime, TimeLimit) in seconds."""
    days, _, hhmmss = duration.rpartition("-")
    parts = [int(p) for p in hhmmss.split(":")]
    return int(days or 0) * 86400 + sum(v * 60**i for i, v in enumerate(reversed(parts)))


def _epoch(timestamp: str) -> float:
    """SLURM's local-time YYYY-MM-DDTHH:MM:SS (StartTime, EndTime) as seconds since the epoch."""
    return datetime.datetime.fromisoformat(timestamp).timestamp()


def _log_times(log: str, text: str) -> list[float]:
    """When a job's dask log (local time, ``2026-01-01 10:00:00,123 - ...``) says ``text``."""
    return [
        datetime.datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
        for line in log.splitlines()
        if text in line and re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} ", line)
    ]


def test_plain_build_is_identical_to_an_in_process_build(idle, builds, reference, tmp_path):
    slurm = idle
    build = _run(builds, slurm, tmp_path, tmp_path / "ds", "--jobs", "1", "--cores", "2", "--walltime", "00:30:00")
    assert build.wait() == 0, build.explain(slurm)
    out = build.output()
    assert "building with slurm cluster, 1 job(s) of 2 cores, 2GiB" in out
    assert re.search(r"\| 1 worker\(s\); slurm jobs: 1 running", out), out
    jobs = slurm.jobs()
    assert len(jobs) >= 1 and list(tmp_path.glob("slurm-*.out")), build.explain(slurm)
    crash.check_complete(build.out, reference)


def test_a_cancelled_job_is_replaced_and_the_build_completes(idle, builds, reference, tmp_path):
    slurm = idle
    before = set(slurm.jobs())
    build = _run(builds, slurm, tmp_path, tmp_path / "ds", "--jobs", "1", "--cores", "2", "--walltime", "00:30:00")
    build.until(lambda: build.records() >= 1 and _running(slurm), "first record", slurm)
    (first,) = _running(slurm)
    slurm.run("scancel", first)
    cancelled_at = build.records()
    assert build.wait() == 0, build.explain(slurm)
    jobs = {k: v for k, v in slurm.jobs().items() if k not in before}
    assert jobs[first]["JobState"] == "CANCELLED", jobs[first]
    replacements = [k for k in jobs if int(k) > int(first)]
    assert replacements, f"no job replaced the cancelled one: {jobs}"
    assert cancelled_at < 16, "the build had finished before the cancel"
    assert re.search(r"\| 0 worker\(s\); slurm jobs: ", build.output()), build.output()
    crash.check_complete(build.out, reference)


def test_walltime_kills_a_hung_job_while_the_other_worker_retires_before_it(idle, builds, reference, tmp_path):
    """--walltime 00:02:00: workers retire 30-90 s after they start (lifetime 60 s +- 30 s), so
    before the limit however loaded the machine, unless a worker takes 30 s to start (1.6 s on 2
    idle cores; with 00:01:00's 15 s margin a busy machine's start-up used it all). One job's
    processes are stopped (SIGSTOP, a hung worker) while it holds shards, so only SLURM's time
    limit ends that job. Both workers hold shards once both are connected and none is complete:
    each takes two of the four at once (dask's worker-saturation 1.1 of one thread). Checked
    against what SLURM and the workers recorded (each job's own time limit and end, the
    workers' logs), not the test's clock: SLURM enforces a limit only at its next check (a hung
    job ran 87 s of its 60)."""
    slurm = idle
    before = set(slurm.jobs())
    build = _run(builds, slurm, tmp_path, tmp_path / "ds", "--jobs", "2", "--cores", "1", "--walltime", "00:02:00")
    build.until(lambda: "| 2 worker(s)" in build.output() and len(_running(slurm)) == 2, "two workers", slurm)
    assert not list(build.out.glob("shards/*/COMPLETE.json")), "a shard was complete before the hang"
    hung = _running(slurm)[0]
    pids = _job_processes(slurm, hung)
    assert pids, f"no processes of job {hung} found"
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGSTOP)
    assert build.wait() == 0, build.explain(slurm)
    jobs = {k: v for k, v in slurm.jobs().items() if k not in before}
    # The hung job ran its whole time limit and SLURM killed it; the build waited for that: the
    # shards it held were completed by another worker after it ended.
    assert jobs[hung]["JobState"] == "TIMEOUT", (jobs[hung], build.explain(slurm))
    assert _seconds(jobs[hung]["RunTime"]) >= _seconds(jobs[hung]["TimeLimit"]), jobs[hung]
    assert "DUE TO TIME LIMIT" in _job_log(tmp_path, hung)
    completed = [p.stat().st_mtime for p in build.out.glob("shards/*/COMPLETE.json")]
    assert max(completed) > _epoch(jobs[hung]["EndTime"]), "the build did not wait for the hung job"
    # Another job's worker retired at its lifetime, before SLURM's limit ended its job, and left
    # less than the job's own time limit after it started.
    retired = [
        k
        for k, j in jobs.items()
        if k != hung
        and j["JobState"] != "TIMEOUT"
        and "Reason: worker-lifetime-reached" in _job_log(tmp_path, k)
        and "DUE TO TIME LIMIT" not in _job_log(tmp_path, k)
    ]
    assert retired, f"no worker retired before its walltime: {[(k, j['JobState']) for k, j in jobs.items()]}"
    for job in retired:
        log = _job_log(tmp_path, job)
        started, left = _log_times(log, "Registered to:"), _log_times(log, "Reason: worker-lifetime-reached")
        assert started and left, log[-1500:]
        assert 0 < left[0] - started[0] < _seconds(jobs[job]["TimeLimit"]), (left[0] - started[0], jobs[job])
    crash.check_complete(build.out, reference)


def test_a_node_drained_mid_build_with_its_job_requeued(idle, builds, reference, tmp_path):
    """Two jobs of 2 cores, one per node. Node sb2 is drained (no new jobs) and its job requeued,
    as an administrator empties a node: the job waits (BeginTime, then Resources: sb1 is busy),
    the progress line says so, and the build completes on sb1."""
    slurm = idle
    build = _run(builds, slurm, tmp_path, tmp_path / "ds", "--jobs", "2", "--cores", "2", "--walltime", "00:30:00")
    build.until(lambda: build.records() >= 1 and len(_running(slurm)) == 2, "first record on two nodes", slurm)
    node_of = {k: j["NodeList"] for k, j in slurm.jobs().items() if j["JobState"] == "RUNNING"}
    job, node = next((k, n) for k, n in node_of.items() if n == "sb2")
    slurm.scontrol("update", "NodeName=sb2", "State=DRAIN", "Reason=shaderball-test")
    assert slurm.node_state("sb2") in ("draining", "drng"), slurm.node_state("sb2")
    assert slurm.jobs()[job]["JobState"] == "RUNNING"  # a drain alone lets the job run on
    slurm.scontrol("requeue", job)
    assert build.wait() == 0, build.explain(slurm)
    assert slurm.jobs()[job]["Restarts"] == "1"
    assert slurm.node_state("sb2") == "drained"
    assert re.search(rf"\| 1 worker\(s\); slurm jobs: 1 running, 1 pending \(job {job}: \w+", build.output()), (
        build.output()
    )
    crash.check_complete(build.out, reference)


def test_jobs_that_cannot_start_stop_the_build_at_the_start_timeout_and_it_resumes(idle, builds, reference, tmp_path):
    slurm = idle
    slurm.scontrol("update", f"PartitionName={slurm.partition}", "State=DOWN")
    options = ("--jobs", "2", "--cores", "2", "--walltime", "00:30:00", "--start-timeout", "15")
    build = _run(builds, slurm, tmp_path, tmp_path / "ds", *options)
    # How long it waits is counted in tests/test_cluster_wait.py (the queue's looks, not a clock).
    assert build.wait() == 2, build.explain(slurm)
    out = build.output()
    ids = re.findall(r"job (\d+): PartitionDown, the partition is down", out)
    assert len(ids) == 2, out
    assert (
        "error: --start-timeout: no worker for 15 s since the build started; slurm jobs: 2 pending "
        f"(job {ids[0]}: PartitionDown, the partition is down; job {ids[1]}: PartitionDown, the "
        "partition is down); the jobs are cancelled; what was rendered is kept: run the same command "
        "again to resume"
    ) in out, out
    assert re.search(
        r"\| 0 worker\(s\); slurm jobs: 2 pending \(job \d+: PartitionDown; job \d+: PartitionDown\)", out
    ), out
    assert "Traceback" not in out
    assert slurm.queue() == [], "the build left its jobs queued"
    assert {p.name for p in build.out.iterdir()} == {"spec.toml", "dataset.json"}

    slurm.scontrol("update", f"PartitionName={slurm.partition}", "State=UP")
    again = _run(builds, slurm, tmp_path, tmp_path / "ds", *options)
    assert again.wait() == 0, again.explain(slurm)
    crash.check_complete(again.out, reference)


def test_a_replacement_that_cannot_start_stops_the_build_and_it_resumes(idle, builds, reference, tmp_path):
    """The partition goes down and the only job is cancelled mid-build: its replacement pends, and
    --start-timeout counts from the moment the last worker left. The samples committed stay."""
    slurm = idle
    options = ("--jobs", "1", "--cores", "2", "--walltime", "00:30:00", "--start-timeout", "20")
    build = _run(builds, slurm, tmp_path, tmp_path / "ds", *options)
    build.until(lambda: build.records() >= 1 and _running(slurm), "first record", slurm)
    slurm.scontrol("update", f"PartitionName={slurm.partition}", "State=DOWN")
    slurm.run("scancel", *_running(slurm))
    assert build.wait() == 2, build.explain(slurm)
    out = build.output()
    assert re.search(
        r"error: --start-timeout: no worker for 20 s since the last one left; slurm jobs: 1 pending "
        r"\(job \d+: PartitionDown, the partition is down\); the jobs are cancelled; what was rendered "
        r"is kept",
        out,
    ), out
    kept = build.records()
    assert 1 <= kept < 16
    assert slurm.queue() == []

    slurm.scontrol("update", f"PartitionName={slurm.partition}", "State=UP")
    again = _run(builds, slurm, tmp_path, tmp_path / "ds", *options)
    assert again.wait() == 0, again.explain(slurm)
    assert f"rendered {16 - kept}, already present {kept}" in again.output()
    crash.check_complete(again.out, reference)


def test_a_job_sbatch_refuses_stops_the_build_at_once(idle, builds, tmp_path):
    slurm = idle
    build = _run(
        builds,
        slurm,
        tmp_path,
        tmp_path / "ds",
        "--jobs",
        "1",
        "--cores",
        "2",
        "--walltime",
        "00:30:00",
        "--queue",
        "nosuch",
    )
    assert build.wait() == 2, build.explain(slurm)  # without the refusal it would wait for ever
    out = build.output()
    assert (
        "error: slurm: the batch system refused a job: `sbatch JOB-SCRIPT` exited 1: sbatch: error: "
        "invalid partition specified: nosuch"
    ) in out, out
    assert "Traceback" not in out


def test_gpu_jobs_ask_for_gres_and_pin_each_worker_to_one_of_the_jobs_gpus(idle, builds, reference, tmp_path):
    """--gpus-per-job 2 on the test SLURM's `gpu` GRES (no hardware; llvm renders): the job asks
    for gpu:2, runs two workers, each with its own CUDA_VISIBLE_DEVICES, and the dataset is the
    in-process one byte for byte."""
    slurm = idle
    before = set(slurm.jobs())
    build = _run(
        builds, slurm, tmp_path, tmp_path / "ds", "--jobs", "1", "--cores", "2", "--walltime", "00:30:00",
        "--gpus-per-job", "2",
    )  # fmt: skip
    assert build.wait() == 0, build.explain(slurm)
    jobs = {job_id: job for job_id, job in slurm.jobs().items() if job_id not in before}
    assert jobs and all("gpu:2" in str(job) for job in jobs.values()), jobs
    out = build.output()
    assert re.search(r"renders per GPU: GPU 0: \d+ \([\d.]+/s\), GPU 1: \d+", out), build.explain(slurm)
    crash.check_complete(build.out, reference)
