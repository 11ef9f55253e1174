"""The README's figure of one material on the four built-in objects under the two shipped
environment maps: ``shaderball figures scenes --out docs/img/scenes.png``.

A 2 x 4 grid: objects across (:data:`geometry.objects.BUILTIN_OBJECTS`), environments down
(:data:`pipeline.figures.environments.ENVIRONMENT_NAMES`, read from the files a spec would
name, ``manifests/environments/*.exr``), each tile path traced as a build renders a sample:
the object and its camera (:func:`geometry.objects.build_object`, ``object_camera``), the
scene and its render (:func:`pipeline.render.renderer.render_sample`) with an
:class:`sky.environment.EnvironmentLight` whose digest is the file's.

Tone map: :func:`pipeline.image.tonemap.preview_srgb8`, one exposure per environment (the
log-average over the four objects' pixels, from their G-buffer masks), so the objects in a
row compare directly and neither map's row is too dark or burnt out.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from geometry.objects import BUILTIN_OBJECTS, build_object, object_camera
from materials import UniformMaterial
from pipeline.errors import ShaderballError
from pipeline.figures.environments import ENVIRONMENT_NAMES, SHIPPED_FOLDER
from pipeline.figures.sun_positions import label
from pipeline.image.tonemap import exposure_for, preview_srgb8
from pipeline.render.envmap import load_environment
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.mitsuba_env import resolve_variant
from pipeline.render.renderer import RenderSettings, render_sample
from pipeline.store.atomic import write_bytes_atomic
from sky.environment import EnvironmentLight

#: Side of a tile (pixels): default, and what the request accepts.
DEFAULT_TILE = 180
TILE_RANGE = (16, 512)
#: Samples per pixel of each tile: default, and what the request accepts.
DEFAULT_SPP = 64
SPP_RANGE = (1, 1024)
#: Tiles at least this wide are labelled (a label is 15 px tall: on a smaller tile it hides it).
LABEL_MIN_TILE = 64
#: The material: a glossy orange dielectric, so the diffuse shading shows the lights' directions
#: and the highlights their shapes (the studio's soft discs, the outdoor sun and sky).
MATERIAL = UniformMaterial(diffuse=(0.50, 0.16, 0.05), specular=(0.04, 0.04, 0.04), roughness=0.15)
#: Rotation of each map (degrees): both as shipped (the key light and the sun to the camera's left).
ROTATION_DEG = {"studio": 0.0, "outdoor": 0.0}
#: The repository's copy of the maps (the figure shows what a spec would be lit by).
ENVIRONMENT_FOLDER = Path(__file__).resolve().parents[2] / SHIPPED_FOLDER


class ScenesFigureError(ShaderballError):
    """The figure's environment map is missing: the message names the file and how to make it."""


def environment_lights(folder: str | os.PathLike = ENVIRONMENT_FOLDER) -> list[EnvironmentLight]:
    """The light of each map in :data:`ENVIRONMENT_NAMES` (``folder/<name>.exr``), digested."""
    lights = []
    for name in ENVIRONMENT_NAMES:
        path = os.path.join(os.fspath(folder), f"{name}.exr")
        if not os.path.isfile(path):
            raise ScenesFigureError(
                f"environment map {path}: no such file; make the maps with "
                f"`python scripts/make_environments.py --out {os.fspath(folder)}`"
            )
        loaded = load_environment(path)
        lights.append(EnvironmentLight(os.path.abspath(path), loaded.digest, ROTATION_DEG[name]))
    return lights


def scenes_grid(
    tile: int = DEFAULT_TILE,
    spp: int = DEFAULT_SPP,
    variant: str = "auto",
    folder: str | os.PathLike = ENVIRONMENT_FOLDER,
    progress: Callable[[str], None] | None = None,
) -> np.ndarray:
    """The figure as uint8 sRGB, (2 tile, 4 tile, 3): row r is environment r, column c object c.
    ``progress`` gets a line before each render."""
    say = progress or (lambda message: None)
    settings = RenderSettings(resolution=tile, spp=spp, variant=resolve_variant(variant))
    lights = environment_lights(folder)
    maps = MATERIAL.to_maps(1)
    images = np.zeros((len(lights), len(BUILTIN_OBJECTS), tile, tile, 3), np.float32)
    masks = np.zeros((len(BUILTIN_OBJECTS), tile, tile), bool)
    count = images.shape[0] * images.shape[1]
    for col, name in enumerate(BUILTIN_OBJECTS):
        obj = build_object(name)
        camera = object_camera(obj)
        masks[col] = load_gbuffer(obj, camera, tile, settings.variant).mask
        for row, light in enumerate(lights):
            index = row * len(BUILTIN_OBJECTS) + col
            say(f"render {index + 1}/{count}: {name} in {ENVIRONMENT_NAMES[row]}")
            images[row, col] = render_sample(obj, camera, maps, light, settings, seed=index).image
    rows = []
    for row, environment in enumerate(ENVIRONMENT_NAMES):
        exposure = exposure_for(images[row].reshape(-1, tile, 3), masks.reshape(-1, tile))
        tiles = [preview_srgb8(image, exposure) for image in images[row]]
        if tile >= LABEL_MIN_TILE:
            tiles = [label(t, f"{name}  {environment}") for t, name in zip(tiles, BUILTIN_OBJECTS)]
        rows.append(np.concatenate(tiles, axis=1))
    return np.concatenate(rows, axis=0)


def write_scenes(
    out: str,
    tile: int = DEFAULT_TILE,
    spp: int = DEFAULT_SPP,
    variant: str = "auto",
    progress: Callable[[str], None] | None = None,
) -> tuple[int, int]:
    """:func:`scenes_grid` as a PNG at ``out`` (written atomically); returns its (width, height)."""
    from PIL import Image

    sheet = scenes_grid(tile, spp, variant, progress=progress)
    buffer = io.BytesIO()
    Image.fromarray(sheet).save(buffer, format="PNG")
    write_bytes_atomic(out, buffer.getvalue())
    return sheet.shape[1], sheet.shape[0]
