"""Mitsuba scene-dict entries for the object (the shaderball or another), its camera and its textures.

The object's meshes are loaded from the PLY files of its geometry cache entry
(``ply`` plugin, vertex normals kept: ``face_normals = False``; UVs as stored, Mitsuba
does not flip v). The shape ids are fixed: :data:`BALL_SHAPE_ID` bears the material,
whatever the object; only the shaderball has a pedestal (:data:`NEUTRAL_SHAPE_ID`).

Mitsuba is loaded (through :mod:`pipeline.render.mitsuba_env`) only where a dict needs a
Mitsuba object: the sensor's transform and a bitmap's tensor.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from geometry import Camera
from pipeline.fields import FieldError
from pipeline.fields.rules import Choice
from pipeline.render.limits import SAMPLERS as RENDER_SAMPLERS
from pipeline.render.mitsuba_env import load_mitsuba

#: Shape id of the material-bearing surfaces (the shaderball's outer shell, rims, inner
#: surface and core; another object's whole mesh). Kept "shaderball" for every object, so
#: scenes, G-buffers and their readers name the material mesh one way.
BALL_SHAPE_ID = "shaderball"
#: Shape id of the pedestal and neck (the shaderball's alone).
NEUTRAL_SHAPE_ID = "pedestal"
#: Shape id of the ground plane.
GROUND_SHAPE_ID = "ground"

#: Neutral grey of the pedestal: linear albedo 0.5 (sRGB ~0.74).
NEUTRAL_BSDF = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}
#: The ground: a darker neutral grey, linear albedo 0.3.
GROUND_BSDF = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.3, 0.3, 0.3]}}

#: "stratified-centres" takes the G-buffer; the others (pipeline.render.limits.SAMPLERS) render.
SAMPLERS = ("stratified-centres", *RENDER_SAMPLERS)


class ObjectLike(Protocol):
    """What the scene, the G-buffer and the raster need of an object: geometry.Shaderball,
    geometry.objects.SceneObject, or any object with the same attributes (a pedestal only
    where ``mesh_files`` names one). Structural, so this layer imports no object builder.

    ``mesh_files``: PLY paths by name, ``"material"`` and ``"ground"`` always, ``"neutral"``
    (the pedestal) only for the shaderball; ``neutral_mesh`` is None without one.
    ``seam_edges`` (E, 2, 3) world-space segments where the texture is discontinuous,
    ``seam_on_crease`` (E,) bool. ``digest`` keys every cache made from the object.
    """

    digest: str
    material_mesh: object
    neutral_mesh: object | None
    ground_mesh: object
    mesh_files: dict[str, str]
    seam_edges: np.ndarray
    seam_on_crease: np.ndarray


def ball_shape_ids() -> tuple[str, ...]:
    """Ids of the shapes that bear the material (one: the whole material mesh)."""
    return (BALL_SHAPE_ID,)


def has_pedestal(obj: ObjectLike) -> bool:
    """Whether the object brings a pedestal (its ``mesh_files`` name a ``"neutral"`` mesh)."""
    return "neutral" in obj.mesh_files


def shape_dicts(
    obj: ObjectLike,
    material_bsdf: dict,
    neutral_bsdf: dict | None = None,
    ground_bsdf: dict | None = None,
) -> dict[str, dict]:
    """Scene-dict entries (id -> dict) for the material mesh, the pedestal (where the object
    has one) and the ground, in that order: the shaderball's are today's, entry for entry."""

    def ply(name: str, bsdf: dict) -> dict:
        return {"type": "ply", "filename": obj.mesh_files[name], "face_normals": False, "bsdf": bsdf}

    shapes = {BALL_SHAPE_ID: ply("material", material_bsdf)}
    if has_pedestal(obj):
        shapes[NEUTRAL_SHAPE_ID] = ply("neutral", neutral_bsdf or NEUTRAL_BSDF)
    shapes[GROUND_SHAPE_ID] = ply("ground", ground_bsdf or GROUND_BSDF)
    return shapes


def sensor_dict(
    camera: Camera,
    resolution: int,
    spp: int,
    *,
    sampler: str = "independent",
    seed: int = 0,
    pixel_format: str = "rgb",
    variant: str,
) -> dict:
    """A perspective sensor for ``camera`` with a square ``resolution`` film and a box filter.

    ``sampler``: ``"independent"`` (random positions in each pixel, for renders) or
    ``"stratified-centres"`` (Mitsuba's ``stratified`` sampler with jitter off: at 1 spp
    every sample sits on its pixel's centre, where the G-buffer is taken; ``spp`` must
    then be a square number), or another Mitsuba sampler of
    :data:`pipeline.render.limits.SAMPLERS` with its defaults (Mitsuba may round ``spp``).
    """
    if sampler not in SAMPLERS:
        raise FieldError("sampler", sampler, Choice(SAMPLERS).allowed, name="sampler")
    if not isinstance(spp, int) or isinstance(spp, bool) or spp < 1:
        raise FieldError("spp", spp, "an integer >= 1", name="spp")
    if sampler == "stratified-centres":
        if math.isqrt(spp) ** 2 != spp:
            raise FieldError("spp", spp, 'a square number with the sampler "stratified-centres"', name="spp")
        sampler_dict = {"type": "stratified", "sample_count": spp, "jitter": False, "seed": seed}
    else:
        sampler_dict = {"type": sampler, "sample_count": spp, "seed": seed}
    return {
        "type": "perspective",
        "fov": float(camera.fov_deg),
        "fov_axis": "x",
        "to_world": _look_at(camera, variant),
        "film": {
            "type": "hdrfilm",
            "width": int(resolution),
            "height": int(resolution),
            "rfilter": {"type": "box"},
            "pixel_format": pixel_format,
        },
        "sampler": sampler_dict,
    }


def _look_at(camera: Camera, variant: str):
    mi = load_mitsuba(variant)
    return mi.ScalarTransform4f().look_at(origin=list(camera.origin), target=list(camera.target), up=list(camera.up))


def bitmap_texture(texture: np.ndarray, *, variant: str, filter_type: str = "bilinear") -> dict:
    """A ``bitmap`` texture dict for a texture-space map: raw data, bilinear, repeat.

    This is the lookup :func:`pipeline.render.raster.project` reproduces: the array is rounded
    to float32 first (both sides), ``raw`` so nothing is sRGB-decoded, row 0 at v = 0.
    """
    mi = load_mitsuba(variant)
    data = np.ascontiguousarray(texture, dtype=np.float32)
    if data.ndim == 2:
        data = data[:, :, None]
    return {
        "type": "bitmap",
        "data": mi.TensorXf(data),
        "raw": True,
        "filter_type": filter_type,
        "wrap_mode": "repeat",
    }
