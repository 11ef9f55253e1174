"""What a build's renders cost without the build, measured on the same samples: bare Mitsuba
renders of the stored samples (kernels warm), the EXR storage, the scene reuse, the moment
renders, and the time inside Mitsuba's render calls of a build (:class:`RenderCallTimer`).
:mod:`pipeline.bench.build_bench` sets them against a timed build.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass

import numpy as np

import pipeline.render.renderer as render
from pipeline.dataset.materialize import make_material
from pipeline.render.kernels import KernelCounter
from pipeline.render.mitsuba_env import load_mitsuba
from pipeline.render.renderer import MaterialScene, pass_plan, render_in_passes, scene_dict
from pipeline.run import shard
from pipeline.run.shard import worker_context, write_material_files
from pipeline.store.exr import read_exr, write_exr
from pipeline.store.folder import read_manifest
from pipeline.store.layout import Layout
from pipeline.store.records import read_json

# --------------------------------------------------------------------------- build benchmark

#: The paper's dataset (manifests/paper.toml): 10,000 materials x 5 lightings, 400x400, 150 spp.
PAPER_RENDERS, PAPER_RESOLUTION, PAPER_SPP = 50_000, 400, 150


@dataclass
class SampleTiming:
    sample_id: str
    dict_s: float  # pipeline.render.renderer.scene_dict
    load_s: float  # mi.load_dict
    render_s: float  # mi.render + numpy conversion: the bare render
    render_cpu_s: float  # CPU time of this process (all render threads) over the same call
    identical: bool  # the bare render equals the build's stored render, bit for bit


def _materials_of(plans):
    return [m for shard in plans for m in shard.materials]


def warm_kernels(spec, plans, variant: str) -> float:
    """Compile (or fetch from drjit's disk cache) every kernel the build will need.

    Spp-1 renders (spp is not part of a kernel, the resolution is): each material's scene
    loaded afresh, as the bare renders load it; then one scene moved from material to
    material and from a material's first lighting to its next, in the plan's order, as an
    in-process build renders them.
    """

    mi = load_mitsuba(variant)
    start = time.perf_counter()
    for material in _materials_of(plans):
        ctx = worker_context(spec, variant, material.object)
        maps, _ = make_material(material, spec)
        desc, _, _ = scene_dict(ctx.ball, ctx.camera, maps, _light(spec, material.samples[0]), ctx.settings)
        np.asarray(mi.render(mi.load_dict(desc), spp=1, seed=0))
        del desc
    with MaterialScene() as held:
        for material in _materials_of(plans):
            ctx = worker_context(spec, variant, material.object)
            maps, _ = make_material(material, spec)
            for s in material.samples[:2]:
                scene, _, _ = held.lit(mi, ctx.ball, ctx.camera, maps, _light(spec, s), ctx.settings)
                np.asarray(mi.render(scene, spp=1, seed=0))
                del scene
    return time.perf_counter() - start


def _stored_render(layout, sample) -> np.ndarray:

    return read_exr(layout.path(layout.render_rel(sample.shard_id, sample.sample_id))).layers["render"]


def _render_seed(layout, sample) -> int:

    record = read_json(layout.path(layout.record_rel(sample.shard_id, sample.sample_id))) or {}
    return int(record.get("seeds", {}).get("render_used", sample.render_seed))


def _light(spec, sample):
    """What lights ``sample`` (the sun and sky, or its environment map), as the build lights it."""
    return shard.sample_light(spec, sample)


def measure_bare(spec, plans, root: str, kernels: KernelCounter, variant: str) -> list[SampleTiming]:
    """Time scene_dict, load_dict and the bare render of every sample; compare with the build."""

    mi = load_mitsuba(variant)
    layout = Layout(root)
    timings = []
    for material in _materials_of(plans):
        ctx = worker_context(spec, variant, material.object)
        maps, _ = make_material(material, spec)
        for s in material.samples:
            seed = _render_seed(layout, s)
            t0 = time.perf_counter()
            desc, _, _ = scene_dict(ctx.ball, ctx.camera, maps, _light(spec, s), ctx.settings)
            t1 = time.perf_counter()
            scene = mi.load_dict(desc)
            t2, cpu = time.perf_counter(), time.process_time()
            with kernels:
                # The build's own passes (pipeline.render.renderer.pass_plan: power-of-two on llvm).
                out = render_in_passes(mi, scene, ctx.settings.spp, seed, pass_plan(ctx.settings.spp, variant)).astype(
                    np.float32
                )
            t3, cpu = time.perf_counter(), time.process_time() - cpu
            del scene, desc  # one scene alive at a time, as in a build worker
            timings.append(
                SampleTiming(
                    s.sample_id,
                    t1 - t0,
                    t2 - t1,
                    t3 - t2,
                    cpu,
                    bool(np.array_equal(_stored_render(layout, s), out[..., 0:3])),
                )
            )
    return timings


def measure_storage(spec, plans, root: str, variant: str) -> tuple[float, float]:
    """(per material: raster + maps files, per render: EXR + hash + atomic write), in seconds."""

    layout = Layout(root)
    scratch = tempfile.mkdtemp(prefix="shaderball-bench-io-")
    try:
        materials = _materials_of(plans)[:4]
        start = time.perf_counter()
        for material in materials:
            maps, description = make_material(material, spec)
            ctx = worker_context(spec, variant, material.object)
            write_material_files(Layout(scratch), spec, ctx, material, maps, description)
        per_material = (time.perf_counter() - start) / len(materials)
        images = [_stored_render(layout, s) for m in materials for s in m.samples][:8]
        start = time.perf_counter()
        for i, image in enumerate(images):
            write_exr(
                os.path.join(scratch, f"r{i}.render.exr"),
                {"render": image},
                {"id": str(i)},
                compression=spec.storage.compression,
            )
        per_render = (time.perf_counter() - start) / len(images)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return per_material, per_render


def measure_reuse(spec, plans, root: str, kernels: KernelCounter, variant: str) -> dict:
    """All lightings of a material from one loaded scene moved in place, as the build does
    (pipeline.render.renderer.MaterialScene), timed against dict + load + render per sample.
    """

    mi = load_mitsuba(variant)
    layout = Layout(root)
    seconds = 0.0
    identical = 0
    for material in _materials_of(plans):
        ctx = worker_context(spec, variant, material.object)
        maps, _ = make_material(material, spec)
        with MaterialScene() as held:
            for s in material.samples:
                seed = _render_seed(layout, s)
                t0 = time.perf_counter()
                scene, _, _ = held.lit(mi, ctx.ball, ctx.camera, maps, _light(spec, s), ctx.settings)
                with kernels:
                    out = render_in_passes(
                        mi, scene, ctx.settings.spp, seed, pass_plan(ctx.settings.spp, variant)
                    ).astype(np.float32)
                seconds += time.perf_counter() - t0
                identical += bool(np.array_equal(_stored_render(layout, s), out[..., 0:3]))
                del scene
    return {"seconds": seconds, "identical": identical}


def measure_moment(spec, plans, variant: str, count: int = 3) -> dict:
    """The first ``count`` samples rendered by the nested integrator alone, against ``moment``.

    Each scene is loaded, rendered once at 1 spp (compiling its kernels if needed), then
    timed at full spp; one scene alive at a time.
    """

    mi = load_mitsuba(variant)
    totals = {"moment": 0.0, "path": 0.0}
    identical = True
    samples = [(m, s) for m in _materials_of(plans) for s in m.samples][:count]
    for material, s in samples:
        ctx = worker_context(spec, variant, material.object)
        maps, _ = make_material(material, spec)
        desc, _, _ = scene_dict(ctx.ball, ctx.camera, maps, _light(spec, s), ctx.settings)
        images = {}
        for name, d in (("path", dict(desc, integrator=desc["integrator"]["nested"])), ("moment", desc)):
            scene = mi.load_dict(d)
            np.asarray(mi.render(scene, spp=1, seed=0))
            t0 = time.perf_counter()
            images[name] = np.asarray(
                render.render_whole(mi, scene, ctx.settings.spp, s.render_seed), dtype=np.float32
            )[..., 0:3]
            totals[name] += time.perf_counter() - t0
            del scene
        identical &= bool(np.array_equal(images["path"], images["moment"]))
    return {
        "integrator": ctx.settings.integrator,
        "samples": len(samples),
        "moment_s": totals["moment"],
        "path_s": totals["path"],
        "identical": identical,
    }


#: The build's phases a :class:`RenderCallTimer` times, in the order they are reported.
BUILD_PHASES = (
    "render calls",  # pipeline.render.renderer.render_scene
    "scene loads",  # MaterialScene.lit where it loads: scene dict + load_dict (the first render)
    "material moves",  # MaterialScene.lit of a material's first lighting: its BSDF + the emitters
    "emitter moves",  # MaterialScene.lit of its next ones: the emitter state + params.update
    "statistics",  # pipeline.image.stats.render_stats of each render
    "writer waits",  # the main thread blocked on the writer thread (queue full, end of a shard)
    "writer thread",  # EXR encoding, SHA-256, fsync and records, beside the next render
)


_LIT_PHASES = {"load": "scene loads", "material": "material moves", "light": "emitter moves"}


def _lit_phase(args) -> str:
    """The phase of ``MaterialScene.lit(self, mi, ball, camera, maps, light, settings)``."""
    held, _mi, ball, camera, maps, light, settings = args
    return _LIT_PHASES[held.step(ball, camera, maps, settings, light)]


class RenderCallTimer:
    """Times the phases of an in-process build (:data:`BUILD_PHASES`) while active.

    For an in-process build (workers=0) this splits the build's own wall time into its
    render calls and everything else, measured at the same moments, so the split is not
    disturbed by other load the way two separate measurements are. Each phase is a
    function looked up in its module (or class) at each call, so wrapping that attribute
    sees every call; ``writer thread`` runs beside the others, the rest on the main thread.
    """

    def __init__(self):
        self.phases = dict.fromkeys(BUILD_PHASES, 0.0)
        #: CPU time of the calling thread in each phase: the work itself, less disturbed by other
        #: load than wall time (render calls: the main thread mostly waits for drjit's threads)
        self.cpu = dict.fromkeys(BUILD_PHASES, 0.0)
        self.calls = 0

    def first_render(self) -> None:
        """The build starts its first render (its start-up, spec to cluster, is over)."""
        self._main_cpu = time.thread_time()

    @property
    def seconds(self) -> float:
        """Time inside render calls."""
        return self.phases["render calls"]

    def _wrap(self, owner, name, phase, counts=False):
        original = getattr(owner, name)

        def timed(*args, **kwargs):
            label = phase(args) if callable(phase) else phase
            start, cpu = time.perf_counter(), time.thread_time()
            try:
                return original(*args, **kwargs)
            finally:
                self.phases[label] += time.perf_counter() - start
                self.cpu[label] += time.thread_time() - cpu
                self.calls += counts

        setattr(owner, name, timed)
        self._restore.append((owner, name, original))

    def __enter__(self):
        self._restore = []
        self._main_cpu = time.thread_time()
        self._wrap(render, "render_scene", "render calls", counts=True)
        self._wrap(render, "render_stats", "statistics")
        self._wrap(render.MaterialScene, "lit", _lit_phase)
        self._wrap(shard.OrderedWriter, "submit", "writer waits")
        self._wrap(shard.OrderedWriter, "close", "writer waits")
        self._wrap(shard, "write_render_and_record", "writer thread")
        self._wrap(shard, "write_material_files", "writer thread")
        return self

    def __exit__(self, *exc):
        #: CPU time of the thread that ran the build (in-process: the main thread) from its
        #: first render on (as the build's wall time is counted: its start-up apart)
        self.main_cpu = time.thread_time() - self._main_cpu
        for owner, name, original in reversed(self._restore):
            setattr(owner, name, original)


def records_render_time(root: str) -> float:
    """Sum of the manifest's ``stats.time_s`` (each render_sample's wall time, in its worker)."""
    total = 0.0
    for line in read_manifest(Layout(root)).split(b"\n"):
        if line.strip():
            total += float(json.loads(line).get("stats", {}).get("time_s", 0.0))
    return total


def cpu_with_children() -> float:
    """CPU seconds of this process and of its terminated, reaped children (dask's nannies and
    workers are reaped when the build closes its local cluster)."""
    import resource

    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime
