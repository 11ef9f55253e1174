"""An EXR's header read and checked before any pixel is decoded: the one gate every EXR read
from outside passes (a dataset folder, a publication's member, the loader's files).

The header is parsed here in Python, not by OpenEXR, so that nothing of the file reaches the
decoder until it is known what decoding it costs: the data window, the channels and their
types, single-part scanline (not tiled, deep or multi-part), and a table of chunk offsets
the file actually holds. :class:`ExrBounds` says what a file may hold, from what is expected
of it (a render: the spec's resolution, three float channels; maps: the resolution and their
layers' channels): its decoded size is at most ``slack`` times the expected image's (a 2 MB
render of 4096 x 4096 x 32 channels would decode to 2.1 GB); when nothing is expected of it,
at most ``budget_bytes``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from pipeline.errors import ShaderballError

MAGIC = b"\x76\x2f\x31\x01"
TILED, LONG_NAMES, DEEP, MULTIPART = 0x200, 0x400, 0x800, 0x1000
#: Scanlines per chunk of each compression (OpenEXR's table; 0 NONE ... 9 DWAB).
LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 16, 8: 32, 9: 256}
#: Bytes per sample of each pixel type (0 UINT, 1 HALF, 2 FLOAT).
PIXEL_BYTES = {0: 4, 1: 2, 2: 4}
PIXEL_TYPES = {0: "uint32", 1: "float16", 2: "float32"}
REQUIRED = (
    "channels",
    "compression",
    "dataWindow",
    "displayWindow",
    "lineOrder",
    "pixelAspectRatio",
    "screenWindowCenter",
    "screenWindowWidth",
)
#: Channels of any EXR read (a maps file has 11).
MAX_CHANNELS = 64
#: Bytes of header attributes read before the header must have ended.
HEADER_BYTES = 1 << 20
#: Width or height of any EXR read (the largest render resolution and texture_resolution).
MAX_SIDE = 4096
#: Decoded bytes of one file when nothing more is known of it: a 4096 x 4096 float render
#: (201 MB) fits; a 4.7 MB file of 20000 x 20000 x 3 floats (4.8 GB) does not.
BUDGET_BYTES = 256 << 20
#: A file may decode to this many times the expected image (float32 samples) ...
SLACK = 2
#: ... or to this many bytes, whichever is more, so that a small file of the wrong layers is
#: still decoded and reported as such (validate's bad_layers) rather than refused here.
FLOOR_BYTES = 1 << 20


class ExrRefused(ShaderballError):
    """An EXR refused from its header, before decoding: ``reason`` says why (without the
    file's name, which ``label`` holds; the message has both)."""

    def __init__(self, label: str, reason: str):
        super().__init__(f"{label}: {reason}")
        self.label = label
        self.reason = reason


@dataclass(frozen=True)
class ExrBounds:
    """What an EXR may hold. ``shape`` (height, width) and ``channels`` (over all layers) are
    what is expected of it; None: not known, and only ``budget_bytes`` and ``max_side`` bound
    it. ``exact``: a data window other than ``shape`` is refused (readers that need the size,
    such as preview and the loader; validate decodes a small file of the wrong size and says
    what is wrong with it)."""

    shape: tuple[int, int] | None = None
    channels: int | None = None
    exact: bool = False
    slack: int = SLACK
    budget_bytes: int = BUDGET_BYTES
    max_side: int = MAX_SIDE
    header_bytes: int = HEADER_BYTES

    @property
    def expected_bytes(self) -> int | None:
        if self.shape is None or self.channels is None:
            return None
        return self.shape[0] * self.shape[1] * self.channels * 4

    @property
    def decoded_bytes(self) -> int:
        """The most a file may decode to."""
        expected = self.expected_bytes
        if expected is None:
            return self.budget_bytes
        return max(self.slack * expected, FLOOR_BYTES)


#: What any EXR read may hold when nothing is known of it.
DEFAULT_BOUNDS = ExrBounds()


@dataclass(frozen=True)
class ExrHeader:
    """What :func:`check_header` read: the data window's size, each channel's name and type."""

    width: int
    height: int
    channels: dict[str, int]  # name -> pixel type (0 UINT, 1 HALF, 2 FLOAT)

    @property
    def decoded_bytes(self) -> int:
        return self.width * self.height * sum(PIXEL_BYTES[t] for t in self.channels.values())


def megabytes(n: int) -> str:
    return f"{n / 1e6:.3g} MB"


def _cstring(data: bytes, start: int, limit: int, label: str, what: str) -> tuple[str, int]:
    end = data.find(b"\x00", start, start + limit + 1)
    if end < 0:
        raise ExrRefused(label, f"EXR header: {what} at byte {start} is not terminated within {limit} bytes")
    try:
        return data[start:end].decode("ascii"), end + 1
    except UnicodeDecodeError:
        raise ExrRefused(label, f"EXR header: {what} at byte {start} is not ASCII") from None


def _channels(value: bytes, label: str) -> dict[str, int]:
    channels, at = {}, 0
    while True:
        if at >= len(value):
            raise ExrRefused(label, "EXR header: the channel list is not terminated")
        if value[at] == 0:
            return channels
        name, at = _cstring(value, at, 255, label, "a channel name")
        if at + 16 > len(value):
            raise ExrRefused(label, f"EXR header: channel {name!r} is cut short")
        pixel_type, _linear, x_sampling, y_sampling = struct.unpack_from("<iB3xii", value, at)
        if pixel_type not in PIXEL_BYTES or x_sampling != 1 or y_sampling != 1:
            raise ExrRefused(
                label,
                f"EXR header: channel {name!r} has pixel type {pixel_type} and sampling "
                f"{x_sampling}x{y_sampling}; expected a plain half/float/uint channel",
            )
        channels[name] = pixel_type
        if len(channels) > MAX_CHANNELS:
            raise ExrRefused(label, f"EXR header: more than {MAX_CHANNELS} channels")
        at += 16


def _attributes(data: bytes, label: str, bounds: ExrBounds) -> tuple[dict[str, tuple[str, bytes]], int]:
    """The header's attributes (name -> (type, value bytes)) and where the header ends."""
    if data[:4] != MAGIC:
        raise ExrRefused(label, "not an EXR file (no OpenEXR magic number)")
    if len(data) < 8:
        raise ExrRefused(label, "EXR file cut short")
    version = struct.unpack_from("<I", data, 4)[0]
    if version & 0xFF != 2 or version & (TILED | DEEP | MULTIPART):
        raise ExrRefused(
            label,
            f"EXR version field {version:#x}: only single-part scanline files (version 2, "
            "not tiled, deep or multi-part) are accepted",
        )
    name_limit = 255 if version & LONG_NAMES else 31
    attributes: dict[str, tuple[str, bytes]] = {}
    at = 8
    end_of_header = min(len(data), 8 + bounds.header_bytes)
    while True:
        if at >= end_of_header:
            raise ExrRefused(label, f"EXR header runs past {bounds.header_bytes} bytes or the end of the file")
        if data[at] == 0:
            return attributes, at + 1
        name, at = _cstring(data, at, name_limit, label, "an attribute name")
        kind, at = _cstring(data, at, name_limit, label, f"the type of attribute {name!r}")
        if at + 4 > end_of_header:
            raise ExrRefused(label, f"EXR header: attribute {name!r} is cut short")
        size = struct.unpack_from("<i", data, at)[0]
        at += 4
        if size < 0 or at + size > end_of_header:
            raise ExrRefused(
                label,
                f"EXR header: attribute {name!r} says {size} bytes, beyond the header cap of "
                f"{bounds.header_bytes} bytes or the file",
            )
        attributes[name] = (kind, data[at : at + size])
        at += size


def check_header(data: bytes, label: str, bounds: ExrBounds = DEFAULT_BOUNDS) -> ExrHeader:
    """The header of a single-part scanline EXR whose decoding stays within ``bounds``, or
    :class:`ExrRefused` naming ``label``. Reads the header's bytes only."""
    attributes, end = _attributes(data, label, bounds)
    missing = [n for n in REQUIRED if n not in attributes]
    if missing:
        raise ExrRefused(label, f"EXR header lacks {', '.join(missing)}")
    kind, window = attributes["dataWindow"]
    if kind != "box2i" or len(window) != 16:
        raise ExrRefused(label, f"EXR header: dataWindow is {kind} of {len(window)} bytes, expected box2i")
    x_min, y_min, x_max, y_max = struct.unpack("<4i", window)
    width, height = x_max - x_min + 1, y_max - y_min + 1
    side = bounds.max_side
    if not (1 <= width <= side and 1 <= height <= side):
        raise ExrRefused(
            label,
            f"EXR header says its data window is {width} x {height} pixels; at most {side} x {side} are accepted",
        )
    if bounds.exact and bounds.shape is not None and (height, width) != tuple(bounds.shape):
        raise ExrRefused(
            label,
            f"EXR header says its data window is {width} x {height} pixels; expected "
            f"{bounds.shape[1]} x {bounds.shape[0]} (the spec's resolution)",
        )
    kind, compression = attributes["compression"]
    if kind != "compression" or len(compression) != 1 or compression[0] not in LINES_PER_CHUNK:
        raise ExrRefused(label, f"EXR header: unknown compression {compression!r}")
    kind, channel_list = attributes["channels"]
    if kind != "chlist":
        raise ExrRefused(label, f"EXR header: channels is {kind}, expected chlist")
    header = ExrHeader(width, height, _channels(channel_list, label))
    if header.decoded_bytes > bounds.decoded_bytes:
        raise ExrRefused(label, _too_large(header, bounds))
    chunks = -(-height // LINES_PER_CHUNK[compression[0]])
    if end + 8 * chunks > len(data):
        raise ExrRefused(label, f"EXR file ends inside its table of {chunks} chunk offsets")
    return header


def _too_large(header: ExrHeader, bounds: ExrBounds) -> str:
    said = (
        f"EXR header says {header.width} x {header.height} pixels of {len(header.channels)} "
        f"channel(s): {megabytes(header.decoded_bytes)} decoded"
    )
    if bounds.expected_bytes is None:
        return f"{said}; at most {megabytes(bounds.decoded_bytes)} are decoded"
    height, width = bounds.shape
    return (
        f"{said}; at most {megabytes(bounds.decoded_bytes)} are decoded for a file expected to "
        f"hold {width} x {height} pixels of {bounds.channels} channel(s)"
    )
