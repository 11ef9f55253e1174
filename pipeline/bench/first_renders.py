"""The spec's first renders, built and timed at the spec's settings (and at a few smaller
ones, to extrapolate what a render at the paper's size costs), and the disk they take:
what :mod:`pipeline.bench.estimate` turns into a plan's time per worker.

Where the spec names objects or environment maps, every one of them is rendered at least
once (:func:`covering_materials`: one lighting of the first material showing it), and each
render's own time (its record's ``stats.time_s``) gives an object's, or a map's, cost relative
to the others': :func:`scene_costs` turns those into seconds per render of each, and weighs the
spec's figure by the materials each object has and the maps' equal shares.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import statistics
import tempfile
import time
from dataclasses import dataclass

from pipeline.bench.bare_renders import warm_kernels
from pipeline.dataset.plan import SCENE_TUPLES, Plan, ShardPlan
from pipeline.render.mitsuba_env import load_mitsuba, resolve_variant
from pipeline.run.shard import make_shard_dir, run_shard
from pipeline.store.exr import MATERIAL_MAP_LAYERS, pixel_bytes
from pipeline.store.layout import MARKER_FILE, Layout
from pipeline.store.records import read_json

#: Lightings timed per material at most (a material may have 1000).
TIMED_LIGHTS = 5
#: Lightings rendered of a material added only so that an object or an environment map the
#: first materials lack is timed (:func:`covering_materials`): one keeps `plan` cheap.
COVER_LIGHTS = 1
#: A spec whose render is at most this work (pixels x spp: the paper's 400x400 px at 150
#: spp, about 5 s on 2 cores), at most this resolution and texture resolution, is timed at
#: its own settings; any other at small settings, and extrapolated (:func:`timing_plan`).
DIRECT_SAMPLES = 400 * 400 * 150
DIRECT_RESOLUTION = 512
DIRECT_TEXELS = 1024
#: The two values each setting too large to time is timed at (resolution in px, spp,
#: texture resolution in texels).
TIMING_RESOLUTIONS = (64, 128)
TIMING_SPP = (16, 64)
TIMING_TEXELS = (512, 1024)


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
    #: (extrapolated: also "timed", each setting's figures, and "fit", the fitted terms)
    by_kind: dict = dataclasses.field(default_factory=dict)
    #: None: timed at the spec's settings; else how the figures were extrapolated to them
    #: (:meth:`TimingPlan.describe`: the settings timed, the model, the spec's settings)
    extrapolation: dict | None = None
    #: Where the spec names objects (environment maps): base name -> renders timed, render_s (the
    #: mean render call, at the timed settings) and seconds_per_render (:func:`scene_costs`);
    #: empty where it names neither, and then left out of to_dict()
    by_object: dict = dataclasses.field(default_factory=dict)
    by_environment: dict = dataclasses.field(default_factory=dict)
    #: The factor the timed renders' mix was weighed by to the spec's shares of objects and maps
    #: (1.0 where it names neither)
    scene_weight: float = 1.0


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


def first_materials(plans: Plan, renders: int, kinds: tuple[str, ...], max_lights: int | None = None) -> list:
    """The spec's first materials, in plan order, holding at least ``renders`` renders (all
    of them when the spec has fewer), and the first material of each of ``kinds`` that they
    lack (the kinds the spec has: an svbrdf material also makes texture maps); each with at
    most ``max_lights`` of its lightings (its first), when given."""
    chosen, count = [], 0
    for shard in plans:
        for material in shard.materials:
            if count < renders or (material.kind in kinds and material.kind not in {m.kind for m in chosen}):
                material = _first_lightings(material, max_lights)
                chosen.append(material)
                count += material.n_lights
            if count >= renders and {m.kind for m in chosen} >= set(kinds):
                return chosen
    return chosen


def _first_lightings(material, max_lights: int | None):
    """``material`` with only its first ``max_lights`` lightings (all when None or fewer)."""
    if max_lights is None or material.n_lights <= max_lights:
        return material
    return _lightings(material, range(max_lights))


def _lightings(material, indices):
    """``material`` with only its lightings ``indices``, in that order (its environment maps,
    rotations and intensities with them, where it has them)."""
    keys = (
        "render_seeds",
        "elevation_deg",
        "azimuth_deg",
        "turbidity",
        *(k for k in SCENE_TUPLES if getattr(material, k)),
    )
    return dataclasses.replace(material, **{key: tuple(getattr(material, key)[i] for i in indices) for key in keys})


def covering_materials(plans: Plan, chosen: list, objects, environments) -> list:
    """Materials to time beside ``chosen`` so that each of ``objects`` and ``environments`` (as
    the plan names them: built-in names or paths) is rendered at least once: for each one the
    chosen (with the lightings they keep) lack, the first material in plan order showing it,
    or one of whose lightings draws it, with :data:`COVER_LIGHTS` lighting (that one). An
    object or a map no material of the plan draws is not timed (the dataset holds none)."""
    want_objects = [o for o in objects if o not in {m.object for m in chosen}]
    want_maps = [e for e in environments if e not in {e for m in chosen for e in m.environment}]
    extra = []
    for shard in plans:
        if not want_objects and not want_maps:
            break
        for material in shard.materials:
            picks = []
            if material.object in want_objects:
                want_objects.remove(material.object)
                picks.append(next((l for l, e in enumerate(material.environment) if e in want_maps), 0))
            for l, e in enumerate(material.environment):
                if e not in want_maps or (l not in picks and len(picks) >= COVER_LIGHTS):
                    continue
                want_maps.remove(e)
                if l not in picks:
                    picks.append(l)
            if picks:
                extra.append(_lightings(material, sorted(picks)))
    return extra


@dataclass(frozen=True)
class TimingPlan:
    """The settings the timed renders use: the spec's own (``extrapolated`` False), or, for
    each of resolution, spp and texture resolution too large to time, two small values
    (:data:`TIMING_RESOLUTIONS`, :data:`TIMING_SPP`, :data:`TIMING_TEXELS`), from which a
    render's time is extrapolated to the spec's (:func:`extrapolate`)."""

    resolutions: tuple[int, ...]
    spp: tuple[int, ...]
    texels: tuple[int, ...]
    spec: tuple[int, int, int]  # the spec's resolution, spp, texture resolution
    extrapolated: bool

    def points(self, kind: str) -> list[tuple[int, int, int]]:
        """(resolution, spp, texels) timed for ``kind``: the base (the largest resolution and
        texture resolution, the smallest spp), then one setting per value varied from it (the
        texture resolution only for svbrdf materials: a uniform one's textures are 1x1)."""
        base = (self.resolutions[-1], self.spp[0], self.texels[-1])
        out = [base]
        if len(self.resolutions) == 2:
            out.append((self.resolutions[0], self.spp[0], self.texels[-1]))
        if len(self.spp) == 2:
            out.append((self.resolutions[-1], self.spp[-1], self.texels[-1]))
        if len(self.texels) == 2 and kind == "svbrdf":
            out.append((self.resolutions[-1], self.spp[0], self.texels[0]))
        return out

    def terms(self) -> str:
        terms = (("b x pixels", self.resolutions), ("c x pixels x spp", self.spp))
        model = " + ".join(["a", *(term for term, values in terms if len(values) == 2)])
        return model + (" (+ d x texels for svbrdf materials)" if len(self.texels) == 2 else "")

    def describe(self) -> dict:
        """How the figures were extrapolated (Timing.extrapolation)."""
        res, spp, texels = self.spec
        too = [
            text
            for text, varied in (
                (f"{res}x{res} px", len(self.resolutions) == 2),
                (f"{spp} spp", len(self.spp) == 2),
                (f"{texels}x{texels} texture maps", len(self.texels) == 2),
            )
            if varied
        ]
        timed = "; ".join(f"{r} px, {s} spp, {t} texels" for r, s, t in self.points("svbrdf"))
        return {
            "timed_at": [list(p) for p in self.points("svbrdf")],
            "spec": list(self.spec),
            "model": self.terms(),
            "text": f"the spec's {', '.join(too)} would take too long to time: renders timed at {timed}; "
            f"a render's time fitted as {self.terms()} and extrapolated to {res}x{res} px, {spp} spp, "
            f"{texels} texels",
        }


def timing_plan(spec) -> TimingPlan:
    """Where the spec's renders are timed (:class:`TimingPlan`): at its own settings when a
    render is at most :data:`DIRECT_SAMPLES` pixels x spp at most :data:`DIRECT_RESOLUTION`
    px, with textures at most :data:`DIRECT_TEXELS`; else at small ones."""
    res, spp, texels = spec.render.resolution, spec.render.spp, spec.materials.texture_resolution
    own = (res, spp, texels)
    if res * res * spp <= DIRECT_SAMPLES and res <= DIRECT_RESOLUTION and texels <= DIRECT_TEXELS:
        return TimingPlan((res,), (spp,), (texels,), own, False)
    return TimingPlan(
        TIMING_RESOLUTIONS if res > TIMING_RESOLUTIONS[-1] else (res,),
        TIMING_SPP if spp > TIMING_SPP[-1] else (spp,),
        TIMING_TEXELS if texels > TIMING_TEXELS[-1] else (texels,),
        own,
        True,
    )


def _spec_at(spec, point: tuple[int, int, int]):
    """``spec`` rendered at ``point`` (resolution, spp, texture resolution)."""
    res, spp, texels = point
    return dataclasses.replace(
        spec,
        render=dataclasses.replace(spec.render, resolution=res, spp=spp),
        materials=dataclasses.replace(spec.materials, texture_resolution=texels),
    )


def extrapolate(plan: TimingPlan, timed: dict, key: str) -> tuple[float, dict]:
    """``key`` (seconds per render, or CPU seconds) at the spec's settings, from the figures
    ``timed`` at ``plan.points(kind)`` (point -> figures), and the fitted terms: each slope
    from the base and the one setting that varies it (a negative slope, timing noise, is
    taken as 0; for spp, as if the whole render were its samples)."""
    points = list(timed)
    base = points[0]
    value = timed[base][key]
    pixels, spp, texels = base[0] ** 2, base[1], base[2] ** 2
    fit = {"a_s": value, "b_s_per_pixel": 0.0, "c_s_per_pixel_spp": 0.0, "d_s_per_texel": 0.0}
    for point in points[1:]:
        if point[1] != base[1]:
            slope = (timed[point][key] - value) / (pixels * (point[1] - spp))
            fit["c_s_per_pixel_spp"] = slope if slope > 0 else timed[point][key] / (pixels * point[1])
    for point in points[1:]:
        if point[0] != base[0]:
            slope = (value - timed[point][key]) / (pixels - point[0] ** 2) - fit["c_s_per_pixel_spp"] * spp
            fit["b_s_per_pixel"] = max(0.0, slope)
        elif point[2] != base[2]:
            fit["d_s_per_texel"] = max(0.0, (value - timed[point][key]) / (texels - point[2] ** 2))
    res, spec_spp, spec_texels = plan.spec
    # the settings not varied are the spec's own: their terms are 0
    to_pixels = res**2 if len(plan.resolutions) == 2 else pixels
    to_spp = spec_spp if len(plan.spp) == 2 else spp
    to_texels = spec_texels**2 if len(plan.texels) == 2 else texels
    fit["a_s"] = value - fit["b_s_per_pixel"] * pixels - fit["c_s_per_pixel_spp"] * pixels * spp
    fit["a_s"] -= fit["d_s_per_texel"] * texels
    result = (
        value
        + fit["b_s_per_pixel"] * (to_pixels - pixels)
        + fit["c_s_per_pixel_spp"] * (to_pixels * to_spp - pixels * spp)
        + fit["d_s_per_texel"] * (to_texels - texels)
    )
    return max(result, max(t[key] for t in timed.values())), fit


def _pixel_bytes_per_render(spec, kind: str, lights: int) -> float:
    """Pixel bytes a render of ``kind`` costs (its render, and its material's maps and
    textures spread over ``lights`` lightings): what scales bytes timed at one setting to another."""
    disk = disk_estimate(spec, 1, 0) if kind == "uniform" else disk_estimate(spec, 0, 1)
    return disk["bytes_per_render"] + (disk["maps_bytes"] + disk["texture_bytes"]) / lights


def _time_kind_at(spec, plan: TimingPlan, kind: str, materials: list, variant: str, render_times: list) -> dict:
    """A kind's materials timed at ``plan``'s settings (:func:`_time_kind`); extrapolated to
    the spec's when ``plan`` says so. ``render_times`` gets the renders timed at the first
    (base) setting, as :func:`_time_kind` gives them."""
    points = plan.points(kind)
    timed = {
        point: _time_kind(_spec_at(spec, point), materials, variant, render_times if point == points[0] else None)
        for point in points
    }
    if not plan.extrapolated:
        return next(iter(timed.values()))
    base = next(iter(timed))
    lights = timed[base]["renders"] / timed[base]["materials"]
    seconds, fit = extrapolate(plan, timed, "seconds_per_render")
    cpu, _fit = extrapolate(plan, timed, "cpu_seconds_per_render")
    scale = _pixel_bytes_per_render(spec, kind, lights) / _pixel_bytes_per_render(_spec_at(spec, base), kind, lights)
    return {
        **timed[base],
        "seconds": sum(t["seconds"] for t in timed.values()),
        "seconds_per_render": seconds,
        "cpu_seconds_per_render": cpu,
        "bytes_per_render": timed[base]["bytes_per_render"] * scale,
        "timed": [{"resolution": r, "spp": s, "texels": t, **timed[(r, s, t)]} for r, s, t in timed],
        "fit": fit,
    }


def _folder_bytes(root: str) -> tuple[int, int]:
    """(bytes of every file under ``root``, bytes of its sample records: the manifest repeats them)."""
    total = records = 0
    for folder, _dirs, files in os.walk(root):
        for name in files:
            size = os.path.getsize(os.path.join(folder, name))
            total += size
            records += size if name.endswith(".json") and name != MARKER_FILE else 0
    return total, records


def _time_kind(spec, materials: list, variant: str, render_times: list | None = None) -> dict:
    """Build ``materials`` (of one kind) into a temporary folder with the build's shard code; time it.
    ``render_times``, when given, gets (object's base name, map's base name or None, the render
    call's seconds from the record) of every render."""
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
        if render_times is not None:
            render_times += _render_times(layout, shard)
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


def _render_times(layout: Layout, shard: ShardPlan) -> list[tuple[str, str | None, float]]:
    """(object, map, seconds) of each render of ``shard`` built under ``layout``: the render
    call's own time, from its record (the materials' maps and the writes are not in it)."""
    out = []
    for sample in shard.samples:
        record = read_json(layout.path(layout.record_rel(sample.shard_id, sample.sample_id)))
        seconds = (record or {}).get("stats", {}).get("time_s")
        if isinstance(seconds, (int, float)) and seconds > 0:
            environment = os.path.basename(sample.environment) if sample.environment else None
            out.append((sample.object_name, environment, float(seconds)))
    return out


def scene_costs(
    render_times: list, base: int, object_shares: dict[str, float], map_shares: dict[str, float]
) -> tuple[dict, dict, float]:
    """Each object's and each map's cost, from ``render_times`` (:func:`_render_times`: the
    first ``base`` are the renders the spec's figure was timed on, the rest those added to cover
    an object or a map): (by object, by map, weight). An object's relative cost is the mean
    render call of its renders over the mean of all; ``relative``, that over the base renders'
    mix of objects (the caller multiplies the base renders' seconds per render by it);
    ``weight``: what the base renders' figure is multiplied by to weigh objects and maps by
    ``object_shares`` and ``map_shares`` (shares of the spec's renders) instead of the base
    renders' mix of them."""
    mean_all = statistics.fmean(t for _o, _e, t in render_times)
    groups = {}
    weight = 1.0
    for position, shares in ((0, object_shares), (1, map_shares)):
        if not shares:
            groups[position] = {}
            continue
        times: dict[str, list[float]] = {}
        for entry in render_times:
            times.setdefault(entry[position], []).append(entry[2])
        relative = {name: statistics.fmean(t) / mean_all for name, t in times.items()}
        base_counts: dict[str, int] = {}
        for entry in render_times[:base]:
            base_counts[entry[position]] = base_counts.get(entry[position], 0) + 1
        base_mix = (
            sum(n * relative[name] for name, n in base_counts.items()) / sum(base_counts.values())
            if base_counts
            else 1.0
        )
        timed = [name for name in shares if name in relative]  # in the spec's order
        spec_mix = sum(shares[name] * relative[name] for name in timed) / sum(shares[name] for name in timed)
        weight *= spec_mix / base_mix
        groups[position] = {
            name: {
                "renders": len(times[name]),
                "render_s": statistics.fmean(times[name]),
                "relative": relative[name] / base_mix,
            }
            for name in timed
        }
    return groups[0], groups[1], weight


def time_first_samples(spec, plans: Plan, samples: int, counts: dict[str, int], scene: dict | None = None) -> Timing:
    """Build the spec's first ``samples`` renders (whole materials, and the first material of
    each kind the spec has; at most :data:`TIMED_LIGHTS` lightings each) with the build's
    shard code, kernels compiled first, each kind timed on its own, at the settings of
    :func:`timing_plan` (extrapolated to the spec's where they are not its own); the figures
    per render are the kinds' weighted by ``counts`` (materials of each kind in the spec).

    ``scene``: the plan summary's ``objects`` (materials per object) and ``environments`` (map
    base names), where the spec names them: each is then timed (:func:`covering_materials`) and
    given its seconds per render, and the figures are weighed to the spec's shares of them
    (:func:`scene_costs`)."""
    variant = resolve_variant(spec.render.variant)
    load_mitsuba(variant)
    import drjit as dr

    threads = os.cpu_count() or 1
    if dr.thread_count() != threads:
        dr.set_thread_count(threads)
    plan = timing_plan(spec)
    scene = scene or {}
    chosen = first_materials(plans, samples, tuple(k for k, n in counts.items() if n), TIMED_LIGHTS)
    # only the objects and maps the spec names beside the default (the plan summary has them)
    extra = covering_materials(
        plans,
        chosen,
        spec.scene.objects if scene.get("objects") else (),
        plans.environments if scene.get("environments") else (),
    )
    shard = ShardPlan(shard_index=chosen[0].shard_index, shard_id=chosen[0].shard_id, materials=tuple(chosen + extra))
    for res in plan.resolutions:  # kernels depend on the resolution; the largest one's set-up is kept
        started = time.perf_counter()
        warm_kernels(_spec_at(spec, (res, plan.spp[0], plan.texels[-1])), [shard], variant)  # also geometry, G-buffer
        setup_s = time.perf_counter() - started
    render_times: list = []
    by_kind = {
        kind: _time_kind_at(spec, plan, kind, [m for m in chosen if m.kind == kind], variant, render_times)
        for kind in counts
        if any(m.kind == kind for m in chosen)
    }
    base = len(render_times)
    if extra:  # their renders' own times only: the spec's figure is the first materials'
        base_point = plan.points("svbrdf")[0]
        _time_kind(_spec_at(spec, base_point), extra, variant, render_times)
    weight = {kind: counts[kind] for kind in by_kind}  # every timed kind is one the spec has

    def mix(key: str) -> float:
        return sum(weight[k] * by_kind[k][key] for k in by_kind) / sum(weight.values())

    by_object, by_environment, scene_weight = {}, {}, 1.0
    if scene and render_times:
        materials = sum(scene.get("objects", {}).values())
        by_object, by_environment, scene_weight = scene_costs(
            render_times,
            base,
            {name: n / materials for name, n in scene.get("objects", {}).items()},
            {name: 1.0 / len(scene.get("environments", ())) for name in scene.get("environments", ())},
        )
        for group in (*by_object.values(), *by_environment.values()):
            group["seconds_per_render"] = mix("seconds_per_render") * group.pop("relative")

    return Timing(
        renders=sum(k["renders"] for k in by_kind.values()),
        materials=len(chosen),
        uniform=by_kind.get("uniform", {}).get("materials", 0),
        svbrdf=by_kind.get("svbrdf", {}).get("materials", 0),
        variant=variant,
        threads=threads,
        setup_s=setup_s,
        seconds=sum(k["seconds"] for k in by_kind.values()),
        seconds_per_render=mix("seconds_per_render") * scene_weight,
        cpu_seconds_per_render=mix("cpu_seconds_per_render") * scene_weight,
        load_average=os.getloadavg()[0],
        bytes_per_render=mix("bytes_per_render"),
        by_kind=by_kind,
        extrapolation=plan.describe() if plan.extrapolated else None,
        by_object=by_object,
        by_environment=by_environment,
        scene_weight=scene_weight,
    )
