"""Tar shards: written deterministically, read without trusting them.

Writing: POSIX ustar, regular files only, members in the order given, mtime 0, uid/gid 0,
no user or group names, mode 0644; the same members give the same bytes.

Reading: Python 3.11.7's ``tarfile`` predates the 2025 fixes (CVE-2025-4517, -4330,
-4138, -4435, -8194), so :func:`scan_tar` first parses every 512-byte header itself and
accepts only what :func:`write_member` writes: plain ustar headers with a valid checksum
for regular files whose names fit the layout, below the size and count caps, byte for byte
the header publish writes, zero padding, and nothing but zeros after the end of the archive. Only then does :func:`read_members` stream the
members through ``tarfile``'s ``extractfile`` (never ``extract``/``extractall``), checking
that ``tarfile`` sees exactly the members the scan saw.
"""

from __future__ import annotations

import io
import tarfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from pipeline.publish.names import MEMBER_NAME
from pipeline.publish.refusal import Limits, Refused

BLOCK = 512
RECORD = tarfile.RECORDSIZE  # 20 blocks: tarfile pads an archive to a multiple of it
MEMBER_MODE = 0o644

#: First bytes of compressed files (gzip, bzip2, xz, zstd, lz4, zip, lzma).
COMPRESSED_MAGIC = {
    b"\x1f\x8b": "gzip",
    b"BZh": "bzip2",
    b"\xfd7zXZ\x00": "xz",
    b"\x28\xb5\x2f\xfd": "zstd",
    b"\x04\x22\x4d\x18": "lz4",
    b"PK\x03\x04": "zip",
    b"\x5d\x00\x00": "lzma",
}

#: Header type flags that are not a regular file, and what each is.
OTHER_TYPES = {
    b"1": ("hardlink", "a hard link"),
    b"2": ("symlink", "a symbolic link"),
    b"3": ("device", "a character device"),
    b"4": ("device", "a block device"),
    b"5": ("directory", "a directory"),
    b"6": ("fifo", "a FIFO (named pipe)"),
    b"7": ("contiguous", "a contiguous file"),
    b"S": ("sparse", "a GNU sparse file"),
    b"x": ("pax_header", "a pax extended header"),
    b"g": ("pax_header", "a pax global header"),
    b"L": ("gnu_longname", "a GNU long-name header"),
    b"K": ("gnu_longname", "a GNU long-link header"),
}


@dataclass(frozen=True)
class Member:
    """A regular file inside a tar: its name, where its data starts and its size."""

    name: str
    offset: int
    size: int


def padded(size: int) -> int:
    return -(-size // BLOCK) * BLOCK


def tar_bytes(member_sizes) -> int:
    """The exact size of the tar :func:`write_member` writes for members of these sizes."""
    return tar_size(sum(member_bytes(s) for s in member_sizes))


def member_bytes(size: int) -> int:
    """What a member of ``size`` bytes takes in a tar: its header block and padded data."""
    return BLOCK + padded(size)


def tar_size(members: int) -> int:
    """The exact size of a tar whose members take ``members`` bytes (:func:`member_bytes`):
    two end blocks, padded to a record."""
    return -(-(members + 2 * BLOCK) // RECORD) * RECORD


def open_writer(fileobj) -> tarfile.TarFile:
    return tarfile.open(fileobj=fileobj, mode="w", format=tarfile.USTAR_FORMAT)


def _info(name: str, size: int) -> tarfile.TarInfo:
    info = tarfile.TarInfo(name)
    info.size = size
    info.mtime = 0
    info.mode = MEMBER_MODE
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    info.type = tarfile.REGTYPE
    return info


def member_header(name: str, size: int) -> bytes:
    """The 512 bytes :func:`write_member` writes before a member's data."""
    return _info(name, size).tobuf(tarfile.USTAR_FORMAT, tarfile.ENCODING, "surrogateescape")


def write_member(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    tar.addfile(_info(name, len(data)), io.BytesIO(data))
    # tarfile keeps a TarInfo of every member it writes (~0.8 kB each), which only reading
    # uses: a writer of millions of members keeps none.
    tar.members.clear()


# --------------------------------------------------------------------------- reading


def _octal(field: bytes) -> int | None:
    text = field.replace(b"\x00", b" ").strip()
    if not text or any(c not in b"01234567" for c in text):
        return None
    return int(text, 8)


def _cstring(field: bytes) -> bytes:
    return field.split(b"\x00", 1)[0]


def compression_of(head: bytes) -> str | None:
    for magic, name in COMPRESSED_MAGIC.items():
        if head.startswith(magic):
            return name
    return None


def check_member_name(label: str, name: str) -> None:
    """Refuse a member name that is absolute, climbs, uses backslashes or does not fit the layout."""
    if name.startswith("/"):
        raise Refused("absolute_path", f"{label}: member {name!r} has an absolute path; refused")
    if "\\" in name:
        raise Refused("backslash", f"{label}: member {name!r} contains a backslash; refused")
    if ".." in name.split("/"):
        raise Refused("dotdot", f"{label}: member {name!r} climbs out with '..'; refused")
    if MEMBER_NAME.match(name) is None:
        raise Refused(
            "bad_name",
            f"{label}: member {name!r} does not fit the layout (KEY.FIELD with KEY "
            "mNNNNNN or mNNNNNN_lK and FIELD json, maps.exr, texture.exr, maps.png, render.exr "
            "or render.png); refused",
        )


def _header_name(label: str, header: bytes, position: int) -> str:
    raw = _cstring(header[0:100])
    prefix = _cstring(header[345:500])
    if prefix:
        raw = prefix + b"/" + raw
    try:
        return raw.decode("ascii")
    except UnicodeDecodeError:
        raise Refused(
            "bad_name", f"{label}: the member at byte {position} has a name that is not ASCII ({raw[:60]!r}); refused"
        ) from None


def _refuse_type(label: str, fh, header: bytes, position: int, name: str, size: int | None) -> None:
    flag = header[156:157]
    kind, what = OTHER_TYPES.get(flag, ("unknown_type", f"of unknown type {flag!r}"))
    if kind == "pax_header" and size is not None and size <= 1 << 16:
        fh.seek(position + BLOCK)
        if b"GNU.sparse" in fh.read(size):
            kind, what = "sparse", "a pax-described GNU sparse file"
    link = _cstring(header[157:257]).decode("ascii", "replace")
    target = f" to {link!r}" if link and kind in ("hardlink", "symlink") else ""
    raise Refused(kind, f"{label}: member {name!r} is {what}{target}; only regular files are accepted")


def scan_tar(fh, label: str, limits: Limits, members_before: int = 0) -> list[Member]:
    """Every member of the tar open in ``fh`` (binary, seekable), or :class:`Refused`.

    ``members_before``: members already counted in other tars (the cap is over all).
    """
    length = tar_length(fh, label)
    members: list[Member] = []
    names: set[str] = set()
    for member in iter_headers(fh, label, limits, length):
        if member.name in names:
            raise Refused("duplicate", f"{label}: member {member.name!r} appears twice; refused")
        check_count(label, limits, members_before + len(members) + 1)
        names.add(member.name)
        members.append(member)
    return members


def tar_length(fh, label: str) -> int:
    """The size of the tar open in ``fh``: not compressed, a whole number of blocks; or Refused."""
    fh.seek(0, io.SEEK_END)
    length = fh.tell()
    fh.seek(0)
    head = fh.read(8)
    compression = compression_of(head)
    if compression:
        raise Refused(
            "compressed",
            f"{label}: a {compression}-compressed file, not a plain tar; compressed "
            "shards are refused (publish writes uncompressed ustar)",
        )
    if length % BLOCK or length < 2 * BLOCK:
        raise Refused(
            "not_tar", f"{label}: {length} bytes, not a whole number of 512-byte tar blocks; truncated or not a tar"
        )
    return length


def check_count(label: str, limits: Limits, members: int) -> None:
    if members > limits.members:
        raise Refused("too_many_members", f"{label}: more than {limits.members} members in the publication; refused")


def iter_headers(fh, label: str, limits: Limits, length: int) -> Iterator[Member]:
    """Each member's header of the tar open in ``fh`` (``length`` bytes), checked alone (all
    but the duplicate and the count), in order; the end of the archive checked last."""
    position = 0
    while True:
        fh.seek(position)
        header = fh.read(BLOCK)
        if header == bytes(BLOCK):
            _check_end(fh, label, position, length)
            return
        stored = _octal(header[148:156])
        computed = sum(header[:148]) + 8 * 32 + sum(header[156:])
        if stored is None or stored != computed:
            raise Refused(
                "not_tar",
                f"{label}: the block at byte {position} is not a tar header (its checksum "
                "is wrong); corrupted or not a tar",
            )
        name = _header_name(label, header, position)
        size = _octal(header[124:136])
        if header[156:157] not in (b"0", b"\x00"):
            _refuse_type(label, fh, header, position, name, size)
        if header[257:263] != b"ustar\x00" or header[263:265] != b"00":
            raise Refused(
                "not_ustar",
                f"{label}: member {name!r} has a {header[257:265]!r} header, not POSIX "
                "ustar; publish writes only ustar",
            )
        check_member_name(label, name)
        if _cstring(header[157:257]):
            raise Refused("hardlink", f"{label}: member {name!r} names a link target; only regular files are accepted")
        if size is None:
            raise Refused(
                "not_tar", f"{label}: member {name!r} has a size field that is not octal ({header[124:136]!r}); refused"
            )
        if size > limits.member_bytes:
            raise Refused(
                "member_too_large",
                f"{label}: member {name!r} is {size} bytes, over the cap of {limits.member_bytes} bytes per member",
            )
        if position + BLOCK + padded(size) > length:
            raise Refused("not_tar", f"{label}: member {name!r} says {size} bytes, past the end of the file; truncated")
        if header != member_header(name, size):
            raise Refused(
                "header_fields",
                f"{label}: member {name!r} has a header other than the one publish "
                "writes (mode, owner, time or unused fields differ); refused",
            )
        fh.seek(position + BLOCK + size)
        if any(fh.read(padded(size) - size)):
            raise Refused("not_tar", f"{label}: member {name!r} is followed by non-zero padding; refused")
        yield Member(name=name, offset=position + BLOCK, size=size)
        position += BLOCK + padded(size)


def _check_end(fh, label: str, position: int, length: int) -> None:
    """After the first zero block: a second one, and nothing but zeros to the end."""
    fh.seek(position)
    remaining = length - position
    if remaining < 2 * BLOCK:
        raise Refused("not_tar", f"{label}: the end-of-archive marker at byte {position} is cut short")
    while remaining:
        chunk = fh.read(min(remaining, 1 << 20))
        if not chunk:
            raise Refused("not_tar", f"{label}: ends early at byte {length - remaining}")
        if chunk.count(0) != len(chunk):
            raise Refused("trailing_data", f"{label}: data after the end of the archive (byte {position}); refused")
        remaining -= len(chunk)


def read_members(fh, label: str, members: Iterable[Member]) -> Iterator[tuple[Member, bytes]]:
    """Stream the scanned ``members`` of the tar in ``fh`` through ``tarfile.extractfile``."""
    fh.seek(0)
    with tarfile.open(fileobj=fh, mode="r:") as tar:
        for expected in members:
            info = tar.next()
            if (
                info is None
                or info.name != expected.name
                or info.size != expected.size
                or info.offset_data != expected.offset
                or not info.isreg()
            ):
                seen = "nothing" if info is None else repr(info.name)
                raise Refused(
                    "not_tar", f"{label}: tarfile reads {seen} where the header scan found {expected.name!r}; refused"
                )
            stream = tar.extractfile(info)
            data = stream.read(expected.size)
            if len(data) != expected.size:
                raise Refused("not_tar", f"{label}: member {expected.name!r} is cut short")
            tar.members.clear()  # tarfile keeps a TarInfo of every member read (~0.8 kB each)
            yield expected, data
        if tar.next() is not None:
            raise Refused("not_tar", f"{label}: tarfile reads more members than the header scan found; refused")
