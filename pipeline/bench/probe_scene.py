"""A tiny test scene for the sky: a unit ball standing on a square of ground.

Used by the sky tests and ``scripts/sun_benchmark.py``; the dataset's scene is
built by ``pipeline/``. Mitsuba's own BSDFs stand in for the project's material
(diffuse, glossy, near-mirror). Frame as in docs/conventions.md: z up, ground at
z = 0, the ball centred on the z axis.
"""

from __future__ import annotations

import numpy as np

from pipeline.render.mitsuba_env import load_mitsuba

#: Mitsuba BSDFs standing in for the three kinds of material of the hard-case sweep.
MATERIALS = {
    "diffuse": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}},
    "glossy": {
        "type": "roughplastic",
        "distribution": "ggx",
        "alpha": 0.15,
        "diffuse_reflectance": {"type": "rgb", "value": [0.3, 0.3, 0.3]},
    },
    "near_mirror": {"type": "roughconductor", "distribution": "ggx", "alpha": 0.02, "material": "Al"},
}

BALL_RADIUS = 1.0
BALL_CENTER = (0.0, 0.0, 1.0)

#: The tests' scene settings. Mitsuba bakes the film size, the sampler's sample
#: count and the spp of ``mi.render`` into the kernel, so tests sharing these
#: share compiled kernels; render with ``spp`` equal to the preset's.
PRESETS = {
    "side": {"view": "side", "resolution": 24, "spp": 8, "max_depth": 4},
    "top": {"view": "top", "resolution": 48, "spp": 32, "max_depth": 4},
}


def sensor_dict(view: str, resolution: int, spp: int, variant: str, extent: float = 4.5) -> dict:
    """``side``: perspective from the -y side (horizon in frame); ``top``: orthographic from +z.

    The ``top`` view sees the square [-extent, extent]^2 of the ground.
    """
    mi = load_mitsuba(variant)
    T = mi.ScalarTransform4f
    if view == "side":
        to_world = T().look_at(origin=[0.0, -7.0, 1.6], target=[0.0, 0.0, 1.0], up=[0.0, 0.0, 1.0])
        camera = {"type": "perspective", "fov": 40.0, "to_world": to_world}
    elif view == "top":
        to_world = T().look_at(origin=[0.0, 0.0, 10.0], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0])
        camera = {"type": "orthographic", "to_world": to_world @ T().scale([extent, extent, 1.0])}
    else:
        raise ValueError(f"view must be 'side' or 'top', got {view!r}")
    camera["film"] = {
        "type": "hdrfilm",
        "width": resolution,
        "height": resolution,
        "pixel_format": "rgb",
        "rfilter": {"type": "box"},
    }
    camera["sampler"] = {"type": "independent", "sample_count": spp}
    return camera


def probe_scene_dict(
    emitters: dict,
    material: str = "diffuse",
    view: str = "side",
    resolution: int = 32,
    spp: int = 16,
    max_depth: int = 6,
    ground_half_size: float = 5.0,
    *,
    variant: str,
) -> dict:
    """Mitsuba scene dict: ball + ground + ``emitters`` (from :func:`pipeline.render.emitter.emitter_dicts`)."""
    mi = load_mitsuba(variant)
    T = mi.ScalarTransform4f
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": max_depth},
        "sensor": sensor_dict(view, resolution, spp, variant),
        "ball": {"type": "sphere", "center": list(BALL_CENTER), "radius": BALL_RADIUS, "bsdf": MATERIALS[material]},
        "ground": {
            "type": "rectangle",
            "to_world": T().scale([ground_half_size, ground_half_size, 1.0]),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.4, 0.4, 0.4]}},
        },
    }
    scene.update(emitters)
    return scene


def render(mi, scene, spp: int, seed: int):
    """Render ``scene`` to a float64 numpy image (H, W, 3)."""
    return np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)


def pixel_rays(mi, scene):
    """World-space (origins, directions) of every pixel centre's primary ray, each (H, W, 3).

    Uses the sensor's own ``sample_ray``, so pixel (row i, col j) is exactly the
    pixel the integrator writes at image row i, column j.
    """
    import drjit as dr

    sensor = scene.sensors()[0]
    width, height = sensor.film().crop_size()
    j, i = np.meshgrid(np.arange(width), np.arange(height))
    position = mi.Point2f((j.ravel() + 0.5) / width, (i.ravel() + 0.5) / height)
    n = width * height
    ray, _ = sensor.sample_ray(dr.zeros(mi.Float, n), dr.full(mi.Float, 0.5, n), position, dr.full(mi.Point2f, 0.5, n))

    def as_image(v):  # an orthographic camera's directions come back as a single value
        a = np.array(v, dtype=np.float64).reshape(3, -1).T
        return np.broadcast_to(a, (n, 3)).reshape(height, width, 3)

    return as_image(ray.o), as_image(ray.d)
