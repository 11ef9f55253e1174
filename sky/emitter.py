"""The sun-and-sky emitter description for Mitsuba, and in-place updates of a loaded scene.

Two ways to light a scene with the Hosek-Wilkie model (docs/sky.md, "Emitter"):

- ``sun="sunsky"``: one Mitsuba ``sunsky`` with its sun disk (an area light of
  0.5358 degrees; soft penumbrae, the disk visible in mirrors);
- ``sun="split"``: a sky-only ``sunsky`` (``sun_scale = 0``) plus a delta
  ``directional`` emitter whose irradiance equals the disk's: its radiance (uniform
  over the disk in Mitsuba 3.9's default RGB model) times its solid angle.
  Emitter selection is weighted per light (:func:`split_sampling_weights`).

Both take the sun direction in the world frame unchanged: ``sunsky``'s local
frame is z-up like the world's, so it needs no ``to_world``.
"""

from __future__ import annotations

import sys

import numpy as np

from pipeline.errors import SetupError, ShaderballError
from sky.lighting import Light
from sky.policy import DEFAULT_POLICY, LightingPolicy, apply_policy
from sky.probe import SUN_SOLID_ANGLE_SR, shared_probe, sunsky_dict

SUN_MODES = ("split", "sunsky")
#: Chosen by measurement (docs/sky.md, `python -m sky.sun_benchmark`).
DEFAULT_SUN = "split"
#: Scene entry names of the emitters.
SKY_KEY, SUN_KEY = "sky", "sun"
#: Split mode: the sun's emitter sampling weight relative to the sky's (1) is this
#: factor times the ratio of the sun's irradiance to the sky's radiant power (both
#: luminance; a sphere's mean irradiance is a quarter of each). More than 1
#: because BSDF sampling with MIS already covers the sky but can never hit a delta
#: sun. Measured in docs/sky.md (`python -m sky.sun_benchmark`).
SPLIT_SUN_WEIGHT_FACTOR = 3.0
#: The ratio is raised to this power (1: proportional; 2 was tried and lost at low suns).
SPLIT_SUN_WEIGHT_EXPONENT = 1.0
#: Bounds of the sun's relative weight.
SPLIT_SUN_WEIGHT_RANGE = (0.02, 50.0)
#: Rec. 709 luminance weights (renders are linear Rec. 709).
LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])


def _resolve_variant(variant: str | None) -> str:
    if variant is None:
        if "mitsuba" in sys.modules:
            current = sys.modules["mitsuba"].variant()
            variant = current or "llvm_ad_rgb"
        else:
            variant = "llvm_ad_rgb"
    if not (variant.endswith("_rgb") and variant.split("_")[0] in ("llvm", "cuda")):
        raise ShaderballError(
            f"render.variant = {variant!r} is not allowed for the sky: an llvm or cuda RGB variant is "
            "required (the hard-case policy was measured on Mitsuba's RGB sunsky; the emitter is "
            "probed with vectorised evaluations)"
        )
    return variant


def _check_sun(sun: str) -> None:
    if sun not in SUN_MODES:
        raise ShaderballError(f"sky.sun = {sun!r} is not allowed: one of {', '.join(SUN_MODES)}")


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


def directional_to_world(direction: np.ndarray):
    """A Mitsuba transform whose local +z is the light's travel direction, ``-direction``."""
    from pipeline.mitsuba_env import load_mitsuba

    mi = load_mitsuba(_resolve_variant(None))
    travel = -np.asarray(direction, dtype=np.float64)
    up = [0.0, 1.0, 0.0] if abs(travel[2]) > 0.9 else [0.0, 0.0, 1.0]
    return mi.ScalarTransform4f().look_at(origin=[0.0, 0.0, 0.0], target=travel.tolist(), up=up)


def split_sampling_weights(sun_irradiance, sky_power) -> tuple[float, float]:
    """(sun, sky) emitter sampling weights of the split for one light.

    Never equal: Mitsuba 3.9 takes a separate code path for equal weights, and
    updating weights in place from equal to unequal leaves the scene sampling
    with the old ones (measured), so equality must never occur.
    """
    sun = float(LUMINANCE_RGB @ np.asarray(sun_irradiance))
    sky = float(LUMINANCE_RGB @ np.asarray(sky_power))
    ratio = SPLIT_SUN_WEIGHT_FACTOR * (sun / sky) ** SPLIT_SUN_WEIGHT_EXPONENT if sky > 0.0 else SPLIT_SUN_WEIGHT_RANGE[1]
    weight = float(np.clip(ratio, *SPLIT_SUN_WEIGHT_RANGE))
    if abs(weight - 1.0) < 1e-3:
        weight = 1.001
    return round(weight, 6), 1.0


def _emitter_state(effective: Light, sun: str, policy: LightingPolicy, variant: str) -> dict:
    """Everything both the dicts and the in-place update need, measured on the probe."""
    from pipeline.mitsuba_env import load_mitsuba

    load_mitsuba(variant)  # the probe's types belong to this variant
    probe = shared_probe(variant).set(effective.direction, effective.turbidity)
    raw_irradiance = probe.sun_disk_radiance() * SUN_SOLID_ANGLE_SR
    state = {"sun": sun, "variant": variant, "raw_sun_irradiance": raw_irradiance}
    if sun == "split":
        irradiance, adjusted = desaturate_to_nonnegative(raw_irradiance)
        sky_min = probe.min_radiance("sky")
        state.update(
            irradiance=irradiance,
            adjusted=adjusted,
            emitter_min=np.minimum(sky_min, irradiance.min()),
            weights=split_sampling_weights(irradiance, probe.sky_power()),
        )
    else:
        state.update(irradiance=raw_irradiance, adjusted=False, emitter_min=probe.min_radiance("both"))
    if policy.floor != "off" and np.any(state["emitter_min"] < 0.0):
        raise SetupError(
            f"the sky emitter for {effective.to_dict()} has negative radiance "
            f"{state['emitter_min'].tolist()} although the elevation floor holds: the floor table in "
            "sky/policy.py does not fit this Mitsuba version; regenerate it with "
            "`python -m sky.hard_cases --table`"
        )
    return state


def _record(policy_record: dict, state: dict) -> dict:
    record = dict(policy_record)
    record["emitter"] = {
        "sun": state["sun"],
        "variant": state["variant"],
        "sun_irradiance_rgb": [float(x) for x in state["irradiance"]],
        "sun_irradiance_adjusted": (
            {
                "from": [float(x) for x in state["raw_sun_irradiance"]],
                "method": "luminance-preserving desaturation to non-negative RGB",
            }
            if state["adjusted"]
            else None
        ),
        "min_radiance_rgb": [float(x) for x in state["emitter_min"]],
        "sampling_weights": (
            {"sun": state["weights"][0], "sky": state["weights"][1]} if state["sun"] == "split" else None
        ),
    }
    return record


def emitter_dicts(
    light: Light,
    sun: str = DEFAULT_SUN,
    policy: LightingPolicy = DEFAULT_POLICY,
    *,
    variant: str | None = None,
) -> tuple[dict, dict]:
    """Mitsuba scene entries {name: plugin dict} lighting the scene with ``light``, and the record.

    The record (JSON-serialisable) is the policy's (requested and effective light,
    what changed and why) plus what the emitter became. ``variant`` defaults to
    the Mitsuba variant already set (llvm_ad_rgb if none).
    """
    _check_sun(sun)
    variant = _resolve_variant(variant)
    effective, policy_record = apply_policy(light, policy)
    state = _emitter_state(effective, sun, policy, variant)
    d = effective.direction
    if sun == "sunsky":
        entries = {SKY_KEY: sunsky_dict(d, effective.turbidity)}
    else:
        sky = sunsky_dict(d, effective.turbidity, sun_scale=0.0)
        sky["sampling_weight"] = state["weights"][1]
        entries = {
            SKY_KEY: sky,
            SUN_KEY: {
                "type": "directional",
                "to_world": directional_to_world(d),
                "irradiance": {"type": "rgb", "value": [float(x) for x in state["irradiance"]]},
                "sampling_weight": state["weights"][0],
            },
        }
    return entries, _record(policy_record, state)


def update_emitter_params(
    params,
    light: Light,
    sun: str = DEFAULT_SUN,
    policy: LightingPolicy = DEFAULT_POLICY,
    *,
    sky_key: str = SKY_KEY,
    sun_key: str = SUN_KEY,
    update: bool = True,
    variant: str | None = None,
) -> dict:
    """Move the emitters of a loaded scene (``mi.traverse(scene)``) to ``light``; return the record.

    The scene must have been built by :func:`emitter_dicts` with the same ``sun``.
    Keys written: ``sky.sun_direction``, ``sky.turbidity`` and, for the split,
    ``sun.irradiance.value`` and ``sun.to_world``; none of them recompiles
    kernels. The result renders identically to a scene built afresh for ``light``.
    """
    _check_sun(sun)
    variant = _resolve_variant(variant)
    from pipeline.mitsuba_env import load_mitsuba

    mi = load_mitsuba(variant)
    expected_sun_scale = 1.0 if sun == "sunsky" else 0.0
    scale_key = f"{sky_key}.sun_scale"
    if scale_key not in params or float(params[scale_key]) != expected_sun_scale:
        found = params[scale_key] if scale_key in params else "missing"
        raise ShaderballError(
            f"sky.sun = {sun!r} does not match the loaded scene ({scale_key} = {found}): "
            "build the scene with emitter_dicts(..., sun=...) of the same mode "
            "(changing sun_scale would recompile Mitsuba's kernels)"
        )
    if sun == "split" and f"{sun_key}.to_world" not in params:
        raise ShaderballError(f"sky.sun = 'split' but the loaded scene has no '{sun_key}' emitter")

    effective, policy_record = apply_policy(light, policy)
    state = _emitter_state(effective, sun, policy, variant)
    d = effective.direction
    params[f"{sky_key}.sun_direction"] = mi.Vector3f(*(float(c) for c in d))
    params[f"{sky_key}.turbidity"] = float(effective.turbidity)
    if sun == "split":
        params[f"{sun_key}.irradiance.value"] = mi.Color3f(*(float(c) for c in state["irradiance"]))
        params[f"{sun_key}.to_world"] = mi.AffineTransform4f(directional_to_world(d))
        params[f"{sun_key}.sampling_weight"], params[f"{sky_key}.sampling_weight"] = state["weights"]
    if update:
        params.update()
    return _record(policy_record, state)
