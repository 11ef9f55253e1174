"""What a build waits on while it has no worker: its batch jobs (``squeue``) and the clock
of ``--start-timeout``. No dask here: the connection (:mod:`pipeline.run.cluster.connection`)
hands in a function that counts the workers and the jobqueue cluster whose jobs to look up.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass

from pipeline.errors import ShaderballError
from pipeline.run.cluster.options import ClusterOptions

#: Seconds between two looks at the batch system's queue (squeue) while a build runs.
QUEUE_POLL_S = 5.0


#: Plain words for SLURM's commonest reasons a job waits (`man squeue`, JOB REASON CODES).
SLURM_REASONS = {
    "PartitionDown": "the partition is down",
    "PartitionInactive": "the partition is inactive",
    "ReqNodeNotAvail": "the nodes it needs are down, drained or reserved",
    "Resources": "waiting for free nodes",
    "Priority": "jobs of higher priority go first",
    "PartitionTimeLimit": "--walltime is above the partition's limit",
    "PartitionNodeLimit": "more nodes than the partition allows",
    "JobHeldAdmin": "held by an administrator",
    "JobHeldUser": "held by its user",
}


@dataclass(frozen=True)
class JobState:
    """A batch job as the batch system reports it."""

    job_id: str
    #: the batch system's word, e.g. SLURM's PENDING, RUNNING, COMPLETING.
    state: str
    #: why a pending job waits: SLURM's reason code (PartitionDown, Resources, Priority, ...).
    reason: str = ""


def slurm_job_states(job_ids: list[str]) -> list[JobState]:
    """``job_ids`` as ``squeue`` lists them; jobs it no longer lists (ended) are left out.

    Raises ShaderballError naming the command, its exit code and output when squeue fails.
    """
    squeue = shutil.which("squeue") or "squeue"
    command = [squeue, "--noheader", "--format=%i|%T|%r", f"--user={os.getuid()}"]
    try:
        result = subprocess.run(command, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise ShaderballError(f"`{' '.join(command)}` failed: {exc}") from None
    if result.returncode != 0:
        output = " ".join((result.stderr or result.stdout).split()) or "no output"
        raise ShaderballError(f"`{' '.join(command)}` exited {result.returncode}: {output}")
    wanted, states = set(job_ids), []
    for line in result.stdout.splitlines():
        fields = line.strip().split("|", 2)
        if len(fields) == 3 and fields[0] in wanted:
            reason = "" if fields[2] in ("None", "(null)") else fields[2]
            states.append(JobState(fields[0], fields[1], reason))
    return states


def describe_jobs(kind: str, states: list[JobState], limit: int = 3, explain: bool = False) -> str:
    """'slurm jobs: 1 running, 2 pending (job 7: PartitionDown; job 8: Resources)'; ``explain``
    adds plain words to the reasons SLURM_REASONS knows."""
    if not states:
        return f"{kind} jobs: none in the queue"
    counts: dict[str, int] = {}
    for job in sorted(states, key=lambda job: (job.state != "RUNNING", job.state != "PENDING", job.state)):
        counts[job.state.lower()] = counts.get(job.state.lower(), 0) + 1
    text = f"{kind} jobs: " + ", ".join(f"{n} {state}" for state, n in counts.items())
    waiting = [
        f"job {job.job_id}: {job.reason}"
        + (f", {SLURM_REASONS[job.reason]}" if explain and job.reason in SLURM_REASONS else "")
        for job in states
        if job.reason
    ]
    if waiting:
        more = f"; and {len(waiting) - limit} more" if len(waiting) > limit else ""
        text += f" ({'; '.join(waiting[:limit])}{more})"
    return text


class WorkerWatch:
    """What a build waits on, and how long it has had no worker at all.

    ``workers()`` counts the workers connected to the scheduler. For ``--cluster slurm`` the
    build's jobs are looked up with ``squeue`` every QUEUE_POLL_S seconds, so the progress
    line shows them pending and why; PBS jobs are counted as submitted (no qstat parsing).
    The clock of ``--start-timeout`` runs while no worker is connected: from the start until
    the first worker arrives, and again from when the last one leaves until a replacement
    arrives. A job the batch system refused stops the build at once (dask-jobqueue would
    never submit it again).
    """

    def __init__(
        self,
        workers: Callable[[], int],
        options: ClusterOptions,
        jobqueue=None,
        clock: Callable[[], float] = time.monotonic,
        job_states=slurm_job_states,
    ):
        self._workers, self.options, self.jobqueue = workers, options, jobqueue
        self.clock, self.job_states = clock, job_states
        self.workers = 0
        self.seen_worker = False
        #: start of the current spell without any worker; None while there are workers.
        self.without_since: float | None = clock()
        self.jobs: list[JobState] | None = None
        self.queue_error = ""
        self._next_queue_poll = 0.0

    def job_ids(self) -> list[str]:
        if self.jobqueue is None:
            return []
        for _ in range(3):  # the cluster's event loop may change the dict meanwhile
            try:
                return [str(job.job_id) for job in list(self.jobqueue.workers.values()) if getattr(job, "job_id", None)]
            except RuntimeError:
                continue
        return []

    def poll(self) -> None:
        now = self.clock()
        before, self.workers = self.workers, self._workers()
        if self.workers:
            self.without_since, self.seen_worker = None, True
        elif self.without_since is None:
            self.without_since = now
        if self.jobqueue is not None and (now >= self._next_queue_poll or self.workers != before):
            self._next_queue_poll = now + QUEUE_POLL_S
            ids = self.job_ids()
            if self.options.cluster != "slurm":
                self.jobs = [JobState(job_id, "submitted") for job_id in ids]
            elif ids:
                try:
                    self.jobs, self.queue_error = self.job_states(ids), ""
                except ShaderballError as exc:
                    self.queue_error = str(exc)
            else:
                self.jobs = None  # none submitted yet

    def refusals(self) -> list[str]:
        return list(getattr(getattr(self.jobqueue, "job_cls", None), "refusals", None) or [])

    def status(self) -> str:
        """For the progress line, e.g. '1 worker(s); slurm jobs: 1 running, 1 pending (job 8:
        Resources)'; '' for a local cluster or scheduler that has workers."""
        if self.jobqueue is None:
            return "" if self.workers else "waiting for a worker (none connected)"
        return f"{self.workers} worker(s); {self.jobs_text()}"

    def jobs_text(self, explain: bool = False) -> str:
        if self.queue_error:
            return f"{self.options.cluster} jobs unknown: {self.queue_error}"
        if self.jobs is None:
            return f"{self.options.cluster} jobs: submitting"
        return describe_jobs(self.options.cluster, self.jobs, explain=explain)

    def check(self) -> None:
        """Raise ShaderballError on a refused job or when --start-timeout has run out."""
        refused = self.refusals()
        if refused:
            raise ShaderballError(
                f"{self.options.cluster}: the batch system refused a job: {refused[0]} "
                "(JOB-SCRIPT is what --print-job-script prints). Check --queue, --account, --cores, "
                "--memory and --walltime against the cluster's limits; what was rendered is kept: "
                "run the same command again to resume"
            )
        limit = self.options.start_timeout
        if limit is None or self.without_since is None or self.clock() - self.without_since < limit:
            return
        since = "since the last one left" if self.seen_worker else "since the build started"
        if self.jobqueue is not None:
            self._next_queue_poll = 0.0
            self.poll()  # the queue as it is now, for the message
            if self.without_since is None:
                return
            why = self.jobs_text(explain=True)
            then = "The jobs are cancelled; what"
        else:
            why = "the scheduler has no worker" if self.options.scheduler else "no local worker started"
            then = "What"
        raise ClusterOptions.field_error(
            "start_timeout",
            limit,
            f"{then.lower()} was rendered is kept: run the same command again to resume "
            "(a larger {start_timeout} waits longer)",
            what=f"no worker for {limit} s {since}; {why}",
        )
