"""What lights a scene, for the renderer: the sun and sky (:mod:`pipeline.render.emitter`) or an
HDR environment map (:mod:`pipeline.render.envmap`), chosen by the light's type, so no stage
above the renderer asks which kind of light it holds.

Each gives the scene entries and the lighting record (``requested``, ``effective``, the
emitter). A scene lit by a map holds that one ``envmap`` emitter: no sun, no sky.
"""

from __future__ import annotations

import os

from pipeline.render.emitter import emitter_dicts, update_emitter_params
from pipeline.render.envmap import environment_light_dict, environment_to_world
from pipeline.render.mitsuba_env import load_mitsuba
from sky.environment import EnvironmentLight, check_rotation, check_scale

#: The scene entry of an environment map.
ENVIRONMENT_KEY = "environment"


def is_environment(light) -> bool:
    return isinstance(light, EnvironmentLight)


def light_entries(light, settings) -> tuple[dict, dict]:
    """Scene entries {name: plugin dict} lighting a scene with ``light`` and its record."""
    if not is_environment(light):
        return emitter_dicts(light, sun=settings.sun, variant=settings.variant)
    entry = environment_light_dict(light, variant=settings.variant)
    return {ENVIRONMENT_KEY: entry}, _environment_record(light, settings)


def movable(held, light) -> bool:
    """A scene loaded with the light ``held`` can be moved to ``light`` in place: both the sun
    and sky, or both the same environment map (its rotation and scale move; another map, whose
    sampling tables Mitsuba builds when it loads, is loaded with a new scene)."""
    if is_environment(light) or is_environment(held):
        return is_environment(light) and is_environment(held) and light.digest == held.digest
    return held is not None


def move_light(params, light, settings) -> dict:
    """Move a loaded scene's light (``mi.traverse(scene)``, a scene :func:`movable` to ``light``)
    to ``light``; return its record. The same bytes as a scene loaded for ``light``
    (tests/test_scenes_build.py, tests/test_scene_reuse.py)."""
    if not is_environment(light):
        return update_emitter_params(params, light, sun=settings.sun, variant=settings.variant)
    mi = load_mitsuba(settings.variant)
    params[f"{ENVIRONMENT_KEY}.scale"] = mi.Float(check_scale(light.scale))
    to_world = environment_to_world(check_rotation(light.rotation_deg), settings.variant)
    params[f"{ENVIRONMENT_KEY}.to_world"] = mi.AffineTransform4f(to_world)
    params.update()
    return _environment_record(light, settings)


def _environment_record(light, settings) -> dict:
    return {
        "requested": {
            "environment": os.path.basename(light.file),
            "rotation_deg": light.rotation_deg,
            "intensity": light.scale,
        },
        "effective": light.to_dict(),
        "emitter": {"type": "envmap", "variant": settings.variant},
    }
