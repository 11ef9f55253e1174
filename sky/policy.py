"""The hard-case policy: what an accepted light becomes before Mitsuba renders it.

Two layers (docs/sky.md, "Hard cases"):

1. **Domain limits** (``Light.check``): turbidity outside [1, 10] and elevation
   outside [0, 90] degrees are refused with a SkyError naming the field.
2. **Elevation floor** (here): Mitsuba 3.9's RGB ``sunsky`` has negative radiance
   for low suns (the sun's blue channel below ~2.4 degrees; the sky at the
   horizon up to ~6.9 degrees at turbidity 10) and is black at 0 degrees. An
   accepted light whose elevation is below the floor measured for its turbidity
   is raised to that floor; direction azimuth and turbidity are kept. The render
   is then an unmodified Hosek-Wilkie render of the *effective* light, and the
   effective light is what the network is told (its lighting vector).

Raising the elevation, rather than clamping radiance, keeps the emitter exactly
the model's (no invented colours, no bias in the estimator) and keeps Mitsuba's
importance sampling of the sky consistent with what it evaluates. The price is
that the lowest suns are moved by up to a few degrees; every move is recorded.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from sky.errors import number_allowed, refusal
from sky.lighting import TURBIDITY_RANGE, Light

POLICY_NAME = "elevation-floor"
POLICY_VERSION = 1
#: What FLOOR_TABLE was measured on; regenerate with `scripts/sky_floor.py --table`.
FLOOR_MEASURED_ON = "mitsuba 3.9.1, llvm_ad_rgb, sunsky albedo 0.3, sun_aperture 0.5358, complex_sun false"

# fmt: off
#: (turbidity lo, turbidity hi, floor in degrees): over every turbidity in the
#: interval (measured every 0.05), the sun-and-sky radiance is >= 0 in all RGB
#: channels for every sun elevation from the floor up to 90 degrees.
FLOOR_TABLE = (
    (1.00, 1.25, 2.434),
    (1.25, 1.50, 2.469),
    (1.50, 1.75, 2.496),
    (1.75, 2.00, 2.520),
    (2.00, 2.25, 2.559),
    (2.25, 2.50, 2.602),
    (2.50, 2.75, 2.648),
    (2.75, 3.00, 2.695),
    (3.00, 3.25, 2.805),
    (3.25, 3.50, 2.934),
    (3.50, 3.75, 3.078),
    (3.75, 4.00, 3.254),
    (4.00, 4.25, 3.254),
    (4.25, 4.50, 3.242),
    (4.50, 4.75, 3.230),
    (4.75, 5.00, 3.215),
    (5.00, 5.25, 3.395),
    (5.25, 5.50, 3.609),
    (5.50, 5.75, 3.844),
    (5.75, 6.00, 4.125),
    (6.00, 6.25, 4.383),
    (6.25, 6.50, 4.531),
    (6.50, 6.75, 4.547),
    (6.75, 7.00, 4.512),
    (7.00, 7.25, 4.809),
    (7.25, 7.50, 4.812),
    (7.50, 7.75, 4.387),
    (7.75, 8.00, 2.793),
    (8.00, 8.25, 2.055),
    (8.25, 8.50, 2.309),
    (8.50, 8.75, 2.312),
    (8.75, 9.00, 2.223),
    (9.00, 9.25, 2.555),
    (9.25, 9.50, 3.145),
    (9.50, 9.75, 4.727),
    (9.75, 10.00, 6.914),
)
# fmt: on

FLOOR_MODES = ("measured", "off")
#: How far above the measured floor a raised sun goes, degrees.
MARGIN_RANGE = (0.0, 5.0)


@dataclass(frozen=True)
class LightingPolicy:
    """How accepted lights are made safe to render.

    ``floor``: ``measured`` raises low suns to the measured floor plus
    ``margin_deg``; ``off`` renders the request as is (diagnostics only: Mitsuba
    may then produce negative or black emitters, and the record says so).
    """

    floor: str = "measured"
    margin_deg: float = 0.1

    def __post_init__(self):
        if self.floor not in FLOOR_MODES:
            raise refusal("sky.policy.floor", self.floor, "one of " + ", ".join(f'"{m}"' for m in FLOOR_MODES))
        margin = self.margin_deg
        if (
            isinstance(margin, bool)
            or not isinstance(margin, (int, float))
            or not MARGIN_RANGE[0] <= margin <= MARGIN_RANGE[1]
        ):
            raise refusal("sky.policy.margin_deg", margin, number_allowed(*MARGIN_RANGE))

    def to_dict(self) -> dict:
        return {"floor": self.floor, "margin_deg": float(self.margin_deg)}


DEFAULT_POLICY = LightingPolicy()


def measured_floor_deg(turbidity: float) -> float:
    """The measured floor (no margin) for ``turbidity`` in [1, 10]; at a knot, the larger neighbour."""
    t = float(turbidity)
    lo, hi = TURBIDITY_RANGE
    if not lo <= t <= hi:
        raise refusal("turbidity", turbidity, number_allowed(lo, hi))
    return max(floor for a, b, floor in FLOOR_TABLE if a <= t <= b)


def elevation_floor_deg(turbidity: float, policy: LightingPolicy = DEFAULT_POLICY) -> float:
    """The lowest elevation the policy lets a light of this turbidity render at."""
    if policy.floor == "off":
        return 0.0
    return round(measured_floor_deg(turbidity) + policy.margin_deg, 6)


#: The floor (with the default margin) for every turbidity: a spec whose elevation
#: range starts here never has a light moved by the policy.
SAFE_ELEVATION_DEG = round(max(f for _, _, f in FLOOR_TABLE) + DEFAULT_POLICY.margin_deg, 6)


def apply_policy(light: Light, policy: LightingPolicy = DEFAULT_POLICY) -> tuple[Light, dict]:
    """(effective light, JSON-serialisable record of what was changed and why)."""
    floor = elevation_floor_deg(light.turbidity, policy)
    actions = []
    effective = light
    if light.elevation_deg < floor:
        effective = dataclasses.replace(light, elevation_deg=floor)
        actions.append(
            {
                "field": "elevation_deg",
                "from": float(light.elevation_deg),
                "to": float(floor),
                "reason": (
                    f"below the elevation floor {floor:g} deg for turbidity {light.turbidity:g}: "
                    "Mitsuba's RGB sunsky is black at 0 deg and has negative radiance "
                    "(sun blue channel, sky at the horizon) below the floor"
                ),
            }
        )
    record = {
        "policy": POLICY_NAME,
        "version": POLICY_VERSION,
        "settings": policy.to_dict(),
        "floor_measured_on": FLOOR_MEASURED_ON,
        "elevation_floor_deg": float(floor),
        "requested": light.to_dict(),
        "effective": effective.to_dict(),
        "changed": bool(actions),
        "actions": actions,
    }
    if policy.floor == "off":
        record["warning"] = "policy off: the emitter may have negative or zero radiance"
    return effective, record
