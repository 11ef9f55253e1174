"""Each effect the build leaves out of a scene leaves the image unchanged (pipeline.render.renderer's EffectPlan).

Small renders (64x64, 32 spp, fixed seeds) of one material with and without the effect:
bit-identical where the arithmetic is the same, equal to float32 rounding where it differs
only in rounding, and within noise (a Z-test on the moment integrator's luminance
variance, pipeline.bench.compare.compare_renders) otherwise. The specular lobe of a zero specular
albedo is the exception the build keeps on purpose: its test shows the image changes.
Render-time savings are measured by `shaderball bench --effects` (docs/build.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from materials.maps import MaterialMaps, UniformMaterial, tilt_normal
from pipeline.bench.compare import compare_renders, render_moments
from pipeline.bench.effects import bitmap_bsdf, flat_normal_map_bsdf, with_material_bsdf
from support import VARIANT

RESOLUTION, SPP, SEED = 64, 32, 11

DIELECTRIC = UniformMaterial((0.5, 0.3, 0.2), (0.04, 0.04, 0.04), 0.4)
METAL = UniformMaterial((0.0, 0.0, 0.0), (0.95, 0.64, 0.54), 0.3)
NO_SPECULAR = UniformMaterial((0.5, 0.5, 0.5), (0.0, 0.0, 0.0), 0.15)


@pytest.fixture(scope="module")
def scene_of(mi):
    """scene_of(maps, effects=None, bsdf=None) -> a loaded Mitsuba scene of the build's kind."""
    from geometry import build_shaderball, default_camera
    from pipeline.render.renderer import RenderSettings, scene_dict
    from sky import Light

    ball, camera = build_shaderball(), default_camera()
    settings = RenderSettings(resolution=RESOLUTION, spp=SPP, variant=VARIANT)
    light = Light(35.0, 300.0, 3.0)

    def make(maps, effects=None, bsdf=None):
        desc = scene_dict(ball, camera, maps, light, settings, effects)[0]
        return mi.load_dict(with_material_bsdf(desc, bsdf) if bsdf is not None else desc)

    return make


def _render(mi, scene, seed=SEED):
    return render_moments(mi, scene, SPP, seed)


# ---------------------------------------------------------------- the comparison itself


def test_z_test_passes_two_seeds_of_one_scene_and_catches_a_small_change(mi, scene_of):
    """Calibration of compare_renders: independent noise passes, a 10% albedo change does not."""
    maps = DIELECTRIC.to_maps(1)
    scene = scene_of(maps)
    a, b = _render(mi, scene, SEED), _render(mi, scene, SEED + 1)
    same_seed = compare_renders(a, _render(mi, scene, SEED))
    assert same_seed["identical"]  # fixed seed: the render is deterministic
    two_seeds = compare_renders(a, b)
    assert not two_seeds["identical"] and two_seeds["within_noise"], two_seeds
    darker = UniformMaterial((0.45, 0.27, 0.18), DIELECTRIC.specular, DIELECTRIC.roughness)
    changed = compare_renders(a, _render(mi, scene_of(darker.to_maps(1)), SEED + 1))
    assert not changed["within_noise"], changed


# ---------------------------------------------------------------- the omissions the build makes


def test_constant_parameters_render_as_replicated_bitmap_textures(mi, scene_of):
    """textured -> constant. Not bit-identical: bilinear weights of four equal texels sum to 1
    only up to rounding, so a bitmap returns the constant to within ~1 ulp (measured max
    |diff| ~1e-7 of the image's maximum); the path samples are the same."""
    maps = DIELECTRIC.to_maps(1)
    constant = _render(mi, scene_of(maps))
    textured = _render(mi, scene_of(maps, bsdf=bitmap_bsdf(maps, 4, variant=VARIANT)))
    c = compare_renders(textured, constant)
    assert c["identical"] or c["rounding"], c
    assert c["within_noise"], c


def test_no_normal_map_renders_as_a_flat_normal_map(mi, scene_of):
    """normal map -> none. Mitsuba's normalmap rebuilds the frame from dp/du (Gram-Schmidt)
    instead of the mesh's shading frame: the same frame to rounding, so equal to rounding."""
    maps = DIELECTRIC.to_maps(1)
    plain = _render(mi, scene_of(maps))
    from pipeline.render.bsdf import bsdf_dict

    wrapped = _render(
        mi, scene_of(maps, bsdf=flat_normal_map_bsdf(bsdf_dict(maps, variant=VARIANT), 4, variant=VARIANT))
    )
    c = compare_renders(wrapped, plain)
    assert c["identical"] or c["rounding"], c
    assert c["within_noise"], c


def test_zero_diffuse_albedo_without_the_diffuse_lobe_is_bit_identical(mi, scene_of):
    """diffuse lobe -> none. With d = 0 the lobe adds exact zeros to value and pdf, and the
    lobe-selection probability is f / (f + 0) = 1 exactly: the same arithmetic."""
    from pipeline.render.renderer import plan_effects

    maps = METAL.to_maps(1)
    plan = plan_effects(maps)
    assert not plan.diffuse_lobe
    with_lobe = _render(mi, scene_of(maps, dataclasses.replace(plan, diffuse_lobe=True)))
    without = _render(mi, scene_of(maps, plan))
    assert np.array_equal(with_lobe.image, without.image)


def test_a_white_specular_also_drops_the_diffuse_lobe_bit_identically(mi, scene_of):
    """d (1 - s) = 0 for s = 1 even with d > 0: the lobe is zero there too."""
    from pipeline.render.renderer import plan_effects

    maps = UniformMaterial((0.6, 0.6, 0.6), (1.0, 1.0, 1.0), 0.3).to_maps(1)
    plan = plan_effects(maps)
    assert not plan.diffuse_lobe
    with_lobe = _render(mi, scene_of(maps, dataclasses.replace(plan, diffuse_lobe=True)))
    assert np.array_equal(with_lobe.image, _render(mi, scene_of(maps, plan)).image)


# ---------------------------------------------------------------- the omission the build does not make


def test_zero_specular_albedo_still_needs_the_specular_lobe(mi, scene_of):
    """Why the specular lobe is never dropped: Schlick's F = s + (1 - s) 2^(...) goes to 1 at
    grazing angles even for s = 0, so leaving the lobe out darkens the ball's rim far beyond
    noise."""
    from pipeline.render.renderer import plan_effects

    maps = NO_SPECULAR.to_maps(1)
    plan = plan_effects(maps)
    assert plan.specular_lobe
    with_lobe = render_moments(mi, scene_of(maps, plan), 4 * SPP, SEED)
    without = render_moments(mi, scene_of(maps, dataclasses.replace(plan, specular_lobe=False)), 4 * SPP, SEED)
    c = compare_renders(with_lobe, without)
    assert not c["within_noise"], c
    assert c["z_total"] > 12.0, c  # the lobe adds light: the image with it is brighter (measured +18)
    assert with_lobe.image.mean() > without.image.mean()


# ---------------------------------------------------------------- the plan and the scene agree


def _svbrdf_maps() -> MaterialMaps:
    from materials import sample_svbrdf
    from pipeline.dataset.plan import seeded_rng

    return sample_svbrdf(seeded_rng(5), "tiles", 16)


CASES = {
    "uniform flat": (DIELECTRIC.to_maps(1), dict(textured=False, normal_map=False, diffuse_lobe=True)),
    "uniform tilted": (
        UniformMaterial((0.5,) * 3, (0.04,) * 3, 0.5, tilt_normal(15.0, 40.0)).to_maps(1),
        dict(textured=False, normal_map=True, diffuse_lobe=True),
    ),
    "metal": (METAL.to_maps(1), dict(textured=False, normal_map=False, diffuse_lobe=False)),
    "no specular": (NO_SPECULAR.to_maps(1), dict(textured=False, normal_map=False, diffuse_lobe=True)),
    "svbrdf": (None, dict(textured=True, normal_map=True, diffuse_lobe=True)),
}


@pytest.mark.parametrize("name", list(CASES))
def test_plan_effects_and_the_scene_dict_agree(name):
    from geometry import build_shaderball, default_camera
    from pipeline.render.renderer import RenderSettings, plan_effects, scene_dict
    from pipeline.render.scene import BALL_SHAPE_ID
    from sky import Light

    maps, expected = CASES[name]
    maps = maps if maps is not None else _svbrdf_maps()
    plan = plan_effects(maps)
    assert {k: getattr(plan, k) for k in expected} == expected
    assert plan.specular_lobe
    settings = RenderSettings(resolution=RESOLUTION, spp=SPP, variant=VARIANT)
    desc, _, effects = scene_dict(build_shaderball(), default_camera(), maps, Light(40.0, 10.0, 3.0), settings)
    assert effects == plan
    bsdf = desc[BALL_SHAPE_ID]["bsdf"]
    assert (bsdf["type"] == "normalmap") == plan.normal_map
    inner = bsdf["bsdf"] if plan.normal_map else bsdf
    textures = [inner[k] for k in ("diffuse", "specular", "roughness")]
    kinds = {t["type"] if isinstance(t, dict) else "float" for t in textures}
    assert kinds == {"bitmap"} if plan.textured else "bitmap" not in kinds
    assert inner["diffuse_lobe"] == plan.diffuse_lobe and inner["specular_lobe"] == plan.specular_lobe
