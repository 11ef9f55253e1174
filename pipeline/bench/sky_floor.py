"""Measure where Mitsuba's RGB ``sunsky`` goes negative, and regenerate the floor table.

``scripts/sky_floor.py`` prints the raw emitter's behaviour on the hard-case sweep and what
the policy does there (the table in docs/sky.md); ``scripts/sky_floor.py --table`` measures
the elevation floor per turbidity and prints the literal pasted into
``sky/policy.py`` (``FLOOR_TABLE``). Slow (minutes): it evaluates the emitter on
~26,000 directions at several thousand (elevation, turbidity) points.

The floor at turbidity T is the smallest sun elevation e such that, for every
sun elevation in [e, 90], the sun-and-sky radiance is >= 0 in every RGB channel
on every check direction (:func:`pipeline.render.sky_probe.hemisphere_check_directions`, dense
at the horizon, plus the sun's centre). Sun elevations are scanned every 0.25
deg up to 15 deg (then bisected), and every degree up to 90 at integer
turbidities; tests/test_sky_policy.py samples the rest at random.
"""

from __future__ import annotations

import logging

import numpy as np

from pipeline.errors import USER_ERRORS
from pipeline.render.sky_probe import SunskyProbe
from sky.directions import sun_direction
from sky.lighting import Light
from sky.policy import apply_policy

log = logging.getLogger(__name__)

SWEEP_ELEVATIONS_DEG = (-5.0, -1e-4, 0.0, 0.5, 1.9, 2.0, 3.0, 10.0, 45.0, 89.999, 90.0)
SWEEP_TURBIDITIES = (0.99, 1.0, 3.0, 10.0, 10.01)


def is_nonnegative(probe: SunskyProbe, elevation_deg: float, turbidity: float) -> bool:
    probe.set(sun_direction(elevation_deg, 0.0), turbidity, parts=("both",))
    return bool(np.all(probe.min_radiance() >= 0.0))


def measure_floor(
    probe: SunskyProbe,
    turbidity: float,
    coarse_step: float = 0.25,
    scan_top: float = 15.0,
    tol: float = 0.005,
    check_high: bool = True,
) -> float:
    """Smallest elevation (degrees) from which the emitter stays non-negative up to 90."""
    scan = list(np.arange(coarse_step, scan_top + 1e-9, coarse_step))
    if check_high:
        scan += list(np.arange(scan_top + 1.0, 90.0 + 1e-9, 1.0))
    negative = [e for e in scan if not is_nonnegative(probe, float(e), turbidity)]
    if not negative:
        return 0.0
    lo = float(max(negative))
    hi = lo + (coarse_step if lo < scan_top else 1.0)
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if is_nonnegative(probe, mid, turbidity):
            hi = mid
        else:
            lo = mid
    # The bisection assumes one sign change inside the last gap: confirm above hi.
    for e in np.arange(hi, lo + coarse_step + 1e-9, 0.01):
        if not is_nonnegative(probe, float(e), turbidity):
            return measure_floor(probe, turbidity, coarse_step / 5, scan_top, tol, check_high)
    return hi


def floor_table(probe: SunskyProbe, knots=np.arange(1.0, 10.01, 0.25), fine_step: float = 0.05):
    """Per interval [knots[i], knots[i+1]]: the largest floor measured at fine_step turbidities."""
    fine = np.round(np.arange(knots[0], knots[-1] + 1e-9, fine_step), 6)
    measured = {}
    for t in fine:
        measured[float(t)] = measure_floor(probe, float(t), check_high=float(t).is_integer())
        log.info("turbidity %.2f: floor %.3f deg", t, measured[float(t)])
    rows = []
    for a, b in zip(knots[:-1], knots[1:]):
        inside = [v for t, v in measured.items() if a - 1e-9 <= t <= b + 1e-9]
        rows.append((float(a), float(b), max(inside)))
    return rows, measured


def sweep_rows(probe: SunskyProbe):
    """Per sweep point: the raw emitter at the request, and what the policy does with it."""

    rows = []
    for t in SWEEP_TURBIDITIES:
        for e in SWEEP_ELEVATIONS_DEG:
            row = {"turbidity": t, "elevation_deg": e}
            try:
                effective, record = apply_policy(Light(e, 0.0, t))
            except USER_ERRORS as exc:
                row["outcome"] = f"rejected: {str(exc).split(' is not allowed')[0]}"
                rows.append(row)
                continue
            probe.set(sun_direction(e, 0.0), t)
            row["raw_sun_rgb"] = probe.sun_disk_radiance()
            row["raw_sky_min_rgb"] = probe.min_radiance("sky")
            row["outcome"] = (
                f"raised to {effective.elevation_deg:g} deg" if record["changed"] else "rendered as requested"
            )
            rows.append(row)
    return rows


def sweep_markdown(rows) -> str:
    """:func:`sweep_rows` as the markdown table of docs/sky.md."""
    fmt = lambda v: "(" + ", ".join(f"{x:.3g}" for x in v) + ")"  # noqa: E731
    lines = ["| turbidity | elevation deg | raw sun disk RGB | raw sky min RGB | policy |", "|---|---|---|---|---|"]
    for row in rows:
        if "raw_sun_rgb" not in row:
            lines.append(f"| {row['turbidity']} | {row['elevation_deg']} | | | {row['outcome']} |")
            continue
        lines.append(
            f"| {row['turbidity']} | {row['elevation_deg']} | {fmt(row['raw_sun_rgb'])} | "
            f"{fmt(row['raw_sky_min_rgb'])} | {row['outcome']} |"
        )
    return "\n".join(lines)


def floor_table_literal(rows) -> str:
    """:func:`floor_table`'s rows as the literal pasted into sky/policy.py."""
    lines = ["FLOOR_TABLE = (  # (turbidity lo, turbidity hi, floor degrees), measured"]
    lines += [f"    ({a:.2f}, {b:.2f}, {v:.3f})," for a, b, v in rows]
    lines.append(")")
    return "\n".join(lines)
