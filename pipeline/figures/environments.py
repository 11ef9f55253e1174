"""Two procedural HDR environment maps, made in code so the repository ships them small and
anyone can make them again: ``studio`` (a dark surround, three soft area lights) and
``outdoor`` (a sky gradient over a dark ground, a small very bright sun).

``scripts/make_environments.py`` writes them to ``manifests/environments/`` (256x128, half
floats, the ``render.R/G/B`` layer :func:`pipeline.render.envmap.read_environment` reads),
where ``manifests/scenes.toml`` and ``shaderball figures scenes`` take them from.

Each pixel is evaluated at the world direction Mitsuba's ``envmap`` gives it at rotation 0
(:func:`sky.environment.map_direction`: row ``i`` at polar angle ``180 i / (H - 1)``,
column ``j`` at ``u = (j + 0.5) / W``), so a light placed here at an azimuth and elevation
lights the scene from there (the camera looks along +y from the -y side: azimuth 270 is
behind the camera). Pure numpy; writing is :func:`write_environments`.
"""

from __future__ import annotations

import os

import numpy as np

from pipeline.store.exr import write_exr
from sky.directions import sun_direction
from sky.environment import map_direction

#: Side lengths of the shipped maps: (height, width), lat-long (width = 2 height).
DEFAULT_HEIGHT = 128
#: Heights :func:`environment` accepts: enough rows for the sun's disc, at most a 4k map.
HEIGHT_RANGE = (16, 2048)
#: The maps, in the order a figure shows them.
ENVIRONMENT_NAMES = ("studio", "outdoor")
#: The folder the maps ship in, relative to the repository.
SHIPPED_FOLDER = os.path.join("manifests", "environments")

#: Studio lights: (name, azimuth_deg, elevation_deg, angular radius_deg, linear RGB radiance).
#: A warm key to the camera's left, a cool dimmer fill to its right, a rim light behind.
STUDIO_LIGHTS = (
    ("key", 220.0, 35.0, 14.0, (30.0, 27.0, 23.0)),
    ("fill", 325.0, 15.0, 18.0, (5.0, 6.0, 7.5)),
    ("rim", 60.0, 50.0, 10.0, (22.0, 22.0, 22.0)),
)
#: The studio's surround at the horizon and straight up (linear RGB): dark, not black.
STUDIO_SURROUND = ((0.02, 0.02, 0.022), (0.045, 0.045, 0.05))
#: Sky radiance at the zenith and at the horizon, and the ground's (linear RGB).
SKY_ZENITH = (0.12, 0.25, 0.75)
SKY_HORIZON = (0.75, 0.85, 1.0)
GROUND = (0.09, 0.08, 0.06)
#: The sun: azimuth and elevation (degrees), angular radius (degrees; the real one is 0.27,
#: too small for a 256-pixel-wide map), radiance (linear RGB): about 8x the sky's irradiance.
SUN = (215.0, 40.0, 2.0, (3000.0, 2800.0, 2400.0))


def _directions(height: int) -> np.ndarray:
    """(H, 2H, 3) world directions of the map's pixels at rotation 0."""
    if not isinstance(height, int) or not HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1]:
        raise ValueError(f"height {height!r}: an integer from {HEIGHT_RANGE[0]} to {HEIGHT_RANGE[1]} is required")
    width = 2 * height
    u = (np.arange(width, dtype=np.float64) + 0.5) / width
    v = np.arange(height, dtype=np.float64) / (height - 1)
    return map_direction(u[None, :], v[:, None])


def _disc(directions: np.ndarray, azimuth_deg: float, elevation_deg: float, radius_deg: float) -> np.ndarray:
    """(H, W) weight in [0, 1] of a soft disc: 1 inside ``radius_deg``, falling smoothly to 0
    at 1.5 radii (a softbox's diffuser, not a hard edge that would alias at 256 px)."""
    centre = sun_direction(elevation_deg, azimuth_deg)
    angle = np.degrees(np.arccos(np.clip(directions @ centre, -1.0, 1.0)))
    t = np.clip((1.5 * radius_deg - angle) / (0.5 * radius_deg), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def studio(height: int = DEFAULT_HEIGHT) -> np.ndarray:
    """The studio map, float32 (H, 2H, 3) linear RGB: a dark surround, a little brighter
    upwards, and :data:`STUDIO_LIGHTS` as soft discs."""
    directions = _directions(height)
    up = np.clip(directions[..., 2:3], 0.0, 1.0)
    low, high = (np.asarray(c) for c in STUDIO_SURROUND)
    radiance = low + (high - low) * up
    for _name, azimuth, elevation, radius, colour in STUDIO_LIGHTS:
        radiance = radiance + _disc(directions, azimuth, elevation, radius)[..., None] * np.asarray(colour)
    return radiance.astype(np.float32)


def outdoor(height: int = DEFAULT_HEIGHT) -> np.ndarray:
    """The outdoor map, float32 (H, 2H, 3) linear RGB: a sky from :data:`SKY_HORIZON` to
    :data:`SKY_ZENITH`, :data:`GROUND` below the horizon (a little lighter towards it), and
    the :data:`SUN` as a small disc."""
    directions = _directions(height)
    z = directions[..., 2:3]
    up = np.sqrt(np.clip(z, 0.0, 1.0))  # the sky is pale over a wide band near the horizon
    sky = np.asarray(SKY_HORIZON) + (np.asarray(SKY_ZENITH) - np.asarray(SKY_HORIZON)) * up
    ground = np.asarray(GROUND) * (1.0 + np.clip(1.0 + 4.0 * z, 0.0, 1.0))
    radiance = np.where(z >= 0.0, sky, ground)
    azimuth, elevation, radius, colour = SUN
    radiance = radiance + _disc(directions, azimuth, elevation, radius)[..., None] * np.asarray(colour)
    return radiance.astype(np.float32)


#: Each map's generator, by name.
GENERATORS = {"studio": studio, "outdoor": outdoor}


def environment(name: str, height: int = DEFAULT_HEIGHT) -> np.ndarray:
    """The map called ``name`` (one of :data:`ENVIRONMENT_NAMES`) at ``height`` rows."""
    if name not in GENERATORS:
        raise ValueError(f"environment {name!r}: one of {', '.join(ENVIRONMENT_NAMES)} is required")
    return GENERATORS[name](height)


def write_environments(folder: str, height: int = DEFAULT_HEIGHT) -> dict[str, str]:
    """Write every map as ``folder/<name>.exr`` (half floats, zip; each file atomically);
    returns {name: path}. The header's metadata names the generator and the size."""
    os.makedirs(folder, exist_ok=True)
    written = {}
    for name in ENVIRONMENT_NAMES:
        path = os.path.join(folder, f"{name}.exr")
        meta = {"environment": name, "generator": "pipeline.figures.environments", "height": height}
        write_exr(path, {"render": environment(name, height)}, meta, half=("render",))
        written[name] = path
    return written
