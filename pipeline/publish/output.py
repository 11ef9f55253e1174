"""A folder being written (PUB by publish, DIR by unpack): new or empty to begin with, every
file written atomically, and what this write made removed again when it fails or is refused.

Cleanup removes only its own: the files this write wrote (each only while it is still the
file written: same device and inode) and the folders it created (``out``, missing parents
of it, folders inside it), deepest first, each only if empty (``os.rmdir``). A file that
another process put into one of those folders meanwhile survives, and so does every folder
above it; nothing is removed by walking a tree (no ``rmtree``)."""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Iterator

from pipeline.publish.request import PublishRequest, format_value, out_refused
from pipeline.store.atomic import write_bytes_atomic, write_chunks_atomic
from pipeline.store.folder import CREATABLE, only_temp_files, real_dir, why_not_creatable
from pipeline.store.lock import busy, current_holder, writer_lock

#: An output folder another writer filled between the check and the lock.
FILLED_MEANWHILE = "a new or empty folder (another writer filled it meanwhile; nothing in it is overwritten)"


def check_out(out: str, source: str | None = None, label: str = "DIR", owner=PublishRequest, leftover=None) -> None:
    """PUB (or an unpack's DIR) must be new or an empty folder, and not inside ``source`` (the
    folder read from, which would no longer check): nothing is overwritten. A folder another
    writer is filling is refused as busy (exit code 3), naming it (pipeline.store.lock).
    ``leftover(out)``: whether a folder that is not empty holds only what a killed writer of
    this command left, which the command then replaces (:func:`held_output`'s ``clear``)."""
    if os.path.lexists(out) and (not os.path.isdir(out) or os.path.islink(out) or os.listdir(out)):
        holder = current_holder(out) if real_dir(out) else None
        if holder is not None:
            raise busy(out, holder, label)
        if leftover is None or not real_dir(out) or not leftover(out):
            raise out_refused(out, owner=owner)
    if why := why_not_creatable(out):
        raise owner.field_error("out", out, CREATABLE, what=f"{format_value(out)} {why}")
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
def held_output(out: str, purpose: str, label: str, clear=None) -> Iterator[Output]:
    """``out`` created and held for writing (pipeline.store.lock) while the block writes it;
    on any failure inside, what this write made is removed again (:meth:`Output.discard`: its
    files while the folder is held, its folders once the lock file is gone). A writer that
    took the folder first is refused (exit code 3); one that filled it meanwhile is not
    written over. ``clear(out)`` (where :func:`check_out` found what a killed writer of this
    command left), called instead of that check once the folder is held: remove it and
    return True, or return False (something else came in: refused as filled meanwhile)."""
    output = Output(out)
    try:
        with writer_lock(out, purpose, label):
            if not (clear(out) if clear is not None else only_temp_files(os.listdir(out))):
                raise out_refused(out, FILLED_MEANWHILE)
            try:
                yield output
            except BaseException:
                output.discard()
                raise
    except BaseException:
        output.discard()
        raise


class Output:
    """PUB while it is written: every file atomically; on failure, what this write made is
    removed (:meth:`discard`). ``listed``: keep each file's SHA-256 and size (``sums``,
    ``sizes``), as publish needs for SHA256SUMS; else only their count and total (``files``,
    ``bytes``), as unpack needs."""

    def __init__(self, out: str, listed: bool = True):
        self.out = out
        #: folders this write created (os.mkdir succeeded), in creation order
        self.created_dirs: list[str] = []
        self.root = os.path.abspath(out)
        #: files this write writes: path relative to ``root`` -> (st_dev, st_ino) once written
        #: (None before). Relative: a full path per file grew unpack's memory by ~300 bytes a
        #: render more, as long as the folder's own path.
        self.written: dict[str, tuple[int, int] | None] = {}
        try:
            self._make_dirs(os.path.abspath(out))
        except BaseException:
            self.discard()
            raise
        self.listed = listed
        self.sums: dict[str, str] = {}
        self.sizes: dict[str, int] = {}
        self.files = self.bytes = 0

    def _make_dirs(self, folder: str) -> None:
        """Create ``folder`` and its missing parents one at a time, recording each this process
        created (one another process makes meanwhile is not this write's)."""
        missing = []
        while not os.path.lexists(folder):
            missing.append(folder)
            folder = os.path.dirname(folder)
        for path in reversed(missing):
            try:
                os.mkdir(path)
            except FileExistsError:
                continue
            self.created_dirs.append(path)

    def path(self, rel: str) -> str:
        """Where ``rel`` is written in ``out``: its folders created (and recorded) first, and the
        path recorded as this write's (a writer may fill it through the path itself)."""
        path = os.path.join(self.out, *rel.split("/"))
        self._make_dirs(os.path.dirname(os.path.abspath(path)))
        self.written.setdefault(rel, None)
        return path

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
        """Count the file ``rel`` (written through :meth:`path`) as this write's, as it is now."""
        path = self.path(rel)
        try:
            info = os.lstat(path)
            self.written[rel] = (info.st_dev, info.st_ino)
        except OSError:
            pass
        self.files += 1
        self.bytes += size
        if self.listed:
            self.sums[rel], self.sizes[rel] = sha256, size
        return sha256

    def discard(self) -> None:
        """Remove what this write made, and nothing else: each file it wrote that is still the
        file it wrote (a regular file; the same inode once written), then each folder it
        created, deepest first, if it is empty (``os.rmdir``). Never raises; may be called
        again (after the writer lock's file is gone, its folders go too)."""
        for rel, identity in list(self.written.items()):
            path = os.path.join(self.root, *rel.split("/"))
            try:
                info = os.lstat(path)
                if stat.S_ISREG(info.st_mode) and identity in (None, (info.st_dev, info.st_ino)):
                    os.unlink(path)
            except OSError:
                pass
            del self.written[rel]
        for path in sorted(self.created_dirs, key=lambda p: p.count(os.sep), reverse=True):
            try:
                os.rmdir(path)
            except OSError:
                continue  # not empty (something else is in it), or gone
            self.created_dirs.remove(path)
