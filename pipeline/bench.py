"""Benchmarks of the build: its overhead over bare Mitsuba renders, and what omitted effects save.

``shaderball bench SPEC`` (or ``python -m pipeline.bench SPEC``)
    Builds SPEC (optionally cut to about ``--samples`` renders, at another
    ``--resolution`` / ``--spp`` / ``--shard-size``) into a fresh folder, then renders the
    same samples with bare ``mi.render`` calls: the same scene dicts
    (:func:`pipeline.render.scene_dict`), each loaded once, one scene alive at a time,
    kernels compiled beforehand, only the render call timed. It prints the build's wall
    time over the sum of those render times (the overhead ratio; the target is at most
    1.03), samples per second of both, the same ratio in CPU time (this process and its
    reaped children: less disturbed by other load than wall time), for in-process builds
    the build's own split between its render calls and the rest (:class:`RenderCallTimer`,
    measured in the same run), and where the rest goes. Kernels are compiled before the
    build (one spp-1 render per material, which fills drjit's on-disk kernel cache), so
    the ratio is the steady state of a long build, not the first minute of a fresh
    machine. ``--profile`` adds two measurements behind the proposals in docs/build.md:
    all lightings of a material rendered from one loaded scene moved in place
    (:func:`sky.update_emitter_params`), and the ``moment`` integrator against its nested
    path tracer alone.

``shaderball bench --effects`` (or ``python -m pipeline.bench --effects``)
    Renders a few materials with each effect the build leaves out present and absent
    (:class:`pipeline.render.EffectPlan`) and reports the render time saved by each
    omission and whether the two images agree: bit-identical, equal to float rounding,
    or equal within noise by a per-pixel Z-test on the luminance variance of the
    ``moment`` integrator. The specular lobe of a zero specular albedo is measured too,
    to show why it is kept.

The helpers :func:`render_moments`, :func:`compare_renders`, :func:`bitmap_bsdf` and
:func:`flat_normal_map_bsdf` are shared with tests/test_effects.py;
:func:`render_in_passes` is the reference implementation of the determinism proposal of
docs/build.md (tests/test_build_bench.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import shutil
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.errors import ShaderballError
from pipeline.render import render_in_passes

#: Z above which a pixel's difference counts as beyond noise (two-sided p ~ 6e-5 if normal).
Z_LIMIT = 4.0
#: Two renders agree within noise when at most this share of pixels exceeds Z_LIMIT ...
Z_FAIL_SHARE = 0.01
#: ... and the summed difference over the image is within this many standard errors.
Z_TOTAL_LIMIT = 5.0
#: Relative max difference below which two renders are "equal to float32 rounding".
ROUNDING_REL = 1e-5


def _fail(option: str, value, allowed: str) -> ShaderballError:
    return ShaderballError(f"{option}: {value!r} is not allowed; allowed: {allowed}")


def _check_int(option: str, value, lo: int, hi: int) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise _fail(option, value, f"an integer from {lo} to {hi}")
    return int(value)


# --------------------------------------------------------------------------- renders and comparisons


@dataclass(frozen=True)
class MomentRender:
    """A render of the ``moment`` integrator: the RGB image and the variance of its luminance.

    The ``moment`` integrator's extra channels are CIE XYZ (``nested.X/Y/Z`` and
    ``m2_nested.X/Y/Z``), not RGB, and it keeps no cross moments, so the variance of each
    RGB channel can't be recovered; the luminance Y is the sRGB image's
    0.2126 R + 0.7152 G + 0.0722 B, and its variance is exact.
    """

    image: np.ndarray  # (H, W, 3) float32 linear RGB
    luminance: np.ndarray  # (H, W) float64, Y of the estimate
    luminance_variance: np.ndarray  # (H, W) float64, variance of the pixel estimate of Y
    seconds: float  # wall time of the render call, numpy conversion included
    cpu_seconds: float  # CPU time of this process (all render threads) over the same call


def render_moments(mi, scene, spp: int, seed: int) -> MomentRender:
    """Render a scene whose integrator is ``moment`` and split its channels."""
    names = list(scene.integrator().aov_names())
    if "nested.Y" not in names or "m2_nested.Y" not in names:
        raise ShaderballError(f"scene integrator: AOVs {names} are not the moment integrator's")
    start, cpu_start = time.perf_counter(), time.process_time()
    out = np.asarray(mi.render(scene, spp=spp, seed=seed), dtype=np.float32)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    m1 = out[..., 3 + names.index("nested.Y")].astype(np.float64)
    m2 = out[..., 3 + names.index("m2_nested.Y")].astype(np.float64)
    variance = np.clip(m2 - m1 * m1, 0.0, None) / spp
    return MomentRender(np.ascontiguousarray(out[..., 0:3]), m1, variance, seconds, cpu_seconds)


def compare_renders(a: MomentRender, b: MomentRender) -> dict:
    """How two renders of (supposedly) the same image differ.

    ``identical``: bit for bit. ``rounding``: max |a - b| <= ROUNDING_REL x max |a|.
    ``z_share``: share of pixels whose luminance difference exceeds Z_LIMIT standard
    errors (sqrt(var_a + var_b)); ``z_total``: the summed luminance difference over the
    image in standard errors of the sum. ``within_noise``: z_share <= Z_FAIL_SHARE and
    |z_total| <= Z_TOTAL_LIMIT (two renders with different seeds pass; see
    tests/test_effects.py, which checks that calibration).
    """
    diff = a.image.astype(np.float64) - b.image.astype(np.float64)
    max_abs = float(np.abs(diff).max()) if diff.size else 0.0
    scale = float(np.abs(a.image).max()) if a.image.size else 0.0
    dy = a.luminance - b.luminance
    var = a.luminance_variance + b.luminance_variance
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(var > 0, dy / np.sqrt(np.where(var > 0, var, 1.0)), np.where(dy == 0, 0.0, np.inf))
    total_var = float(var.sum())
    z_total = float(dy.sum() / math.sqrt(total_var)) if total_var > 0 else (0.0 if not dy.any() else math.inf)
    z_share = float(np.mean(np.abs(z) > Z_LIMIT))
    return {
        "identical": bool(np.array_equal(a.image, b.image)),
        "max_abs": max_abs,
        "max_rel": max_abs / scale if scale > 0 else (0.0 if max_abs == 0 else math.inf),
        "rounding": max_abs <= ROUNDING_REL * scale,
        "z_share": z_share,
        "z_total": z_total,
        "within_noise": z_share <= Z_FAIL_SHARE and abs(z_total) <= Z_TOTAL_LIMIT,
    }


def describe_comparison(c: dict) -> str:
    if c["identical"]:
        return "bit-identical"
    if c["rounding"]:
        return f"equal to rounding (max |diff| {c['max_abs']:.2g}, {c['max_rel']:.2g} of max)"
    verdict = "within noise" if c["within_noise"] else "DIFFERENT beyond noise"
    return (f"{verdict}: {100 * c['z_share']:.2f}% of pixels |z| > {Z_LIMIT:g}, "
            f"summed z {c['z_total']:+.1f}, max |diff| {c['max_abs']:.2g}")


def _bitmap(mi, data: np.ndarray) -> dict:
    array = np.array(data, dtype=np.float32, order="C", copy=True)
    if array.ndim == 2:
        array = array[..., None]
    return {"type": "bitmap", "bitmap": mi.Bitmap(array), "raw": True,
            "filter_type": "bilinear", "wrap_mode": "repeat"}


def bitmap_bsdf(maps, size: int, lobes: dict | None = None) -> dict:
    """The material BSDF of a uniform ``maps`` with its values replicated in size x size bitmaps.

    What the build would render without the textured -> constant omission (no normal map:
    combine with :func:`flat_normal_map_bsdf` for that).
    """
    from materials import mitsuba_bsdf
    from pipeline.mitsuba_env import load_mitsuba

    mi = load_mitsuba(mitsuba_bsdf.VARIANT)
    uniform = maps.uniform_values()
    if uniform is None:
        raise ShaderballError("bitmap_bsdf: the material is not uniform")
    replicated = uniform.to_maps(size)
    bsdf = mitsuba_bsdf.bsdf_dict(uniform.to_maps(1), lobes=lobes)
    if bsdf["type"] == "normalmap":
        bsdf = bsdf["bsdf"]
    bsdf = dict(bsdf)
    bsdf["diffuse"] = _bitmap(mi, replicated.diffuse)
    bsdf["specular"] = _bitmap(mi, replicated.specular)
    bsdf["roughness"] = _bitmap(mi, replicated.roughness)
    return bsdf


def flat_normal_map_bsdf(bsdf: dict, size: int) -> dict:
    """``bsdf`` inside Mitsuba's ``normalmap`` with a flat (0, 0, 1) size x size map."""
    from materials import mitsuba_bsdf
    from materials.maps import encode_normal_map
    from pipeline.mitsuba_env import load_mitsuba

    mi = load_mitsuba(mitsuba_bsdf.VARIANT)
    flat = np.zeros((size, size, 3), np.float32)
    flat[..., 2] = 1.0
    return mitsuba_bsdf.normalmap_dict(_bitmap(mi, encode_normal_map(flat)), bsdf)


def with_material_bsdf(scene: dict, bsdf: dict) -> dict:
    """A copy of a scene dict of :func:`pipeline.render.scene_dict` with another material BSDF."""
    from pipeline.mitsuba_scene import BALL_SHAPE_ID

    out = dict(scene)
    out[BALL_SHAPE_ID] = dict(scene[BALL_SHAPE_ID], bsdf=bsdf)
    return out


# --------------------------------------------------------------------------- effects benchmark


@dataclass
class EffectCase:
    omission: str
    material: str
    applied: bool  # does the build make this omission?
    wall_with: list[float]  # wall seconds of each timed render, with the effect
    wall_without: list[float]
    cpu_with: list[float]  # CPU seconds (all threads) of the same renders
    cpu_without: list[float]
    comparison: dict

    @staticmethod
    def _saved(with_: float, without: float) -> float:
        return 1.0 - without / with_ if with_ > 0 else 0.0

    @property
    def saved_wall(self) -> float:
        """Share of the wall time saved, best of the repeats of each (least disturbed by load)."""
        return self._saved(min(self.wall_with), min(self.wall_without))

    @property
    def saved_cpu(self) -> float:
        """Share of the CPU time saved, medians of the repeats."""
        return self._saved(statistics.median(self.cpu_with), statistics.median(self.cpu_without))

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "saved_wall": self.saved_wall, "saved_cpu": self.saved_cpu}


@dataclass
class EffectsBench:
    resolution: int
    spp: int
    repeats: int
    texture_size: int
    variant: str
    threads: int
    cases: list[EffectCase] = field(default_factory=list)

    def lines(self) -> list[str]:
        out = [f"effects benchmark: {self.resolution}x{self.resolution}, {self.spp} spp, {self.repeats} "
               f"alternating renders of each variant, {self.variant}, {self.threads} render threads; "
               f"textures {self.texture_size}x{self.texture_size}",
               "wall: best of the repeats; cpu: median CPU time of the process (all render threads)",
               f"{'omission':<36} {'material':<32} {'wall with/without':>18} {'saved':>6} "
               f"{'cpu with/without':>17} {'saved':>6}  images"]
        for c in self.cases:
            name = c.omission + ("" if c.applied else " [not applied]")
            out.append(f"{name:<36} {c.material:<32} {min(c.wall_with):7.3f}/{min(c.wall_without):7.3f}s "
                       f"{100 * c.saved_wall:5.1f}% {statistics.median(c.cpu_with):7.3f}/"
                       f"{statistics.median(c.cpu_without):7.3f}s {100 * c.saved_cpu:5.1f}%  "
                       f"{describe_comparison(c.comparison)}")
        return out

    def to_dict(self) -> dict:
        return {**{k: v for k, v in dataclasses.asdict(self).items() if k != "cases"},
                "cases": [c.to_dict() for c in self.cases]}


def _effect_cases(texture_size: int):
    """(omission, material label, applied by the build, scene with the effect, scene without).

    A scene is a function of ``base(maps, effects)`` (the build's scene dict for ``maps``,
    optionally with a forced :class:`pipeline.render.EffectPlan`).
    """
    from materials.maps import UniformMaterial
    from materials.mitsuba_bsdf import bsdf_dict
    from pipeline.render import plan_effects

    dielectric = UniformMaterial((0.5, 0.3, 0.2), (0.04, 0.04, 0.04), 0.4).to_maps(1)
    metal = UniformMaterial((0.0, 0.0, 0.0), (0.95, 0.64, 0.54), 0.3).to_maps(1)
    no_specular = UniformMaterial((0.5, 0.5, 0.5), (0.0, 0.0, 0.0), 0.2).to_maps(1)

    def built(maps, **forced):
        effects = dataclasses.replace(plan_effects(maps), **forced) if forced else None
        return lambda base: base(maps, effects)

    def swapped(maps, make_bsdf):
        return lambda base: with_material_bsdf(base(maps, None), make_bsdf())

    return [
        ("textured -> constant", "uniform dielectric, r=0.4", True,
         swapped(dielectric, lambda: bitmap_bsdf(dielectric, texture_size)), built(dielectric)),
        ("normal map -> none", "uniform dielectric, flat normal", True,
         swapped(dielectric, lambda: flat_normal_map_bsdf(bsdf_dict(dielectric), texture_size)),
         built(dielectric)),
        ("both -> constant, none", "uniform dielectric, flat normal", True,
         swapped(dielectric, lambda: flat_normal_map_bsdf(bitmap_bsdf(dielectric, texture_size),
                                                          texture_size)),
         built(dielectric)),
        ("diffuse lobe -> none", "copper-like metal, d=0, r=0.3", True,
         built(metal, diffuse_lobe=True), built(metal)),
        ("specular lobe -> none", "dielectric s=0, d=0.5, r=0.2", False,
         built(no_specular), built(no_specular, specular_lobe=False)),
    ]


def run_effects_bench(*, resolution: int | None = None, spp: int | None = None, repeats: int | None = None,
                      texture_size: int | None = None, seed: int = 1,
                      progress=None) -> EffectsBench:
    """Render time with and without each omission; see the module docstring."""
    from geometry import build_shaderball, default_camera
    from pipeline.mitsuba_env import load_mitsuba
    from pipeline.render import RenderSettings, scene_dict
    from sky import Light

    resolution = _check_int("--resolution", resolution, 16, 4096) or 128
    spp = _check_int("--spp", spp, 1, 65536) or 64
    repeats = _check_int("--repeats", repeats, 1, 100) or 5
    texture_size = _check_int("--texture-size", texture_size, 1, 4096) or 256
    mi = load_mitsuba("llvm_ad_rgb")
    import drjit as dr

    settings = RenderSettings(resolution=resolution, spp=spp, variant=mi.variant()).check()
    ball, camera = build_shaderball(), default_camera()
    light = Light(35.0, 300.0, 3.0)  # sun from the camera's left, above: highlights and shading

    def base(maps, effects):
        return scene_dict(ball, camera, maps, light, settings, effects)[0]

    bench = EffectsBench(resolution, spp, repeats, texture_size, mi.variant(), dr.thread_count())
    for omission, label, applied, make_with, make_without in _effect_cases(texture_size):
        if progress:
            progress(f"effects: {omission} ...")
        scene_with, scene_without = mi.load_dict(make_with(base)), mi.load_dict(make_without(base))
        first_with = render_moments(mi, scene_with, spp, seed)  # compiles; also the compared image
        first_without = render_moments(mi, scene_without, spp, seed)
        timed_with, timed_without = [], []
        for r in range(repeats):
            timed_with.append(render_moments(mi, scene_with, spp, seed + 1 + r))
            timed_without.append(render_moments(mi, scene_without, spp, seed + 1 + r))
        bench.cases.append(EffectCase(
            omission, label, applied, [t.seconds for t in timed_with], [t.seconds for t in timed_without],
            [t.cpu_seconds for t in timed_with], [t.cpu_seconds for t in timed_without],
            compare_renders(first_with, first_without)))
    return bench


# --------------------------------------------------------------------------- build benchmark


def derive_spec(spec, *, samples: int | None = None, resolution: int | None = None, spp: int | None = None,
                shard_size: int | None = None):
    """``spec`` cut to about ``samples`` renders (whole materials) and re-sized; other fields kept."""
    dataset, render = spec.dataset, spec.render
    if shard_size is not None:
        dataset = dataclasses.replace(dataset, shard_size=shard_size)
    if samples is not None:
        lights = dataset.lights_per_material
        if samples < lights:
            dataset = dataclasses.replace(dataset, materials=1, lights_per_material=samples)
        else:
            dataset = dataclasses.replace(dataset, materials=-(-samples // lights))
    if resolution is not None:
        render = dataclasses.replace(render, resolution=resolution)
    if spp is not None:
        render = dataclasses.replace(render, spp=spp)
    return dataclasses.replace(spec, dataset=dataset, render=render)


@dataclass
class SampleTiming:
    sample_id: str
    dict_s: float  # pipeline.render.scene_dict
    load_s: float  # mi.load_dict
    render_s: float  # mi.render + numpy conversion: the bare render
    render_cpu_s: float  # CPU time of this process (all render threads) over the same call
    identical: bool  # the bare render equals the build's stored render, bit for bit


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
    timings: list[SampleTiming] = field(default_factory=list)
    material_files_s: float = 0.0  # per material: raster projection + maps (+ texture) EXR
    render_file_s: float = 0.0  # per render: EXR encode + SHA-256 + atomic write
    reuse: dict | None = None
    moment: dict | None = None
    compiled: dict | None = None  # kernels compiled during the timed bare renders (should be 0)

    @property
    def bare_s(self) -> float:
        return sum(t.render_s for t in self.timings)

    @property
    def ratio(self) -> float:
        return self.build_s / self.bare_s if self.bare_s > 0 else math.inf

    @property
    def bare_cpu_s(self) -> float:
        return sum(t.render_cpu_s for t in self.timings)

    @property
    def cpu_ratio(self) -> float:
        """Build CPU over bare-render CPU: less disturbed than wall time on a shared machine."""
        return self.build_cpu_s / self.bare_cpu_s if self.bare_cpu_s > 0 else math.inf

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
            f"ratio build / bare:       {self.ratio:8.3f}   (target <= 1.03); "
            f"without start-up: {(self.build_s - self.startup_s) / self.bare_s:.3f}; "
            f"CPU time {self.build_cpu_s:.1f} s / {self.bare_cpu_s:.1f} s = {self.cpu_ratio:.3f}",
            *([f"in-process build, same run: {self.in_build_render_s:.2f} s in render calls, "
               f"{self.build_s - self.in_build_render_s:.2f} s elsewhere: build / its own renders = "
               f"{self.build_s / self.in_build_render_s:.3f}"] if self.in_build_render_s else []),
            f"bare renders bit-identical to the build's: "
            f"{sum(t.identical for t in self.timings)}/{len(self.timings)}",
            "where the rest goes, per render (measured outside the build): "
            f"scene_dict {mean([t.dict_s for t in self.timings]):.3f} s, "
            f"load_dict {mean([t.load_s for t in self.timings]):.3f} s, "
            f"render EXR+SHA-256+fsync {self.render_file_s:.3f} s; per material: raster + maps EXR "
            f"{self.material_files_s:.3f} s",
        ]
        if self.compiled:
            out.append("kernels compiled during the timed renders (0 = all warm): "
                       + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}"
                                   for k, v in self.compiled.items()))
        if self.reuse:
            r = self.reuse
            out.append(f"profile, one loaded scene per material moved in place: {r['seconds']:.2f} s for "
                       f"{n} renders, {r['seconds'] - r['compile_s']:.2f} s without its {r['compiled']} "
                       f"kernel compile(s) (vs {r['fresh_seconds']:.2f} s dict+load+render each), "
                       f"{r['identical']}/{n} bit-identical to the build's")
        if self.moment:
            m = self.moment
            out.append(f"profile, moment vs plain {m['integrator']} ({m['samples']} renders): "
                       f"{m['moment_s']:.2f} s vs {m['path_s']:.2f} s "
                       f"({100 * (m['moment_s'] / m['path_s'] - 1):+.1f}%), RGB "
                       f"{'bit-identical' if m['identical'] else 'not bit-identical'}")
        return out

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(bare_s=self.bare_s, ratio=self.ratio, bare_cpu_s=self.bare_cpu_s, cpu_ratio=self.cpu_ratio)
        return d


def _materials_of(plans):
    return [m for shard in plans for m in shard.materials]


def warm_kernels(spec, plans) -> float:
    """Compile (or fetch from drjit's disk cache) every kernel the build will need.

    One spp-1 render per material: spp is not part of a kernel, the resolution is.
    """
    from pipeline.materialize import make_material
    from pipeline.render import scene_dict
    from pipeline.shard import worker_context
    from sky import Light

    ctx = worker_context(spec)
    from pipeline.mitsuba_env import load_mitsuba

    mi = load_mitsuba(spec.render.variant)
    start = time.perf_counter()
    for material in _materials_of(plans):
        maps, _ = make_material(material, spec)
        s = material.samples[0]
        desc, _, _ = scene_dict(ctx.ball, ctx.camera, maps, Light(s.elevation_deg, s.azimuth_deg, s.turbidity),
                                ctx.settings)
        np.asarray(mi.render(mi.load_dict(desc), spp=1, seed=0))
    return time.perf_counter() - start


class KernelCounter:
    """Counts drjit kernels compiled (not found in the memory or disk cache) while active.

    A kernel's hash covers the Mitsuba objects alive in the process (virtual calls are
    traced over every registered instance), so two scenes alive at once give new kernels:
    the measurements below keep one scene alive at a time, as a build worker does.
    """

    def __init__(self):
        import drjit as dr

        self._dr = dr
        self.compiled = 0
        self.compile_s = 0.0

    def __enter__(self):
        self._dr.set_flag(self._dr.JitFlag.KernelHistory, True)
        self._dr.kernel_history()  # clears
        return self

    def __exit__(self, *exc):
        dr = self._dr
        for k in dr.kernel_history():
            if k["type"] == dr.KernelType.JIT and not k.get("cache_hit"):
                self.compiled += 1
                self.compile_s += k.get("backend_time", 0.0) / 1000.0
        dr.set_flag(dr.JitFlag.KernelHistory, False)


def _stored_render(layout, sample) -> np.ndarray:
    from pipeline.exr import read_exr

    return read_exr(layout.path(layout.render_rel(sample.shard_id, sample.sample_id))).layers["render"]


def _render_seed(layout, sample) -> int:
    from pipeline.records import read_json

    record = read_json(layout.path(layout.record_rel(sample.shard_id, sample.sample_id))) or {}
    return int(record.get("seeds", {}).get("render_used", sample.render_seed))


def _light(sample):
    from sky import Light

    return Light(sample.elevation_deg, sample.azimuth_deg, sample.turbidity)


def measure_bare(spec, plans, root: str, kernels: KernelCounter) -> list[SampleTiming]:
    """Time scene_dict, load_dict and the bare render of every sample; compare with the build."""
    from pipeline.layout import Layout
    from pipeline.materialize import make_material
    from pipeline.mitsuba_env import load_mitsuba
    from pipeline.render import scene_dict
    from pipeline.shard import worker_context

    ctx = worker_context(spec)
    mi = load_mitsuba(spec.render.variant)
    layout = Layout(root)
    timings = []
    for material in _materials_of(plans):
        maps, _ = make_material(material, spec)
        for s in material.samples:
            seed = _render_seed(layout, s)
            t0 = time.perf_counter()
            desc, _, _ = scene_dict(ctx.ball, ctx.camera, maps, _light(s), ctx.settings)
            t1 = time.perf_counter()
            scene = mi.load_dict(desc)
            t2, cpu = time.perf_counter(), time.process_time()
            with kernels:
                # The build's own arithmetic: power-of-two passes (pipeline.render.render_in_passes).
                out = render_in_passes(mi, scene, ctx.settings.spp, seed).astype(np.float32)
            t3, cpu = time.perf_counter(), time.process_time() - cpu
            del scene, desc  # one scene alive at a time, as in a build worker
            timings.append(SampleTiming(s.sample_id, t1 - t0, t2 - t1, t3 - t2, cpu,
                                        bool(np.array_equal(_stored_render(layout, s), out[..., 0:3]))))
    return timings


def measure_storage(spec, plans, root: str) -> tuple[float, float]:
    """(per material: raster + maps files, per render: EXR + hash + atomic write), in seconds."""
    from pipeline.exr import write_exr
    from pipeline.layout import Layout
    from pipeline.materialize import make_material
    from pipeline.shard import worker_context, write_material_files

    ctx = worker_context(spec)
    layout = Layout(root)
    scratch = tempfile.mkdtemp(prefix="shaderball-bench-io-")
    try:
        materials = _materials_of(plans)[:4]
        start = time.perf_counter()
        for material in materials:
            maps, description = make_material(material, spec)
            write_material_files(Layout(scratch), spec, ctx, material, maps, description)
        per_material = (time.perf_counter() - start) / len(materials)
        images = [_stored_render(layout, s) for m in materials for s in m.samples][:8]
        start = time.perf_counter()
        for i, image in enumerate(images):
            write_exr(os.path.join(scratch, f"r{i}.render.exr"), {"render": image}, {"id": str(i)},
                      compression=spec.storage.compression)
        per_render = (time.perf_counter() - start) / len(images)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return per_material, per_render


def measure_reuse(spec, plans, root: str, kernels: KernelCounter) -> dict:
    """All lightings of a material from one loaded scene, moved with sky.update_emitter_params.

    The first lighting renders the scene as loaded, the others after an in-place update:
    the proposal of docs/build.md, timed against dict + load + render per sample.
    """
    from pipeline.layout import Layout
    from pipeline.materialize import make_material
    from pipeline.mitsuba_env import load_mitsuba
    from pipeline.render import scene_dict
    from pipeline.shard import worker_context
    from sky import update_emitter_params

    ctx = worker_context(spec)
    mi = load_mitsuba(spec.render.variant)
    layout = Layout(root)
    seconds = 0.0
    identical = 0
    for material in _materials_of(plans):
        maps, _ = make_material(material, spec)
        scene = params = None
        for s in material.samples:
            seed = _render_seed(layout, s)
            t0 = time.perf_counter()
            if scene is None:
                desc, _, _ = scene_dict(ctx.ball, ctx.camera, maps, _light(s), ctx.settings)
                scene = mi.load_dict(desc)
                params = mi.traverse(scene)
            else:
                update_emitter_params(params, _light(s), sun=ctx.settings.sun, variant=ctx.variant)
            with kernels:
                out = render_in_passes(mi, scene, ctx.settings.spp, seed).astype(np.float32)
            seconds += time.perf_counter() - t0
            identical += bool(np.array_equal(_stored_render(layout, s), out[..., 0:3]))
        del scene, params
    return {"seconds": seconds, "identical": identical}


def measure_moment(spec, plans, count: int = 3) -> dict:
    """The first ``count`` samples rendered by the nested integrator alone, against ``moment``.

    Each scene is loaded, rendered once at 1 spp (compiling its kernels if needed), then
    timed at full spp; one scene alive at a time.
    """
    from pipeline.materialize import make_material
    from pipeline.mitsuba_env import load_mitsuba
    from pipeline.render import scene_dict
    from pipeline.shard import worker_context

    ctx = worker_context(spec)
    mi = load_mitsuba(spec.render.variant)
    totals = {"moment": 0.0, "path": 0.0}
    identical = True
    samples = [(m, s) for m in _materials_of(plans) for s in m.samples][:count]
    for material, s in samples:
        maps, _ = make_material(material, spec)
        desc, _, _ = scene_dict(ctx.ball, ctx.camera, maps, _light(s), ctx.settings)
        images = {}
        for name, d in (("path", dict(desc, integrator=desc["integrator"]["nested"])), ("moment", desc)):
            scene = mi.load_dict(d)
            np.asarray(mi.render(scene, spp=1, seed=0))
            t0 = time.perf_counter()
            images[name] = np.asarray(mi.render(scene, spp=ctx.settings.spp, seed=s.render_seed),
                                      dtype=np.float32)[..., 0:3]
            totals[name] += time.perf_counter() - t0
            del scene
        identical &= bool(np.array_equal(images["path"], images["moment"]))
    return {"integrator": ctx.settings.integrator, "samples": len(samples), "moment_s": totals["moment"],
            "path_s": totals["path"], "identical": identical}


class RenderCallTimer:
    """Times every ``pipeline.render.render_scene`` call made in this process while active.

    For an in-process build (workers=0) this splits the build's own wall time into its
    render calls and everything else, measured at the same moments, so the split is not
    disturbed by other load the way two separate measurements are. (render_scene is looked
    up in its module at each call, so wrapping the module attribute sees every call.)
    """

    def __init__(self):
        self.seconds = 0.0
        self.calls = 0

    def __enter__(self):
        import pipeline.render as render

        self._module, self._original = render, render.render_scene

        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return self._original(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start
                self.calls += 1

        render.render_scene = timed
        return self

    def __exit__(self, *exc):
        self._module.render_scene = self._original


def _cpu_with_children() -> float:
    """CPU seconds of this process and of its terminated, reaped children (dask's nannies and
    workers are reaped when the build closes its local cluster)."""
    import resource

    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def run_build_bench(spec_path: str, *, out: str | None = None, samples: int | None = None,
                    resolution: int | None = None, spp: int | None = None, workers: int | None = None,
                    shard_size: int | None = None, profile: bool = False, progress=None) -> BuildBench:
    """Build a spec and time the same renders bare; see the module docstring."""
    from pipeline.atomic import write_text_atomic
    from pipeline.build import build, read_spec_text
    from pipeline.mitsuba_env import load_mitsuba
    from pipeline.plan import plan_dataset
    from pipeline.spec import spec_to_toml

    samples = _check_int("--samples", samples, 1, 1_000_000)
    resolution = _check_int("--resolution", resolution, 16, 4096)
    spp = _check_int("--spp", spp, 1, 65536)
    workers = _check_int("--workers", workers, 0, 1024)
    shard_size = _check_int("--shard-size", shard_size, 1, 1_000_000)
    spec, _ = read_spec_text(spec_path)
    spec = derive_spec(spec, samples=samples, resolution=resolution, spp=spp, shard_size=shard_size)
    if out is not None and os.path.exists(out) and (not os.path.isdir(out) or os.listdir(out)):
        raise _fail("--out", out, "a new or empty folder (the benchmark builds from scratch)")
    scratch = tempfile.mkdtemp(prefix="shaderball-bench-")
    root = out or os.path.join(scratch, "dataset")
    say = progress or (lambda message: None)
    try:
        derived_path = os.path.join(scratch, "bench-spec.toml")
        write_text_atomic(derived_path, spec_to_toml(spec))
        plans = plan_dataset(spec)
        mi = load_mitsuba(spec.render.variant)
        import drjit as dr

        say("warming kernels (one spp-1 render per material) ...")
        warmup = warm_kernels(spec, plans)
        marks = {}

        def started(where, _dashboard):
            marks["where"] = where
            marks["started"] = time.perf_counter()

        say("building ...")
        cpu0 = _cpu_with_children()
        in_build = RenderCallTimer()
        t0 = time.perf_counter()
        with in_build:
            summary = build(derived_path, root, workers=workers, on_start=started)
        build_s = time.perf_counter() - t0
        build_cpu = _cpu_with_children() - cpu0
        first_start = min((marks.get("started", t0) - t0), build_s)
        say("bare renders ...")
        kernels = KernelCounter()
        timings = measure_bare(spec, plans, root, kernels)
        per_material, per_render = measure_storage(spec, plans, root)
        bench = BuildBench(
            spec_name=spec.dataset.name, samples=summary.total, materials=spec.dataset.materials,
            resolution=spec.render.resolution, spp=spec.render.spp,
            workers=marks.get("where", "?"), variant=mi.variant(), threads=dr.thread_count(),
            warmup_s=warmup, build_s=build_s, build_cpu_s=build_cpu, startup_s=first_start,
            in_build_render_s=in_build.seconds if in_build.calls else None,
            timings=timings, material_files_s=per_material, render_file_s=per_render)
        bench.compiled = {"bare renders": kernels.compiled, "compile seconds": round(kernels.compile_s, 2)}
        if profile:
            say("profile: one scene per material ...")
            reuse_kernels = KernelCounter()
            bench.reuse = measure_reuse(spec, plans, root, reuse_kernels)
            bench.reuse.update(fresh_seconds=sum(t.dict_s + t.load_s + t.render_s for t in timings),
                               compiled=reuse_kernels.compiled, compile_s=reuse_kernels.compile_s)
            say("profile: moment vs plain integrator ...")
            bench.moment = measure_moment(spec, plans)
        return bench
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


# --------------------------------------------------------------------------- python -m pipeline.bench


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m pipeline.bench", description=__doc__.split("\n\n")[0])
    p.add_argument("spec", nargs="?", help="spec file to build (not needed with --effects)")
    p.add_argument("--samples", type=int, help="cut the spec to about this many renders (whole materials)")
    p.add_argument("--resolution", type=int, help="override render.resolution (effects: default 128)")
    p.add_argument("--spp", type=int, help="override render.spp (effects: default 64)")
    p.add_argument("--workers", type=int, help="as `shaderball build --workers` (default: the build's)")
    p.add_argument("--shard-size", type=int, help="override dataset.shard_size (materials per shard)")
    p.add_argument("--out", help="keep the benchmark's dataset here (a new or empty folder)")
    p.add_argument("--profile", action="store_true", help="also time scene reuse and moment vs path")
    p.add_argument("--effects", action="store_true", help="run the effects benchmark instead")
    p.add_argument("--repeats", type=int, help="effects: timed renders per variant (default 5)")
    p.add_argument("--json", dest="json_path", help="also write the figures to this JSON file")
    return p


def run_from_args(spec=None, *, effects=False, samples=None, resolution=None, spp=None, workers=None,
                  shard_size=None, out=None, profile=False, repeats=None, json_path=None, progress=None):
    """What `shaderball bench` and `python -m pipeline.bench` do; returns the result object."""
    if effects:
        result = run_effects_bench(resolution=resolution, spp=spp, repeats=repeats, progress=progress)
    else:
        if not spec:
            raise ShaderballError("SPEC: missing; allowed: a spec file (e.g. manifests/smoke.toml), "
                                  "or --effects for the effects benchmark")
        result = run_build_bench(spec, out=out, samples=samples, resolution=resolution, spp=spp,
                                 workers=workers, shard_size=shard_size, profile=profile, progress=progress)
    if json_path:
        from pipeline.atomic import write_text_atomic
        from pipeline.records import dumps

        write_text_atomic(json_path, dumps(result.to_dict()) + "\n")
    return result


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    try:
        result = run_from_args(**vars(args), progress=lambda m: print(m, file=sys.stderr, flush=True))
    except ShaderballError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    print("\n".join(result.lines()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
