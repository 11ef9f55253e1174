"""What a sample's record says that follows from its spec and its plan, in one place for the
writer (:mod:`pipeline.run.shard`) and the checker (:mod:`pipeline.check.crosscheck`)."""

from __future__ import annotations

import numpy as np

from materials.brdf_ref import DEFAULT_MODEL
from sky import Light
from sky.environment import EnvironmentLight


def model_record(model: str) -> dict:
    """What records and render files say about the material model: nothing for the default.

    Absent means "shaderball", so the files and records of the default model are
    the bytes they were before the model could be chosen.
    """
    return {} if model == DEFAULT_MODEL else {"model": model}


def light_from_record(lighting: dict):
    """The effective light a record's ``lighting`` describes: a ``sky.Light``, or an
    ``EnvironmentLight`` where ``source`` says so (the map named by its base name and digest)."""
    if lighting.get("source") == "environment":
        return EnvironmentLight(lighting["file"], lighting["sha256"], lighting["rotation_deg"], lighting["scale"])
    return Light.from_dict(lighting)


def lighting_discrepancies(record: dict) -> list[str]:
    """What a record says about its effective lighting that does not follow from its angles
    (direction, lighting vector) or from its render (the seed used); [] when consistent."""

    lighting = record.get("lighting") if isinstance(record.get("lighting"), dict) else {}
    try:
        light = light_from_record(lighting)
    except Exception as exc:  # missing keys, out-of-range values: the message says which
        return [f"lighting is not a valid light ({exc})"]
    out = []
    direction = lighting.get("direction")
    try:
        if isinstance(light, Light) and not np.allclose(
            np.asarray(direction, np.float64), light.direction, rtol=0, atol=1e-9
        ):
            out.append(
                f"lighting.direction {direction!r} does not follow from elevation_deg "
                f"{light.elevation_deg!r} and azimuth_deg {light.azimuth_deg!r}"
            )
    except (TypeError, ValueError):
        out.append(f"lighting.direction is {direction!r}, not a 3-vector")
    vector = record.get("lighting_vector")
    try:
        if not np.allclose(np.asarray(vector, np.float64), light.lighting_vector(), rtol=0, atol=1e-6):
            out.append(
                f"lighting_vector {vector!r} does not follow from the effective lighting "
                + (
                    f"(direction and turbidity {light.turbidity!r})"
                    if isinstance(light, Light)
                    else f"(rotation {light.rotation_deg!r} and scale {light.scale!r})"
                )
            )
    except (TypeError, ValueError):
        out.append(f"lighting_vector is {vector!r}, not a 4-vector")
    seeds, stats = record.get("seeds") or {}, record.get("stats") or {}
    if isinstance(seeds, dict) and isinstance(stats, dict) and seeds.get("render_used") != stats.get("seed"):
        out.append(f"seeds.render_used is {seeds.get('render_used')!r}, stats.seed is {stats.get('seed')!r}")
    return out
