"""Durable, atomic file writes: a temporary file in the same folder, fsync, rename.

A reader (or a resumed build) sees either the old complete file or the new complete
file, never a torn one, whatever instant the writer is killed at.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile

from pipeline.store.links import refuse_link

#: Prefix of the temporary file of a write in progress (left behind when the writer is
#: killed). pipeline.store.folder tells such files apart by it.
TEMP_PREFIX = ".tmp-"


def _file_mode() -> int:
    """0666 less the process umask: what open() would have given (mkstemp gives 0600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


_FILE_MODE = _file_mode()


def fsync_dir(path: str) -> None:
    """fsync a directory so a rename inside it survives a crash."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_file(path: str, inside: str | None = None):
    """The one atomic writer: an open binary file (``w+b``) whose content replaces ``path``
    when the block ends, durably (fsync of the file, rename, fsync of the folder), with the
    mode a plain ``open`` gives (0666 less the umask). An exception, or a kill, leaves the
    old file whole; the temporary file (:data:`TEMP_PREFIX`) is removed or left to sweep.
    ``inside``: the folder ``path`` is written into (a run or dataset folder): a path that is,
    or passes through, a symbolic link inside it is refused before anything is made
    (:func:`pipeline.store.links.refuse_link`)."""
    if inside is not None:
        refuse_link(inside, path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=TEMP_PREFIX, suffix="-" + os.path.basename(path), dir=folder)
    try:
        os.fchmod(fd, _FILE_MODE)
        with os.fdopen(fd, "w+b") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError) and exc.filename is None:
            exc.filename = path  # a failed write (EFBIG, ENOSPC) names no file: say which
        raise
    fsync_dir(folder)


def write_bytes_atomic(path: str, data: bytes, inside: str | None = None) -> str:
    """Write ``data`` to ``path`` atomically and durably (``inside``: as :func:`atomic_file`);
    return its SHA-256 hex digest."""
    with atomic_file(path, inside) as fh:
        fh.write(data)
    return hashlib.sha256(data).hexdigest()


def write_chunks_atomic(path: str, chunks, inside: str | None = None) -> str:
    """:func:`write_bytes_atomic` of the concatenation of ``chunks`` (bytes), written as they
    come: a large file (a manifest of millions of records) is never held in memory whole."""
    digest = hashlib.sha256()
    with atomic_file(path, inside) as fh:
        for chunk in chunks:
            fh.write(chunk)
            digest.update(chunk)
    return digest.hexdigest()


def write_text_atomic(path: str, text: str, inside: str | None = None) -> str:
    return write_bytes_atomic(path, text.encode("utf-8"), inside)


def sha256_file(path: str, chunk_bytes: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(chunk_bytes), b""):
            digest.update(block)
    return digest.hexdigest()
