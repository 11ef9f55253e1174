"""The cluster options of a build (``shaderball build --cluster/--workers/--jobs/...``), checked.

:class:`ClusterOptions` is what the user asked for, each option declared once
(``pipeline.fields``; the command's options are generated from it);
:meth:`ClusterOptions.check` refuses a bad value or a mix of kinds with a message naming
the option, before anything starts.
``--memory`` takes dask's units (the value is handed to dask), so it is parsed with dask's
own parser; nothing else here touches dask.
"""

from __future__ import annotations

import re
import socket
from dataclasses import dataclass

from pipeline.errors import ShaderballError
from pipeline.fields import Checked, field
from pipeline.fields.rules import Choice, Int, Optional, Reject, Rule, Text, format_value, is_integer, parse_int

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
#: --gpus: a count of GPUs (the first N visible), or device ids (as CUDA numbers them here).
GPU_COUNT_RANGE = (1, 256)
GPU_ID_RANGE = (0, 255)
GPUS_PER_JOB_RANGE = (1, 64)


_MEMORY_TEXT = "an amount from 256MiB to 64TiB with a unit, e.g. 16GiB or 64GB"
_WALLTIME_TEXT = f"HH:MM:SS from {WALLTIME_SPAN}"
_SCHEDULER_TEXT = "tcp://HOST:PORT or tls://HOST:PORT, e.g. tcp://10.0.0.1:8786"


def memory_bytes(text: str) -> int:
    """``--memory`` in bytes (dask's units: 16GiB, 16GB, 16000MB), checked."""
    from dask.utils import parse_bytes

    try:  # dask reads any script's digits ("１６GiB"): ASCII only here, as every number
        value = parse_bytes(text) if text.isascii() and "_" not in text else None
    except (ValueError, TypeError):
        value = None
    if value is None or not _MIN_MEMORY <= value <= _MAX_MEMORY:
        raise ClusterOptions.field_error("memory", text, _MEMORY_TEXT)
    return int(value)


def walltime_seconds(text: str) -> int:
    match = _WALLTIME.match(text)
    seconds = None if match is None else int(match[1]) * 3600 + int(match[2]) * 60 + int(match[3])
    if seconds is None or seconds < _MIN_WALLTIME_S:
        raise ClusterOptions.field_error("walltime", text, _WALLTIME_TEXT)
    return seconds


def scheduler_host_port(address: str) -> tuple[str, int]:
    match = re.match(r"^(?:tcp|tls)://(\[[0-9A-Fa-f:]+\]|[A-Za-z0-9_.-]+):(\d{1,5})\Z", address, re.ASCII)
    if match is None or not 0 < int(match[2]) < 65536:
        raise ClusterOptions.field_error("scheduler", address, _SCHEDULER_TEXT)
    return match[1].strip("[]"), int(match[2])


class _Parsed(Rule):
    """A text that ``parse`` reads without a refusal (an amount of memory, a wall time, a
    scheduler's address); the text itself is kept."""

    def __init__(self, parse, allowed: str):
        self.parse_text, self.allowed = parse, allowed

    def check(self, value):
        if not isinstance(value, str):
            raise Reject()
        try:
            self.parse_text(value)
        except ShaderballError:
            raise Reject() from None
        return value


class Gpus(Rule):
    """``--gpus``: ``4`` (a count: the first 4 visible GPUs) or ``0,2`` (device ids, a list:
    a single id is written with a comma, ``3,``). Stored as an int or a tuple of ints."""

    allowed = (
        f"a count from {GPU_COUNT_RANGE[0]} to {GPU_COUNT_RANGE[1]} (e.g. 4), or device ids from "
        f"{GPU_ID_RANGE[0]} to {GPU_ID_RANGE[1]} separated by commas (e.g. 0,2; one id: 3,)"
    )
    metavar = "N|ID,ID,..."

    def parse(self, text: str):
        if "," not in text:
            return parse_int(text)
        return tuple(parse_int(part) for part in text.split(",") if part.strip())

    @property
    def brief(self) -> str:
        return (
            f"a count {GPU_COUNT_RANGE[0]} to {GPU_COUNT_RANGE[1]}, or ids {GPU_ID_RANGE[0]} to {GPU_ID_RANGE[1]} (0,2)"
        )

    def check(self, value):
        if isinstance(value, bool):
            raise Reject()
        if isinstance(value, int):
            if GPU_COUNT_RANGE[0] <= value <= GPU_COUNT_RANGE[1]:
                return value
            raise Reject()
        if not isinstance(value, (list, tuple)) or not value or not all(is_integer(v) for v in value):
            raise Reject()
        if not all(GPU_ID_RANGE[0] <= v <= GPU_ID_RANGE[1] for v in value):
            raise Reject()
        if len(set(value)) != len(value):
            raise Reject("(repeated ids)")
        return tuple(int(v) for v in value)


_SHELL_WORD_TEXT = "1 to 128 characters from A-Z a-z 0-9 _ . @ : + -"


@dataclass(frozen=True)
class ClusterOptions(Checked):
    """Where the workers of a build come from (the ``build`` command's cluster options).

    Options of another kind of cluster left at None; :meth:`check` refuses a mix.
    """

    cluster: str = field(
        "local", rule=Choice(KINDS), doc="Where workers run: this machine, or batch jobs via dask-jobqueue."
    )
    workers: int | None = field(
        None,
        rule=Optional(Int(*WORKERS_RANGE), "unset (one per 2 cores)", default_text="one per 2 cores"),
        doc="Local dask worker processes; 0 runs in this process without dask. Ignored with a scheduler.",
        unit="processes",
    )
    scheduler: str | None = field(
        None,
        rule=Optional(_Parsed(scheduler_host_port, _SCHEDULER_TEXT)),
        metavar="ADDRESS",
        doc="Use an existing dask scheduler, e.g. tcp://10.0.0.1:8786, instead of a local cluster "
        "(its workers need DIR at the same path; docs/cluster.md).",
    )
    jobs: int | None = field(
        None, rule=Optional(Int(*JOBS_RANGE)), doc="slurm/pbs: batch jobs (nodes); one worker each.", unit="jobs"
    )
    cores: int | None = field(
        None, rule=Optional(Int(*CORES_RANGE)), doc="slurm/pbs: cores per job; every render uses all.", unit="cores"
    )
    memory: str | None = field(
        None,
        rule=Optional(_Parsed(memory_bytes, _MEMORY_TEXT)),
        metavar="SIZE",
        doc="Memory per worker (local) or per job (slurm/pbs), e.g. 16GiB; a worker past 95% of "
        "its limit is restarted and its shard runs again.",
    )
    walltime: str | None = field(
        None,
        rule=Optional(_Parsed(walltime_seconds, _WALLTIME_TEXT)),
        metavar="HH:MM:SS",
        doc="slurm/pbs: wall-clock limit per job; workers retire about 5 min "
        "(or 5%; half the walltime below 10 min) before it and a new job replaces each.",
    )
    queue: str | None = field(
        None, rule=Optional(Text(_SHELL_WORD.pattern, _SHELL_WORD_TEXT)), doc="slurm/pbs: partition or queue."
    )
    account: str | None = field(
        None, rule=Optional(Text(_SHELL_WORD.pattern, _SHELL_WORD_TEXT)), doc="slurm/pbs: account to charge."
    )
    scratch: str | None = field(
        None,
        rule=Optional(
            Text(
                _SCRATCH.pattern,
                "a path of 1 to 256 characters from A-Z a-z 0-9 _ . / $ { } : + - "
                "(shell variables such as $TMPDIR are expanded on the node)",
            )
        ),
        metavar="DIR",
        doc="slurm/pbs: node-local folder for the kernel cache and dask's files "
        f"[default: {DEFAULT_SCRATCH}, expanded on the node].",
    )
    recycle_after: int = field(
        DEFAULT_RECYCLE_AFTER,
        rule=Int(*RECYCLE_AFTER_RANGE),
        metavar="RENDERS",
        doc="Restart a dask worker process once it has rendered this many samples "
        "(bounds Mitsuba's slow memory growth, docs/cluster.md); 0: never.",
        unit="renders",
    )
    start_timeout: int | None = field(
        None,
        rule=Optional(Int(*START_TIMEOUT_RANGE), "unset (wait as long as it takes)"),
        metavar="SECONDS",
        doc="Stop (exit 2, naming the jobs and why they wait) when the build has had no worker for "
        "this long: before the first one arrives, or after the last one left "
        "(e.g. a partition down). The dataset resumes with the same command. [default: wait "
        "as long as it takes]",
        unit="seconds",
    )

    gpus: int | tuple[int, ...] | None = field(
        None,
        rule=Optional(
            Gpus(), "unset (every visible GPU when the variant is cuda)", default_text="every visible GPU with cuda"
        ),
        doc="Local build: the GPUs to render on, a count (4: the first four visible) or device ids "
        "(0,2); one worker process per GPU (or {workers} spread over them), each pinned to its GPU "
        "through CUDA_VISIBLE_DEVICES.",
        metavar="N|IDS",
    )
    gpus_per_job: int | None = field(
        None,
        rule=Optional(Int(*GPUS_PER_JOB_RANGE)),
        doc="slurm/pbs: GPUs per job, asked of the batch system (--gres=gpu:N; PBS ngpus=N); the "
        "job runs one worker process per GPU, each pinned to one of the job's GPUs.",
        unit="GPUs",
    )

    @property
    def is_jobqueue(self) -> bool:
        return self.cluster in JOBQUEUE_KINDS

    def check_cross(self) -> None:
        """The options of one kind of cluster, not another's."""
        if self.start_timeout is not None and self.workers == 0 and not self.scheduler:
            raise self._refuse("start_timeout", "not allowed with {workers} 0", "there are no workers to wait for")
        if self.gpus is not None and (self.scheduler is not None or self.is_jobqueue or self.workers == 0):
            reason = (
                "{scheduler}" if self.scheduler is not None else "{workers} 0" if self.workers == 0 else "batch jobs"
            )
            instead = "use {gpus_per_job}" if self.is_jobqueue else "leave it out here"
            raise self._refuse("gpus", f"not allowed with {reason}", instead)
        if self.gpus_per_job is not None and not self.is_jobqueue:
            raise self._refuse(
                "gpus_per_job", "only with {cluster} slurm or {cluster} pbs", "use {gpus} on one machine"
            )
        if self.scheduler is not None and self.cluster != "local":
            raise self._refuse("scheduler", f"not allowed with {{cluster}} {self.cluster}", "use one or the other")
        if self.is_jobqueue:
            if self.workers is not None:
                raise self._refuse(
                    "workers", f"not allowed with {{cluster}} {self.cluster}", "use {jobs} (one worker process per job)"
                )
            for name, example in (("cores", "32"), ("memory", "64GiB"), ("walltime", "12:00:00")):
                if getattr(self, name) is None:
                    raise self._refuse(
                        name, f"required with {{cluster}} {self.cluster}", f"for example: {{{name}}} {example}"
                    )
        else:
            for name in ("jobs", "cores", "walltime", "queue", "account", "scratch"):
                if getattr(self, name) is not None:
                    raise self._refuse(name, "only with {cluster} slurm or {cluster} pbs", "leave it out here")
            if self.scheduler is not None and self.memory is not None:
                raise self._refuse(
                    "memory", "not allowed with {scheduler}", "give --memory-limit to `dask worker` instead"
                )

    def _refuse(self, name: str, what: str, allowed: str):
        return self.field_error(name, getattr(self, name), allowed, what=what)


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


def check_scheduler_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast with a clear message when nothing listens at ``address``."""
    host, port = scheduler_host_port(address)
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        raise ClusterOptions.field_error(
            "scheduler",
            address,
            "is `dask scheduler` running there?",
            what=f"cannot reach {format_value(address)} ({exc.strerror or exc})",
        ) from None
