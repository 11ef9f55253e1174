"""`shaderball publish DIR --out PUB`: a validated dataset folder as tar shards, a samples
table, a dataset card, Croissant metadata and checksums (layout: pipeline.publish.names).

The same folder gives the same bytes: members in plan order with fixed metadata
(pipeline.publish.tarsafe), JSON with sorted keys, nothing from the clock, the host or
the user. A material's maps are stored once, before its lightings, in the same tar
(the card's Files section gives what repeating them per sample would cost).

PUB is held for writing (pipeline.store.lock) from its first check to its last file, as
unpack holds its DIR: a second publish into it is refused (exit code 3) naming the first.

PUB, held while it is written, is pipeline.publish.pub_folder; the members of each
material, planned from the manifest, pipeline.publish.material_members.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import os
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field

from pipeline.check.preview import write_preview
from pipeline.check.request import PreviewRequest
from pipeline.check.snapshot import read_snapshot
from pipeline.check.validate import validate
from pipeline.dataset.spec import DatasetSpec
from pipeline.publish.card import EFFECTS, dataset_card
from pipeline.publish.croissant import croissant_metadata
from pipeline.publish.material_members import (
    MaterialGroup,
    draw_previews,
    manifest_records,
    material_groups,
    read_checked,
)
from pipeline.publish.names import (
    CARD_FILE,
    CROISSANT_FILE,
    FORMAT,
    FORMAT_VERSION,
    INDEX_FILE,
    MARKERS_REL,
    MATERIALS,
    PREVIEW_FILE,
    RENDERS,
    SAMPLES_FILE,
    SOURCE_FILES,
    SUMS_FILE,
    tar_rel,
)
from pipeline.publish.output import Output
from pipeline.publish.pub_folder import held_publication
from pipeline.publish.publication_facts import PublicationFacts, RecordSummary, TarFacts
from pipeline.publish.refusal import Refused, refuse_invalid
from pipeline.publish.request import DEFAULT_LICENSE, DEFAULT_SHARD_BYTES, PublishRequest
from pipeline.publish.scene_fields import has_scene_columns
from pipeline.publish.tarsafe import member_bytes, open_writer, tar_size, write_member
from pipeline.store.atomic import atomic_file, sha256_file
from pipeline.store.bounded_read import MAX_JSON_BYTES, list_bound, read_bytes, read_chunks, resolve_inside
from pipeline.store.layout import MANIFEST_FILE, MARKER_FILE, Layout
from pipeline.store.records import dumps

PREVIEW_SAMPLES = 8


@dataclass(frozen=True)
class PublishSummary:
    out: str
    samples: int
    materials: int
    tars: list[TarFacts]
    published_bytes: int
    source_bytes: int
    member_bytes: int
    repeated_maps_extra_bytes: int
    validation_s: float
    seconds: float
    #: what a killed publish had left in PUB, which this one replaced (its message), or None
    replaced: str | None = None

    def to_dict(self) -> dict:
        return {
            "out": self.out,
            "samples": self.samples,
            "materials": self.materials,
            "shards": [t.to_dict() for t in self.tars],
            "published_bytes": self.published_bytes,
            "source_bytes": self.source_bytes,
            "member_bytes": self.member_bytes,
            "repeated_maps_extra_bytes": self.repeated_maps_extra_bytes,
            "validation_s": round(self.validation_s, 3),
            "seconds": round(self.seconds, 3),
            "replaced": self.replaced,
        }

    def lines(self) -> list[str]:
        return [
            f"published {self.out}: {self.samples} samples ({self.materials} materials) in "
            f"{len(self.tars)} tar shard(s), {self.published_bytes / 1e6:.2f} MB "
            f"(source folder {self.source_bytes / 1e6:.2f} MB)",
            f"maps stored once per material; repeating them per sample would add "
            f"{self.repeated_maps_extra_bytes / 1e6:.2f} MB",
            f"validated in {self.validation_s:.1f} s, published in {self.seconds:.1f} s; "
            f"check with `shaderball verify {self.out}`",
        ]


def publish(request: PublishRequest, *, progress: Callable[[str], None] | None = None) -> PublishSummary:
    """Validate the dataset ``request.directory`` fully, then publish it to ``request.out``.

    Raises :class:`Refused` (exit code 1) when the dataset is not valid: nothing is written.
    """
    root = request.directory
    start = time.perf_counter()
    # PUB is held from here, validation included: a second publish into it is refused at once.
    with held_publication(request.out, root, progress) as (output, replaced):
        if progress:
            progress(f"validating {root} (every file, as `shaderball validate`)")
        refuse_invalid(validate(root), f"the dataset {root!r}", "nothing was published")
        validation_s = time.perf_counter() - start
        return _write_into(output, request, validation_s=validation_s, progress=progress, replaced=replaced)


class TarPair:
    """The materials tar and the renders tar of number ``index``, each written atomically as
    materials join them: a material's members are written when it joins, then dropped."""

    def __init__(self, output: Output, layout: Layout, index: int):
        self.output, self.layout, self.index = output, layout, index
        self.stack = ExitStack()
        self.files, self.tars, self.paths = {}, {}, {}
        for kind in (MATERIALS, RENDERS):
            self.paths[kind] = output.path(tar_rel(index, kind))
            fh = self.stack.enter_context(atomic_file(self.paths[kind]))
            self.files[kind], self.tars[kind] = fh, self.stack.enter_context(open_writer(fh))
        self.body = {MATERIALS: 0, RENDERS: 0}  # bytes of the members written (tarsafe.member_bytes)
        self.members = {MATERIALS: 0, RENDERS: 0}
        self.materials, self.samples = 0, 0
        self.first: dict[str, str] = {}
        self.last: dict[str, str] = {}

    def fits(self, sizes: tuple[list[int], list[int]], shard_bytes: int) -> bool:
        """Whether a material whose members have ``sizes`` joins with both tars at most ``shard_bytes``."""
        return all(
            tar_size(self.body[kind] + sum(map(member_bytes, extra))) <= shard_bytes
            for kind, extra in zip((MATERIALS, RENDERS), sizes)
        )

    def add(self, group: MaterialGroup) -> list[dict]:
        """Write ``group``'s members; its samples-table rows."""
        rows = group.rows(self.index)
        for kind, members in (
            (MATERIALS, group.materials_members(self.index)),
            (RENDERS, group.renders_members()),
        ):
            for member in members:
                data = member.data if member.source is None else read_checked(self.layout, member)
                with _naming(self.paths[kind]):
                    write_member(self.tars[kind], member.name, data)
                self.body[kind] += member_bytes(member.size)
                self.members[kind] += 1
        self.first.setdefault(MATERIALS, group.material_id)
        self.first.setdefault(RENDERS, rows[0]["id"])
        self.last[MATERIALS], self.last[RENDERS] = group.material_id, rows[-1]["id"]
        self.materials += 1
        self.samples += len(rows)
        return rows

    def close(self) -> list[TarFacts]:
        """Finish both tars (end blocks, fsync, rename); their facts."""
        for kind in (RENDERS, MATERIALS):  # the stack closes the renders tar first: either order
            with _naming(self.paths[kind]):
                self.tars[kind].close()  # its end blocks: a write
        ends = {kind: self.files[kind].tell() for kind in (MATERIALS, RENDERS)}
        self.stack.close()
        facts = []
        for kind in (MATERIALS, RENDERS):
            rel = tar_rel(self.index, kind)
            digest = sha256_file(self.output.path(rel))
            expected = tar_size(self.body[kind])
            assert ends[kind] == expected, (ends[kind], expected)
            self.output.adopt(rel, digest, ends[kind])
            facts.append(
                TarFacts(
                    path=rel,
                    kind=kind,
                    bytes=ends[kind],
                    sha256=digest,
                    members=self.members[kind],
                    samples=self.samples,
                    materials=self.materials,
                    first=self.first[kind],
                    last=self.last[kind],
                )
            )
        return facts

    def abort(self) -> None:
        """Remove what was written (the temporary files): the publication failed."""
        _abandon(self.stack)


@contextlib.contextmanager
def _naming(path: str):
    """A write into ``path``'s open temporary file that fails (EFBIG, ENOSPC) names no file:
    name ``path``, so the message says where (pipeline.errors.filesystem_error)."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None:
            exc.filename = path
        raise


def _abandon(stack: ExitStack) -> None:
    abandoned = RuntimeError("publication abandoned")
    try:  # each atomic file sees an exception, so it removes its temporary file
        stack.__exit__(RuntimeError, abandoned, None)
    except Exception:
        pass  # the failure that abandoned the publication is the one reported


class StreamedFile:
    """A file of PUB written a piece at a time, atomically; its SHA-256 and size counted."""

    def __init__(self, output: Output, rel: str):
        self.output, self.rel, self.path = output, rel, output.path(rel)
        self.stack = ExitStack()
        self.fh = self.stack.enter_context(atomic_file(self.path))
        self.digest, self.size = hashlib.sha256(), 0

    def write(self, data: bytes) -> None:
        with _naming(self.path):
            self.fh.write(data)
        self.digest.update(data)
        self.size += len(data)

    def close(self) -> None:
        self.stack.close()
        self.output.adopt(self.rel, self.digest.hexdigest(), self.size)

    def abort(self) -> None:
        """Remove what was written (the temporary files): the publication failed."""
        _abandon(self.stack)


def _marker_line(layout: Layout, shard: str) -> bytes:
    """A shard's marker file, byte for byte: one line of JSON, or Refused."""
    data = read_bytes(resolve_inside(layout.root, Layout.marker_rel(shard)), list_bound(None))
    if not data.endswith(b"\n") or data.count(b"\n") != 1:
        raise Refused(
            "invalid_dataset",
            f"shards/{shard}/{MARKER_FILE}: not one line of JSON as "
            "`shaderball build` writes it; cannot publish it byte for byte",
        )
    return data


def write_publication(
    root: str,
    out: str,
    *,
    shard_bytes: int = DEFAULT_SHARD_BYTES,
    license_id: str = DEFAULT_LICENSE,
    url: str | None = None,
    contact_sheet: bool = True,
    validation_s: float = 0.0,
    progress: Callable[[str], None] | None = None,
) -> PublishSummary:
    """Publish the folder at ``root`` to ``out`` without validating it first (:func:`publish`
    does; tests use this to build hostile publications)."""
    request = PublishRequest(directory=root, out=out, shard_bytes=shard_bytes, license=license_id, url=url)
    with held_publication(out, root, progress) as (output, replaced):
        return _write_into(
            output,
            request,
            contact_sheet=contact_sheet,
            validation_s=validation_s,
            progress=progress,
            replaced=replaced,
        )


def _write_into(
    output: Output,
    request: PublishRequest,
    *,
    contact_sheet: bool = True,
    validation_s: float,
    progress: Callable[[str], None] | None,
    replaced: str | None = None,
) -> PublishSummary:
    """The publication of ``request.directory``, written into ``output`` while this process
    holds it (:func:`pipeline.publish.output.held_output` removes it again on a failure);
    ``replaced``: what a killed publish had left there (:func:`held_publication`)."""
    out, root, shard_bytes = output.out, request.directory, request.shard_bytes
    start = time.perf_counter()
    layout = Layout(root)
    spec: DatasetSpec = read_snapshot(root)
    scene = has_scene_columns(json.loads(read_bytes(layout.description, MAX_JSON_BYTES)))
    records = manifest_records(layout)
    first = next(records, None)
    if first is None:
        raise PublishRequest.field_error(
            "directory", root, "a dataset with finished renders", what=f"{root!r} has no records in its manifest"
        )
    table: StreamedFile | None = None
    try:
        table = StreamedFile(output, SAMPLES_FILE)
        packed = _pack_materials(
            output, layout, spec, itertools.chain([first], records), table, shard_bytes, progress, scene
        )
        _copy_sources(output, layout, packed)
        table.close()
        table = None
        if contact_sheet:
            _write_contact_sheet(output, root, progress)
        facts = _publication_facts(output, layout, spec, packed, request, has_preview=contact_sheet)
        _write_metadata(output, facts)
    except BaseException:
        if table is not None:
            table.abort()
        raise  # held_output removes what was written
    published = sum(output.sizes.values())
    return PublishSummary(
        out=out,
        samples=packed.summary.samples,
        materials=packed.materials,
        tars=packed.tars,
        published_bytes=published,
        source_bytes=facts.source_bytes,
        member_bytes=facts.member_bytes,
        repeated_maps_extra_bytes=facts.repeated_maps_extra_bytes,
        validation_s=validation_s,
        seconds=time.perf_counter() - start,
        replaced=replaced,
    )


@dataclass
class _Packed:
    """What packing the materials into tar pairs gives: the tars' facts (sorted by path), the
    records' summary, the source shards in plan order (the keys), and the byte counts the
    card reports."""

    tars: list[TarFacts] = field(default_factory=list)
    summary: RecordSummary = field(default_factory=RecordSummary)
    shards: dict[str, None] = field(default_factory=dict)
    materials: int = 0
    source_bytes: int = 0  # of the source files packed
    member_bytes: int = 0
    repeated_extra: int = 0  # what repeating each material's maps per lighting would add


def _pack_materials(
    output: Output,
    layout: Layout,
    spec: DatasetSpec,
    records,
    table: StreamedFile,
    shard_bytes: int,
    progress: Callable[[str], None] | None,
    scene: bool = False,
) -> _Packed:
    """Every material of ``records`` (manifest order) with its previews into tar pairs, a new
    pair when a material would take one over ``shard_bytes``; its rows into ``table`` (with
    the scene columns where ``scene``)."""
    packed = _Packed()
    pair: TarPair | None = None
    try:
        for number, group in enumerate(material_groups(layout, records, scene), start=1):
            if progress:
                progress(f"previews of {group.material_id} ({number}/{spec.dataset.materials})")
            draw_previews(layout, group, spec.render.resolution)
            sizes = group.sizes()
            if pair is not None and not pair.fits(sizes, shard_bytes):
                if progress:
                    progress(f"writing {tar_rel(pair.index, MATERIALS)} and {tar_rel(pair.index, RENDERS)}")
                packed.tars += pair.close()
                pair = None
            if pair is None:
                pair = TarPair(output, layout, len(packed.tars) // 2)
            for record, row in zip(group.records, pair.add(group)):
                table.write((dumps(row) + "\n").encode("utf-8"))
                packed.summary.add(record, row, [key for key, _what in EFFECTS])
                packed.shards.setdefault(record["shard"], None)
            packed.materials += 1
            packed.source_bytes += sum(os.path.getsize(layout.path(m.source)) for m in group.shared + group.lightings)
            packed.member_bytes += sum(sizes[0]) + sum(sizes[1])
            packed.repeated_extra += (len(group.records) - 1) * group.shared_bytes
        packed.tars += pair.close()
        pair = None
    except BaseException:
        if pair is not None:
            pair.abort()
        raise
    packed.tars.sort(key=lambda t: t.path)  # as SHA256SUMS and publication.json list them
    return packed


def _copy_sources(output: Output, layout: Layout, packed: _Packed) -> None:
    """The source folder's files byte for byte (the manifest a chunk at a time), and the
    markers of its shards, one line each, in one file."""
    for source, rel in SOURCE_FILES.items():
        if source == MANIFEST_FILE:
            _copy(output, rel, layout.path(source), list_bound(packed.summary.samples))
        else:
            output.write(rel, read_bytes(layout.path(source), MAX_JSON_BYTES))
    markers = StreamedFile(output, MARKERS_REL)
    try:
        for shard in packed.shards:
            markers.write(_marker_line(layout, shard))
    except BaseException:
        markers.abort()
        raise
    markers.close()


def _write_contact_sheet(output: Output, root: str, progress: Callable[[str], None] | None) -> None:
    if progress:
        progress("drawing the contact sheet")
    write_preview(PreviewRequest(directory=root, out=output.path(PREVIEW_FILE), rows=PREVIEW_SAMPLES))
    with open(output.path(PREVIEW_FILE), "rb") as fh:
        output.adopt(PREVIEW_FILE, hashlib.sha256(fh.read()).hexdigest(), os.path.getsize(output.path(PREVIEW_FILE)))


def _publication_facts(
    output: Output,
    layout: Layout,
    spec: DatasetSpec,
    packed: _Packed,
    request: PublishRequest,
    *,
    has_preview: bool,
) -> PublicationFacts:
    """What the metadata files say, from the files written so far (the source files' bytes
    counted as published)."""
    description = json.loads(read_bytes(layout.description, MAX_JSON_BYTES))
    source_bytes = packed.source_bytes
    source_bytes += sum(output.sizes[rel] for rel in SOURCE_FILES.values()) + output.sizes[MARKERS_REL]
    return PublicationFacts(
        spec=spec,
        description=description,
        summary=packed.summary,
        tars=packed.tars,
        license_id=request.license,
        url=request.url,
        shard_bytes=request.shard_bytes,
        files=dict(output.sums),
        sizes=dict(output.sizes),
        source_bytes=source_bytes,
        member_bytes=packed.member_bytes,
        repeated_maps_extra_bytes=packed.repeated_extra,
        materials=packed.materials,
        has_preview=has_preview,
    )


def _write_metadata(output: Output, facts: PublicationFacts) -> None:
    """publication.json, croissant.json (which lists the first's SHA-256), the card, then
    SHA256SUMS of every file."""
    output.write(INDEX_FILE, (json.dumps(publication_index(facts), indent=1, sort_keys=True) + "\n").encode("utf-8"))
    facts.files[INDEX_FILE] = output.sums[INDEX_FILE]
    facts.sizes[INDEX_FILE] = output.sizes[INDEX_FILE]
    output.write(
        CROISSANT_FILE, (json.dumps(croissant_metadata(facts), indent=2, ensure_ascii=False) + "\n").encode("utf-8")
    )
    facts.sizes[CROISSANT_FILE] = output.sizes[CROISSANT_FILE]
    output.write(CARD_FILE, dataset_card(facts).encode("utf-8"))
    output.write(SUMS_FILE, "".join(f"{sha}  {rel}\n" for rel, sha in sorted(output.sums.items())).encode("utf-8"))


def _copy(output: Output, rel: str, path: str, limit: int) -> None:
    """Copy the regular file at ``path`` (at most ``limit`` bytes) to ``rel``, a chunk at a time."""
    copy = StreamedFile(output, rel)
    try:
        for chunk in read_chunks(path, limit):
            copy.write(chunk)
    except BaseException:
        copy.abort()
        raise
    copy.close()


def publication_index(facts: PublicationFacts) -> dict:
    """``publication.json``: what a reader checks the rest against."""
    description = facts.description
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "maps": "once per material: MATERIAL.maps.exr (and MATERIAL.texture.exr) in materials-N.tar, "
        "its lightings in renders-N.tar of the same number",
        "source": {
            "name": description.get("name"),
            "version": description.get("version"),
            "spec_digest": description.get("spec_digest"),
            "plan_digest": description.get("plan_digest"),
            "renders": facts.summary.samples,
            "materials": facts.materials,
        },
        "shard_bytes": facts.shard_bytes,
        "shards": [t.to_dict() for t in facts.tars],
    }
