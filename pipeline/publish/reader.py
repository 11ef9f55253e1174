"""Reading a publication without trusting it: `shaderball verify`, the first pass of
`shaderball unpack`, and :func:`iter_samples` for the training stage.

:func:`open_publication` checks the small files: it refuses links and unlisted files,
checks every file's SHA-256 against ``SHA256SUMS`` (tars are checked when they are
opened), checks every manifest path against the layout before any is used, and checks
that the manifest, ``samples.jsonl`` and the markers agree, a line at a time (what it
keeps is a few counts and ids, not the files: memory bounded by structure). Each tar
pair's rows are a :class:`Section` of those files; :meth:`Publication.section` reads one
again (its SHA-256 as checked) and derives the exact members each tar of the pair must
hold, in order, with their sizes and SHA-256. :meth:`Publication.members` then streams one
tar: its SHA-256 first, then every header (pipeline.publish.tarsafe), then each member,
whose size, SHA-256, EXR header or record must be the expected one. Any difference raises
:class:`~pipeline.publish.refusal.Refused` naming the file and member.
:meth:`Publication.locate` streams every tar so and says where each checked member's bytes
lie; :func:`read_located` reads one again there (the training stage's map-style loader,
pipeline.neural.data).
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from array import array
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

from pipeline.publish.exrcheck import check_exr_header, member_bounds
from pipeline.publish.line_reader import CHUNK_BYTES, LineReader, scan
from pipeline.publish.names import (
    CROISSANT_FILE,
    DATASET_DIR,
    FORMAT,
    FORMAT_VERSION,
    INDEX_FILE,
    MARKERS_REL,
    MATERIALS,
    OPTIONAL_FILES,
    PLAIN_FILES,
    RENDERS,
    SAMPLES_FILE,
    SHARDS_DIR,
    SOURCE_FILES,
    SUMS_FILE,
    TAR_KINDS,
    TAR_NAME,
    allowed_file,
    paired_tar,
    tar_rel,
)
from pipeline.publish.previews import preview_problem
from pipeline.publish.refusal import DEFAULT_LIMITS, Limits, Refused
from pipeline.publish.request import VerifyRequest, format_value
from pipeline.publish.table import (
    PREVIEW_ROLES,
    FileRef,
    file_refs,
    material_member,
    material_row,
    preview_member,
    record_member,
    sample_row,
)
from pipeline.publish.tarsafe import Member, check_count, iter_headers, read_members, scan_tar, tar_length
from pipeline.store.folder import (
    OverBound,
    Recorded,
    field_type_problem,
    json_type_name,
    read_bytes,
    read_manifest,
    resolve_inside,
    short_json,
    structure_problem,
)
from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, SPEC_FILE, Layout
from pipeline.store.records import dumps, without_timings

HEX = frozenset("0123456789abcdef")
MANIFEST_REL = SOURCE_FILES[MANIFEST_FILE]
#: The files read a line at a time, never whole.
LINE_FILES = (MANIFEST_REL, SAMPLES_FILE, MARKERS_REL)


@dataclass(frozen=True)
class Expected:
    """A member a tar must hold: its name, what it is, its size and SHA-256, and where it
    lives in the dataset folder (``path``, relative, the layout's)."""

    name: str
    role: str  # maps, texture, record, render
    size: int
    sha256: str
    path: str | None  # None for a member derived by publish (a preview, a material's row)
    sample_id: str | None
    material_id: str
    record: bytes | None = None  # a lighting's members: its manifest line


@dataclass(frozen=True)
class Located:
    """Where a member checked by :meth:`Publication.locate` lies: its tar (relative to PUB) and
    that tar's size when checked, the member's name, the offset and size of its bytes, and
    its SHA-256 (the manifest's). :func:`read_located` reads it again without ``tarfile``."""

    tar: str
    tar_size: int
    name: str
    offset: int
    size: int
    sha256: str


@dataclass
class TarEntry:
    rel: str
    sha256: str
    size: int
    number: int
    kind: str  # materials, renders
    count: int = 0  # the members it must hold


@dataclass(frozen=True)
class Section:
    """Where the rows of one tar pair lie: the number of their first line in the manifest
    (and ``samples.jsonl``, line for line), how many, their offsets in both files, and the
    SHA-256 of those lines as :func:`open_publication` checked them (each manifest line and
    its row, each with a newline)."""

    first_line: int
    lines: int
    manifest_offset: int
    table_offset: int
    sha256: str


class SourceFiles(Mapping):
    """spec.toml, dataset.json, manifest.jsonl: bytes as published. The manifest is read
    when asked for (its SHA-256 checked again); use :meth:`Publication.manifest_chunks` to
    stream it."""

    def __init__(self, publication: Publication, small: dict[str, bytes]):
        self._publication, self._small = publication, small

    def __getitem__(self, name: str) -> bytes:
        if name == MANIFEST_FILE:
            return b"".join(self._publication.manifest_chunks())
        return self._small[name]

    def __iter__(self):
        return iter(SOURCE_FILES)

    def __len__(self) -> int:
        return len(SOURCE_FILES)


@dataclass
class Publication:
    """A publication whose small files have been checked (:func:`open_publication`)."""

    root: str
    limits: Limits
    sums: dict[str, str]
    sizes: dict[str, int]
    small_files: dict[str, bytes]  # spec.toml, dataset.json (by name)
    tars: list[TarEntry]
    index: dict
    samples: int
    materials: int
    sections: dict[int, Section]  # tar pair number -> its rows
    shards: list[str]  # the source shards, in the manifest's (and markers.jsonl's) order
    marker_bytes: int  # the longest line of markers.jsonl

    def __post_init__(self):
        self.source_files = SourceFiles(self, self.small_files)
        #: what each role's EXR members may hold (pipeline.publish.exrcheck.member_bounds)
        self.exr_bounds = member_bounds(self.small_files.get(SPEC_FILE, b""))

    def path(self, rel: str) -> str:
        return os.path.join(self.root, *rel.split("/"))

    @property
    def description(self) -> dict:
        return json.loads(self.small_files[DESCRIPTION_FILE])

    def expected(self, tar: TarEntry) -> Iterator[Expected]:
        """The members ``tar`` must hold, in order, derived again from its pair's rows."""
        at = self.sections.get(tar.number)
        return iter(()) if at is None else _section_members(self, tar.kind, at)

    def members(self, tar: TarEntry, before: int = 0) -> Iterator[tuple[Expected, bytes]]:
        """Every member of ``tar``, checked, in order (``before``: members of earlier tars)."""
        for expected, _member, data in self.checked_members(tar, before):
            yield expected, data

    def checked_members(self, tar: TarEntry, before: int = 0) -> Iterator[tuple[Expected, Member, bytes]]:
        """As :meth:`members`, with where each member's bytes lie in the tar (``Member``)."""
        label = tar.rel
        with _open_regular(self.path(tar.rel), label) as fh:
            digest = hashlib.sha256()
            for block in iter(lambda: fh.read(CHUNK_BYTES), b""):
                digest.update(block)
            if digest.hexdigest() != tar.sha256:
                raise Refused(
                    "checksum",
                    f"{label}: SHA-256 {digest.hexdigest()[:16]}... differs from {SUMS_FILE}'s "
                    f"{tar.sha256[:16]}...: the file changed or is corrupt; nothing of it is read",
                )
            where = _scan_in_order(fh, label, self.limits, before, self.expected(tar))
            if where is None:  # the first difference, named as a scan of every header names it
                _compare_members(label, scan_tar(fh, label, self.limits, before), list(self.expected(tar)))
                raise AssertionError(f"{label}: members differ from the expected ones, yet each compares equal")
            offsets, sizes = where
            slot: list[Expected] = []

            def scanned():  # each member as the scan found it; its Expected in ``slot``
                for i, expected in enumerate(self.expected(tar)):
                    slot[:] = [expected]
                    yield Member(expected.name, offsets[i], sizes[i])

            for member, data in read_members(fh, label, scanned()):
                _check_member(label, member, data, slot[0], self.limits, self.exr_bounds)
                yield slot[0], member, data

    def locate(self, progress: Callable[[str], None] | None = None) -> dict[str, Located]:
        """Check every tar and member (as `shaderball verify` does) and say where each member's
        bytes lie: the dataset-folder path of each file (``Expected.path``) -> :class:`Located`."""
        found: dict[str, Located] = {}
        before = 0
        for tar in self.tars:
            if progress:
                progress(tar.rel)
            for expected, member, _data in self.checked_members(tar, before):
                if expected.path is None:  # a preview or a material's row: no file of the dataset
                    continue
                found[expected.path] = Located(
                    tar.rel, tar.size, member.name, member.offset, member.size, expected.sha256
                )
            before += tar.count
        return found

    def manifest_chunks(self) -> Iterator[bytes]:
        """manifest.jsonl as published, a piece at a time, no more bytes than it had when checked
        (a file grown since is refused before it is read); Refused at its end when its bytes are
        not those checked (the caller discards what it made of them)."""
        checked = self.sizes[MANIFEST_REL]
        with _open_regular(self.path(MANIFEST_REL), MANIFEST_REL) as fh:
            if os.fstat(fh.fileno()).st_size != checked:
                raise _resized(MANIFEST_REL, os.fstat(fh.fileno()).st_size, checked)
            digest, read = hashlib.sha256(), 0
            for chunk in iter(lambda: fh.read(CHUNK_BYTES), b""):
                read += len(chunk)
                if read > checked:
                    raise _resized(MANIFEST_REL, read, checked)
                digest.update(chunk)
                yield chunk
        _same(MANIFEST_REL, digest.hexdigest(), self.sums[MANIFEST_REL])

    def markers(self) -> Iterator[tuple[str, bytes]]:
        """(shard id, its COMPLETE.json bytes) for each line of markers.jsonl, as checked; Refused
        at the end when the file's bytes are not those checked."""
        with _open_regular(self.path(MARKERS_REL), MARKERS_REL) as fh:
            lines = LineReader(fh, MARKERS_REL)
            for shard in self.shards:
                line = lines.next(self.marker_bytes, lambda n: f"{MARKERS_REL} line {n}")
                if line is None:
                    break
                yield shard, line + b"\n"
        _same(MARKERS_REL, lines.digest.hexdigest(), self.sums[MARKERS_REL])


def _resized(rel: str, size: int, checked: int) -> Refused:
    return Refused(
        "changed",
        f"{rel}: {size} bytes, {checked} when it was checked: the publication changed while it was read; refused",
    )


def _same(rel: str, digest: str, checked: str) -> None:
    if digest != checked:
        raise Refused(
            "changed", f"{rel}: its SHA-256 is not the one checked: the publication changed while it was read; refused"
        )


# --------------------------------------------------------------------------- small files


def _open_regular(path: str, label: str):
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


def _walk(root: str, limits: Limits) -> dict[str, int]:
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


def _read_small(root: str, rel: str, size_cap: int) -> bytes:
    chunks, size = [], 0
    with _open_regular(os.path.join(root, *rel.split("/")), rel) as fh:
        # a piece at a time: one read of the cap would allocate all of it, whatever the file's size
        while size <= size_cap and (chunk := fh.read(min(1 << 20, size_cap + 1 - size))):
            chunks.append(chunk)
            size += len(chunk)
    if size > size_cap:
        raise Refused("too_large", f"{rel}: over the cap of {size_cap} bytes for a file read into memory; refused")
    return b"".join(chunks)


def _parse_sums(data: bytes) -> dict[str, str]:
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


def _structure(data: bytes) -> tuple[int, int]:
    return data.count(b"[") + data.count(b"{"), data.count(b",") + data.count(b":")


def _check_size(size: int, where: str, shape: Shape) -> None:
    if size > shape.bytes:
        raise Refused("too_large", f"{where}: {size} bytes, over the cap of {shape.bytes} for one JSON text; refused")


def _json(data: bytes, where: str, shape: Shape):
    _check_size(len(data), where, shape)
    containers, values = _structure(data)
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


def open_publication(root: str, limits: Limits = DEFAULT_LIMITS) -> Publication:
    """Check the small files of the publication at ``root``; see the module's docstring."""
    if not os.path.isdir(root):
        why = "is not a folder" if os.path.lexists(root) else "does not exist"
        raise VerifyRequest.field_error(
            "pub", root, "a folder written by `shaderball publish`", what=f"{format_value(root)} {why}"
        )
    files = _walk(root, limits)
    if SUMS_FILE not in files:
        raise Refused("missing_file", f"{SUMS_FILE}: missing; PUB is not a (finished) publication")
    total = sum(files.values())
    if total > limits.total_bytes:
        raise Refused(
            "too_large", f"the publication holds {total} bytes, over the cap of {limits.total_bytes}; refused"
        )
    sums = _parse_sums(_read_small(root, SUMS_FILE, limits.text_bytes))
    for rel in sorted(set(files) - set(sums) - {SUMS_FILE}):
        raise Refused("unlisted_file", f"{shown(rel)}: not listed in {SUMS_FILE}; refused")
    for rel in sorted(set(sums) - set(files)):
        raise Refused("missing_file", f"{rel}: listed in {SUMS_FILE} but missing")
    for rel in PLAIN_FILES:
        if rel not in sums and rel not in OPTIONAL_FILES:
            raise Refused("missing_file", f"{rel}: missing from the publication")
    texts: dict[str, bytes] = {}
    counts: dict[str, tuple[int, bool]] = {}  # lines, and whether the last ends with a newline
    for rel in sorted(r for r in sums if not TAR_NAME.match(r)):
        if rel in LINE_FILES:
            with _open_regular(os.path.join(root, *rel.split("/")), rel) as fh:
                digest, lines, newline = scan(fh)
            counts[rel] = lines, newline
        else:
            data = _read_small(root, rel, limits.text_bytes)
            digest = hashlib.sha256(data).hexdigest()
            texts[rel] = data
        if digest != sums[rel]:
            raise Refused("checksum", f"{rel}: SHA-256 differs from {SUMS_FILE}'s; the file changed or is corrupt")
    samples, shards = _manifest(root, sums, limits)
    metadata = Shape(
        limits.text_bytes,
        4096 + limits.json_containers_per_file * len(sums),
        65536 + limits.json_values_per_file * len(sums),
    )
    index = _json(texts[INDEX_FILE], INDEX_FILE, metadata)
    tars = _tars(index, sums, files)
    if counts[SAMPLES_FILE][0] != samples:
        raise Refused("bad_table", f"{SAMPLES_FILE}: {counts[SAMPLES_FILE][0]} rows for {samples} manifest records")
    _check_croissant(texts, sums, metadata)
    lines, newline = counts[MARKERS_REL]
    if not newline or lines != shards:
        raise Refused("bad_marker", f"{MARKERS_REL}: expected one line per source shard ({shards}); refused")
    checked = _check_rows(root, sums, tars, limits)
    small = {name: texts[rel] for name, rel in SOURCE_FILES.items() if rel in texts}
    _json(small[DESCRIPTION_FILE], SOURCE_FILES[DESCRIPTION_FILE], metadata)
    return Publication(
        root=root,
        limits=limits,
        sums=sums,
        sizes=files,
        small_files=small,
        tars=tars,
        index=index,
        samples=samples,
        **checked,
    )


def _checked_record(line: bytes, where: str, shape: Shape) -> dict:
    """A manifest line's record: its shape before it is parsed, then the layout of its ids and
    paths and the types of its fields."""
    record = _json(line, where, shape)
    file_refs(record, where)
    why = field_type_problem(record)
    if why:
        raise Refused("bad_record", f"{where}: {why}; refused")
    return record


def _manifest(root: str, sums: dict[str, str], limits: Limits) -> tuple[int, int]:
    """(records, source shards) of the manifest, every line checked (:func:`_checked_record`),
    its id unique, each shard's records adjacent (as a build writes them), one at a time."""
    rel = MANIFEST_REL
    shape = record_shape(limits)
    ids: set[str] = set()
    done: set[str] = set()
    shard = None
    with _open_regular(os.path.join(root, *rel.split("/")), rel) as fh:
        lines = LineReader(fh, rel)
        while (line := lines.next(shape.bytes, lambda n: f"{rel} line {n}")) is not None:
            number = lines.number
            if number > limits.members:
                raise Refused(
                    "too_many_members", f"{rel}: more than {limits.members} lines (the cap on members); refused"
                )
            where = f"{rel} line {number}"
            record = _checked_record(line, where, shape)
            if record["id"] in ids:
                raise Refused("duplicate", f"{where}: a second record for {record['id']}; refused")
            ids.add(record["id"])
            if record["shard"] != shard:
                if record["shard"] in done:
                    raise Refused(
                        "bad_marker",
                        f"{where} ({record['id']}): the records of shard {record['shard']} are not "
                        "adjacent (a build writes each shard's together); refused",
                    )
                if shard is not None:
                    done.add(shard)
                shard = record["shard"]
    _same(rel, lines.digest.hexdigest(), sums[rel])
    if not ids:
        raise Refused("bad_record", f"{rel}: no records")
    return len(ids), len(done) + 1


def _tars(index, sums: dict[str, str], files: dict[str, int]) -> list[TarEntry]:
    if not isinstance(index, dict) or index.get("format") != FORMAT or index.get("format_version") != FORMAT_VERSION:
        raise Refused("bad_index", f"{INDEX_FILE}: not a {FORMAT} version {FORMAT_VERSION} index; refused")
    shards = index.get("shards")
    listed = sorted(r for r in sums if TAR_NAME.match(r))
    if not isinstance(shards, list) or [s.get("path") if isinstance(s, dict) else None for s in shards] != listed:
        raise Refused("bad_index", f"{INDEX_FILE}: its shards are not the tars {SUMS_FILE} lists ({len(listed)})")
    numbers = {
        kind: [TAR_NAME.match(r).group(2) for r in listed if TAR_NAME.match(r).group(1) == kind] for kind in TAR_KINDS
    }
    for kind in TAR_KINDS:
        if numbers[kind] != [f"{n:06d}" for n in range(len(numbers[MATERIALS]))]:
            raise Refused(
                "bad_index",
                f"{SHARDS_DIR}/{kind}-*.tar: tars must be numbered from 000000 without gaps, "
                "a materials tar and a renders tar for each number",
            )
    for number, rel in enumerate(listed):
        said = shards[number].get("bytes")
        if isinstance(said, bool) or not isinstance(said, int):
            raise Refused(
                "bad_index",
                f"{rel}: {INDEX_FILE} gives its size as {json_type_name(said)} ({short_json(said)}), "
                f"not an integer number of bytes (the file has {files[rel]})",
            )
        if said != files[rel]:
            raise Refused("bad_index", f"{rel}: {files[rel]} bytes, {INDEX_FILE} says {said}")
    return [
        TarEntry(rel, sums[rel], files[rel], int(TAR_NAME.match(rel).group(2)), TAR_NAME.match(rel).group(1))
        for rel in listed
    ]


def _sum_and_size(row: dict, column: str, limits: Limits) -> tuple[str, int] | None:
    """A row's (SHA-256, size) of a member it names (``column``_sha256, ``column``_bytes), or None."""
    sha, size = row.get(f"{column}_sha256"), row.get(f"{column}_bytes")
    if (
        not (isinstance(sha, str) and len(sha) == 64 and set(sha) <= HEX)
        or isinstance(size, bool)
        or not isinstance(size, int)
        or not 0 <= size <= limits.member_bytes
    ):
        return None
    return sha, size


@dataclass(frozen=True)
class Row:
    """One manifest line and its ``samples.jsonl`` row, checked against each other."""

    number: int
    line: bytes
    record: dict
    refs: dict[str, FileRef]
    tar: TarEntry  # its renders tar
    material_row: dict  # the row of its material (pipeline.publish.table.material_row)
    record_sha256: str
    record_bytes: int
    previews: dict[str, tuple[str, int]]


def _row(number: int, line: bytes, row_line: bytes, by_rel: dict[str, TarEntry], limits: Limits) -> Row:
    """The manifest's line ``number`` and the table's row of that number, which must be the
    row that line gives; any disagreement is refused."""
    manifest = MANIFEST_REL
    record = _checked_record(line, f"{manifest} line {number}", record_shape(limits))
    row = _json(row_line, f"{SAMPLES_FILE} line {number}", record_shape(limits))
    tar_rel = row.get("shard") if isinstance(row, dict) else None
    sums = {c: _sum_and_size(row, c, limits) for c in ("record", *PREVIEW_ROLES)} if isinstance(row, dict) else {}
    if (
        not isinstance(tar_rel, str)
        or tar_rel not in by_rel
        or TAR_NAME.match(tar_rel).group(1) != RENDERS
        or not sums
        or None in sums.values()
    ):
        raise Refused(
            "bad_table",
            f"{SAMPLES_FILE} line {number}: no valid shard, record_sha256 and record_bytes "
            "(or preview SHA-256 and size); refused",
        )
    sha, size = sums["record"]
    previews = {role: sums[role] for role in PREVIEW_ROLES}
    expected_row = sample_row(record, tar_rel, sha, size, previews)
    if dumps(expected_row).encode("utf-8") != row_line:
        raise Refused(
            "bad_table",
            f"{SAMPLES_FILE} line {number}: differs from the row {manifest} line {number} ({record['id']}) gives; refused",
        )
    refs = file_refs(record, f"{manifest} line {number}")
    return Row(number, line, record, refs, by_rel[tar_rel], material_row(expected_row), sha, size, previews)


def _shared_of(row: Row) -> dict:
    """What every lighting of a material must agree on: its maps' (and texture's) SHA-256 and
    size, and its maps preview's."""
    shared = {r: (row.refs[r].sha256, row.refs[r].bytes) for r in ("maps", "texture") if r in row.refs}
    shared["maps_preview"] = row.previews["maps_preview"]
    return shared


def _material_members(row: Row) -> list[Expected]:
    """A material's members in its materials tar: its row, maps (and texture), maps preview."""
    material = row.record["material_id"]
    data = (dumps(row.material_row) + "\n").encode("utf-8")
    members = [
        Expected(
            material_member(material), "material", len(data), hashlib.sha256(data).hexdigest(), None, None, material
        )
    ]
    members += [_shared(row.refs[role], material) for role in ("maps", "texture") if role in row.refs]
    members.append(_preview(row.record, "maps_preview", row.previews, None))
    return members


def _lighting_members(row: Row) -> list[Expected]:
    """A lighting's members in its renders tar: its record, render and render preview (each
    with its manifest line)."""
    sample, material, shard = row.record["id"], row.record["material_id"], row.record["shard"]
    render = row.refs["render"]
    return [
        Expected(
            record_member(sample),
            "record",
            row.record_bytes,
            row.record_sha256,
            Layout.record_rel(shard, sample),
            sample,
            material,
            row.line,
        ),
        Expected(render.member, "render", render.bytes, render.sha256, render.path, sample, material, row.line),
        _preview(row.record, "render_preview", row.previews, sample, row.line),
    ]


def _check_rows(root: str, sums: dict[str, str], tars: list[TarEntry], limits: Limits) -> dict:
    """The manifest, the samples table and the markers read together, a line of each at a
    time: each table row must be the one its record gives, each tar pair's rows adjacent and
    in the tars' order, each material's lightings adjacent in one pair and agreeing on its
    maps, each marker the one of its shard. Counts each tar's members and notes where each
    pair's rows lie (:class:`Section`); keeps no more than a shard's records and the ids of
    the materials."""
    shape = record_shape(limits)
    paths = {rel: os.path.join(root, *rel.split("/")) for rel in LINE_FILES}
    with (
        _open_regular(paths[MANIFEST_REL], MANIFEST_REL) as manifest_fh,
        _open_regular(paths[SAMPLES_FILE], SAMPLES_FILE) as table_fh,
        _open_regular(paths[MARKERS_REL], MARKERS_REL) as markers_fh,
    ):
        manifest = LineReader(manifest_fh, MANIFEST_REL)
        table = LineReader(table_fh, SAMPLES_FILE)
        markers = LineReader(markers_fh, MARKERS_REL)
        rows = _RowsCheck(tars, markers, limits)
        while True:
            m_offset, t_offset = manifest.offset, table.offset
            line = manifest.next(shape.bytes, lambda n: f"{MANIFEST_REL} line {n}")
            if line is None:
                break
            number = manifest.number
            row_line = table.next(shape.bytes, lambda n: f"{SAMPLES_FILE} line {n}")
            if row_line is None:
                _same(SAMPLES_FILE, "", sums[SAMPLES_FILE])
            rows.add(_row(number, line, row_line, rows.by_rel, limits), row_line, m_offset, t_offset)
        rows.finish()
    for rel, reader in ((MANIFEST_REL, manifest), (SAMPLES_FILE, table), (MARKERS_REL, markers)):
        _same(rel, reader.digest.hexdigest(), sums[rel])
    return {
        "materials": len(rows.seen),
        "sections": rows.sections,
        "shards": rows.shards,
        "marker_bytes": rows.marker_bytes,
    }


class _PairRows:
    """The rows of the tar pair being read: where the first lies, how many, their SHA-256 so far
    (each manifest line and its row, each with a newline)."""

    def __init__(self, tar: TarEntry, first_line: int, manifest_offset: int, table_offset: int):
        self.tar = tar  # its renders tar
        self.first_line, self.manifest_offset, self.table_offset = first_line, manifest_offset, table_offset
        self.lines = 0
        self.digest = hashlib.sha256()

    def section(self) -> Section:
        return Section(self.first_line, self.lines, self.manifest_offset, self.table_offset, self.digest.hexdigest())


class _RowsCheck:
    """What :func:`_check_rows` keeps while it reads, and its checks of one row against the
    rows before it: its tar pair's, its material's and its shard's (with ``markers``)."""

    def __init__(self, tars: list[TarEntry], markers: LineReader, limits: Limits):
        self.by_rel = {t.rel: t for t in tars}
        self.markers, self.limits = markers, limits
        self.sections: dict[int, Section] = {}
        self.shards: list[str] = []
        self.seen: dict[str, int] = {}  # material -> the number of its tar pair
        self.marker_bytes = 0
        self.pair: _PairRows | None = None
        self.current = None  # (material, what its lightings share)
        self.shard_rows: list[tuple[bytes, dict]] = []

    def add(self, row: Row, row_line: bytes, manifest_offset: int, table_offset: int) -> None:
        """The next row (``row_line`` its line of the table, the offsets those of both lines)."""
        self._join_pair(row, row_line, manifest_offset, table_offset)
        self._join_material(row)
        row.tar.count += 3
        if self.shard_rows and row.record["shard"] != self.shard_rows[0][1]["shard"]:
            self._check_shard()
            self.shard_rows = []
        self.shard_rows.append((row.line, row.record))

    def finish(self) -> None:
        """After the last row: the last pair's section, the last shard's marker."""
        if self.pair:
            self.sections[self.pair.tar.number] = self.pair.section()
        if self.shard_rows:
            self._check_shard()

    def _join_pair(self, row: Row, row_line: bytes, manifest_offset: int, table_offset: int) -> None:
        tar, pair = row.tar, self.pair
        if not pair or pair.tar is not tar:
            if pair and tar.number < pair.tar.number:
                raise Refused(
                    "bad_table",
                    f"{SAMPLES_FILE} line {row.number}: {row.record['id']} is in {tar.rel}, before "
                    "the tar of the sample above it; refused",
                )
            if pair:
                self.sections[pair.tar.number] = pair.section()
            pair = self.pair = _PairRows(tar, row.number, manifest_offset, table_offset)
        pair.lines += 1
        pair.digest.update(row.line + b"\n" + row_line + b"\n")

    def _join_material(self, row: Row) -> None:
        tar, number = row.tar, row.number
        material = row.record["material_id"]
        shared = _shared_of(row)
        if material not in self.seen:
            self.seen[material] = tar.number
            self.current = (material, shared)
            self.by_rel[paired_tar(tar.rel, MATERIALS)].count += len(_material_members(row))
        elif self.seen[material] != tar.number:
            raise Refused(
                "bad_table",
                f"{SAMPLES_FILE} line {number}: material {material} is split across "
                f"{tar_rel(self.seen[material])} and {tar.rel}; refused",
            )
        elif self.current != (material, shared):
            raise Refused(
                "bad_record",
                f"{MANIFEST_REL} line {number} ({row.record['id']}): its material's maps differ "
                "from its other lightings', or its lightings are not adjacent; refused",
            )

    def _check_shard(self) -> None:
        self.marker_bytes = max(self.marker_bytes, _check_marker(self.markers, self.shard_rows, self.limits))
        self.shards.append(self.shard_rows[0][1]["shard"])


def _section_members(publication: Publication, kind: str, at: Section) -> Iterator[Expected]:
    """The members one tar of a pair must hold, in order, derived again from its section of
    the manifest and the table (each line checked again); Refused at the end when those lines
    are not the ones :func:`open_publication` checked."""
    by_rel = {t.rel: t for t in publication.tars}
    digest = hashlib.sha256()
    material = None
    shape = record_shape(publication.limits)
    with (
        _open_regular(publication.path(MANIFEST_REL), MANIFEST_REL) as manifest_fh,
        _open_regular(publication.path(SAMPLES_FILE), SAMPLES_FILE) as table_fh,
    ):
        manifest_fh.seek(at.manifest_offset)
        table_fh.seek(at.table_offset)
        manifest = LineReader(manifest_fh, MANIFEST_REL, at.manifest_offset)
        table = LineReader(table_fh, SAMPLES_FILE, at.table_offset)
        for number in range(at.first_line, at.first_line + at.lines):
            line = manifest.next(shape.bytes, lambda n, first=number: f"{MANIFEST_REL} line {first}")
            row_line = table.next(shape.bytes, lambda n, first=number: f"{SAMPLES_FILE} line {first}")
            if line is None or row_line is None:
                break
            digest.update(line + b"\n" + row_line + b"\n")
            row = _row(number, line, row_line, by_rel, publication.limits)
            if kind == RENDERS:
                yield from _lighting_members(row)
            elif row.record["material_id"] != material:
                material = row.record["material_id"]
                yield from _material_members(row)
    if digest.hexdigest() != at.sha256:
        raise Refused(
            "changed",
            f"{MANIFEST_REL} and {SAMPLES_FILE} lines {at.first_line}-{at.first_line + at.lines - 1}: not those "
            "checked when the publication was opened: it changed while it was read; refused",
        )


def _preview(
    record: dict, role: str, previews: dict[str, tuple[str, int]], sample: str | None, line: bytes | None = None
) -> Expected:
    sha, size = previews[role]
    return Expected(preview_member(record, role), "preview", size, sha, None, sample, record["material_id"], line)


def _shared(ref: FileRef, material: str) -> Expected:
    return Expected(ref.member, ref.role, ref.bytes, ref.sha256, ref.path, None, material)


def _check_croissant(texts: dict[str, bytes], sums: dict[str, str], shape: Shape) -> None:
    """croissant.json's SHA-256 of each file must be the one SHA256SUMS lists."""
    metadata = _json(texts[CROISSANT_FILE], CROISSANT_FILE, shape)
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


def _check_marker(markers: LineReader, rows: list[tuple[bytes, dict]], limits: Limits) -> int:
    """The next line of markers.jsonl must be the complete marker of the shard whose records
    (manifest lines and records) are ``rows``; returns its size."""
    number = markers.number + 1
    where = f"{MARKERS_REL} line {number}"
    shard = rows[0][1]["shard"]
    # a marker holds its shard's records (but for timings) and a few fields of its own
    own = [_structure(line) for line, _record in rows]
    shape = Shape(
        sum(len(line) + 64 for line, _record in rows) + limits.record_bytes,
        sum(c for c, _ in own) + limits.record_containers,
        sum(v for _, v in own) + limits.record_values,
    )
    line = markers.next(shape.bytes, lambda n: where)
    if line is None:
        raise Refused("bad_marker", f"{MARKERS_REL}: expected one line per source shard; refused")
    marker = _json(line, where, shape)
    if not isinstance(marker, dict) or marker.get("shard") != shard or marker.get("complete") is not True:
        raise Refused("bad_marker", f"{where}: not the complete marker of shard {shard}")
    mine = [record for _line, record in rows]
    theirs = marker.get("records")
    if (
        not isinstance(theirs, list)
        or len(theirs) != len(mine)
        or marker.get("samples") != [r["id"] for r in mine]
        or any(
            not isinstance(t, dict)
            or not isinstance(t.get("stats", {}), dict)
            or without_timings(t) != without_timings(r)
            for t, r in zip(theirs, mine)
        )
    ):
        raise Refused(
            "bad_marker",
            f"{where}: the marker of shard {shard} does not hold the manifest's records of that shard; refused",
        )
    return len(line) + 1


def _scan_in_order(fh, label: str, limits: Limits, before: int, expected: Iterator[Expected]):
    """Every header of the tar in ``fh`` checked as :func:`~pipeline.publish.tarsafe.scan_tar`
    checks it, each name against the next expected one: (offsets, sizes) of the members'
    bytes when every name is the expected one in order (the expected names are unique: no
    name appears twice), None at the first difference. Holds 16 bytes a member."""
    offsets, sizes = array("Q"), array("Q")
    length = tar_length(fh, label)
    for member in iter_headers(fh, label, limits, length):
        wanted = next(expected, None)
        if wanted is None or wanted.name != member.name:
            return None
        check_count(label, limits, before + len(offsets) + 1)
        offsets.append(member.offset)
        sizes.append(member.size)
    if next(expected, None) is not None:
        return None
    return offsets, sizes


# --------------------------------------------------------------------------- members


def _compare_members(label: str, scanned: list[Member], expected: list[Expected]) -> None:
    names = [m.name for m in scanned]
    wanted = [e.name for e in expected]
    if names == wanted:
        return
    have, want = set(names), set(wanted)
    missing = [n for n in wanted if n not in have]
    extra = [n for n in names if n not in want]
    if missing:  # the layout's own names
        raise Refused("missing_member", f"{label}: member(s) {', '.join(missing[:5])} missing; refused")
    if extra:  # names from tar headers, which may hold any byte but NUL: as repr
        raise Refused(
            "extra_member", f"{label}: member(s) {', '.join(map(repr, extra[:5]))} are no part of this tar; refused"
        )
    first = next(i for i, (a, b) in enumerate(zip(names, wanted)) if a != b)
    raise Refused(
        "member_order",
        f"{label}: member {first} is {names[first]!r}, expected {wanted[first]!r} (members in plan order); refused",
    )


def _check_member(
    label: str,
    member: Member,
    data: bytes,
    expected: Expected,
    limits: Limits,
    bounds: dict,
) -> None:
    where = f"{label}: member {member.name!r}"
    if member.size != expected.size:
        raise Refused("member_checksum", f"{where} is {member.size} bytes, the manifest says {expected.size}; refused")
    digest = hashlib.sha256(data).hexdigest()
    if digest != expected.sha256:
        raise Refused(
            "member_checksum",
            f"{where}: SHA-256 {digest[:16]}... differs from the manifest's {expected.sha256[:16]}...; refused",
        )
    if expected.role == "record":
        record = _json(data, where, record_shape(limits))
        if (
            not isinstance(record, dict)
            or not isinstance(record.get("stats", {}), dict)
            or without_timings(record) != without_timings(json.loads(expected.record))
        ):
            raise Refused("bad_record", f"{where} is not the manifest's record of {expected.sample_id}; refused")
    elif expected.role == "preview":  # decoded within the preview's size (previews.preview_problem)
        role = "maps_preview" if expected.name.endswith(".maps.png") else "render_preview"
        side = bounds["render"].shape[0] if bounds["render"].shape else None
        problem = preview_problem(data, role, side)
        if problem:
            raise Refused("preview", f"{where}: {problem}; refused")
    elif expected.role != "material":  # a material's row: its bytes are the table's (checked above)
        check_exr_header(data, where, limits, bounds[expected.role])


# --------------------------------------------------------------------------- samples


def sample_dict(record: dict, files: dict[str, bytes]) -> dict:
    """The sample :func:`iter_samples` and :func:`iter_folder_samples` yield."""
    paths = {entry["role"]: entry["path"] for entry in record["files"]}
    return {
        "id": record["id"],
        "material_id": record["material_id"],
        "record": record,
        "files": {role: files[role] for role in paths},
        "paths": paths,
    }


def iter_samples(
    pub: str, limits: Limits = DEFAULT_LIMITS, progress: Callable[[str], None] | None = None
) -> Iterator[dict]:
    """Every sample of the publication at ``pub``, in plan order, checked as it streams.

    Each sample is ``{"id", "material_id", "record", "files", "paths"}``: ``record`` is its
    manifest record (docs/manifest.md), ``files`` maps each role of the record's files
    (``render``, ``maps``, ``texture``) to the file's bytes (decode with
    ``pipeline.store.exr.read_exr``), ``paths`` maps it to the file's path in the dataset
    folder. A tar's SHA-256 is checked before it is opened; every member's against the
    manifest. Raises :class:`Refused` on the first problem (samples already yielded were
    checked).
    """
    publication = open_publication(pub, limits)
    yield from publication_samples(publication, progress)


def publication_samples(publication: Publication, progress: Callable[[str], None] | None = None) -> Iterator[dict]:
    """The samples of each tar pair: its renders tar streamed, its materials tar streamed
    alongside (a material's maps are read when its first lighting comes)."""
    before = {t.rel: 0 for t in publication.tars}
    count = 0
    for tar in publication.tars:
        before[tar.rel] = count
        count += tar.count
    by_rel = {t.rel: t for t in publication.tars}
    for tar in publication.tars:
        if TAR_NAME.match(tar.rel).group(1) != RENDERS:
            continue
        if progress:
            progress(tar.rel)
        materials = by_rel[paired_tar(tar.rel, MATERIALS)]
        maps_members = publication.members(materials, before[materials.rel])
        material, shared = None, {}
        for expected, data in publication.members(tar, before[tar.rel]):
            if expected.role != "render":
                continue
            if expected.material_id != material:
                material, shared = expected.material_id, {}
                for got, got_data in maps_members:
                    if got.role in ("maps", "texture"):
                        shared[got.role] = got_data
                    if got.role == "preview":  # the material's last member
                        break
            yield sample_dict(json.loads(expected.record), {**shared, "render": data})
        for _rest in maps_members:  # the materials tar is checked to its end
            pass


def iter_folder_samples(root: str) -> Iterator[dict]:
    """The samples of a complete dataset folder, as :func:`iter_samples` yields them from its
    publication (each file's SHA-256 checked against the manifest)."""
    layout = Layout(root)
    records = []
    for number, line in enumerate(read_manifest(layout).split(b"\n"), start=1):
        if not line.strip():
            continue
        too_much = structure_problem(line)
        if too_much:
            raise Refused("too_complex", f"{MANIFEST_FILE} line {number}: {too_much}")
        records.append(json.loads(line))
    shared: dict[str, bytes] = {}
    material = None
    for number, record in enumerate(records, start=1):
        refs = file_refs(record, f"{MANIFEST_FILE} line {number}")
        if record["material_id"] != material:
            material = record["material_id"]
            shared = {role: _read_verified(layout, refs[role]) for role in ("maps", "texture") if role in refs}
        yield sample_dict(record, {**shared, "render": _read_verified(layout, refs["render"])})


def _read_verified(layout: Layout, ref: FileRef) -> bytes:
    """The bytes of a file of the folder, read only at the size the manifest records (a file
    grown in place is refused before a byte is read) and only with the manifest's SHA-256."""
    try:
        data = read_bytes(resolve_inside(layout.root, ref.path), Recorded(ref.bytes, MANIFEST_FILE))
    except OverBound as exc:
        raise Refused(
            "size_mismatch", f"{ref.path}: {exc.strerror}; check the folder with `shaderball validate`"
        ) from None
    if hashlib.sha256(data).hexdigest() != ref.sha256:
        raise Refused(
            "checksum", f"{ref.path}: SHA-256 differs from the manifest's; check the folder with `shaderball validate`"
        )
    return data


def read_located(root: str, at: Located, check_sha256: bool = True) -> bytes:
    """The bytes of a member :meth:`Publication.locate` checked, read again at its offset (one
    ``pread``, no ``tarfile``, nothing extracted); the tar must still have the size it had
    and, with ``check_sha256``, the bytes the manifest's SHA-256. Raises :class:`Refused`."""
    label = f"{at.tar}: member {at.name!r}"
    with _open_regular(os.path.join(root, *at.tar.split("/")), at.tar) as fh:
        size = os.fstat(fh.fileno()).st_size
        if size != at.tar_size:
            raise Refused(
                "changed",
                f"{at.tar}: {size} bytes, {at.tar_size} when it was verified: the publication "
                "changed since; check it with `shaderball verify`",
            )
        data = os.pread(fh.fileno(), at.size, at.offset)
    if len(data) != at.size:
        raise Refused(
            "changed",
            f"{label} is cut short: the publication changed since it was verified; check it with `shaderball verify`",
        )
    if check_sha256:
        digest = hashlib.sha256(data).hexdigest()
        if digest != at.sha256:
            raise Refused(
                "member_checksum",
                f"{label}: SHA-256 {digest[:16]}... differs from the manifest's "
                f"{at.sha256[:16]}...: the publication changed since it was verified; "
                "check it with `shaderball verify`",
            )
    return data
