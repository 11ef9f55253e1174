"""Where a build's dask workers come from, how long they live, and what memory they use.

:mod:`pipeline.run.build` hands the shards to :func:`run_shards_on_dask`, which submits one
task per shard to the client this module connects (the only module that runs dask):

- ``local`` (the default): a ``LocalCluster`` of spawned worker processes on this machine;
- an existing scheduler (``--scheduler tcp://HOST:PORT``) with workers started by hand;
- ``slurm`` / ``pbs``: a dask-jobqueue cluster, one batch job per node, each job one worker
  process with one dask thread (one shard at a time) whose Mitsuba renders use every core
  of the job.

Worker memory is bounded twice: the nanny restarts a worker whose memory passes 95 % of its
limit (its unfinished shard runs again), and ``recycle_after`` restarts a worker process,
between shards, once it has rendered that many samples (Mitsuba's memory grows slowly when
it renders in a long loop; scripts/memory_probe.py measures it, docs/cluster.md). Re-running a shard is safe
because shard tasks are idempotent (:mod:`pipeline.run.shard`).

GPUs. A local build whose variant is cuda starts one worker process per visible GPU (``--gpus``
chooses them; ``--workers`` more than the GPUs spreads several over each), and a batch job of
``--gpus-per-job N`` runs N worker processes. Each worker is pinned to one GPU through
``CUDA_VISIBLE_DEVICES`` in its own environment, set before its process touches CUDA (drjit
reads it when it first initialises CUDA), so that ``auto`` and every kernel cache see one
device. Locally that is dask's own ``env`` of a ``Nanny`` (applied in the spawned worker
process before the worker starts; a nanny that restarts its worker keeps it): a ``Nanny``
subclass hands each nanny of the ``LocalCluster`` the next device. Not dask-cuda's
``LocalCUDACluster``: it is not installed here, pulls in CUDA Python packages (pynvml), and
would replace the ``LocalCluster`` whose settings this module depends on (spawned processes,
SIGINT handling, memory limits, lost-worker timeout) for the one thing a nanny's ``env`` does.
In a batch job the script starts one ``dask worker`` per GPU, each with
``CUDA_VISIBLE_DEVICES`` set to the i-th id of the job's allocation (SLURM's or PBS's
``CUDA_VISIBLE_DEVICES``, else ``SLURM_JOB_GPUS``, else i), named as dask-jobqueue names
the N workers of one job, so adaptive scaling, retirement and the watch are unchanged.

``scripts/memory_probe.py --memory-probe 200`` re-measures the growth. The options are checked in
:mod:`pipeline.run.cluster.options`; batch jobs are watched by :mod:`pipeline.run.cluster.watch`.

The environment that steers the workers (render threads, kernel cache, GPU pins) is
pipeline.run.cluster.worker_env.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing.spawn
import os
import pickle
import re
import shlex
import shutil
import signal
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from pipeline.errors import USER_ERRORS, ShaderballError, caused_by_interrupt
from pipeline.run.cluster.options import (
    DEFAULT_SCRATCH,
    ClusterOptions,
    check_scheduler_reachable,
    memory_bytes,
    worker_lifetime,
)
from pipeline.run.cluster.watch import WorkerWatch
from pipeline.run.cluster.worker_env import (
    CUDA_DEVICES_ENV,
    KERNEL_CACHE_ENV,
    PINNED_GPU_ENV,
    RENDER_THREADS_ENV,
    gpu_pins,
    pinned_worker_commands,
    worker_render_threads,
)
from pipeline.run.shard import run_shard_in_process

#: The worker's memory limit, as a share of the job's memory: the nanny restarts the worker
#: (at 95 % of its limit) before the batch system's cgroup kills the whole job at 100 %.
WORKER_MEMORY_SHARE = 0.9
#: The job id in each batch system's environment (for per-job scratch folders).
JOB_ID_VARIABLE = {"slurm": "${SLURM_JOB_ID:-$$}", "pbs": "${PBS_JOBID:-$$}"}


# --------------------------------------------------------------------------- jobqueue


def _jobqueue_job_class(kind: str, gpus_per_job: int | None = None):
    """dask-jobqueue's Job class of ``kind``, changed to one dask thread per worker process
    (and with ``gpus_per_job``, one worker command per GPU, each pinned to its GPU)."""
    try:
        if kind == "slurm":
            from dask_jobqueue.slurm import SLURMJob as base
        else:
            from dask_jobqueue.pbs import PBSJob as base
    except ImportError:
        raise ClusterOptions.field_error(
            "cluster", kind, "install it with `pip install dask-jobqueue`", what=f"{kind} needs dask-jobqueue"
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

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            if gpus_per_job:
                self._command_template = pinned_worker_commands(self._command_template, str(self.name), gpus_per_job)

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

    user_lines = list(dask.config.get(f"jobqueue.{options.cluster}.job-script-prologue", None) or [])
    scratch = options.scratch or DEFAULT_SCRATCH
    job_id = JOB_ID_VARIABLE[options.cluster]
    return user_lines + [
        f"export {RENDER_THREADS_ENV}={max(1, options.cores // (options.gpus_per_job or 1))}",
        # drjit writes compiled kernels to $HOME/.drjit by default: on NFS, with every node
        # writing and sweeping it, that breaks. One cache per job on node-local disk.
        f'export {KERNEL_CACHE_ENV}="{scratch}/shaderball-drjit-{job_id}"',
        f'mkdir -p "${KERNEL_CACHE_ENV}"',
    ]


def jobqueue_kwargs(options: ClusterOptions) -> dict:
    """Keyword arguments for a dask-jobqueue Job or Cluster of ``options``."""
    lifetime_s, stagger_s = worker_lifetime(options.walltime)
    scratch = options.scratch or DEFAULT_SCRATCH
    return {
        **_gpu_request(options),
        "cores": options.cores,
        "processes": options.gpus_per_job or 1,
        "memory": options.memory,
        "walltime": options.walltime,
        "queue": options.queue,
        "account": options.account,
        "job_name": "shaderball",
        "python": sys.executable,
        "local_directory": f"{scratch}/shaderball-dask-{JOB_ID_VARIABLE[options.cluster]}",
        "job_script_prologue": job_script_prologue(options),
        # No --lifetime-restart: a worker restarted inside a job about to end would be
        # killed with it; adaptive scaling submits a new job instead.
        "worker_extra_args": ["--lifetime", f"{lifetime_s}s", "--lifetime-stagger", f"{stagger_s}s"],
    }


def _gpu_request(options: ClusterOptions) -> dict:
    """The batch system's own request for ``--gpus-per-job`` GPUs (with the user's configured
    extra directives kept): SLURM's ``--gres=gpu:N``, PBS's ``ngpus=N`` in its select."""
    import dask

    n = options.gpus_per_job
    if not n:
        return {}
    if options.cluster == "slurm":
        extra = list(dask.config.get("jobqueue.slurm.job-extra-directives", None) or [])
        return {"job_extra_directives": [*extra, f"--gres=gpu:{n}"]}
    from dask_jobqueue.pbs import pbs_format_bytes_ceil

    memory = pbs_format_bytes_ceil(memory_bytes(options.memory))
    return {"resource_spec": f"select=1:ncpus={options.cores}:ngpus={n}:mem={memory}"}


def job_script(options: ClusterOptions, scheduler_address: str = "tcp://SCHEDULER-HOST:PORT") -> str:
    """The batch script each job of ``options`` runs, without submitting or starting anything."""
    job_class = _jobqueue_job_class(options.cluster, options.gpus_per_job)
    return job_class(scheduler=scheduler_address, name="shaderball-worker", **jobqueue_kwargs(options)).job_script()


def jobqueue_cluster(options: ClusterOptions, adapt: bool = True):
    """A dask-jobqueue cluster (its scheduler runs in this process), kept at ``jobs`` jobs.

    ``adapt`` False: submit nothing (to inspect ``cluster.job_script()``).
    """
    job_class = _jobqueue_job_class(options.cluster, options.gpus_per_job)
    import dask_jobqueue

    base = {"slurm": dask_jobqueue.SLURMCluster, "pbs": dask_jobqueue.PBSCluster}[options.cluster]
    cluster_class = type(f"Shaderball{base.__name__}", (base,), {"job_cls": job_class})
    import dask

    scheduler_options = {
        "dashboard_address": ":0",
        **(dask.config.get(f"jobqueue.{options.cluster}.scheduler-options", None) or {}),
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
        # BaseException: a client closed meanwhile cancels the call (asyncio's CancelledError is
        # no Exception), and a thread's uncaught error is printed with its traceback.
        with contextlib.suppress(BaseException):
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


def _pinned_nanny(pins: list[str]):
    """A ``Nanny`` class whose i-th instance gives its worker process ``CUDA_VISIBLE_DEVICES``
    = ``pins[i]`` (dask applies a nanny's ``env`` in the spawned process, before the worker)."""
    from distributed import Nanny

    made = [0]

    class PinnedNanny(Nanny):
        def __init__(self, *args, env=None, **kwargs):
            device = pins[made[0] % len(pins)]
            made[0] += 1
            pinned = {CUDA_DEVICES_ENV: device, PINNED_GPU_ENV: device}
            super().__init__(*args, env={**(env or {}), **pinned}, **kwargs)

    return PinnedNanny


#: What the spawn wrapper runs before the worker's Python: SIGINT blocked, then exec. A
#: shell can ignore a signal but not block it.
_BLOCK_SIGINT_AND_EXEC = (
    "import os, signal, sys; signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}); "
    "os.execv(sys.executable, [sys.executable] + sys.argv[1:])"
)


@contextlib.contextmanager
def spawned_ignoring_sigint() -> Iterator[None]:
    """Every process spawned meanwhile (local dask workers, and the ones their nannies start
    again later: recycling, a memory restart) starts with SIGINT ignored and blocked.

    A terminal's Ctrl-C reaches the whole process group; a worker process caught while it
    imports printed a KeyboardInterrupt traceback (seen on a loaded machine). An
    ignored signal stays ignored across exec and Python then installs no handler of its own,
    so the spawn start method runs a wrapper that ignores SIGINT and execs this Python. Ignored
    is not enough while Mitsuba renders: it installs its own SIGINT handler for the length of
    a render, which cancels it and logs from inside the signal handler, on whichever thread
    the kernel picks. Blocked in every thread from the start (a mask is inherited by each new
    thread and kept across exec), the signal never reaches it. The driver closes the workers
    on a Ctrl-C."""
    folder = tempfile.mkdtemp(prefix="shaderball-spawn-")
    wrapper = os.path.join(folder, "python")
    python = shlex.quote(sys.executable)
    with open(wrapper, "w") as fh:
        fh.write(f"#!/bin/sh\ntrap '' INT\nexec {python} -S -c {shlex.quote(_BLOCK_SIGINT_AND_EXEC)} \"$@\"\n")
    os.chmod(wrapper, 0o700)
    previous = multiprocessing.spawn.get_executable()
    multiprocessing.spawn.set_executable(wrapper)
    try:
        yield
    finally:
        multiprocessing.spawn.set_executable(previous)
        shutil.rmtree(folder, ignore_errors=True)


@contextlib.contextmanager
def _sigint_blocked_in_new_threads() -> Iterator[None]:
    """SIGINT blocked in this thread while a local cluster starts, so that the threads it
    starts (its event loop, the nannies' process threads) block it too, and every worker
    process they spawn, now or when a nanny starts one again, begins with it blocked: a
    Ctrl-C before the wrapper's ``trap`` has run waits instead of killing the worker.
    multiprocessing's resource tracker is started first, here: starting it unblocks SIGINT
    in the thread that does (it blocks it for its own spawn, then unblocks it).

    A Ctrl-C meanwhile is not lost: the process's handler (pipeline.run.build records it)
    runs when another thread takes the signal, or when this one unblocks it."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


@contextlib.contextmanager
def connect(options: ClusterOptions, variant: str | None = None) -> Iterator[Connection]:
    """A dask client for ``options``; closes what it started (cluster, jobs) on exit.

    ``variant``: the build's Mitsuba variant; a cuda one pins each local worker to a GPU."""
    import dask
    from distributed import Client, LocalCluster

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
                raise ClusterOptions.field_error(
                    "scheduler", options.scheduler, "a running dask scheduler", what=f"cannot connect: {exc}"
                ) from None
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
                    f"{options.cluster} cluster, {options.jobs or 1} job(s) of {options.cores} cores, {options.memory}",
                    None,
                    cluster,
                )
            )
        else:
            pins = gpu_pins(options, variant)
            n = len(pins) if pins else local_workers(options.workers)
            memory = memory_bytes(options.memory) if options.memory else "auto"
            pinned = {"worker_class": _pinned_nanny(pins)} if pins else {}
            if os.name == "posix":
                stack.enter_context(spawned_ignoring_sigint())
            with _sigint_blocked_in_new_threads():
                cluster = LocalCluster(
                    n_workers=n,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=":0",
                    silence_logs=40,
                    memory_limit=memory,
                    **pinned,
                )
            stack.callback(cluster.close)
            client = Client(cluster)
            stack.callback(client.close)
            where = f"local cluster, {n} worker process(es)"
            if pins:
                where += f" on GPU(s) {', '.join(dict.fromkeys(pins))} ({CUDA_DEVICES_ENV} per worker)"
            yield from _interruptible(Connection(client, where, max(1, (os.cpu_count() or 1) // n)), local=True)


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


#: Key of a shard task's result that holds the error the build reports itself (a full disk,
#: a refusal): returned, not raised, so the worker logs no "Compute Failed" and traceback.
FAILED = "failed"


def _returnable(exc: BaseException) -> bool:
    """Whether ``exc`` survives the trip back to the driver (pickled as a task's result)."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:  # noqa: BLE001 - any failure: raise it as a task's error instead
        return False
    return True


def shard_task(out: str, spec, shard, variant: str, threads: int | None, recycle_after: int = 0) -> dict:
    """The dask task: one shard with a bounded Mitsuba thread pool, then maybe recycle.

    ``threads`` None: the worker decides (``SHADERBALL_RENDER_THREADS``, else its CPU set).
    An error the build reports as a message (an OSError, a user error) is returned under
    :data:`FAILED`; :func:`run_shards_on_dask` raises it. A bug is raised (and logged).
    """
    try:
        result = run_shard_in_process(out, spec, shard, variant, threads or worker_render_threads())
    except (OSError, *USER_ERRORS) as exc:
        if caused_by_interrupt(exc) or not _returnable(exc):
            raise
        return {FAILED: exc}
    result["recycled"] = after_shard(result["rendered"], recycle_after)
    result["device"] = os.environ.get(PINNED_GPU_ENV)  # the worker's GPU, when pinned
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
    with connect(options, variant) as conn:
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
        next_report, began, per_gpu = 0.0, time.monotonic(), {}
        try:
            while pending:
                try:
                    done, pending = wait(pending, timeout=1.0, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = set()
                for future in done:
                    result = future.result()  # raises a task's error here
                    if FAILED in result:
                        raise result[FAILED]  # an error the task reported (shard_task)
                    results.append(result)
                    if result.get("device") is not None:
                        per_gpu[result["device"]] = per_gpu.get(result["device"], 0) + result["rendered"]
                    # Released at once: a worker that retires (walltime, recycling) then has no
                    # results to hand to a peer first (a hung peer stalled that: measured on
                    # SLURM), and a lost worker's finished shards are not run again.
                    future.release()
                if pending and time.monotonic() >= next_report:  # about once a second
                    next_report = time.monotonic() + 1.0
                    watch.poll()
                    report(_with_gpu_rates(watch.status(), per_gpu, time.monotonic() - began))
                    watch.check()
            recycled = len(client.get_events(RECYCLE_EVENT))
        except KilledWorker as exc:
            raise ShaderballError(
                f"build: a shard's worker died too often ({exc}); see the workers' logs (memory "
                "limit? a crash in Mitsuba?). What was rendered is kept: run the same command "
                "again to resume"
            ) from None
    return results, dashboard, recycled


def _with_gpu_rates(status: str, per_gpu: dict[str, int], seconds: float) -> str:
    """``status`` and, for workers pinned to GPUs, each GPU's renders a second so far."""
    if not per_gpu or seconds <= 0:
        return status
    rates = "per GPU: " + ", ".join(f"{d} {n / seconds:.2f}/s" for d, n in sorted(per_gpu.items()))
    return f"{status}; {rates}" if status else rates


def _has_dashboard() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True
