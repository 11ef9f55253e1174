"""Reading a publication without trusting it: `shaderball verify`, the first pass of
`shaderball unpack`, and :func:`iter_samples` for the training stage.

:func:`open_publication` reads only the small files: it refuses links and unlisted files,
checks every file's SHA-256 against ``SHA256SUMS`` (tars are checked when they are
opened), checks every manifest path against the layout before any is used, and derives
from the manifest and ``samples.jsonl`` the exact members each tar must hold, in order,
with their sizes and SHA-256. :meth:`Publication.members` then streams one tar: its
SHA-256 first, then every header (pipeline.publish.tarsafe), then each member, whose
size, SHA-256, EXR header or record must be the expected one. Any difference raises
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
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field

from pipeline.errors import bad_value
from pipeline.publish.exrcheck import check_exr_header, member_bounds
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
)
from pipeline.publish.previews import png_size
from pipeline.publish.refusal import DEFAULT_LIMITS, Limits, Refused
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
from pipeline.publish.tarsafe import Member, read_members, scan_tar
from pipeline.store.folder import (
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
    expected: list[Expected] = field(default_factory=list)


@dataclass
class Publication:
    """A publication whose small files have been checked (:func:`open_publication`)."""

    root: str
    limits: Limits
    sums: dict[str, str]
    sizes: dict[str, int]
    source_files: dict[str, bytes]  # spec.toml, dataset.json, manifest.jsonl: bytes as published
    markers: list[tuple[str, bytes]]  # (shard id, COMPLETE.json bytes)
    records: Records  # the manifest's, in order (parsed when used)
    tars: list[TarEntry]
    index: dict

    def __post_init__(self):
        self.by_id = _ById(self.records)
        #: what each role's EXR members may hold (pipeline.publish.exrcheck.member_bounds)
        self.exr_bounds = member_bounds(self.source_files.get(SPEC_FILE, b""))

    def path(self, rel: str) -> str:
        return os.path.join(self.root, *rel.split("/"))

    @property
    def description(self) -> dict:
        return json.loads(self.source_files[DESCRIPTION_FILE])

    def members(self, tar: TarEntry, before: int = 0) -> Iterator[tuple[Expected, bytes]]:
        """Every member of ``tar``, checked, in order (``before``: members of earlier tars)."""
        for expected, _member, data in self.checked_members(tar, before):
            yield expected, data

    def checked_members(self, tar: TarEntry, before: int = 0) -> Iterator[tuple[Expected, Member, bytes]]:
        """As :meth:`members`, with where each member's bytes lie in the tar (``Member``)."""
        label = tar.rel
        with _open_regular(self.path(tar.rel), label) as fh:
            digest = hashlib.sha256()
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
            if digest.hexdigest() != tar.sha256:
                raise Refused(
                    "checksum",
                    f"{label}: SHA-256 {digest.hexdigest()[:16]}... differs from {SUMS_FILE}'s "
                    f"{tar.sha256[:16]}...: the file changed or is corrupt; nothing of it is read",
                )
            scanned = scan_tar(fh, label, self.limits, before)
            _compare_members(label, scanned, tar.expected)
            for (member, data), expected in zip(read_members(fh, label, scanned), tar.expected):
                _check_member(label, member, data, expected, self.by_id, self.limits, self.exr_bounds)
                yield expected, member, data

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
            before += len(tar.expected)
        return found


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
                    raise Refused("too_many_files", f"PUB: more than {limits.entries} files and folders; refused")
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
    with _open_regular(os.path.join(root, *rel.split("/")), rel) as fh:
        data = fh.read(size_cap + 1)
    if len(data) > size_cap:
        raise Refused("too_large", f"{rel}: over the cap of {size_cap} bytes for a file read into memory; refused")
    return data


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


def _lines(data: bytes) -> Iterator[tuple[int, int, int]]:
    """(line number, start, end) of each line of ``data`` (a final newline ends the last line;
    an empty line inside is a line), without copying ``data``."""
    number, start = 0, 0
    while start < len(data):
        end = data.find(b"\n", start)
        end = len(data) if end < 0 else end
        number += 1
        yield number, start, end
        start = end + 1


class Records(Sequence):
    """The manifest's records, checked once when the publication is opened, then kept as
    their bytes (offsets into ``manifest.jsonl``) and parsed again where used: what reading a
    publication holds is its manifest's size, whatever structure the lines hold."""

    def __init__(self, data: bytes):
        self._data = data
        self._starts = array("Q")
        self._ends = array("Q")
        self.index: dict[str, int] = {}

    def add(self, sample_id: str, start: int, end: int) -> None:
        self.index[sample_id] = len(self._starts)
        self._starts.append(start)
        self._ends.append(end)

    def line(self, i: int) -> bytes:
        return self._data[self._starts[i] : self._ends[i]]

    def __len__(self) -> int:
        return len(self._starts)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        return json.loads(self.line(i))

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]


class _ById(Mapping):
    """sample id -> its record (parsed when asked for)."""

    def __init__(self, records: Records):
        self._records = records

    def __getitem__(self, sample_id):
        return self._records[self._records.index[sample_id]]

    def __iter__(self):
        return iter(self._records.index)

    def __len__(self) -> int:
        return len(self._records)


def open_publication(root: str, limits: Limits = DEFAULT_LIMITS) -> Publication:
    """Check the small files of the publication at ``root``; see the module's docstring."""
    if not os.path.isdir(root):
        raise bad_value("PUB", root, "a folder written by `shaderball publish`")
    files = _walk(root, limits)
    if SUMS_FILE not in files:
        raise Refused("missing_file", f"{SUMS_FILE}: missing; PUB is not a (finished) publication")
    total = sum(files.values())
    if total > limits.total_bytes:
        raise Refused("too_large", f"PUB: {total} bytes, over the cap of {limits.total_bytes}; refused")
    sums = _parse_sums(_read_small(root, SUMS_FILE, limits.text_bytes))
    for rel in sorted(set(files) - set(sums) - {SUMS_FILE}):
        raise Refused("unlisted_file", f"{shown(rel)}: not listed in {SUMS_FILE}; refused")
    for rel in sorted(set(sums) - set(files)):
        raise Refused("missing_file", f"{rel}: listed in {SUMS_FILE} but missing")
    for rel in PLAIN_FILES:
        if rel not in sums and rel not in OPTIONAL_FILES:
            raise Refused("missing_file", f"{rel}: missing from the publication")
    texts: dict[str, bytes] = {}
    for rel in sorted(r for r in sums if not TAR_NAME.match(r)):
        data = _read_small(root, rel, limits.text_bytes)
        if hashlib.sha256(data).hexdigest() != sums[rel]:
            raise Refused("checksum", f"{rel}: SHA-256 differs from {SUMS_FILE}'s; the file changed or is corrupt")
        texts[rel] = data
    records = _manifest(texts[SOURCE_FILES[MANIFEST_FILE]], limits)
    metadata = Shape(
        limits.text_bytes,
        4096 + limits.json_containers_per_file * len(sums),
        65536 + limits.json_values_per_file * len(sums),
    )
    index = _json(texts[INDEX_FILE], INDEX_FILE, metadata)
    tars = _tars(index, sums, files)
    _expect_members(tars, records, texts[SAMPLES_FILE], limits)
    _check_croissant(texts, sums, metadata)
    markers = _markers(texts[MARKERS_REL], records, limits)
    source = {name: texts[rel] for name, rel in SOURCE_FILES.items()}
    _json(source[DESCRIPTION_FILE], SOURCE_FILES[DESCRIPTION_FILE], metadata)
    return Publication(
        root=root,
        limits=limits,
        sums=sums,
        sizes=files,
        source_files=source,
        markers=markers,
        records=records,
        tars=tars,
        index=index,
    )


def _manifest(data: bytes, limits: Limits) -> Records:
    """Every line checked (its shape before it is parsed, then the layout of its ids and
    paths, the types of its fields, its id unique), one at a time; kept as bytes."""
    rel = SOURCE_FILES[MANIFEST_FILE]
    records = Records(data)
    shape = record_shape(limits)
    for number, start, end in _lines(data):
        if number > limits.members:
            raise Refused("too_many_members", f"{rel}: more than {limits.members} lines (the cap on members); refused")
        where = f"{rel} line {number}"
        _check_size(end - start, where, shape)  # before the line is copied
        record = _json(data[start:end], where, shape)
        file_refs(record, where)
        why = field_type_problem(record)
        if why:
            raise Refused("bad_record", f"{where}: {why}; refused")
        if record["id"] in records.index:
            raise Refused("duplicate", f"{where}: a second record for {record['id']}; refused")
        records.add(record["id"], start, end)
    if not records:
        raise Refused("bad_record", f"{rel}: no records")
    return records


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
    return [TarEntry(rel=rel, sha256=sums[rel], size=files[rel]) for rel in listed]


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


def _expect_members(tars: list[TarEntry], records: list[dict], table: bytes, limits: Limits) -> None:
    """Fill each tar's expected members from the manifest and the samples table, refusing any
    disagreement between the two: a materials tar holds each of its materials' row, maps
    (and texture) and maps preview; the renders tar of its number, each of their lightings'
    record, render and render preview."""
    rows = table.split(b"\n")
    if rows and rows[-1] == b"":
        rows.pop()
    if len(rows) != len(records):
        raise Refused("bad_table", f"{SAMPLES_FILE}: {len(rows)} rows for {len(records)} manifest records")
    by_rel = {t.rel: t for t in tars}
    shape = record_shape(limits)
    material_tar: dict[str, tuple[str, dict]] = {}
    last_tar = -1
    manifest = SOURCE_FILES[MANIFEST_FILE]
    for number, (record, line) in enumerate(zip(records, rows), start=1):
        row = _json(line, f"{SAMPLES_FILE} line {number}", shape)
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
        if dumps(expected_row).encode("utf-8") != line:
            raise Refused(
                "bad_table",
                f"{SAMPLES_FILE} line {number}: differs from the row {manifest} line "
                f"{number} ({record['id']}) gives; refused",
            )
        tar = by_rel[tar_rel]
        materials = by_rel[expected_row["material_shard"]]
        position = tars.index(tar)
        if position < last_tar:
            raise Refused(
                "bad_table",
                f"{SAMPLES_FILE} line {number}: {record['id']} is in {tar_rel}, before "
                "the tar of the sample above it; refused",
            )
        last_tar = position
        refs = file_refs(record, f"{manifest} line {number}")
        material = record["material_id"]
        shared = {r: (refs[r].sha256, refs[r].bytes) for r in ("maps", "texture") if r in refs}
        shared["maps_preview"] = previews["maps_preview"]
        if material not in material_tar:
            material_tar[material] = (tar_rel, shared)
            data = (dumps(material_row(expected_row)) + "\n").encode("utf-8")
            materials.expected.append(
                Expected(
                    material_member(material),
                    "material",
                    len(data),
                    hashlib.sha256(data).hexdigest(),
                    None,
                    None,
                    material,
                )
            )
            materials.expected += [_shared(refs[role], material) for role in ("maps", "texture") if role in refs]
            materials.expected.append(_preview(record, "maps_preview", previews, None))
        elif material_tar[material][0] != tar_rel:
            raise Refused(
                "bad_table",
                f"{SAMPLES_FILE} line {number}: material {material} is split across "
                f"{material_tar[material][0]} and {tar_rel}; refused",
            )
        elif material_tar[material][1] != shared or tar.expected[-1].material_id != material:
            raise Refused(
                "bad_record",
                f"{manifest} line {number} ({record['id']}): its material's maps differ "
                "from its other lightings', or its lightings are not adjacent; refused",
            )
        sample = record["id"]
        shard = record["shard"]
        tar.expected.append(
            Expected(record_member(sample), "record", size, sha, Layout.record_rel(shard, sample), sample, material)
        )
        render = refs["render"]
        tar.expected.append(
            Expected(render.member, "render", render.bytes, render.sha256, render.path, sample, material)
        )
        tar.expected.append(_preview(record, "render_preview", previews, sample))


def _preview(record: dict, role: str, previews: dict[str, tuple[str, int]], sample: str | None) -> Expected:
    sha, size = previews[role]
    return Expected(preview_member(record, role), "preview", size, sha, None, sample, record["material_id"])


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


def _markers(data: bytes, records: Records, limits: Limits) -> list[tuple[str, bytes]]:
    by_shard: dict[str, list[int]] = {}
    for i, record in enumerate(records):
        by_shard.setdefault(record["shard"], []).append(i)
    shards = list(by_shard)
    lines = [line + b"\n" for line in data.split(b"\n")[:-1]] if data.endswith(b"\n") else None
    if lines is None or len(lines) != len(shards):
        raise Refused("bad_marker", f"{MARKERS_REL}: expected one line per source shard ({len(shards)}); refused")
    out = []
    for number, (shard, line) in enumerate(zip(shards, lines), start=1):
        # a marker holds its shard's records (but for timings) and a few fields of its own
        own = [_structure(records.line(i)) for i in by_shard[shard]]
        shape = Shape(
            sum(len(records.line(i)) + 64 for i in by_shard[shard]) + limits.record_bytes,
            sum(c for c, _ in own) + limits.record_containers,
            sum(v for _, v in own) + limits.record_values,
        )
        marker = _json(line, f"{MARKERS_REL} line {number}", shape)
        if not isinstance(marker, dict) or marker.get("shard") != shard or marker.get("complete") is not True:
            raise Refused("bad_marker", f"{MARKERS_REL} line {number}: not the complete marker of shard {shard}")
        mine = [records[i] for i in by_shard[shard]]
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
                f"{MARKERS_REL} line {number}: the marker of shard {shard} does not hold "
                f"the manifest's records of that shard; refused",
            )
        out.append((shard, line))
    return out


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
    records: dict[str, dict],
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
            or without_timings(record) != without_timings(records[expected.sample_id])
        ):
            raise Refused("bad_record", f"{where} is not the manifest's record of {expected.sample_id}; refused")
    elif expected.role == "preview":
        size = png_size(data)
        if size is None or not (0 < size[0] <= 4 * limits.exr_side and 0 < size[1] <= limits.exr_side):
            raise Refused(
                "preview", f"{where}: not a PNG of at most {4 * limits.exr_side} x {limits.exr_side}; refused"
            )
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
    records = publication.by_id
    before = {t.rel: 0 for t in publication.tars}
    count = 0
    for tar in publication.tars:
        before[tar.rel] = count
        count += len(tar.expected)
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
            yield sample_dict(records[expected.sample_id], {**shared, "render": data})
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
    data = read_bytes(resolve_inside(layout.root, ref.path))
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
