"""The gate for users' mesh files: every refusal on a file the test crafts, each message
naming the file, and what passes (a 200k-triangle mesh's header)."""

import json
import struct

import numpy as np
import pytest
import trimesh

from geometry import MeshFileError, build_object, check_mesh_file, meshfile
from geometry.errors import GeometryError


def _refused(path, *words, cache=None):
    """build_object(path) is refused with a MeshFileError naming the file and ``words``."""
    with pytest.raises(MeshFileError) as info:
        build_object(str(path), cache)
    message = str(info.value)
    assert str(path) in message, message
    for word in words:
        assert word in message, message
    assert isinstance(info.value, GeometryError)
    return message


def _triangle_obj(tmp_path, name, body):
    path = tmp_path / name
    path.write_text(body)
    return path


def _glb(doc: dict, binary: bytes = b"") -> bytes:
    data = json.dumps(doc).encode()
    data += b" " * (-len(data) % 4)
    out = struct.pack("<I", len(data)) + struct.pack("<I", 0x4E4F534A) + data
    if binary:
        binary += b"\0" * (-len(binary) % 4)
        out += struct.pack("<I", len(binary)) + struct.pack("<I", 0x004E4942) + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(out)) + out


def _gltf_doc(buffer_uri, images=None):
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 48} if buffer_uri is None else {"byteLength": 48, "uri": buffer_uri}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 12}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
    }
    if images is not None:
        doc["images"] = images
    return doc


# --------------------------------------------------------------------------- passes


def test_a_200k_triangle_ply_header_passes(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=4)
    faces = np.tile(mesh.faces, (40, 1))  # 204,800 triangles over the same vertices
    path = tmp_path / "big.ply"
    trimesh.Trimesh(mesh.vertices, faces, process=False).export(str(path))
    facts = check_mesh_file(str(path))
    assert facts.faces == len(faces) and facts.vertices == len(mesh.vertices)
    assert facts.suffix == ".ply" and facts.size_bytes == path.stat().st_size


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".glb"])
def test_counts_are_read_before_loading(suffix, tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=1)
    path = tmp_path / f"s{suffix}"
    mesh.export(str(path))
    facts = check_mesh_file(str(path))
    assert facts.faces == len(mesh.faces)
    assert facts.vertices >= len(mesh.vertices)


def test_degenerate_faces_are_dropped_not_refused(tmp_path):
    body = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n"  # the second is a sliver of area 0
    obj = build_object(str(_triangle_obj(tmp_path, "sliver.obj", body)), str(tmp_path / "cache"))
    assert len(obj.material_mesh.faces) == 1


# --------------------------------------------------------------------------- refusals


def test_nan_vertex_in_obj(tmp_path):
    path = _triangle_obj(tmp_path, "nan.obj", "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    _refused(path, "non-finite", cache=str(tmp_path / "cache"))


def test_infinite_vertex_in_ply(tmp_path):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.inf]], float)
    path = tmp_path / "inf.ply"
    trimesh.Trimesh(vertices, [[0, 1, 2]], process=False).export(str(path))
    _refused(path, "non-finite", cache=str(tmp_path / "cache"))


@pytest.mark.parametrize("index", ["5", "-4", "0"])
def test_face_index_out_of_range_in_obj(index, tmp_path):
    path = _triangle_obj(tmp_path, "range.obj", f"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 {index}\n")
    _refused(path, "out of range", index)


def test_face_index_out_of_range_in_ply(tmp_path):
    header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    header += "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    path = tmp_path / "range.ply"
    path.write_text(header + "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    _refused(path, "7", cache=str(tmp_path / "cache"))


def test_no_faces(tmp_path):
    _refused(_triangle_obj(tmp_path, "points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"), "no faces")
    header = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
    path = tmp_path / "points.ply"
    path.write_text(header + "end_header\n0 0 0\n")
    _refused(path, "no faces")


def test_all_faces_degenerate(tmp_path):
    path = _triangle_obj(tmp_path, "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n")
    _refused(path, "all 2 faces have zero area", cache=str(tmp_path / "cache"))


def test_unknown_suffix(tmp_path):
    path = tmp_path / "mesh.fbx"
    path.write_bytes(b"Kaydara FBX Binary")
    message = _refused(path, "'.fbx'")
    assert ".obj" in message and ".glb" in message


def test_oversized_file_is_refused_by_its_size(tmp_path, monkeypatch):
    path = tmp_path / "s.stl"
    trimesh.creation.icosphere(subdivisions=1).export(str(path))
    monkeypatch.setattr(meshfile, "MAX_MESH_FILE_BYTES", path.stat().st_size - 1)
    _refused(path, f"{path.stat().st_size} bytes", "MAX_MESH_FILE_BYTES")


def test_face_count_over_budget_from_the_ply_header(tmp_path):
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    header += f"property float z\nelement face {meshfile.MAX_FACES + 1}\nproperty list uchar int vertex_indices\n"
    path = tmp_path / "huge.ply"
    path.write_bytes((header + "end_header\n").encode() + b"\0" * 64)  # the body is never read
    _refused(path, f"{meshfile.MAX_FACES + 1} faces", "MAX_FACES")


def test_vertex_count_over_budget_from_a_binary_stl(tmp_path, monkeypatch):
    monkeypatch.setattr(meshfile, "MAX_VERTICES", 10)
    path = tmp_path / "s.stl"
    trimesh.creation.icosphere(subdivisions=1).export(str(path))
    _refused(path, "vertices", "MAX_VERTICES")


def test_gltf_with_an_external_buffer(tmp_path):
    (tmp_path / "mesh.bin").write_bytes(b"\0" * 48)
    path = tmp_path / "mesh.gltf"
    path.write_text(json.dumps(_gltf_doc("mesh.bin")))
    _refused(path, "buffers[0]", "'mesh.bin'", "data: URIs only")


def test_gltf_with_a_url(tmp_path):
    path = tmp_path / "mesh.gltf"
    path.write_text(json.dumps(_gltf_doc("https://example.com/mesh.bin")))
    _refused(path, "https://example.com/mesh.bin")


def test_glb_with_an_embedded_image(tmp_path):
    doc = _gltf_doc(None, images=[{"bufferView": 0, "mimeType": "image/png"}])
    path = tmp_path / "textured.glb"
    path.write_bytes(_glb(doc, b"\0" * 48))
    _refused(path, "image", "no textures")


def test_glb_written_by_trimesh_with_a_texture_is_refused(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=1)
    mesh.visual = trimesh.visual.TextureVisuals(uv=(mesh.vertices[:, :2] + 1) / 2)
    path = tmp_path / "uv.glb"
    mesh.export(str(path))
    _refused(path, "image")


def test_glb_with_a_lying_header(tmp_path):
    path = tmp_path / "short.glb"
    data = bytearray(_glb(_gltf_doc(None), b"\0" * 48))
    data[12:16] = struct.pack("<I", 1 << 30)  # a JSON chunk longer than the file
    path.write_bytes(bytes(data))
    _refused(path, "do not fit the file")


def test_gltf_json_that_does_not_parse(tmp_path):
    path = tmp_path / "broken.gltf"
    path.write_text('{"buffers": [')
    _refused(path, "does not parse")


def test_obj_that_names_a_material_library_reads_nothing_else(tmp_path):
    secret = tmp_path / "lib.mtl"
    secret.write_text("newmtl x\nmap_Kd secret.png\n")
    path = _triangle_obj(tmp_path, "mtl.obj", "mtllib lib.mtl\nusemtl x\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    obj = build_object(str(path), str(tmp_path / "cache"))  # the .mtl is refused, the mesh loads
    assert len(obj.material_mesh.faces) == 1 and obj.uv_source == "xatlas"


def test_not_a_file(tmp_path):
    folder = tmp_path / "dir.obj"
    folder.mkdir()
    _refused(folder, "not a regular file")
    _refused(tmp_path / "missing.ply", "cannot be read")
