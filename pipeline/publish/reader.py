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

The reads of single files, without trusting them, are pipeline.publish.small_files; the
checks of the line files against each other, and the members a row's tars must hold,
pipeline.publish.rows.
"""

from __future__ import annotations

import hashlib
import json
import os
from array import array
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

from pipeline.publish.exrcheck import check_exr_header, member_bounds
from pipeline.publish.line_reader import CHUNK_BYTES, LineReader, scan
from pipeline.publish.names import (
    INDEX_FILE,
    MARKERS_REL,
    MATERIALS,
    OPTIONAL_FILES,
    PLAIN_FILES,
    RENDERS,
    SAMPLES_FILE,
    SOURCE_FILES,
    SUMS_FILE,
    TAR_NAME,
    paired_tar,
)
from pipeline.publish.previews import preview_problem
from pipeline.publish.refusal import DEFAULT_LIMITS, Limits, Refused
from pipeline.publish.request import VerifyRequest, format_value
from pipeline.publish.rows import (
    LINE_FILES,
    MANIFEST_REL,
    Expected,
    Section,
    TarEntry,
    check_manifest,
    check_rows,
    checked_row,
    lighting_members,
    material_members,
    tar_entries,
)
from pipeline.publish.scene_fields import has_scene_columns
from pipeline.publish.small_files import (
    Shape,
    check_croissant,
    open_regular,
    parse_json,
    parse_sums,
    read_small,
    record_shape,
    resized,
    same_as_checked,
    shown,
    walk_files,
)
from pipeline.publish.table import FileRef, file_refs
from pipeline.publish.tarsafe import Member, check_count, iter_headers, read_members, scan_tar, tar_length
from pipeline.store.bounded_read import OverBound, Recorded, read_bytes, resolve_inside, structure_problem
from pipeline.store.folder import read_manifest
from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, SPEC_FILE, Layout
from pipeline.store.records import without_timings


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
    scene: bool = False  # samples.jsonl has the scene columns (pipeline.publish.scene_fields)

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
        with open_regular(self.path(tar.rel), label) as fh:
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
        with open_regular(self.path(MANIFEST_REL), MANIFEST_REL) as fh:
            if os.fstat(fh.fileno()).st_size != checked:
                raise resized(MANIFEST_REL, os.fstat(fh.fileno()).st_size, checked)
            digest, read = hashlib.sha256(), 0
            for chunk in iter(lambda: fh.read(CHUNK_BYTES), b""):
                read += len(chunk)
                if read > checked:
                    raise resized(MANIFEST_REL, read, checked)
                digest.update(chunk)
                yield chunk
        same_as_checked(MANIFEST_REL, digest.hexdigest(), self.sums[MANIFEST_REL])

    def markers(self) -> Iterator[tuple[str, bytes]]:
        """(shard id, its COMPLETE.json bytes) for each line of markers.jsonl, as checked; Refused
        at the end when the file's bytes are not those checked."""
        with open_regular(self.path(MARKERS_REL), MARKERS_REL) as fh:
            lines = LineReader(fh, MARKERS_REL)
            for shard in self.shards:
                line = lines.next(self.marker_bytes, lambda n: f"{MARKERS_REL} line {n}")
                if line is None:
                    break
                yield shard, line + b"\n"
        same_as_checked(MARKERS_REL, lines.digest.hexdigest(), self.sums[MARKERS_REL])


def open_publication(root: str, limits: Limits = DEFAULT_LIMITS) -> Publication:
    """Check the small files of the publication at ``root``; see the module's docstring."""
    if not os.path.isdir(root):
        why = "is not a folder" if os.path.lexists(root) else "does not exist"
        raise VerifyRequest.field_error(
            "pub", root, "a folder written by `shaderball publish`", what=f"{format_value(root)} {why}"
        )
    files = walk_files(root, limits)
    if SUMS_FILE not in files:
        raise Refused("missing_file", f"{SUMS_FILE}: missing; PUB is not a (finished) publication")
    total = sum(files.values())
    if total > limits.total_bytes:
        raise Refused(
            "too_large", f"the publication holds {total} bytes, over the cap of {limits.total_bytes}; refused"
        )
    sums = parse_sums(read_small(root, SUMS_FILE, limits.text_bytes))
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
            with open_regular(os.path.join(root, *rel.split("/")), rel) as fh:
                digest, lines, newline = scan(fh)
            counts[rel] = lines, newline
        else:
            data = read_small(root, rel, limits.text_bytes)
            digest = hashlib.sha256(data).hexdigest()
            texts[rel] = data
        if digest != sums[rel]:
            raise Refused("checksum", f"{rel}: SHA-256 differs from {SUMS_FILE}'s; the file changed or is corrupt")
    samples, shards = check_manifest(root, sums, limits)
    metadata = Shape(
        limits.text_bytes,
        4096 + limits.json_containers_per_file * len(sums),
        65536 + limits.json_values_per_file * len(sums),
    )
    index = parse_json(texts[INDEX_FILE], INDEX_FILE, metadata)
    tars = tar_entries(index, sums, files)
    if counts[SAMPLES_FILE][0] != samples:
        raise Refused("bad_table", f"{SAMPLES_FILE}: {counts[SAMPLES_FILE][0]} rows for {samples} manifest records")
    check_croissant(texts, sums, metadata)
    lines, newline = counts[MARKERS_REL]
    if not newline or lines != shards:
        raise Refused("bad_marker", f"{MARKERS_REL}: expected one line per source shard ({shards}); refused")
    small = {name: texts[rel] for name, rel in SOURCE_FILES.items() if rel in texts}
    # the rows' columns follow the description (the scene columns: where its counts name objects or maps)
    scene = has_scene_columns(parse_json(small[DESCRIPTION_FILE], SOURCE_FILES[DESCRIPTION_FILE], metadata))
    checked = check_rows(root, sums, tars, limits, scene)
    return Publication(
        root=root,
        limits=limits,
        sums=sums,
        sizes=files,
        small_files=small,
        tars=tars,
        index=index,
        samples=samples,
        scene=scene,
        **checked,
    )


def _section_members(publication: Publication, kind: str, at: Section) -> Iterator[Expected]:
    """The members one tar of a pair must hold, in order, derived again from its section of
    the manifest and the table (each line checked again); Refused at the end when those lines
    are not the ones :func:`open_publication` checked."""
    by_rel = {t.rel: t for t in publication.tars}
    digest = hashlib.sha256()
    material = None
    shape = record_shape(publication.limits)
    with (
        open_regular(publication.path(MANIFEST_REL), MANIFEST_REL) as manifest_fh,
        open_regular(publication.path(SAMPLES_FILE), SAMPLES_FILE) as table_fh,
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
            row = checked_row(number, line, row_line, by_rel, publication.limits, publication.scene)
            if kind == RENDERS:
                yield from lighting_members(row)
            elif row.record["material_id"] != material:
                material = row.record["material_id"]
                yield from material_members(row)
    if digest.hexdigest() != at.sha256:
        raise Refused(
            "changed",
            f"{MANIFEST_REL} and {SAMPLES_FILE} lines {at.first_line}-{at.first_line + at.lines - 1}: not those "
            "checked when the publication was opened: it changed while it was read; refused",
        )


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
        record = parse_json(data, where, record_shape(limits))
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
    with open_regular(os.path.join(root, *at.tar.split("/")), at.tar) as fh:
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
