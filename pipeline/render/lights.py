"""What lights a scene, for the renderer: the sun and sky (:mod:`pipeline.render.emitter`) or an
HDR environment map (:mod:`pipeline.render.envmap`), chosen by the light's type, so no stage
above the renderer asks which kind of light it holds.

Each gives the scene entries and the lighting record (``requested``, ``effective``, the
emitter). A scene lit by a map holds that one ``envmap`` emitter: no sun, no sky.
"""

from __future__ import annotations

import functools
import hashlib
import os

from pipeline.errors import ShaderballError, quoted
from pipeline.render.emitter import emitter_dicts
from pipeline.render.envmap import environment_emitter_dict, read_environment
from sky.environment import EnvironmentLight

#: The scene entry of an environment map.
ENVIRONMENT_KEY = "environment"


def is_environment(light) -> bool:
    return isinstance(light, EnvironmentLight)


def light_entries(light, settings) -> tuple[dict, dict]:
    """Scene entries {name: plugin dict} lighting a scene with ``light`` and its record."""
    if not is_environment(light):
        return emitter_dicts(light, sun=settings.sun, variant=settings.variant)
    radiance = environment_radiance(light.file, light.digest)
    entry = environment_emitter_dict(radiance, light.rotation_deg, light.scale, variant=settings.variant)
    height, width = radiance.shape[:2]
    record = {
        "requested": {
            "environment": os.path.basename(light.file),
            "rotation_deg": light.rotation_deg,
            "intensity": light.scale,
        },
        "effective": light.to_dict(),
        "emitter": {"type": "envmap", "width": int(width), "height": int(height), "variant": settings.variant},
    }
    return {ENVIRONMENT_KEY: entry}, record


@functools.lru_cache(maxsize=4)
def environment_radiance(path: str, digest: str):
    """The map at ``path`` (read, checked and converted once per process), refused unless its
    bytes still have the SHA-256 the spec was digested with: a map changed after the build
    started would make a dataset of two maps under one name."""
    with open(path, "rb") as handle:
        found = hashlib.file_digest(handle, "sha256").hexdigest()
    if found != digest:
        raise ShaderballError(
            f"{quoted(path)}: the environment map changed since the spec was read (SHA-256 {found[:12]}, "
            f"the spec's {digest[:12]}): a changed map is another dataset; build it into a new folder"
        )
    return read_environment(path)
