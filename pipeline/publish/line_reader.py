"""A text file of a publication read a line at a time: what reading a manifest, a samples
table or a markers file holds is one line (up to its cap) and a read buffer, whatever the
file's size. Lines are split as ``bytes.split(b"\\n")`` splits them, a final newline ending
the last line; an empty line inside is a line."""

from __future__ import annotations

import hashlib

from pipeline.publish.refusal import Refused

#: A read of a file: what a reader holds beyond its longest line (a fixed 64 kB, not a
#: share of the file).
CHUNK_BYTES = 1 << 16


class LineReader:
    """The lines of ``fh`` from its current position; ``digest`` counts every byte read (the
    whole file's SHA-256 once :meth:`next` has returned None from its start)."""

    def __init__(self, fh, rel: str, offset: int = 0):
        self.fh, self.rel = fh, rel
        self.digest = hashlib.sha256()
        self.offset = offset  # where the next line starts in the file
        self.number = 0  # lines returned
        self._buffer = b""
        self._at = 0  # where the next line starts in the buffer
        self._end = False

    def _fill(self) -> bool:
        chunk = self.fh.read(CHUNK_BYTES)
        if not chunk:
            self._end = True
            return False
        self.digest.update(chunk)
        self._buffer = self._buffer[self._at :] + chunk
        self._at = 0
        return True

    def next(self, cap: int, where) -> bytes | None:
        """The next line, without its newline, or None at the end of the file; a line over
        ``cap`` bytes is refused (``where(number)`` names it) after it is counted to its end,
        never held whole."""
        while True:
            newline = self._buffer.find(b"\n", self._at)
            if newline >= 0:
                return self._take(newline, newline + 1, cap, where)
            if len(self._buffer) - self._at > cap:
                self._refuse_long(cap, where)
            if not self._fill():
                if self._at < len(self._buffer):
                    return self._take(len(self._buffer), len(self._buffer), cap, where)
                return None

    def _take(self, end: int, after: int, cap: int, where) -> bytes:
        self.number += 1
        if end - self._at > cap:
            _too_large(where(self.number), end - self._at, cap)
        line = self._buffer[self._at : end]
        self.offset += after - self._at
        self._at = after
        return line

    def _refuse_long(self, cap: int, where) -> None:
        size = len(self._buffer) - self._at
        self._buffer, self._at = b"", 0
        while True:
            chunk = self.fh.read(CHUNK_BYTES)
            newline = chunk.find(b"\n")
            if not chunk or newline >= 0:
                size += newline if newline >= 0 else 0
                _too_large(where(self.number + 1), size, cap)
            size += len(chunk)


def _too_large(where: str, size: int, cap: int) -> None:
    raise Refused("too_large", f"{where}: {size} bytes, over the cap of {cap} for one JSON text; refused")


def scan(fh) -> tuple[str, int, bool]:
    """(SHA-256, number of lines, whether it ends with a newline) of ``fh`` read to its end."""
    digest, lines, last = hashlib.sha256(), 0, b""
    for chunk in iter(lambda: fh.read(CHUNK_BYTES), b""):
        digest.update(chunk)
        lines += chunk.count(b"\n")
        last = chunk[-1:]
    return digest.hexdigest(), lines + (1 if last not in (b"", b"\n") else 0), last == b"\n"
