"""Uniform materials: one value per map, replicated (the paper's half of the dataset).

A material is a dielectric (grey specular albedo of a few percent, coloured
diffuse) or, with probability ``metal_probability``, a metal (specular albedo
grey to gold/copper/brass, almost no diffuse). Colours are drawn in HSV with V in
sRGB-encoded units, so brightness is spread perceptually, then decoded to
linear. Roughness is uniform in ``r`` (alpha = r^2), which is already close to
perceptually uniform. The normal is flat with probability
``flat_normal_probability``, otherwise tilted by an angle uniform in solid
angle up to ``normal_tilt_max_deg``, towards a uniform azimuth. Per channel
``d <= 1 - s`` always holds. docs/materials.md has the reasoning.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from materials.colorspace import hsv_to_rgb, srgb_decode
from materials.errors import MaterialError, number_allowed, pair_allowed, refusal
from materials.maps import ALBEDO_RANGE, ROUGHNESS_RANGE, UniformMaterial, tilt_normal

#: A probability.
PROBABILITY_RANGE = (0.0, 1.0)
#: An HSV component (hue as a fraction of the circle; value in sRGB-encoded units).
HSV_RANGE = (0.0, 1.0)
#: The largest tilt a uniform material's normal may be drawn with, degrees from z.
NORMAL_TILT_RANGE = (0.0, 80.0)

#: What each field of :class:`UniformRanges` may hold: a number in, or a pair within, these
#: bounds. Declared here once; the spec's ``[materials]`` rules are built from it.
UNIFORM_LIMITS: dict[str, tuple[float, float]] = {
    "roughness": ROUGHNESS_RANGE,
    "metal_probability": PROBABILITY_RANGE,
    "dielectric_specular": ALBEDO_RANGE,
    "diffuse_value_srgb": HSV_RANGE,
    "diffuse_saturation": HSV_RANGE,
    "metal_value_srgb": HSV_RANGE,
    "metal_saturation": HSV_RANGE,
    "metal_hue": HSV_RANGE,
    "metal_diffuse_fraction": PROBABILITY_RANGE,
    "flat_normal_probability": PROBABILITY_RANGE,
    "normal_tilt_max_deg": NORMAL_TILT_RANGE,
}


@dataclass(frozen=True)
class UniformRanges:
    """Ranges of :func:`sample_uniform`; every bound is checked at construction."""

    #: Roughness r, uniform in [min, max] (alpha = r^2). Below ~0.05 highlights are
    #: near-mirror images of the sun and path-traced noise grows sharply.
    roughness: tuple[float, float] = (0.05, 1.0)
    #: Probability that a material is a metal (coloured specular, ~no diffuse).
    metal_probability: float = 0.3
    #: Dielectric specular albedo (grey), uniform: water ~0.02, plastics ~0.04-0.05, gems ~0.08+.
    dielectric_specular: tuple[float, float] = (0.02, 0.08)
    #: Dielectric diffuse brightness, HSV value in sRGB-encoded units (0.15 -> 0.02 linear,
    #: 0.95 -> 0.89 linear: charcoal to fresh snow).
    diffuse_value_srgb: tuple[float, float] = (0.15, 0.95)
    #: Dielectric diffuse saturation (HSV).
    diffuse_saturation: tuple[float, float] = (0.0, 0.85)
    #: Metal specular brightness, HSV value in sRGB-encoded units (0.55 -> 0.26 linear, e.g.
    #: titanium-like dark metals, to 1.0: silver).
    metal_value_srgb: tuple[float, float] = (0.55, 1.0)
    #: Metal specular saturation (HSV); gold and copper are ~0.4-0.5.
    metal_saturation: tuple[float, float] = (0.0, 0.5)
    #: Metal specular hue (HSV, 0 = red, 1/6 = yellow): copper, gold and brass lie in
    #: ~0.03-0.15; greys (low saturation) are hue-neutral.
    metal_hue: tuple[float, float] = (0.0, 0.17)
    #: Metal diffuse albedo as a fraction of the room left, 1 - s (dirt, oxide).
    metal_diffuse_fraction: tuple[float, float] = (0.0, 0.1)
    #: Probability of a flat normal (0, 0, 1).
    flat_normal_probability: float = 0.5
    #: Largest tilt of a non-flat normal from z, degrees.
    normal_tilt_max_deg: float = 20.0

    def __post_init__(self):
        """Raise :class:`MaterialError` naming the field, its value and what is allowed."""
        for f in fields(self):
            value = getattr(self, f.name)
            low, high = UNIFORM_LIMITS[f.name]
            if isinstance(value, tuple):
                ok = (
                    len(value) == 2
                    and all(isinstance(v, (int, float)) and np.isfinite(v) for v in value)
                    and low <= value[0] <= value[1] <= high
                )
                allowed = pair_allowed(low, high)
            else:
                ok = isinstance(value, (int, float)) and np.isfinite(value) and low <= value <= high
                allowed = number_allowed(low, high)
            if not ok:
                raise refusal(f"UniformRanges.{f.name}", value, allowed)


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def _colour(rng, value_srgb, saturation, hue=(0.0, 1.0)) -> np.ndarray:
    hsv = np.array([_uniform(rng, hue), _uniform(rng, saturation), _uniform(rng, value_srgb)])
    return np.clip(srgb_decode(hsv_to_rgb(hsv)), 0.0, 1.0)


def sample_uniform(rng: np.random.Generator, ranges: UniformRanges = UniformRanges()) -> UniformMaterial:
    """Draw one uniform material; the same generator state gives the same material."""
    if not isinstance(rng, np.random.Generator):
        raise MaterialError(f"sample_uniform: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    is_metal = bool(rng.uniform() < ranges.metal_probability)
    if is_metal:
        specular = _colour(rng, ranges.metal_value_srgb, ranges.metal_saturation, ranges.metal_hue)
        diffuse_colour = _colour(rng, (0.5, 1.0), (0.0, 0.5))
        diffuse = diffuse_colour * _uniform(rng, ranges.metal_diffuse_fraction) * (1.0 - specular)
    else:
        specular = np.full(3, _uniform(rng, ranges.dielectric_specular))
        diffuse = _colour(rng, ranges.diffuse_value_srgb, ranges.diffuse_saturation)
    diffuse = np.minimum(diffuse, 1.0 - specular)
    roughness = _uniform(rng, ranges.roughness)
    if rng.uniform() < ranges.flat_normal_probability:
        normal = (0.0, 0.0, 1.0)
    else:
        cos_max = np.cos(np.radians(ranges.normal_tilt_max_deg))
        tilt = np.degrees(np.arccos(rng.uniform(cos_max, 1.0)))
        normal = tilt_normal(tilt, rng.uniform(0.0, 360.0))
    # float32 round trip so the values equal what the maps hold.
    f32 = lambda v: tuple(float(x) for x in np.asarray(v, dtype=np.float32))  # noqa: E731
    return UniformMaterial(
        diffuse=f32(diffuse),
        specular=f32(specular),
        roughness=float(np.float32(roughness)),
        normal=f32(normal),
    )
