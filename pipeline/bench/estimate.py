"""`shaderball plan SPEC`: what a build of SPEC will be, before it starts.

From the spec alone (no rendering; `shaderball info SPEC` prints this part): the counts
(renders, materials by kind, lightings, shards) and the disk size, derived from the
resolution and the layers, channels and float widths the store writes
(:func:`pipeline.store.exr.pixel_bytes`): pixel data before EXR's lossless compression.

Timed (`shaderball plan`): the spec's own first samples (whole materials, in plan order, and
the first material of each kind they lack: an svbrdf material also makes texture maps; at
most :data:`TIMED_LIGHTS` lightings of each) are built with the build's own shard code
(:func:`pipeline.run.shard.run_shard`) into a temporary folder, in this process with every
core, kernels compiled first and timed apart (a build compiles them once per worker), each
kind on its own. Timing stays bounded whatever the spec says: a spec whose render is at
most the paper's work (:data:`DIRECT_SAMPLES` pixels x spp, at most
:data:`DIRECT_RESOLUTION` px, textures at most :data:`DIRECT_TEXELS`) is timed at its own
settings; any other at small ones (:func:`timing_plan`: each of resolution, spp and texture
resolution that is too large is timed at two small values), and a render's time is fitted
as a + b x pixels + c x pixels x spp (+ d x texels for svbrdf textures), one term per
setting varied, and extrapolated to the spec's settings; the plan says so. Their wall
time per render, and the bytes the folder then holds per render, weighed by the spec's
counts of each kind, are extrapolated to the whole spec: in this
process, on a local cluster of worker processes sharing the cores, or on ``--cluster
slurm|pbs`` jobs of ``--cores`` each, a shard at a time per worker (per-worker arithmetic:
rounds of shards x a shard's renders x seconds per render x this machine's cores / the
worker's cores; a remote core is taken to be as fast as one here).

A spec that names objects or environment maps also gets its materials per object, the maps
and their ranges; timed, every object and map is rendered at least once and given its seconds
per render, and the spec's figure is weighed to its shares of them
(:func:`pipeline.bench.first_renders.scene_costs`). A spec that names neither reports as before.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass

from pipeline.bench.first_renders import TIMED_LIGHTS, Timing, disk_estimate, time_first_samples, timing_plan
from pipeline.bench.gpu_rate import gpu_rate
from pipeline.bench.training_specs import cheaper_for_training
from pipeline.check.info import counted_names, human_bytes, lighting_summary, listed_names
from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec_file import spec_digest, spec_operand
from pipeline.fields import Checked, field, same_as
from pipeline.fields.rules import Bool, Int
from pipeline.render.limits import launch_limit_text, launch_spp
from pipeline.run.cluster.options import JOBQUEUE_KINDS, ClusterOptions
from pipeline.run.out_folder import read_spec_text

#: Renders timed (whole materials, so at least this many).
RENDERS_RANGE = (1, 1000)
DEFAULT_RENDERS = 4


@dataclass(frozen=True)
class PlanRequest(Checked):
    """What `shaderball plan` is asked; the cluster's fields are ClusterOptions' declarations."""

    spec: str = spec_operand()
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
    gpus: int | tuple[int, ...] | None = same_as(
        ClusterOptions,
        "gpus",
        doc="Also estimate the time on this many GPUs (a count, or device ids 0,2), from a "
        "per-GPU rate: measured when this machine renders on a GPU, else the recorded figure it names.",
    )
    gpus_per_job: int | None = same_as(ClusterOptions, "gpus_per_job")

    def check_cross(self) -> None:
        if self.gpus is not None and self.cluster in JOBQUEUE_KINDS:
            raise self._refuse("gpus", f"not allowed with {{cluster}} {self.cluster}", "use {gpus_per_job}")
        if self.gpus_per_job is not None and self.cluster not in JOBQUEUE_KINDS:
            raise self._refuse("gpus_per_job", "only with {cluster} slurm or {cluster} pbs", "use {gpus}")
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
    #: The plan summary's materials per object and environment maps (base names), where the
    #: spec names them; ``lighting``: the environment maps' ranges (empty under the sun)
    objects: dict = dataclasses.field(default_factory=dict)
    environments: list = dataclasses.field(default_factory=list)
    lighting: str = ""
    scheme: str = ""  # how objects are drawn (with objects)

    def to_dict(self) -> dict:
        out = asdict(self)
        # a spec naming no object or map: the document as it was before either existed
        for key in ("objects", "environments", "lighting", "scheme"):
            if not out[key]:
                del out[key]
        if out["timing"] is not None:
            for key in ("by_object", "by_environment"):
                if not out["timing"][key]:
                    del out["timing"][key]
            if not (self.objects or self.environments):
                del out["timing"]["scene_weight"]
        return out

    def scene_lines(self) -> list[str]:
        """The objects and maps the spec names (none where it names neither)."""
        out = []
        if self.objects:
            out.append(f"objects (materials planned, {self.scheme}): {counted_names(self.objects)}")
        if self.environments:
            out.append(f"lighting: {self.lighting}; {len(self.environments)} map(s): {listed_names(self.environments)}")
        return out

    def scene_timing_lines(self) -> list[str]:
        """Seconds per render of each object and map timed (none where the spec names neither)."""
        t, out = self.timing, []
        for what, groups in (("object", t.by_object), ("environment map", t.by_environment)):
            if groups:
                out.append(
                    f"time per {what} (its render calls against the others'): "
                    + listed_names(
                        f"{name} {g['seconds_per_render']:.3f} s a render ({g['renders']} timed)"
                        for name, g in groups.items()
                    )
                )
        if t.scene_weight != 1.0:
            out.append(
                f"the spec's mix (objects by their materials, maps in equal shares) costs x{t.scene_weight:.3f} "
                "the timed renders' mix: in the figures above"
            )
        return out

    def lines(self) -> list[str]:
        d = self.disk
        out = [
            f"spec {self.spec}: {self.name} v{self.version}, digest {self.spec_digest[:12]}",
            f"renders: {self.renders:,} = {self.materials:,} materials ({self.uniform:,} uniform, "
            f"{self.svbrdf:,} svbrdf) x {self.lights_per_material} lightings; {self.resolution}x{self.resolution} px, "
            f"{self.spp} spp, variant {self.variant}",
            f"shards: {self.shards:,} of {self.shard_size} materials ({self.renders_per_shard} renders)",
            *self.scene_lines(),
            f"disk (pixel data before EXR compression): {human_bytes(d['total_bytes'])} = renders "
            f"{human_bytes(d['render_bytes'])} ({human_bytes(d['bytes_per_render'])} each) + screen-space maps "
            f"{human_bytes(d['maps_bytes'])} ({human_bytes(d['bytes_per_material_maps'])} a material) + texture maps "
            f"{human_bytes(d['texture_bytes'])}",
        ]
        t = self.timing
        if t is not None:
            x = t.extrapolation
            each = "each, extrapolated" if x else "each"
            kinds = ", ".join(
                f"{k['renders']} {kind} at {k['seconds_per_render']:.3f} s {each}" for kind, k in t.by_kind.items()
            )
            settings = f" at each of {len(x['timed_at'])} settings" if x else ""
            out.append(
                f"timed: {t.renders} renders{settings} ({kinds}) of {t.materials} materials (the spec's first, and the first of each kind), "
                f"{t.variant}, "
                f"{t.threads} threads: {t.seconds_per_render:.3f} s a render in the spec's mix "
                f"(CPU {t.cpu_seconds_per_render:.3f} s a render; load average {t.load_average:.1f}), set-up {t.setup_s:.2f} s (geometry, G-buffer, kernels; once per worker)"
            )
            if x:
                out.append(f"extrapolated: {x['text']}")
            out.extend(self.scene_timing_lines())
            out.append(
                f"disk as written (EXR compressed, records, markers, manifest): {human_bytes(t.bytes_per_render)} a "
                f"render, {human_bytes(t.bytes_per_render * self.renders)} in all"
            )
            for e in self.estimates:
                out.append(
                    f"time, {e.where}: {e.seconds:,.0f} s ({_hours(e.seconds)}); {e.workers} worker(s) x "
                    f"{e.threads_per_worker} thread(s), {e.rounds} shard(s) each at {e.shard_seconds:,.1f} s"
                )
        out.extend(f"note: {n}" for n in self.notes)
        return out


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.1f} min"


def plan_spec(req: PlanRequest, progress=None) -> PlanReport:
    """Counts and disk of ``req.spec``; with ``req.timing`` also the timed renders and the time
    estimates (``progress(str)`` says when they start). Nothing is written outside a temporary
    folder, removed after."""
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
        objects=dict(summary.get("objects", {})),
        environments=list(summary.get("environments", [])),
        lighting=lighting_summary(spec.lighting) if summary.get("environments") else "",
        scheme=spec.scene.scheme if summary.get("objects") else "",
    )
    cheaper = cheaper_for_training(report.spec_digest)
    if cheaper is not None:
        report.notes.append(
            f"for training the network, {cheaper.cheaper} builds the same samples for less: {cheaper.verdict} "
            f"({cheaper.report})"
        )
    split = launch_spp(spec.render.spp, spec.render.resolution**2)
    if len(split) > 1:
        report.notes.append(
            f"a render is {spec.render.resolution}^2 x {spec.render.spp} samples, more than {launch_limit_text()} "
            f"(Mitsuba's most in one launch): it renders in launches of at most {split[0]} spp, averaged"
        )
    if not req.timing:
        return report
    if progress is not None:
        where = "at small settings, extrapolated to its own" if timing_plan(spec).extrapolated else "at its settings"
        progress(
            f"timing the first {req.renders}+ renders of {req.spec} {where} (kernels compiled first; "
            "nothing is kept) ..."
        )
    scene = {"objects": report.objects, "environments": report.environments}
    report.timing = time_first_samples(
        spec, plans, req.renders, {"uniform": report.uniform, "svbrdf": report.svbrdf}, scene
    )
    report.estimates = estimates(report, req)
    if spec.render.target_error > 0:
        report.notes.append(
            "render.target_error is on: a render stops when it reaches the target, so its time varies with "
            "the material and lighting; the timed ones stand for all"
        )
    t = report.timing
    if ds.lights_per_material > TIMED_LIGHTS:
        report.notes.append(
            f"each timed material rendered its first {TIMED_LIGHTS} of its {ds.lights_per_material} lightings: "
            f"its maps' time is spread over {TIMED_LIGHTS} renders, not {ds.lights_per_material} (a little long)"
        )
    if t.extrapolation and spec.render.target_error > 0:
        report.notes.append(
            "extrapolated with render.target_error on: as if every render took all its spp (an upper bound)"
        )
    if t.load_average > t.threads:
        idle = t.setup_s + report.renders * t.cpu_seconds_per_render / t.threads
        report.notes.append(
            f"the machine was busy (load average {t.load_average:.1f} on {t.threads} cores): wall times are "
            f"longer than on an idle machine; from the CPU time per render ({t.cpu_seconds_per_render:.3f} s) "
            f"this process would take about {idle:,.0f} s ({_hours(idle)}) with the cores to itself"
        )
    return report


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
    gpus = (req.jobs or 1) * req.gpus_per_job if req.gpus_per_job else req.gpus
    if gpus is not None:
        out.append(_gpu_estimate(report, req, gpus if isinstance(gpus, int) else len(gpus)))
    return out


def _gpu_estimate(report: PlanReport, req: PlanRequest, gpus: int) -> Estimate:
    """One worker per GPU, a shard at a time, at the per-GPU rate (its source in ``where``)."""
    t = report.timing
    rate, source = gpu_rate(report.resolution, report.spp, t.variant, t.seconds_per_render)
    rounds = math.ceil(report.shards / gpus)
    shard_seconds = report.renders_per_shard / rate
    if req.gpus_per_job:
        where = f"--cluster {req.cluster}, {req.jobs} job(s) x {req.gpus_per_job} GPU(s)"
    else:
        where = f"{gpus} GPU(s), one worker each"
    where += f", {rate:.2f} renders/s per GPU ({source})"
    return Estimate(where, gpus, 1, rounds, shard_seconds, rounds * shard_seconds)


__all__ = ["PlanReport", "PlanRequest", "disk_estimate", "plan_spec"]
