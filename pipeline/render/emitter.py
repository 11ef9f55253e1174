"""Mitsuba's side of the sun-and-sky emitter: scene entries and in-place updates.

The modes, constants and pure arithmetic live in :mod:`sky.emitter`; this module
measures the emitter on a :class:`pipeline.render.sky_probe.SunskyProbe` (the sun's
irradiance, the sky's power, the smallest radiance) and builds the entries a scene
needs, or moves a loaded scene's emitters to a new light without recompiling.
Both take the sun direction in the world frame unchanged: ``sunsky``'s local frame
is z-up like the world's, so it needs no ``to_world``.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import SetupError, ShaderballError
from pipeline.render.mitsuba_env import load_mitsuba
from pipeline.render.sky_probe import shared_probe
from sky.emitter import (
    DEFAULT_SUN,
    SKY_KEY,
    SUN_KEY,
    SUN_SOLID_ANGLE_SR,
    check_sun,
    desaturate_to_nonnegative,
    split_sampling_weights,
    sunsky_dict,
)
from sky.lighting import Light
from sky.policy import DEFAULT_POLICY, LightingPolicy, apply_policy


def _check_variant(variant: str) -> str:
    if not (variant.endswith("_rgb") and variant.split("_")[0] in ("llvm", "cuda")):
        raise ShaderballError(
            f"render.variant = {variant!r} is not allowed for the sky: an llvm or cuda RGB variant is "
            "required (the hard-case policy was measured on Mitsuba's RGB sunsky; the emitter is "
            "probed with vectorised evaluations)"
        )
    return variant


def directional_to_world(direction: np.ndarray, variant: str):
    """A Mitsuba transform whose local +z is the light's travel direction, ``-direction``."""
    mi = load_mitsuba(variant)
    travel = -np.asarray(direction, dtype=np.float64)
    up = [0.0, 1.0, 0.0] if abs(travel[2]) > 0.9 else [0.0, 0.0, 1.0]
    return mi.ScalarTransform4f().look_at(origin=[0.0, 0.0, 0.0], target=travel.tolist(), up=up)


def loaded_sun_direction(direction, variant: str):
    """The float32 sun direction Mitsuba's ``sunsky`` loader makes of ``direction`` (a Vector3f).

    The loader normalises the dict's vector in float32 with its own arithmetic; for some
    directions the result differs by an ulp from the rounded vector (measured: 6 of the smoke
    spec's 16), and no numpy or drjit expression tried here reproduces it for every
    direction. So a lone sky emitter is loaded (~2 ms, no scene, nothing compiled) and its
    vector read back: a scene moved to a light then renders the same bytes as a scene loaded
    for it.
    """
    mi = load_mitsuba(variant)
    emitter = mi.load_dict(sunsky_dict(direction, 3.0, sun_scale=0.0))
    value = np.asarray(mi.traverse(emitter)["sun_direction"], dtype=np.float32).ravel()
    del emitter
    return mi.Vector3f(*(float(c) for c in value))


def _emitter_state(effective: Light, sun: str, policy: LightingPolicy, variant: str) -> dict:
    """Everything both the dicts and the in-place update need, measured on the probe."""
    load_mitsuba(variant)  # the probe's types belong to this variant
    # Only the probe's emitters read below are moved (each move recomputes a sunsky's tables).
    parts = ("sun", "sky") if sun == "split" else ("sun", "both")
    probe = shared_probe(variant).set(effective.direction, effective.turbidity, parts=parts)
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
            "`scripts/sky_floor.py --table`"
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
    variant: str,
) -> tuple[dict, dict]:
    """Mitsuba scene entries {name: plugin dict} lighting the scene with ``light``, and the record.

    The record (JSON-serialisable) is the policy's (requested and effective light,
    what changed and why) plus what the emitter became. ``variant`` is the
    render's resolved Mitsuba variant.
    """
    check_sun(sun)
    variant = _check_variant(variant)
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
                "to_world": directional_to_world(d, variant),
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
    variant: str,
) -> dict:
    """Move the emitters of a loaded scene (``mi.traverse(scene)``) to ``light``; return the record.

    The scene must have been built by :func:`emitter_dicts` with the same ``sun``.
    Keys written: ``sky.sun_direction``, ``sky.turbidity`` and, for the split,
    ``sun.irradiance.value`` and ``sun.to_world``; none of them recompiles
    kernels. The result renders the same bytes as a scene loaded afresh for ``light``: the
    direction written is the loader's own (:func:`loaded_sun_direction`), and every other
    value is the float the dict holds (tests/test_build_bench.py).
    """
    check_sun(sun)
    variant = _check_variant(variant)
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
    params[f"{sky_key}.sun_direction"] = loaded_sun_direction(d, variant)
    params[f"{sky_key}.turbidity"] = float(effective.turbidity)
    if sun == "split":
        params[f"{sun_key}.irradiance.value"] = mi.Color3f(*(float(c) for c in state["irradiance"]))
        params[f"{sun_key}.to_world"] = mi.AffineTransform4f(directional_to_world(d, variant))
        params[f"{sun_key}.sampling_weight"], params[f"{sky_key}.sampling_weight"] = state["weights"]
    if update:
        params.update()
    return _record(policy_record, state)
