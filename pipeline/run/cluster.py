"""Where a build's dask workers come from, how long they live, and what memory they use.

:mod:`pipeline.run.build` submits one task per shard; this module gives it the client to submit
to (with :mod:`pipeline.run.build`, the only code that knows about dask):

- ``local`` (the default): a ``LocalCluster`` of spawned worker processes on this machine;
- an existing scheduler (``--scheduler tcp://HOST:PORT``) with workers started by hand;
- ``slurm`` / ``pbs``: a dask-jobqueue cluster, one batch job per node, each job one worker
  process with one dask thread (one shard at a time) whose Mitsuba renders use every core
  of the job.

Worker memory is bounded twice: the nanny restarts a worker whose memory passes 95 % of its
limit (its unfinished shard runs again), and ``recycle_after`` restarts a worker process,
between shards, once it has rendered that many samples (Mitsuba's memory grows slowly when
it renders in a long loop; docs/cluster.md has the measurement). Re-running a shard is safe
because shard tasks are idempotent (:mod:`pipeline.run.shard`).

``python -m pipeline.run.cluster --memory-probe 200`` re-measures the growth.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from pipeline.errors import ShaderballError, caused_by_interrupt, check_int
from pipeline.run.shard import run_shard_in_process

KINDS = ("local", "slurm", "pbs")
JOBQUEUE_KINDS = ("slurm", "pbs")
#: Environment variable telling a worker how many threads its Mitsuba renders use.
RENDER_THREADS_ENV = "SHADERBALL_RENDER_THREADS"
#: drjit's kernel-cache location (default ``$HOME/.drjit``, shared over NFS on most clusters).
KERNEL_CACHE_ENV = "DRJIT_CACHE_DIR"
#: The worker's memory limit, as a share of the job's memory: the nanny restarts the worker
#: (at 95 % of its limit) before the batch system's cgroup kills the whole job at 100 %.
WORKER_MEMORY_SHARE = 0.9
#: Default of ``--recycle-after``: renders per worker process before it is restarted. Measured
#: growth is ~7 MiB per 100 renders at 400x400 (docs/cluster.md): at most ~140 MiB, for a
#: restart (~5-10 s) every ~2.5 h of paper-size rendering.
DEFAULT_RECYCLE_AFTER = 2000
#: Shell expression for node-local scratch space, the default of ``--scratch``.
DEFAULT_SCRATCH = "${TMPDIR:-/tmp}"
#: The job id in each batch system's environment (for per-job scratch folders).
JOB_ID_VARIABLE = {"slurm": "${SLURM_JOB_ID:-$$}", "pbs": "${PBS_JOBID:-$$}"}

_WALLTIME = re.compile(r"^(\d{1,4}):([0-5]\d):([0-5]\d)\Z", re.ASCII)
_SHELL_WORD = re.compile(r"^[A-Za-z0-9_.@:+-]{1,128}\Z", re.ASCII)
_SCRATCH = re.compile(r"^[A-Za-z0-9_./${}:+-]{1,256}\Z", re.ASCII)
_MIN_WALLTIME_S = 60
#: --start-timeout's range in seconds: below 10 s not even a local worker process starts.
START_TIMEOUT_RANGE = (10, 10_000_000)
#: Seconds between two looks at the batch system's queue (squeue) while a build runs.
QUEUE_POLL_S = 5.0
_MIN_MEMORY, _MAX_MEMORY = 256 * 2**20, 64 * 2**40


@dataclass(frozen=True)
class ClusterOptions:
    """Where the workers of a build come from (the ``build`` command's cluster options).

    Options of another kind of cluster left at None; :meth:`check` refuses a mix.
    """

    kind: str = "local"
    #: local worker processes (default: one per 2 cores); 0 renders in this process.
    workers: int | None = None
    #: address of an existing scheduler, e.g. tcp://10.0.0.1:8786 (kind "local" only).
    scheduler: str | None = None
    #: batch jobs (= nodes) for slurm/pbs; each runs one worker process.
    jobs: int | None = None
    #: cores per job (slurm/pbs): every render of the job's worker uses them all.
    cores: int | None = None
    #: memory per worker process (local) or per job (slurm/pbs), e.g. "16GiB".
    memory: str | None = None
    #: wall-clock limit per job, HH:MM:SS (slurm/pbs).
    walltime: str | None = None
    queue: str | None = None
    account: str | None = None
    #: node-local scratch folder (shell expression) for the kernel cache and dask's spill.
    scratch: str | None = None
    #: restart a worker process once it has rendered this many samples; 0: never.
    recycle_after: int = DEFAULT_RECYCLE_AFTER
    #: seconds the build may go without any worker (before the first one arrives, or after
    #: the last one left) before it stops; None: wait as long as it takes.
    start_timeout: int | None = None

    @property
    def is_jobqueue(self) -> bool:
        return self.kind in JOBQUEUE_KINDS

    def check(self) -> ClusterOptions:
        """Return self, or raise a ShaderballError naming the option, value and what's allowed."""
        if self.kind not in KINDS:
            raise ShaderballError(f"--cluster: {self.kind!r} is not allowed; allowed: {', '.join(KINDS)}")
        check_int("--workers", self.workers, 0, 1024)
        check_int("--jobs", self.jobs, 1, 10000)
        check_int("--cores", self.cores, 1, 1024)
        check_int("--recycle-after", self.recycle_after, 0, 10_000_000)
        check_int("--start-timeout", self.start_timeout, *START_TIMEOUT_RANGE)
        if self.start_timeout is not None and self.workers == 0 and not self.scheduler:
            raise ShaderballError("--start-timeout: not allowed with --workers 0 (no workers to wait for)")
        if self.memory is not None:
            memory_bytes(self.memory)
        if self.walltime is not None:
            walltime_seconds(self.walltime)
        for option, value in (("--queue", self.queue), ("--account", self.account)):
            if value is not None and not _SHELL_WORD.match(value):
                raise ShaderballError(
                    f"{option}: {value!r} is not allowed; allowed: 1 to 128 characters from A-Z a-z 0-9 _ . @ : + -"
                )
        if self.scratch is not None and not _SCRATCH.match(self.scratch):
            raise ShaderballError(
                f"--scratch: {self.scratch!r} is not allowed; allowed: a path of "
                "1 to 256 characters from A-Z a-z 0-9 _ . / $ { } : + - "
                "(shell variables such as $TMPDIR are expanded on the node)"
            )
        if self.scheduler is not None:
            if self.kind != "local":
                raise ShaderballError(f"--scheduler: not allowed with --cluster {self.kind}; use one or the other")
            scheduler_host_port(self.scheduler)
        if self.is_jobqueue:
            if self.workers is not None:
                raise ShaderballError(
                    f"--workers: not allowed with --cluster {self.kind}; use --jobs (one worker process per job)"
                )
            for option, value, example in (
                ("--cores", self.cores, "--cores 32"),
                ("--memory", self.memory, "--memory 64GiB"),
                ("--walltime", self.walltime, "--walltime 12:00:00"),
            ):
                if value is None:
                    raise ShaderballError(f"{option}: required with --cluster {self.kind}; for example: {example}")
        else:
            for option, value in (
                ("--jobs", self.jobs),
                ("--cores", self.cores),
                ("--walltime", self.walltime),
                ("--queue", self.queue),
                ("--account", self.account),
                ("--scratch", self.scratch),
            ):
                if value is not None:
                    raise ShaderballError(f"{option}: only with --cluster slurm or --cluster pbs")
            if self.scheduler is not None and self.memory is not None:
                raise ShaderballError(
                    "--memory: not allowed with --scheduler; give --memory-limit to `dask worker` instead"
                )
        return self


def memory_bytes(text: str) -> int:
    """``--memory`` in bytes (dask's units: 16GiB, 16GB, 16000MB), checked."""
    from dask.utils import parse_bytes

    try:
        value = parse_bytes(text)
    except (ValueError, TypeError):
        value = None
    if value is None or not _MIN_MEMORY <= value <= _MAX_MEMORY:
        raise ShaderballError(
            f"--memory: {text!r} is not allowed; allowed: an amount from 256MiB to "
            "64TiB with a unit, e.g. 16GiB or 64GB"
        )
    return int(value)


def walltime_seconds(text: str) -> int:
    match = _WALLTIME.match(text)
    seconds = None if match is None else int(match[1]) * 3600 + int(match[2]) * 60 + int(match[3])
    if seconds is None or seconds < _MIN_WALLTIME_S:
        raise ShaderballError(f"--walltime: {text!r} is not allowed; allowed: HH:MM:SS from 00:01:00 to 9999:59:59")
    return seconds


def worker_lifetime(walltime: str) -> tuple[int, int]:
    """(lifetime, stagger) in seconds: workers retire before the batch system kills the job.

    A worker that retires hands its queued shards back; jobqueue's adaptive scaling then
    submits a fresh job. The margin (5 minutes or 5 % of the walltime, the larger, but at
    most half of it for walltimes under 10 minutes) leaves the running shard time to finish
    or be handed back cleanly. dask staggers each worker's lifetime by up to +-stagger, so a
    worker retires between 1.5 and 0.5 margins before the walltime.
    """
    total = walltime_seconds(walltime)
    margin = min(max(300, total // 20), total // 2)
    return total - margin, margin // 2


def scheduler_host_port(address: str) -> tuple[str, int]:
    match = re.match(r"^(?:tcp|tls)://(\[[0-9A-Fa-f:]+\]|[A-Za-z0-9_.-]+):(\d{1,5})\Z", address, re.ASCII)
    if match is None or not 0 < int(match[2]) < 65536:
        raise ShaderballError(
            f"--scheduler: {address!r} is not allowed; allowed: tcp://HOST:PORT or "
            "tls://HOST:PORT, e.g. tcp://10.0.0.1:8786"
        )
    return match[1].strip("[]"), int(match[2])


def check_scheduler_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast with a clear message when nothing listens at ``address``."""
    host, port = scheduler_host_port(address)
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        raise ShaderballError(
            f"--scheduler: cannot reach {address!r} ({exc.strerror or exc}); is `dask scheduler` running there?"
        ) from None


# --------------------------------------------------------------------------- jobqueue


def _jobqueue_job_class(kind: str):
    """dask-jobqueue's Job class of ``kind``, changed to one dask thread per worker process."""
    try:
        if kind == "slurm":
            from dask_jobqueue.slurm import SLURMJob as base
        else:
            from dask_jobqueue.pbs import PBSJob as base
    except ImportError:
        raise ShaderballError(
            f"--cluster {kind}: needs dask-jobqueue; install it with `pip install dask-jobqueue`"
        ) from None

    class ShaderballJob(base):
        #: Submissions the batch system refused (sbatch/qsub's exit code and output), read by
        #: the build's WorkerWatch. dask-jobqueue never retries a refused job: the build
        #: stops on the first refusal.
        refusals: list[str] = []

        async def start(self):
            try:
                await super().start()
            except Exception as exc:
                # Recorded for the build to stop on, not raised: raised, it is printed as a
                # traceback by the event loop and leaves a job that fails the cluster's close.
                from distributed.core import Status

                type(self).refusals.append(_refusal_text(str(exc)))
                self.status = Status.running  # a job without an id: closing it cancels nothing

        # One shard at a time per worker process; its renders use all the job's cores.
        @property
        def worker_process_threads(self):
            return 1

        # Below the job's memory, so the nanny restarts the worker before the batch
        # system's cgroup kills the job.
        @property
        def worker_process_memory(self):
            from dask.utils import format_bytes

            share = WORKER_MEMORY_SHARE * self.worker_memory / self.worker_processes
            return format_bytes(share).replace(" ", "")

    ShaderballJob.__name__ = ShaderballJob.__qualname__ = f"Shaderball{base.__name__}"
    ShaderballJob.refusals = []
    return ShaderballJob


def _refusal_text(error: str) -> str:
    """dask-jobqueue's error for a failed submit command, on one line: command, exit code, output."""
    parts = dict(
        re.findall(
            r"(Exit code|Command|stdout|stderr):[ \t]*\n?(.*?)(?=\n(?:Exit code|Command|stdout|stderr):|\Z)",
            error,
            re.S,
        )
    )
    if not parts:
        return " ".join(error.split())[:800]
    output = (parts.get("stderr") or "").strip() or (parts.get("stdout") or "").strip() or "no output"
    output = " / ".join(line.strip() for line in output.splitlines() if line.strip())
    # The script's temporary file is gone by now: name it for what it is.
    command = re.sub(r"\S+\.sh\b", "JOB-SCRIPT", " ".join(parts.get("Command", "").split()))
    return f"`{command}` exited {parts.get('Exit code', '?').strip()}: {output}"[:800]


def job_script_prologue(options: ClusterOptions) -> list[str]:
    """Shell lines run before the worker starts: threads and a node-local kernel cache."""
    import dask

    user_lines = list(dask.config.get(f"jobqueue.{options.kind}.job-script-prologue", None) or [])
    scratch = options.scratch or DEFAULT_SCRATCH
    job_id = JOB_ID_VARIABLE[options.kind]
    return user_lines + [
        f"export {RENDER_THREADS_ENV}={options.cores}",
        # drjit writes compiled kernels to $HOME/.drjit by default: on NFS, with every node
        # writing and sweeping it, that breaks. One cache per job on node-local disk.
        f'export {KERNEL_CACHE_ENV}="{scratch}/shaderball-drjit-{job_id}"',
        f'mkdir -p "${KERNEL_CACHE_ENV}"',
    ]


def jobqueue_kwargs(options: ClusterOptions) -> dict:
    """Keyword arguments for a dask-jobqueue Job or Cluster of ``options``."""
    options.check()
    lifetime_s, stagger_s = worker_lifetime(options.walltime)
    scratch = options.scratch or DEFAULT_SCRATCH
    return {
        "cores": options.cores,
        "processes": 1,
        "memory": options.memory,
        "walltime": options.walltime,
        "queue": options.queue,
        "account": options.account,
        "job_name": "shaderball",
        "python": sys.executable,
        "local_directory": f"{scratch}/shaderball-dask-{JOB_ID_VARIABLE[options.kind]}",
        "job_script_prologue": job_script_prologue(options),
        # No --lifetime-restart: a worker restarted inside a job about to end would be
        # killed with it; adaptive scaling submits a new job instead.
        "worker_extra_args": ["--lifetime", f"{lifetime_s}s", "--lifetime-stagger", f"{stagger_s}s"],
    }


def job_script(options: ClusterOptions, scheduler_address: str = "tcp://SCHEDULER-HOST:PORT") -> str:
    """The batch script each job of ``options`` runs, without submitting or starting anything."""
    job_class = _jobqueue_job_class(options.kind)
    return job_class(scheduler=scheduler_address, name="shaderball-worker", **jobqueue_kwargs(options)).job_script()


def jobqueue_cluster(options: ClusterOptions, adapt: bool = True):
    """A dask-jobqueue cluster (its scheduler runs in this process), kept at ``jobs`` jobs.

    ``adapt`` False: submit nothing (to inspect ``cluster.job_script()``).
    """
    job_class = _jobqueue_job_class(options.kind)
    import dask_jobqueue

    base = {"slurm": dask_jobqueue.SLURMCluster, "pbs": dask_jobqueue.PBSCluster}[options.kind]
    cluster_class = type(f"Shaderball{base.__name__}", (base,), {"job_cls": job_class})
    import dask

    scheduler_options = {
        "dashboard_address": ":0",
        **(dask.config.get(f"jobqueue.{options.kind}.scheduler-options", None) or {}),
    }
    cluster = cluster_class(scheduler_options=scheduler_options, **jobqueue_kwargs(options))
    if adapt:
        # adapt(), not scale(): a job that ends (walltime, preemption) is replaced.
        jobs = options.jobs or 1
        cluster.adapt(minimum_jobs=jobs, maximum_jobs=jobs)
    return cluster


# --------------------------------------------------------------------------- clients


@dataclass
class Connection:
    client: object
    #: for people: where the work runs.
    where: str
    #: Mitsuba threads per worker; None: each worker decides (:func:`worker_render_threads`).
    render_threads: int | None
    #: the dask-jobqueue cluster (its jobs), for --cluster slurm/pbs; else None.
    jobqueue: object | None = None


#: How long a Ctrl-C waits for the workers to silence their logs before closing them anyway.
QUIET_TIMEOUT_S = 5.0


def quiet_for_shutdown(client, workers_too: bool) -> None:
    """Silence dask's logging in this process and (``workers_too``: a local cluster's, whose
    output is this terminal's) on every worker, before an interrupted build closes its cluster. Closing mid-work makes workers and nannies log errors (a heartbeat
    to a scheduler that is going away, with a 30-line traceback; seen on a loaded machine),
    which would bury the one line a Ctrl-C prints. Only for an interrupt: a failure's logs
    are kept. The workers' switch is bounded in time: a busy or stuck worker is closed anyway.
    """
    logging.disable(logging.CRITICAL)  # this process: the scheduler, nannies and client of a local cluster
    if not workers_too:
        return  # a scheduler's own workers outlive this build and log to their own files
    done = threading.Event()

    def run():
        with contextlib.suppress(Exception):
            client.run(logging.disable, logging.CRITICAL, on_error="ignore")
        done.set()

    threading.Thread(target=run, name="shaderball-quiet", daemon=True).start()
    done.wait(QUIET_TIMEOUT_S)


def _interruptible(conn: Connection, local: bool = False) -> Iterator[Connection]:
    """Yield ``conn``; on a Ctrl-C (or an error it caused) silence the cluster's logs first."""
    try:
        yield conn
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt) or caused_by_interrupt(exc):
            quiet_for_shutdown(conn.client, workers_too=local)
        raise


def local_workers(workers: int | None) -> int:
    return workers or max(1, (os.cpu_count() or 1) // 2)


@contextlib.contextmanager
def connect(options: ClusterOptions) -> Iterator[Connection]:
    """A dask client for ``options``; closes what it started (cluster, jobs) on exit."""
    import dask
    from distributed import Client, LocalCluster

    options.check()
    config = {
        "distributed.worker.multiprocessing-method": "spawn",  # LLVM JIT and fork() don't mix
        "distributed.worker.daemon": False,
        "distributed.scheduler.allowed-failures": 5,
    }
    if not options.scheduler and not options.is_jobqueue:
        # A LocalCluster closes a nanny for good when its worker is absent 15 s after any
        # earlier removal of it, as happens when restarts (recycling, memory limit) come a
        # few seconds apart: the build then waits forever on a cluster without workers.
        # Local nannies restart their own workers; never close them.
        config["distributed.deploy.lost-worker-timeout"] = "3650 days"
    with dask.config.set(config), contextlib.ExitStack() as stack:
        stack.callback(logging.disable, logging.root.manager.disable)  # last: undo quiet_for_shutdown
        if options.scheduler:
            check_scheduler_reachable(options.scheduler)
            try:
                client = Client(options.scheduler, timeout="20s")
            except OSError as exc:
                raise ShaderballError(f"--scheduler: cannot connect to {options.scheduler!r}: {exc}") from None
            stack.callback(client.close)
            n = len(client.scheduler_info().get("workers", {}))
            yield from _interruptible(Connection(client, f"scheduler {options.scheduler} ({n} worker(s) now)", None))
        elif options.is_jobqueue:
            cluster = jobqueue_cluster(options)
            stack.callback(cluster.close)
            client = Client(cluster)
            stack.callback(client.close)
            yield from _interruptible(
                Connection(
                    client,
                    f"{options.kind} cluster, {options.jobs or 1} job(s) of {options.cores} cores, {options.memory}",
                    None,
                    cluster,
                )
            )
        else:
            n = local_workers(options.workers)
            memory = memory_bytes(options.memory) if options.memory else "auto"
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                silence_logs=40,
                memory_limit=memory,
            )
            stack.callback(cluster.close)
            client = Client(cluster)
            stack.callback(client.close)
            yield from _interruptible(
                Connection(client, f"local cluster, {n} worker process(es)", max(1, (os.cpu_count() or 1) // n)),
                local=True,
            )


# --------------------------------------------------------------------------- in the worker


def worker_render_threads() -> int:
    """Mitsuba threads for a worker that was not told: the environment, else its CPUs."""
    value = os.environ.get(RENDER_THREADS_ENV, "")
    if value.isdigit() and int(value) > 0:
        return int(value)
    try:
        return max(1, len(os.sched_getaffinity(0)))  # the batch system's CPU set
    except AttributeError:
        return os.cpu_count() or 1


_RENDERED = {"count": 0}
#: Topic of the scheduler event a worker logs when it restarts itself (counted by the build).
RECYCLE_EVENT = "shaderball-recycle"


def after_shard(rendered: int, recycle_after: int) -> bool:
    """Count a shard's renders; at ``recycle_after`` ask this worker process to restart.

    The worker retires gracefully (its queued shards go elsewhere) and its nanny starts a
    fresh process, which returns the memory Mitsuba accumulated. Outside a dask worker
    (``--workers 0``) this does nothing. Return whether a restart was asked for.
    """
    _RENDERED["count"] += rendered
    if not recycle_after or _RENDERED["count"] < recycle_after:
        return False
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return False
    _RENDERED["count"] = 0
    worker.log_event(RECYCLE_EVENT, {"pid": os.getpid(), "recycle_after": recycle_after})
    worker.loop.add_callback(worker.close_gracefully, restart=True, reason=RECYCLE_EVENT)
    return True


# --------------------------------------------------------------------------- the build's dask loop


def shard_task(out: str, spec, shard, variant: str, threads: int | None, recycle_after: int = 0) -> dict:
    """The dask task: one shard with a bounded Mitsuba thread pool, then maybe recycle.

    ``threads`` None: the worker decides (``SHADERBALL_RENDER_THREADS``, else its CPU set).
    """
    result = run_shard_in_process(out, spec, shard, variant, threads or worker_render_threads())
    result["recycled"] = after_shard(result["rendered"], recycle_after)
    return result


def run_shards_on_dask(
    out: str, spec, todo: list, variant: str, options: ClusterOptions, report: Callable[[str], None], on_start=None
) -> tuple[list[dict], str | None, int]:
    """Run the shards ``todo`` on the workers ``options`` describe.

    ``report(status)`` is called about every second; ``status`` says what the build waits on
    (workers, batch jobs pending and why), "" when there is nothing to say. Stops with a
    ShaderballError when the build has had no worker for ``options.start_timeout`` seconds,
    or the batch system refused a job. Returns (the shards' results, the dashboard link or
    None, worker restarts for memory).
    """
    from distributed import wait
    from distributed.scheduler import KilledWorker

    # Remote workers resolve paths in their own working directory: give them an absolute one.
    out_abs = os.path.abspath(out)
    token = uuid.uuid4().hex[:8]
    with connect(options) as conn:
        client = conn.client
        dashboard = client.dashboard_link if _has_dashboard() else None
        if on_start:
            on_start(conn.where, dashboard)
        pending = {
            client.submit(
                shard_task,
                out_abs,
                spec,
                shard,
                variant,
                conn.render_threads,
                options.recycle_after,
                key=f"shard-{shard.shard_id}-{token}",
                pure=False,
            )
            for shard in todo
        }
        watch = WorkerWatch(lambda: len(client.nthreads()), options, conn.jobqueue)
        results: list[dict] = []
        next_report = 0.0
        try:
            while pending:
                try:
                    done, pending = wait(pending, timeout=1.0, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = set()
                for future in done:
                    results.append(future.result())  # raises a task's error here
                    # Released at once: a worker that retires (walltime, recycling) then has no
                    # results to hand to a peer first (a hung peer stalled that: measured on
                    # SLURM), and a lost worker's finished shards are not run again.
                    future.release()
                if pending and time.monotonic() >= next_report:  # about once a second
                    next_report = time.monotonic() + 1.0
                    watch.poll()
                    report(watch.status())
                    watch.check()
            recycled = len(client.get_events(RECYCLE_EVENT))
        except KilledWorker as exc:
            raise ShaderballError(
                f"build: a shard's worker died too often ({exc}); see the workers' logs (memory "
                "limit? a crash in Mitsuba?). What was rendered is kept: run the same command "
                "again to resume"
            ) from None
    return results, dashboard, recycled


# --------------------------------------------------------------------------- waiting for workers


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
            if self.options.kind != "slurm":
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
            return f"{self.options.kind} jobs unknown: {self.queue_error}"
        if self.jobs is None:
            return f"{self.options.kind} jobs: submitting"
        return describe_jobs(self.options.kind, self.jobs, explain=explain)

    def check(self) -> None:
        """Raise ShaderballError on a refused job or when --start-timeout has run out."""
        refused = self.refusals()
        if refused:
            raise ShaderballError(
                f"--cluster {self.options.kind}: the batch system refused a job: {refused[0]} "
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
        raise ShaderballError(
            f"--start-timeout {limit}: no worker for {limit} s {since}; {why}. {then} was rendered "
            "is kept: run the same command again to resume (a larger --start-timeout waits longer)"
        )


def _has_dashboard() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True
