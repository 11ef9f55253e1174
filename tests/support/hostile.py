"""Helpers for the hostile-input tests: see which files outside a dataset a
command opens (Linux inotify through ctypes), and make a dataset copy to spoil."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import shutil
import struct
from pathlib import Path

IN_ACCESS, IN_OPEN, IN_NONBLOCK, IN_CLOEXEC = 0x1, 0x20, 0o4000, 0o2000000
_EVENT = struct.Struct("iIII")


class OpenWatch:
    """Names opened or read in a folder while the watch runs (any process: a CLI subprocess
    included). ``opened()`` drains the events seen so far."""

    def __init__(self, folder: Path):
        self._libc = ctypes.CDLL(None, use_errno=True)
        self._fd = self._libc.inotify_init1(IN_NONBLOCK | IN_CLOEXEC)
        if self._fd < 0:
            raise OSError(ctypes.get_errno(), "inotify_init1")
        if self._libc.inotify_add_watch(self._fd, os.fsencode(folder), IN_OPEN | IN_ACCESS) < 0:
            raise OSError(ctypes.get_errno(), f"inotify_add_watch {folder}")
        self._seen: list[str] = []

    def opened(self) -> list[str]:
        while True:
            try:
                data = os.read(self._fd, 1 << 16)
            except BlockingIOError:
                break
            except OSError as exc:
                if exc.errno == errno.EAGAIN:
                    break
                raise
            offset = 0
            while offset < len(data):
                _wd, _mask, _cookie, length = _EVENT.unpack_from(data, offset)
                name = data[offset + _EVENT.size : offset + _EVENT.size + length].rstrip(b"\0")
                self._seen.append(os.fsdecode(name) or ".")
                offset += _EVENT.size + length
        return list(self._seen)

    def close(self) -> None:
        os.close(self._fd)


@contextlib.contextmanager
def watch_opens(folder: Path):
    watch = OpenWatch(folder)
    try:
        yield watch
    finally:
        watch.close()


def copy_dataset(reference: Path, dest: Path) -> Path:
    shutil.copytree(reference, dest, symlinks=True)
    return dest


def snapshot(folder: Path) -> dict:
    """rel path -> (size, mtime) of every entry under ``folder`` (links not followed)."""
    out = {}
    for path in sorted(folder.rglob("*")):
        info = path.lstat()
        out[path.relative_to(folder).as_posix()] = (info.st_size, info.st_mtime_ns)
    return out
