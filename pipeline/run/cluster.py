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
import os
import re
import socket
import sys
import threading
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from pipeline.errors import ShaderballError, check_int
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

_WALLTIME = re.compile(r"^(\d{1,4}):([0-5]\d):([0-5]\d)$")
_SHELL_WORD = re.compile(r"^[A-Za-z0-9_.@:+-]{1,128}$")
_SCRATCH = re.compile(r"^[A-Za-z0-9_./${}:+-]{1,256}$")
_MIN_WALLTIME_S = 15 * 60
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
        if self.memory is not None:
            memory_bytes(self.memory)
        if self.walltime is not None:
            walltime_seconds(self.walltime)
        for option, value in (("--queue", self.queue), ("--account", self.account)):
            if value is not None and not _SHELL_WORD.match(value):
                raise ShaderballError(f"{option}: {value!r} is not allowed; allowed: 1 to 128 "
                                      "characters from A-Z a-z 0-9 _ . @ : + -")
        if self.scratch is not None and not _SCRATCH.match(self.scratch):
            raise ShaderballError(f"--scratch: {self.scratch!r} is not allowed; allowed: a path of "
                                  "1 to 256 characters from A-Z a-z 0-9 _ . / $ { } : + - "
                                  "(shell variables such as $TMPDIR are expanded on the node)")
        if self.scheduler is not None:
            if self.kind != "local":
                raise ShaderballError(f"--scheduler: not allowed with --cluster {self.kind}; "
                                      "use one or the other")
            scheduler_host_port(self.scheduler)
        if self.is_jobqueue:
            if self.workers is not None:
                raise ShaderballError(f"--workers: not allowed with --cluster {self.kind}; "
                                      "use --jobs (one worker process per job)")
            for option, value, example in (("--cores", self.cores, "--cores 32"),
                                           ("--memory", self.memory, "--memory 64GiB"),
                                           ("--walltime", self.walltime, "--walltime 12:00:00")):
                if value is None:
                    raise ShaderballError(f"{option}: required with --cluster {self.kind}; "
                                          f"for example: {example}")
        else:
            for option, value in (("--jobs", self.jobs), ("--cores", self.cores),
                                  ("--walltime", self.walltime), ("--queue", self.queue),
                                  ("--account", self.account), ("--scratch", self.scratch)):
                if value is not None:
                    raise ShaderballError(f"{option}: only with --cluster slurm or --cluster pbs")
            if self.scheduler is not None and self.memory is not None:
                raise ShaderballError("--memory: not allowed with --scheduler; "
                                      "give --memory-limit to `dask worker` instead")
        return self


def memory_bytes(text: str) -> int:
    """``--memory`` in bytes (dask's units: 16GiB, 16GB, 16000MB), checked."""
    from dask.utils import parse_bytes

    try:
        value = parse_bytes(text)
    except (ValueError, TypeError):
        value = None
    if value is None or not _MIN_MEMORY <= value <= _MAX_MEMORY:
        raise ShaderballError(f"--memory: {text!r} is not allowed; allowed: an amount from 256MiB to "
                              "64TiB with a unit, e.g. 16GiB or 64GB")
    return int(value)


def walltime_seconds(text: str) -> int:
    match = _WALLTIME.match(text)
    seconds = None if match is None else int(match[1]) * 3600 + int(match[2]) * 60 + int(match[3])
    if seconds is None or seconds < _MIN_WALLTIME_S:
        raise ShaderballError(f"--walltime: {text!r} is not allowed; allowed: HH:MM:SS from 00:15:00 "
                              "to 9999:59:59")
    return seconds


def worker_lifetime(walltime: str) -> tuple[int, int]:
    """(lifetime, stagger) in seconds: workers retire before the batch system kills the job.

    A worker that retires hands its queued shards back; jobqueue's adaptive scaling then
    submits a fresh job. The margin (5 minutes or 5 % of the walltime, the larger) leaves
    the running shard time to finish or be handed back cleanly.
    """
    total = walltime_seconds(walltime)
    margin = max(300, total // 20)
    return total - margin, margin // 2


def scheduler_host_port(address: str) -> tuple[str, int]:
    match = re.match(r"^(?:tcp|tls)://(\[[0-9A-Fa-f:]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$", address)
    if match is None or not 0 < int(match[2]) < 65536:
        raise ShaderballError(f"--scheduler: {address!r} is not allowed; allowed: tcp://HOST:PORT or "
                              "tls://HOST:PORT, e.g. tcp://10.0.0.1:8786")
    return match[1].strip("[]"), int(match[2])


def check_scheduler_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast with a clear message when nothing listens at ``address``."""
    host, port = scheduler_host_port(address)
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        raise ShaderballError(f"--scheduler: cannot reach {address!r} ({exc.strerror or exc}); "
                              "is `dask scheduler` running there?") from None


# --------------------------------------------------------------------------- jobqueue


def _jobqueue_job_class(kind: str):
    """dask-jobqueue's Job class of ``kind``, changed to one dask thread per worker process."""
    try:
        if kind == "slurm":
            from dask_jobqueue.slurm import SLURMJob as base
        else:
            from dask_jobqueue.pbs import PBSJob as base
    except ImportError:
        raise ShaderballError(f"--cluster {kind}: needs dask-jobqueue; install it with "
                              "`pip install dask-jobqueue`") from None

    class ShaderballJob(base):
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
    return ShaderballJob


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
    return job_class(scheduler=scheduler_address, name="shaderball-worker",
                     **jobqueue_kwargs(options)).job_script()


def jobqueue_cluster(options: ClusterOptions, adapt: bool = True):
    """A dask-jobqueue cluster (its scheduler runs in this process), kept at ``jobs`` jobs.

    ``adapt`` False: submit nothing (to inspect ``cluster.job_script()``).
    """
    job_class = _jobqueue_job_class(options.kind)
    import dask_jobqueue

    base = {"slurm": dask_jobqueue.SLURMCluster, "pbs": dask_jobqueue.PBSCluster}[options.kind]
    cluster_class = type(f"Shaderball{base.__name__}", (base,), {"job_cls": job_class})
    import dask

    scheduler_options = {"dashboard_address": ":0",
                         **(dask.config.get(f"jobqueue.{options.kind}.scheduler-options", None) or {})}
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


def local_workers(workers: int | None) -> int:
    return workers or max(1, (os.cpu_count() or 1) // 2)


@contextlib.contextmanager
def connect(options: ClusterOptions) -> Iterator[Connection]:
    """A dask client for ``options``; closes what it started (cluster, jobs) on exit."""
    import dask
    from distributed import Client, LocalCluster

    options.check()
    config = {"distributed.worker.multiprocessing-method": "spawn",  # LLVM JIT and fork() don't mix
              "distributed.worker.daemon": False,
              "distributed.scheduler.allowed-failures": 5}
    if not options.scheduler and not options.is_jobqueue:
        # A LocalCluster closes a nanny for good when its worker is absent 15 s after any
        # earlier removal of it, as happens when restarts (recycling, memory limit) come a
        # few seconds apart: the build then waits forever on a cluster without workers.
        # Local nannies restart their own workers; never close them.
        config["distributed.deploy.lost-worker-timeout"] = "3650 days"
    with dask.config.set(config), contextlib.ExitStack() as stack:
        if options.scheduler:
            check_scheduler_reachable(options.scheduler)
            try:
                client = Client(options.scheduler, timeout="20s")
            except OSError as exc:
                raise ShaderballError(f"--scheduler: cannot connect to {options.scheduler!r}: {exc}") from None
            stack.callback(client.close)
            n = len(client.scheduler_info().get("workers", {}))
            yield Connection(client, f"scheduler {options.scheduler} ({n} worker(s) now)", None)
        elif options.is_jobqueue:
            cluster = jobqueue_cluster(options)
            stack.callback(cluster.close)
            client = Client(cluster)
            stack.callback(client.close)
            yield Connection(client, f"{options.kind} cluster, {options.jobs or 1} job(s) of "
                                     f"{options.cores} cores, {options.memory}", None)
        else:
            n = local_workers(options.workers)
            memory = memory_bytes(options.memory) if options.memory else "auto"
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=40, memory_limit=memory)
            stack.callback(cluster.close)
            client = Client(cluster)
            stack.callback(client.close)
            yield Connection(client, f"local cluster, {n} worker process(es)",
                             max(1, (os.cpu_count() or 1) // n))


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


def run_shards_on_dask(out: str, spec, todo: list, variant: str, options: ClusterOptions,
                       report: Callable[[], None], on_start=None) -> tuple[list[dict], str | None, int]:
    """Run the shards ``todo`` on the workers ``options`` describe; ``report`` is called every second.

    Returns (the shards' results, the dashboard link or None, worker restarts for memory).
    """
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    # Remote workers resolve paths in their own working directory: give them an absolute one.
    out_abs = os.path.abspath(out)
    token = uuid.uuid4().hex[:8]
    with connect(options) as conn:
        client = conn.client
        dashboard = client.dashboard_link if _has_dashboard() else None
        if on_start:
            on_start(conn.where, dashboard)
        futures = [client.submit(shard_task, out_abs, spec, shard, variant, conn.render_threads,
                                 options.recycle_after, key=f"shard-{shard.shard_id}-{token}",
                                 pure=False)
                   for shard in todo]
        stop = threading.Event()

        def report_loop():
            while not stop.wait(1.0):
                report()

        reporter = threading.Thread(target=report_loop, daemon=True)
        reporter.start()
        try:
            results = [f.result() for f in as_completed(futures)]  # raises a task's error here
            recycled = len(client.get_events(RECYCLE_EVENT))
        except KilledWorker as exc:
            raise ShaderballError(
                f"build: a shard's worker died too often ({exc}); see the workers' logs (memory "
                "limit? a crash in Mitsuba?). What was rendered is kept: run the same command "
                "again to resume") from None
        finally:
            stop.set()
            reporter.join()
    return results, dashboard, recycled


def _has_dashboard() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True
