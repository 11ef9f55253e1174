"""Contact sheet of procedural SVBRDF examples: ``shaderball figures contact-sheet --out PATH``.

One row per family, ``examples`` materials per row (example k of family f is
drawn from ``SeedSequence([seed, f, k])``). Each
material shows a preview rendered with the numpy reference BRDF (flat
sample 2 x 2 tiled, so seams would show, lit by a flash-like point light near
the camera as in Deschaintre et al.'s inputs) next to its four maps: diffuse
and specular (sRGB-encoded for display), roughness (grey) and the normal
(encoded as (n + 1) / 2).
"""

from __future__ import annotations

import io
from collections.abc import Callable

import numpy as np

from materials.brdf_ref import eval_brdf
from materials.maps import MaterialMaps, encode_normal_map
from materials.svbrdf import MIN_RESOLUTION, SVBRDF_FAMILIES, sample_svbrdf
from pipeline.image.srgb import srgb_encode
from pipeline.store.atomic import write_bytes_atomic

#: Seed of example k of family f: SeedSequence([SHEET_SEED, f, k]).
SHEET_SEED = 2019
#: Materials per family, and the side of their maps in texels.
EXAMPLES_RANGE = (1, 64)
RESOLUTION_RANGE = (MIN_RESOLUTION, 1024)


def flash_preview(maps: MaterialMaps, *, tiles: int = 2, light_intensity: float = 6.0) -> np.ndarray:
    """Linear RGB image of the flat material ``tiles`` x ``tiles`` times, camera and light above it.

    The sample spans [-1, 1]^2 in the z = 0 plane; the camera is at (0, 0, 2.2)
    and a point light at (-0.4, 0.4, 2.2) (slightly off-axis, so the highlight
    shows the normals).
    """
    height, width = maps.resolution
    rows, cols = height * tiles, width * tiles
    x = (np.arange(cols) + 0.5) / cols * 2.0 - 1.0
    y = 1.0 - (np.arange(rows) + 0.5) / rows * 2.0
    p = np.stack(np.broadcast_arrays(x[None, :], y[:, None], np.zeros((rows, 1))), axis=-1)
    camera = np.array([0.0, 0.0, 2.2])
    light = np.array([-0.4, 0.4, 2.2])
    wi = camera - p
    to_light = light - p
    dist2 = np.sum(to_light * to_light, axis=-1, keepdims=True)
    tile = lambda m: np.tile(m, (tiles, tiles) + (1,) * (m.ndim - 2))  # noqa: E731
    radiance = eval_brdf(wi, to_light, tile(maps.normal), tile(maps.diffuse), tile(maps.specular), tile(maps.roughness))
    return radiance * light_intensity / dist2


def _to_8bit(linear: np.ndarray) -> np.ndarray:
    # in float64, as the figure was first drawn (colour-science's encoding): its bytes are the docs'
    linear = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.round(np.clip(srgb_encode(linear), 0.0, 1.0) * 255.0).astype(np.uint8)


def material_tile(maps: MaterialMaps) -> np.ndarray:
    """uint8 (S, 2S, 3) block: preview (S x S) | 2 x 2 maps (each S/2), S = 2 x map side."""
    from PIL import Image

    height, width = maps.resolution
    preview = _to_8bit(flash_preview(maps))
    grey = lambda m: np.repeat(m[..., None], 3, axis=-1)  # noqa: E731
    small = [
        _to_8bit(maps.diffuse),
        _to_8bit(maps.specular),
        np.round(grey(maps.roughness) * 255.0).astype(np.uint8),
        np.round(encode_normal_map(maps.normal) * 255.0).astype(np.uint8),
    ]
    block = np.zeros((2 * height, 2 * width, 3), dtype=np.uint8)
    for k, image in enumerate(small):
        i, j = divmod(k, 2)
        block[i * height : (i + 1) * height, j * width : (j + 1) * width] = image
    preview_img = np.asarray(Image.fromarray(preview))
    return np.concatenate([preview_img, block], axis=1)


def contact_sheet(
    *, examples: int, resolution: int, seed: int = SHEET_SEED, progress: Callable[[str], None] | None = None
) -> np.ndarray:
    """The sheet as a uint8 (H, W, 3) array: rows are families, with a label column.
    ``progress`` gets a line before each family's row."""
    from PIL import Image, ImageDraw

    say = progress or (lambda message: None)
    gap, label_width = 8, 120
    block_h, block_w = 2 * resolution, 4 * resolution
    sheet_h = len(SVBRDF_FAMILIES) * (block_h + gap) + gap + 20
    sheet_w = label_width + examples * (block_w + gap) + gap
    sheet = Image.new("RGB", (sheet_w, sheet_h), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    draw.text(
        (label_width + gap, 4),
        "each material: flash preview (2x2 tiled) | diffuse, specular / roughness, normal",
        fill=(0, 0, 0),
    )
    for f, family in enumerate(SVBRDF_FAMILIES):
        say(f"family {f + 1}/{len(SVBRDF_FAMILIES)}: {family}")
        top = 20 + gap + f * (block_h + gap)
        draw.text((8, top + block_h // 2 - 6), family, fill=(0, 0, 0))
        for k in range(examples):
            rng = np.random.default_rng(np.random.SeedSequence([seed, f, k]))
            block = material_tile(sample_svbrdf(rng, family, resolution))
            sheet.paste(Image.fromarray(block), (label_width + gap + k * (block_w + gap), top))
    return np.asarray(sheet)


def write_contact_sheet(
    out: str,
    *,
    examples: int,
    resolution: int,
    seed: int = SHEET_SEED,
    progress: Callable[[str], None] | None = None,
) -> tuple[int, int]:
    """The sheet as a PNG at ``out`` (written atomically); returns its (width, height). The
    sizes are checked by the command's request (pipeline.figures.command.FiguresRequest)."""
    from PIL import Image

    image = contact_sheet(examples=examples, resolution=resolution, seed=seed, progress=progress)
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    write_bytes_atomic(out, buffer.getvalue())
    return image.shape[1], image.shape[0]
