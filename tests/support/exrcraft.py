"""EXR headers written by hand, attribute by attribute (what a hostile tool could write): any
order, any attribute repeated, any value of any size. ``zeros_exr`` adds valid ZIP-compressed
pixel data of zeros for whatever channel list OpenEXR will read, made without holding the
decoded pixels (a file of a few hundred kB can decode to hundreds of MB)."""

from __future__ import annotations

import struct
import zlib

MAGIC = b"\x76\x2f\x31\x01"
RGB = ("render.B", "render.G", "render.R")
#: Scanlines of a ZIP chunk.
ZIP_LINES = 16


def attribute(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def chlist(names, pixel_type: int = 2) -> bytes:
    """A channel list's value: each name, its pixel type (2 FLOAT) and 1 x 1 sampling."""
    return b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", pixel_type, 0, 1, 1) for n in names) + b"\0"


def box(x0: int, y0: int, x1: int, y1: int) -> bytes:
    return struct.pack("<4i", x0, y0, x1, y1)


def required(width: int = 64, height: int = 64, names=RGB) -> list[tuple[str, str, bytes]]:
    """The eight attributes every EXR holds (ZIP compression), as (name, type, value)."""
    return [
        ("channels", "chlist", chlist(names)),
        ("compression", "compression", b"\x03"),
        ("dataWindow", "box2i", box(0, 0, width - 1, height - 1)),
        ("displayWindow", "box2i", box(0, 0, width - 1, height - 1)),
        ("lineOrder", "lineOrder", b"\0"),
        ("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        ("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0)),
        ("screenWindowWidth", "float", struct.pack("<f", 1.0)),
    ]


def exr(attributes, version: int = 2, chunks: int = 256) -> bytes:
    """A header of ``attributes`` ((name, type, value) tuples, or bytes taken as they are) and
    a table of ``chunks`` zero offsets (room for any window read; never decoded)."""
    body = b"".join(a if isinstance(a, bytes) else attribute(*a) for a in attributes)
    return MAGIC + struct.pack("<I", version) + body + b"\0" + bytes(8 * chunks)


def zeros_exr(attributes, width: int, height: int, channels: int) -> bytes:
    """A valid file: the header of ``attributes``, then ZIP chunks of ``width`` x 16 zeros in
    each of the ``channels`` float channels OpenEXR reads from it (its predictor turns zero
    bytes into 0, 128, 128, ...). ``height`` must be a multiple of 16."""
    assert height % ZIP_LINES == 0
    head = exr(attributes, chunks=0)
    raw = width * ZIP_LINES * channels * 4
    packer = zlib.compressobj(9)
    block = packer.compress(b"\0") + packer.compress(b"\x80" * (raw - 1)) + packer.flush()
    count = height // ZIP_LINES
    start = len(head) + 8 * count
    table = b"".join(struct.pack("<Q", start + k * (8 + len(block))) for k in range(count))
    return head + table + b"".join(struct.pack("<ii", ZIP_LINES * k, len(block)) + block for k in range(count))


def merged_channels_bomb(names, lists: int = 250, side: int = 64) -> bytes:
    """``side`` x ``side`` pixels whose last channel list is ``names`` (what a reader keeping
    the last list sees), after ``lists`` lists of 64 other channels that OpenEXR merges with
    it: 250 lists at 64 px decode to 262 MB from a 0.6 MB file."""
    extra = [("channels", "chlist", chlist([f"c{k:03d}.{i:02d}" for i in range(64)])) for k in range(lists)]
    return zeros_exr(extra + required(side, side, names), side, side, 64 * lists + len(names))
