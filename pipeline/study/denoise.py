"""Intel Open Image Denoise (``pyoidn``) with noise-free guide buffers from the project's
exact screen-space maps and G-buffer geometry.

What OIDN is fed (its documentation asks for the "albedo" a path's first hit reflects, in
[0, 1], and for a perfect mirror or a metal the specular colour):

- **albedo**: on the ball, d (1 - s) + s per channel, clipped to [0, 1], from the
  screen-space diffuse d and specular s maps the network sees (pipeline.render.raster):
  the model's diffuse lobe is weighted by (1 - s) and its specular lobe's directional
  albedo tends to s at normal incidence (Schlick F0 = s), so a black-diffuse gold ball
  gets its gold colour rather than black, which would tell OIDN there is no texture
  to keep. The pedestal and ground get their constant diffuse albedos (0.5, 0.3,
  pipeline.render.scene); pixels that see the sky get 1 (the radiance is its own
  "texture" there).
- **normal**: the world-space shading normal at the pixel centre (the mesh's, before
  the material's normal map: the renderer's tangent frame is not exported), 0 where
  the sky is seen.

Both are exact, so ``clean_aux`` is on (no prefiltering). The colour is given as HDR,
negatives clipped to 0. OIDN is biased: its error against the reference is what counts.
"""

from __future__ import annotations

import numpy as np

from pipeline.render.gbuffer import intersection_scene, pixel_centre_rays
from pipeline.render.mitsuba_env import load_mitsuba
from pipeline.render.scene import BALL_SHAPE_ID, GROUND_BSDF, GROUND_SHAPE_ID, NEUTRAL_BSDF, NEUTRAL_SHAPE_ID


def shape_ids_and_normals(ball, camera, resolution: int, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel: the id of the shape hit at the pixel centre ("" for none) and its shading normal."""
    mi = load_mitsuba(variant)
    scene = intersection_scene(ball, camera, resolution, variant)
    si = scene.ray_intersect(pixel_centre_rays(scene, resolution, variant), ray_flags=mi.RayFlags.All, coherent=True)
    valid = np.array(si.is_valid(), dtype=bool)
    ids = np.full(resolution * resolution, "", dtype=object)
    for shape in scene.shapes():
        hit = np.array(si.shape == mi.ShapePtr(shape), dtype=bool) & valid
        ids[hit] = shape.id()
    normal = np.array(si.sh_frame.n, dtype=np.float32).T.reshape(resolution, resolution, 3)
    normal[~valid.reshape(resolution, resolution)] = 0.0
    return ids.reshape(resolution, resolution), normal


def guides(shape_ids: np.ndarray, normals: np.ndarray, screen_maps: dict) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, normal) float32 (H, W, 3) guide buffers (see the module's docstring)."""
    h, w = shape_ids.shape
    albedo = np.ones((h, w, 3), np.float32)
    albedo[shape_ids == NEUTRAL_SHAPE_ID] = NEUTRAL_BSDF["reflectance"]["value"]
    albedo[shape_ids == GROUND_SHAPE_ID] = GROUND_BSDF["reflectance"]["value"]
    ball = shape_ids == BALL_SHAPE_ID
    d, s = screen_maps["diffuse"], screen_maps["specular"]
    albedo[ball] = np.clip(d * (1.0 - s) + s, 0.0, 1.0)[ball]
    return albedo, np.clip(normals, -1.0, 1.0).astype(np.float32)
