"""Scene objects other than the shaderball: built-in primitives and users' mesh files
(normalised into the shaderball's box, standing on the ground), their UVs, normals,
seams, digests, cache and camera. Every mesh file is written by the test itself."""

import os
import shutil

import numpy as np
import pytest
import trimesh

from geometry import (
    BUILTIN_OBJECTS,
    ShaderballParams,
    build_object,
    build_shaderball,
    default_camera,
    object_camera,
)

PRIMITIVES = [name for name in BUILTIN_OBJECTS if name != "shaderball"]
PARAMS = ShaderballParams()
HALF_WIDTH = max(PARAMS.shell_radius_m, PARAMS.pedestal_radius_m)
TOL = 1e-6


@pytest.fixture(scope="module")
def objects_cache(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("objects-cache"))


def _assert_normalised(obj):
    v = np.asarray(obj.material_mesh.vertices, np.float64)
    assert np.isfinite(v).all()
    assert abs(v[:, 2].min()) <= TOL, "stands on the ground"
    assert v[:, 2].max() <= PARAMS.top_z_m + TOL
    assert np.abs(v[:, :2]).max() <= HALF_WIDTH + TOL
    # fills the box along its limiting axis (uniform scale up to the box)
    fill = max(np.abs(v[:, :2]).max() / HALF_WIDTH, v[:, 2].max() / PARAMS.top_z_m)
    assert fill == pytest.approx(1.0, abs=1e-5)
    lo, hi = obj.bounds
    np.testing.assert_allclose(lo, v.min(0), atol=TOL)
    np.testing.assert_allclose(hi, v.max(0), atol=TOL)


def _assert_surface_attributes(obj):
    uv = obj.material_uv
    normals = obj.material_normals
    assert uv.shape == (len(obj.material_mesh.vertices), 2) and np.isfinite(uv).all()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    # normals point out of the faces they shade: winding and normals agree
    faces = np.asarray(obj.material_mesh.faces)
    p = np.asarray(obj.material_mesh.vertices, np.float64)[faces]
    geometric = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(np.einsum("ij,ij->i", geometric, normals[faces].sum(1)) > 0)
    assert obj.seam_edges.ndim == 3 and obj.seam_edges.shape[1:] == (2, 3)
    assert obj.seam_on_crease.shape == (len(obj.seam_edges),)


def _assert_framed(obj):
    camera = object_camera(obj)
    xy, depth = camera.project(np.asarray(obj.material_mesh.vertices), 64)
    assert np.all(depth > 0)
    assert np.all((xy >= 0) & (xy <= 64)), "every vertex inside the image"


# --------------------------------------------------------------------------- built-ins


@pytest.mark.parametrize("name", PRIMITIVES)
def test_builtin_builds_normalised_with_uvs_normals_and_camera(name, objects_cache):
    obj = build_object(name, objects_cache)
    assert obj.name == name and obj.kind == "primitive" and obj.uv_source == "built-in"
    assert obj.source is None and obj.source_sha256 is None and obj.neutral_mesh is None
    assert 2_000 <= len(obj.material_mesh.faces) <= 20_000
    assert set(obj.mesh_files) == {"material", "ground"}
    assert all(os.path.isfile(path) for path in obj.mesh_files.values())
    _assert_normalised(obj)
    _assert_surface_attributes(obj)
    _assert_framed(obj)
    # no crease on these surfaces, and their UV seams are shared edges (closed meshes)
    assert len(obj.seam_edges) > 0 and not obj.seam_on_crease.any()
    welded = obj.material_mesh.copy()
    welded.merge_vertices(merge_tex=True, merge_norm=True)
    assert welded.is_watertight


@pytest.mark.parametrize("name", PRIMITIVES)
def test_builtin_digest_is_the_same_in_process_and_after_the_cache_is_removed(name, tmp_path):
    first = build_object(name, str(tmp_path))
    again = build_object(name, str(tmp_path))
    assert again.digest == first.digest and "load" in again.timings
    shutil.rmtree(tmp_path / "objects")
    rebuilt = build_object(name, str(tmp_path))
    assert "build" in rebuilt.timings
    assert rebuilt.digest == first.digest


def test_builtins_differ_from_each_other(objects_cache):
    digests = {build_object(name, objects_cache).digest for name in PRIMITIVES}
    assert len(digests) == len(PRIMITIVES)


def test_ground_is_the_shaderballs_ground(objects_cache):
    ball = build_shaderball(cache_dir=objects_cache)
    sphere = build_object("sphere", objects_cache)
    with open(ball.mesh_files["ground"], "rb") as a, open(sphere.mesh_files["ground"], "rb") as b:
        assert a.read() == b.read()


def test_shaderball_through_build_object_is_build_shaderball(objects_cache):
    via = build_object("shaderball", objects_cache)
    direct = build_shaderball(cache_dir=objects_cache)
    assert type(via) is type(direct)
    assert via.digest == direct.digest and via.mesh_files == direct.mesh_files
    assert (via.name, via.kind, via.uv_source, via.source, via.source_sha256) == (
        "shaderball",
        "shaderball",
        "built-in",
        None,
        None,
    )
    assert via.bounds == ((-HALF_WIDTH, -HALF_WIDTH, 0.0), (HALF_WIDTH, HALF_WIDTH, PARAMS.top_z_m))
    assert object_camera(via) == default_camera()
    assert object_camera(via).fov_deg == default_camera().fov_deg
    _assert_framed(via)


def test_unknown_or_relative_object_is_refused(objects_cache):
    from geometry.errors import GeometryError

    for bad in ("cube", "meshes/teapot.obj"):
        with pytest.raises(GeometryError) as info:
            build_object(bad, objects_cache)
        assert repr(bad) in str(info.value) and "sphere" in str(info.value)


# --------------------------------------------------------------------------- mesh files


def _box_mesh():
    """A subdivided box on a 1/64 grid: exact in OBJ's decimal text and in PLY's floats."""
    mesh = trimesh.creation.box(extents=(1.0, 2.0, 0.5)).subdivide()
    mesh.vertices = np.round(mesh.vertices * 64.0) / 64.0 + np.array([3.0, -1.0, 2.0])
    return mesh


def _uv_sphere_mesh():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    uv = (mesh.vertices[:, :2] + 1.0) / 2.0
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv)
    return mesh


def test_obj_with_uvs_keeps_them(tmp_path):
    path = str(tmp_path / "ball.obj")
    _uv_sphere_mesh().export(path)
    obj = build_object(path, str(tmp_path / "cache"))
    assert obj.kind == "mesh" and obj.uv_source == "file" and obj.name == "ball.obj" and obj.source == path
    from geometry import file_sha256

    assert obj.source_sha256 == file_sha256(path)
    _assert_normalised(obj)
    _assert_surface_attributes(obj)
    _assert_framed(obj)
    # the file's u = (x + 1) / 2 survives normalisation (a uniform scale and shift of x)
    v = np.asarray(obj.material_mesh.vertices)
    x01 = (v[:, 0] - v[:, 0].min()) / np.ptp(v[:, 0])
    np.testing.assert_allclose(obj.material_uv[:, 0], x01, atol=1e-3)


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".glb"])
def test_files_without_uvs_get_an_xatlas_atlas(suffix, tmp_path):
    path = str(tmp_path / f"box{suffix}")
    _box_mesh().export(path)
    obj = build_object(path, str(tmp_path / "cache"))
    assert obj.uv_source == "xatlas" and obj.kind == "mesh"
    _assert_normalised(obj)
    _assert_surface_attributes(obj)
    _assert_framed(obj)
    uv = obj.material_uv
    assert uv.min() >= 0.0 and uv.max() <= 1.0
    # a box: flat faces with creases at its 12 edges, each a seam on a crease
    assert len(obj.material_mesh.vertices) == 6 * 9
    assert obj.seam_on_crease.all() and len(obj.seam_edges) == 12 * 2


def test_gltf_is_turned_from_y_up_to_z_up(tmp_path):
    mesh = _box_mesh()  # 1 x 2 x 0.5: y is its longest side
    mesh.export(str(tmp_path / "box.glb"))
    mesh.export(str(tmp_path / "box.ply"))
    glb = build_object(str(tmp_path / "box.glb"), str(tmp_path / "cache"))
    ply = build_object(str(tmp_path / "box.ply"), str(tmp_path / "cache"))
    (glo, ghi), (plo, phi) = glb.bounds, ply.bounds
    size_glb, size_ply = np.subtract(ghi, glo), np.subtract(phi, plo)
    assert size_glb[2] == pytest.approx(size_glb[0] * 2.0)  # the file's y is now up
    assert size_ply[1] == pytest.approx(size_ply[0] * 2.0)


def test_same_mesh_in_two_formats_has_the_same_canonical_digest(tmp_path):
    mesh = _box_mesh()
    digests = {}
    for suffix in (".obj", ".ply", ".stl"):
        path = str(tmp_path / f"box{suffix}")
        mesh.export(path, **({"include_normals": False} if suffix == ".obj" else {}))
        digests[suffix] = build_object(path, str(tmp_path / "cache")).digest
    assert digests[".obj"] == digests[".ply"] == digests[".stl"]


def test_mesh_file_cache_is_keyed_by_content_and_loads_without_rebuilding(tmp_path):
    cache = str(tmp_path / "cache")
    first = tmp_path / "a" / "box.ply"
    first.parent.mkdir()
    _box_mesh().export(str(first))
    built = build_object(str(first), cache)
    second = tmp_path / "b" / "renamed.ply"
    second.parent.mkdir()
    shutil.copy(first, second)
    loaded = build_object(str(second), cache)
    assert "load" in loaded.timings and loaded.digest == built.digest
    assert loaded.name == "renamed.ply" and loaded.source == str(second)
    assert loaded.mesh_files == built.mesh_files
    shutil.rmtree(os.path.join(cache, "objects"))
    assert build_object(str(first), cache).digest == built.digest


def test_damaged_cache_entry_is_rebuilt(tmp_path):
    cache = str(tmp_path / "cache")
    obj = build_object("torus", cache)
    with open(obj.mesh_files["material"], "r+b") as fh:
        fh.seek(-40, os.SEEK_END)
        fh.write(b"\x7f" * 8)
    again = build_object("torus", cache)
    assert "build" in again.timings and again.digest == obj.digest


def test_crease_normals_split_a_cube_and_keep_a_sphere_smooth():
    from geometry.meshops import crease_normals

    cube = trimesh.creation.box()
    source, faces, normals = crease_normals(np.asarray(cube.vertices), np.asarray(cube.faces))
    assert len(source) == 24  # 4 corners per face, each with its face's normal
    assert set(np.round(np.abs(normals), 6).ravel().tolist()) == {0.0, 1.0}
    sphere = trimesh.creation.icosphere(subdivisions=3)
    source, faces, normals = crease_normals(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    assert len(source) == len(sphere.vertices)
    cos = np.einsum(
        "ij,ij->i", normals, sphere.vertices[source] / np.linalg.norm(sphere.vertices[source], axis=1)[:, None]
    )
    assert cos.min() > 0.999
