"""What lights a scene, for the renderer: the sun and sky (:mod:`pipeline.render.emitter`) or an
HDR environment map (:mod:`pipeline.render.envmap`), chosen by the light's type, so no stage
above the renderer asks which kind of light it holds.

Each gives the scene entries and the lighting record (``requested``, ``effective``, the
emitter). A scene lit by a map holds that one ``envmap`` emitter: no sun, no sky.
"""

from __future__ import annotations

import os

from pipeline.render.emitter import emitter_dicts
from pipeline.render.envmap import environment_light_dict
from sky.environment import EnvironmentLight

#: The scene entry of an environment map.
ENVIRONMENT_KEY = "environment"


def is_environment(light) -> bool:
    return isinstance(light, EnvironmentLight)


def light_entries(light, settings) -> tuple[dict, dict]:
    """Scene entries {name: plugin dict} lighting a scene with ``light`` and its record."""
    if not is_environment(light):
        return emitter_dicts(light, sun=settings.sun, variant=settings.variant)
    entry = environment_light_dict(light, variant=settings.variant)
    record = {
        "requested": {
            "environment": os.path.basename(light.file),
            "rotation_deg": light.rotation_deg,
            "intensity": light.scale,
        },
        "effective": light.to_dict(),
        "emitter": {"type": "envmap", "variant": settings.variant},
    }
    return {ENVIRONMENT_KEY: entry}, record
