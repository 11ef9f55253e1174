"""A bounded reader of Radiance .hdr (RGBE) images, in numpy: environment maps users bring.

An .hdr file is a text header (``#?RADIANCE``, ``FORMAT=32-bit_rle_rgbe``, optional
``EXPOSURE=``, an empty line), a resolution line, then one scanline per row: four bytes a
pixel (a shared exponent ``E`` and three mantissas; the value is ``(m + 0.5) 2^(E - 136)``,
0 when ``E = 0``, as Radiance's ``colr_color`` decodes it), stored flat or with the
"new-style" run-length encoding (``2 2 hi lo`` then the four channels one after the
other, each as runs: a count ``c > 128`` repeats the next byte ``c - 128`` times, a count
``1 <= c <= 128`` is followed by ``c`` literal bytes).

The file is untrusted input, so everything it says is bounded before it costs anything:

- the header is read within :data:`HEADER_BYTES`, and only ``-Y H +X W`` (rows top to
  bottom, columns left to right: the orientation every writer uses) is accepted;
- the width, the height and their product are checked against the caller's limits before
  any pixel array is allocated, so a 40-byte file that says 10^6 x 10^6 costs nothing;
- a run may not go past its scanline (the RLE bomb: a count of 255 in a 1-pixel line), a
  scanline must say its own width, and a file that ends inside a scanline, or has bytes
  after the last one, is refused;
- old-style runs (a ``1 1 1 n`` pixel repeating the one before it, from before 1991) are
  refused, not decoded: Radiance's reader would expand them, a plain reader would not.

``EXPOSURE`` lines are honoured (the pixels are divided by their product, as Radiance
defines them); ``COLORCORR`` and ``PRIMARIES`` are not (the map is taken as linear Rec.709,
like everything else here). Errors are :class:`HdrRefused`, naming the file and the reason.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from pipeline.errors import ShaderballError
from pipeline.store.bounded_read import read_bytes

#: Bytes of header (everything before the first scanline) read at most.
HEADER_BYTES = 64 << 10
#: The magic strings a Radiance file may start with.
MAGICS = (b"#?RADIANCE", b"#?RGBE")
#: The pixel format accepted (XYZE files would need a colour conversion: refused).
RGBE_FORMAT = "32-bit_rle_rgbe"
#: New-style RLE is defined for these widths only (the count is two bytes, high bit clear).
RLE_WIDTHS = (8, 0x7FFF)
_RESOLUTION = re.compile(rb"-Y ([0-9]{1,9}) \+X ([0-9]{1,9})")
_ANY_RESOLUTION = re.compile(rb"[-+][XY] [0-9]+ [-+][XY] [0-9]+")


class HdrRefused(ShaderballError):
    """A Radiance file refused: ``reason`` says why (the message names the file too)."""

    def __init__(self, label: str, reason: str):
        super().__init__(f"cannot read Radiance HDR {label}: {reason}")
        self.label = label
        self.reason = reason


@dataclass(frozen=True)
class HdrHeader:
    """What a file's header says: its size, the product of its EXPOSURE lines, and the byte
    where its first scanline starts."""

    width: int
    height: int
    exposure: float
    data_offset: int


def max_file_bytes(max_pixels: int, max_side: int) -> int:
    """The most bytes a file within these limits holds: its header, and per scanline its
    pixels with the worst case of RLE (a literal run of one byte costs two) or flat."""
    return HEADER_BYTES + 4 * max_side + 8 * max_pixels


def min_scanline_bytes(width: int, rle: bool) -> int:
    """The fewest bytes a scanline of ``width`` pixels takes: flat, 4 a pixel; run-length
    encoded, its 4-byte start and per channel one 2-byte run per 127 pixels."""
    return 4 + 4 * 2 * -(-width // 127) if rle else 4 * width


def _header_lines(data: bytes, label: str) -> tuple[list[bytes], bytes, int]:
    """(header lines, resolution line, offset after it)."""
    lines, at = [], 0
    while True:
        end = data.find(b"\n", at, HEADER_BYTES)
        if end < 0:
            raise HdrRefused(label, f"no end of header within its first {HEADER_BYTES} bytes (or the file ends)")
        line = data[at:end]
        at = end + 1
        if not line:  # the empty line ends the header; the resolution line follows
            end = data.find(b"\n", at, HEADER_BYTES)
            if end < 0:
                raise HdrRefused(label, "no resolution line after the header")
            return lines, data[at:end], end + 1
        lines.append(line)


def read_hdr_header(data: bytes, label: str, *, max_pixels: int, max_side: int) -> HdrHeader:
    """The header of the Radiance image ``data`` if it is one this reader decodes within the
    limits (``max_side`` per side, ``max_pixels`` in all); :class:`HdrRefused` otherwise.
    Reads the header's bytes only."""
    if not data.startswith(MAGICS):
        raise HdrRefused(label, "not a Radiance file (it does not start with #?RADIANCE or #?RGBE)")
    lines, resolution, offset = _header_lines(data, label)
    exposure = 1.0
    for line in lines[1:]:
        text = line.decode("latin-1").strip()
        if text.startswith("FORMAT="):
            if text[len("FORMAT=") :].strip() != RGBE_FORMAT:
                raise HdrRefused(label, f"pixel format {text!r}; only FORMAT={RGBE_FORMAT} is read")
        elif text.startswith("EXPOSURE="):
            try:
                value = float(text[len("EXPOSURE=") :])
            except ValueError:
                value = math.nan
            if not (math.isfinite(value) and value > 0.0):
                raise HdrRefused(label, f"header line {text[:40]!r}: EXPOSURE must be a finite number > 0")
            exposure *= value
    match = _RESOLUTION.fullmatch(resolution.strip())
    if match is None:
        shown = resolution[:40].decode("latin-1")
        why = "orientation" if _ANY_RESOLUTION.fullmatch(resolution.strip()) else "resolution line"
        raise HdrRefused(
            label, f"{why} {shown!r}; only '-Y <height> +X <width>' (top to bottom, left to right) is read"
        )
    height, width = int(match.group(1)), int(match.group(2))
    if not (1 <= width <= max_side and 1 <= height <= max_side and width * height <= max_pixels):
        raise HdrRefused(
            label,
            f"the header says {width} x {height} pixels; at most {max_side} per side and "
            f"{max_pixels} pixels in all are read",
        )
    if not (math.isfinite(exposure) and exposure > 0.0):
        raise HdrRefused(label, f"the product of its EXPOSURE lines is {exposure:g}; a finite number > 0 is needed")
    return HdrHeader(width=width, height=height, exposure=exposure, data_offset=offset)


def _rle_channel(data: bytes, at: int, out: np.ndarray, row: int, label: str) -> int:
    """Decode one channel of one new-style scanline into ``out`` (width,), from ``at``;
    return the offset after it. A run may not pass the scanline's end."""
    width, x, size = out.shape[0], 0, len(data)
    while x < width:
        if at >= size:
            raise HdrRefused(label, f"the file ends inside scanline {row}")
        count = data[at]
        at += 1
        if count > 128:
            count -= 128
            if x + count > width or at >= size:
                raise _overrun(label, row, x, count, width, at >= size)
            out[x : x + count] = data[at]
            at += 1
        else:
            if count == 0 or x + count > width or at + count > size:
                raise _overrun(label, row, x, count, width, at + count > size)
            out[x : x + count] = np.frombuffer(data, np.uint8, count, at)
            at += count
        x += count
    return at


def _overrun(label: str, row: int, x: int, count: int, width: int, ended: bool) -> HdrRefused:
    if ended:
        return HdrRefused(label, f"the file ends inside scanline {row}")
    if count == 0:
        return HdrRefused(label, f"scanline {row}: a run of length 0 at pixel {x}")
    return HdrRefused(label, f"scanline {row}: a run of {count} at pixel {x} passes the scanline's {width} pixels")


def _scanlines(data: bytes, header: HdrHeader, label: str) -> np.ndarray:
    """The (H, W, 4) RGBE bytes of the image, decoded scanline by scanline."""
    width, height = header.width, header.height
    at, size = header.data_offset, len(data)
    rle_width = RLE_WIDTHS[0] <= width <= RLE_WIDTHS[1]
    least = height * min_scanline_bytes(width, rle_width)
    if size - at < least:  # before the pixels are allocated: a short file says a large image cheaply
        raise HdrRefused(
            label,
            f"{size - at} bytes of scanlines; {width} x {height} pixels take at least {least} (the file is cut short)",
        )
    rgbe = np.empty((height, width, 4), dtype=np.uint8)
    for row in range(height):
        if at + 4 > size:
            raise HdrRefused(label, f"the file ends before scanline {row} of {height}")
        if rle_width and data[at] == 2 and data[at + 1] == 2 and not data[at + 2] & 0x80:
            said = (data[at + 2] << 8) | data[at + 3]
            if said != width:
                raise HdrRefused(label, f"scanline {row} says it is {said} pixels wide; the header says {width}")
            at += 4
            for channel in range(4):
                at = _rle_channel(data, at, rgbe[row, :, channel], row, label)
        else:
            end = at + 4 * width
            if end > size:
                raise HdrRefused(label, f"the file ends inside scanline {row} of {height}")
            line = np.frombuffer(data, np.uint8, 4 * width, at).reshape(width, 4)
            if np.any((line[:, 0] == 1) & (line[:, 1] == 1) & (line[:, 2] == 1)):
                raise HdrRefused(
                    label, f"scanline {row} holds old-style run-length codes (1 1 1 n), which are not read"
                )
            rgbe[row] = line
            at = end
    if at != size:
        raise HdrRefused(label, f"{size - at} byte(s) after the last scanline")
    return rgbe


def rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """(..., 4) RGBE bytes as (..., 3) float32 radiance: ``(m + 0.5) 2^(E - 136)``, 0 where E = 0."""
    exponent = rgbe[..., 3].astype(np.int32)
    factor = np.where(exponent > 0, np.ldexp(np.float32(1.0), exponent - 136).astype(np.float32), np.float32(0.0))
    return ((rgbe[..., :3].astype(np.float32) + np.float32(0.5)) * factor[..., None]).astype(np.float32)


def decode_hdr(data: bytes, label: str, *, max_pixels: int, max_side: int) -> np.ndarray:
    """The Radiance image ``data`` (bytes of a file named ``label``) as float32 (H, W, 3)
    linear RGB, row 0 at the top; :class:`HdrRefused` for anything outside this reader."""
    header = read_hdr_header(data, label, max_pixels=max_pixels, max_side=max_side)
    radiance = rgbe_to_float(_scanlines(data, header, label))
    if header.exposure != 1.0:
        radiance /= np.float32(header.exposure)
    return radiance


def read_hdr(path: str | os.PathLike, *, max_pixels: int, max_side: int) -> np.ndarray:
    """The Radiance file at ``path`` decoded by :func:`decode_hdr`, read within
    :func:`max_file_bytes` (a larger file is refused before a byte is read)."""
    label = os.fspath(path)
    try:
        data = read_bytes(label, max_file_bytes(max_pixels, max_side))
    except OSError as exc:
        raise HdrRefused(label, exc.strerror or str(exc)) from None
    return decode_hdr(data, label, max_pixels=max_pixels, max_side=max_side)
