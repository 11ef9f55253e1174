"""Reading a file of a dataset folder, which is untrusted input (anyone may have edited it):

- a path named in a manifest, record or marker is opened only through :func:`resolve_inside`:
  a plain relative path (no ``..``, not absolute, no backslash), every component of it inside
  the folder and none a symbolic link; a path that fails is never followed
  (:class:`UnsafePath`);
- files are opened with ``O_NOFOLLOW | O_NONBLOCK`` and read only when they are regular files
  (a FIFO or a device is refused at once, it never blocks), and only within a size bound
  given by every caller (:func:`read_bytes`, the one whole-file reader): the size a record
  gives the file (:class:`Recorded`: a data file is read only at exactly that size), or a
  declared budget where nothing records it (:data:`MAX_JSON_BYTES` for a record, a
  description or a spec; markers and the manifest by the plan's count of renders). A file
  outside its bound is refused before a byte is read (:class:`OverBound`, naming the file,
  its size and the bound): a render grown to 8 GB costs a ``stat``, not 8 GB;
- a JSON text is parsed only when its structure is within what its records may hold
  (:func:`structure_problem`).

The folder given by the user (DIR itself) may be a symbolic link: that is their choice.
What is checked is everything below it. Between the check of a path and its opening, a
process that can write the folder could swap a component for a link; the last component is
opened with ``O_NOFOLLOW``, the ones before it are not re-checked (a writer with that access
can write the data itself anyway)."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass

#: Largest record file, description or spec read from a folder (a record is ~3 kB).
MAX_JSON_BYTES = 1 << 20
#: Largest marker or manifest without a plan to size them by (the paper's 250,000 renders
#: make a ~800 MB manifest).
MAX_LIST_BYTES = 1 << 32


class UnsafePath(OSError):
    """A path that leaves the folder, passes through a symbolic link, or names something that
    is not a regular file, or a file over its size bound: never followed, never read.
    ``strerror`` says which (an OSError, so callers that report unreadable files report it)."""

    def __init__(self, path: str, reason: str):
        super().__init__(errno.EPERM, reason, path)


def list_bound(renders: int | None) -> int:
    """Size bound of a marker or manifest listing ``renders`` records."""
    return MAX_LIST_BYTES if renders is None else 4096 + renders * MAX_JSON_BYTES


def rel_problem(rel) -> str | None:
    """Why ``rel`` is not a plain relative path inside a folder (None when it is)."""
    if not isinstance(rel, str) or not rel:
        return f"{rel!r} is not a path"
    if rel.startswith("/") or "\\" in rel or "\0" in rel or ":" in rel.split("/")[0]:
        return f"{rel!r} is absolute or not a plain relative path"
    if any(part in ("", ".", "..") for part in rel.split("/")):
        return f"{rel!r} leaves the folder or is not a plain relative path ('..', '.' or an empty part)"
    return None


def file_kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISLNK, "a symbolic link"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISDIR, "a directory"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def resolve_inside(root: str, rel) -> str:
    """The path of ``rel`` (a path a record names, relative to DIR with forward slashes)
    inside ``root``, after checking that it stays there: UnsafePath if it is absolute, has a
    ``..``, or passes through a symbolic link (none is followed). A part that does not exist
    ends the walk: opening the path then fails with FileNotFoundError."""
    problem = rel_problem(rel)
    if problem:
        raise UnsafePath(str(rel), f"{problem}: it is not followed")
    path = root
    for part in rel.split("/"):
        path = os.path.join(path, part)
        try:
            mode = os.lstat(path).st_mode
        except FileNotFoundError:
            break
        except OSError:
            break  # e.g. ENOTDIR: opening it reports the reason
        if stat.S_ISLNK(mode):
            where = os.path.relpath(path, root).replace(os.sep, "/")
            raise UnsafePath(rel, f"{where} is a symbolic link (to {os.readlink(path)!r}): not followed")
    return path


def unsafe_entry(root: str, rel) -> str | None:
    """Why ``rel`` may not be opened inside ``root`` (None when it may)."""
    try:
        resolve_inside(root, rel)
    except UnsafePath as exc:
        return exc.strerror
    return None


@dataclass(frozen=True)
class Recorded:
    """The size a record gives a file, and the file that says so as validate names it
    (``manifest.jsonl``, a marker): a bound :func:`read_bytes` reads the file within only at
    exactly this size (larger, it was grown; smaller, truncated; either way not read)."""

    size: int
    listed_by: str = "its record"


#: What bounds one read: a :class:`Recorded` size, or a budget in bytes (at most this many).
Bound = Recorded | int


class OverBound(UnsafePath):
    """A regular file whose size is not within its bound: not read. ``strerror`` gives its size
    and the bound, in validate's words for a recorded size (``9013 bytes, manifest.jsonl says
    18026: the file was truncated``)."""

    def __init__(self, path: str, size: int, bound: Bound):
        self.size, self.bound = size, bound
        if isinstance(bound, Recorded):
            how = "truncated" if size < bound.size else "grown"
            reason = f"{size} bytes, {bound.listed_by} says {bound.size}: the file was {how}"
        else:
            reason = f"{size} bytes, over the {bound}-byte bound for this file"
        super().__init__(path, reason)


def _limit(bound: Bound) -> int:
    """The most bytes a read within ``bound`` takes; TypeError for anything but a bound (no
    read is unbounded: a caller with no recorded size declares a budget)."""
    if isinstance(bound, Recorded):
        return bound.size
    if isinstance(bound, int) and not isinstance(bound, bool):
        return bound
    raise TypeError(f"a read needs a bound (a Recorded size or a budget in bytes), not {bound!r}")


def _open_regular(path: str, bound: Bound | None) -> tuple[int, int]:
    """(fd, size) of the regular file at ``path``, opened without following a final symbolic
    link and without blocking on a FIFO; UnsafePath when it is not a regular file, OverBound
    when its size is not within ``bound`` (None: the caller bounds what it reads itself)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise UnsafePath(path, "a symbolic link: not followed") from None
        raise
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        os.close(fd)
        raise UnsafePath(path, f"{file_kind(info.st_mode)}, not a regular file: not read")
    if bound is not None and (
        info.st_size > _limit(bound) or (isinstance(bound, Recorded) and info.st_size != bound.size)
    ):
        os.close(fd)
        raise OverBound(path, info.st_size, bound)
    return fd, info.st_size


def _chunks(fd: int, path: str, limit: int | None, size: int = 1 << 20):
    total = 0
    while True:
        chunk = os.read(fd, size)
        if not chunk:
            return
        total += len(chunk)
        if limit is not None and total > limit:
            raise UnsafePath(path, f"grew past the {limit}-byte bound for this file while read: not read")
        yield chunk


def read_bytes(path: str, bound: Bound) -> bytes:
    """The bytes of the regular file at ``path``, if its size is within ``bound``: the size a
    record gives it (:class:`Recorded`: exactly that) or a budget (at most that many bytes).
    The one whole-file reader of a dataset, publication, run or report file: a file outside
    its bound is refused before anything is read (:class:`OverBound`), a file that grows while
    read too; not through a final symbolic link, never from a FIFO or a device (UnsafePath).
    FileNotFoundError and other OSErrors pass through."""
    limit = _limit(bound)
    fd, _size = _open_regular(path, bound)
    try:
        return b"".join(_chunks(fd, path, limit))
    finally:
        os.close(fd)


def read_chunks(path: str, bound: Bound) -> Iterator[bytes]:
    """The bytes of the regular file at ``path`` a chunk at a time, as :func:`read_bytes`
    reads them (opened by the call: OSErrors are raised by it)."""
    limit = _limit(bound)
    fd, _size = _open_regular(path, bound)

    def chunks():
        try:
            yield from _chunks(fd, path, limit)
        finally:
            os.close(fd)

    return chunks()


def file_digest(path: str, bound: Bound) -> tuple[int, str]:
    """(size, SHA-256 hex) of the regular file at ``path``, read as :func:`read_bytes` reads
    (streamed: a large render is not held in memory)."""
    limit = _limit(bound)
    fd, _size = _open_regular(path, bound)
    digest, size = hashlib.sha256(), 0
    try:
        for chunk in _chunks(fd, path, limit):
            digest.update(chunk)
            size += len(chunk)
    finally:
        os.close(fd)
    return size, digest.hexdigest()


#: What one record may hold, counted in its bytes before it is parsed: arrays and objects
#: (``[``, ``{``) and values (``,``, ``:``); a record of the smoke dataset holds 26 and 179.
#: Parsing ``[[],[],...]`` costs ~30 times its size in memory: a parse is bounded by the
#: structure of what is parsed, not only by its size (a bracket inside a string counts too:
#: the count can only be too high).
RECORD_CONTAINERS = 256
RECORD_VALUES = 4096


def structure_problem(data: bytes, records: int = 1) -> str | None:
    """Why ``data`` holds more JSON structure than ``records`` records may (None if not)."""
    containers = data.count(b"[") + data.count(b"{")
    values = data.count(b",") + data.count(b":")
    if containers <= RECORD_CONTAINERS * records and values <= RECORD_VALUES * records:
        return None
    return (
        f"{containers} JSON arrays/objects and {values} values, more than {records} record(s) may hold "
        f"(at most {RECORD_CONTAINERS} and {RECORD_VALUES} each): not parsed"
    )


def read_json_checked(path: str, limit: int = MAX_JSON_BYTES):
    """(value, None) for a readable JSON file, else (None, why: 'missing', 'a FIFO, ...').
    Its structure is bounded by its size bound: one record's per :data:`MAX_JSON_BYTES`."""
    try:
        data = read_bytes(path, limit)
    except FileNotFoundError:
        return None, "missing"
    except OSError as exc:
        return None, exc.strerror or str(exc)
    too_much = structure_problem(data, -(-limit // MAX_JSON_BYTES) + 1)
    if too_much:
        return None, too_much
    try:
        return json.loads(data.decode("utf-8")), None
    except (UnicodeDecodeError, ValueError) as exc:
        return None, f"not JSON (torn or edited: {exc})"
    except RecursionError:
        return None, "not JSON this reader accepts (nested too deeply)"


def read_json(path: str, limit: int = MAX_JSON_BYTES):
    """A JSON file's content, or None when it is missing, torn, unsafe or over ``limit``."""
    return read_json_checked(path, limit)[0]


#: Bytes read at a time by :func:`iter_lines`: a few records' worth, so what a reader of lines
#: holds does not grow with the file up to a larger chunk.
LINE_CHUNK = 1 << 16


def iter_lines(path: str, bound: Bound) -> Iterator[tuple[int, int, bytes]]:
    """(line number from 1, byte offset, bytes without the newline) of every line of the
    regular file at ``path``, read a chunk at a time (as :func:`read_bytes` reads: no link, no
    FIFO, within ``bound``, OverBound beyond), so only one line is held at a time.
    The file is opened before the first line is asked for: OSErrors are raised by the call."""
    limit = _limit(bound)
    fd, _size = _open_regular(path, bound)
    return _lines_of(fd, path, limit)


def _lines_of(fd: int, path: str, limit: int | None) -> Iterator[tuple[int, int, bytes]]:
    number, offset, parts = 0, 0, []  # parts: the line so far (a long line is not re-copied per chunk)
    try:
        for chunk in _chunks(fd, path, limit, LINE_CHUNK):
            start = 0
            while (end := chunk.find(b"\n", start)) >= 0:
                line = b"".join([*parts, chunk[start:end]]) if parts else chunk[start:end]
                parts = []
                number += 1
                yield number, offset, line
                offset += len(line) + 1
                start = end + 1
            if start < len(chunk):
                parts.append(chunk[start:])
        if parts:
            yield number + 1, offset, b"".join(parts)
    finally:
        os.close(fd)


def read_line_at(path: str, offset: int, limit: int) -> bytes:
    """The line of the regular file at ``path`` that starts at byte ``offset`` (a line
    :func:`iter_lines` found), without its newline; at most ``limit`` bytes are read."""
    fd, _size = _open_regular(path, None)
    try:
        data = os.pread(fd, limit + 1, offset)
    finally:
        os.close(fd)
    return data.split(b"\n", 1)[0]
