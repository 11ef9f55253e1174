"""`shaderball build`: a spec to a sharded EXR dataset, in parallel, resumable.

The one module that knows about dask. A shard (pipeline.shard) is one task; tasks are
idempotent, so dask's at-least-once execution (a lost worker's tasks run again) is safe.
Worker processes are spawned, never forked (Mitsuba's LLVM JIT and fork() don't mix).
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

from pipeline.atomic import write_text_atomic
from pipeline.errors import ShaderballError
from pipeline.layout import Layout
from pipeline.plan import ShardPlan, plan_dataset, plan_summary
from pipeline.records import dumps, read_json
from pipeline.spec import DatasetSpec, parse_spec, parse_spec_text, spec_digest, spec_to_toml

LAYOUT_VERSION = 1


@dataclass
class Progress:
    """What a progress callback receives, about once a second and at the end."""

    done: int
    total: int
    elapsed_s: float
    rate: float  # renders per second since this build started rendering
    eta_s: float | None
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

    def lines(self) -> list[str]:
        rate = self.rendered / self.seconds if self.seconds > 0 else 0.0
        return [
            f"dataset {self.out}: {self.total} renders in {self.shards} shards, complete",
            f"rendered {self.rendered}, already present {self.skipped}, "
            f"{self.seconds:.1f} s ({rate:.2f} renders/s)",
            f"manifest: {os.path.join(self.out, 'manifest.jsonl')}",
        ] + self.notes


def read_spec_text(spec_path: str) -> tuple[DatasetSpec, str]:
    try:
        with open(spec_path, encoding="utf-8") as fh:
            text = fh.read()
    except OSError as exc:
        raise ShaderballError(f"SPEC: cannot read {spec_path!r}: {exc.strerror}") from None
    return parse_spec(spec_path), text


def check_output_dir(out: str, spec: DatasetSpec) -> str:
    """Refuse an output directory that holds something else; return 'new' or 'resume'."""
    layout = Layout(out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise ShaderballError(f"--out: {out!r} exists and is not a directory")
    if not os.path.isdir(out) or not os.listdir(out):
        parent = os.path.dirname(os.path.abspath(out))
        probe = parent
        while not os.path.exists(probe):
            probe = os.path.dirname(probe)
        if not os.access(probe, os.W_OK):
            raise ShaderballError(f"--out: {out!r} cannot be created: {probe} is not writable")
        return "new"
    if not os.path.isfile(layout.spec):
        raise ShaderballError(
            f"--out: {out!r} is not empty and holds no {os.path.basename(layout.spec)}: "
            "not a shaderball dataset; choose an empty or new directory")
    try:
        existing = parse_spec(layout.spec)
    except ShaderballError as exc:
        raise ShaderballError(f"--out: the spec snapshot in {out!r} is unreadable ({exc}); "
                              "run `shaderball validate --repair` or choose another directory") from None
    if spec_digest(existing) != spec_digest(spec):
        raise ShaderballError(
            f"--out: {out!r} holds dataset {existing.dataset.name!r} built from a different spec "
            f"(digest {spec_digest(existing)[:12]} vs {spec_digest(spec)[:12]}); "
            "resume it with its own spec (DIR/spec.toml) or choose another directory")
    if not os.access(out, os.W_OK):
        raise ShaderballError(f"--out: {out!r} is not writable")
    return "resume"


def description(spec: DatasetSpec, plans: list[ShardPlan], variant: str) -> dict:
    from pipeline import __version__
    from pipeline.mitsuba_env import library_versions

    return {
        "name": spec.dataset.name,
        "version": spec.dataset.version,
        "layout_version": LAYOUT_VERSION,
        "spec_digest": spec_digest(spec),
        "shaderball": __version__,
        "libraries": library_versions(),
        "variant": variant,
        "counts": plan_summary(plans),
        "colorspace": "linear Rec.709 (sRGB primaries, D65 white)",
    }


def prepare(out: str, spec: DatasetSpec, plans: list[ShardPlan]) -> str:
    """Create ``out`` with the spec snapshot and description; return the Mitsuba variant."""
    from pipeline.mitsuba_env import load_mitsuba

    mode = check_output_dir(out, spec)
    variant = load_mitsuba(spec.render.variant).variant()
    os.makedirs(out, exist_ok=True)
    layout = Layout(out)
    if mode == "new":
        write_text_atomic(layout.spec, spec_to_toml(spec))
    write_text_atomic(layout.description, dumps(description(spec, plans, variant)) + "\n")
    return variant


def count_done(out: str, plans: list[ShardPlan]) -> int:
    """Renders with a record on disk (progress; cheap: one listing per shard)."""
    layout = Layout(out)
    done = 0
    for shard in plans:
        folder = layout.shard_dir(shard.shard_id)
        try:
            names = os.listdir(folder)
        except FileNotFoundError:
            continue
        if "COMPLETE.json" in names:
            done += shard.n_renders
        else:
            done += sum(1 for n in names if n.endswith(".json") and not n.startswith("."))
    return done


def write_manifest(out: str, plans: list[ShardPlan]) -> int:
    """manifest.jsonl from the shard markers, in plan order; return the record count."""
    layout = Layout(out)
    lines = []
    for shard in plans:
        marker = read_json(layout.marker(shard.shard_id))
        if not marker or not marker.get("complete"):
            raise ShaderballError(f"shard {shard.shard_id} is not complete; cannot write the manifest")
        lines.extend(dumps(record) for record in marker["records"])
    write_text_atomic(layout.manifest, "".join(line + "\n" for line in lines))
    return len(lines)


def render_threads(workers: int) -> int:
    return max(1, (os.cpu_count() or 1) // max(1, workers))


def _run_shard_task(out: str, spec: DatasetSpec, shard: ShardPlan, threads: int) -> dict:
    """The dask task: one shard, with a bounded Mitsuba thread pool in this worker."""
    from pipeline.mitsuba_env import load_mitsuba
    from pipeline.shard import run_shard

    load_mitsuba(spec.render.variant)
    import drjit as dr

    if dr.thread_count() != threads:
        dr.set_thread_count(threads)
    return run_shard(out, spec, shard)


def build(spec_path: str, out: str, *, workers: int | None = None, scheduler: str | None = None,
          progress: Callable[[Progress], None] | None = None,
          on_start: Callable[[str, str | None], None] | None = None) -> BuildSummary:
    """Build (or resume) the dataset of ``spec_path`` into ``out``.

    ``workers``: local worker processes (default: one per 2 cores); 0 runs the shards in
    this process, without dask. ``scheduler``: address of an existing dask scheduler
    (then ``workers`` is ignored).
    """
    spec, _text = read_spec_text(spec_path)
    if workers is not None and (isinstance(workers, bool) or workers < 0 or workers > 1024):
        raise ShaderballError(f"--workers: {workers!r} is not allowed; allowed: an integer in [0, 1024]")
    plans = plan_dataset(spec)
    variant = prepare(out, spec, plans)
    total = sum(s.n_renders for s in plans)
    layout = Layout(out)
    todo = [s for s in plans if not (read_json(layout.marker(s.shard_id)) or {}).get("complete")]
    already = total - sum(s.n_renders for s in todo)
    start = time.perf_counter()
    results: list[dict] = []
    dashboard = None
    if todo:
        if workers == 0 and scheduler is None:
            if on_start:
                on_start("in-process (no dask)", None)
            threads = os.cpu_count() or 1
            for shard in todo:
                results.append(_run_shard_task(out, spec, shard, threads))
                _report(progress, out, plans, total, already, start)
        else:
            results, dashboard = _run_with_dask(out, spec, plans, todo, total, already, start,
                                                workers, scheduler, progress, on_start)
    write_manifest(out, plans)
    seconds = time.perf_counter() - start
    rendered = sum(r["rendered"] for r in results)
    _report(progress, out, plans, total, already, start)
    return BuildSummary(out=out, total=total, rendered=rendered, skipped=total - rendered,
                        seconds=seconds, shards=len(plans), dashboard=dashboard,
                        notes=[f"variant {variant}"])


def _report(progress, out, plans, total, already, start):
    if progress is None:
        return
    done = count_done(out, plans)
    elapsed = time.perf_counter() - start
    new = max(0, done - already)
    rate = new / elapsed if elapsed > 0 else 0.0
    eta = (total - done) / rate if rate > 0 else None
    progress(Progress(done=done, total=total, elapsed_s=elapsed, rate=rate, eta_s=eta))


def _run_with_dask(out, spec, plans, todo, total, already, start, workers, scheduler, progress, on_start):
    import dask
    from distributed import Client, LocalCluster, as_completed

    cluster = None
    with dask.config.set({"distributed.worker.multiprocessing-method": "spawn",
                          "distributed.worker.daemon": False,
                          "distributed.scheduler.allowed-failures": 5}):
        if scheduler:
            try:
                client = Client(scheduler, timeout="20s")
            except OSError as exc:
                raise ShaderballError(f"--scheduler: cannot reach {scheduler!r}: {exc}") from None
            n_workers = max(1, len(client.scheduler_info().get("workers", {})))
            threads = None  # remote workers size their own pools
        else:
            n_workers = workers or max(1, (os.cpu_count() or 1) // 2)
            cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=40)
            client = Client(cluster)
            threads = render_threads(n_workers)
        try:
            dashboard = client.dashboard_link if _has_dashboard() else None
            if on_start:
                on_start(scheduler or f"local cluster, {n_workers} worker process(es)", dashboard)
            spec_future = client.scatter(spec, broadcast=True)
            futures = [client.submit(_run_shard_task, out, spec_future, shard,
                                     threads or render_threads(1), key=f"shard-{shard.shard_id}-{os.getpid()}",
                                     pure=False)
                       for shard in todo]
            stop = threading.Event()

            def report_loop():
                while not stop.wait(1.0):
                    _report(progress, out, plans, total, already, start)

            reporter = threading.Thread(target=report_loop, daemon=True)
            reporter.start()
            try:
                results = [f.result() for f in as_completed(futures)]  # raises a task's error here
            finally:
                stop.set()
                reporter.join()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    return results, dashboard


def _has_dashboard() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True
