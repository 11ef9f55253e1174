"""`shaderball build`: a spec to a sharded EXR dataset, in parallel, resumable.

A shard (:mod:`pipeline.run.shard`) is one dask task; tasks are idempotent, so dask's
at-least-once execution (a lost worker's tasks run again, possibly while the first run
still goes on) is safe. This module submits the tasks; :mod:`pipeline.run.cluster` provides
the workers (a local cluster, a scheduler address, SLURM or PBS). Worker processes are
spawned, never forked (Mitsuba's LLVM JIT and fork() don't mix).

Resume (docs/resume.md): a build on an existing directory of the same spec trusts every
shard with a complete marker, re-renders only samples whose record does not verify, and
rewrites the manifest. A different spec is refused, except a change of the fields no
sample depends on (``dataset.name``, ``dataset.version``) with ``allow_spec_change``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

from geometry.objects import BUILTIN_OBJECTS, build_object
from pipeline.dataset.materialize import check_imported_files
from pipeline.dataset.plan import Plan, plan_dataset
from pipeline.dataset.spec import DatasetSpec
from pipeline.dataset.spec_file import environment_files, spec_to_toml
from pipeline.errors import ShaderballError, filesystem_error, quoted
from pipeline.render.envmap import load_environment
from pipeline.render.mitsuba_env import (
    determinism,
    resolve_variant,
    weakest_guarantee,
)
from pipeline.render.renderer import MaterialScene
from pipeline.run.cluster.connection import run_shards_on_dask
from pipeline.run.cluster.options import ClusterOptions, check_scheduler_reachable
from pipeline.run.out_folder import (
    check_output_dir,
    check_same_installation,
    description,
    plan_digest,
    read_spec_text,
    recorded_guarantee,
)
from pipeline.run.shard import run_shard_in_process
from pipeline.store.atomic import write_chunks_atomic, write_text_atomic
from pipeline.store.folder import (
    complete_marker,
    record_stamps,
    recorded_count,
    remove_temp_files,
    shard_ids_on_disk,
)
from pipeline.store.layout import MANIFEST_FILE, Layout
from pipeline.store.lock import writer_lock
from pipeline.store.records import dumps


@dataclass
class Progress:
    """What a progress callback receives, about once a second and at the end."""

    done: int
    total: int
    elapsed_s: float
    rate: float  # renders per second since this build started rendering
    eta_s: float | None
    #: what the build waits on, e.g. "0 worker(s); slurm jobs: 1 pending (job 7: PartitionDown)".
    message: str = ""


@dataclass
class BuildSummary:
    out: str
    total: int
    rendered: int
    skipped: int
    seconds: float
    shards: int
    dashboard: str | None = None
    notes: list[str] = field(default_factory=list)
    #: worker processes whose shard results came back (0 when nothing was to do).
    processes: int = 0
    #: stale temporary files of killed writes removed at the end.
    temp_removed: int = 0
    #: worker processes that restarted themselves (``--recycle-after``).
    recycled: int = 0

    def lines(self) -> list[str]:
        rate = self.rendered / self.seconds if self.seconds > 0 else 0.0
        return [
            f"dataset {self.out}: {self.total} renders in {self.shards} shards, complete",
            f"rendered {self.rendered}, already present {self.skipped}, {self.seconds:.1f} s ({rate:.2f} renders/s)",
            f"manifest: {self.manifest}",
        ] + self.notes

    @property
    def manifest(self) -> str:
        return os.path.join(self.out, MANIFEST_FILE)

    def to_dict(self) -> dict:
        return {**asdict(self), "manifest": self.manifest}


def prepare(
    out: str,
    spec: DatasetSpec,
    plans: Plan,
    allow_spec_change: bool = False,
    tick: Callable[[int, int], None] | None = None,
    variant: str | None = None,
) -> str:
    """Create ``out`` with the spec snapshot and description; return the Mitsuba variant.

    The variant is resolved here, once, from the spec (or ``variant``: validate --repair
    passes the one dataset.json records, not what ``auto`` would pick on this machine);
    every worker is given this name. The dataset's determinism guarantee is the weakest of
    the variant's and the one already recorded: a resume never promises more than the
    renders it keeps. ``tick(shards, of)`` follows the plan digest (every shard planned and
    hashed once).
    """
    mode = check_output_dir(out, spec, allow_spec_change)
    variant = resolve_variant(variant or spec.render.variant)
    guarantee = determinism(variant)
    digest = plan_digest(plans, tick)
    if mode != "new":
        check_same_installation(out, plans, variant, digest)
        guarantee = weakest_guarantee(guarantee, recorded_guarantee(out))
    os.makedirs(out, exist_ok=True)
    layout = Layout(out)
    if mode in ("new", "respec"):
        write_text_atomic(layout.spec, spec_to_toml(spec))
    write_text_atomic(layout.description, dumps(description(spec, plans, variant, digest, guarantee)) + "\n")
    return variant


def check_scene_sources(spec: DatasetSpec) -> None:
    """Every mesh file and environment map the spec names through its gate, before anything is
    written: a mesh is bounded, checked and built into the geometry cache (where the workers load
    it), a map read, bounded and checked (finite, non-negative radiance). A refused file stops
    the build here with the file and the reason (exit 2), not in a worker halfway through."""
    for name in spec.scene.objects:
        if name not in BUILTIN_OBJECTS:
            build_object(name)
    for path in environment_files(spec):
        load_environment(path)


def count_done(out: str, plans: Plan) -> int:
    """Renders with a record on disk (progress; cheap: one listing per shard)."""
    return DoneCounter(out, plans)()


class DoneCounter:
    """Renders with a record on disk, counted again at each progress report: one listing of
    ``shards/``, then one of each shard folder not yet seen complete (a complete shard is
    remembered), so a report costs the shards in progress, not all of them."""

    def __init__(self, out: str, plans: Plan):
        self.layout = Layout(out)
        self.counts = dict(plans.shard_counts())
        self.complete: set[str] = set()

    def __call__(self) -> int:
        started = set(shard_ids_on_disk(self.layout)) & self.counts.keys()
        done = sum(self.counts[sid] for sid in self.complete)
        for sid in started - self.complete:
            planned = self.counts[sid]
            count = recorded_count(self.layout, sid, planned)
            if count == planned and os.path.lexists(self.layout.marker(sid)):
                self.complete.add(sid)
            done += count
        return done


def write_manifest(out: str, plans: Plan) -> int:
    """manifest.jsonl from the shard markers, in plan order; return the record count."""
    layout = Layout(out)
    count = 0

    def shard_lines():
        nonlocal count
        for index, (sid, _renders) in enumerate(plans.shard_counts()):
            records = complete_marker(layout, sid, plans.shard_sample_ids(index))
            if records is None:
                raise ShaderballError(f"shard {sid} is not complete; cannot write the manifest")
            count += len(records)
            yield "".join(dumps(record) + "\n" for record in records).encode("utf-8")

    write_chunks_atomic(layout.manifest, shard_lines())  # streamed: never held whole
    return count


def renders_written(out: str, shards, before: dict[str, tuple[int, int]]) -> int:
    """Samples of ``shards`` ((shard id, sample ids) pairs) whose record this build wrote.

    Counted on disk, not from task results: under at-least-once execution a task's result
    can be lost (its worker died or was recycled after the shard was done) and the re-run
    reports nothing rendered. A record counts when it is new or its (inode, mtime) differs
    from ``before`` (:func:`pipeline.store.folder.record_stamps`, taken before the build).
    """
    layout = Layout(out)
    count = 0
    for sid, ids in shards:
        for sample in ids:
            path = layout.path(layout.record_rel(sid, sample))
            try:
                st = os.stat(path, follow_symlinks=False)
            except FileNotFoundError:
                continue
            if before.get(path) != (st.st_ino, st.st_mtime_ns):
                count += 1
    return count


def sweep_temp_files(out: str, plans: Plan, older_than: float) -> int:
    """Remove temporary files (of writes killed mid-way) last modified before ``older_than``.

    Called once a build is complete, with the time then: every write the build waited for
    has finished, and the folder's writer lock keeps other builds out, so a temp file belongs
    to a killed writer (of an earlier build, or a worker killed during this one). Removing a
    live writer's temp file (a task of a worker wrongly declared dead, still running) cannot
    corrupt anything: its rename fails, and the sample is committed already. Return the
    count removed.
    """
    return remove_temp_files(Layout(out), [sid for sid, _renders in plans.shard_counts()], older_than)


def build(
    spec_path: str,
    out: str,
    *,
    cluster: ClusterOptions = ClusterOptions(),
    allow_spec_change: bool = False,
    progress: Callable[[Progress], None] | None = None,
    on_start: Callable[[str, str | None], None] | None = None,
    variant: str | None = None,
) -> BuildSummary:
    """Build (or resume) the dataset of ``spec_path`` into ``out``.

    ``cluster``: where the workers come from, every option of ``shaderball build``'s
    ``--cluster``/``--workers``/``--scheduler``/... (default: a local cluster of one worker
    process per 2 cores); ``ClusterOptions(workers=0)`` runs the shards in this process,
    without dask; ``ClusterOptions(scheduler=ADDRESS)`` uses an existing dask scheduler, which
    must answer before anything is written. ``allow_spec_change``: accept a spec that differs
    from the directory's snapshot in ``dataset.name`` / ``dataset.version`` only. ``variant``: the
    Mitsuba variant instead of the spec's ``render.variant`` resolved anew (validate --repair
    passes the dataset's recorded one).
    """
    spec, _text = read_spec_text(spec_path)
    if cluster.scheduler:
        check_scheduler_reachable(cluster.scheduler)  # before anything is written
    plans = plan_dataset(spec)
    check_imported_files(plans)
    check_output_dir(out, spec, allow_spec_change)  # refused here, nothing is created
    check_scene_sources(spec)  # so is a bad mesh or map
    try:
        os.makedirs(out, exist_ok=True)
        with writer_lock(out, "build"):
            return _build_locked(out, spec, plans, cluster, allow_spec_change, progress, on_start, variant)
    except OSError as exc:  # a full disk, a folder that cannot be written, ...: a message, not a traceback
        raise filesystem_error(
            exc,
            out,
            f"every write is atomic, so nothing in {quoted(out)} is torn: fix the "
            "cause and run the same command again to resume",
        ) from None


def _build_locked(
    out: str,
    spec: DatasetSpec,
    plans: Plan,
    cluster: ClusterOptions,
    allow_spec_change: bool,
    progress,
    on_start,
    variant: str | None = None,
) -> BuildSummary:
    """The build, once this process holds ``out`` (pipeline.store.lock): the folder is
    checked again (another writer may have finished in between), then written."""
    counts = plans.shard_counts()
    total = sum(renders for _sid, renders in counts)
    variant = prepare(out, spec, plans, allow_spec_change, _planning_ticks(progress, total), variant)
    layout = Layout(out)
    on_disk = set(shard_ids_on_disk(layout))
    todo = [
        i
        for i, (sid, _renders) in enumerate(counts)
        if sid not in on_disk or complete_marker(layout, sid, plans.shard_sample_ids(i)) is None
    ]
    already = total - sum(counts[i][1] for i in todo)
    start = time.perf_counter()
    stamps = record_stamps(layout, [counts[i][0] for i in todo if counts[i][0] in on_disk])
    done = DoneCounter(out, plans)
    results: list[dict] = []
    dashboard, recycled = None, 0
    if todo:
        if cluster.workers == 0 and cluster.scheduler is None and not cluster.is_jobqueue:
            if on_start:
                on_start("in-process (no dask)", None)
            threads = os.cpu_count() or 1
            with MaterialScene() as scene:  # one loaded scene for every shard, moved from material to material
                for index in todo:  # one shard planned at a time: a lazy plan is never held whole
                    results.append(run_shard_in_process(out, spec, plans[index], variant, threads, scene))
                    _report(progress, done, total, already, start)
        else:

            def report(status: str = ""):
                _report(progress, done, total, already, start, status)

            with sigint_at_safe_points(on_start, report) as (started, reported):
                results, dashboard, recycled = run_shards_on_dask(
                    out, spec, [plans[i] for i in todo], variant, cluster, reported, started
                )
    write_manifest(out, plans)
    # Every temp file, this build's too: a worker killed mid-write during the build (a SLURM job
    # cancelled, requeued or at its walltime) leaves one that no later write of it removes.
    removed = sweep_temp_files(out, plans, older_than=time.time())
    seconds = time.perf_counter() - start
    rendered = renders_written(out, ((counts[i][0], plans.shard_sample_ids(i)) for i in todo), stamps)
    _report(progress, done, total, already, start)
    processes = len({r["pid"] for r in results})
    notes = [f"variant {variant}"]
    if removed:
        notes.append(f"removed {removed} temporary file(s) left by interrupted writes")
    if recycled:
        notes.append(f"{recycled} worker process restart(s) to bound memory (--recycle-after)")
    notes.extend(per_gpu_notes(results, seconds))
    return BuildSummary(
        out=out,
        total=total,
        rendered=rendered,
        skipped=total - rendered,
        seconds=seconds,
        shards=len(plans),
        dashboard=dashboard,
        notes=notes,
        processes=processes,
        temp_removed=removed,
        recycled=recycled,
    )


def per_gpu_notes(results: list[dict], seconds: float) -> list[str]:
    """One note of each GPU's renders and rate, from the shards of workers pinned to a GPU."""
    rendered: dict[str, int] = {}
    for result in results:
        if result.get("device") is not None:
            rendered[result["device"]] = rendered.get(result["device"], 0) + result["rendered"]
    if not rendered:
        return []
    each = ", ".join(
        f"GPU {device}: {n} ({n / seconds:.2f}/s)" if seconds > 0 else f"GPU {device}: {n}"
        for device, n in sorted(rendered.items())
    )
    return [f"renders per GPU: {each}"]


@contextlib.contextmanager
def sigint_at_safe_points(on_start, report):
    """Ctrl-C of a dask build is acted on where the driver can close its cluster cleanly: once
    the cluster is up (``on_start``) and between two looks at the shards (``report``, about
    every second). The handler only records it.

    Why not where it lands: a Ctrl-C raised as KeyboardInterrupt anywhere in the driver can
    land inside dask's or a finalizer's code (where Python prints "Exception ignored" with a
    traceback and the build goes on), or while a LocalCluster starts, whose half-made nannies
    nothing would close. Why not ignore it while the cluster starts: SIGINT's disposition is
    the process's and its mask is each thread's; a Ctrl-C that the kernel hands to one of the
    driver's other threads (which do not block it; multiprocessing's resource tracker unblocks
    it in the thread that starts it) is discarded while it is ignored, and the build runs on
    to the end. The workers ignore SIGINT themselves
    (pipeline.run.cluster.connection.spawned_ignoring_sigint). A second Ctrl-C before the
    first is acted on stops the driver at once."""
    if threading.current_thread() is not threading.main_thread():  # signal handlers are the main thread's
        yield on_start, report
        return
    caught: list[float] = []

    def note(signum, frame):
        if caught:
            raise KeyboardInterrupt
        caught.append(time.monotonic())

    def check() -> None:
        if caught:
            raise KeyboardInterrupt

    def started(where, dashboard):
        check()
        if on_start:
            on_start(where, dashboard)

    def reported(status: str = ""):
        check()
        report(status)

    previous = signal.signal(signal.SIGINT, note)
    try:
        yield started, reported
    finally:
        signal.signal(signal.SIGINT, previous)
    check()  # a Ctrl-C after the last look: the shards are done, the manifest is not written


def _planning_ticks(progress, total: int):
    """A ``tick(shards, of)`` for :func:`prepare` that shows the planning as progress (at
    once, then about twice a second): a spec of millions of renders takes a while to plan."""
    if progress is None:
        return None
    start, last = time.perf_counter(), [-1.0]

    def tick(shards: int, of: int) -> None:
        now = time.perf_counter()
        if now - last[0] >= 0.5 or shards == of:
            last[0] = now
            progress(
                Progress(
                    done=0,
                    total=total,
                    elapsed_s=now - start,
                    rate=0.0,
                    eta_s=None,
                    message=f"planning: {shards}/{of} shards planned and checked",
                )
            )

    return tick


def _report(progress, counter, total, already, start, status=""):
    if progress is None:
        return
    done = counter()
    elapsed = time.perf_counter() - start
    new = max(0, done - already)
    rate = new / elapsed if elapsed > 0 else 0.0
    eta = (total - done) / rate if rate > 0 else None
    progress(Progress(done=done, total=total, elapsed_s=elapsed, rate=rate, eta_s=eta, message=status))
