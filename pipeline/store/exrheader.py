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

**One reading.** The gate reads a header as OpenEXR's own header parser does
(OpenEXRCore's ``parse_header.c``) or refuses it, so that what it bounds is what OpenEXR
decodes. OpenEXR reads attributes in any order; it *merges* a repeated ``channels`` list
and lets a repeated ``dataWindow`` (and other attributes) replace the first; by default it
skips an attribute it cannot read and goes on reading from wherever that left it (a value
of the wrong size for its type can hide attributes the gate would not see); it honours
``type``, ``tiles``, ``chunkCount``, ``version`` and ``name`` besides the eight required
attributes. So the gate refuses any repeated attribute, any attribute whose value OpenEXR
would reject (the fixed size of its type, a malformed list, an enumeration out of range),
those honoured attributes where they would change how the file is read, unknown version
flags, and repeated channel names. :func:`pipeline.store.exr.read_exr` then asks OpenEXR
for the header (without pixels) and refuses the file if OpenEXR reads another channel list
or window than the gate did. Messages give counts and the first few names, never a list.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from pipeline.errors import ShaderballError

MAGIC = b"\x76\x2f\x31\x01"
TILED, LONG_NAMES, DEEP, MULTIPART = 0x200, 0x400, 0x800, 0x1000
#: Every version flag OpenEXR knows; a file with another is refused (by OpenEXR too).
KNOWN_FLAGS = TILED | LONG_NAMES | DEEP | MULTIPART
#: Scanlines per chunk of each compression (OpenEXR's table; 0 NONE ... 9 DWAB).
LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 16, 8: 32, 9: 256}
#: Bytes per sample of each pixel type (0 UINT, 1 HALF, 2 FLOAT).
PIXEL_BYTES = {0: 4, 1: 2, 2: 4}
PIXEL_TYPES = {0: "uint32", 1: "float16", 2: "float32"}
#: The attributes every EXR holds, and their types.
REQUIRED_TYPES = {
    "channels": "chlist",
    "compression": "compression",
    "dataWindow": "box2i",
    "displayWindow": "box2i",
    "lineOrder": "lineOrder",
    "pixelAspectRatio": "float",
    "screenWindowCenter": "v2f",
    "screenWindowWidth": "float",
}
REQUIRED = tuple(REQUIRED_TYPES)
#: Attributes OpenEXR honours besides the required ones (the multi-part and deep attributes),
#: and the type it reads each as: checked below for what they would change.
HONOURED_TYPES = {"type": "string", "tiles": "tiledesc", "chunkCount": "int", "version": "int", "name": "string"}
#: Bytes of a value of each attribute type OpenEXR reads with a fixed size (its table in
#: OpenEXRCore's attributes.c); another size is refused.
FIXED_SIZES = {
    "box2i": 16,
    "box2f": 16,
    "chromaticities": 32,
    "compression": 1,
    "double": 8,
    "envmap": 1,
    "float": 4,
    "int": 4,
    "keycode": 28,
    "lineOrder": 1,
    "m33f": 36,
    "m33d": 72,
    "m44f": 64,
    "m44d": 128,
    "rational": 8,
    "tiledesc": 9,
    "timecode": 8,
    "v2i": 8,
    "v2f": 8,
    "v2d": 16,
    "v3i": 12,
    "v3f": 12,
    "v3d": 24,
    "deepImageState": 1,
}
#: One-byte enumerations: how many values each has (a larger one is refused).
ENUM_VALUES = {"compression": len(LINES_PER_CHUNK), "envmap": 2, "lineOrder": 3, "deepImageState": 4}
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
#: Names a message shows of a list, and characters of each name.
SHOWN_NAMES, SHOWN_CHARS = 3, 40


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

    @property
    def file_bytes(self) -> int:
        """The most bytes a file within these bounds holds: its header, a chunk offset and a
        chunk header (8 bytes each) per scanline at most, and its pixels (OpenEXR stores a
        chunk that does not compress as it is, so no chunk is larger than its pixels)."""
        return self.header_bytes + 16 * self.max_side + self.decoded_bytes


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


def shown(name: str) -> str:
    """A name from a file, as a message shows it: quoted, escaped, cut to SHOWN_CHARS."""
    return repr(name if len(name) <= SHOWN_CHARS else name[:SHOWN_CHARS] + "...")


def shown_names(names, total: int | None = None) -> str:
    """``n name(s): 'a', 'b', 'c', ...``: a count and the first few names."""
    names = list(names)
    total = len(names) if total is None else total
    more = ", ..." if total > SHOWN_NAMES else ""
    return f"{total} ({', '.join(shown(n) for n in names[:SHOWN_NAMES])}{more})"


def _cstring(data: bytes, start: int, limit: int, label: str, what: str) -> tuple[str, int]:
    end = data.find(b"\x00", start, start + limit + 1)
    if end < 0:
        raise ExrRefused(label, f"EXR header: {what} at byte {start} is not terminated within {limit} bytes")
    try:
        return data[start:end].decode("utf-8"), end + 1
    except UnicodeDecodeError:
        raise ExrRefused(label, f"EXR header: {what} at byte {start} is not UTF-8") from None


def _channels(value: bytes, label: str, name_limit: int) -> dict[str, int]:
    """The channel list (name -> pixel type) of a ``chlist`` value, as OpenEXR reads it:
    names of at most ``name_limit`` bytes, each followed by 16 bytes (type, pLinear and three
    reserved bytes, x and y sampling), ended by an empty name at the value's last byte."""
    channels, at = {}, 0
    while True:
        if at >= len(value):
            raise ExrRefused(label, "EXR header: the channel list is not terminated")
        if value[at] == 0:
            if at + 1 != len(value):
                raise ExrRefused(label, f"EXR header: {len(value) - at - 1} byte(s) after the channel list's end")
            return channels
        name, at = _cstring(value, at, name_limit, label, "a channel name")
        if at + 16 > len(value):
            raise ExrRefused(label, f"EXR header: channel {shown(name)} is cut short")
        pixel_type, _linear, x_sampling, y_sampling = struct.unpack_from("<iB3xii", value, at)
        if pixel_type not in PIXEL_BYTES or x_sampling != 1 or y_sampling != 1:
            raise ExrRefused(
                label,
                f"EXR header: channel {shown(name)} has pixel type {pixel_type} and sampling "
                f"{x_sampling}x{y_sampling}; expected a plain half/float/uint channel",
            )
        if name in channels:
            raise ExrRefused(label, f"EXR header: channel {shown(name)} is listed twice")
        channels[name] = pixel_type
        if len(channels) > MAX_CHANNELS:
            raise ExrRefused(label, f"EXR header: more than {MAX_CHANNELS} channels")
        at += 16


def _check_value(name: str, kind: str, value: bytes, label: str, name_limit: int) -> None:
    """Refuse a value OpenEXR would not read as it is (it would skip the attribute, or read
    on from the middle of it): a fixed-size type of another size, an enumeration out of
    range, a malformed list (a channel list under any name included)."""
    where = f"EXR header: attribute {shown(name)} of type {shown(kind)}"
    size = FIXED_SIZES.get(kind)
    if size is not None and len(value) != size:
        raise ExrRefused(label, f"{where} holds {len(value)} bytes; that type has {size}")
    if kind in ENUM_VALUES and value[0] >= ENUM_VALUES[kind]:
        raise ExrRefused(label, f"{where} has the unknown value {value[0]}")
    if kind == "tiledesc" and (value[8] & 0xF >= 3 or value[8] >> 4 >= 2):
        raise ExrRefused(label, f"{where} has an unknown level or rounding mode")
    if kind == "chlist":
        _channels(value, label, name_limit)
    if kind == "floatvector" and len(value) % 4:
        raise ExrRefused(label, f"{where} holds {len(value)} bytes, not a whole number of floats")
    if kind == "stringvector":
        at = 0
        while at < len(value):
            length = struct.unpack_from("<i", value, at)[0] if at + 4 <= len(value) else -1
            if length < 0 or at + 4 + length > len(value):
                raise ExrRefused(label, f"{where}: a string at byte {at} runs past the value's end")
            at += 4 + length
    if kind == "preview":
        width, height = struct.unpack_from("<II", value) if len(value) >= 8 else (0, 0)
        if width * height == 0 or len(value) != 8 + 4 * width * height:
            raise ExrRefused(label, f"{where} says {width} x {height} pixels in {len(value)} bytes")
    if kind == "bytes":
        hint = struct.unpack_from("<i", value)[0] if len(value) >= 4 else -1
        if not 0 <= hint <= len(value) - 4:
            raise ExrRefused(label, f"{where} has a type hint of {hint} bytes in {len(value)}")


def _attributes(data: bytes, label: str, bounds: ExrBounds) -> tuple[dict[str, tuple[str, bytes]], int, int]:
    """The header's attributes (name -> (type, value bytes)), where the header ends, and the
    longest name a channel may have (OpenEXR's long-names flag). Refuses a header OpenEXR
    could read otherwise: a repeated attribute, a value it would reject, unknown flags."""
    if data[:4] != MAGIC:
        raise ExrRefused(label, "not an EXR file (no OpenEXR magic number)")
    if len(data) < 8:
        raise ExrRefused(label, "EXR file cut short")
    version = struct.unpack_from("<I", data, 4)[0]
    if version & 0xFF != 2 or version & (TILED | DEEP | MULTIPART) or version & ~(KNOWN_FLAGS | 0xFF):
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
            return attributes, at + 1, name_limit
        name, at = _cstring(data, at, name_limit, label, "an attribute name")
        kind, at = _cstring(data, at, name_limit, label, f"the type of attribute {shown(name)}")
        if not kind:
            raise ExrRefused(label, f"EXR header: attribute {shown(name)} has no type")
        if at + 4 > end_of_header:
            raise ExrRefused(label, f"EXR header: attribute {shown(name)} is cut short")
        size = struct.unpack_from("<i", data, at)[0]
        at += 4
        if size < 0 or at + size > end_of_header:
            raise ExrRefused(
                label,
                f"EXR header: attribute {shown(name)} says {size} bytes, beyond the header cap of "
                f"{bounds.header_bytes} bytes or the file",
            )
        if name in attributes:  # OpenEXR merges a repeated channel list, keeps the last of others
            raise ExrRefused(
                label,
                f"EXR header: attribute {shown(name)} appears twice (OpenEXR would merge or replace "
                "it; a header is read one way only)",
            )
        value = data[at : at + size]
        _check_value(name, kind, value, label, name_limit)
        attributes[name] = (kind, value)
        at += size


def check_header(data: bytes, label: str, bounds: ExrBounds = DEFAULT_BOUNDS) -> ExrHeader:
    """The header of a single-part scanline EXR whose decoding stays within ``bounds``, or
    :class:`ExrRefused` naming ``label``. Reads the header's bytes only."""
    attributes, end, name_limit = _attributes(data, label, bounds)
    missing = [n for n in REQUIRED if n not in attributes]
    if missing:
        raise ExrRefused(label, f"EXR header lacks {', '.join(missing)}")
    for name, kind in (REQUIRED_TYPES | HONOURED_TYPES).items():
        if name in attributes and attributes[name][0] != kind:
            raise ExrRefused(label, f"EXR header: {name} is {shown(attributes[name][0])}, expected {kind}")
    _, window = attributes["dataWindow"]
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
    compression = attributes["compression"][1][0]
    header = ExrHeader(width, height, _channels(attributes["channels"][1], label, name_limit))
    if header.decoded_bytes > bounds.decoded_bytes:
        raise ExrRefused(label, _too_large(header, bounds))
    chunks = -(-height // LINES_PER_CHUNK[compression])
    _check_honoured(attributes, chunks, label)
    if end + 8 * chunks > len(data):
        raise ExrRefused(label, f"EXR file ends inside its table of {chunks} chunk offsets")
    return header


def _check_honoured(attributes: dict[str, tuple[str, bytes]], chunks: int, label: str) -> None:
    """The attributes OpenEXR honours beyond the required ones, where they would make it read
    the file as another kind or with another chunk table: refused."""
    if "type" in attributes and attributes["type"][1] != b"scanlineimage":
        raise ExrRefused(
            label, f"EXR header: type is {shown(attributes['type'][1].decode('latin-1'))}, not a scanline image"
        )
    if "tiles" in attributes:
        raise ExrRefused(label, "EXR header: a scanline file with a tile description (tiles)")
    if "version" in attributes and struct.unpack("<i", attributes["version"][1])[0] != 1:
        raise ExrRefused(label, "EXR header: version attribute other than 1")
    if "chunkCount" in attributes and struct.unpack("<i", attributes["chunkCount"][1])[0] != chunks:
        raise ExrRefused(label, f"EXR header: chunkCount differs from the {chunks} chunks of its data window")


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
