"""A folder being written (PUB by publish, DIR by unpack): new or empty to begin with, every
file written atomically, and everything removed again when the write fails or is refused."""

from __future__ import annotations

import os
import shutil

from pipeline.errors import bad_value
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.folder import check_creatable


def check_out(out: str, source: str | None = None) -> None:
    """PUB (or an unpack's DIR) must be new or an empty folder, and not inside ``source`` (the
    folder read from, which would no longer check): nothing is overwritten."""
    if os.path.lexists(out) and (not os.path.isdir(out) or os.path.islink(out) or os.listdir(out)):
        raise bad_value("--out", out, "a new or empty folder (nothing in it is overwritten)")
    check_creatable(out)
    if source is not None:
        inner, outer = os.path.realpath(out), os.path.realpath(source)
        if os.path.commonpath([inner, outer]) in (inner, outer):
            raise bad_value(
                "--out",
                out,
                f"a folder outside {source!r} and not containing it (files written "
                "there would make it fail its own checks)",
            )


class Output:
    """PUB while it is written: every file atomically; on failure, everything written is removed."""

    def __init__(self, out: str):
        self.out = out
        # the outermost folder this write creates (out itself, or a missing parent of it)
        self.created_top = None
        path = os.path.abspath(out)
        while not os.path.lexists(path):
            self.created_top, path = path, os.path.dirname(path)
        os.makedirs(out, exist_ok=True)
        self.sums: dict[str, str] = {}
        self.sizes: dict[str, int] = {}

    def path(self, rel: str) -> str:
        return os.path.join(self.out, *rel.split("/"))

    def write(self, rel: str, data: bytes) -> str:
        self.sums[rel] = write_bytes_atomic(self.path(rel), data)
        self.sizes[rel] = len(data)
        return self.sums[rel]

    def adopt(self, rel: str, sha256: str, size: int) -> None:
        self.sums[rel], self.sizes[rel] = sha256, size

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
