"""Decompression bombs, small on disk and made without holding their decoded pixels: an EXR
whose every chunk is the same ZIP-compressed block of zeros, and a PNG of zeros compressed
row by row. Both are valid files: a reader that trusts their headers decodes them whole."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np

LINES_PER_ZIP_CHUNK = 16


def _attribute(header: bytes, name: str) -> int:
    """Where the value of attribute ``name`` starts in ``header``."""
    key = name.encode() + b"\x00"
    at = header.index(key)
    kind_end = header.index(b"\x00", at + len(key))
    return kind_end + 1 + 4


def exr_bomb(width: int, height: int, layers: dict[str, tuple[str, ...]]) -> bytes:
    """A single-part scanline EXR of ``width`` x ``height`` float zeros in the channels
    ``layer.suffix`` of ``layers``, ZIP-compressed: ``height`` must be a multiple of 16. One
    16-line chunk is encoded by OpenEXR; the file repeats it with the header's windows
    widened (a 2048 x 2048 x 6-channel file is ~110 kB and decodes to 100 MB)."""
    import OpenEXR

    assert height % LINES_PER_ZIP_CHUNK == 0
    channels = {
        f"{layer}.{suffix}": np.zeros((LINES_PER_ZIP_CHUNK, width), np.float32)
        for layer, suffixes in layers.items()
        for suffix in suffixes
    }
    buffer = io.BytesIO()
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, channels).write(buffer)
    template = buffer.getvalue()
    # the header ends where the one-entry offset table starts: the offset it holds is its end + 8
    end = next(i for i in range(8, len(template) - 8) if struct.unpack_from("<Q", template, i)[0] == i + 8)
    header = bytearray(template[:end])
    window = struct.pack("<4i", 0, 0, width - 1, height - 1)
    for name in ("dataWindow", "displayWindow"):
        at = _attribute(bytes(header), name)
        header[at : at + 16] = window
    _y, size = struct.unpack_from("<ii", template, end + 8)
    block = template[end + 16 : end + 16 + size]
    chunks = height // LINES_PER_ZIP_CHUNK
    table_end = len(header) + 8 * chunks
    chunk_bytes = 8 + len(block)
    offsets = b"".join(struct.pack("<Q", table_end + k * chunk_bytes) for k in range(chunks))
    body = b"".join(struct.pack("<ii", k * LINES_PER_ZIP_CHUNK, len(block)) + block for k in range(chunks))
    return bytes(header) + offsets + body


def png_bomb(width: int, height: int, mode: str = "L") -> bytes:
    """An 8-bit PNG (grey ``L`` or ``RGB``) of ``width`` x ``height`` zeros, its rows
    compressed one at a time (nothing of its size is held)."""
    channels = {"L": 1, "RGB": 3}[mode]
    colour = {"L": 0, "RGB": 2}[mode]

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    row = bytes(1 + width * channels)  # filter type 0, then zeros
    packer = zlib.compressobj(9)
    data = b"".join(packer.compress(row) for _ in range(height)) + packer.flush()
    header = struct.pack(">IIBBBBB", width, height, 8, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", data) + chunk(b"IEND", b"")


PEAK = """
import atexit, sys
def peak():
    with open("/proc/self/status") as fh:  # VmHWM: this process's own peak, not its parent's
        kib = next(int(line.split()[1]) for line in fh if line.startswith("VmHWM:"))
    with open(sys.argv[1], "w") as out:
        out.write(str(kib / 1024))
atexit.register(peak)
import cli
cli.main(args=sys.argv[2:], prog_name="shaderball")
"""


def peak_of(args: list, note, cwd, timeout: int = 300):
    """(the finished process, its peak resident memory in MB) of ``shaderball ARGS`` run in its
    own process (``note``: a file for the figure)."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-c", PEAK, str(note), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
    )
    return done, float(note.read_text())
