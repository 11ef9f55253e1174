"""A folder being written (PUB by publish, DIR by unpack): new or empty to begin with, every
file written atomically, and everything removed again when the write fails or is refused."""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator

from pipeline.publish.request import PublishRequest, format_value, out_refused
from pipeline.store.atomic import write_bytes_atomic, write_chunks_atomic
from pipeline.store.folder import check_creatable, only_temp_files, real_dir
from pipeline.store.lock import busy, current_holder, writer_lock

#: An output folder another writer filled between the check and the lock.
FILLED_MEANWHILE = "a new or empty folder (another writer filled it meanwhile; nothing in it is overwritten)"


def check_out(out: str, source: str | None = None, label: str = "DIR", owner=PublishRequest) -> None:
    """PUB (or an unpack's DIR) must be new or an empty folder, and not inside ``source`` (the
    folder read from, which would no longer check): nothing is overwritten. A folder another
    writer is filling is refused as busy (exit code 3), naming it (pipeline.store.lock)."""
    if os.path.lexists(out) and (not os.path.isdir(out) or os.path.islink(out) or os.listdir(out)):
        holder = current_holder(out) if real_dir(out) else None
        if holder is not None:
            raise busy(out, holder, label)
        raise out_refused(out, owner=owner)
    check_creatable(out)
    if source is not None:
        inner, outer = os.path.realpath(out), os.path.realpath(source)
        if os.path.commonpath([inner, outer]) in (inner, outer):
            raise out_refused(
                out,
                f"a folder outside {format_value(source)} and not containing it (files written "
                "there would make it fail its own checks)",
                owner,
            )


@contextlib.contextmanager
def held_output(out: str, purpose: str, label: str) -> Iterator[Output]:
    """``out`` created and held for writing (pipeline.store.lock) while the block writes it;
    on any failure inside, everything written there is removed again. A writer that took the
    folder first is refused (exit code 3); one that filled it meanwhile is not written over."""
    output = Output(out)
    with writer_lock(out, purpose, label):
        if not only_temp_files(os.listdir(out)):
            raise out_refused(out, FILLED_MEANWHILE)
        try:
            yield output
        except BaseException:
            output.discard()
            raise


class Output:
    """PUB while it is written: every file atomically; on failure, everything written is removed.
    ``listed``: keep each file's SHA-256 and size (``sums``, ``sizes``), as publish needs for
    SHA256SUMS; else only their count and total (``files``, ``bytes``), as unpack needs."""

    def __init__(self, out: str, listed: bool = True):
        self.out = out
        # the outermost folder this write creates (out itself, or a missing parent of it)
        self.created_top = None
        path = os.path.abspath(out)
        while not os.path.lexists(path):
            self.created_top, path = path, os.path.dirname(path)
        os.makedirs(out, exist_ok=True)
        self.listed = listed
        self.sums: dict[str, str] = {}
        self.sizes: dict[str, int] = {}
        self.files = self.bytes = 0

    def path(self, rel: str) -> str:
        return os.path.join(self.out, *rel.split("/"))

    def write(self, rel: str, data: bytes) -> str:
        return self.adopt(rel, write_bytes_atomic(self.path(rel), data), len(data))

    def write_chunks(self, rel: str, chunks) -> str:
        """As :meth:`write`, the file's bytes coming a piece at a time (never held whole); an
        exception from ``chunks`` leaves no file."""
        size = 0

        def counted():
            nonlocal size
            for chunk in chunks:
                size += len(chunk)
                yield chunk

        sha256 = write_chunks_atomic(self.path(rel), counted())
        return self.adopt(rel, sha256, size)

    def adopt(self, rel: str, sha256: str, size: int) -> str:
        self.files += 1
        self.bytes += size
        if self.listed:
            self.sums[rel], self.sizes[rel] = sha256, size
        return sha256

    def discard(self) -> None:
        if self.created_top:
            shutil.rmtree(self.created_top, ignore_errors=True)
            return
        for name in os.listdir(self.out):
            target = os.path.join(self.out, name)
            if os.path.isdir(target) and not os.path.islink(target):
                shutil.rmtree(target, ignore_errors=True)
            else:
                os.unlink(target)
