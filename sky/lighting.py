"""The lighting of one sample (``Light``) and the ranges a spec samples from (``LightingRanges``).

Both are frozen dataclasses that check their own values on construction and raise
:class:`sky.errors.SkyError` naming the field, the value and what is allowed
(``<field>: <value> is not allowed; <allowed>``). Accepted values may still be moved by the
hard-case policy (:mod:`sky.policy`) before rendering; that is recorded, never silent.

The ranges below are declared here once: the spec's ``[lighting]`` rules, `shaderball
render`'s and `infer`'s sun options and `shaderball serve`'s API and sliders are built from
them (``pipeline`` reads them; this package imports nothing of it).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from sky.directions import sun_direction
from sky.errors import number_allowed, pair_allowed, refusal

#: Turbidity: Mitsuba's sunsky refuses turbidity outside this range when a scene loads.
TURBIDITY_RANGE = (1.0, 10.0)
#: Sun elevation, degrees: a daylight sun, on or above the horizon, up to the zenith.
#: Mitsuba's sunsky is black for a sun at or below the horizon, so negative elevations are refused.
ELEVATION_RANGE = (0.0, 90.0)
#: One sun's azimuth, degrees counter-clockwise from +x seen from above: any angle of the
#: turn below 0 or the turn above 360 (a slip of a turn stays valid).
AZIMUTH_RANGE = (-360.0, 720.0)
#: Where a sampled azimuth range lies: within one turn either side of 0 ...
AZIMUTH_BOUNDS = (-360.0, 360.0)
#: ... and at most one turn wide.
MAX_AZIMUTH_SPAN_DEG = 360.0
#: One whole turn: the azimuths a spec samples by default, and a slider's.
AZIMUTH_TURN = (0.0, 360.0)

SCHEMES = ("uniform_hemisphere", "uniform_angles", "stratified", "sobol")


def _check_in(field: str, value, bounds: tuple[float, float]) -> float:
    """``value`` as a float in ``bounds``; refused otherwise (booleans and strings too)."""
    lo, hi = bounds
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise refusal(field, value, number_allowed(lo, hi))
    x = float(value)
    if not (math.isfinite(x) and lo <= x <= hi):
        raise refusal(field, value, number_allowed(lo, hi))
    return x


def _check_interval(
    field: str, value, bounds: tuple[float, float], max_span: float | None = None
) -> tuple[float, float]:
    """``value`` as a closed interval (lo, hi) within ``bounds``; refused otherwise."""
    allowed = pair_allowed(*bounds, max_span)
    try:
        a, b = value
    except (TypeError, ValueError):
        raise refusal(field, value, allowed) from None
    a = _check_in(f"{field}[0]", a, bounds)
    b = _check_in(f"{field}[1]", b, bounds)
    if a > b:
        raise refusal(field, value, f"{allowed} (lo {a:g} > hi {b:g}: the range is inverted)")
    if max_span is not None and b - a > max_span:
        raise refusal(field, value, f"{allowed} (span {b - a:g})")
    return a, b


@dataclass(frozen=True)
class Light:
    """One sun-and-sky lighting: where the sun is and how hazy the air is.

    ``elevation_deg`` in :data:`ELEVATION_RANGE` above the horizon, ``azimuth_deg`` in
    :data:`AZIMUTH_RANGE` (counter-clockwise from +x seen from above), ``turbidity`` in
    :data:`TURBIDITY_RANGE`.
    """

    elevation_deg: float
    azimuth_deg: float
    turbidity: float

    def __post_init__(self):
        _check_in("light.elevation_deg", self.elevation_deg, ELEVATION_RANGE)
        _check_in("light.azimuth_deg", self.azimuth_deg, AZIMUTH_RANGE)
        _check_in("light.turbidity", self.turbidity, TURBIDITY_RANGE)

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
    azimuth_deg: tuple[float, float] = AZIMUTH_TURN
    turbidity: tuple[float, float] = TURBIDITY_RANGE
    scheme: str = "uniform_hemisphere"

    def __post_init__(self):
        # Normalise lists from TOML/JSON into tuples so instances hash and compare.
        for name in ("elevation_deg", "azimuth_deg", "turbidity"):
            value = getattr(self, name)
            if isinstance(value, list):
                object.__setattr__(self, name, tuple(value))
        _check_interval("lighting.elevation_deg", self.elevation_deg, ELEVATION_RANGE)
        _check_interval("lighting.azimuth_deg", self.azimuth_deg, AZIMUTH_BOUNDS, MAX_AZIMUTH_SPAN_DEG)
        _check_interval("lighting.turbidity", self.turbidity, TURBIDITY_RANGE)
        if self.scheme not in SCHEMES:
            raise refusal("lighting.scheme", self.scheme, "one of " + ", ".join(f'"{s}"' for s in SCHEMES))

    def to_dict(self) -> dict:
        return {
            "elevation_deg": list(map(float, self.elevation_deg)),
            "azimuth_deg": list(map(float, self.azimuth_deg)),
            "turbidity": list(map(float, self.turbidity)),
            "scheme": self.scheme,
        }
