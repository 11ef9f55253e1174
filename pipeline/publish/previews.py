"""The PNG previews a publication holds beside its EXR files, for people and for the Hugging
Face viewer: a render tone-mapped, and a strip of a material's four maps (diffuse,
specular, roughness, normal), each at most ``PREVIEW_SIDE`` pixels a side.

A preview is a pure function of the EXR bytes: numpy arithmetic, then a PNG written here
(not by Pillow: its encoder, and so the bytes, change with its version), compressed by
zlib at level 9 with one filter for every row. Never used for data: 8-bit, tone-mapped.
An EXR whose header does not pass pipeline.store.exrheader (the resolution, the role's
channels) is never decoded: its preview is a grey placeholder (publish validates first, so
only a forged folder gets one).
"""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np

from pipeline.check.preview import map_tiles
from pipeline.errors import USER_ERRORS
from pipeline.image.tonemap import preview_srgb8
from pipeline.store.exr import ROLE_LAYERS, layer_bounds, read_exr

#: The largest side of a preview tile, in pixels (a 400x400 render gets a 200x200 preview).
PREVIEW_SIDE = 256
MAP_ORDER = ("diffuse", "specular", "roughness", "normal")
PLACEHOLDER = (96, 96, 96)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def encode_png(picture: np.ndarray) -> bytes:
    """uint8 (H, W, 3) as an 8-bit RGB PNG: every row with the Up filter, zlib level 9."""
    picture = np.ascontiguousarray(picture, dtype=np.uint8)
    height, width, channels = picture.shape
    assert channels == 3
    up = picture.astype(np.int16)
    up[1:] -= picture[:-1].astype(np.int16)
    rows = np.concatenate([np.full((height, 1), 2, np.uint8), (up % 256).astype(np.uint8).reshape(height, -1)], axis=1)
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        PNG_SIGNATURE
        + _chunk(b"IHDR", header)
        + _chunk(b"IDAT", zlib.compress(rows.tobytes(), 9))
        + _chunk(b"IEND", b"")
    )


def png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG's IHDR, without decoding it; None if it is not a PNG."""
    if len(data) < 24 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", data[16:24])


def preview_size(role: str, side: int | None) -> tuple[int, int]:
    """(width, height) of the preview ``role`` ("render_preview", or "maps_preview": a strip of
    four tiles) of a dataset of ``side`` pixels a side; None: the most any preview has."""
    tile = PREVIEW_SIDE if side is None else side // preview_factor(side)
    return (len(MAP_ORDER) * tile if role == "maps_preview" else tile), tile


def preview_problem(data: bytes, role: str, side: int | None) -> str | None:
    """What is wrong with ``data`` as the preview ``role`` of a dataset of ``side`` pixels
    (None: of any size; see :func:`preview_size`), or None. Its IHDR is read first: not a
    PNG, or another size (larger than any preview when ``side`` is not known), is said
    without decoding a pixel; then Pillow, opening it as a PNG only, decodes it (the size it
    reads must be the IHDR's, so at most the preview's pixels are decoded) and checks every
    chunk's CRC through IEND: a truncated or corrupt PNG is refused too."""
    from PIL import Image

    size = png_size(data)
    width, height = preview_size(role, side)
    if size is None:
        return "not a PNG"
    if side is not None and size != (width, height):
        return f"a PNG of {size[0]} x {size[1]} pixels; the preview is {width} x {height}"
    if not (0 < size[0] <= width and 0 < size[1] <= height):
        return f"a PNG of {size[0]} x {size[1]} pixels; a preview is at most {width} x {height}"
    try:
        with Image.open(io.BytesIO(data), formats=["PNG"]) as image:
            if image.size != size:
                return f"a PNG Pillow reads as {image.size[0]} x {image.size[1]} pixels, not its IHDR's"
            image.load()
        with Image.open(io.BytesIO(data), formats=["PNG"]) as image:
            image.verify()
    except (OSError, SyntaxError, ValueError, EOFError, struct.error, Image.DecompressionBombError) as exc:
        return f"not a whole PNG ({str(exc)[:120] or type(exc).__name__})"
    return None


def preview_factor(side: int) -> int:
    """The integer factor a ``side``-pixel image is shrunk by to at most PREVIEW_SIDE."""
    return max(1, -(-side // PREVIEW_SIDE))


def shrink(picture: np.ndarray, factor: int) -> np.ndarray:
    """uint8 (H, W, 3) averaged over factor x factor blocks (a remainder is cut off)."""
    if factor == 1:
        return picture
    h, w = picture.shape[0] // factor, picture.shape[1] // factor
    blocks = picture[: h * factor, : w * factor].astype(np.float64).reshape(h, factor, w, factor, 3)
    return (blocks.mean(axis=(1, 3)) + 0.5).astype(np.uint8)


def _layers(data: bytes | None, label: str, side: int) -> dict | None:
    """The layers of a ``side`` x ``side`` render or maps file; None if it is not one."""
    if data is None:
        return None
    try:
        return read_exr(data, label, layer_bounds(side, ROLE_LAYERS[label], exact=True)).layers
    except USER_ERRORS:
        return None


def _placeholder(side: int, tiles: int = 1) -> np.ndarray:
    return np.tile(np.array(PLACEHOLDER, np.uint8), (side, side * tiles, 1))


def render_preview(render_exr: bytes, maps_exr: bytes | None, side: int) -> bytes:
    """The render tone-mapped (pipeline.image.tonemap.preview_srgb8: exposure from the ball's pixels, the
    maps' mask; Reinhard; sRGB), as a PNG of ``side // preview_factor(side)`` pixels a side."""
    factor = preview_factor(side)
    render = _layers(render_exr, "render", side)
    if render is None or "render" not in render:
        return encode_png(_placeholder(side // factor))
    maps = _layers(maps_exr, "maps", side) or {}
    mask = maps.get("mask")
    mask = mask[..., 0] > 0.5 if mask is not None and mask.shape[:2] == render["render"].shape[:2] else None
    return encode_png(shrink(preview_srgb8(render["render"], mask=mask), factor))


def maps_preview(maps_exr: bytes, side: int) -> bytes:
    """A strip of the material's maps as the network sees them, left to right: diffuse and
    specular albedo (sRGB-encoded), roughness (grey), normal ((n + 1) / 2), each shrunk as
    the render preview is."""
    factor = preview_factor(side)
    tile = side // factor
    layers = _layers(maps_exr, "maps", side)
    if layers is None:
        return encode_png(_placeholder(tile, len(MAP_ORDER)))
    pictures = map_tiles(layers)
    strip = []
    for name in MAP_ORDER:
        picture = pictures.get(name)
        strip.append(_placeholder(tile) if picture is None else shrink(picture, factor)[:tile, :tile])
    return encode_png(np.concatenate(strip, axis=1))
