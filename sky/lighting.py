"""The lighting of one sample (``Light``) and the ranges a spec samples from (``LightingRanges``).

Both are frozen dataclasses that check their own values on construction and raise
:class:`sky.errors.SkyError` naming the field, the value and what is
allowed. Accepted values may still be moved by the hard-case policy
(:mod:`sky.policy`) before rendering; that is recorded, never silent.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from sky.directions import sun_direction
from sky.errors import SkyError

#: Mitsuba's sunsky refuses turbidity outside this range when a scene loads.
TURBIDITY_RANGE = (1.0, 10.0)
#: A daylight sun: on or above the horizon, up to the zenith. Mitsuba's sunsky is
#: black for a sun at or below the horizon, so negative elevations are refused.
ELEVATION_RANGE = (0.0, 90.0)
#: Azimuth ranges are intervals of at most one turn, anywhere on the real line.
MAX_AZIMUTH_SPAN_DEG = 360.0

SCHEMES = ("uniform_hemisphere", "uniform_angles", "stratified", "sobol")


def _fail(field: str, value, allowed: str) -> SkyError:
    return SkyError(f"{field} = {value!r} is not allowed: {allowed}")


def _check_number(field: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise _fail(field, value, "expected a number")
    if not math.isfinite(float(value)):
        raise _fail(field, value, "expected a finite number")
    return float(value)


def _check_in(field: str, value, lo: float, hi: float, unit: str = "") -> float:
    x = _check_number(field, value)
    if not lo <= x <= hi:
        raise _fail(field, value, f"allowed range is [{lo:g}, {hi:g}]{unit}")
    return x


def _check_interval(field: str, value, lo: float, hi: float, unit: str = "") -> tuple[float, float]:
    try:
        a, b = value
    except (TypeError, ValueError):
        raise _fail(field, value, "expected a pair (lo, hi)") from None
    a = _check_in(f"{field}[0]", a, lo, hi, unit)
    b = _check_in(f"{field}[1]", b, lo, hi, unit)
    if a > b:
        raise _fail(field, value, "lo must not exceed hi")
    return a, b


@dataclass(frozen=True)
class Light:
    """One sun-and-sky lighting: where the sun is and how hazy the air is.

    ``elevation_deg`` in [0, 90] above the horizon, ``azimuth_deg`` any finite
    number (counter-clockwise from +x seen from above), ``turbidity`` in [1, 10].
    """

    elevation_deg: float
    azimuth_deg: float
    turbidity: float

    def __post_init__(self):
        self.check()

    def check(self, prefix: str = "light") -> None:
        _check_in(f"{prefix}.elevation_deg", self.elevation_deg, *ELEVATION_RANGE, " degrees")
        _check_number(f"{prefix}.azimuth_deg", self.azimuth_deg)
        _check_in(f"{prefix}.turbidity", self.turbidity, *TURBIDITY_RANGE)

    @property
    def direction(self) -> np.ndarray:
        """Unit vector towards the sun in the world frame, float64 (3,)."""
        return sun_direction(self.elevation_deg, self.azimuth_deg)

    def lighting_vector(self) -> np.ndarray:
        """The network's lighting input: (d_x, d_y, d_z, turbidity), float32 (4,)."""
        return np.concatenate([self.direction, [self.turbidity]]).astype(np.float32)

    def to_dict(self) -> dict:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> Light:
        return cls(**{k: data[k] for k in ("elevation_deg", "azimuth_deg", "turbidity")})


@dataclass(frozen=True)
class LightingRanges:
    """Where lights are sampled from.

    ``scheme`` picks the distribution (see docs/sky.md):

    - ``uniform_hemisphere`` (the paper's "random sun direction on the upper
      hemisphere"): uniform over the *solid angle* of the band
      elevation_deg x azimuth_deg, i.e. sin(elevation) and azimuth uniform;
    - ``uniform_angles``: elevation and azimuth uniform in degrees (denser near
      the zenith per steradian);
    - ``stratified``: the ``uniform_hemisphere`` density, Latin-hypercube
      stratified jointly over (sin elevation, azimuth, turbidity);
    - ``sobol``: the same density from a scrambled Sobol' sequence.

    Turbidity is uniform over ``turbidity`` in every scheme.
    """

    elevation_deg: tuple[float, float] = ELEVATION_RANGE
    azimuth_deg: tuple[float, float] = (0.0, 360.0)
    turbidity: tuple[float, float] = TURBIDITY_RANGE
    scheme: str = "uniform_hemisphere"

    def __post_init__(self):
        # Normalise lists from TOML/JSON into tuples so instances hash and compare.
        for name in ("elevation_deg", "azimuth_deg", "turbidity"):
            value = getattr(self, name)
            if isinstance(value, list):
                object.__setattr__(self, name, tuple(value))
        self.check()

    def check(self, prefix: str = "lighting") -> None:
        _check_interval(f"{prefix}.elevation_deg", self.elevation_deg, *ELEVATION_RANGE, " degrees")
        a, b = _check_interval(f"{prefix}.azimuth_deg", self.azimuth_deg, -math.inf, math.inf)
        if b - a > MAX_AZIMUTH_SPAN_DEG:
            raise _fail(f"{prefix}.azimuth_deg", self.azimuth_deg, "span hi - lo must be at most 360 degrees")
        _check_interval(f"{prefix}.turbidity", self.turbidity, *TURBIDITY_RANGE)
        if self.scheme not in SCHEMES:
            raise _fail(f"{prefix}.scheme", self.scheme, f"one of {', '.join(SCHEMES)}")

    def to_dict(self) -> dict:
        return {
            "elevation_deg": list(map(float, self.elevation_deg)),
            "azimuth_deg": list(map(float, self.azimuth_deg)),
            "turbidity": list(map(float, self.turbidity)),
            "scheme": self.scheme,
        }
