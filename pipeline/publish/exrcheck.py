"""Read an untrusted EXR's header without OpenEXR, so that nothing decodes a file whose
header would make the decoder allocate absurdly (a 2e9 x 2e9 data window), or that is not
the kind of file a dataset holds (tiled, deep, multi-part)."""

from __future__ import annotations

import struct

from pipeline.publish.refusal import Limits, Refused

MAGIC = b"\x76\x2f\x31\x01"
TILED, LONG_NAMES, DEEP, MULTIPART = 0x200, 0x400, 0x800, 0x1000
#: Scanlines per chunk of each compression (OpenEXR's table; 0 NONE ... 9 DWAB).
LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 16, 8: 32, 9: 256}
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
MAX_CHANNELS = 64


def _cstring(data: bytes, start: int, limit: int, label: str, what: str) -> tuple[str, int]:
    end = data.find(b"\x00", start, start + limit + 1)
    if end < 0:
        raise Refused(
            "exr_header", f"{label}: EXR header: {what} at byte {start} is not terminated within {limit} bytes; refused"
        )
    try:
        return data[start:end].decode("ascii"), end + 1
    except UnicodeDecodeError:
        raise Refused("exr_header", f"{label}: EXR header: {what} at byte {start} is not ASCII; refused") from None


def _channels(value: bytes, label: str) -> list[str]:
    names, at = [], 0
    while True:
        if at >= len(value):
            raise Refused("exr_header", f"{label}: EXR header: the channel list is not terminated; refused")
        if value[at] == 0:
            return names
        name, at = _cstring(value, at, 255, label, "a channel name")
        if at + 16 > len(value):
            raise Refused("exr_header", f"{label}: EXR header: channel {name!r} is cut short; refused")
        pixel_type, _linear, x_sampling, y_sampling = struct.unpack_from("<iB3xii", value, at)
        if pixel_type not in (0, 1, 2) or x_sampling != 1 or y_sampling != 1:
            raise Refused(
                "exr_header",
                f"{label}: EXR header: channel {name!r} has pixel type {pixel_type} and "
                f"sampling {x_sampling}x{y_sampling}; expected a plain half/float/uint "
                "channel; refused",
            )
        names.append(name)
        if len(names) > MAX_CHANNELS:
            raise Refused("exr_header", f"{label}: EXR header: more than {MAX_CHANNELS} channels; refused")
        at += 16


def check_exr_header(data: bytes, label: str, limits: Limits) -> tuple[int, int, list[str]]:
    """(width, height, channel names) of a single-part scanline EXR, or :class:`Refused`."""
    if data[:4] != MAGIC:
        raise Refused("exr_header", f"{label}: not an EXR file (no OpenEXR magic number); refused")
    if len(data) < 8:
        raise Refused("exr_header", f"{label}: EXR file cut short; refused")
    version = struct.unpack_from("<I", data, 4)[0]
    if version & 0xFF != 2 or version & (TILED | DEEP | MULTIPART):
        raise Refused(
            "exr_header",
            f"{label}: EXR version field {version:#x}: only single-part scanline "
            "files (version 2, not tiled, deep or multi-part) are accepted; refused",
        )
    name_limit = 255 if version & LONG_NAMES else 31
    attributes: dict[str, tuple[str, bytes]] = {}
    at = 8
    end_of_header = min(len(data), 8 + limits.exr_header_bytes)
    while True:
        if at >= end_of_header:
            raise Refused(
                "exr_header",
                f"{label}: EXR header runs past {limits.exr_header_bytes} bytes or the end of the file; refused",
            )
        if data[at] == 0:
            at += 1
            break
        name, at = _cstring(data, at, name_limit, label, "an attribute name")
        kind, at = _cstring(data, at, name_limit, label, f"the type of attribute {name!r}")
        if at + 4 > end_of_header:
            raise Refused("exr_header", f"{label}: EXR header: attribute {name!r} is cut short; refused")
        size = struct.unpack_from("<i", data, at)[0]
        at += 4
        if size < 0 or at + size > end_of_header:
            raise Refused(
                "exr_header",
                f"{label}: EXR header: attribute {name!r} says {size} bytes, beyond the "
                f"header cap of {limits.exr_header_bytes} bytes or the file; refused",
            )
        attributes[name] = (kind, data[at : at + size])
        at += size
    missing = [n for n in REQUIRED if n not in attributes]
    if missing:
        raise Refused("exr_header", f"{label}: EXR header lacks {', '.join(missing)}; refused")
    kind, window = attributes["dataWindow"]
    if kind != "box2i" or len(window) != 16:
        raise Refused(
            "exr_header", f"{label}: EXR header: dataWindow is {kind} of {len(window)} bytes, expected box2i; refused"
        )
    x_min, y_min, x_max, y_max = struct.unpack("<4i", window)
    width, height = x_max - x_min + 1, y_max - y_min + 1
    if not (1 <= width <= limits.exr_side and 1 <= height <= limits.exr_side):
        raise Refused(
            "exr_header",
            f"{label}: EXR header says its data window is {width} x {height} pixels; "
            f"at most {limits.exr_side} x {limits.exr_side} are accepted; refused",
        )
    kind, compression = attributes["compression"]
    if kind != "compression" or len(compression) != 1 or compression[0] not in LINES_PER_CHUNK:
        raise Refused("exr_header", f"{label}: EXR header: unknown compression {compression!r}; refused")
    kind, channel_list = attributes["channels"]
    if kind != "chlist":
        raise Refused("exr_header", f"{label}: EXR header: channels is {kind}, expected chlist; refused")
    channels = _channels(channel_list, label)
    chunks = -(-height // LINES_PER_CHUNK[compression[0]])
    if at + 8 * chunks > len(data):
        raise Refused("exr_header", f"{label}: EXR file ends inside its table of {chunks} chunk offsets; refused")
    return width, height, channels
