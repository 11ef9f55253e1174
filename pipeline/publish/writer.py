"""`shaderball publish DIR --out PUB`: a validated dataset folder as tar shards, a samples
table, a dataset card, Croissant metadata and checksums (layout: pipeline.publish.names).

The same folder gives the same bytes: members in plan order with fixed metadata
(pipeline.publish.tarsafe), JSON with sorted keys, nothing from the clock, the host or
the user. A material's maps are stored once, before its lightings, in the same tar
(docs/publish.md measures what repeating them per sample would cost).

PUB is held for writing (pipeline.store.lock) from its first check to its last file, as
unpack holds its DIR: a second publish into it is refused (exit code 3) naming the first.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from pipeline.check.preview import write_preview
from pipeline.check.snapshot import read_snapshot
from pipeline.check.validate import validate
from pipeline.dataset.spec import DatasetSpec
from pipeline.errors import ShaderballError, bad_value, check_int
from pipeline.publish.card import dataset_card
from pipeline.publish.croissant import croissant_metadata
from pipeline.publish.facts import LICENSES, PublicationFacts, TarFacts
from pipeline.publish.names import (
    CARD_FILE,
    CROISSANT_FILE,
    FORMAT,
    FORMAT_VERSION,
    INDEX_FILE,
    MARKERS_REL,
    MATERIALS,
    PREVIEW_FIELDS,
    PREVIEW_FILE,
    RENDERS,
    SAMPLES_FILE,
    SOURCE_FILES,
    SUMS_FILE,
    member_name,
    tar_rel,
)
from pipeline.publish.output import Output, check_out, held_output
from pipeline.publish.previews import maps_preview, render_preview
from pipeline.publish.refusal import Refused
from pipeline.publish.table import file_refs, material_member, material_row, record_member, sample_row
from pipeline.publish.tarsafe import BLOCK, open_writer, padded, tar_bytes, write_member
from pipeline.store.atomic import atomic_file, sha256_file
from pipeline.store.folder import MAX_JSON_BYTES, list_bound, read_bytes, read_manifest, resolve_inside
from pipeline.store.layout import MANIFEST_FILE, MARKER_FILE, Layout
from pipeline.store.records import dumps

DEFAULT_SHARD_BYTES = 1_000_000_000
SHARD_BYTES_RANGE = (1 << 16, 1 << 40)
DEFAULT_LICENSE = "cc-by-4.0"
PREVIEW_SAMPLES = 8
#: How publish's messages name its output folder.
PUB_LABEL = "PUB"


@dataclass(frozen=True)
class PackedMember:
    """A member to write: its name, the source file (None for a derived member: a preview or
    a material's row, whose bytes are ``data``), its size and its SHA-256."""

    name: str
    source: str | None
    size: int
    sha256: str | None
    data: bytes | None = None


def derived(name: str, data: bytes) -> PackedMember:
    return PackedMember(name, None, len(data), hashlib.sha256(data).hexdigest(), data)


@dataclass
class MaterialGroup:
    """A material's members: its maps (and texture) and their preview for the materials tar,
    then each lighting's record, render and render preview for the renders tar."""

    material_id: str
    shared: list[PackedMember] = field(default_factory=list)  # maps, texture (source files)
    lightings: list[PackedMember] = field(default_factory=list)  # record, render per lighting
    records: list[dict] = field(default_factory=list)
    shared_bytes: int = 0  # tar bytes of the maps and texture members
    maps_preview: PackedMember | None = None
    render_previews: list[PackedMember] = field(default_factory=list)
    record_sums: list[tuple[str, int]] = field(default_factory=list)

    def rows(self, index: int) -> list[dict]:
        """The samples table's rows of the material's lightings, in the tar pair ``index``."""
        maps = (self.maps_preview.sha256, self.maps_preview.size)
        return [
            sample_row(
                record, tar_rel(index, RENDERS), *sums, {"render_preview": (p.sha256, p.size), "maps_preview": maps}
            )
            for record, sums, p in zip(self.records, self.record_sums, self.render_previews)
        ]

    def materials_members(self, index: int) -> list[PackedMember]:
        row = derived(material_member(self.material_id), (dumps(material_row(self.rows(index)[0])) + "\n").encode())
        return [row, *self.shared, self.maps_preview]

    def renders_members(self) -> list[PackedMember]:
        out = []
        for i, preview in enumerate(self.render_previews):
            out += [*self.lightings[2 * i : 2 * i + 2], preview]
        return out

    def sizes(self) -> tuple[list[int], list[int]]:
        """Member sizes in its materials tar and its renders tar (a row's size does not depend
        on the tar's number: six digits always)."""
        return [m.size for m in self.materials_members(0)], [m.size for m in self.renders_members()]


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


def check_options(shard_bytes: int, license_id: str, url: str | None = None) -> None:
    check_int("--shard-bytes", shard_bytes, *SHARD_BYTES_RANGE)
    if license_id not in LICENSES:
        raise bad_value("--license", license_id, ", ".join(LICENSES))
    if url is not None and not (isinstance(url, str) and url.startswith(("https://", "http://")) and " " not in url):
        raise bad_value("--url", url, "an http(s) URL without spaces, where the publication will live")


def publish(
    root: str,
    out: str,
    *,
    shard_bytes: int = DEFAULT_SHARD_BYTES,
    license_id: str = DEFAULT_LICENSE,
    url: str | None = None,
    progress: Callable[[str], None] | None = None,
) -> PublishSummary:
    """Validate the dataset at ``root`` fully, then publish it to ``out``.

    Raises :class:`Refused` (exit code 1) when the dataset is not valid: nothing is written.
    """
    check_options(shard_bytes, license_id, url)
    check_out(out, root, PUB_LABEL)
    start = time.perf_counter()
    # PUB is held from here, validation included: a second publish into it is refused at once.
    with held_output(out, "publish", PUB_LABEL) as output:
        if progress:
            progress(f"validating {root} (every file, as `shaderball validate`)")
        report = validate(root)
        if not report.ok:
            first = "; ".join(p.message for p in report.problems[:3])
            raise Refused(
                "invalid_dataset",
                f"DIR: {root!r} does not pass `shaderball validate` "
                f"({len(report.problems)} problem(s): {first}); nothing was published",
            )
        validation_s = time.perf_counter() - start
        return _write_into(
            output,
            root,
            shard_bytes=shard_bytes,
            license_id=license_id,
            url=url,
            validation_s=validation_s,
            progress=progress,
        )


# --------------------------------------------------------------------------- planning


def _read_manifest(layout: Layout) -> list[dict]:
    data = read_manifest(layout)  # a regular file, bounded (pipeline.store.folder)
    return [json.loads(line) for line in data.decode("utf-8").splitlines() if line.strip()]


def material_groups(layout: Layout, records: list[dict]) -> list[MaterialGroup]:
    """Members of each material in plan order (the manifest's); previews not yet drawn."""
    groups: list[MaterialGroup] = []
    for number, record in enumerate(records, start=1):
        refs = file_refs(record, f"manifest.jsonl line {number}")
        if not groups or groups[-1].material_id != record["material_id"]:
            group = MaterialGroup(record["material_id"])
            for role in ("maps", "texture"):
                if role in refs:
                    ref = refs[role]
                    group.shared.append(PackedMember(ref.member, ref.path, ref.bytes, ref.sha256))
                    group.shared_bytes += BLOCK + padded(ref.bytes)
            groups.append(group)
        group = groups[-1]
        record_rel = Layout.record_rel(record["shard"], record["id"])
        group.lightings.append(
            PackedMember(record_member(record["id"]), record_rel, os.path.getsize(layout.path(record_rel)), None)
        )
        render = refs["render"]
        group.lightings.append(PackedMember(render.member, render.path, render.bytes, render.sha256))
        group.records.append(record)
    return groups


def draw_previews(layout: Layout, group: MaterialGroup, side: int) -> None:
    """Read the material's files once (each checked against the manifest): the records'
    SHA-256, and the previews of its maps and renders (pipeline.publish.previews)."""
    maps = _read_checked(layout, group.shared[0])
    group.maps_preview = derived(
        member_name(group.material_id, PREVIEW_FIELDS["maps_preview"]), maps_preview(maps, side)
    )
    group.render_previews, group.record_sums = [], []
    for i, record in enumerate(group.records):
        record_member_, render_member = group.lightings[2 * i : 2 * i + 2]
        data = _read_checked(layout, record_member_)
        group.record_sums.append((hashlib.sha256(data).hexdigest(), len(data)))
        group.lightings[2 * i] = PackedMember(
            record_member_.name, record_member_.source, len(data), hashlib.sha256(data).hexdigest()
        )
        preview = render_preview(_read_checked(layout, render_member), maps, side)
        group.render_previews.append(derived(member_name(record["id"], PREVIEW_FIELDS["render_preview"]), preview))


def fits(pair_sizes: list[tuple[list[int], list[int]]], sizes: tuple[list[int], list[int]], shard_bytes: int) -> bool:
    """Whether a material whose members have ``sizes`` (MaterialGroup.sizes) joins a tar pair
    whose materials have ``pair_sizes`` with both tars at most ``shard_bytes``."""
    every = pair_sizes + [sizes]
    return all(tar_bytes([n for s in every for n in s[kind]]) <= shard_bytes for kind in (0, 1))


# --------------------------------------------------------------------------- writing


def _read_checked(layout: Layout, member: PackedMember) -> bytes:
    try:  # inside the folder, through no link, a regular file (pipeline.store.folder)
        data = read_bytes(resolve_inside(layout.root, member.source), member.size)
    except OSError as exc:
        raise Refused(
            "changed",
            f"{member.source}: cannot be read ({exc.strerror}): the folder changed while "
            "it was published; publish again",
        ) from None
    if len(data) != member.size or (member.sha256 and hashlib.sha256(data).hexdigest() != member.sha256):
        raise Refused(
            "changed",
            f"{member.source}: {len(data)} bytes whose SHA-256 differs from the manifest's: "
            "the folder changed while it was published; publish again",
        )
    return data


def _write_tar(output: Output, layout: Layout, rel: str, members: list[PackedMember]) -> tuple[int, str]:
    """Write the tar ``rel`` of ``members`` atomically; its size and SHA-256."""
    final = output.path(rel)
    with atomic_file(final) as fh:
        with open_writer(fh) as tar:
            for member in members:
                write_member(tar, member.name, member.data if member.source is None else _read_checked(layout, member))
        size = fh.tell()
    digest = sha256_file(final)
    expected = tar_bytes([m.size for m in members])
    assert size == expected, (size, expected)
    output.adopt(rel, digest, size)
    return size, digest


def _write_pair(
    output: Output, layout: Layout, index: int, pair: list[MaterialGroup]
) -> tuple[list[TarFacts], list[dict]]:
    """The materials tar and the renders tar of number ``index``; their facts and the rows."""
    rows = [row for group in pair for row in group.rows(index)]
    facts = []
    for kind in (MATERIALS, RENDERS):
        rel = tar_rel(index, kind)
        members = [m for g in pair for m in (g.materials_members(index) if kind == MATERIALS else g.renders_members())]
        size, digest = _write_tar(output, layout, rel, members)
        first, last = (
            (pair[0].material_id, pair[-1].material_id) if kind == MATERIALS else (rows[0]["id"], rows[-1]["id"])
        )
        facts.append(
            TarFacts(
                path=rel,
                kind=kind,
                bytes=size,
                sha256=digest,
                members=len(members),
                samples=len(rows),
                materials=len(pair),
                first=first,
                last=last,
            )
        )
    for group in pair:  # the previews are written: keep their sums, not their bytes
        group.maps_preview = replace(group.maps_preview, data=b"")
        group.render_previews = [replace(p, data=b"") for p in group.render_previews]
    return facts, rows


def _markers(layout: Layout, records: list[dict]) -> bytes:
    """Every shard's marker file, byte for byte, one line each, in plan order."""
    lines = []
    for shard in dict.fromkeys(r["shard"] for r in records):
        data = read_bytes(resolve_inside(layout.root, Layout.marker_rel(shard)), list_bound(None))
        if not data.endswith(b"\n") or data.count(b"\n") != 1:
            raise Refused(
                "invalid_dataset",
                f"shards/{shard}/{MARKER_FILE}: not one line of JSON as "
                "`shaderball build` writes it; cannot publish it byte for byte",
            )
        lines.append(data)
    return b"".join(lines)


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
    check_options(shard_bytes, license_id, url)
    check_out(out, root, PUB_LABEL)
    with held_output(out, "publish", PUB_LABEL) as output:
        return _write_into(
            output,
            root,
            shard_bytes=shard_bytes,
            license_id=license_id,
            url=url,
            contact_sheet=contact_sheet,
            validation_s=validation_s,
            progress=progress,
        )


def _write_into(
    output: Output,
    root: str,
    *,
    shard_bytes: int,
    license_id: str,
    url: str | None,
    contact_sheet: bool = True,
    validation_s: float,
    progress: Callable[[str], None] | None,
) -> PublishSummary:
    """The publication of ``root``, written into ``output`` while this process holds it
    (:func:`pipeline.publish.output.held_output` removes it again on a failure)."""
    out = output.out
    start = time.perf_counter()
    layout = Layout(root)
    spec: DatasetSpec = read_snapshot(root)
    records = _read_manifest(layout)
    if not records:
        raise ShaderballError(f"DIR: {root!r} has no records in its manifest; nothing to publish")
    groups = material_groups(layout, records)
    side = spec.render.resolution
    tars, rows = [], []
    pair: list[MaterialGroup] = []
    pair_sizes: list[tuple[list[int], list[int]]] = []
    for number, group in enumerate(groups, start=1):
        if progress:
            progress(f"previews of {group.material_id} ({number}/{len(groups)})")
        draw_previews(layout, group, side)
        sizes = group.sizes()
        if pair and not fits(pair_sizes, sizes, shard_bytes):
            index = len(tars) // 2
            if progress:
                progress(f"writing {tar_rel(index, MATERIALS)} and {tar_rel(index, RENDERS)}")
            written, pair_rows = _write_pair(output, layout, index, pair)
            tars += written
            rows += pair_rows
            pair, pair_sizes = [], []
        pair.append(group)
        pair_sizes.append(sizes)
    written, pair_rows = _write_pair(output, layout, len(tars) // 2, pair)
    tars += written
    rows += pair_rows
    tars.sort(key=lambda t: t.path)  # as SHA256SUMS and publication.json list them
    for source, rel in SOURCE_FILES.items():
        output.write(
            rel,
            read_bytes(layout.path(source), MAX_JSON_BYTES if source != MANIFEST_FILE else list_bound(len(records))),
        )
    output.write(MARKERS_REL, _markers(layout, records))
    output.write(SAMPLES_FILE, "".join(dumps(row) + "\n" for row in rows).encode("utf-8"))
    if contact_sheet:
        if progress:
            progress("drawing the contact sheet")
        write_preview(root, output.path(PREVIEW_FILE), samples=PREVIEW_SAMPLES)
        with open(output.path(PREVIEW_FILE), "rb") as fh:
            output.adopt(
                PREVIEW_FILE, hashlib.sha256(fh.read()).hexdigest(), os.path.getsize(output.path(PREVIEW_FILE))
            )
    description = json.loads(read_bytes(layout.description, MAX_JSON_BYTES))
    source_bytes = (
        sum(os.path.getsize(layout.path(m.source)) for g in groups for m in g.shared + g.lightings)
        + sum(output.sizes[rel] for rel in SOURCE_FILES.values())
        + output.sizes[MARKERS_REL]
    )
    facts = PublicationFacts(
        spec=spec,
        description=description,
        records=records,
        rows=rows,
        tars=tars,
        license_id=license_id,
        url=url,
        shard_bytes=shard_bytes,
        files=dict(output.sums),
        sizes=dict(output.sizes),
        source_bytes=source_bytes,
        member_bytes=sum(sum(a) + sum(b) for a, b in (g.sizes() for g in groups)),
        repeated_maps_extra_bytes=sum((len(g.records) - 1) * g.shared_bytes for g in groups),
        materials=len(groups),
        has_preview=contact_sheet,
    )
    output.write(INDEX_FILE, (json.dumps(publication_index(facts), indent=1, sort_keys=True) + "\n").encode("utf-8"))
    facts.files[INDEX_FILE] = output.sums[INDEX_FILE]
    facts.sizes[INDEX_FILE] = output.sizes[INDEX_FILE]
    output.write(
        CROISSANT_FILE, (json.dumps(croissant_metadata(facts), indent=2, ensure_ascii=False) + "\n").encode("utf-8")
    )
    facts.sizes[CROISSANT_FILE] = output.sizes[CROISSANT_FILE]
    output.write(CARD_FILE, dataset_card(facts).encode("utf-8"))
    output.write(SUMS_FILE, "".join(f"{sha}  {rel}\n" for rel, sha in sorted(output.sums.items())).encode("utf-8"))
    published = sum(output.sizes.values())
    return PublishSummary(
        out=out,
        samples=len(records),
        materials=len(groups),
        tars=tars,
        published_bytes=published,
        source_bytes=facts.source_bytes,
        member_bytes=facts.member_bytes,
        repeated_maps_extra_bytes=facts.repeated_maps_extra_bytes,
        validation_s=validation_s,
        seconds=time.perf_counter() - start,
    )


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
            "renders": len(facts.records),
            "materials": facts.materials,
        },
        "shard_bytes": facts.shard_bytes,
        "shards": [t.to_dict() for t in facts.tars],
    }
