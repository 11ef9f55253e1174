"""The hard-case policy: the elevation floor, its record, and the floor table against live Mitsuba."""

import json

import numpy as np
import pytest

from pipeline.errors import USER_ERRORS
from sky import SAFE_ELEVATION_DEG, Light, LightingPolicy, apply_policy, elevation_floor_deg, sun_direction
from sky.policy import FLOOR_TABLE, measured_floor_deg
from support import VARIANT


def test_floor_table_covers_1_to_10_without_gaps():
    assert FLOOR_TABLE[0][0] == 1.0 and FLOOR_TABLE[-1][1] == 10.0
    for (_, b0, _), (a1, _, _) in zip(FLOOR_TABLE[:-1], FLOOR_TABLE[1:]):
        assert b0 == a1
    assert all(0.0 < f < 10.0 for _, _, f in FLOOR_TABLE)


def test_floor_lookup_takes_the_larger_neighbour_at_knots():
    assert measured_floor_deg(9.75) == max(f for a, b, f in FLOOR_TABLE if a <= 9.75 <= b)
    assert measured_floor_deg(10.0) == FLOOR_TABLE[-1][2]
    assert elevation_floor_deg(3.0) == pytest.approx(measured_floor_deg(3.0) + 0.1)
    assert elevation_floor_deg(3.0, LightingPolicy(floor="off")) == 0.0
    assert SAFE_ELEVATION_DEG == pytest.approx(max(f for _, _, f in FLOOR_TABLE) + 0.1)


def test_low_sun_is_raised_to_the_floor_and_recorded():
    light = Light(elevation_deg=0.0, azimuth_deg=123.0, turbidity=3.0)
    effective, record = apply_policy(light)
    floor = elevation_floor_deg(3.0)
    assert effective == Light(floor, 123.0, 3.0)
    assert record["changed"] is True
    assert record["requested"] == light.to_dict()
    assert record["effective"] == effective.to_dict()
    (action,) = record["actions"]
    assert action["field"] == "elevation_deg" and action["from"] == 0.0 and action["to"] == floor
    assert "floor" in action["reason"]
    assert json.loads(json.dumps(record)) == record


def test_lights_at_or_above_the_floor_are_untouched():
    for t in (1.0, 3.0, 7.3, 10.0):
        for el in (elevation_floor_deg(t), 10.0, 45.0, 90.0):
            light = Light(el, 10.0, t)
            effective, record = apply_policy(light)
            assert effective == light
            assert record["changed"] is False and record["actions"] == []


def test_policy_off_changes_nothing_and_says_so():
    effective, record = apply_policy(Light(0.0, 0.0, 3.0), LightingPolicy(floor="off"))
    assert effective.elevation_deg == 0.0 and not record["changed"]
    assert "warning" in record


def test_policy_settings_are_checked():
    with pytest.raises(USER_ERRORS, match="sky.policy.floor"):
        LightingPolicy(floor="clamp")
    with pytest.raises(USER_ERRORS, match="sky.policy.margin_deg"):
        LightingPolicy(margin_deg=-1.0)


# --- the floor table against Mitsuba 3.9's sunsky itself -------------------------------------


@pytest.fixture(scope="module")
def probe(mi):
    from pipeline.render.sky_probe import SunskyProbe

    return SunskyProbe(VARIANT)


def _min_radiance(probe, elevation_deg, turbidity):
    probe.set(sun_direction(elevation_deg, 0.0), turbidity, parts=("both",))
    return probe.min_radiance("both")


def test_emitter_is_nonnegative_from_the_floor_up(probe):
    rng = np.random.default_rng(2024)
    turbidities = np.concatenate([[1.0, 3.0, 7.3, 9.99, 10.0], rng.uniform(1.0, 10.0, 40)])
    for t in turbidities:
        floor = elevation_floor_deg(t)
        for el in (floor, floor + rng.uniform(0.0, 3.0), rng.uniform(floor, 90.0), 90.0):
            assert np.all(_min_radiance(probe, el, t) >= 0.0), (el, t)


def test_below_the_floor_the_raw_emitter_is_negative_or_black(probe):
    """The facts the policy exists for (this fails if a new Mitsuba fixes them)."""
    # the sun's blue channel, low clear sun
    probe.set(sun_direction(2.0, 0.0), 1.0)
    assert probe.sun_disk_radiance()[2] < 0.0
    # the sky at the horizon, hazy sky
    assert _min_radiance(probe, 6.0, 10.0).min() < 0.0
    # black at exactly 0 degrees
    probe.set(sun_direction(0.0, 0.0), 3.0)
    assert probe.sun_disk_radiance().max() == 0.0 and probe.sky_power().max() == 0.0
    # the sun's table stops changing below 2 degrees
    a = probe.set(sun_direction(0.5, 0.0), 3.0).sun_disk_radiance()
    b = probe.set(sun_direction(1.9, 0.0), 3.0).sun_disk_radiance()
    np.testing.assert_allclose(a, b, rtol=1e-4)


@pytest.mark.parametrize("turbidity", [0.99, 10.01])
def test_raw_sunsky_rejects_turbidity_outside_1_10(mi, turbidity):
    from pipeline.render.sky_probe import sunsky_dict

    with pytest.raises(RuntimeError, match="out of range"):
        mi.load_dict(sunsky_dict(sun_direction(30.0, 0.0), turbidity))
