"""The fixed pinhole camera that frames the shaderball in a square image.

Conventions (docs/conventions.md): the camera is on the -y side of the ball looking
towards +y, slightly above it; in the image +x is right and +z is up. ``fov_deg`` is
the full horizontal field of view, which for the square images used here is also
the vertical one (Mitsuba's ``perspective`` with ``fov_axis = "x"``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from geometry.params import ShaderballParams

#: Distance from the camera to the point it looks at, metres.
DEFAULT_DISTANCE_M = 4.5
#: Elevation of the camera above the point it looks at, degrees.
DEFAULT_ELEVATION_DEG = 12.0
#: Fraction of the half field of view left free around the shaderball's bounding box.
DEFAULT_MARGIN = 0.10


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: world-space origin, look-at target and up vector, horizontal fov."""

    origin: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 30.0

    def as_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit (right, up, forward) vectors of the image plane in world space."""
        forward = np.subtract(self.target, self.origin).astype(np.float64)
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        return right, up, forward

    def project(self, points: np.ndarray, resolution: int) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel coordinates (x right, y down; pixel centres at i + 0.5) of points.

        Returns ``(xy, depth)``: ``xy`` (N, 2) and the depth along the view axis (N,),
        negative for points behind the camera.
        """
        right, up, forward = self.basis()
        rel = np.asarray(points, np.float64) - np.asarray(self.origin, np.float64)
        depth = rel @ forward
        scale = 1.0 / math.tan(math.radians(self.fov_deg) / 2.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            sx = (rel @ right) / depth * scale
            sy = (rel @ up) / depth * scale
        xy = np.stack([(1.0 + sx) * 0.5 * resolution, (1.0 - sy) * 0.5 * resolution], axis=-1)
        return xy, depth


def default_camera(params: ShaderballParams | None = None) -> Camera:
    """The camera that frames the shaderball of ``params`` (default sizes if None).

    The ball-and-pedestal bounding box framed by :func:`frame_box`.
    """
    params = params or ShaderballParams()
    return frame_box(max(params.shell_radius_m, params.pedestal_radius_m), params.top_z_m)


def frame_box(half_width: float, top: float) -> Camera:
    """The camera that frames the box |x|, |y| <= ``half_width``, 0 <= z <= ``top``.

    It looks at the centre of the box from DEFAULT_DISTANCE_M away,
    DEFAULT_ELEVATION_DEG above the horizontal, on the -y side, with the narrowest field
    of view that keeps the box DEFAULT_MARGIN inside the frame. One rule for every
    object (the shaderball and the others, :func:`geometry.objects.object_camera`).
    """
    target = np.array([0.0, 0.0, 0.5 * top])
    elevation = math.radians(DEFAULT_ELEVATION_DEG)
    origin = target + DEFAULT_DISTANCE_M * np.array([0.0, -math.cos(elevation), math.sin(elevation)])
    probe = Camera(tuple(origin), tuple(target), (0.0, 0.0, 1.0), 90.0)
    right, up, forward = probe.basis()
    corners = np.array(
        [[x, y, z] for x in (-half_width, half_width) for y in (-half_width, half_width) for z in (0.0, top)]
    )
    rel = corners - origin
    depth = rel @ forward
    tan_half = max(np.max(np.abs(rel @ right) / depth), np.max(np.abs(rel @ up) / depth))
    fov = 2.0 * math.degrees(math.atan(tan_half * (1.0 + DEFAULT_MARGIN)))
    return Camera(
        origin=tuple(round(float(c), 6) for c in origin),
        target=tuple(round(float(c), 6) for c in target),
        up=(0.0, 0.0, 1.0),
        fov_deg=round(fov, 3),
    )
