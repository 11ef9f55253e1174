"""Sun and sky: directions, the lighting vector, sampling, the hard-case policy, the emitter;
and HDR environment maps as the other light (:mod:`sky.environment`).

A domain package: it imports neither Mitsuba nor anything of ``pipeline``. The
emitter's Mitsuba side (:func:`pipeline.render.emitter.emitter_dicts`,
:func:`pipeline.render.emitter.update_emitter_params`) builds on :mod:`sky.emitter`.
See docs/sky.md. The sun's and turbidity's ranges are declared here once
(:mod:`sky.lighting`): every rule of the spec, the commands and the server is built from them.

Layer 1 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): imports
nothing of the project.
"""

from sky.directions import normalize_azimuth, sun_angles, sun_direction
from sky.emitter import DEFAULT_SUN, SKY_KEY, SUN_KEY, SUN_MODES
from sky.environment import (
    ENVIRONMENT_SUFFIXES,
    ROTATION_RANGE,
    SCALE_RANGE,
    EnvironmentLight,
    list_environment_files,
    sample_rotations,
)
from sky.errors import SkyError
from sky.lighting import (
    AZIMUTH_BOUNDS,
    AZIMUTH_RANGE,
    AZIMUTH_TURN,
    ELEVATION_RANGE,
    MAX_AZIMUTH_SPAN_DEG,
    SCHEMES,
    TURBIDITY_RANGE,
    Light,
    LightingRanges,
)
from sky.policy import (
    DEFAULT_POLICY,
    SAFE_ELEVATION_DEG,
    LightingPolicy,
    apply_policy,
    elevation_floor_deg,
)
from sky.sampling import direction_pdf, sample_lights

__all__ = [
    "AZIMUTH_BOUNDS",
    "AZIMUTH_RANGE",
    "AZIMUTH_TURN",
    "DEFAULT_POLICY",
    "DEFAULT_SUN",
    "ELEVATION_RANGE",
    "ENVIRONMENT_SUFFIXES",
    "MAX_AZIMUTH_SPAN_DEG",
    "ROTATION_RANGE",
    "SAFE_ELEVATION_DEG",
    "SCALE_RANGE",
    "SCHEMES",
    "SKY_KEY",
    "SUN_KEY",
    "SUN_MODES",
    "SkyError",
    "TURBIDITY_RANGE",
    "EnvironmentLight",
    "Light",
    "LightingPolicy",
    "LightingRanges",
    "apply_policy",
    "direction_pdf",
    "elevation_floor_deg",
    "list_environment_files",
    "normalize_azimuth",
    "sample_lights",
    "sample_rotations",
    "sun_angles",
    "sun_direction",
]
