"""Renders with the plugin: white furnace against the reference, and the lobe switches.

A sphere under a constant environment of radiance 1, seen by an orthographic
camera, direct lighting only (max_depth 2; a convex object never sees
itself): each pixel is then the directional albedo of the material at that
pixel's view angle, averaged over the pixel. The expected image is computed
from the numpy reference by quadrature, supersampled over each pixel.
"""

import numpy as np
import pytest

from materials import UniformMaterial
from materials.brdf_ref import MODELS, eval_brdf, eval_normal_mapped, spec_albedo_quadrature
from pipeline.render import bsdf as mitsuba_bsdf
from support import VARIANT
from support.material_cases import deschaintre_code_brdf

RES, RADIUS = 48, 0.95


@pytest.fixture(scope="module")
def mi(mi):
    mitsuba_bsdf.register(variant=VARIANT)
    return mi


def _render(mi, bsdf, *, spp=128, seed=3):
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True},
            "sensor": {
                "type": "orthographic",
                "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                "film": {
                    "type": "hdrfilm",
                    "width": RES,
                    "height": RES,
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "independent", "sample_count": spp},
            },
            "emitter": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
            "ball": {"type": "sphere", "radius": RADIUS, "bsdf": bsdf},
        }
    )
    return np.array(mi.render(scene, seed=seed), dtype=np.float64)


def _material(d, s, r, **options):
    return {
        "type": "shaderball_ct",
        "diffuse": {"type": "rgb", "value": [d] * 3},
        "specular": {"type": "rgb", "value": [s] * 3},
        "roughness": r,
        **options,
    }


def _expected(d, s, r, lobes=("diffuse", "specular"), sub=8, model="shaderball"):
    """Pixel-averaged directional albedo of the sphere image (radially symmetric)."""
    cos_nodes = np.linspace(0.0, 1.0, 65) ** 1.5
    a0, a1 = np.array(
        [spec_albedo_quadrature(r, c, np.array([0.0, 1.0]), n_theta=512, n_phi=128, model=model) for c in cos_nodes]
    ).T
    offsets = (np.arange(sub) + 0.5) / sub
    x = -1.0 + 2.0 * (np.arange(RES)[:, None] + offsets[None, :]).ravel() / RES
    xx, yy = np.meshgrid(x, x)
    rho2 = (xx**2 + yy**2) / RADIUS**2
    inside = rho2 < 1.0
    cos = np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0))
    total = np.zeros_like(cos)
    if "diffuse" in lobes:
        total += d * (1.0 - s)
    if "specular" in lobes:
        total += s * np.interp(cos, cos_nodes, a1) + (1.0 - s) * np.interp(cos, cos_nodes, a0)
    total = np.where(inside, total, 0.0)
    pixel = total.reshape(RES, sub, RES, sub).mean(axis=(1, 3))
    ring = (
        np.sqrt(
            ((np.arange(RES) + 0.5) / RES * 2 - 1)[None, :] ** 2 + ((np.arange(RES) + 0.5) / RES * 2 - 1)[:, None] ** 2
        )
        / RADIUS
    )
    return pixel, ring


def _assert_matches_in_rings(image, expected, ring, *, slack=2.5e-3):
    residual = image.mean(axis=-1) - expected
    edges = [0.0, 0.4, 0.6, 0.75, 0.85, 0.92, 0.97]  # inside the disk, away from the silhouette pixels
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (ring >= lo) & (ring < hi)
        sigma = residual[sel].std() / np.sqrt(sel.sum())
        assert abs(residual[sel].mean()) < 4 * sigma + slack, (lo, hi, residual[sel].mean(), sigma)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("d, s, r", [(0.5, 0.04, 0.2), (0.0, 1.0, 0.5), (0.9, 0.0, 0.1), (0.0, 1.0, 0.1)])
def test_white_furnace_render_matches_reference_albedo(mi, d, s, r, model):
    image = _render(mi, _material(d, s, r, model=model))
    expected, ring = _expected(d, s, r, model=model)
    assert np.all(np.isfinite(image)) and image.min() >= 0
    _assert_matches_in_rings(image, expected, ring)


@pytest.mark.parametrize("r, kept", [(0.05, 0.012), (0.1, 0.190), (0.15, 0.755)])
def test_floored_model_fails_the_white_furnace_by_design(mi, record_property, r, kept):
    """A mirror-like metal (d = 0, s = 1) in a white furnace: the default model keeps ~all the light
    at normal incidence, deschaintre2018 keeps only A1 of the docs' table (0.012, 0.19,
    0.76 at r = 0.05, 0.1, 0.15), by design: its floors cap GGX's peak."""
    centre = np.hypot(*np.meshgrid(np.arange(RES) + 0.5 - RES / 2, np.arange(RES) + 0.5 - RES / 2)) < 0.2 * RES / 2
    means = {}
    for model in MODELS:
        image = _render(mi, _material(0.0, 1.0, r, model=model)).mean(axis=-1)
        means[model] = float(image[centre].mean())  # within 11.5 degrees of normal incidence
    record_property(f"furnace_centre_r{r}", means)
    assert means["shaderball"] == pytest.approx(1.0, abs=5e-3)
    assert means["deschaintre2018"] == pytest.approx(kept, rel=0.03, abs=2e-3)
    lost = 1.0 - means["deschaintre2018"] / means["shaderball"]
    assert lost == pytest.approx(1.0 - kept, abs=0.03)


@pytest.mark.parametrize("model", MODELS)
def test_render_of_a_normal_map_seen_from_below_follows_the_convention(mi, model):
    """A plane with a constant normal map tilted away from a grazing viewer (n.v < 0 < n.l), lit by a
    directional light, through bsdf_dict as the renderer builds it: every pixel is the reference's
    eval_normal_mapped (the map's normal mirrored), not 0 (the normal as it is) and not Deschaintre
    et al.'s value (n.v clamped to 0)."""
    view = np.array([np.sin(np.radians(75.0)), 0.0, np.cos(np.radians(75.0))])  # towards the camera
    light = np.array([-0.3, 0.2, 0.93])
    light /= np.linalg.norm(light)
    tilt = np.radians(30.0)
    normal = np.array([-np.sin(tilt), 0.0, np.cos(tilt)])  # tilted away from the viewer
    assert view @ normal < 0 < light @ normal
    diffuse, specular, roughness = 0.05, 0.5, 0.3
    maps = UniformMaterial(
        diffuse=(diffuse,) * 3, specular=(specular,) * 3, roughness=roughness, normal=tuple(normal)
    ).to_maps(1)
    bsdf = mitsuba_bsdf.bsdf_dict(maps, model=model, variant=VARIANT)
    assert bsdf["type"] == "normalmap"
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True},
            "sensor": {
                "type": "orthographic",
                "to_world": mi.ScalarTransform4f().look_at(origin=(5 * view).tolist(), target=[0, 0, 0], up=[0, 1, 0])
                @ mi.ScalarTransform4f().scale([0.3, 0.3, 1.0]),
                "film": {"type": "hdrfilm", "width": 4, "height": 4, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                "sampler": {"type": "independent", "sample_count": 4},
            },
            "sun": {"type": "directional", "direction": (-light).tolist(), "irradiance": {"type": "rgb", "value": 1.0}},
            "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([10.0, 10.0, 1.0]), "bsdf": bsdf},
        }
    )
    image = np.array(mi.render(scene, seed=1), dtype=np.float64)
    # The rectangle's tangent frame: s = dp/du = +x, n = +z, so the map's normal is world (x, y, z).
    expected = eval_normal_mapped(view, light, normal, diffuse, specular, roughness, model=model)
    assert expected[0] > 1e-3
    np.testing.assert_allclose(image.reshape(-1, 3), np.broadcast_to(expected, (16, 3)), rtol=2e-3)
    assert np.all(eval_brdf(view, light, normal, diffuse, specular, roughness, model=model) == 0)
    theirs = deschaintre_code_brdf(view, light, normal, diffuse, specular, roughness)
    assert abs(theirs[0] / expected[0] - 1) > 0.1


def test_diffuse_lobe_off_is_bit_identical_when_diffuse_is_zero(mi):
    on = _render(mi, _material(0.0, 0.5, 0.3))
    off = _render(mi, _material(0.0, 0.5, 0.3, diffuse_lobe=False))
    assert np.array_equal(on, off)


def test_specular_lobe_off_at_zero_specular_loses_the_schlick_grazing_term(mi, record_property):
    """s = 0 does not switch the specular lobe off: F = 2^(...) > 0 and -> 1 at grazing v.h.

    Dropping it removes exactly the reference's A0 term, mostly near the silhouette.
    """
    d, r = 0.5, 0.2
    on = _render(mi, _material(d, 0.0, r))
    off = _render(mi, _material(d, 0.0, r, specular_lobe=False))
    expected_off, ring = _expected(d, 0.0, r, lobes=("diffuse",))
    expected_lost, _ = _expected(d, 0.0, r, lobes=("specular",))
    _assert_matches_in_rings(off, expected_off, ring)
    _assert_matches_in_rings(on - off, expected_lost, ring)
    lost = (on - off).mean() / on.mean()
    record_property("specular_zero_lobe_off_image_loss", float(lost))
    assert lost > 0.05  # ~7% of the whole image; up to ~40% of a pixel's value at the rim
