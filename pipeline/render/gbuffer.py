"""The per-pixel G-buffer of the object (the shaderball or another): UV, shading normal,
depth and material mask.

It is taken by Mitsuba itself at pixel centres: the rays are generated exactly as a
1-spp render with the ``stratified-centres`` sampler (see
:func:`pipeline.render.scene.sensor_dict`) generates them, and intersected with the same
scene, so a texture looked up through the G-buffer equals Mitsuba's own lookup at those
centres (tests/test_gbuffer_projection.py checks it to 1e-6).

The G-buffer depends only on geometry, camera and resolution; :func:`load_gbuffer`
caches it as an EXR keyed by all three (and the Mitsuba version).

Every function here takes any object with geometry.Shaderball's attributes
(:class:`pipeline.render.scene.ObjectLike`); one without a pedestal gets none in the scene.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass

import numpy as np

from geometry import Camera
from geometry.shaderball import default_cache_dir
from pipeline.errors import USER_ERRORS
from pipeline.fields import FieldError
from pipeline.fields.rules import Int, Reject
from pipeline.render.limits import RESOLUTION_RANGE
from pipeline.render.mitsuba_env import load_mitsuba
from pipeline.render.scene import (
    BALL_SHAPE_ID,
    GROUND_SHAPE_ID,
    NEUTRAL_SHAPE_ID,
    ObjectLike,
    sensor_dict,
    shape_dicts,
)
from pipeline.store.exr import layer_bounds, read_exr, write_exr

#: Bump when what the G-buffer holds or how it is taken changes (2: the depth layer).
GBUFFER_CODE_VERSION = 2
#: The layers of a cached G-buffer file (pipeline.store.exr naming).
GBUFFER_LAYERS = ("uv", "normal", "mask", "depth")
MIN_RESOLUTION, MAX_RESOLUTION = RESOLUTION_RANGE


@dataclass(frozen=True, eq=False)
class GBuffer:
    """Screen-space geometry at pixel centres; row 0 is the top of the picture.

    ``uv`` (H, W, 2) float32 atlas coordinates, ``normal`` (H, W, 3) float32 world-space
    shading normal (unit), ``mask`` (H, W) bool: the pixel centre sees a material-bearing
    surface, ``depth`` (H, W) float32 metres from the camera plane along the view axis
    (z-depth, not the distance along the ray: what a depth buffer holds). Outside the mask
    uv, normal and depth are 0.
    """

    uv: np.ndarray
    normal: np.ndarray
    mask: np.ndarray
    resolution: int
    camera: Camera
    geometry_digest: str
    #: The Mitsuba variant it was taken with (the render's); seam visibility reuses it.
    variant: str
    depth: np.ndarray

    def layers(self) -> dict[str, np.ndarray]:
        """EXR layers (pipeline.store.exr naming): uv.U/V, normal.X/Y/Z, mask.Y (0 or 1), depth.Z."""
        return {"uv": self.uv, "normal": self.normal, "mask": self.mask.astype(np.float32), "depth": self.depth}


#: A G-buffer's resolution: RenderSettings' ``resolution`` rule.
RESOLUTION = Int(MIN_RESOLUTION, MAX_RESOLUTION)


def check_resolution(resolution) -> int:
    """``resolution`` as an int a G-buffer may have; else a FieldError naming ``resolution``."""
    try:
        return RESOLUTION.check(resolution)
    except Reject:
        raise FieldError("resolution", resolution, RESOLUTION.allowed, name="resolution") from None


def intersection_scene(obj: ObjectLike, camera: Camera, resolution: int, variant: str):
    """The object, its pedestal (if it has one) and the ground with a 1-spp pixel-centre sensor."""
    mi = load_mitsuba(variant)
    scene = {"type": "scene", **shape_dicts(obj, {"type": "diffuse"})}
    scene["sensor"] = sensor_dict(camera, resolution, 1, sampler="stratified-centres", variant=variant)
    return mi.load_dict(scene)


def pixel_centre_rays(scene, resolution: int, variant: str):
    """Primary rays through the pixel centres, bit-identical to a render's.

    Mirrors Mitsuba's SamplingIntegrator: film position = (pixel + sample) * (1 / size)
    with one fused multiply-add, the sample being 0.5 for an unjittered 1-spp
    stratified sampler; time 0; aperture sample irrelevant for a pinhole.
    """
    mi = load_mitsuba(variant)
    import drjit as dr

    index = dr.arange(mi.UInt32, resolution * resolution)
    x = mi.Float(index % resolution)
    y = mi.Float(index // resolution)
    scale = float(np.float32(1.0) / np.float32(resolution))
    position = mi.Point2f(dr.fma(x + 0.5, scale, 0.0), dr.fma(y + 0.5, scale, 0.0))
    sensor = scene.sensors()[0]
    ray, _ = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5, 0.5))
    return ray


def compute_gbuffer(obj: ObjectLike, camera: Camera, resolution: int, variant: str) -> GBuffer:
    """Intersect the pixel-centre rays with the scene; keep hits on the material mesh."""
    resolution = check_resolution(resolution)
    mi = load_mitsuba(variant)
    scene = intersection_scene(obj, camera, resolution, variant)
    ray = pixel_centre_rays(scene, resolution, variant)
    si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
    ball_shape = next(s for s in scene.shapes() if s.id() == BALL_SHAPE_ID)
    hit_ball = si.is_valid() & (si.shape == mi.ShapePtr(ball_shape))
    shape = (resolution, resolution)
    mask = np.array(hit_ball, dtype=bool).reshape(shape)
    uv = np.array(si.uv, dtype=np.float32).T.reshape(shape + (2,))
    normal = np.array(si.sh_frame.n, dtype=np.float32).T.reshape(shape + (3,))
    depth = z_depth(np.array(si.p, dtype=np.float64).T, camera).reshape(shape)
    uv[~mask] = 0.0
    normal[~mask] = 0.0
    depth[~mask] = 0.0
    return GBuffer(uv, normal, mask, resolution, camera, obj.digest, variant, depth)


def z_depth(points: np.ndarray, camera: Camera) -> np.ndarray:
    """float32 (N,) distance of world ``points`` (N, 3) from the camera plane along its view axis.

    Measured from ``camera.origin``, not from the ray's origin: Mitsuba starts a primary ray
    on its near-clip plane (1 cm in front of the origin), so the ray's t misses that much.
    """
    _, _, forward = camera.basis()
    return ((points - np.asarray(camera.origin, np.float64)) @ forward).astype(np.float32)


#: The surfaces a first hit may be on, in the order of :attr:`FirstHits.surface`'s codes.
SURFACES = (BALL_SHAPE_ID, NEUTRAL_SHAPE_ID, GROUND_SHAPE_ID)


@dataclass(frozen=True, eq=False)
class FirstHits:
    """What the pixel-centre rays hit first, every surface of the scene (not cached).

    ``surface`` (H, W) int8: the index in :data:`SURFACES`, -1 where nothing is hit;
    ``uv`` (H, W, 2) and ``normal`` (H, W, 3, world-space shading normal) as in
    :class:`GBuffer`, 0 where nothing is hit. On the material mesh they equal the G-buffer's.
    """

    surface: np.ndarray
    uv: np.ndarray
    normal: np.ndarray


def first_hits(obj: ObjectLike, camera: Camera, resolution: int, variant: str) -> FirstHits:
    """Intersect the pixel-centre rays with the object, its pedestal (if any) and the ground
    (the auxiliary buffers of a denoiser: pipeline.neural.denoise). A surface the scene does
    not hold (the pedestal of an object without one) keeps its code and is never hit."""
    resolution = check_resolution(resolution)
    mi = load_mitsuba(variant)
    scene = intersection_scene(obj, camera, resolution, variant)
    ray = pixel_centre_rays(scene, resolution, variant)
    si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
    shape = (resolution, resolution)
    surface = np.full(shape, -1, np.int8)
    meshes = {s.id(): s for s in scene.shapes()}
    for code, shape_id in enumerate(SURFACES):
        mesh = meshes.get(shape_id)
        if mesh is None:
            continue
        surface[np.array(si.is_valid() & (si.shape == mi.ShapePtr(mesh)), dtype=bool).reshape(shape)] = code
    uv = np.array(si.uv, dtype=np.float32).T.reshape(shape + (2,))
    normal = np.array(si.sh_frame.n, dtype=np.float32).T.reshape(shape + (3,))
    uv[surface < 0] = 0.0
    normal[surface < 0] = 0.0
    return FirstHits(surface, uv, normal)


def view_directions(camera: Camera, resolution: int) -> np.ndarray:
    """(H, W, 3) unit world-space directions of the pixel-centre rays (float64)."""
    right, up, forward = camera.basis()
    tan_half = np.tan(np.radians(camera.fov_deg) / 2.0)
    centres = (np.arange(resolution) + 0.5) / resolution * 2.0 - 1.0
    sx = centres[None, :, None] * tan_half
    sy = centres[:, None, None] * tan_half
    d = forward + sx * right - sy * up
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def facing_mask(gbuffer: GBuffer) -> np.ndarray:
    """(H, W) bool: mask pixels whose shading normal faces the camera.

    At a silhouette the interpolated shading normal can face away from the camera
    though the triangle faces it; Mitsuba's BSDFs and area emitters evaluate to zero
    there (they test the direction in the shading frame), so such pixels (a handful per
    image) render black whatever the material.
    """
    cosine = -np.einsum("ijk,ijk->ij", view_directions(gbuffer.camera, gbuffer.resolution), gbuffer.normal)
    return gbuffer.mask & (cosine > 0)


def gbuffer_key_inputs(obj: ObjectLike, camera: Camera, resolution: int, variant: str) -> dict:
    import mitsuba

    return {
        "variant": variant,
        "geometry": obj.digest,
        "camera": camera.as_dict(),
        "resolution": int(resolution),
        "code": GBUFFER_CODE_VERSION,
        "mitsuba": mitsuba.__version__,
    }


def gbuffer_key(obj: ObjectLike, camera: Camera, resolution: int, variant: str) -> str:
    text = json.dumps(gbuffer_key_inputs(obj, camera, resolution, variant), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def gbuffer_path(obj: ObjectLike, camera: Camera, resolution: int, variant: str, cache_dir: str | None = None) -> str:
    key = gbuffer_key(obj, camera, resolution, variant)
    return os.path.join(cache_dir or default_cache_dir(), "gbuffer", key + ".exr")


def load_gbuffer(
    obj: ObjectLike, camera: Camera, resolution: int, variant: str, cache_dir: str | None = None
) -> GBuffer:
    """The G-buffer from the cache, or computed, stored (atomically) and returned.

    ``variant``: the render's (resolved) Mitsuba variant; the G-buffer is taken with it,
    so the maps see exactly what that render sees, and the cache is keyed by it.
    """
    resolution = check_resolution(resolution)
    load_mitsuba(variant)  # the key names the Mitsuba version; import it the supported way first
    path = gbuffer_path(obj, camera, resolution, variant, cache_dir)
    if os.path.isfile(path):
        try:
            return gbuffer_from_exr(path, obj, camera, resolution, variant)
        except (*USER_ERRORS, KeyError, ValueError):
            pass  # damaged or foreign file: recompute and replace it
    gbuffer = compute_gbuffer(obj, camera, resolution, variant)
    write_exr(path, gbuffer.layers(), gbuffer_key_inputs(obj, camera, resolution, variant))
    return gbuffer


def gbuffer_from_exr(path: str, obj: ObjectLike, camera: Camera, resolution: int, variant: str) -> GBuffer:
    image = read_exr(path, bounds=layer_bounds(resolution, GBUFFER_LAYERS, exact=True))
    if image.meta != gbuffer_key_inputs(obj, camera, resolution, variant):
        raise ValueError(f"{path} was made for other inputs")
    layers = image.layers
    if layers["uv"].shape != (resolution, resolution, 2):
        raise ValueError(f"{path}: uv layer has shape {layers['uv'].shape}")
    return GBuffer(
        uv=layers["uv"].astype(np.float32),
        normal=layers["normal"].astype(np.float32),
        mask=layers["mask"][..., 0] > 0.5,
        resolution=resolution,
        camera=camera,
        geometry_digest=obj.digest,
        variant=variant,
        depth=layers["depth"][..., 0].astype(np.float32),
    )


# --------------------------------------------------------------------------- seams


def visible_seam_points(
    gbuffer: GBuffer, obj: ObjectLike, *, include_creases: bool = True, spacing_px: float = 0.25
) -> np.ndarray:
    """Pixel coordinates (N, 2) of seam points the camera sees, every ``spacing_px``."""
    mi = load_mitsuba(gbuffer.variant)
    camera, res = gbuffer.camera, gbuffer.resolution
    segments = np.asarray(obj.seam_edges, np.float64).reshape(-1, 2, 3)
    if not include_creases:
        segments = segments[~np.asarray(obj.seam_on_crease, bool)]
    if len(segments) == 0:
        return np.zeros((0, 2))
    ends, depth = camera.project(segments.reshape(-1, 3), res)
    ends = ends.reshape(-1, 2, 2)
    in_front = (depth.reshape(-1, 2) > 0).all(1)
    segments, ends = segments[in_front], ends[in_front]
    length_px = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    counts = np.maximum(2, np.ceil(length_px / spacing_px).astype(np.int64) + 1)
    seg_index = np.repeat(np.arange(len(segments)), counts)
    starts = np.cumsum(counts) - counts
    t = (np.arange(counts.sum()) - np.repeat(starts, counts)) / np.repeat(counts - 1, counts)
    points = segments[seg_index, 0] + (segments[seg_index, 1] - segments[seg_index, 0]) * t[:, None]
    xy, _ = camera.project(points, res)
    inside = np.all((xy >= 0) & (xy < res), axis=1)
    points, xy = points[inside], xy[inside]
    if len(points) == 0:
        return np.zeros((0, 2))

    scene = intersection_scene(obj, camera, res, gbuffer.variant)
    origin = np.asarray(camera.origin, np.float64)
    offset = points - origin
    distance = np.linalg.norm(offset, axis=1)
    direction = offset / distance[:, None]
    ray = mi.Ray3f(
        mi.Point3f(*[mi.Float(np.full(len(points), c, np.float32)) for c in origin]),
        mi.Vector3f(*[mi.Float(direction[:, k].astype(np.float32)) for k in range(3)]),
    )
    si = scene.ray_intersect(ray)
    hit_t = np.array(si.t, dtype=np.float64)
    valid = np.array(si.is_valid(), dtype=bool)
    # A seam point is seen when nothing is hit noticeably before it.
    seen = ~valid | (hit_t >= distance * (1.0 - 1e-4))
    return xy[seen]


def seam_band(gbuffer: GBuffer, obj: ObjectLike, px: float = 2.0, *, include_creases: bool = True) -> np.ndarray:
    """(H, W) bool: mask pixels whose centre is within ``px`` pixels of a visible seam."""
    from scipy.spatial import cKDTree

    band = np.zeros_like(gbuffer.mask)
    points = visible_seam_points(gbuffer, obj, include_creases=include_creases, spacing_px=min(0.25, px / 4))
    if len(points) == 0 or not gbuffer.mask.any():
        return band
    rows, cols = np.nonzero(gbuffer.mask)
    centres = np.stack([cols + 0.5, rows + 0.5], 1)
    distance, _ = cKDTree(points).query(centres, k=1, distance_upper_bound=px + 1e-9)
    band[rows, cols] = distance <= px
    return band


def seam_share(gbuffer: GBuffer, obj: ObjectLike, px: float = 2.0, *, include_creases: bool = True) -> float:
    """Share of ball (mask) pixels whose centre is within ``px`` pixels of a visible UV seam.

    ``include_creases=False`` counts only seams that do not run along a crease, where a
    texture discontinuity is not masked by a change of shading.
    """
    count = int(gbuffer.mask.sum())
    if count == 0:
        return 0.0
    return float(seam_band(gbuffer, obj, px, include_creases=include_creases).sum()) / count
