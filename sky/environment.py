"""HDR environment maps as a light: the record of one, its conventions, its sampling.

An environment light is a lat-long (equirectangular) HDR image, ``width == 2 * height``,
that surrounds the scene at infinity. This module is the pure side of it (numpy and the
standard library): which files are maps (:func:`list_environment_files`), what a sample
records (:class:`EnvironmentLight`), the lighting vector a network is given, and how
rotations are drawn (:func:`sample_rotations`). Reading the files and building Mitsuba's
``envmap`` emitter is :mod:`pipeline.render.envmap`.

**Conventions** (the world frame of docs/conventions.md: z up, the camera on the -y side
looking towards +y; azimuths counter-clockwise from +x seen from above):

- the map's top row is the zenith (+z) and its bottom row the nadir (-z); Mitsuba's
  ``envmap`` puts row ``i`` of ``H`` at the polar angle ``180 * i / (H - 1)`` degrees and
  column ``j`` of ``W`` at ``u = (j + 0.5) / W`` (measured: tests/test_environment_numerics.py);
- at ``rotation_deg = 0`` the map's centre (``u = 0.5`` on the horizon) lies **in front of
  the camera**, along world +y: the camera sees it behind the ball, as a photographer who
  stood where the camera stands saw it. ``u`` grows towards the viewer's right (+x), as the
  image reads when viewed from inside the sphere (no mirror image);
- so a column ``u`` looks towards the azimuth ``270 - 360 u + rotation_deg`` degrees:
  ``rotation_deg`` turns the whole map counter-clockwise about +z seen from above, and a
  bright spot at azimuth ``a`` moves to ``a + rotation_deg`` (:func:`map_direction`).

**The lighting vector** (:meth:`EnvironmentLight.lighting_vector`) has the sun's width, 4
numbers, so a network's input layer is the same for both lights: the unit direction of the
map's centre (``cos(90 + r), sin(90 + r), 0``; like the sun's, a world direction, and it
turns with the map) and ``log2(scale)`` (exposure in stops, the way intensity is perceived;
0 for an unscaled map). It does not say *which* map lit a sample: that is the record's
``sha256``.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sky.directions import sun_direction
from sky.errors import number_allowed, refusal
from sky.lighting import _check_in, _check_interval

#: File suffixes of environment maps (compared without regard to case).
ENVIRONMENT_SUFFIXES = (".exr", ".hdr")
#: Rotation of a map about +z, degrees counter-clockwise seen from above: one turn.
ROTATION_RANGE = (0.0, 360.0)
#: Radiance multiplier of a map: four decades either way (an HDRI's own exposure varies that much).
SCALE_RANGE = (1e-4, 1e4)
#: Azimuth, degrees, of the map's centre column at rotation 0: world +y, in front of the camera.
CENTRE_AZIMUTH_DEG = 90.0

_SHA256 = re.compile(r"[0-9a-f]{64}")


def map_azimuth_deg(u, rotation_deg: float = 0.0):
    """The world azimuth (degrees, not wrapped) that the map's column ``u`` in [0, 1] looks
    towards: ``270 - 360 u + rotation_deg`` (the module's conventions)."""
    return CENTRE_AZIMUTH_DEG + 180.0 - 360.0 * np.asarray(u, dtype=np.float64) + rotation_deg


def map_direction(u, v, rotation_deg: float = 0.0) -> np.ndarray:
    """The unit world direction that the map point (``u``, ``v``) in [0, 1]^2 looks towards
    (``v = 0`` the zenith, ``v = 1`` the nadir); arrays broadcast to (..., 3)."""
    elevation = 90.0 - 180.0 * np.asarray(v, dtype=np.float64)
    return sun_direction(elevation, map_azimuth_deg(u, rotation_deg))


def _check_file(path) -> str:
    allowed = f"an absolute path, or a base name as a record gives it, of a file ending in {' or '.join(ENVIRONMENT_SUFFIXES)}"
    if not isinstance(path, str) or not (os.path.isabs(path) or (path and os.path.basename(path) == path)):
        raise refusal("environment.file", path, allowed)
    if not path.lower().endswith(ENVIRONMENT_SUFFIXES):
        raise refusal("environment.file", path, allowed)
    return path


@dataclass(frozen=True)
class EnvironmentLight:
    """One environment lighting of a sample: which map (``file`` as given, absolute, or its base
    name as a sample's record gives it, and the
    SHA-256 ``digest`` of its bytes: the file is checked against it when rendered), turned by
    ``rotation_deg`` in :data:`ROTATION_RANGE` and multiplied by ``scale`` in
    :data:`SCALE_RANGE`. Checked on construction (:class:`sky.errors.SkyError`)."""

    file: str
    digest: str
    rotation_deg: float
    scale: float = 1.0

    def __post_init__(self):
        _check_file(self.file)
        if not isinstance(self.digest, str) or not _SHA256.fullmatch(self.digest):
            raise refusal("environment.sha256", self.digest, "64 lowercase hexadecimal digits (a SHA-256)")
        object.__setattr__(self, "rotation_deg", check_rotation(self.rotation_deg))
        object.__setattr__(self, "scale", check_scale(self.scale))

    def to_dict(self) -> dict:
        """The JSON record of a sample's lighting: the file's base name, not its path (a
        dataset moves between machines; the digest identifies the map)."""
        return {
            "source": "environment",
            "file": os.path.basename(self.file),
            "sha256": self.digest,
            "rotation_deg": float(self.rotation_deg),
            "scale": float(self.scale),
        }

    def centre_direction(self) -> np.ndarray:
        """Unit world direction of the map's centre (``u = 0.5`` on the horizon), float64 (3,)."""
        return sun_direction(0.0, CENTRE_AZIMUTH_DEG + self.rotation_deg)

    def lighting_vector(self) -> np.ndarray:
        """The network's lighting input: (centre direction x, y, z = 0, log2(scale)), float32 (4,)."""
        return np.concatenate([self.centre_direction(), [math.log2(self.scale)]]).astype(np.float32)


def _is_map(name: str) -> bool:
    return name.lower().endswith(ENVIRONMENT_SUFFIXES)


def _files_of(path: str) -> list[str]:
    """The maps ``path`` names: itself (a file), or its direct children that are (a folder),
    hidden files left out as the spec's folder rule leaves them out (macOS's ``._name.exr``)."""
    if os.path.isdir(path):
        return [
            os.path.join(path, name)
            for name in os.listdir(path)
            if not name.startswith(".") and _is_map(name) and os.path.isfile(os.path.join(path, name))
        ]
    if not os.path.isfile(path):
        raise refusal("environment.files", path, "an existing file or folder of environment maps")
    if not _is_map(path):
        raise refusal("environment.files", path, f"a file ending in {' or '.join(ENVIRONMENT_SUFFIXES)}")
    return [path]


def list_environment_files(paths: Sequence[str]) -> tuple[str, ...]:
    """The environment maps ``paths`` name, as sorted absolute paths without repeats: a file
    is taken as it is (refused unless it ends in one of :data:`ENVIRONMENT_SUFFIXES`), a
    folder gives its direct children that do (sub-folders are not searched: what a spec
    lights with is what its folder shows). A path that does not exist, or a list that finds
    no map, is refused. Sorted so that a plan indexes the same maps on every machine."""
    if isinstance(paths, str) or not isinstance(paths, Sequence):
        raise refusal("environment.files", paths, "a list of files or folders of environment maps")
    found: set[str] = set()
    for path in paths:
        if not isinstance(path, str) or not path:
            raise refusal("environment.files", path, "a path of a file or folder of environment maps")
        found.update(os.path.abspath(p) for p in _files_of(os.path.abspath(path)))
    if not found:
        raise refusal(
            "environment.files",
            list(paths),
            f"files or folders holding at least one {' or '.join(ENVIRONMENT_SUFFIXES)} map",
        )
    return tuple(sorted(found))


def sample_rotations(rng: np.random.Generator, n: int, rotation_range) -> np.ndarray:
    """``n`` rotations (degrees, float64) uniform in ``rotation_range``, a pair within
    :data:`ROTATION_RANGE`; ``lo + (hi - lo) * u``, IEEE operations only, so a plan holds
    the same bits on every machine. Deterministic given ``rng``."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be an integer >= 0, got {n!r}")
    lo, hi = _check_interval("environment.rotation_deg", rotation_range, ROTATION_RANGE)
    return lo + (hi - lo) * rng.random(int(n))


def check_scale(scale) -> float:
    """``scale`` as a float in :data:`SCALE_RANGE`, or a refusal naming ``environment.scale``."""
    return _check_in("environment.scale", scale, SCALE_RANGE)


#: What a scale allows, in the project's words (for a spec's field rule).
SCALE_ALLOWED = number_allowed(*SCALE_RANGE)


def check_rotation(rotation_deg) -> float:
    """``rotation_deg`` as a float in :data:`ROTATION_RANGE`, or a refusal naming ``environment.rotation_deg``."""
    return _check_in("environment.rotation_deg", rotation_deg, ROTATION_RANGE)
