"""Intel Open Image Denoise (``pyoidn``) for `shaderball evaluate`'s low-spp renders, with
the noise-free auxiliary buffers OIDN asks for: the albedo and normal of each pixel's first
hit (docs/neural.md, "Denoising").

- **albedo**: on the material, the sum of its two lobes' albedos at normal incidence,
  ``d (1 - s) + s`` (the diffuse lobe ``d (1 - s) / pi`` reflects ``d (1 - s)``; the specular
  lobe's Fresnel term starts at ``F0 = s``), with the model's clamps (``d >= 0``, ``s`` in
  [0, 1]) and clipped to [0, 1]. OIDN's guidance: the sum of the lobes' albedos for a
  layered surface, the reflectivity at normal incidence for a metal; our metals are
  ``d ~ 0``, ``s`` large, so they get ``s``. On the pedestal and the ground: their diffuse
  reflectance (:data:`pipeline.render.scene.NEUTRAL_BSDF`, ``GROUND_BSDF``); 0 where no
  surface is hit.
- **normal**: the world-space shading normal of the first hit
  (:func:`pipeline.render.gbuffer.first_hits`; on the material mesh the G-buffer's normal),
  without the normal map.
- Both are taken at ``k x k`` pixel centres per pixel (:data:`SUPERSAMPLE`) and
  box-averaged, because the renders' box filter averages each pixel's area and OIDN wants
  its auxiliary images filtered as the colour is; being noise-free, they are passed with
  ``clean_aux``. The texture lookup is the renderer's (:func:`pipeline.render.raster.bilinear_lookup`).
"""

from __future__ import annotations

import numpy as np

from geometry import Camera, Shaderball
from materials import MaterialMaps
from pipeline.errors import quoted
from pipeline.neural.data import box_downsample
from pipeline.render.gbuffer import SURFACES, first_hits
from pipeline.render.limits import RESOLUTION_RANGE
from pipeline.render.raster import bilinear_lookup
from pipeline.render.scene import BALL_SHAPE_ID, GROUND_BSDF, GROUND_SHAPE_ID, NEUTRAL_BSDF, NEUTRAL_SHAPE_ID

#: Pixel centres per pixel side for the auxiliary buffers (fewer where the resolution is large).
SUPERSAMPLE = 4
#: What the material's albedo buffer holds: the lobes' sum (used), or the diffuse albedo alone.
ALBEDOS = ("lobes", "diffuse")


def material_albedo(diffuse: np.ndarray, specular: np.ndarray) -> np.ndarray:
    """OIDN's albedo of the Cook-Torrance material: ``d (1 - s) + s`` in [0, 1]."""
    d = np.maximum(np.asarray(diffuse, np.float32), 0.0)
    s = np.clip(np.asarray(specular, np.float32), 0.0, 1.0)
    return np.clip(d * (1.0 - s) + s, 0.0, 1.0)


def _reflectance(bsdf: dict) -> np.ndarray:
    return np.asarray(bsdf["reflectance"]["value"], np.float32)


class AuxBuffers:
    """The first-hit albedo and normal of renders at ``resolution`` (the renderer's), box-averaged
    by ``factor`` more (the network's resolution), for any material.

    The variants `shaderball neural-bench denoise` compares with the one used:
    ``supersample=1`` (pixel centres only, like the dataset's maps), ``surroundings=False``
    (albedo and normal 0 off the material, like the G-buffer), ``albedo="diffuse"`` (``d``).
    """

    def __init__(
        self,
        ball: Shaderball,
        camera: Camera,
        resolution: int,
        variant: str,
        factor: int = 1,
        supersample: int = SUPERSAMPLE,
        surroundings: bool = True,
        albedo: str = "lobes",
    ):
        if albedo not in ALBEDOS:
            raise ValueError(f"albedo: {quoted(albedo)}; allowed: {', '.join(ALBEDOS)}")
        self.supersample = max(1, min(supersample, RESOLUTION_RANGE[1] // resolution))
        self.kind = albedo
        hits = first_hits(ball, camera, resolution * self.supersample, variant)
        self.block = self.supersample * factor
        self.surface = hits.surface  # at resolution * supersample: indices in SURFACES, -1 nothing
        self.on_ball = hits.surface == SURFACES.index(BALL_SHAPE_ID)
        self.uv = hits.uv[self.on_ball]
        base = np.zeros(hits.surface.shape + (3,), np.float32)
        normal = hits.normal
        if surroundings:
            base[hits.surface == SURFACES.index(NEUTRAL_SHAPE_ID)] = _reflectance(NEUTRAL_BSDF)
            base[hits.surface == SURFACES.index(GROUND_SHAPE_ID)] = _reflectance(GROUND_BSDF)
        else:
            normal = np.where(self.on_ball[..., None], normal, np.float32(0))
        self.base = base
        self.normal = np.ascontiguousarray(box_downsample(normal, self.block), np.float32)

    def albedo(self, maps: MaterialMaps) -> np.ndarray:
        albedo = self.base.copy()
        diffuse = bilinear_lookup(maps.diffuse, self.uv)
        if self.kind == "diffuse":
            albedo[self.on_ball] = np.clip(diffuse, 0.0, 1.0)
        else:
            albedo[self.on_ball] = material_albedo(diffuse, bilinear_lookup(maps.specular, self.uv))
        return np.ascontiguousarray(box_downsample(albedo, self.block), np.float32)
