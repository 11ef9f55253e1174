"""The hard-case sweep: every (elevation, turbidity) of the issue, three materials, both sun modes.

Rejected requests raise ShaderballError naming the field; accepted ones render with
no NaN, Inf or negative pixel, are never black, and the record says what the
policy did. One scene per (material, sun mode), moved between lights in place.
"""

import json

import numpy as np
import pytest

from pipeline.bench.probe_scene import MATERIALS, PRESETS, probe_scene_dict, render
from pipeline.bench.sky_floor import SWEEP_ELEVATIONS_DEG, SWEEP_TURBIDITIES
from pipeline.errors import USER_ERRORS
from pipeline.render.emitter import emitter_dicts, update_emitter_params
from sky import SUN_MODES, Light, LightingPolicy, elevation_floor_deg
from support import VARIANT

SIDE = PRESETS["side"]

#: Towards the camera's side (front light), so the near-mirror ball shows the sun's reflection.
AZIMUTH_DEG = 260.0
ACCEPTED = [(e, t) for e in SWEEP_ELEVATIONS_DEG for t in SWEEP_TURBIDITIES if e >= 0.0 and 1.0 <= t <= 10.0]
REJECTED = [(e, t) for e in SWEEP_ELEVATIONS_DEG for t in SWEEP_TURBIDITIES if (e, t) not in ACCEPTED]


def test_sweep_partition():
    assert len(ACCEPTED) == 9 * 3 and len(REJECTED) == 11 * 5 - 27
    assert SWEEP_ELEVATIONS_DEG == (-5.0, -1e-4, 0.0, 0.5, 1.9, 2.0, 3.0, 10.0, 45.0, 89.999, 90.0)
    assert SWEEP_TURBIDITIES == (0.99, 1.0, 3.0, 10.0, 10.01)


@pytest.mark.parametrize("elevation, turbidity", REJECTED)
def test_rejected_requests_name_the_field(elevation, turbidity):
    with pytest.raises(USER_ERRORS) as info:
        Light(elevation, AZIMUTH_DEG, turbidity)
    message = str(info.value)
    if not 1.0 <= turbidity <= 10.0 and elevation >= 0.0:
        assert "light.turbidity" in message and "from 1 to 10" in message
    else:
        assert "light.elevation_deg" in message and "from 0 to 90" in message


def _scene(mi, material, sun):
    entries, _ = emitter_dicts(Light(45.0, AZIMUTH_DEG, 3.0), sun=sun, variant=VARIANT)
    scene = mi.load_dict(probe_scene_dict(entries, material=material, **SIDE, variant=VARIANT))
    return scene, mi.traverse(scene)


@pytest.mark.slow
@pytest.mark.parametrize("sun", SUN_MODES)
@pytest.mark.parametrize("material", sorted(MATERIALS))
def test_accepted_requests_render_finite_nonnegative_and_recorded(mi, material, sun):
    scene, params = _scene(mi, material, sun)
    for i, (elevation, turbidity) in enumerate(ACCEPTED):
        record = update_emitter_params(params, Light(elevation, AZIMUTH_DEG, turbidity), sun=sun, variant=VARIANT)
        image = render(mi, scene, SIDE["spp"], 1000 + i)
        case = (material, sun, elevation, turbidity)
        assert np.all(np.isfinite(image)), case
        assert image.min() >= 0.0, case
        assert image.mean() > 1e-4, case  # never the black emitter of a sun at 0 degrees
        # the record says what the policy did
        assert json.loads(json.dumps(record)) == record
        floor = elevation_floor_deg(turbidity)
        assert record["requested"] == {"elevation_deg": elevation, "azimuth_deg": AZIMUTH_DEG, "turbidity": turbidity}
        assert record["changed"] == (elevation < floor), case
        assert record["effective"]["elevation_deg"] == max(elevation, floor)
        assert record["effective"]["turbidity"] == turbidity
        if record["changed"]:
            assert record["actions"][0]["field"] == "elevation_deg"
        assert min(record["emitter"]["min_radiance_rgb"]) >= 0.0


@pytest.mark.slow
def test_without_the_policy_the_sweep_does_go_negative_and_black(mi):
    """The control: with the floor off, Mitsuba's raw emitter gives what the policy prevents."""
    off = LightingPolicy(floor="off")
    scene, params = _scene(mi, "near_mirror", "sunsky")
    record = update_emitter_params(params, Light(0.5, AZIMUTH_DEG, 1.0), sun="sunsky", policy=off, variant=VARIANT)
    assert record["emitter"]["min_radiance_rgb"][2] < 0.0  # the sun's blue channel
    assert render(mi, scene, SIDE["spp"], 1).min() < 0.0
    update_emitter_params(params, Light(0.0, AZIMUTH_DEG, 3.0), sun="sunsky", policy=off, variant=VARIANT)
    assert render(mi, scene, SIDE["spp"], 1).max() == 0.0


def test_split_sun_is_desaturated_when_the_floor_is_off(mi):
    """Without the floor the directional sun would be negative in blue: the split keeps it >= 0."""
    _, record = emitter_dicts(Light(1.0, 0.0, 1.0), sun="split", policy=LightingPolicy(floor="off"), variant=VARIANT)
    adjusted = record["emitter"]["sun_irradiance_adjusted"]
    assert adjusted is not None and adjusted["from"][2] < 0.0
    assert min(record["emitter"]["sun_irradiance_rgb"]) >= 0.0
