"""The procedural shaderball (trimesh), its UV atlas (xatlas), the camera, and the other
scene objects (built-in primitives, users' mesh files behind a gate).

See docs/geometry.md for the parameters, the material-bearing surfaces, the seams and
the cache.

Layer 1 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): imports
nothing of the project.
"""

from geometry.camera import Camera, default_camera, frame_box
from geometry.meshfile import MESH_SUFFIXES, MeshFileError, MeshFileFacts, check_mesh_file, file_sha256
from geometry.objects import BUILTIN_OBJECTS, SceneObject, build_object, object_camera
from geometry.params import ShaderballParams
from geometry.shaderball import Shaderball, build_shaderball, default_cache_dir

__all__ = [
    "BUILTIN_OBJECTS",
    "Camera",
    "MESH_SUFFIXES",
    "MeshFileError",
    "MeshFileFacts",
    "SceneObject",
    "Shaderball",
    "ShaderballParams",
    "build_object",
    "build_shaderball",
    "check_mesh_file",
    "default_cache_dir",
    "default_camera",
    "file_sha256",
    "frame_box",
    "object_camera",
]
