"""The emitter description: structure, irradiance match, in-place updates, placement in the scene."""

import json
import math

import numpy as np
import pytest

from pipeline.bench.probe_scene import BALL_CENTER, BALL_RADIUS, PRESETS, pixel_rays, probe_scene_dict, render
from pipeline.errors import USER_ERRORS
from pipeline.render.emitter import emitter_dicts, update_emitter_params
from pipeline.render.sky_probe import SunskyProbe
from sky import SUN_MODES, Light, sun_angles
from sky.emitter import (
    LUMINANCE_RGB,
    SPLIT_SUN_WEIGHT_RANGE,
    SUN_APERTURE_DEG,
    SUN_SOLID_ANGLE_SR,
    desaturate_to_nonnegative,
    split_sampling_weights,
)
from support import VARIANT

SIDE, TOP = PRESETS["side"], PRESETS["top"]


def _lum(img):
    return img @ LUMINANCE_RGB


def test_desaturation_keeps_luminance_and_removes_negatives():
    rgb = np.array([0.5, 0.1, -0.02])
    out, changed = desaturate_to_nonnegative(rgb)
    assert changed and out.min() >= 0.0 and out[2] == pytest.approx(0.0, abs=1e-15)
    assert LUMINANCE_RGB @ out == pytest.approx(LUMINANCE_RGB @ rgb)
    # hue order kept: still reddest in red
    assert out[0] > out[1] > out[2]
    same, changed = desaturate_to_nonnegative([0.3, 0.2, 0.1])
    assert not changed and np.array_equal(same, [0.3, 0.2, 0.1])
    black, changed = desaturate_to_nonnegative([-1.0, 0.1, 0.1])
    assert changed and np.array_equal(black, np.zeros(3))


def test_split_sampling_weights_follow_the_sun_and_are_never_equal():
    sky_power = np.array([0.5, 0.6, 0.7])
    weights = [split_sampling_weights(s * np.ones(3), sky_power)[0] for s in np.linspace(0.0, 20.0, 4001)]
    assert np.all(np.diff(weights) >= 0.0)  # more sun, more sun samples
    assert weights[0] == SPLIT_SUN_WEIGHT_RANGE[0] and weights[-1] == SPLIT_SUN_WEIGHT_RANGE[1]
    assert 1.0 not in weights  # equal weights take another path in Mitsuba (see the docstring)
    assert all(split_sampling_weights(s * np.ones(3), sky_power)[1] == 1.0 for s in (0.1, 1.0))


@pytest.mark.parametrize("sun", SUN_MODES)
def test_emitter_dicts_structure_and_record(mi, sun):
    light = Light(30.0, 200.0, 4.0)
    entries, record = emitter_dicts(light, sun=sun, variant=VARIANT)
    sky = entries["sky"]
    assert sky["type"] == "sunsky" and "to_world" not in sky  # z-up like the world
    np.testing.assert_allclose(sky["sun_direction"], light.direction)
    assert sky["turbidity"] == 4.0
    if sun == "sunsky":
        assert set(entries) == {"sky"} and sky["sun_scale"] == 1.0
    else:
        assert set(entries) == {"sky", "sun"} and sky["sun_scale"] == 0.0
        assert entries["sun"]["type"] == "directional"
        weights = (entries["sun"]["sampling_weight"], sky["sampling_weight"])
        assert weights[0] != weights[1]
        assert record["emitter"]["sampling_weights"] == {"sun": weights[0], "sky": weights[1]}
    json.dumps(record)
    assert record["emitter"]["sun"] == sun
    assert min(record["emitter"]["min_radiance_rgb"]) >= 0.0
    mi.load_dict({"type": "scene", **entries})  # loads


def test_split_sun_irradiance_is_disk_radiance_times_solid_angle(mi):
    """Integrate Mitsuba's own sun disk numerically and compare with the directional's irradiance."""
    light = Light(25.0, 40.0, 2.5)
    entries, _ = emitter_dicts(light, sun="split", variant=VARIANT)
    irradiance = np.array(entries["sun"]["irradiance"]["value"])
    probe = SunskyProbe(variant=VARIANT).set(light.direction, light.turbidity)
    half = math.radians(SUN_APERTURE_DEG / 2.0) * 1.2
    n = 240
    u = np.linspace(-half, half, n)
    a, b = np.meshgrid(u, u)
    d = light.direction
    e1 = np.cross([0.0, 0.0, 1.0], d)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    dirs = d + a.reshape(-1, 1) * e1 + b.reshape(-1, 1) * e2
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    integral = probe.radiance(dirs, "sun").sum(axis=0) * (u[1] - u[0]) ** 2
    np.testing.assert_allclose(irradiance, integral, rtol=0.02)
    assert SUN_SOLID_ANGLE_SR == pytest.approx(6.87e-5, rel=0.01)


def test_split_and_sunsky_light_the_ground_equally(mi):
    """Equal irradiance: mean ground radiance seen from above agrees to within noise and penumbra."""
    means = {}
    for sun in SUN_MODES:
        entries, _ = emitter_dicts(Light(50.0, 20.0, 3.0), sun=sun, variant=VARIANT)
        scene = mi.load_dict(probe_scene_dict(entries, **TOP, variant=VARIANT))
        means[sun] = _lum(render(mi, scene, TOP["spp"], 3)).mean()
    assert means["split"] == pytest.approx(means["sunsky"], rel=0.02)


def _render_kernel_hashes(mi, scene):
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clears
    mi.render(scene, spp=SIDE["spp"], seed=0)
    hashes = sorted(k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT)
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    return hashes


@pytest.mark.parametrize("sun", SUN_MODES)
def test_update_in_place_matches_a_fresh_scene_without_recompiling(mi, sun):
    a, b = Light(40.0, 10.0, 2.0), Light(12.0, 250.0, 8.5)
    entries_a, _ = emitter_dicts(a, sun=sun, variant=VARIANT)
    scene = mi.load_dict(probe_scene_dict(entries_a, material="glossy", **SIDE, variant=VARIANT))
    before = _render_kernel_hashes(mi, scene)
    params = mi.traverse(scene)
    record = update_emitter_params(params, b, sun=sun, variant=VARIANT)
    assert record["effective"] == b.to_dict()
    assert _render_kernel_hashes(mi, scene) == before
    updated = render(mi, scene, SIDE["spp"], 5)
    entries_b, record_b = emitter_dicts(b, sun=sun, variant=VARIANT)
    fresh = render(
        mi, mi.load_dict(probe_scene_dict(entries_b, material="glossy", **SIDE, variant=VARIANT)), SIDE["spp"], 5
    )
    assert np.array_equal(updated, fresh)
    assert record == record_b


def test_changing_sun_scale_recompiles(mi):
    """Why the sun mode is fixed per scene (and why updates refuse a mode change)."""
    entries, _ = emitter_dicts(Light(40.0, 10.0, 3.0), sun="sunsky", variant=VARIANT)
    scene = mi.load_dict(probe_scene_dict(entries, **SIDE, variant=VARIANT))
    before = _render_kernel_hashes(mi, scene)
    params = mi.traverse(scene)
    params["sky.sun_scale"] = 0.0
    params.update()
    assert _render_kernel_hashes(mi, scene) != before
    with pytest.raises(USER_ERRORS, match="sky.sun = 'sunsky' does not match"):
        update_emitter_params(params, Light(20.0, 0.0, 3.0), sun="sunsky", variant=VARIANT)


def test_unknown_sun_mode_and_variant_are_refused():
    with pytest.raises(USER_ERRORS, match="sky.sun"):
        emitter_dicts(Light(30.0, 0.0, 3.0), sun="disk", variant=VARIANT)
    for variant in ("llvm_ad_spectral", "scalar_rgb"):
        with pytest.raises(USER_ERRORS, match="RGB variant"):
            emitter_dicts(Light(30.0, 0.0, 3.0), variant=variant)


# --- placement: the highlight and the shadow fall where the direction says -------------------


@pytest.fixture(scope="module", params=SUN_MODES)
def top_scene(request, mi):
    entries, _ = emitter_dicts(Light(45.0, 0.0, 3.0), sun=request.param, variant=VARIANT)
    scene = mi.load_dict(probe_scene_dict(entries, **TOP, variant=VARIANT))
    origins, _ = pixel_rays(mi, scene)
    return request.param, scene, mi.traverse(scene), origins[..., 0], origins[..., 1]


def _angle_diff(a, b):
    return abs((a - b + 180.0) % 360.0 - 180.0)


@pytest.mark.parametrize("elevation, azimuth", [(40.0, 30.0), (60.0, 135.0), (30.0, 250.0), (50.0, 320.0)])
def test_shadow_and_highlight_follow_the_sun(mi, top_scene, elevation, azimuth):
    sun, scene, params, x, y = top_scene
    update_emitter_params(params, Light(elevation, azimuth, 3.0), sun=sun, variant=VARIANT)
    lum = _lum(render(mi, scene, TOP["spp"], 11))
    r = np.hypot(x, y)
    # shadow: dark ground pixels, centred opposite the sun's azimuth
    ground = r > 1.1 * BALL_RADIUS
    shadow = ground & (lum < 0.5 * np.percentile(lum[ground], 90))
    shadow_az = math.degrees(math.atan2(y[shadow].mean(), x[shadow].mean()))
    assert _angle_diff(shadow_az, azimuth + 180.0) < 5.0
    # highlight: fit L = n . v over the lit part of the diffuse ball; v points at the sun
    ball = r < 0.97 * BALL_RADIUS
    n = np.stack([x, y, np.sqrt(np.clip(1.0 - r**2, 0.0, 1.0))], axis=-1)[ball]
    lit = lum[ball] > 0.4 * lum[ball].max()
    v, *_ = np.linalg.lstsq(n[lit], lum[ball][lit], rcond=None)
    fit_el, fit_az = sun_angles(v)
    assert abs(fit_el - elevation) < 8.0
    assert _angle_diff(fit_az, azimuth) < 10.0


def test_shadow_moves_out_as_the_sun_sinks(mi, top_scene):
    sun, scene, params, x, y = top_scene
    distances = []
    for elevation in (70.0, 45.0, 30.0):
        update_emitter_params(params, Light(elevation, 90.0, 3.0), sun=sun, variant=VARIANT)
        lum = _lum(render(mi, scene, TOP["spp"], 1))
        ground = np.hypot(x, y) > 1.1
        shadow = ground & (lum < 0.5 * np.percentile(lum[ground], 90))
        distances.append(-y[shadow].mean())  # sun at +y, shadow towards -y
    assert distances[0] < distances[1] < distances[2]


@pytest.mark.parametrize("azimuth, brighter", [(0.0, "right"), (180.0, "left")])
def test_azimuth_0_lights_the_ball_from_the_image_right(mi, azimuth, brighter):
    """docs/conventions.md: camera on -y looking +y, image +x to the right."""
    entries, _ = emitter_dicts(Light(20.0, azimuth, 3.0), variant=VARIANT)
    scene = mi.load_dict(probe_scene_dict(entries, **SIDE, variant=VARIANT))
    origins, directions = pixel_rays(mi, scene)
    # pixels whose primary ray hits the ball
    oc = origins - np.array(BALL_CENTER)
    b = np.sum(oc * directions, axis=-1)
    c = np.sum(oc * oc, axis=-1) - BALL_RADIUS**2
    on_ball = b * b - c > 0.05
    lum = _lum(render(mi, scene, SIDE["spp"], 2))
    n = SIDE["resolution"]
    cols = np.arange(n)[None, :].repeat(n, 0)
    right = lum[on_ball & (cols >= n // 2)].mean()
    left = lum[on_ball & (cols < n // 2)].mean()
    assert (right > 1.5 * left) if brighter == "right" else (left > 1.5 * right)
