"""The sun-and-sky emitter description, independent of any renderer.

Two ways to light a scene with the Hosek-Wilkie model (docs/sky.md, "Emitter"):

- ``sun="sunsky"``: one ``sunsky`` emitter with its sun disk (an area light of
  0.5358 degrees; soft penumbrae, the disk visible in mirrors);
- ``sun="split"``: a sky-only ``sunsky`` (``sun_scale = 0``) plus a delta
  ``directional`` emitter whose irradiance equals the disk's.

This module holds the modes, the constants and the pure arithmetic of both (plugin
dicts as plain data, the split's sampling weights, the luminance-preserving
desaturation); :mod:`pipeline.render.emitter` measures the emitter with Mitsuba and
builds the scene entries from them.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from sky.errors import refusal

SUN_MODES = ("split", "sunsky")
#: Chosen by measurement (docs/sky.md, `scripts/sun_benchmark.py`).
DEFAULT_SUN = "split"
#: Scene entry names of the emitters.
SKY_KEY, SUN_KEY = "sky", "sun"
#: Split mode: the sun's emitter sampling weight relative to the sky's (1) is this
#: factor times the ratio of the sun's irradiance to the sky's radiant power (both
#: luminance; a sphere's mean irradiance is a quarter of each). More than 1
#: because BSDF sampling with MIS already covers the sky but can never hit a delta
#: sun. Measured in docs/sky.md (`scripts/sun_benchmark.py`).
SPLIT_SUN_WEIGHT_FACTOR = 3.0
#: The ratio is raised to this power (1: proportional; 2 was tried and lost at low suns).
SPLIT_SUN_WEIGHT_EXPONENT = 1.0
#: Bounds of the sun's relative weight.
SPLIT_SUN_WEIGHT_RANGE = (0.02, 50.0)
#: Rec. 709 luminance weights (renders are linear Rec. 709).
LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])


def check_sun(sun: str) -> None:
    if sun not in SUN_MODES:
        raise refusal("sky.sun", sun, "one of " + ", ".join(f'"{m}"' for m in SUN_MODES))


def desaturate_to_nonnegative(rgb) -> tuple[np.ndarray, bool]:
    """Move ``rgb`` towards grey of the same luminance until no channel is negative.

    The smallest change in chromaticity that keeps luminance: rgb' = Y + s (rgb - Y)
    with the largest s in [0, 1] that makes every channel >= 0 (0 if Y <= 0).
    Returns (rgb', changed).
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if np.all(rgb >= 0.0):
        return rgb.copy(), False
    y = float(LUMINANCE_RGB @ rgb)
    if y <= 0.0:
        return np.zeros(3), True
    negative = rgb < 0.0
    s = float(np.min(y / (y - rgb[negative])))
    out = y + s * (rgb - y)
    return np.maximum(out, 0.0), True  # max() only removes round-off


def split_sampling_weights(sun_irradiance, sky_power) -> tuple[float, float]:
    """(sun, sky) emitter sampling weights of the split for one light.

    Never equal: Mitsuba 3.9 takes a separate code path for equal weights, and
    updating weights in place from equal to unequal leaves the scene sampling
    with the old ones (measured), so equality must never occur.
    """
    sun = float(LUMINANCE_RGB @ np.asarray(sun_irradiance))
    sky = float(LUMINANCE_RGB @ np.asarray(sky_power))
    ratio = (
        SPLIT_SUN_WEIGHT_FACTOR * (sun / sky) ** SPLIT_SUN_WEIGHT_EXPONENT if sky > 0.0 else SPLIT_SUN_WEIGHT_RANGE[1]
    )
    weight = float(np.clip(ratio, *SPLIT_SUN_WEIGHT_RANGE))
    if abs(weight - 1.0) < 1e-3:
        weight = 1.001
    return round(weight, 6), 1.0


#: Ground albedo given to ``sunsky`` (Mitsuba's default). The measured elevation
#: floor (sky.policy) holds for this value.
GROUND_ALBEDO = 0.3
#: Mitsuba's default apparent diameter of the sun, degrees.
SUN_APERTURE_DEG = 0.5358
#: Solid angle of the sun disk, steradians: 2 pi (1 - cos(aperture / 2)).
SUN_SOLID_ANGLE_SR = 2.0 * math.pi * (1.0 - math.cos(math.radians(SUN_APERTURE_DEG / 2.0)))


def sunsky_dict(direction, turbidity: float, sun_scale: float = 1.0, sky_scale: float = 1.0) -> dict:
    """A Mitsuba ``sunsky`` plugin dict in the world frame (z-up, like the plugin)."""
    return {
        "type": "sunsky",
        "sun_direction": [float(c) for c in direction],
        "turbidity": float(turbidity),
        "albedo": GROUND_ALBEDO,
        "sun_scale": float(sun_scale),
        "sky_scale": float(sky_scale),
        "sun_aperture": SUN_APERTURE_DEG,
    }


def hemisphere_check_directions(sun_dir: np.ndarray) -> np.ndarray:
    """Directions where negative radiance shows up first: dense at the horizon, all azimuths.

    The sky model is symmetric about the vertical plane through the sun, so
    azimuths are taken relative to the sun over one half-turn.
    """
    sun_az = math.atan2(sun_dir[1], sun_dir[0])
    cos_el, sin_el, turn = _check_grid()
    # the azimuths' cosines and sines once, broadcast over the elevations: the same values
    # (and bits) as those of the full grid, at 1/145 of the cost
    az = sun_az + turn
    dirs = np.stack([cos_el * np.cos(az), cos_el * np.sin(az), sin_el], -1).reshape(-1, 3)
    return np.concatenate([dirs, sun_dir[None, :]])


@functools.cache
def _check_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sun-independent part of :func:`hemisphere_check_directions`, computed once: cosine
    and sine of the elevation grid (elevations x azimuths) and the half-turn of azimuths."""
    horizon = np.concatenate([[0.0], np.geomspace(1e-4, 0.5, 24)])
    elevations = np.concatenate([horizon, np.linspace(0.75, 90.0, 120)])
    turn = np.radians(np.linspace(0.0, 180.0, 181))
    el, _ = np.meshgrid(np.radians(elevations), turn, indexing="ij")
    cos_el, sin_el = np.cos(el), np.sin(el)
    for array in (cos_el, sin_el, turn):
        array.flags.writeable = False
    return cos_el, sin_el, turn
