"""The line files of a publication checked against each other, a line of each at a time:
the manifest (every record's shape, layout and field types; ids unique; each shard's records
adjacent), ``samples.jsonl`` (each row the one its record gives; each tar pair's rows
adjacent and in the tars' order; each material's lightings adjacent in one pair and agreeing
on its maps) and ``markers.jsonl`` (each marker the complete one of its shard), with the
index's tars (:class:`TarEntry`). Where each pair's rows lie is kept (:class:`Section`); from
a row, :func:`material_members` and :func:`lighting_members` derive the members
(:class:`Expected`) its tars must hold, in order."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

from pipeline.publish.line_reader import LineReader
from pipeline.publish.names import (
    FORMAT,
    FORMAT_VERSION,
    INDEX_FILE,
    MARKERS_REL,
    MATERIALS,
    RENDERS,
    SAMPLES_FILE,
    SHARDS_DIR,
    SOURCE_FILES,
    SUMS_FILE,
    TAR_KINDS,
    TAR_NAME,
    paired_tar,
    tar_rel,
)
from pipeline.publish.refusal import Limits, Refused
from pipeline.publish.scene_fields import OBJECT_COLUMNS, scene_problem
from pipeline.publish.small_files import (
    HEX,
    Shape,
    json_structure,
    open_regular,
    parse_json,
    record_shape,
    same_as_checked,
)
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
from pipeline.store.layout import MANIFEST_FILE, Layout
from pipeline.store.record_fields import field_type_problem, json_type_name, short_json
from pipeline.store.records import dumps, without_timings

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


def _checked_record(line: bytes, where: str, shape: Shape) -> dict:
    """A manifest line's record: its shape before it is parsed, then the layout of its ids and
    paths, the types of its fields and its scene's (an object's and a map's digests)."""
    record = parse_json(line, where, shape)
    file_refs(record, where)
    why = field_type_problem(record) or scene_problem(record)
    if why:
        raise Refused("bad_record", f"{where}: {why}; refused")
    return record


def check_manifest(root: str, sums: dict[str, str], limits: Limits) -> tuple[int, int]:
    """(records, source shards) of the manifest, every line checked (:func:`_checked_record`),
    its id unique, each shard's records adjacent (as a build writes them), one at a time."""
    rel = MANIFEST_REL
    shape = record_shape(limits)
    ids: set[str] = set()
    done: set[str] = set()
    shard = None
    with open_regular(os.path.join(root, *rel.split("/")), rel) as fh:
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
    same_as_checked(rel, lines.digest.hexdigest(), sums[rel])
    if not ids:
        raise Refused("bad_record", f"{rel}: no records")
    return len(ids), len(done) + 1


def tar_entries(index, sums: dict[str, str], files: dict[str, int]) -> list[TarEntry]:
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


def checked_row(
    number: int, line: bytes, row_line: bytes, by_rel: dict[str, TarEntry], limits: Limits, scene: bool = False
) -> Row:
    """The manifest's line ``number`` and the table's row of that number, which must be the
    row that line gives (``scene``: with the scene columns); any disagreement is refused."""
    manifest = MANIFEST_REL
    record = _checked_record(line, f"{manifest} line {number}", record_shape(limits))
    row = parse_json(row_line, f"{SAMPLES_FILE} line {number}", record_shape(limits))
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
    expected_row = sample_row(record, tar_rel, sha, size, previews, scene)
    if dumps(expected_row).encode("utf-8") != row_line:
        raise Refused(
            "bad_table",
            f"{SAMPLES_FILE} line {number}: differs from the row {manifest} line {number} ({record['id']}) gives; refused",
        )
    refs = file_refs(record, f"{manifest} line {number}")
    return Row(number, line, record, refs, by_rel[tar_rel], material_row(expected_row), sha, size, previews)


def _shared_of(row: Row) -> dict:
    """What every lighting of a material must agree on: its maps' (and texture's) SHA-256 and
    size, its maps preview's, and its object (where the rows name one)."""
    shared = {r: (row.refs[r].sha256, row.refs[r].bytes) for r in ("maps", "texture") if r in row.refs}
    shared["maps_preview"] = row.previews["maps_preview"]
    shared.update({c: row.material_row[c] for c in OBJECT_COLUMNS if c in row.material_row})
    return shared


def material_members(row: Row) -> list[Expected]:
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


def lighting_members(row: Row) -> list[Expected]:
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


def check_rows(root: str, sums: dict[str, str], tars: list[TarEntry], limits: Limits, scene: bool = False) -> dict:
    """The manifest, the samples table and the markers read together, a line of each at a
    time: each table row must be the one its record gives (``scene``: with the scene columns,
    pipeline.publish.scene_fields), each tar pair's rows adjacent and
    in the tars' order, each material's lightings adjacent in one pair and agreeing on its
    maps, each marker the one of its shard. Counts each tar's members and notes where each
    pair's rows lie (:class:`Section`); keeps no more than a shard's records and the ids of
    the materials."""
    shape = record_shape(limits)
    paths = {rel: os.path.join(root, *rel.split("/")) for rel in LINE_FILES}
    with (
        open_regular(paths[MANIFEST_REL], MANIFEST_REL) as manifest_fh,
        open_regular(paths[SAMPLES_FILE], SAMPLES_FILE) as table_fh,
        open_regular(paths[MARKERS_REL], MARKERS_REL) as markers_fh,
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
                same_as_checked(SAMPLES_FILE, "", sums[SAMPLES_FILE])
            rows.add(checked_row(number, line, row_line, rows.by_rel, limits, scene), row_line, m_offset, t_offset)
        rows.finish()
    for rel, reader in ((MANIFEST_REL, manifest), (SAMPLES_FILE, table), (MARKERS_REL, markers)):
        same_as_checked(rel, reader.digest.hexdigest(), sums[rel])
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
    """What :func:`check_rows` keeps while it reads, and its checks of one row against the
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
            self.by_rel[paired_tar(tar.rel, MATERIALS)].count += len(material_members(row))
        elif self.seen[material] != tar.number:
            raise Refused(
                "bad_table",
                f"{SAMPLES_FILE} line {number}: material {material} is split across "
                f"{tar_rel(self.seen[material])} and {tar.rel}; refused",
            )
        elif self.current != (material, shared):
            raise Refused(
                "bad_record",
                f"{MANIFEST_REL} line {number} ({row.record['id']}): its material's maps (or object) "
                "differ from its other lightings', or its lightings are not adjacent; refused",
            )

    def _check_shard(self) -> None:
        self.marker_bytes = max(self.marker_bytes, _check_marker(self.markers, self.shard_rows, self.limits))
        self.shards.append(self.shard_rows[0][1]["shard"])


def _preview(
    record: dict, role: str, previews: dict[str, tuple[str, int]], sample: str | None, line: bytes | None = None
) -> Expected:
    sha, size = previews[role]
    return Expected(preview_member(record, role), "preview", size, sha, None, sample, record["material_id"], line)


def _shared(ref: FileRef, material: str) -> Expected:
    return Expected(ref.member, ref.role, ref.bytes, ref.sha256, ref.path, None, material)


def _check_marker(markers: LineReader, rows: list[tuple[bytes, dict]], limits: Limits) -> int:
    """The next line of markers.jsonl must be the complete marker of the shard whose records
    (manifest lines and records) are ``rows``; returns its size."""
    number = markers.number + 1
    where = f"{MARKERS_REL} line {number}"
    shard = rows[0][1]["shard"]
    # a marker holds its shard's records (but for timings) and a few fields of its own
    own = [json_structure(line) for line, _record in rows]
    shape = Shape(
        sum(len(line) + 64 for line, _record in rows) + limits.record_bytes,
        sum(c for c, _ in own) + limits.record_containers,
        sum(v for _, v in own) + limits.record_values,
    )
    line = markers.next(shape.bytes, lambda n: where)
    if line is None:
        raise Refused("bad_marker", f"{MARKERS_REL}: expected one line per source shard; refused")
    marker = parse_json(line, where, shape)
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
