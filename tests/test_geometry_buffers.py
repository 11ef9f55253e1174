"""Geometry buffers beside the maps (``geometry_normal``, ``depth``), and a scene and G-buffer
that take any object, the shaderball's unchanged.

- a small build whose spec asks for the geometry layers stores them (float32 with half maps),
  validate passes, and their values are the G-buffer's: unit normals inside the mask, depths
  inside the object's bounding sphere, 0 outside;
- the G-buffer's depth equals an independent computation from Mitsuba's own intersection
  (origin + t * direction projected on the camera's forward axis);
- maps projected on an object other than the shaderball (a torus made here, no pedestal)
  equal Mitsuba's texture evaluation at the pixel centres, as tests/test_gbuffer_projection.py
  shows for the shaderball;
- the default spec stores what it stored and keeps its digest; the shaderball's scene
  entries are today's, entry for entry.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass

import numpy as np
import pytest
import trimesh

from geometry import default_camera
from geometry.ply import write_ply
from pipeline.check.inspect import content_issues, map_value_issues, sample_expectations
from pipeline.dataset.spec import GEOMETRY_LAYERS, MAP_LAYERS
from pipeline.dataset.spec_file import parse_spec, parse_spec_text, spec_digest
from pipeline.render.gbuffer import (
    SURFACES,
    compute_gbuffer,
    facing_mask,
    first_hits,
    gbuffer_path,
    intersection_scene,
    load_gbuffer,
    pixel_centre_rays,
)
from pipeline.render.raster import project, project_material
from pipeline.render.scene import (
    BALL_SHAPE_ID,
    GROUND_BSDF,
    GROUND_SHAPE_ID,
    NEUTRAL_BSDF,
    NEUTRAL_SHAPE_ID,
    bitmap_texture,
    sensor_dict,
    shape_dicts,
)
from pipeline.store import exr
from support import SMOKE, VARIANT

#: manifests/smoke.toml's digest before the geometry layers existed (pure JSON hashing: the
#: same on every machine; tests/test_materials_model.py holds the same value).
SMOKE_DIGEST = "fbe79ed45c42f3bc064fb3250a8204252560721f63b64717c33c02306007c878"
SMOKE_LAYERS = '["diffuse", "specular", "roughness", "normal", "mask"]'


# --------------------------------------------------------------------------- helpers


def bounding_sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """A sphere holding every vertex: centred on the bounding box, radius to the farthest."""
    vertices = np.asarray(vertices, np.float64)
    centre = (vertices.min(0) + vertices.max(0)) / 2
    return centre, float(np.linalg.norm(vertices - centre, axis=1).max())


def depth_range(camera, vertices) -> tuple[float, float]:
    """The z-depths the object can have: its bounding sphere's, along the camera's forward axis."""
    centre, radius = bounding_sphere(vertices)
    _, _, forward = camera.basis()
    middle = float((centre - np.asarray(camera.origin)) @ forward)
    return middle - radius, middle + radius


@dataclass(frozen=True)
class StandIn:
    """An object with geometry.Shaderball's attributes and no pedestal (what
    geometry.objects.build_object gives for a non-shaderball object)."""

    digest: str
    material_mesh: object
    neutral_mesh: None
    ground_mesh: object
    mesh_files: dict
    seam_edges: np.ndarray
    seam_on_crease: np.ndarray


def torus_mesh(centre, axis, major_m=0.36, minor_m=0.14, n_around=72, n_tube=36):
    """A UV-parametrised torus: u around the ring, v around the tube, each in [0, 1], the seam
    vertices doubled; analytic unit vertex normals."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    u, v = np.meshgrid(np.linspace(0, 1, n_around + 1), np.linspace(0, 1, n_tube + 1), indexing="ij")
    theta, phi = 2 * np.pi * u.ravel(), 2 * np.pi * v.ravel()
    radial = np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2
    normals = np.cos(phi)[:, None] * radial + np.sin(phi)[:, None] * axis
    positions = np.asarray(centre) + major_m * radial + minor_m * normals
    index = np.arange((n_around + 1) * (n_tube + 1)).reshape(n_around + 1, n_tube + 1)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    uv = np.stack([u.ravel(), v.ravel()], 1)
    return positions, faces, normals, uv


def ground_quad(half_m=20.0):
    positions = np.array(
        [[-half_m, -half_m, 0], [half_m, -half_m, 0], [half_m, half_m, 0], [-half_m, half_m, 0]], float
    )
    normals = np.tile([0.0, 0.0, 1.0], (4, 1))
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    return positions, np.array([[0, 1, 2], [0, 2, 3]]), normals, uv


@pytest.fixture(scope="module")
def torus(tmp_path_factory) -> StandIn:
    folder = tmp_path_factory.mktemp("torus")
    camera = default_camera()
    # Tilted towards the camera, so the hole, the inner and the outer side are all seen.
    positions, faces, normals, uv = torus_mesh(camera.target, axis=[0.0, -0.8, 0.6])
    files = {"material": str(folder / "material.ply"), "ground": str(folder / "ground.ply")}
    write_ply(files["material"], positions, faces, normals, uv)
    write_ply(files["ground"], *ground_quad())
    digest = hashlib.sha256(b"".join(open(path, "rb").read() for path in files.values())).hexdigest()
    material = trimesh.Trimesh(positions, faces, vertex_normals=normals, process=False)
    ground = trimesh.Trimesh(*ground_quad()[:2], process=False)
    seam = np.zeros((0, 2, 3))
    return StandIn(digest, material, None, ground, files, seam, np.zeros(0, bool))


def mitsuba_lookup(mi, obj, camera, resolution, texture):
    """Mitsuba's own evaluation of ``texture`` on the material mesh at the pixel centres: the
    mesh an area emitter of that radiance, one unjittered sample per pixel, emission only."""
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 1},
        **shape_dicts(obj, {"type": "diffuse"}),
        "sensor": sensor_dict(camera, resolution, 1, sampler="stratified-centres", variant=VARIANT),
    }
    scene[BALL_SHAPE_ID]["emitter"] = {"type": "area", "radiance": bitmap_texture(texture, variant=VARIANT)}
    return np.array(mi.render(mi.load_dict(scene), seed=0), dtype=np.float32)


# --------------------------------------------------------------------------- a build


@pytest.fixture(scope="module")
def geometry_build(tmp_path_factory):
    """A small smoke-like build (2 materials, 1 lighting each) storing the geometry layers."""
    from pipeline.run.build import build
    from pipeline.run.cluster.options import ClusterOptions

    base = tmp_path_factory.mktemp("geometry-build")
    text = open(SMOKE).read()
    for key, value in (("materials", "2"), ("lights_per_material", "1"), ("shard_size", "1"), ("spp", "4")):
        text, n = re.subn(rf"(?m)^{key} = \S+", f"{key} = {value}", text)
        assert n == 1, key
    assert SMOKE_LAYERS in text
    text = text.replace(SMOKE_LAYERS, '["diffuse", "mask", "depth", "geometry_normal"]')
    spec_path = base / "spec.toml"
    spec_path.write_text(text)
    summary = build(str(spec_path), str(base / "out"), cluster=ClusterOptions(workers=0))
    assert summary.rendered == summary.total == 2
    return parse_spec(str(spec_path)), base / "out"


def test_build_stores_the_geometry_layers_and_validate_passes(geometry_build, ball, cache_dir, mi):
    from pipeline.check.validate import validate

    spec, root = geometry_build
    assert spec.storage.layers == ("diffuse", "mask", "geometry_normal", "depth")
    assert spec.storage.maps_half
    report = validate(str(root))
    assert report.ok, report

    camera, resolution = default_camera(), spec.render.resolution
    gbuffer = load_gbuffer(ball, camera, resolution, cache_dir=cache_dir, variant=VARIANT)
    low, high = depth_range(camera, ball.material_mesh.vertices)
    maps_files = sorted(root.rglob("*.maps.exr"))
    assert len(maps_files) == 2
    for path in maps_files:
        layers = exr.read_exr(str(path)).layers
        assert set(layers) == {"diffuse", "mask", "geometry_normal", "depth"}
        assert layers["diffuse"].dtype == np.float16  # maps_half halves the maps...
        assert layers["geometry_normal"].dtype == np.float32 and layers["depth"].dtype == np.float32  # not these
        mask = layers["mask"][..., 0] > 0.5
        np.testing.assert_array_equal(mask, gbuffer.mask)
        normal, depth = layers["geometry_normal"], layers["depth"][..., 0]
        np.testing.assert_allclose(np.linalg.norm(normal[mask], axis=1), 1.0, atol=1e-5)
        assert np.all(normal[~mask] == 0) and np.all(depth[~mask] == 0)
        assert low <= depth[mask].min() and depth[mask].max() <= high
        assert depth[mask].max() - depth[mask].min() > 0.2  # the ball's depth really varies
        np.testing.assert_allclose(normal, gbuffer.normal, atol=1e-6)
        np.testing.assert_allclose(depth, gbuffer.depth, atol=1e-6)


def test_validate_checks_the_geometry_values(ball, cache_dir, mi):
    gbuffer = load_gbuffer(ball, default_camera(), 64, cache_dir=cache_dir, variant=VARIANT)
    good = {
        "mask": gbuffer.mask.astype(np.float32)[..., None],
        "geometry_normal": gbuffer.normal.copy(),
        "depth": gbuffer.depth.copy()[..., None],
    }
    assert map_value_issues(good, screen_space=True) == []
    rows, cols = np.nonzero(gbuffer.mask)
    inside, outside = (rows[0], cols[0]), np.argwhere(~gbuffer.mask)[0]

    def issues(name, where, value):
        bad = {k: v.copy() for k, v in good.items()}
        bad[name][tuple(where)] = value
        return [kind for kind, _ in map_value_issues(bad, screen_space=True)]

    assert issues("geometry_normal", inside, [0.0, 0.0, 2.0]) == ["normal_not_unit"]
    assert issues("depth", inside, -1.0) == ["out_of_range"]
    assert issues("depth", inside, 0.0) == ["out_of_range"]
    assert issues("depth", inside, np.inf) == ["non_finite", "out_of_range"]
    assert issues("depth", outside, 3.0) == ["out_of_range"]
    assert issues("geometry_normal", outside, [0.0, 0.0, 1.0]) == ["out_of_range"]
    # Without a mask layer, the non-zero pixels are where the object is.
    no_mask = {k: v for k, v in good.items() if k != "mask"}
    assert map_value_issues(no_mask, screen_space=True) == []
    no_mask["depth"] = -no_mask["depth"]
    assert [kind for kind, _ in map_value_issues(no_mask, screen_space=True)] == ["out_of_range"]


def test_the_training_loaders_check_allows_the_geometry_layers(ball, cache_dir, mi):
    gbuffer = load_gbuffer(ball, default_camera(), 64, cache_dir=cache_dir, variant=VARIANT)
    screen = project_material(_uniform_maps(), gbuffer, geometry=True)
    layers = {name: value[..., None] if value.ndim == 2 else value for name, value in screen.items()}
    expect = sample_expectations(64)["maps"]
    assert content_issues(layers, expect) == []  # allowed, not needed:
    maps_only = {name: layers[name] for name in MAP_LAYERS}
    assert content_issues(maps_only, expect) == []
    assert [kind for kind, _ in content_issues({**layers, "extra": layers["depth"]}, expect)] == ["bad_layers"]


# --------------------------------------------------------------------------- depth


def test_depth_equals_mitsubas_hit_point_on_the_view_axis(ball, cache_dir, mi):
    camera, resolution = default_camera(), 48
    gbuffer = load_gbuffer(ball, camera, resolution, cache_dir=cache_dir, variant=VARIANT)
    scene = intersection_scene(ball, camera, resolution, variant=VARIANT)
    ray = pixel_centre_rays(scene, resolution, variant=VARIANT)
    si = scene.ray_intersect(ray)
    origin = np.array(ray.o, np.float64).T
    direction = np.array(ray.d, np.float64).T
    t = np.array(si.t, np.float64)
    _, _, forward = camera.basis()
    expected = ((origin + t[:, None] * direction - np.asarray(camera.origin)) @ forward).reshape(resolution, -1)

    mask = gbuffer.mask
    assert mask.sum() > 300
    np.testing.assert_allclose(gbuffer.depth[mask], expected[mask], rtol=0, atol=2e-5)
    assert np.all(gbuffer.depth[~mask] == 0)
    low, high = depth_range(camera, ball.material_mesh.vertices)
    assert low <= gbuffer.depth[mask].min() and gbuffer.depth[mask].max() <= high
    # The cache file (written by the first load) gives back what is computed.
    assert os.path.isfile(gbuffer_path(ball, camera, resolution, VARIANT, cache_dir))
    cached = load_gbuffer(ball, camera, resolution, cache_dir=cache_dir, variant=VARIANT)
    fresh = compute_gbuffer(ball, camera, resolution, variant=VARIANT)
    np.testing.assert_array_equal(cached.depth, fresh.depth)
    assert cached.depth.dtype == np.float32 and cached.depth.shape == (resolution, resolution)


# --------------------------------------------------------------------------- another object


def test_an_object_without_a_pedestal_gets_none(torus, tmp_path, mi):
    entries = shape_dicts(torus, {"type": "diffuse"})
    assert list(entries) == [BALL_SHAPE_ID, GROUND_SHAPE_ID]
    hits = first_hits(torus, default_camera(), 48, variant=VARIANT)
    assert SURFACES.index(NEUTRAL_SHAPE_ID) not in set(np.unique(hits.surface))
    assert (hits.surface == SURFACES.index(BALL_SHAPE_ID)).sum() > 200
    assert (hits.surface == SURFACES.index(GROUND_SHAPE_ID)).sum() > 200


@pytest.mark.parametrize("resolution, texture_shape", [(64, (37, 53, 3)), (96, (29, 41))])
def test_maps_on_a_torus_equal_mitsubas_texture_evaluation(torus, tmp_path, mi, resolution, texture_shape):
    camera = default_camera()
    rng = np.random.default_rng(resolution + len(texture_shape))
    texture = rng.random(texture_shape).astype(np.float32)
    gbuffer = load_gbuffer(torus, camera, resolution, cache_dir=str(tmp_path), variant=VARIANT)
    assert gbuffer.geometry_digest == torus.digest
    assert 0.05 < gbuffer.mask.mean() < 0.6

    rendered = mitsuba_lookup(mi, torus, camera, resolution, texture)
    projected = project(texture, gbuffer)
    if projected.shape[-1] == 1:  # a one-channel bitmap emits grey
        projected = np.repeat(projected, 3, axis=-1)
    facing = facing_mask(gbuffer)
    assert gbuffer.mask.sum() - facing.sum() <= max(2, 0.01 * gbuffer.mask.sum())
    error = np.abs(rendered - projected)
    assert error[facing].max() <= 1e-6
    assert np.all(rendered[~gbuffer.mask] == 0)
    assert projected[facing].std() > 0.1

    # Its geometry buffers: unit normals, depths inside the torus's bounding sphere.
    layers = project_material(_uniform_maps(), gbuffer, geometry=True)
    mask = gbuffer.mask
    np.testing.assert_allclose(np.linalg.norm(layers["geometry_normal"][mask], axis=1), 1.0, atol=1e-5)
    low, high = depth_range(camera, torus.material_mesh.vertices)
    assert low <= layers["depth"][mask].min() and layers["depth"][mask].max() <= high


@pytest.mark.parametrize("name", ["torus", "sphere", "rounded_cube"])
def test_maps_on_the_built_in_objects_equal_mitsubas_texture_evaluation(name, cache_dir, tmp_path, mi):
    from geometry.objects import build_object, object_camera

    obj = build_object(name, cache_dir=cache_dir)
    assert "neutral" not in obj.mesh_files
    camera, resolution = object_camera(obj), 64
    texture = np.random.default_rng(7).random((31, 43, 3)).astype(np.float32)
    gbuffer = load_gbuffer(obj, camera, resolution, cache_dir=str(tmp_path), variant=VARIANT)
    assert gbuffer.mask.mean() > 0.05
    rendered = mitsuba_lookup(mi, obj, camera, resolution, texture)
    projected = project(texture, gbuffer)
    facing = facing_mask(gbuffer)
    assert gbuffer.mask.sum() - facing.sum() <= max(2, 0.01 * gbuffer.mask.sum())
    assert np.abs(rendered - projected)[facing].max() <= 1e-6
    assert projected[facing].std() > 0.1
    low, high = depth_range(camera, obj.material_mesh.vertices)
    assert low <= gbuffer.depth[gbuffer.mask].min() and gbuffer.depth[gbuffer.mask].max() <= high


def _uniform_maps():
    from materials.maps import MaterialMaps

    return MaterialMaps(
        diffuse=np.full((1, 1, 3), 0.5, np.float32),
        specular=np.full((1, 1, 3), 0.04, np.float32),
        roughness=np.full((1, 1), 0.5, np.float32),
        normal=np.array([[[0.0, 0.0, 1.0]]], np.float32),
    )


# --------------------------------------------------------------------------- what stays as it was


def test_default_spec_layers_and_the_smoke_digest_are_unchanged():
    smoke = parse_spec(SMOKE)
    assert spec_digest(smoke) == SMOKE_DIGEST
    assert smoke.storage.layers == MAP_LAYERS
    default = parse_spec_text('[dataset]\nname = "x"\nversion = "1"\nseed = 1\nmaterials = 2\n')
    assert default.storage.layers == MAP_LAYERS == ("diffuse", "specular", "roughness", "normal", "mask")
    # Asked in any order, the layers take one canonical order (one spec, one digest).
    asked = open(SMOKE).read().replace(SMOKE_LAYERS, '["depth", "normal", "geometry_normal", "diffuse"]')
    spec = parse_spec_text(asked)
    assert spec.storage.layers == ("diffuse", "normal", "geometry_normal", "depth")
    assert spec_digest(spec) != SMOKE_DIGEST


def test_layer_tables_agree():
    assert GEOMETRY_LAYERS == exr.GEOMETRY_LAYERS == ("geometry_normal", "depth")
    assert exr.LAYER_CHANNELS["geometry_normal"] == ("X", "Y", "Z")
    assert exr.LAYER_CHANNELS["depth"] == ("Z",)
    assert set(GEOMETRY_LAYERS) <= set(exr.ROLE_LAYERS["maps"])
    assert not set(GEOMETRY_LAYERS) & set(exr.MATERIAL_MAP_LAYERS)  # never halved


def test_the_shaderballs_scene_entries_are_todays(ball):
    material = {"type": "diffuse"}

    def ply(name, bsdf):
        return {"type": "ply", "filename": ball.mesh_files[name], "face_normals": False, "bsdf": bsdf}

    entries = shape_dicts(ball, material)
    assert list(entries) == [BALL_SHAPE_ID, NEUTRAL_SHAPE_ID, GROUND_SHAPE_ID]
    assert entries == {
        BALL_SHAPE_ID: ply("material", material),
        NEUTRAL_SHAPE_ID: ply("neutral", NEUTRAL_BSDF),
        GROUND_SHAPE_ID: ply("ground", GROUND_BSDF),
    }
    other = {"type": "conductor"}
    assert shape_dicts(ball, material, other, other)[NEUTRAL_SHAPE_ID] == ply("neutral", other)
