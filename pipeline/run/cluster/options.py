"""The cluster options of a build (``shaderball build --cluster/--workers/--jobs/...``), checked.

:class:`ClusterOptions` is what the user asked for; :meth:`ClusterOptions.check` refuses a
bad value or a mix of kinds with a message naming the option, before anything starts.
``--memory`` takes dask's units (the value is handed to dask), so it is parsed with dask's
own parser; nothing else here touches dask.
"""

from __future__ import annotations

import re
import socket
from dataclasses import dataclass

from pipeline.errors import ShaderballError, bad_value, check_int

KINDS = ("local", "slurm", "pbs")
JOBQUEUE_KINDS = ("slurm", "pbs")
#: Default of ``--recycle-after``: renders per worker process before it is restarted. Measured
#: growth is ~7 MiB per 100 renders at 400x400 (docs/cluster.md): at most ~140 MiB, for a
#: restart (~5-10 s) every ~2.5 h of paper-size rendering.
DEFAULT_RECYCLE_AFTER = 2000
#: Shell expression for node-local scratch space, the default of ``--scratch``.
DEFAULT_SCRATCH = "${TMPDIR:-/tmp}"

_WALLTIME = re.compile(r"^(\d{1,4}):([0-5]\d):([0-5]\d)\Z", re.ASCII)
_SHELL_WORD = re.compile(r"^[A-Za-z0-9_.@:+-]{1,128}\Z", re.ASCII)
_SCRATCH = re.compile(r"^[A-Za-z0-9_./${}:+-]{1,256}\Z", re.ASCII)
_MIN_WALLTIME_S = 60
#: --walltime's range, as the refusal and the CLI help word it.
WALLTIME_SPAN = "00:01:00 to 9999:59:59"
#: The ranges of the integer options, defined once (the checks below; the CLI help).
WORKERS_RANGE = (0, 1024)
JOBS_RANGE = (1, 10000)
CORES_RANGE = (1, 1024)
RECYCLE_AFTER_RANGE = (0, 10_000_000)
#: --start-timeout's range in seconds: below 10 s not even a local worker process starts.
START_TIMEOUT_RANGE = (10, 10_000_000)
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
            raise bad_value("--cluster", self.kind, ", ".join(KINDS))
        check_int("--workers", self.workers, *WORKERS_RANGE)
        check_int("--jobs", self.jobs, *JOBS_RANGE)
        check_int("--cores", self.cores, *CORES_RANGE)
        check_int("--recycle-after", self.recycle_after, *RECYCLE_AFTER_RANGE)
        check_int("--start-timeout", self.start_timeout, *START_TIMEOUT_RANGE)
        if self.start_timeout is not None and self.workers == 0 and not self.scheduler:
            raise ShaderballError("--start-timeout: not allowed with --workers 0 (no workers to wait for)")
        if self.memory is not None:
            memory_bytes(self.memory)
        if self.walltime is not None:
            walltime_seconds(self.walltime)
        for option, value in (("--queue", self.queue), ("--account", self.account)):
            if value is not None and not _SHELL_WORD.match(value):
                raise bad_value(option, value, "1 to 128 characters from A-Z a-z 0-9 _ . @ : + -")
        if self.scratch is not None and not _SCRATCH.match(self.scratch):
            raise bad_value(
                "--scratch",
                self.scratch,
                "a path of 1 to 256 characters from A-Z a-z 0-9 _ . / $ { } : + - "
                "(shell variables such as $TMPDIR are expanded on the node)",
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
        raise bad_value("--memory", text, "an amount from 256MiB to 64TiB with a unit, e.g. 16GiB or 64GB")
    return int(value)


def walltime_seconds(text: str) -> int:
    match = _WALLTIME.match(text)
    seconds = None if match is None else int(match[1]) * 3600 + int(match[2]) * 60 + int(match[3])
    if seconds is None or seconds < _MIN_WALLTIME_S:
        raise bad_value("--walltime", text, f"HH:MM:SS from {WALLTIME_SPAN}")
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
        raise bad_value("--scheduler", address, "tcp://HOST:PORT or tls://HOST:PORT, e.g. tcp://10.0.0.1:8786")
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
