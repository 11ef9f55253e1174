"""One sample's Mitsuba scene and its render.

The scene holds only the effects the material calls for (:class:`EffectPlan`):
constants instead of textures for a uniform material, no normal map when it is
flat, no diffuse lobe when ``d (1 - s)`` is zero everywhere. The specular lobe is
never dropped: the model's Schlick term is not zero for a zero specular albedo
(docs/materials.md), so leaving it out would change the image.

Renders use Mitsuba's ``moment`` integrator around the path tracer, which gives a
per-pixel variance in the same pass: the noise estimate recorded with each render.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from pipeline.errors import bad_value, check_int
from pipeline.render import bsdf as mitsuba_bsdf
from pipeline.render.bsdf import needed_lobes
from pipeline.render.emitter import emitter_dicts
from pipeline.render.limits import INTEGRATORS, MAX_DEPTH_RANGE, RESOLUTION_RANGE, SPP_RANGE
from pipeline.render.mitsuba_env import load_mitsuba
from pipeline.render.scene import sensor_dict, shape_dicts
from pipeline.render.stats import is_bad, render_stats
from sky.emitter import SUN_MODES

#: A render with NaN, Inf or negative pixels is re-rendered with a new, recorded seed
#: up to this many times in all; if every attempt is bad it is kept and flagged.
MAX_RENDER_ATTEMPTS = 3
_SEED_STEP = 0x9E3779B9  # golden-ratio step: retry seeds far from the original



@dataclass(frozen=True)
class RenderSettings:
    """How a sample is rendered. Field names are the spec's `render` section's."""

    resolution: int = 400
    spp: int = 150
    max_depth: int = 8
    integrator: str = "path"
    sun: str = "split"
    #: The resolved Mitsuba variant (pipeline.render.mitsuba_env.resolve_variant), chosen once.
    variant: str = field(kw_only=True)

    def check(self, field_name=lambda name: f"render.{name}") -> RenderSettings:
        """Raise naming the field as ``field_name(name)`` says (a spec field, a CLI option); else self."""

        def integer(name, lo, hi):
            check_int(field_name(name), getattr(self, name), lo, hi)

        integer("resolution", *RESOLUTION_RANGE)
        integer("spp", *SPP_RANGE)
        integer("max_depth", *MAX_DEPTH_RANGE)
        if self.integrator not in INTEGRATORS:
            raise bad_value(field_name("integrator"), self.integrator, ", ".join(INTEGRATORS))
        if self.sun not in SUN_MODES:
            raise bad_value(field_name("sun"), self.sun, ", ".join(SUN_MODES))
        return self


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


def material_bsdf(maps, effects: EffectPlan, variant: str) -> dict:
    """The Mitsuba dict of the material, honouring ``effects``."""
    mitsuba_bsdf.register(variant)
    bsdf = mitsuba_bsdf.bsdf_dict(
        maps, lobes={"diffuse_lobe": effects.diffuse_lobe, "specular_lobe": effects.specular_lobe},
        variant=variant,
    )
    if effects.normal_map != (bsdf["type"] == "normalmap"):
        raise AssertionError("effect plan and BSDF disagree about the normal map")
    return bsdf


def scene_dict(ball, camera, maps, light, settings: RenderSettings, effects: EffectPlan | None = None,
               *, seed: int = 0) -> tuple[dict, dict, EffectPlan]:
    """The whole Mitsuba scene dict for one sample; also the lighting record and effects."""
    effects = effects or plan_effects(maps)
    emitters, lighting_record = emitter_dicts(light, sun=settings.sun, variant=settings.variant)
    scene = {
        "type": "scene",
        "integrator": {
            "type": "moment",
            "nested": {"type": settings.integrator, "max_depth": int(settings.max_depth)},
        },
        "sensor": sensor_dict(camera, settings.resolution, settings.spp, seed=seed, variant=settings.variant),
        **shape_dicts(ball, material_bsdf(maps, effects, settings.variant)),
        **emitters,
    }
    return scene, lighting_record, effects


@dataclass(frozen=True)
class RenderResult:
    image: np.ndarray  # (H, W, 3) float32, linear Rec.709
    variance: np.ndarray  # (H, W) float32, variance of the pixel estimate (mean over RGB)
    stats: dict  # pipeline.render.stats.render_stats + time, spp, seed, attempts, flagged
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


def render_in_passes(mi, scene, spp: int, seed: int) -> np.ndarray:
    """Every channel of ``spp`` samples per pixel, rendered as power-of-two passes, averaged.

    Why: in the llvm variant a render whose spp is not a power of two is not
    bit-reproducible with several render threads. A pixel's samples can straddle two of
    drjit's work blocks, whose threads add into the pixel in either order (measured: 237
    of 160,000 pixels differ by ~1 ulp between two 400x400, 150 spp renders). With
    power-of-two passes a pixel's samples never straddle; the passes are averaged in
    float64, weighted by their spp: exact for every channel of the moment integrator,
    whose channels are per-pixel means too. Cost: one kernel per distinct pass size
    (cached) and about +10% at 150 spp (docs/build.md).
    """
    total = None
    for k, n in enumerate(power_of_two_passes(spp)):
        image = np.asarray(mi.render(scene, spp=n, seed=pass_seed(seed, k)), dtype=np.float64) * n
        total = image if total is None else total + image
    return total / spp


def render_scene(mi, scene, spp: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Render a loaded scene (moment integrator); return (image, variance of the mean).

    The moment integrator's extra channels are the first and second moments of the nested
    integrator in CIE XYZ; the variance returned is that of the luminance Y (channels 4
    and 7), divided by spp: the variance of the pixel's estimate.
    """
    out = render_in_passes(mi, scene, spp, seed)
    image = np.ascontiguousarray(out[..., 0:3], dtype=np.float32)
    m1, m2 = out[..., 4], out[..., 7]
    variance = np.clip(m2 - m1 * m1, 0.0, None) / spp
    return image, variance.astype(np.float32)


def render_sample(ball, camera, maps, light, settings: RenderSettings, seed: int,
                  mask: np.ndarray | None = None) -> RenderResult:
    """Render one material under one light, re-rendering bad (NaN/Inf/negative) results."""
    settings.check()
    mi = load_mitsuba(settings.variant)
    start = time.perf_counter()
    scene_desc, lighting, effects = scene_dict(ball, camera, maps, light, settings)
    scene = mi.load_dict(scene_desc)
    attempts = []
    for attempt in range(MAX_RENDER_ATTEMPTS):
        attempt_seed = derived_seed(seed, attempt)
        image, variance = render_scene(mi, scene, settings.spp, attempt_seed)
        stats = render_stats(image, variance, mask)
        attempts.append({"seed": attempt_seed, "nan": stats["nan"], "inf": stats["inf"],
                         "negative": stats["negative"]})
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
    return RenderResult(image=image, variance=variance, stats=stats, lighting=lighting, effects=effects)
