"""The named parameters of the procedural shaderball, their ranges and their digest."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from geometry.errors import GeometryError

#: Bump when the construction, the charts or the cache layout change: old caches then miss.
GEOMETRY_CODE_VERSION = 3


@dataclass(frozen=True)
class ShaderballParams:
    """Sizes of the shaderball in metres, its cut-away band and its tessellation.

    World frame: z up, ground at z = 0, the ball centred on the z axis, the camera on -y.
    """

    #: Outer radius of the shell.
    shell_radius_m: float = 0.5
    #: Wall thickness of the shell; the inner surface has radius shell_radius_m - this.
    shell_thickness_m: float = 0.04
    #: Radius of the inner core revealed by the band.
    core_radius_m: float = 0.40
    #: Width of the cut-away band, measured along the band's normal.
    band_width_m: float = 0.30
    #: Tilt of the band about the view axis (y); positive rises to the image's right.
    band_tilt_deg: float = 20.0
    #: Angular extent of the cut around the band's axis, centred on the camera side (-y).
    band_span_deg: float = 180.0
    #: Radius of the pedestal disc standing on the ground.
    pedestal_radius_m: float = 0.32
    #: Height of the pedestal disc.
    pedestal_height_m: float = 0.05
    #: Radius of the neck joining the pedestal to the ball.
    neck_radius_m: float = 0.09
    #: Visible height of the neck between the pedestal's top and the ball's bottom.
    neck_height_m: float = 0.10
    #: Half the side of the square ground plane at z = 0 (long enough for low-sun shadows).
    ground_half_size_m: float = 50.0
    #: Vertices around a full circle; rings and rows follow from it.
    segments: int = 160
    #: How many times the texture repeats across the UV atlas (an integer keeps the
    #: atlas layout; larger values shrink the texture on the ball).
    texture_repeats: int = 1

    def __post_init__(self):
        """Raise GeometryError naming the field, its value and the allowed range."""
        _in_range("shell_radius_m", self.shell_radius_m, 0.05, 10.0)
        r = self.shell_radius_m
        _in_range("shell_thickness_m", self.shell_thickness_m, 0.005 * r, 0.3 * r)
        inner = r - self.shell_thickness_m
        _in_range("core_radius_m", self.core_radius_m, 0.3 * r, 0.98 * inner)
        _in_range("band_width_m", self.band_width_m, 0.05 * r, 1.2 * self.core_radius_m)
        _in_range("pedestal_radius_m", self.pedestal_radius_m, 0.2 * r, 2.0 * r)
        _in_range("pedestal_height_m", self.pedestal_height_m, 0.005, 0.5 * r)
        _in_range("neck_radius_m", self.neck_radius_m, 0.05 * r, min(0.5 * r, 0.9 * self.pedestal_radius_m))
        _in_range("neck_height_m", self.neck_height_m, 0.0, 2.0 * r)
        _in_range("band_tilt_deg", self.band_tilt_deg, -60.0, 60.0)
        # The band must stay clear of the circle where the neck enters the shell.
        neck = self.neck_radius_m
        edge = math.acos(0.5 * self.band_width_m / r)  # band edge's angle from the band's pole
        clear = math.degrees(edge - math.atan2(neck, math.sqrt(r * r - neck * neck)))
        _in_range("band_tilt_deg", self.band_tilt_deg, -min(60.0, clear), min(60.0, clear))
        _in_range("band_span_deg", self.band_span_deg, 60.0, 300.0)
        _in_range("ground_half_size_m", self.ground_half_size_m, 4.0 * r, 1.0e4)
        _in_range("segments", self.segments, 32, 1024, integer=True)
        _in_range("texture_repeats", self.texture_repeats, 1, 64, integer=True)

    @property
    def inner_radius_m(self) -> float:
        return self.shell_radius_m - self.shell_thickness_m

    @property
    def ball_centre_z_m(self) -> float:
        return self.pedestal_height_m + self.neck_height_m + self.shell_radius_m

    @property
    def top_z_m(self) -> float:
        return self.ball_centre_z_m + self.shell_radius_m

    def as_dict(self) -> dict:
        return asdict(self)

    def digest(self) -> str:
        """A stable SHA-256 of the parameters, the construction code and library versions.

        Anything that can change the mesh or its atlas is in it, so a cache entry keyed
        by it is never stale.
        """
        return hashlib.sha256(_canonical_json(digest_inputs(self)).encode()).hexdigest()

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


def digest_inputs(params: ShaderballParams) -> dict:
    import trimesh
    import xatlas

    return {
        "params": params.as_dict(),
        "code": GEOMETRY_CODE_VERSION,
        "versions": {
            "numpy": np.__version__,
            "trimesh": trimesh.__version__,
            "xatlas": getattr(xatlas, "__version__", "unknown"),
        },
    }


def _canonical_json(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def _in_range(name: str, value, lo: float, hi: float, *, integer: bool = False) -> None:
    kind = "an integer" if integer else "a number"
    ok = (
        isinstance(value, int) and not isinstance(value, bool)
        if integer
        else (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value))
    )
    if not ok or not (lo <= value <= hi):
        raise GeometryError(f"geometry.{name}: {value!r} is not allowed; allowed: {kind} in [{lo:g}, {hi:g}]")
