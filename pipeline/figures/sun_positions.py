"""The README's figure of one material under three suns.

shaderball figures sun-positions --out docs/img/sun_positions.png
"""

from __future__ import annotations

import io
from collections.abc import Callable

import numpy as np

from geometry import build_shaderball, default_camera
from materials import UniformMaterial
from pipeline.image.tonemap import exposure_for, preview_srgb8
from pipeline.render.mitsuba_env import resolve_variant
from pipeline.render.renderer import RenderSettings, render_sample
from pipeline.store.atomic import write_bytes_atomic
from sky import Light

#: (elevation_deg, azimuth_deg, turbidity) of the README's three suns.
SUN_POSITIONS = ((60.0, 300.0, 2.5), (25.0, 0.0, 3.0), (6.0, 120.0, 6.0))


def label(image: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    pil = Image.fromarray(image)
    draw = ImageDraw.Draw(pil)
    draw.rectangle([0, 0, pil.width, 14], fill=(0, 0, 0))
    draw.text((3, 2), text, fill=(255, 255, 255))
    return np.asarray(pil)


def sun_positions(
    out: str,
    resolution: int = 240,
    spp: int = 128,
    variant: str = "auto",
    progress: Callable[[str], None] | None = None,
) -> tuple[int, int]:
    """One copper-ish glossy material under three suns, with one shared exposure, as a PNG at
    ``out``; returns its (width, height). ``progress`` gets a line before each render."""
    from PIL import Image

    say = progress or (lambda message: None)
    ball, camera = build_shaderball(), default_camera()
    maps = UniformMaterial((0.35, 0.12, 0.05), (0.25, 0.15, 0.1), 0.3).to_maps(1)
    settings = RenderSettings(resolution=resolution, spp=spp, variant=resolve_variant(variant))
    images = []
    for i, sun in enumerate(SUN_POSITIONS):
        say(f"render {i + 1}/{len(SUN_POSITIONS)}: elevation {sun[0]:g}, azimuth {sun[1]:g}, turbidity {sun[2]:g}")
        images.append(render_sample(ball, camera, maps, Light(*sun), settings, seed=i).image)
    exposure = exposure_for(images[1])
    tiles = [
        label(preview_srgb8(img, exposure), f"elev {e:g}  azim {a:g}  turb {t:g}")
        for img, (e, a, t) in zip(images, SUN_POSITIONS)
    ]
    sheet = np.concatenate(tiles, axis=1)
    buffer = io.BytesIO()
    Image.fromarray(sheet).save(buffer, format="PNG")
    write_bytes_atomic(out, buffer.getvalue())
    return sheet.shape[1], sheet.shape[0]
