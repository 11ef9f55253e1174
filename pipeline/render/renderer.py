"""One sample's Mitsuba scene and its render.

The scene holds only the effects the material calls for (:class:`EffectPlan`):
constants instead of textures for a uniform material, no normal map when it is
flat, no diffuse lobe when ``d (1 - s)`` is zero everywhere. The specular lobe is
never dropped: the model's Schlick term is not zero for a zero specular albedo
(docs/materials.md), so leaving it out would change the image.

Renders use Mitsuba's ``moment`` integrator around the path tracer, which gives a
per-pixel variance in the same pass: the noise estimate recorded with each render.

Beyond the paper's recipe (independent sampler, fixed spp) a render may use another
Mitsuba sampler, another Russian-roulette depth, a luminance clamp on each camera path's
contribution (:mod:`pipeline.render.clamp`, biased) and adaptive rendering
(``target_error``: power-of-two passes until the moment integrator's estimate of the
relative error on the ball meets the target or ``spp`` is reached). Every default leaves
the scene dict and the render exactly as they were before these options existed.
"""

from __future__ import annotations

import math
import signal
import time
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np

from materials.brdf_ref import DEFAULT_MODEL
from pipeline.errors import caused_by_interrupt
from pipeline.image.metrics import RELMSE_EPS  # the adaptive statistic estimates relMSE with it
from pipeline.image.stats import is_bad, render_stats
from pipeline.render import bsdf as mitsuba_bsdf
from pipeline.render.bsdf import needed_lobes
from pipeline.render.clamp import register_clamp, wrap_in_clamp
from pipeline.render.lights import light_entries, movable, move_light
from pipeline.render.limits import DEFAULT_RR_DEPTH, launch_spp
from pipeline.render.mitsuba_env import BYTE_IDENTICAL, determinism, load_mitsuba
from pipeline.render.scene import BALL_SHAPE_ID, sensor_dict, shape_dicts
from pipeline.render.settings import RenderSettings

#: A render with NaN, Inf or negative pixels is re-rendered with a new, recorded seed
#: up to this many times in all; if every attempt is bad it is kept and flagged.
MAX_RENDER_ATTEMPTS = 3
_SEED_STEP = 0x9E3779B9  # golden-ratio step: retry seeds far from the original
#: Adaptive rendering's first pass (or ``spp`` when smaller): enough samples for a
#: variance estimate, then the total doubles pass by pass (docs/accuracy.md).
ADAPTIVE_FIRST_SPP = 16


@dataclass(frozen=True)
class EffectPlan:
    """What a sample's scene simulates; recorded per sample."""

    textured: bool  # bitmap textures (spatially varying) vs constant parameters
    normal_map: bool  # Mitsuba `normalmap` wrapper vs the geometric shading frame
    diffuse_lobe: bool  # d (1 - s) / pi is non-zero somewhere
    specular_lobe: bool  # always True for this model (Schlick F > 0 for s = 0)

    def to_dict(self) -> dict:
        return asdict(self)

    def key(self) -> tuple:
        return tuple(asdict(self).values())


def plan_effects(maps) -> EffectPlan:
    """The effects ``maps`` (a materials.MaterialMaps) needs, and nothing more."""

    lobes = needed_lobes(maps)
    return EffectPlan(
        textured=maps.uniform_values() is None,
        normal_map=not bool(np.all(maps.normal[..., 2] == 1.0)),
        diffuse_lobe=lobes["diffuse_lobe"],
        specular_lobe=lobes["specular_lobe"],
    )


def material_bsdf(maps, effects: EffectPlan, variant: str, model: str = DEFAULT_MODEL) -> dict:
    """The Mitsuba dict of the material in ``model``, honouring ``effects``."""
    mitsuba_bsdf.register(variant)
    bsdf = mitsuba_bsdf.bsdf_dict(
        maps,
        lobes={"diffuse_lobe": effects.diffuse_lobe, "specular_lobe": effects.specular_lobe},
        model=model,
        variant=variant,
    )
    if effects.normal_map != (bsdf["type"] == "normalmap"):
        raise AssertionError("effect plan and BSDF disagree about the normal map")
    return bsdf


def scene_dict(
    ball, camera, maps, light, settings: RenderSettings, effects: EffectPlan | None = None, *, seed: int = 0
) -> tuple[dict, dict, EffectPlan]:
    """The whole Mitsuba scene dict for one sample; also the lighting record and effects."""
    effects = effects or plan_effects(maps)
    emitters, lighting_record = light_entries(light, settings)
    nested = {"type": settings.integrator, "max_depth": int(settings.max_depth)}
    if settings.rr_depth != DEFAULT_RR_DEPTH:  # only then: default scenes stay as they were
        nested["rr_depth"] = int(settings.rr_depth)
    if settings.clamp > 0:
        register_clamp(settings.variant)
        nested = wrap_in_clamp(nested, settings.clamp)
    scene = {
        "type": "scene",
        "integrator": {"type": "moment", "nested": nested},
        "sensor": sensor_dict(
            camera, settings.resolution, settings.spp, sampler=settings.sampler, seed=seed, variant=settings.variant
        ),
        **shape_dicts(ball, material_bsdf(maps, effects, settings.variant, settings.model)),
        **emitters,
    }
    return scene, lighting_record, effects


@dataclass(frozen=True)
class RenderResult:
    image: np.ndarray  # (H, W, 3) float32, linear Rec.709
    variance: np.ndarray  # (H, W) float32, variance of each pixel's luminance estimate
    stats: dict  # pipeline.image.stats.render_stats + time, spp, seed, attempts, flagged
    lighting: dict  # the lighting policy's record
    effects: EffectPlan


def derived_seed(seed: int, attempt: int) -> int:
    return (int(seed) + attempt * _SEED_STEP) % (1 << 32)


def power_of_two_passes(spp: int) -> list[int]:
    """``spp`` as a sum of distinct powers of two, largest first: 150 -> [128, 16, 4, 2]."""
    return [1 << b for b in range(int(spp).bit_length() - 1, -1, -1) if spp >> b & 1]


def pass_seed(seed: int, k: int) -> int:
    """The seed of pass ``k`` of a render seeded ``seed`` (32 bits; keyed by both)."""
    return int(np.random.SeedSequence([int(seed), k]).generate_state(1, np.uint32)[0])


def pass_plan(spp: int, variant: str) -> list[int]:
    """The passes a render of ``spp`` is split into on ``variant``: power-of-two passes where
    re-renders are byte-identical (llvm: the passes are what makes them so), one pass where
    they are not anyway (cuda, mitsuba3#1938: there the passes would only add launches)."""
    return power_of_two_passes(spp) if determinism(variant) == BYTE_IDENTICAL else [int(spp)]


def render_in_passes(mi, scene, spp: int, seed: int, passes: list[int] | None = None, on_pass=None) -> np.ndarray:
    """Every channel of ``spp`` samples per pixel, rendered as power-of-two passes, averaged.

    Why: in the llvm variant a render whose spp is not a power of two is not
    bit-reproducible with several render threads. A pixel's samples can straddle two of
    drjit's work blocks, whose threads add into the pixel in either order (measured: 237
    of 160,000 pixels differ by ~1 ulp between two 400x400, 150 spp renders). With
    power-of-two passes a pixel's samples never straddle; the passes are averaged in
    float64, weighted by their spp: exact for every channel of the moment integrator,
    whose channels are per-pixel means too. Cost: one kernel per distinct pass size
    (cached) and a little render time at 150 spp (`shaderball bench` measures it). ``passes`` (:func:`pass_plan`) may
    say otherwise; a single pass is seeded like the first of several. ``on_pass(n)``: called
    after each pass with its spp (a command's progress).
    """
    passes = power_of_two_passes(spp) if passes is None else passes
    if len(passes) == 1:  # no float64 sum to make: the pass itself (same values, half the copies)
        image = np.asarray(render_whole(mi, scene, spp=passes[0], seed=pass_seed(seed, 0)), dtype=np.float64)
        if on_pass is not None:
            on_pass(passes[0])
        return image
    total = None
    for k, n in enumerate(passes):
        image = np.asarray(render_whole(mi, scene, spp=n, seed=pass_seed(seed, k)), dtype=np.float64) * n
        total = image if total is None else total + image
        if on_pass is not None:
            on_pass(n)
    return total / spp


def film_pixels(scene) -> int:
    """The pixels one sample per pixel of ``scene``'s render takes (its film, border included)."""
    film = scene.sensors()[0].film()
    size = film.crop_size()
    if film.sample_border():
        size += 2 * film.rfilter().border_size()
    return int(size[0]) * int(size[1])


def launches(mi, scene, spp: int, sampler: str = "independent") -> list[int]:
    """The spp of each ``mi.render`` call of a render of ``spp`` (:func:`pipeline.render.limits.launch_spp`)."""
    return launch_spp(spp, film_pixels(scene), lambda n: sampler_spp(mi, sampler, n))


def render_whole(mi, scene, spp: int, seed: int, sampler: str = "independent"):
    """``spp`` samples per pixel of ``scene``: one ``mi.render`` call (:func:`render_launch`), or,
    over :data:`pipeline.render.limits.LAUNCH_SAMPLES_MAX` samples, several (:func:`launches`;
    launch ``j`` seeded ``pass_seed(seed, j)``) averaged in float64, weighted by the spp each used."""
    sizes = launches(mi, scene, spp, sampler)
    if len(sizes) == 1:  # every render under the limit: the call it always was
        return render_launch(mi, scene, spp, seed)
    acc = PassSum()
    for j, n in enumerate(sizes):
        used = sampler_spp(mi, sampler, n)
        with _quiet(mi, used != n):
            acc.add(render_launch(mi, scene, n, pass_seed(seed, j)), used)
    return acc.mean()


def render_launch(mi, scene, spp: int, seed: int):
    """``mi.render``, never cut short. Mitsuba installs a SIGINT handler for the length of a
    render that cancels it and returns what it has so far (fewer samples, no error). Here a
    cancelled render is never used: where this process ignores SIGINT (a dask worker: the
    build's driver handles Ctrl-C, pipeline.run.build.sigint_at_safe_points) it is rendered
    again, to the same bytes (same seed); elsewhere KeyboardInterrupt is raised."""
    while True:
        try:
            image = mi.render(scene, spp=spp, seed=seed)
        except RuntimeError as exc:  # Ctrl-C inside a Python plugin's callback, wrapped by drjit
            if caused_by_interrupt(exc):
                raise KeyboardInterrupt("a render was interrupted by SIGINT; it is not stored") from None
            raise
        if not scene.integrator().should_stop():
            return image
        if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
            raise KeyboardInterrupt("a render was cancelled by SIGINT; it is not stored")


def sampler_spp(mi, sampler: str, spp: int) -> int:
    """The samples per pixel Mitsuba's ``sampler`` really takes when asked for ``spp``."""
    if sampler == "independent":
        return int(spp)
    with _quiet(mi):  # its rounding warning: the spp used is recorded instead
        return int(mi.load_dict({"type": sampler, "sample_count": int(spp)}).sample_count())


class _quiet:
    """Mitsuba's log at Error level while inside (a sampler's rounding warning is recorded, not printed)."""

    def __init__(self, mi, on: bool = True):
        self.logger, self.on = mi.logger(), on
        self.error = mi.LogLevel.Error

    def __enter__(self):
        self.level = self.logger.log_level()
        if self.on:
            self.logger.set_log_level(self.error)

    def __exit__(self, *exc):
        self.logger.set_log_level(self.level)


class PassSum:
    """Running spp-weighted sum of render passes (float64), and the spp it holds."""

    def __init__(self):
        self.total, self.spp = None, 0

    def add(self, image: np.ndarray, spp: int) -> None:
        weighted = np.asarray(image, dtype=np.float64) * spp
        self.total = weighted if self.total is None else self.total + weighted
        self.spp += spp

    def mean(self) -> np.ndarray:
        return self.total / self.spp


def render_pass(mi, scene, spp: int, seed: int, k: int, sampler: str = "independent") -> tuple[np.ndarray, int]:
    """Pass ``k`` of a render seeded ``seed``: every channel (float64) and the spp it used."""
    used = sum(sampler_spp(mi, sampler, n) for n in launches(mi, scene, spp, sampler))
    with _quiet(mi, used != spp):
        image = render_whole(mi, scene, spp=spp, seed=pass_seed(seed, k), sampler=sampler)
    return np.asarray(image, dtype=np.float64), used


def luminance_variance(out: np.ndarray, spp: int) -> np.ndarray:
    """Variance of each pixel's luminance estimate: (m2 - m1^2) / spp of the Y channels."""
    m1, m2 = out[..., 4], out[..., 7]
    return np.clip(m2 - m1 * m1, 0.0, None) / spp


def relative_error(
    out: np.ndarray, spp: int, mask: np.ndarray | None = None, variance: np.ndarray | None = None
) -> float:
    """The adaptive renderer's statistic: the square root of the moment integrator's estimate
    of the image's relMSE against its converged limit, on the luminance over ``mask`` (the
    ball; the whole frame when None): sqrt(mean(var_Y / (Y^2 + eps))), eps = RELMSE_EPS.

    It estimates the quantity the accuracy study ranks recipes by (relMSE, eps 0.01), per
    pixel, so dark and bright parts of the ball count alike. The relative standard error
    of the ball's *mean* luminance would be about sqrt(pixels) times smaller than the noise
    of any pixel and says little about the noise a viewer (or a network) sees.

    ``variance``: ``luminance_variance(out, spp)`` where the caller has it already (the same
    values: not computed twice).
    """
    sel = np.ones(out.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    if not sel.any():
        sel = np.ones(out.shape[:2], bool)
    y = out[..., 4][sel]
    variance = luminance_variance(out, spp) if variance is None else variance
    terms = variance[sel] / (y * y + RELMSE_EPS)
    value = float(np.sqrt(terms.mean()))
    return value if math.isfinite(value) else math.inf


def adaptive_stages(cap: int, first: int = ADAPTIVE_FIRST_SPP) -> list[list[int]]:
    """Pass sizes of an adaptive render, stage by stage; the error is checked after each stage.

    The first stage is ``first`` spp (or the largest power of two <= ``cap``); every later
    stage doubles the total, the last one stops at ``cap`` exactly (its step split into
    power-of-two passes): cap 150 -> [[16], [16], [32], [64], [16, 4, 2]] (totals 16, 32, 64,
    128, 150).
    """
    start = min(first, 1 << (int(cap).bit_length() - 1))
    stages, total = [[start]], start
    while total < cap:
        step = min(total, cap - total)
        stages.append(power_of_two_passes(step))
        total += step
    return stages


class RenderOutput(NamedTuple):
    image: np.ndarray  # (H, W, 3) float32
    variance: np.ndarray  # (H, W) float32: variance of each pixel's luminance estimate
    spp_used: int  # samples per pixel rendered (after a sampler's rounding; adaptive: where it stopped)
    error_estimate: float  # relative_error of the result (over ``mask``)


def render_stages(spp: int, sampler: str, target_error: float, single_pass: bool) -> list[list[int]]:
    """The passes :func:`render_scene` renders, stage by stage (the spp of each; an adaptive
    render may stop after any stage)."""
    if target_error <= 0 and sampler == "independent":
        return [[int(spp)] if single_pass else power_of_two_passes(spp)]
    stages = adaptive_stages(spp) if target_error > 0 else [power_of_two_passes(spp)]
    return [[sum(stage)] for stage in stages] if single_pass else stages


def sample_stages(settings: RenderSettings) -> list[list[int]]:
    """The passes :func:`render_sample` renders with ``settings`` (its variant resolved), stage
    by stage: :func:`render_stages` on this variant."""
    single_pass = determinism(settings.variant) != BYTE_IDENTICAL
    return render_stages(settings.spp, settings.sampler, settings.target_error, single_pass)


def render_scene(
    mi,
    scene,
    spp: int,
    seed: int,
    *,
    sampler: str = "independent",
    target_error: float = 0.0,
    mask: np.ndarray | None = None,
    single_pass: bool = False,
    on_pass=None,
) -> RenderOutput:
    """Render a loaded scene (moment integrator): image, luminance variance, spp used, error.

    The moment integrator's extra channels are the first and second moments of the nested
    integrator in CIE XYZ; the variance returned is that of the luminance Y (channels 4
    and 7), divided by spp: the variance of the pixel's estimate.

    ``target_error > 0`` renders adaptively (:func:`adaptive_stages`, ``spp`` the cap):
    after each stage the estimate :func:`relative_error` is computed from all passes so
    far and the render stops once it is at most ``target_error``. Every decision is a
    function of the passes rendered, which are deterministic, so the result is too.

    ``single_pass`` (a variant whose re-renders are not byte-identical anyway, :func:`pass_plan`):
    each stage is one pass instead of power-of-two passes (:func:`render_stages` says which).
    ``on_pass(n)``: called after each pass with its spp.
    """
    stages = render_stages(spp, sampler, target_error, single_pass)
    if target_error <= 0 and sampler == "independent":
        out, used = render_in_passes(mi, scene, spp, seed, stages[0], on_pass), int(spp)
    else:
        acc, k = PassSum(), 0
        for stage in stages:
            for n in stage:
                image, n_used = render_pass(mi, scene, n, seed, k, sampler)
                acc.add(image, n_used)
                k += 1
                if on_pass is not None:
                    on_pass(n)
            if target_error > 0 and relative_error(acc.mean(), acc.spp, mask) <= target_error:
                break
        out, used = acc.mean(), acc.spp
    image = np.ascontiguousarray(out[..., 0:3], dtype=np.float32)
    variance = luminance_variance(out, used)
    return RenderOutput(image, variance.astype(np.float32), used, relative_error(out, used, mask, variance))


class MaterialScene:
    """A loaded scene moved from material to material and from lighting to lighting.

    The first :meth:`lit` loads the whole scene; most of a load (~70 ms at 400 px on 2
    cores) is the shaderball's mesh and its acceleration structure, which no material
    changes. The next ones move what changed, in place: a new material's BSDF is loaded
    alone (its dict, ~1 ms) and set on the ball's shape (``Shape.set_bsdf``), and the
    emitters are moved to the light (:func:`pipeline.render.emitter.update_emitter_params`).
    No scene dict, no ``load_dict`` of the scene (nor the memory growth of repeated loads,
    mitsuba3#1890), and the same bytes as a scene loaded afresh for that material and light
    (tests/test_scene_reuse.py). A scene is loaded afresh only where the ball, the camera or
    the render settings differ from the held scene's.

    Kernels: a swapped BSDF takes another instance id than a fresh load gives it, so the
    held scene's kernels are not all those of fresh scenes; they are a handful per process
    (one per effect plan and id layout, measured), never one per material.

    Keep one alive at a time and release it (``with``, or :meth:`release`) before another
    scene is loaded: two scenes alive at once change the kernels' hashes (drjit traces
    virtual calls over every registered instance) and recompile them.
    """

    def __init__(self):
        self.maps = self.scene = self.params = self.effects = None
        self._ball = self._camera = self._settings = self._shape = self._light = None

    def step(self, ball, camera, maps, settings: RenderSettings, light=None) -> str:
        """What :meth:`lit` does for these: ``"load"``, ``"material"`` (swap the BSDF, move
        the emitters) or ``"light"`` (move the emitters). A scene lit by an environment map
        moves to another rotation or scale of the same map; another map is loaded afresh
        (:func:`pipeline.render.lights.movable`)."""
        same_scene = (
            self.scene is not None
            and ball is self._ball
            and camera is self._camera
            and settings == self._settings
            and movable(self._light, light)
        )
        if not same_scene:
            return "load"
        return "light" if maps is self.maps else "material"

    def lit(self, mi, ball, camera, maps, light, settings: RenderSettings):
        """The scene of ``maps`` lit by ``light``; its lighting record and effects."""
        step = self.step(ball, camera, maps, settings, light)
        if step == "load":
            self.release()
            desc, lighting, effects = scene_dict(ball, camera, maps, light, settings)
            with _quiet(mi, settings.sampler != "independent"):  # a sampler's rounding: recorded, not printed
                self.scene = mi.load_dict(desc)
            del desc
            self._shape = next(s for s in self.scene.shapes() if s.id() == BALL_SHAPE_ID)
            self._ball, self._camera, self._settings, self._light = ball, camera, settings, light
            self.maps, self.effects = maps, effects
            return self.scene, lighting, effects
        if step == "material":
            self.params = None  # its references would keep the old BSDF (and its instance id) alive
            effects = plan_effects(maps)
            bsdf = mi.load_dict(material_bsdf(maps, effects, settings.variant, settings.model))
            self._shape.set_bsdf(bsdf)
            del bsdf
            self.maps, self.effects = maps, effects
        if self.params is None:
            self.params = mi.traverse(self.scene)
        lighting = move_light(self.params, light, settings)
        self._light = light
        return self.scene, lighting, self.effects

    def release(self) -> None:
        self.maps = self.scene = self.params = self.effects = None
        self._ball = self._camera = self._settings = self._shape = self._light = None

    def __enter__(self) -> MaterialScene:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def render_sample(
    ball,
    camera,
    maps,
    light,
    settings: RenderSettings,
    seed: int,
    mask: np.ndarray | None = None,
    scene: MaterialScene | None = None,
    on_pass=None,
) -> RenderResult:
    """Render one material under one light, re-rendering bad (NaN/Inf/negative) results.

    ``scene``: a :class:`MaterialScene` kept across renders (a build keeps one for all its
    materials and lightings); None loads a scene for this render only. ``on_pass(n)``: called
    after each pass of each attempt with its spp (:func:`render_scene`).
    """
    mi = load_mitsuba(settings.variant)
    start = time.perf_counter()
    loaded, lighting, effects = (scene or MaterialScene()).lit(mi, ball, camera, maps, light, settings)
    single_pass = determinism(settings.variant) != BYTE_IDENTICAL
    attempts = []
    for attempt in range(MAX_RENDER_ATTEMPTS):
        attempt_seed = derived_seed(seed, attempt)
        image, variance, spp_used, error_estimate = render_scene(
            mi,
            loaded,
            settings.spp,
            attempt_seed,
            sampler=settings.sampler,
            target_error=settings.target_error,
            mask=mask,
            single_pass=single_pass,
            on_pass=on_pass,
        )
        stats = render_stats(image, variance, mask)
        attempts.append({"seed": attempt_seed, "nan": stats["nan"], "inf": stats["inf"], "negative": stats["negative"]})
        if not is_bad(stats):
            break
    stats.update(
        time_s=time.perf_counter() - start,
        spp=settings.spp,
        seed=attempts[-1]["seed"],
        attempts=len(attempts),
        rejected_attempts=attempts[:-1],
        flagged=is_bad(stats),
    )
    if settings.adaptive or spp_used != settings.spp:  # only then: default headers stay as they were
        stats.update(spp_used=spp_used, error_estimate=error_estimate)
        if settings.adaptive:
            stats["target_error"] = settings.target_error
    return RenderResult(image=image, variance=variance, stats=stats, lighting=lighting, effects=effects)
