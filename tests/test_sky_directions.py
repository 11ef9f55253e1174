"""Direction conventions, the lighting vector and request validation (no Mitsuba)."""

import json
import math

import numpy as np
import pytest

from pipeline.errors import USER_ERRORS
from sky import Light, LightingRanges, normalize_azimuth, sun_angles, sun_direction


@pytest.mark.parametrize(
    "elevation, azimuth, expected",
    [
        (0.0, 0.0, (1.0, 0.0, 0.0)),  # from the image's right
        (0.0, 90.0, (0.0, 1.0, 0.0)),  # from behind the ball (backlight)
        (0.0, 180.0, (-1.0, 0.0, 0.0)),  # from the image's left
        (0.0, 270.0, (0.0, -1.0, 0.0)),  # from the camera's side
        (0.0, -90.0, (0.0, -1.0, 0.0)),
        (90.0, 123.0, (0.0, 0.0, 1.0)),  # zenith
        (30.0, 0.0, (math.sqrt(3) / 2, 0.0, 0.5)),
        (45.0, 45.0, (0.5, 0.5, math.sqrt(0.5))),
    ],
)
def test_sun_direction_known_values(elevation, azimuth, expected):
    d = sun_direction(elevation, azimuth)
    assert d.shape == (3,) and d.dtype == np.float64
    np.testing.assert_allclose(d, expected, atol=1e-12)


def test_sun_direction_is_unit_and_broadcasts():
    rng = np.random.default_rng(1)
    el = rng.uniform(-90, 90, size=(5, 7))
    az = rng.uniform(-720, 720, size=(5, 7))
    d = sun_direction(el, az)
    assert d.shape == (5, 7, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(d[..., 2], np.sin(np.radians(el)), atol=1e-12)


def test_round_trip_angles():
    rng = np.random.default_rng(2)
    el = rng.uniform(-89.9, 89.9, 1000)
    az = rng.uniform(-1000, 1000, 1000)
    el2, az2 = sun_angles(sun_direction(el, az))
    np.testing.assert_allclose(el2, el, atol=1e-9)
    assert np.all((az2 >= 0) & (az2 < 360))
    # compare on the circle
    np.testing.assert_allclose(np.cos(np.radians(az2 - az)), 1.0, atol=1e-12)


def test_sun_angles_scalars_and_non_unit_input():
    el, az = sun_angles([0.0, -2.0, 0.0])
    assert isinstance(el, float) and isinstance(az, float)
    assert el == pytest.approx(0.0) and az == pytest.approx(270.0)
    assert sun_angles([0.0, 0.0, 5.0]) == (90.0, 0.0)
    assert sun_angles([1.0, 0.0, 1.0])[0] == pytest.approx(45.0)


def test_azimuth_wraps_into_0_360():
    assert normalize_azimuth(-1e-17) == 0.0  # would be 360.0 with a bare modulo
    assert normalize_azimuth(360.0) == 0.0
    assert normalize_azimuth(-90.0) == 270.0
    assert sun_angles(sun_direction(10.0, -1e-13))[1] < 360.0


def test_lighting_vector_and_record():
    light = Light(elevation_deg=30.0, azimuth_deg=270.0, turbidity=4.5)
    v = light.lighting_vector()
    assert v.dtype == np.float32 and v.shape == (4,)
    np.testing.assert_allclose(v[:3], [0.0, -math.sqrt(3) / 2, 0.5], atol=1e-7)
    assert v[3] == np.float32(4.5)
    data = json.loads(json.dumps(light.to_dict()))
    assert Light.from_dict(data) == light


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(elevation_deg=-5.0, azimuth_deg=0.0, turbidity=3.0), "light.elevation_deg"),
        (dict(elevation_deg=-1e-4, azimuth_deg=0.0, turbidity=3.0), "light.elevation_deg"),
        (dict(elevation_deg=90.0001, azimuth_deg=0.0, turbidity=3.0), "light.elevation_deg"),
        (dict(elevation_deg=10.0, azimuth_deg=0.0, turbidity=0.99), "light.turbidity"),
        (dict(elevation_deg=10.0, azimuth_deg=0.0, turbidity=10.01), "light.turbidity"),
        (dict(elevation_deg=float("nan"), azimuth_deg=0.0, turbidity=3.0), "light.elevation_deg"),
        (dict(elevation_deg=10.0, azimuth_deg=float("inf"), turbidity=3.0), "light.azimuth_deg"),
        (dict(elevation_deg=10.0, azimuth_deg="north", turbidity=3.0), "light.azimuth_deg"),
    ],
)
def test_light_rejects_out_of_domain_with_field_value_and_range(kwargs, field):
    with pytest.raises(USER_ERRORS) as info:
        Light(**kwargs)
    message = str(info.value)
    assert field in message
    assert info.value.exit_code == 2


def test_light_error_names_value_and_range():
    """The project's one wording: ``<field>: <value> is not allowed; <allowed>``, the range sky's."""
    with pytest.raises(USER_ERRORS, match=r"^light\.turbidity: 10\.01 is not allowed; a finite number from 1 to 10$"):
        Light(10.0, 0.0, 10.01)
    with pytest.raises(
        USER_ERRORS, match=r"^light\.elevation_deg: -5\.0 is not allowed; a finite number from 0 to 90$"
    ):
        Light(-5.0, 0.0, 3.0)
    with pytest.raises(
        USER_ERRORS, match=r'^light\.azimuth_deg: "north" is not allowed; a finite number from -360 to 720$'
    ):
        Light(5.0, "north", 3.0)
    with pytest.raises(
        USER_ERRORS,
        match=r"^lighting\.azimuth_deg: \[-300, 200\] is not allowed; a pair .* <= 360 and hi - lo <= 360 \(span 500\)$",
    ):
        LightingRanges(azimuth_deg=(-300, 200))


def test_light_accepts_domain_edges():
    for el in (0.0, 90.0):
        for t in (1.0, 10.0):
            Light(el, 0.0, t)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(elevation_deg=(-1.0, 90.0)), "lighting.elevation_deg[0]"),
        (dict(elevation_deg=(10.0, 95.0)), "lighting.elevation_deg[1]"),
        (dict(elevation_deg=(50.0, 10.0)), "lighting.elevation_deg"),
        (dict(azimuth_deg=(0.0, 400.0)), "lighting.azimuth_deg"),
        (dict(turbidity=(0.5, 4.0)), "lighting.turbidity[0]"),
        (dict(turbidity=(2.0, 11.0)), "lighting.turbidity[1]"),
        (dict(turbidity=3.0), "lighting.turbidity"),
        (dict(scheme="halton"), "lighting.scheme"),
    ],
)
def test_ranges_reject_with_field(kwargs, field):
    with pytest.raises(USER_ERRORS) as info:
        LightingRanges(**kwargs)
    assert field in str(info.value)


def test_ranges_accept_lists_from_toml_and_serialise():
    r = LightingRanges(elevation_deg=[5, 80], azimuth_deg=[-180, 180], turbidity=[2, 6], scheme="sobol")
    assert r.elevation_deg == (5, 80)
    assert LightingRanges(**json.loads(json.dumps(r.to_dict()))) == r
