"""The G-buffer (pixel centres, cache), the camera model against Mitsuba's rays, the
seam share, and the bilinear lookup's conventions."""

import dataclasses

import numpy as np
import pytest

from geometry import default_camera
from pipeline.errors import ShaderballError
from pipeline.render.gbuffer import (
    compute_gbuffer,
    facing_mask,
    gbuffer_path,
    intersection_scene,
    load_gbuffer,
    pixel_centre_rays,
    seam_band,
    seam_share,
    view_directions,
)
from pipeline.render.raster import bilinear_lookup, decode_normal, encode_normal_texture, project, project_material
from pipeline.render.scene import BALL_SHAPE_ID
from pipeline.store.exr import read_exr
from support import VARIANT


@pytest.fixture(scope="session")
def camera():
    return default_camera()


@pytest.fixture(scope="session")
def gbuffer96(ball, camera, cache_dir, mi):
    return load_gbuffer(ball, camera, 96, cache_dir=cache_dir, variant=VARIANT)


def test_gbuffer_holds_the_ball_at_pixel_centres(gbuffer96, ball):
    gb = gbuffer96
    assert gb.uv.shape == (96, 96, 2) and gb.normal.shape == (96, 96, 3) and gb.mask.shape == (96, 96)
    assert gb.uv.dtype == np.float32 and gb.mask.dtype == bool
    assert 0.2 < gb.mask.mean() < 0.5
    assert np.allclose(np.linalg.norm(gb.normal[gb.mask], axis=1), 1.0, atol=1e-5)
    assert np.all(gb.uv[~gb.mask] == 0) and np.all(gb.normal[~gb.mask] == 0)
    uv = gb.uv[gb.mask]
    assert uv.min() >= 0 and uv.max() <= ball.material_uv.max() + 1e-6
    # The ball sits in the upper middle of the picture; the corners see no ball.
    assert not gb.mask[0, 0] and not gb.mask[-1, -1] and gb.mask[30, 48]
    # Almost every shading normal faces the camera (a few silhouette pixels may not).
    assert facing_mask(gb).sum() >= gb.mask.sum() - 3


def test_gbuffer_cache_round_trip_and_key(gbuffer96, ball, camera, cache_dir):
    path = gbuffer_path(ball, camera, 96, VARIANT, cache_dir)
    image = read_exr(path)
    assert set(image.layers) == {"uv", "normal", "mask", "depth"}
    assert image.meta["geometry"] == ball.digest and image.meta["resolution"] == 96
    again = load_gbuffer(ball, camera, 96, cache_dir=cache_dir, variant=VARIANT)
    np.testing.assert_array_equal(again.uv, gbuffer96.uv)
    np.testing.assert_array_equal(again.mask, gbuffer96.mask)
    assert gbuffer_path(ball, camera, 97, VARIANT, cache_dir) != path
    moved = dataclasses.replace(camera, fov_deg=camera.fov_deg + 1)
    assert gbuffer_path(ball, moved, 96, VARIANT, cache_dir) != path


def test_cached_gbuffer_equals_a_fresh_one(gbuffer96, ball, camera):
    fresh = compute_gbuffer(ball, camera, 96, variant=VARIANT)
    np.testing.assert_array_equal(fresh.uv, gbuffer96.uv)
    np.testing.assert_array_equal(fresh.normal, gbuffer96.normal)
    np.testing.assert_array_equal(fresh.mask, gbuffer96.mask)


@pytest.mark.parametrize("resolution", [15, 4097, 64.0, True])
def test_resolution_is_checked(ball, camera, resolution):
    with pytest.raises(ShaderballError, match="resolution"):
        compute_gbuffer(ball, camera, resolution, variant=VARIANT)


def test_camera_model_matches_mitsuba_rays(ball, camera, mi):
    resolution = 40
    scene = intersection_scene(ball, camera, resolution, variant=VARIANT)
    ray = pixel_centre_rays(scene, resolution, variant=VARIANT)
    origin = np.array(ray.o, dtype=np.float64).T
    direction = np.array(ray.d, dtype=np.float64).T
    np.testing.assert_allclose(direction, view_directions(camera, resolution).reshape(-1, 3), atol=2e-6)
    # Mitsuba starts the rays on the near plane, on the line through the camera's origin.
    offset = origin - np.asarray(camera.origin)
    assert np.all(np.linalg.norm(offset, axis=1) < 0.1)
    np.testing.assert_allclose(np.cross(offset, direction), 0.0, atol=1e-5)
    xy, depth = camera.project(origin + 3.0 * direction, resolution)
    j, i = np.meshgrid(np.arange(resolution), np.arange(resolution))
    expected = np.stack([j.ravel() + 0.5, i.ravel() + 0.5], 1)
    np.testing.assert_allclose(xy, expected, atol=1e-3)
    assert np.all(depth > 0)


def test_mitsuba_tangent_frame_follows_v(ball, camera, mi):
    # Mitsuba's shading frame is (s ~ dp/du, t = n x s, n); with unmirrored charts t points
    # along +v, so a tangent-space normal map's +y means +v (down the texture image).
    import drjit as dr

    scene = intersection_scene(ball, camera, 48, variant=VARIANT)
    si = scene.ray_intersect(pixel_centre_rays(scene, 48, variant=VARIANT))
    ball_shape = next(s for s in scene.shapes() if s.id() == BALL_SHAPE_ID)
    on_ball = np.array(si.is_valid() & (si.shape == mi.ShapePtr(ball_shape)), bool)
    t_dot_dpdv = np.array(dr.dot(si.sh_frame.t, si.dp_dv))
    assert on_ball.sum() > 300
    assert np.all(t_dot_dpdv[on_ball] > 0)


def test_seam_share_is_small_and_mostly_on_creases(gbuffer96, ball):
    everything = seam_share(gbuffer96, ball)
    smooth_only = seam_share(gbuffer96, ball, include_creases=False)
    assert 0.0 < smooth_only < everything < 0.35
    band = seam_band(gbuffer96, ball)
    assert not np.any(band & ~gbuffer96.mask)
    # A wider band takes in more pixels.
    assert seam_share(gbuffer96, ball, px=4) > everything


# --------------------------------------------------------------------------- lookup conventions


def test_lookup_at_texel_centres_returns_texels():
    rng = np.random.default_rng(0)
    tex = rng.random((5, 7, 3)).astype(np.float32)
    i, j = np.meshgrid(np.arange(5), np.arange(7), indexing="ij")
    uv = np.stack([(j + 0.5) / 7, (i + 0.5) / 5], -1).astype(np.float32)
    np.testing.assert_allclose(bilinear_lookup(tex, uv), tex, atol=1e-6)
    # Row 0 sits at small v: no flip.
    assert np.allclose(bilinear_lookup(tex, np.array([[0.5 / 7, 0.5 / 5]], np.float32))[0], tex[0, 0], atol=1e-6)


def test_lookup_is_bilinear_and_repeats():
    tex = np.array([[0.0, 1.0], [2.0, 4.0]], np.float32)
    # Midway between the four texel centres.
    assert bilinear_lookup(tex, np.array([[0.5, 0.5]], np.float32))[0, 0] == pytest.approx(1.75)
    # Between texel (0, 1) and its repeated neighbour (0, 0): u = 1.0 wraps.
    assert bilinear_lookup(tex, np.array([[1.0, 0.25]], np.float32))[0, 0] == pytest.approx(0.5)
    uv = np.random.default_rng(1).random((50, 2)).astype(np.float32)
    np.testing.assert_allclose(bilinear_lookup(tex, uv), bilinear_lookup(tex, uv + 3.0), atol=2e-6)


def test_normal_encoding_round_trip():
    flat = np.zeros((4, 4, 3), np.float32)
    flat[..., 2] = 1.0
    np.testing.assert_array_equal(decode_normal(encode_normal_texture(flat)), flat)
    rng = np.random.default_rng(2)
    n = rng.normal(size=(8, 3)) + [0, 0, 3]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(decode_normal(encode_normal_texture(n)), n, atol=1e-6)


@dataclasses.dataclass(frozen=True)
class _Maps:  # stands in for materials.MaterialMaps (same field names)
    diffuse: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    normal: np.ndarray


def test_project_material_shapes_and_fill(gbuffer96):
    rng = np.random.default_rng(3)
    normal = rng.normal(size=(16, 16, 3)) * 0.3 + [0, 0, 1]
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    maps = _Maps(
        diffuse=rng.random((16, 16, 3)),
        specular=rng.random((16, 16, 3)),
        roughness=rng.random((16, 16)),
        normal=normal,
    )
    out = project_material(maps, gbuffer96)
    mask = gbuffer96.mask
    assert set(out) == {"diffuse", "specular", "roughness", "normal", "mask"}
    assert out["roughness"].shape == (96, 96) and out["normal"].shape == (96, 96, 3)
    assert all(v.dtype == np.float32 for v in out.values())
    np.testing.assert_array_equal(out["mask"], mask.astype(np.float32))
    assert np.allclose(np.linalg.norm(out["normal"][mask], axis=1), 1.0, atol=1e-6)
    assert np.all(out["normal"][mask][:, 2] > 0)
    for key in ("diffuse", "specular", "roughness", "normal"):
        assert np.all(out[key][~mask] == 0)
    np.testing.assert_array_equal(out["diffuse"], project(maps.diffuse, gbuffer96))
