"""`shaderball plan SPEC`: what a build of SPEC will be, before it starts.

From the spec alone (no rendering; `shaderball info SPEC` prints this part): the counts
(renders, materials by kind, lightings, shards) and the disk size, derived from the
resolution and the layers, channels and float widths the store writes
(:func:`pipeline.store.exr.pixel_bytes`): pixel data before EXR's lossless compression.

Timed (`shaderball plan`): the spec's own first samples (whole materials, in plan order, and
the first material of each kind they lack: an svbrdf material also makes texture maps) are
built with the build's own shard code (:func:`pipeline.run.shard.run_shard`) into a temporary
folder, at the spec's settings, in this process with every core, kernels compiled first
and timed apart (a build compiles them once per worker), each kind on its own. Their wall
time per render, and the bytes the folder then holds per render, weighed by the spec's
counts of each kind, are extrapolated to the whole spec: in this
process, on a local cluster of worker processes sharing the cores, or on ``--cluster
slurm|pbs`` jobs of ``--cores`` each, a shard at a time per worker (per-worker arithmetic:
rounds of shards x a shard's renders x seconds per render x this machine's cores / the
worker's cores; a remote core is taken to be as fast as one here).
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass

from pipeline.bench.build_bench import warm_kernels
from pipeline.dataset.plan import Plan, ShardPlan, plan_dataset
from pipeline.dataset.spec import spec_digest
from pipeline.fields import Bool, Checked, Int, Path, field, same_as
from pipeline.render.mitsuba_env import load_mitsuba, resolve_variant
from pipeline.run.build import read_spec_text
from pipeline.run.cluster.options import JOBQUEUE_KINDS, ClusterOptions
from pipeline.run.shard import make_shard_dir, run_shard
from pipeline.store.exr import MATERIAL_MAP_LAYERS, pixel_bytes
from pipeline.store.layout import MARKER_FILE, Layout

#: Renders timed (whole materials, so at least this many).
RENDERS_RANGE = (1, 1000)
DEFAULT_RENDERS = 4


@dataclass(frozen=True)
class PlanRequest(Checked):
    """What `shaderball plan` is asked; the cluster's fields are ClusterOptions' declarations."""

    spec: str = field(rule=Path("a spec file", exists="file"), doc="The spec file.", positional=True, metavar="SPEC")
    renders: int = field(
        DEFAULT_RENDERS,
        rule=Int(*RENDERS_RANGE),
        doc="Renders to time: the spec's first materials, whole (so at least this many).",
        unit="renders",
    )
    timing: bool = field(
        True,
        rule=Bool(),
        doc="Render the spec's first renders and time them; without: counts and disk only, nothing "
        "rendered (what `info SPEC` prints).",
    )
    cluster: str = same_as(
        ClusterOptions,
        "cluster",
        doc="Also estimate the time on slurm or pbs batch jobs (of the jobs and cores below), as a "
        "build on that cluster would run them.",
    )
    workers: int | None = same_as(
        ClusterOptions, "workers", doc="Local dask worker processes to estimate for; 0: this process without dask."
    )
    jobs: int | None = same_as(ClusterOptions, "jobs")
    cores: int | None = same_as(ClusterOptions, "cores")

    def check(self) -> PlanRequest:
        return self.check_fields()

    def check_cross(self) -> None:
        if self.cluster in JOBQUEUE_KINDS:
            if self.workers is not None:
                raise self._refuse("workers", f"not allowed with {{cluster}} {self.cluster}", "use {jobs}")
            for name, example in (("jobs", "8"), ("cores", "32")):
                if getattr(self, name) is None:
                    raise self._refuse(
                        name, f"required with {{cluster}} {self.cluster}", f"for example: {{{name}}} {example}"
                    )
        else:
            for name in ("jobs", "cores"):
                if getattr(self, name) is not None:
                    raise self._refuse(name, "only with {cluster} slurm or {cluster} pbs", "leave it out here")

    def _refuse(self, name: str, what: str, allowed: str):
        return self.field_error(name, getattr(self, name), allowed, what=what)


@dataclass
class Timing:
    """The timed renders: the spec's first materials, built as a build builds them."""

    renders: int
    materials: int
    uniform: int
    svbrdf: int
    variant: str
    threads: int  # render threads in this process (this machine's cores)
    setup_s: float  # geometry, G-buffer and kernel compilation, once per worker
    seconds: float  # the timed build of those materials (wall)
    seconds_per_render: float
    cpu_seconds_per_render: float  # CPU time of this process (every thread) per render: less disturbed by other load
    load_average: float  # the machine's 1-minute load average after the timed renders
    bytes_per_render: float  # what a dataset holds per render: EXRs, records, markers, manifest line
    #: "uniform"/"svbrdf" -> materials, renders, seconds, seconds_per_render, cpu_seconds_per_render,
    #: bytes_per_render of that kind's timed materials; the figures above weigh them by the spec's counts
    by_kind: dict = dataclasses.field(default_factory=dict)


@dataclass
class Estimate:
    where: str
    workers: int
    threads_per_worker: int
    rounds: int  # shards each worker builds, one after another (the busiest worker's)
    shard_seconds: float  # one full shard on one worker
    seconds: float  # the whole spec, setup included


@dataclass
class PlanReport:
    spec: str
    name: str
    version: str
    spec_digest: str
    renders: int
    materials: int
    uniform: int
    svbrdf: int
    lights_per_material: int
    shards: int
    shard_size: int  # materials per shard
    renders_per_shard: int
    resolution: int
    spp: int
    variant: str  # the spec's (auto, llvm, cuda, ...)
    disk: dict
    timing: Timing | None = None
    estimates: list[Estimate] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)

    def lines(self) -> list[str]:
        d = self.disk
        out = [
            f"spec {self.spec}: {self.name} v{self.version}, digest {self.spec_digest[:12]}",
            f"renders: {self.renders:,} = {self.materials:,} materials ({self.uniform:,} uniform, "
            f"{self.svbrdf:,} svbrdf) x {self.lights_per_material} lightings; {self.resolution}x{self.resolution} px, "
            f"{self.spp} spp, variant {self.variant}",
            f"shards: {self.shards:,} of {self.shard_size} materials ({self.renders_per_shard} renders)",
            f"disk (pixel data before EXR compression): {_human(d['total_bytes'])} = renders "
            f"{_human(d['render_bytes'])} ({_human(d['bytes_per_render'])} each) + screen-space maps "
            f"{_human(d['maps_bytes'])} ({_human(d['bytes_per_material_maps'])} a material) + texture maps "
            f"{_human(d['texture_bytes'])}",
        ]
        t = self.timing
        if t is not None:
            kinds = ", ".join(
                f"{k['renders']} {kind} at {k['seconds_per_render']:.3f} s each" for kind, k in t.by_kind.items()
            )
            out.append(
                f"timed: {t.renders} renders ({kinds}) of {t.materials} materials (the spec's first, and the first of each kind), "
                f"{t.variant}, "
                f"{t.threads} threads: {t.seconds_per_render:.3f} s a render in the spec's mix "
                f"(CPU {t.cpu_seconds_per_render:.3f} s a render; load average {t.load_average:.1f}), set-up {t.setup_s:.2f} s (geometry, G-buffer, kernels; once per worker)"
            )
            out.append(
                f"disk as written (EXR compressed, records, markers, manifest): {_human(t.bytes_per_render)} a "
                f"render, {_human(t.bytes_per_render * self.renders)} in all"
            )
            for e in self.estimates:
                out.append(
                    f"time, {e.where}: {e.seconds:,.0f} s ({_hours(e.seconds)}); {e.workers} worker(s) x "
                    f"{e.threads_per_worker} thread(s), {e.rounds} shard(s) each at {e.shard_seconds:,.1f} s"
                )
        out.extend(f"note: {n}" for n in self.notes)
        return out


def _human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} TiB"


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.1f} min"


def disk_estimate(spec, uniform: int, svbrdf: int) -> dict:
    """Pixel bytes of every file a build writes, from the store's layers and float widths."""
    storage, side = spec.storage, spec.render.resolution
    half = MATERIAL_MAP_LAYERS if storage.maps_half else ()
    per_render = pixel_bytes(("render",), side)
    per_maps = pixel_bytes(storage.layers, side, half)
    # Uniform materials store 1x1 texture maps; procedural and imported SVBRDFs texture_resolution
    # square ones (an imported file keeps its own size: this assumes the spec's).
    tex_uniform = pixel_bytes(MATERIAL_MAP_LAYERS, 1, half) if storage.texture_maps else 0
    tex_svbrdf = (
        pixel_bytes(MATERIAL_MAP_LAYERS, spec.materials.texture_resolution, half) if storage.texture_maps else 0
    )
    materials = uniform + svbrdf
    render_bytes = per_render * spec.dataset.n_renders
    maps_bytes = per_maps * materials
    texture_bytes = tex_uniform * uniform + tex_svbrdf * svbrdf
    return {
        "bytes_per_render": per_render,
        "bytes_per_material_maps": per_maps,
        "bytes_per_texture": {"uniform": tex_uniform, "svbrdf": tex_svbrdf},
        "render_bytes": render_bytes,
        "maps_bytes": maps_bytes,
        "texture_bytes": texture_bytes,
        "total_bytes": render_bytes + maps_bytes + texture_bytes,
        "basis": "pixel data as the store lays it out (renders float32; maps half where storage.maps_half, "
        "the mask float32), before EXR's lossless compression; headers and records not counted",
    }


def plan_spec(req: PlanRequest, progress=None) -> PlanReport:
    """Counts and disk of ``req.spec``; with ``req.timing`` also the timed renders and the time
    estimates (``progress(str)`` says when they start). Nothing is written outside a temporary
    folder, removed after."""
    req.check()
    spec, _text = read_spec_text(req.spec)
    plans = plan_dataset(spec)
    summary = plans.summary()
    ds = spec.dataset
    report = PlanReport(
        spec=req.spec,
        name=ds.name,
        version=ds.version,
        spec_digest=spec_digest(spec),
        renders=ds.n_renders,
        materials=ds.materials,
        uniform=summary["uniform"],
        svbrdf=summary["svbrdf"],
        lights_per_material=ds.lights_per_material,
        shards=ds.n_shards,
        shard_size=ds.shard_size,
        renders_per_shard=min(ds.shard_size, ds.materials) * ds.lights_per_material,
        resolution=spec.render.resolution,
        spp=spec.render.spp,
        variant=spec.render.variant,
        disk=disk_estimate(spec, summary["uniform"], summary["svbrdf"]),
    )
    if not req.timing:
        return report
    if progress is not None:
        progress(
            f"timing the first {req.renders}+ renders of {req.spec} at its settings (kernels compiled first; "
            "nothing is kept) ..."
        )
    report.timing = time_first_samples(spec, plans, req.renders, {"uniform": report.uniform, "svbrdf": report.svbrdf})
    report.estimates = estimates(report, req)
    if spec.render.target_error > 0:
        report.notes.append(
            "render.target_error is on: a render stops when it reaches the target, so its time varies with "
            "the material and lighting; the timed ones stand for all"
        )
    t = report.timing
    if t.load_average > t.threads:
        idle = t.setup_s + report.renders * t.cpu_seconds_per_render / t.threads
        report.notes.append(
            f"the machine was busy (load average {t.load_average:.1f} on {t.threads} cores): wall times are "
            f"longer than on an idle machine; from the CPU time per render ({t.cpu_seconds_per_render:.3f} s) "
            f"this process would take about {idle:,.0f} s ({_hours(idle)}) with the cores to itself"
        )
    return report


def first_materials(plans: Plan, renders: int, kinds: tuple[str, ...]) -> list:
    """The spec's first materials, in plan order, holding at least ``renders`` renders (all
    of them when the spec has fewer), and the first material of each of ``kinds`` that they
    lack (the kinds the spec has: an svbrdf material also makes texture maps)."""
    chosen, count = [], 0
    for shard in plans:
        for material in shard.materials:
            if count < renders or (material.kind in kinds and material.kind not in {m.kind for m in chosen}):
                chosen.append(material)
                count += material.n_lights
            if count >= renders and {m.kind for m in chosen} >= set(kinds):
                return chosen
    return chosen


def _folder_bytes(root: str) -> tuple[int, int]:
    """(bytes of every file under ``root``, bytes of its sample records: the manifest repeats them)."""
    total = records = 0
    for folder, _dirs, files in os.walk(root):
        for name in files:
            size = os.path.getsize(os.path.join(folder, name))
            total += size
            records += size if name.endswith(".json") and name != MARKER_FILE else 0
    return total, records


def _time_kind(spec, materials: list, variant: str) -> dict:
    """Build ``materials`` (of one kind) into a temporary folder with the build's shard code; time it."""
    first = materials[0]
    shard = ShardPlan(shard_index=first.shard_index, shard_id=first.shard_id, materials=tuple(materials))
    root = tempfile.mkdtemp(prefix="shaderball-plan-")
    try:
        layout = Layout(root)
        for shard_id in sorted({m.shard_id for m in materials}):  # the materials may span shards
            make_shard_dir(layout, shard_id)
        started, cpu_started = time.perf_counter(), time.process_time()
        done = run_shard(root, spec, shard, variant)
        seconds, cpu_seconds = time.perf_counter() - started, time.process_time() - cpu_started
        written, records = _folder_bytes(root)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    renders = done["rendered"]
    return {
        "materials": len(materials),
        "renders": renders,
        "seconds": seconds,
        "seconds_per_render": seconds / renders,
        "cpu_seconds_per_render": cpu_seconds / renders,
        "bytes_per_render": (written + records) / renders,
    }


def time_first_samples(spec, plans: Plan, samples: int, counts: dict[str, int]) -> Timing:
    """Build the spec's first ``samples`` renders (whole materials, and the first material of
    each kind the spec has) with the build's shard code, kernels compiled first, each kind
    timed on its own; the figures per render are the kinds' weighted by ``counts`` (materials
    of each kind in the spec)."""
    variant = resolve_variant(spec.render.variant)
    load_mitsuba(variant)
    import drjit as dr

    threads = os.cpu_count() or 1
    if dr.thread_count() != threads:
        dr.set_thread_count(threads)
    chosen = first_materials(plans, samples, tuple(k for k, n in counts.items() if n))
    started = time.perf_counter()
    shard = ShardPlan(shard_index=chosen[0].shard_index, shard_id=chosen[0].shard_id, materials=tuple(chosen))
    warm_kernels(spec, [shard], variant)  # also makes this process's geometry and G-buffer
    setup_s = time.perf_counter() - started
    by_kind = {
        kind: _time_kind(spec, [m for m in chosen if m.kind == kind], variant)
        for kind in counts
        if any(m.kind == kind for m in chosen)
    }
    weight = {kind: counts[kind] for kind in by_kind}  # every timed kind is one the spec has

    def mix(key: str) -> float:
        return sum(weight[k] * by_kind[k][key] for k in by_kind) / sum(weight.values())

    return Timing(
        renders=sum(k["renders"] for k in by_kind.values()),
        materials=len(chosen),
        uniform=by_kind.get("uniform", {}).get("materials", 0),
        svbrdf=by_kind.get("svbrdf", {}).get("materials", 0),
        variant=variant,
        threads=threads,
        setup_s=setup_s,
        seconds=sum(k["seconds"] for k in by_kind.values()),
        seconds_per_render=mix("seconds_per_render"),
        cpu_seconds_per_render=mix("cpu_seconds_per_render"),
        load_average=os.getloadavg()[0],
        bytes_per_render=mix("bytes_per_render"),
        by_kind=by_kind,
    )


def _estimate(report: PlanReport, where: str, workers: int, threads: int, cores: float, cores_here: int) -> Estimate:
    """A shard at a time per worker, each with ``cores`` cores' worth of this machine's speed,
    every shard as long as a full one: rounds x shard time, after the set-up."""
    t = report.timing
    rounds = math.ceil(report.shards / workers)
    shard_seconds = report.renders_per_shard * t.seconds_per_render * cores_here / cores
    return Estimate(where, workers, threads, rounds, shard_seconds, t.setup_s + rounds * shard_seconds)


def estimates(report: PlanReport, req: PlanRequest) -> list[Estimate]:
    """In this process; on the local cluster (``--workers``, default one per 2 cores) sharing
    this machine's cores; on ``--jobs`` batch jobs of ``--cores`` each."""
    cores = report.timing.threads
    out = [_estimate(report, "this machine, in this process (--workers 0)", 1, cores, cores, cores)]
    if req.cluster in JOBQUEUE_KINDS:
        where = f"--cluster {req.cluster}, {req.jobs} job(s) x {req.cores} cores"
        out.append(_estimate(report, where, req.jobs, req.cores, req.cores, cores))
    elif req.workers != 0:
        # Local workers share this machine's cores (as many render threads as the build gives each).
        workers = req.workers or max(1, cores // 2)
        where = f"this machine, {workers} local worker(s)"
        out.append(_estimate(report, where, workers, max(1, cores // workers), cores / workers, cores))
    return out


__all__ = ["PlanReport", "PlanRequest", "disk_estimate", "plan_spec"]
