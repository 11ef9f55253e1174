"""`shaderball study SPEC --out DIR`: render references and configurations, measure, report.

Order of work: the selection (:mod:`pipeline.study.select`), then every sample's
reference (the expensive part, written first so a killed study keeps them), then every
configuration of every sample, each row written as soon as it is measured. Re-running the
same command on the same folder resumes: references and rows already written are kept;
another request on the same folder is refused. Nothing is written before every option
and the spec have been checked.

Every configuration is rendered with ``repeats`` seeds per sample (seed: the sample's render
seed, the configuration's settings and the repeat index; never the clock), and the spec's
recipe once more with other seeds: the A/A configuration, the recipe against itself.

Time is what a build pays per render (``build_cpu_s``): the render, any post-process, the
scene load divided by the lightings that share a loaded scene in a build
(``lights_per_material``), and kernel compilation as a build pays it: a kernel compiled
the first time these settings meet this scene structure
(:class:`pipeline.render.renderer.EffectPlan`) in this process is paid once per build
worker, so it is divided by a build's renders per worker (the spec's renders over this
machine's cores); one compiled again later for the same settings and structure counts in
full. Compilation is drjit's own record of its backend time for kernels not found in its
memory or disk cache. Before each timed render the same scene is rendered
once (at 1 spp for the independent sampler, whose kernels do not depend on the spp; with
the same passes for the other samplers, whose kernels do), so the render's own time
(``render_cpu_s``) is kernels warm. CPU time is the process's over all threads
(time.process_time), so it counts every render thread.
"""

from __future__ import annotations

import dataclasses
import datetime
import io
import json
import math
import os
import time
import zlib
from dataclasses import dataclass, replace

import numpy as np

from geometry import build_shaderball, default_camera
from pipeline.dataset.materialize import make_material
from pipeline.dataset.plan import plan_dataset
from pipeline.image.denoise import denoise
from pipeline.image.tonemap import hdr_to_srgb8
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.kernels import KernelCounter
from pipeline.render.mitsuba_env import load_mitsuba, resolve_variant
from pipeline.render.raster import project_material
from pipeline.render.renderer import (
    MaterialScene,
    RenderSettings,
    luminance_variance,
    plan_effects,
    render_pass,
    render_scene,
)
from pipeline.store.atomic import write_bytes_atomic, write_text_atomic
from pipeline.study import measure as m
from pipeline.study.configs import Config, aa_name, paper_name, study_configs
from pipeline.study.denoise import guides, shape_ids_and_normals
from pipeline.study.report import write_outputs
from pipeline.study.request import (
    REQUEST_FILE,
    StudyRequest,
    StudySummary,
    check_request,
    check_resumable,
    machine_line,
    request_record,
)
from pipeline.study.select import select_samples
from sky import Light


def derived_seed(*keys) -> int:
    """A 32-bit seed keyed by integers and strings (strings through CRC-32)."""
    words = [k if isinstance(k, int) else zlib.crc32(str(k).encode()) for k in keys]
    return int(np.random.SeedSequence(words).generate_state(1, np.uint32)[0])


def _finite(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


class SampleScene:
    """One study sample: its material, light and screen-space maps; renders it under settings."""

    def __init__(self, ctx, sample, plan):
        self.ctx, self.sample = ctx, sample
        self.maps, _ = make_material(plan, ctx.spec)
        self.light = Light(sample.elevation_deg, sample.azimuth_deg, sample.turbidity)
        self.screen = project_material(self.maps, ctx.gbuffer)
        #: The scene's structure: scenes of equal structure and settings share kernels.
        self.structure = plan_effects(self.maps).key()

    def scene(self, settings):
        loaded, _, _ = MaterialScene().lit(self.ctx.mi, self.ctx.ball, self.ctx.camera, self.maps, self.light, settings)
        return loaded

    def render(self, settings: RenderSettings, seed: int, passes: tuple[int, ...] = (), warm: bool = True) -> dict:
        """Load and render; ``warm``: first render the scene once untimed (its kernels compile).

        Without ``warm`` (kernels already compiled for these settings and this structure) a
        kernel that compiles anyway is counted by drjit's record and taken out of the
        render's CPU time: compilation is reported apart (``compile_s``)."""
        mi, mask = self.ctx.mi, self.ctx.gbuffer.mask
        load_wall, load_cpu = time.perf_counter(), time.process_time()
        scene = self.scene(settings)
        load_wall, load_cpu = time.perf_counter() - load_wall, time.process_time() - load_cpu
        # The independent sampler's kernels do not depend on the spp; the other samplers' do
        # (measured: ~0.8 s per new sample count at 80x80), so they are warmed with the very
        # passes they are timed with.
        with KernelCounter() as warm_compiled:
            if warm and passes:
                for p in sorted(set(passes)):
                    render_pass(mi, scene, 1 if settings.sampler == "independent" else p, seed, 99, settings.sampler)
            elif warm:
                render_scene(
                    mi,
                    scene,
                    1 if settings.sampler == "independent" else settings.spp,
                    derived_seed(seed, "warm"),
                    sampler=settings.sampler,
                    target_error=settings.target_error,
                    mask=mask,
                )
        with KernelCounter() as compiled:
            wall, cpu = time.perf_counter(), time.process_time()
            if passes:
                done = [render_pass(mi, scene, p, seed, k, settings.sampler) for k, p in enumerate(passes)]
                result = {
                    "passes": [d[0] for d in done],
                    "spp_used": int(sum(d[1] for d in done)),
                    "error_estimate": None,
                }
            else:
                out = render_scene(
                    mi,
                    scene,
                    settings.spp,
                    seed,
                    sampler=settings.sampler,
                    target_error=settings.target_error,
                    mask=mask,
                )
                result = {
                    "image": out.image,
                    "variance": out.variance,
                    "spp_used": out.spp_used,
                    "error_estimate": out.error_estimate,
                }
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        result.update(
            wall_s=max(0.0, wall - compiled.compile_s),
            cpu_s=max(0.0, cpu - compiled.compile_s),
            load_wall_s=load_wall,
            load_cpu_s=load_cpu,
            compile_s=warm_compiled.compile_s + compiled.compile_s,
            kernels_compiled=warm_compiled.compiled + compiled.compiled,
        )
        del scene
        return result


@dataclass
class Context:
    spec: object
    variant: str
    mi: object
    ball: object
    camera: object
    gbuffer: object
    base: RenderSettings
    shape_ids: np.ndarray
    normals: np.ndarray
    #: Renders a build worker makes (the spec's renders over this machine's cores): what a
    #: kernel compiled once per worker is divided by.
    renders_per_worker: float = 1.0
    #: Lightings of a material that share one loaded scene in a build.
    lights_per_material: int = 1
    #: Settings keys already rendered in this process (their kernels compiled once).
    warmed: set = dataclasses.field(default_factory=set)


def robust_combine(passes: list[np.ndarray], post: str) -> np.ndarray:
    """Equal passes (each (H, W, 9) moments) combined per pixel: mean, trim (drop the pass
    brightest in luminance, average the rest) or mom (median of the pass means per channel)."""
    images = np.stack([p[..., 0:3] for p in passes])
    if post == "mean":
        return images.mean(axis=0).astype(np.float32)
    if post == "trim":
        y = images @ m.LUMA
        brightest = np.argmax(y, axis=0)
        keep = np.ones(y.shape, bool)
        np.put_along_axis(keep, brightest[None], False, axis=0)
        return ((images * keep[..., None]).sum(axis=0) / (len(passes) - 1)).astype(np.float32)
    if post == "mom":
        return np.median(images, axis=0).astype(np.float32)
    raise ValueError(post)


def render_reference(subject: SampleScene, ctx: Context, reference_spp: int) -> dict:
    settings = replace(ctx.base, spp=reference_spp // 2)
    seed = subject.sample.render_seed
    halves = [subject.render(settings, derived_seed(seed, "reference", h)) for h in (1, 2)]
    image = ((halves[0]["image"].astype(np.float64) + halves[1]["image"]) / 2).astype(np.float32)
    variance = ((halves[0]["variance"].astype(np.float64) + halves[1]["variance"]) / 4).astype(np.float32)
    floor = m.reference_floor(image, variance, halves[0]["image"], halves[1]["image"], ctx.gbuffer.mask)
    return {
        "image": image,
        "variance": variance,
        "half1": halves[0]["image"],
        "half2": halves[1]["image"],
        "floor": floor,
        "cpu_s": halves[0]["cpu_s"] + halves[1]["cpu_s"],
        "wall_s": halves[0]["wall_s"] + halves[1]["wall_s"],
    }


def save_reference(path: str, ref: dict) -> None:
    buf = io.BytesIO()
    np.savez(
        buf,
        image=ref["image"],
        variance=ref["variance"],
        half1=ref["half1"],
        half2=ref["half2"],
        meta=np.frombuffer(
            json.dumps({"floor": ref["floor"], "cpu_s": ref["cpu_s"], "wall_s": ref["wall_s"]}).encode(), dtype=np.uint8
        ),
    )
    write_bytes_atomic(path, buf.getvalue())


def load_reference(path: str) -> dict | None:
    try:
        with np.load(path) as z:
            ref = {k: z[k] for k in ("image", "variance", "half1", "half2")}
            ref.update(json.loads(z["meta"].tobytes().decode()))
    except (OSError, ValueError, KeyError, EOFError):
        return None
    return ref


def row_key(config_name: str, repeat: int) -> str:
    """A row's key in ``rows/SAMPLE.json``: the configuration and the repeat index."""
    return f"{config_name}#{repeat}"


def measure_config(
    subject: SampleScene, ctx: Context, config: Config, ref: dict, cache: dict, flip: bool, repeat: int = 0
) -> dict:
    key = config.settings_key()
    seed = derived_seed(subject.sample.render_seed, repr(key), "repeat", repeat)
    if (key, repeat) not in cache:
        settings = replace(ctx.base, spp=config.spp, **config.changes)
        for old in [k for k, v in cache.items() if "passes" in v]:  # pass stacks are big: keep one
            del cache[old]
        # Warm once per settings and scene structure: later renders find the kernels cached.
        first = (key, subject.structure) not in ctx.warmed
        ctx.warmed.add((key, subject.structure))
        r = subject.render(settings, seed, config.passes, warm=first)  # denoisers reuse the ladder's renders
        # A kernel compiled at the first render of these settings and this scene structure in
        # this process is paid once per build worker; compiled again later, per render.
        r["compile_paid_s"] = r["compile_s"] / ctx.renders_per_worker if first else r["compile_s"]
        cache[(key, repeat)] = r
    r = cache[(key, repeat)]
    post_wall = post_cpu = 0.0
    variance = None
    if config.post in ("mean", "trim", "mom"):
        wall, cpu = time.perf_counter(), time.process_time()
        image = robust_combine(r["passes"], config.post)
        post_wall, post_cpu = time.perf_counter() - wall, time.process_time() - cpu
        if config.post == "mean":
            acc = np.mean(np.stack(r["passes"]), axis=0)
            variance = luminance_variance(acc, r["spp_used"])
    elif config.post in ("oidn", "oidn-color"):
        albedo = normal = None
        if config.post == "oidn":
            albedo, normal = guides(ctx.shape_ids, ctx.normals, subject.screen)
        image, post_wall, post_cpu = denoise(r["image"], albedo, normal)
    else:
        image, variance = r["image"], r["variance"]
    metrics = m.measure(image, ref, ctx.gbuffer.mask, variance, flip=flip)
    row = {
        "sample_id": subject.sample.sample_id,
        "material_class": subject.sample.material_class,
        "config": config.name,
        "family": config.family,
        "post": config.post,
        "spp": config.spp,
        "spp_used": r["spp_used"],
        "seed": seed,
        "repeat": repeat,
        **config.changes,
        "error_estimate": r["error_estimate"],
        "render_wall_s": r["wall_s"],
        "render_cpu_s": r["cpu_s"],
        "post_wall_s": post_wall,
        "post_cpu_s": post_cpu,
        "wall_s": r["wall_s"] + post_wall,
        "cpu_s": r["cpu_s"] + post_cpu,
        "load_cpu_s": r["load_cpu_s"],
        "compile_s": r["compile_s"],
        "kernels_compiled": r["kernels_compiled"],
        "build_cpu_s": r["cpu_s"] + post_cpu + r["load_cpu_s"] / ctx.lights_per_material + r["compile_paid_s"],
        "floor_ball": ref["floor"]["floor_ball"],
        **metrics,
    }
    return {k: _finite(v) for k, v in row.items()}


def run_study(req: StudyRequest, progress=None, command: str = "") -> StudySummary:
    """Run (or resume) a study; see the module's docstring. ``command``: the command line
    that asked for it, as the report's first line names it."""
    started = time.perf_counter()
    spec = check_request(req)
    record = request_record(req, spec)
    check_resumable(req, record)
    ctx = study_context(spec, record["resolution"])
    selection = select_samples(spec, req.draws, req.scan)
    configs = chosen_configs(req, spec)
    wanted = {s.material_index for s in selection}
    plans = {p.material_index: p for shard in plan_dataset(spec) for p in shard.materials if p.material_index in wanted}

    os.makedirs(os.path.join(req.out, "references"), exist_ok=True)
    os.makedirs(os.path.join(req.out, "rows"), exist_ok=True)
    write_text_atomic(os.path.join(req.out, REQUEST_FILE), json.dumps(record, indent=1) + "\n")
    tick = Ticker(len(selection) * (1 + req.repeats * len(configs)), started, progress)
    subjects = {s.sample_id: SampleScene(ctx, s, plans[s.material_index]) for s in selection}
    references = ensure_references(req, ctx, selection, subjects, tick)
    rows, counts = measure_rows(req, ctx, selection, configs, subjects, references, tick)
    meta = study_meta(req, ctx, record, selection, configs, references, command)
    recommendations = write_outputs(req.out, meta, rows, configs)
    return StudySummary(
        req.out,
        len(selection),
        len(configs),
        len(rows),
        counts["rendered"],
        counts["reused"],
        time.perf_counter() - started,
        recommendations,
    )


def study_context(spec, resolution: int) -> Context:
    """Mitsuba loaded, the shaderball, its G-buffer and guides at ``resolution``, and the
    paper's recipe at the study's resolution (the spec's sampler, clamp and target are the
    configurations' to vary)."""
    variant = resolve_variant(spec.render.variant)
    mi = load_mitsuba(variant)
    ball, camera = build_shaderball(), default_camera()
    gbuffer = load_gbuffer(ball, camera, resolution, variant)
    r = spec.render
    base = RenderSettings(
        resolution=resolution, spp=r.spp, max_depth=r.max_depth, integrator=r.integrator, sun=r.sun, variant=variant
    )
    shape_ids, normals = shape_ids_and_normals(ball, camera, resolution, variant)
    return Context(
        spec,
        variant,
        mi,
        ball,
        camera,
        gbuffer,
        base,
        shape_ids,
        normals,
        renders_per_worker=max(1.0, spec.dataset.n_renders / (os.cpu_count() or 1)),
        lights_per_material=spec.dataset.lights_per_material,
    )


def chosen_configs(req: StudyRequest, spec) -> list[Config]:
    """The configurations of the request's families and ladder; with ``only``, those and the
    spec's recipe and its A/A row."""
    r = spec.render
    configs = study_configs(r.spp, spec.lighting.sun, req.ladder, req.configs, r.max_depth)
    if req.only:
        always = (paper_name(r.spp), aa_name(r.spp))
        configs = [c for c in configs if c.name in req.only or c.name in always]
    return configs


class Ticker:
    """Counts the study's steps and tells ``progress`` of each (done, total, what, elapsed)."""

    def __init__(self, total: int, started: float, progress=None):
        self.total, self.started, self.progress, self.done = total, started, progress, 0

    def __call__(self, what: str) -> None:
        self.done += 1
        if self.progress is not None:
            elapsed = time.perf_counter() - self.started
            self.progress({"done": self.done, "total": self.total, "what": what, "elapsed_s": elapsed})


def ensure_references(req: StudyRequest, ctx: Context, selection, subjects: dict, tick) -> dict:
    """Every sample's reference, read from the study folder or rendered and written there
    first (the expensive part, kept by a killed study); with its sRGB picture."""
    references = {}
    for s in selection:
        path = os.path.join(req.out, "references", f"{s.sample_id}.npz")
        ref = load_reference(path)
        if ref is None:
            ref = render_reference(subjects[s.sample_id], ctx, req.reference_spp)
            save_reference(path, ref)
        ref["srgb8"] = hdr_to_srgb8(ref["image"])
        references[s.sample_id] = ref
        tick(f"reference {s.sample_id}")
    return references


def measure_rows(req: StudyRequest, ctx: Context, selection, configs, subjects: dict, references: dict, tick):
    """Every row (sample x configuration x repeat): kept where the sample's rows file holds
    it, else measured and the file written at once. Returns (rows, counts)."""
    rows, counts = [], {"rendered": 0, "reused": 0}
    for s in selection:
        path = os.path.join(req.out, "rows", f"{s.sample_id}.json")
        try:
            with open(path, encoding="utf-8") as fh:
                mine = json.load(fh)
        except (OSError, ValueError):
            mine = {}
        cache: dict = {}
        for config in configs:
            for repeat in range(req.repeats):
                name = row_key(config.name, repeat)
                if name in mine:
                    counts["reused"] += 1
                else:
                    mine[name] = measure_config(
                        subjects[s.sample_id], ctx, config, references[s.sample_id], cache, req.flip, repeat
                    )
                    write_text_atomic(path, json.dumps(mine, indent=0, allow_nan=False) + "\n")
                    counts["rendered"] += 1
                rows.append(mine[name])
                tick(f"{s.sample_id} {config.name} #{repeat}")
    return rows, counts


def study_meta(
    req: StudyRequest, ctx: Context, record: dict, selection, configs, references: dict, command: str
) -> dict:
    """What study.json's ``meta`` holds: the request, the recipe, the samples, the
    configurations, the references' floors and the machine."""
    spec, r = ctx.spec, ctx.spec.render
    return {
        "request": record,
        "spec": os.path.abspath(req.spec),
        "variant": ctx.variant,
        "resolution": record["resolution"],
        "recipe": {"spp": r.spp, "max_depth": r.max_depth, "sun": spec.lighting.sun, "sampler": "independent"},
        "selection": [s.to_dict() for s in selection],
        "configs": [c.to_dict() for c in configs],
        "references": {
            sid: {**ref["floor"], "cpu_s": ref["cpu_s"], "wall_s": ref["wall_s"]} for sid, ref in references.items()
        },
        "cpu_count": os.cpu_count(),
        "relmse_eps": m.RELMSE_EPS,
        "floor_factor": m.FLOOR_FACTOR,
        "firefly_share": m.FIREFLY_SHARE,
        "repeats": req.repeats,
        "renders_per_worker": ctx.renders_per_worker,
        "lights_per_material": ctx.lights_per_material,
        "command": command,
        "machine": machine_line(ctx.variant),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    }
