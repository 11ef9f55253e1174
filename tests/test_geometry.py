"""The procedural shaderball: parameters, mesh soundness, crease-split normals, the UV
atlas (equal area, orientation, no overlap), seams placement, the cache, the camera."""

import dataclasses
import os

import numpy as np
import pytest
import trimesh

from geometry import Camera, ShaderballParams, build_shaderball, default_camera
from geometry.errors import GeometryError
from geometry.patches import band_frame, uv_signed_areas


def _face_areas(positions, faces):
    p = positions[faces].astype(np.float64)
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


# --------------------------------------------------------------------------- parameters


@pytest.mark.parametrize(
    "field, value",
    [
        ("shell_radius_m", 0.0),
        ("shell_thickness_m", 0.4),
        ("core_radius_m", 0.49),
        ("band_span_deg", 360.0),
        ("segments", 8),
        ("segments", 64.5),
        ("texture_repeats", 0),
        ("band_tilt_deg", float("nan")),
    ],
)
def test_check_names_field_value_and_range(field, value):
    with pytest.raises(GeometryError) as info:
        dataclasses.replace(ShaderballParams(), **{field: value})
    message = str(info.value)
    assert field in message and repr(value) in message and "allowed" in message


def test_band_must_clear_the_neck():
    with pytest.raises(GeometryError, match=r"band_tilt_deg: 55.0 is not allowed; allowed: a number in \[-50"):
        ShaderballParams(band_width_m=0.48, band_tilt_deg=55.0)
    ShaderballParams(band_width_m=0.48, band_tilt_deg=45.0)


def test_digest_is_stable_and_follows_every_parameter():
    base = ShaderballParams()
    assert base.digest() == ShaderballParams().digest()
    assert len(base.digest()) == 64
    digests = {base.digest()}
    for field in ShaderballParams.field_names():
        value = getattr(base, field)
        changed = dataclasses.replace(base, **{field: value + 1 if isinstance(value, int) else value * 1.01 + 0.001})
        digests.add(changed.digest())
    assert len(digests) == 1 + len(ShaderballParams.field_names())


# --------------------------------------------------------------------------- the mesh


def test_material_mesh_is_a_closed_consistently_wound_solid(ball):
    mesh = ball.material_mesh
    welded = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    assert welded.is_watertight
    assert welded.is_winding_consistent
    p = ball.params
    full = 4.0 / 3.0 * np.pi * (p.shell_radius_m**3 - p.inner_radius_m**3 + p.core_radius_m**3)
    # Positive (outward normals) and a little less than shell + core: the band is cut away.
    assert 0.85 * full < welded.volume < full


def test_winding_agrees_with_vertex_normals(ball):
    for mesh in (ball.material_mesh, ball.neutral_mesh, ball.ground_mesh):
        p = mesh.vertices[mesh.faces]
        geometric = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        shading = np.asarray(mesh.vertex_normals)[mesh.faces].sum(1)
        assert np.all(np.einsum("ij,ij->i", geometric, shading) > 0)
        assert np.allclose(np.linalg.norm(mesh.vertex_normals, axis=1), 1.0, atol=1e-6)


def test_normals_are_split_at_creases_and_only_there(ball):
    mesh = ball.material_mesh
    normals = np.asarray(mesh.vertex_normals)
    _, first, group = np.unique(np.asarray(mesh.vertices), axis=0, return_index=True, return_inverse=True)
    group = group.ravel()
    dots = np.einsum("ij,ij->i", normals, normals[first[group]])
    min_dot = np.ones(len(first))
    np.minimum.at(min_dot, group, dots)
    # Crease vertices exist (rim and end-face edges: about 90 degrees between the sides) ...
    assert np.sum(min_dot < 0.5) > 100
    # ... and coincident vertices either share their normal or sit on a real crease.
    assert np.all((min_dot > 1 - 1e-6) | (min_dot < 0.8))


def test_shading_normals_of_spheres_are_radial(ball):
    p = ball.params
    centre = np.array([0.0, 0.0, p.ball_centre_z_m])
    rel = np.asarray(ball.material_mesh.vertices, np.float64) - centre
    radius = np.linalg.norm(rel, axis=1)
    normals = np.asarray(ball.material_normals, np.float64)
    on_outer = np.abs(radius - p.shell_radius_m) < 1e-5
    cosine = np.einsum("ij,ij->i", normals[on_outer], rel[on_outer] / radius[on_outer, None])
    # Outer sphere vertices: radial, except those on the cut's edges (rim / end-face sides).
    assert np.mean(cosine > 1 - 1e-5) > 0.97
    assert np.all((cosine > 1 - 1e-5) | (np.abs(cosine) < 0.75))


def test_neck_and_pedestal_stand_on_the_ground_under_the_ball(ball):
    neutral = np.asarray(ball.neutral_mesh.vertices)
    p = ball.params
    assert neutral[:, 2].min() == pytest.approx(0.0, abs=1e-6)
    assert neutral[:, 2].max() < p.ball_centre_z_m - p.inner_radius_m * 0.9
    ground = np.asarray(ball.ground_mesh.vertices)
    assert np.all(ground[:, 2] == 0.0) and ground[:, 0].max() == pytest.approx(p.ground_half_size_m)


# --------------------------------------------------------------------------- the atlas


def test_atlas_has_uniform_texel_density(ball):
    mesh = ball.material_mesh
    uv = ball.material_uv.astype(np.float64)
    ratio = np.abs(uv_signed_areas(uv, mesh.faces)) / _face_areas(np.asarray(mesh.vertices), mesh.faces)
    median = np.median(ratio)
    assert ratio.min() > 0.97 * median and ratio.max() < 1.03 * median


def test_atlas_charts_are_not_mirrored(ball):
    # (dp/du, dp/dv, n) right-handed everywhere, so Mitsuba's tangent frame (dp/du, n x dp/du)
    # gives t along +v and tangent-space normal maps keep their y axis.
    mesh = ball.material_mesh
    assert np.all(uv_signed_areas(ball.material_uv.astype(np.float64), mesh.faces) > 0)


def test_atlas_fits_the_unit_square_without_overlap(ball):
    from PIL import Image, ImageDraw

    uv = ball.material_uv.astype(np.float64)
    assert uv.min() >= 0.0 and uv.max() <= 1.0
    size = 512  # xatlas pads 4 texels at 1024, so charts stay apart at 512
    coverage = np.zeros((size, size), np.int32)
    for chart in range(len(ball.chart_names)):
        image = Image.new("1", (size, size), 0)
        draw = ImageDraw.Draw(image)
        for tri in uv[ball.material_mesh.faces[ball.face_chart == chart]] * size:
            draw.polygon([tuple(pt) for pt in tri], fill=1)
        coverage += np.asarray(image, np.int32)
    assert coverage.max() == 1
    assert coverage.mean() > 0.4  # the charts fill a fair part of the atlas


def test_seams_off_creases_lie_on_the_back_or_on_the_core(ball):
    p = ball.params
    frame = band_frame(p)
    smooth = ball.seam_edges[~ball.seam_on_crease].astype(np.float64).reshape(-1, 3)
    local = (smooth - frame.centre) @ frame.axes
    radius = np.linalg.norm(local, axis=1)
    on_core = np.abs(radius - p.core_radius_m) < 1e-5
    # Shell seams off creases run on the back half (y' >= 0), never across the front.
    assert np.all(local[~on_core, 1] >= -1e-6)
    assert on_core.any() and (~on_core).any()
    assert ball.seam_on_crease.any()


# --------------------------------------------------------------------------- the cache


def test_cache_hit_returns_the_same_ball(ball, cache_dir):
    again = build_shaderball(ShaderballParams(), cache_dir=cache_dir)
    assert "load" in again.timings
    np.testing.assert_array_equal(again.material_mesh.vertices, ball.material_mesh.vertices)
    np.testing.assert_array_equal(again.material_uv, ball.material_uv)
    np.testing.assert_array_equal(again.seam_edges, ball.seam_edges)
    assert again.digest == ShaderballParams().digest()


def test_build_is_deterministic_and_a_damaged_entry_is_rebuilt(ball, tmp_path):
    other = build_shaderball(ShaderballParams(), cache_dir=str(tmp_path))
    assert "unwrap" in other.timings
    for name, path in other.mesh_files.items():
        with open(path, "rb") as a, open(ball.mesh_files[name], "rb") as b:
            assert a.read() == b.read(), name
    index = os.path.join(os.path.dirname(other.mesh_files["material"]), "shaderball.npz")
    with open(index, "rb") as fh:
        truncated = fh.read()[:200]  # a zip header, cut short
    with open(index, "wb") as fh:
        fh.write(truncated)
    rebuilt = build_shaderball(ShaderballParams(), cache_dir=str(tmp_path))
    assert "unwrap" in rebuilt.timings
    np.testing.assert_array_equal(rebuilt.face_chart, ball.face_chart)


def test_other_parameters_build_a_sound_ball(tmp_path):
    params = ShaderballParams(band_tilt_deg=-10.0, band_span_deg=220.0, segments=48, texture_repeats=2)
    ball = build_shaderball(params, cache_dir=str(tmp_path))
    welded = trimesh.Trimesh(ball.material_mesh.vertices, ball.material_mesh.faces, process=True)
    assert welded.is_watertight and welded.is_winding_consistent
    assert 1.0 < ball.material_uv.max() <= 2.0  # the atlas repeats twice


# --------------------------------------------------------------------------- the camera


def test_default_camera_frames_the_ball_from_the_front_and_above():
    params = ShaderballParams()
    camera = default_camera(params)
    assert isinstance(camera, Camera)
    assert camera.origin[1] < 0 and camera.origin[2] > params.ball_centre_z_m
    r = params.shell_radius_m
    box = np.array([[x, y, z] for x in (-r, r) for y in (-r, r) for z in (0.0, params.top_z_m)])
    xy, depth = camera.project(box, 400)
    assert np.all(depth > 0)
    assert np.all((xy > 0.02 * 400) & (xy < 0.98 * 400))
    # Tightly framed: the box spans most of the frame.
    assert np.ptp(xy[:, 1]) > 0.7 * 400
    right, up, _ = camera.basis()
    assert right[0] > 0.99 and up[2] > 0.9  # +x right, +z up in the image
