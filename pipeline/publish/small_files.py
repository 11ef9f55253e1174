"""The files of a publication read without trusting them: a file opened without following a
link (anything but a regular file refused), PUB walked (links, devices and unknown folders
refused), a small file read under its cap, ``SHA256SUMS`` parsed, croissant.json's SHA-256
of each file checked against it, and the shape of a JSON text counted before it is parsed
(:class:`Shape`), so a text whose parse would cost far more memory than its size is refused
first."""

from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass

from pipeline.publish.names import CROISSANT_FILE, DATASET_DIR, SUMS_FILE, allowed_file
from pipeline.publish.refusal import Limits, Refused
from pipeline.store.layout import SHARDS_DIR

HEX = frozenset("0123456789abcdef")


def resized(rel: str, size: int, checked: int) -> Refused:
    return Refused(
        "changed",
        f"{rel}: {size} bytes, {checked} when it was checked: the publication changed while it was read; refused",
    )


def same_as_checked(rel: str, digest: str, checked: str) -> None:
    if digest != checked:
        raise Refused(
            "changed", f"{rel}: its SHA-256 is not the one checked: the publication changed while it was read; refused"
        )


# --------------------------------------------------------------------------- small files


def open_regular(path: str, label: str):
    """Open a file for reading without following a symbolic link; refuse anything but a file."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except FileNotFoundError:
        raise Refused("missing_file", f"{label}: missing") from None
    except OSError as exc:
        raise Refused("not_regular", f"{label}: cannot be opened as a regular file ({exc.strerror}); refused") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise Refused("not_regular", f"{label}: not a regular file; refused")
    return os.fdopen(fd, "rb")


def shown(name: str) -> str:
    """A name from the file system or a tar header, as a one-line message may show it: as is
    when every character prints, else as its repr (a newline never reaches the message raw)."""
    return name if name.isprintable() else repr(name)


def walk_files(root: str, limits: Limits) -> dict[str, int]:
    """Every file under ``root`` (relative path -> size); links, devices and unknown folders refused."""
    files: dict[str, int] = {}
    entries = 0
    pending = [""]
    while pending:
        folder = pending.pop()
        with os.scandir(os.path.join(root, *folder.split("/")) if folder else root) as it:
            for entry in it:
                entries += 1
                if entries > limits.entries:
                    raise Refused(
                        "too_many_files", f"the publication has more than {limits.entries} files and folders; refused"
                    )
                rel = f"{folder}/{entry.name}" if folder else entry.name
                mode = entry.stat(follow_symlinks=False).st_mode
                if stat.S_ISLNK(mode):
                    raise Refused("link", f"{shown(rel)}: a symbolic link inside PUB; refused")
                if stat.S_ISDIR(mode):
                    if folder or entry.name not in (DATASET_DIR, SHARDS_DIR):
                        raise Refused(
                            "unlisted_file", f"{shown(rel + '/')}: a folder that is no part of a publication; refused"
                        )
                    pending.append(rel)
                elif stat.S_ISREG(mode):
                    files[rel] = entry.stat(follow_symlinks=False).st_size
                else:
                    raise Refused(
                        "not_regular", f"{shown(rel)}: not a regular file (a device, FIFO or socket); refused"
                    )
    return files


def read_small(root: str, rel: str, size_cap: int) -> bytes:
    chunks, size = [], 0
    with open_regular(os.path.join(root, *rel.split("/")), rel) as fh:
        # a piece at a time: one read of the cap would allocate all of it, whatever the file's size
        while size <= size_cap and (chunk := fh.read(min(1 << 20, size_cap + 1 - size))):
            chunks.append(chunk)
            size += len(chunk)
    if size > size_cap:
        raise Refused("too_large", f"{rel}: over the cap of {size_cap} bytes for a file read into memory; refused")
    return b"".join(chunks)


def parse_sums(data: bytes) -> dict[str, str]:
    sums: dict[str, str] = {}
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise Refused("bad_sums", f"{SUMS_FILE}: not ASCII text; refused") from None
    for number, line in enumerate(text.split("\n"), start=1):
        if not line:
            continue
        sha, sep, rel = line.partition("  ")
        if not sep or len(sha) != 64 or not set(sha) <= HEX:
            raise Refused("bad_sums", f"{SUMS_FILE} line {number}: not 'SHA256  PATH' ({line[:80]!r}); refused")
        if not allowed_file(rel):
            raise Refused("bad_sums", f"{SUMS_FILE} line {number}: {rel!r} is not a file a publication holds; refused")
        if rel in sums:
            raise Refused("bad_sums", f"{SUMS_FILE} line {number}: {rel!r} is listed twice; refused")
        sums[rel] = sha
    return sums


@dataclass(frozen=True)
class Shape:
    """What one JSON text may hold: bytes, arrays and objects (``[`` and ``{``), values (``,``
    and ``:``). Counted in the bytes before parsing (a bracket inside a string counts too:
    the count can only be too high), so a text whose parse would cost far more memory than
    its size (``[[],[],...]``: ~30x) is refused first."""

    bytes: int
    containers: int
    values: int


def record_shape(limits: Limits) -> Shape:
    return Shape(limits.record_bytes, limits.record_containers, limits.record_values)


def json_structure(data: bytes) -> tuple[int, int]:
    return data.count(b"[") + data.count(b"{"), data.count(b",") + data.count(b":")


def _check_size(size: int, where: str, shape: Shape) -> None:
    if size > shape.bytes:
        raise Refused("too_large", f"{where}: {size} bytes, over the cap of {shape.bytes} for one JSON text; refused")


def parse_json(data: bytes, where: str, shape: Shape):
    _check_size(len(data), where, shape)
    containers, values = json_structure(data)
    if containers > shape.containers or values > shape.values:
        raise Refused(
            "too_complex",
            f"{where}: {containers} JSON arrays/objects and {values} values, over the caps of "
            f"{shape.containers} and {shape.values} (what parsing it may cost in memory); refused before parsing",
        )
    try:
        return json.loads(data)
    except (ValueError, RecursionError) as exc:
        raise Refused("bad_json", f"{where}: not JSON ({str(exc)[:80]}); refused") from None


def check_croissant(texts: dict[str, bytes], sums: dict[str, str], shape: Shape) -> None:
    """croissant.json's SHA-256 of each file must be the one SHA256SUMS lists."""
    metadata = parse_json(texts[CROISSANT_FILE], CROISSANT_FILE, shape)
    objects = metadata.get("distribution") if isinstance(metadata, dict) else None
    if not isinstance(objects, list):
        raise Refused("bad_croissant", f"{CROISSANT_FILE}: no distribution list; refused")
    for entry in objects:
        if isinstance(entry, dict) and entry.get("@type") == "cr:FileObject":
            rel = entry.get("contentUrl")
            if not isinstance(rel, str) or rel not in sums or entry.get("sha256") != sums[rel]:
                raise Refused(
                    "bad_croissant",
                    f"{CROISSANT_FILE}: FileObject {rel!r} has a SHA-256 that is not "
                    f"{SUMS_FILE}'s (or names no file of PUB); refused",
                )
