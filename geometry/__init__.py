"""The procedural shaderball (trimesh), its UV atlas (xatlas) and the fixed camera.

See docs/geometry.md for the parameters, the material-bearing surfaces, the seams and
the cache.

Layer 1 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): imports
nothing of the project.
"""

from geometry.camera import Camera, default_camera
from geometry.params import ShaderballParams
from geometry.shaderball import Shaderball, build_shaderball, default_cache_dir

__all__ = [
    "Camera",
    "Shaderball",
    "ShaderballParams",
    "build_shaderball",
    "default_cache_dir",
    "default_camera",
]
