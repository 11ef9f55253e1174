"""The build benchmark: a build's overhead over bare Mitsuba renders of the same samples.

``shaderball bench SPEC``
    Builds SPEC (optionally cut to about ``renders`` renders, at another ``resolution`` /
    ``spp`` / ``shard_size``: :class:`pipeline.bench.command.BenchRequest`) into a fresh folder, then renders the
    same samples with bare ``mi.render`` calls: the same scene dicts
    (:func:`pipeline.render.renderer.scene_dict`), each loaded once, one scene alive at a time,
    kernels compiled beforehand, only the render call timed. It prints the build's wall
    time over the sum of those render times (the overhead ratio; the target at the paper's 150 spp
    is at most 1.03), samples per second of both, the same ratio in CPU time (this process and its
    reaped children: less disturbed by other load than wall time), for in-process builds
    the build's own split between its render calls and the rest (:class:`RenderCallTimer`,
    measured in the same run), the kernels an in-process build compiled, where the rest
    goes, and the paper's 50,000 renders on this machine (:meth:`BuildBench.paper_estimate`).
    Kernels are compiled before the build (one spp-1 render per material, which fills
    drjit's on-disk kernel cache), so the ratio is the steady state of a long build, not the
    first minute of a fresh machine. The bare renders use the build's passes
    (:func:`pipeline.render.renderer.pass_plan`). ``profile`` adds two measurements: all
    lightings of a material rendered from one loaded scene moved in place, as the build
    does (:class:`pipeline.render.renderer.MaterialScene`), against dict + load + render
    each, and the ``moment`` integrator against its nested path tracer alone.

``shaderball bench --effects`` is :mod:`pipeline.bench.effects`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field

from pipeline.bench.bare_renders import (
    BUILD_PHASES,
    RenderCallTimer,
    SampleTiming,
    cpu_with_children,
    measure_bare,
    measure_moment,
    measure_reuse,
    measure_storage,
    records_render_time,
    warm_kernels,
)
from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec_file import spec_to_toml
from pipeline.fields import FieldError
from pipeline.fields.rules import format_value
from pipeline.render.kernels import KernelCounter
from pipeline.render.mitsuba_env import load_mitsuba, resolve_variant
from pipeline.run.build import build
from pipeline.run.cluster.options import ClusterOptions
from pipeline.run.out_folder import read_spec_text
from pipeline.store.atomic import write_text_atomic
from pipeline.store.folder import folder_names

# --------------------------------------------------------------------------- build benchmark

#: The paper's dataset (manifests/paper.toml): 10,000 materials x 5 lightings, 400x400, 150 spp.
PAPER_RENDERS, PAPER_RESOLUTION, PAPER_SPP = 50_000, 400, 150


def derive_spec(
    spec,
    *,
    renders: int | None = None,
    resolution: int | None = None,
    spp: int | None = None,
    shard_size: int | None = None,
):
    """``spec`` cut to about ``renders`` renders (whole materials) and re-sized; other fields kept."""
    dataset, render = spec.dataset, spec.render
    if shard_size is not None:
        dataset = dataclasses.replace(dataset, shard_size=shard_size)
    if renders is not None:
        lights = dataset.lights_per_material
        if renders < lights:
            dataset = dataclasses.replace(dataset, materials=1, lights_per_material=renders)
        else:
            dataset = dataclasses.replace(dataset, materials=-(-renders // lights))
    if resolution is not None:
        render = dataclasses.replace(render, resolution=resolution)
    if spp is not None:
        render = dataclasses.replace(render, spp=spp)
    return dataclasses.replace(spec, dataset=dataset, render=render)


#: The spec fields each keyword of :func:`derive_spec` sets, as (section, field).
DERIVED_FIELDS = {
    "renders": (("dataset", "materials"), ("dataset", "lights_per_material")),
    "resolution": (("render", "resolution"),),
    "spp": (("render", "spp"),),
    "shard_size": (("dataset", "shard_size"),),
}


def derive_for(request, spec, named: dict[str, str] | None = None, **changes):
    """:func:`derive_spec` for ``request``, whose options gave ``changes`` (named as the
    keywords, or as ``named`` says: the scale benchmark's sizes are ``renders`` from its
    ``scale``). A field of the derived spec that is refused (a shard of more renders than a
    marker holds, more materials or shards than a spec may have) is refused as the option
    that set it, with its value: the user typed ``--shard-size``, not ``dataset.shard_size``."""
    try:
        return derive_spec(spec, **changes)
    except FieldError as exc:
        given = {k: changes[k] for k in DERIVED_FIELDS if changes.get(k) is not None}
        if not given:  # nothing changed: the spec's own refusal
            raise
        raise _refused_as_option(request, exc, given, named or {}) from None


def _refused_as_option(request, exc: FieldError, given: dict, named: dict[str, str]) -> FieldError:
    section = getattr(exc, "section", None) or getattr(exc.owner, "SECTION", "")
    by_field = [k for k in given if (section, exc.name) in DERIVED_FIELDS[k]]
    by_section = [k for k in given if any(s == section for s, _ in DERIVED_FIELDS[k])]
    key = (by_field or by_section or list(given))[0]
    value = given[key]
    if by_field and exc.value == value:  # the option's own value, refused by a rule between fields
        return request.field_error(named.get(key, key), value, exc.allowed, what=exc.what)
    refused = f"{section}.{exc.name}" if exc.name else f"[{section}]"
    return request.field_error(
        named.get(key, key),
        value,
        f"with it the spec's {refused} ({format_value(exc.value)}) is refused: {exc.allowed}",
    )


def _over(part: float, whole: float) -> float:
    """``part / whole``, infinite where ``whole`` is none (a ratio of times)."""
    return part / whole if whole > 0 else math.inf


@dataclass
class BuildBench:
    spec_name: str
    samples: int
    materials: int
    resolution: int
    spp: int
    workers: str
    variant: str
    threads: int
    warmup_s: float
    build_s: float
    build_cpu_s: float  # CPU time of this process and its (reaped) children during the build
    startup_s: float  # build() call to the start of rendering (spec, plan, dask cluster)
    in_build_render_s: float | None  # in-process builds: time inside render_scene during the build
    in_build_phases: dict | None = None  # in-process builds: seconds per phase (BUILD_PHASES)
    in_build_phases_cpu: dict | None = None  # the same phases' CPU time on the thread that ran them
    in_build_main_cpu_s: float | None = None  # CPU time of the build's thread from its first render on
    timings: list[SampleTiming] = field(default_factory=list)
    material_files_s: float = 0.0  # per material: raster projection + maps (+ texture) EXR
    render_file_s: float = 0.0  # per render: EXR encode + SHA-256 + atomic write
    reuse: dict | None = None
    moment: dict | None = None
    compiled: dict | None = None  # kernels compiled during the timed bare renders (should be 0)
    build_compiled: int | None = None  # in-process builds: kernels compiled during the build (warm: 0)
    #: the records' render times (stats.time_s: scene, render, statistics, in the worker) summed,
    #: and the worker processes that made them: the same run's split for any kind of workers
    records_render_s: float = 0.0
    processes: int = 1

    @property
    def bare_s(self) -> float:
        return sum(t.render_s for t in self.timings)

    @property
    def ratio(self) -> float:
        return _over(self.build_s, self.bare_s)

    @property
    def bare_cpu_s(self) -> float:
        return sum(t.render_cpu_s for t in self.timings)

    @property
    def cpu_ratio(self) -> float:
        """Build CPU over bare-render CPU: less disturbed than wall time on a shared machine."""
        return _over(self.build_cpu_s, self.bare_cpu_s)

    @property
    def records_ratio(self) -> float:
        """The build from its first render on over the records' render times per worker process:
        both taken in the same run, so other load on the machine moves both alike."""
        per_process = self.records_render_s / max(self.processes, 1)
        return _over(self.build_s - self.startup_s, per_process)

    @property
    def steady_ratio(self) -> float:
        """Build wall time from its first render on, over the bare renders: the ratio a long
        build tends to, where the start-up (spec, plan, cluster) is spread over many renders."""
        return _over(self.build_s - self.startup_s, self.bare_s)

    @property
    def render_call_ratio(self) -> float | None:
        """In-process builds: the build's render calls over the bare renders of the same scenes
        (1.0: no slowdown of the render itself inside the build)."""
        if not self.in_build_render_s or self.bare_s <= 0:
            return None
        return self.in_build_render_s / self.bare_s

    @property
    def outside_per_render_s(self) -> float | None:
        """In-process builds: the build's wall time from its first render on, less its render
        calls, per render: everything a render costs beside the render itself."""
        if not self.in_build_render_s:
            return None
        return (self.build_s - self.startup_s - self.in_build_render_s) / max(self.samples, 1)

    @property
    def main_thread_outside_cpu_s(self) -> float | None:
        """In-process builds: CPU time of the build's thread from its first render on, outside
        its render calls (the phases and the rest): the figure least moved by other load."""
        if self.in_build_main_cpu_s is None or not self.in_build_phases_cpu:
            return None
        return self.in_build_main_cpu_s - self.in_build_phases_cpu["render calls"]

    def _phase_lines(self) -> list[str]:
        if not self.in_build_render_s:
            return []
        n = max(self.samples, 1)
        phases = self.in_build_phases or {}
        main = [p for p in BUILD_PHASES if p not in ("render calls", "writer thread")]
        rest = self.outside_per_render_s - sum(phases.get(p, 0.0) for p in main) / n
        return [
            f"in-process build, same run: {self.in_build_render_s:.2f} s in render calls, "
            f"{self.build_s - self.in_build_render_s:.2f} s elsewhere: build / its own renders = "
            f"{self.build_s / self.in_build_render_s:.3f}",
            f"render calls inside the build over bare renders of the same scenes: {self.render_call_ratio:.3f} "
            f"({self.in_build_render_s:.2f} s / {self.bare_s:.2f} s)",
            f"outside the render calls, per render: {self.outside_per_render_s * 1e3:.1f} ms (goal <= 10 ms): "
            + ", ".join(f"{p} {phases.get(p, 0.0) / n * 1e3:.1f} ms" for p in main)
            + f", the rest {rest * 1e3:.1f} ms; beside them on the writer thread "
            f"{phases.get('writer thread', 0.0) / n * 1e3:.1f} ms",
            *(
                [
                    "the same phases in CPU time of their thread, per render (less moved by other load): "
                    + ", ".join(f"{p} {cpu.get(p, 0.0) / n * 1e3:.1f} ms" for p in main if p != "writer waits")
                    + f"; writer thread {cpu.get('writer thread', 0.0) / n * 1e3:.1f} ms"
                    + (
                        f"; the main thread outside its render calls {main_cpu / n * 1e3:.1f} ms (goal <= 10 ms)"
                        if (main_cpu := self.main_thread_outside_cpu_s) is not None
                        else ""
                    )
                ]
                if (cpu := self.in_build_phases_cpu)
                else []
            ),
        ]

    def paper_estimate(self) -> dict:
        """The paper's 50,000 renders on this machine, two ways: at this build's own rate (its
        wall time from the first render on, per render: every worker and render thread it ran,
        so the machine's parallelism is in the figure, and every overhead) and from the bare
        renders alone (one at a time with every render thread of this process: the whole
        machine, or its GPU). Runs smaller than 400x400 at 150 spp are scaled by pixels x spp
        (rough: a render's fixed costs do not scale)."""
        scale = (PAPER_RESOLUTION**2 * PAPER_SPP) / (self.resolution**2 * self.spp)
        n = max(self.samples, 1)
        build_per_render = (self.build_s - self.startup_s) / n * scale
        bare_per_render = self.bare_s / max(len(self.timings), 1) * scale
        return {
            "renders": PAPER_RENDERS,
            "scaled_by": scale,
            "build_per_render_s": build_per_render,
            "bare_per_render_s": bare_per_render,
            "hours": build_per_render * PAPER_RENDERS / 3600.0,
            "hours_bare": bare_per_render * PAPER_RENDERS / 3600.0,
        }

    def lines(self) -> list[str]:
        n = self.samples
        mean = lambda xs: sum(xs) / len(xs) if xs else 0.0  # noqa: E731
        out = [
            f"bench: {self.spec_name}, {n} renders ({self.materials} materials), "
            f"{self.resolution}x{self.resolution}, {self.spp} spp, {self.variant}, "
            f"workers: {self.workers}, {self.threads} render threads",
            f"kernel warm-up before the build (not counted): {self.warmup_s:.1f} s",
            f"build, end to end:        {self.build_s:8.2f} s  {n / self.build_s:7.3f} samples/s"
            f"  (start-up before the first render: {self.startup_s:.1f} s)",
            f"bare mi.render, summed:   {self.bare_s:8.2f} s  {n / self.bare_s:7.3f} samples/s"
            f"  (mean {self.bare_s / n:.3f} s per render)",
            f"wall ratio build / bare:  {self.ratio:8.3f}   "
            "(targets at the paper's 400 px, 150 spp: <= 1.03 on CPU, <= 1.15 on GPU); "
            f"from the first render on: {self.steady_ratio:.3f}",
            f"CPU ratio build / bare:   {self.cpu_ratio:8.3f}   "
            f"(CPU time {self.build_cpu_s:.1f} s / {self.bare_cpu_s:.1f} s, this process and its reaped children)",
            *(
                [
                    f"same run, from the records: build {self.build_s - self.startup_s:.2f} s from its first render on "
                    f"over their summed render time {self.records_render_s:.2f} s / {self.processes} process(es) = "
                    f"{self.records_ratio:.3f}"
                ]
                if self.records_render_s > 0
                else []
            ),
            *self._phase_lines(),
            f"bare renders bit-identical to the build's: {sum(t.identical for t in self.timings)}/{len(self.timings)}",
            *(
                [
                    f"kernels compiled during the build (in-process; 0 = every scene and light change "
                    f"reused warm kernels): {self.build_compiled}"
                ]
                if self.build_compiled is not None
                else []
            ),
            self._paper_line(),
            "where the rest goes, per render (measured outside the build): "
            f"scene_dict {mean([t.dict_s for t in self.timings]):.3f} s, "
            f"load_dict {mean([t.load_s for t in self.timings]):.3f} s, "
            f"render EXR+SHA-256+fsync {self.render_file_s:.3f} s; per material: raster + maps EXR "
            f"{self.material_files_s:.3f} s",
        ]
        if self.compiled:
            out.append(
                "kernels compiled during the timed renders (0 = all warm): "
                + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}" for k, v in self.compiled.items())
            )
        if self.reuse:
            r = self.reuse
            out.append(
                f"profile, one loaded scene per material moved in place: {r['seconds']:.2f} s for "
                f"{n} renders, {r['seconds'] - r['compile_s']:.2f} s without its {r['compiled']} "
                f"kernel compile(s) (vs {r['fresh_seconds']:.2f} s dict+load+render each), "
                f"{r['identical']}/{n} bit-identical to the build's"
            )
        if self.moment:
            m = self.moment
            out.append(
                f"profile, moment vs plain {m['integrator']} ({m['samples']} renders): "
                f"{m['moment_s']:.2f} s vs {m['path_s']:.2f} s "
                f"({100 * (m['moment_s'] / m['path_s'] - 1):+.1f}%), RGB "
                f"{'bit-identical' if m['identical'] else 'not bit-identical'}"
            )
        return out

    def _paper_line(self) -> str:
        e = self.paper_estimate()
        if e["scaled_by"] != 1:
            return (
                f"paper scale: run at {PAPER_RESOLUTION}x{PAPER_RESOLUTION}, {PAPER_SPP} spp for the estimate "
                f"(e.g. --limit 10 of manifests/paper.toml); scaling this {self.resolution}x{self.resolution}, "
                f"{self.spp} spp run by pixels x spp gives {e['hours']:.0f} h at the build's rate, "
                f"{e['hours_bare']:.0f} h from the bare renders, overestimates: fixed costs scale too"
            )
        return (
            f"paper scale on this machine: {e['renders']:,} renders x {e['build_per_render_s']:.2f} s "
            f"(this build's wall time per render from its first render on, {self.workers}) = "
            f"{e['hours']:.1f} h ({e['hours'] / 24:.1f} days); bare renders alone x {e['bare_per_render_s']:.2f} s "
            f"({self.threads} render threads, one render at a time) = {e['hours_bare']:.1f} h"
        )

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(
            bare_s=self.bare_s,
            ratio=self.ratio,
            bare_cpu_s=self.bare_cpu_s,
            cpu_ratio=self.cpu_ratio,
            steady_ratio=self.steady_ratio,
            records_ratio=self.records_ratio,
            render_call_ratio=self.render_call_ratio,
            outside_per_render_s=self.outside_per_render_s,
            paper_estimate=self.paper_estimate(),
        )
        return d


def bench_spec(request):
    """The spec the build benchmark builds: ``request.spec`` cut and re-sized as its options
    ask (:func:`derive_for`: a refusal names the option)."""
    spec, _ = read_spec_text(request.spec)
    resolution, spp = request.settings()
    return derive_for(
        request, spec, renders=request.renders, resolution=resolution, spp=spp, shard_size=request.shard_size
    )


def run_build_bench(request, progress=None) -> BuildBench:
    """Build ``request.spec`` (cut and re-sized as it asks) and time the same renders bare;
    see the module docstring."""
    out = request.out
    spec = bench_spec(request)
    if out is not None and os.path.exists(out) and folder_names(out) != []:
        raise request.field_error("out", out, "a new or empty folder (the benchmark builds from scratch)")
    scratch = tempfile.mkdtemp(prefix="shaderball-bench-")
    root = out or os.path.join(scratch, "dataset")
    say = progress or (lambda message: None)
    try:
        derived_path = os.path.join(scratch, "bench-spec.toml")
        write_text_atomic(derived_path, spec_to_toml(spec))
        plans = plan_dataset(spec)
        variant = resolve_variant(spec.render.variant)  # chosen once for the whole benchmark
        load_mitsuba(variant)
        say("warming kernels (one spp-1 render per material) ...")
        warmup = warm_kernels(spec, plans, variant)
        say("building ...")
        timed = timed_build(derived_path, root, request.workers)
        say("bare renders ...")
        kernels = KernelCounter()
        timings = measure_bare(spec, plans, root, kernels, variant)
        per_material, per_render = measure_storage(spec, plans, root, variant)
        bench = timed.bench(spec, variant, warmup, timings)
        bench.material_files_s, bench.render_file_s = per_material, per_render
        bench.compiled = {"bare renders": kernels.compiled, "compile seconds": round(kernels.compile_s, 2)}
        bench.records_render_s = records_render_time(root)
        if request.profile:
            profile_scenes(bench, spec, plans, root, variant, timings, say)
        return bench
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


@dataclass
class TimedBuild:
    """A build timed: wall and CPU time, when its first render started, and what an
    in-process build's phase timer and kernel counter saw."""

    summary: object  # pipeline.run.build's summary
    seconds: float
    cpu_seconds: float
    startup_s: float
    where: str
    phases: RenderCallTimer
    kernels: KernelCounter

    def bench(self, spec, variant: str, warmup_s: float, timings: list[SampleTiming]) -> BuildBench:
        """The benchmark's figures of this build and the bare ``timings``."""
        import drjit as dr

        phases = self.phases
        in_process = bool(phases.calls)
        return BuildBench(
            spec_name=spec.dataset.name,
            samples=self.summary.total,
            materials=spec.dataset.materials,
            resolution=spec.render.resolution,
            spp=spec.render.spp,
            workers=self.where,
            variant=variant,
            threads=dr.thread_count(),
            warmup_s=warmup_s,
            build_s=self.seconds,
            build_cpu_s=self.cpu_seconds,
            startup_s=self.startup_s,
            in_build_render_s=phases.seconds if in_process else None,
            in_build_phases=dict(phases.phases) if in_process else None,
            in_build_phases_cpu=dict(phases.cpu) if in_process else None,
            in_build_main_cpu_s=phases.main_cpu if in_process else None,
            timings=timings,
            processes=max(self.summary.processes, 1),
            build_compiled=self.kernels.compiled if in_process else None,
        )


def timed_build(spec_path: str, root: str, workers: int | None) -> TimedBuild:
    """Build ``spec_path`` into ``root``: its wall and CPU time (this process and its reaped
    children), its start-up (to the first render), and for an in-process build its phases and
    the kernels it compiled."""
    marks = {}
    in_build, build_kernels = RenderCallTimer(), KernelCounter()

    def started(where, _dashboard):
        marks["where"] = where
        marks["started"] = time.perf_counter()
        in_build.first_render()

    cpu0 = cpu_with_children()
    t0 = time.perf_counter()
    # the kernel counter's reading of drjit's history is the benchmark's work: it runs
    # after the timer has stopped (the history's recording still runs inside it)
    with build_kernels, in_build:
        summary = build(spec_path, root, cluster=ClusterOptions(workers=workers), on_start=started)
    build_s = time.perf_counter() - t0
    build_cpu = cpu_with_children() - cpu0
    first_start = min((marks.get("started", t0) - t0), build_s)
    return TimedBuild(summary, build_s, build_cpu, first_start, marks.get("where", "?"), in_build, build_kernels)


def profile_scenes(bench: BuildBench, spec, plans, root: str, variant: str, timings: list[SampleTiming], say) -> None:
    """``profile``: one loaded scene per material moved in place against dict + load +
    render each, and the moment integrator against its nested path tracer (into ``bench``)."""
    say("profile: one scene per material ...")
    reuse_kernels = KernelCounter()
    bench.reuse = measure_reuse(spec, plans, root, reuse_kernels, variant)
    bench.reuse.update(
        fresh_seconds=sum(t.dict_s + t.load_s + t.render_s for t in timings),
        compiled=reuse_kernels.compiled,
        compile_s=reuse_kernels.compile_s,
    )
    say("profile: moment vs plain integrator ...")
    bench.moment = measure_moment(spec, plans, variant)
