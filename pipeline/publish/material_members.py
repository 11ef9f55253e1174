"""What a publication's tars hold, planned from the manifest a material at a time: each
material's members (:class:`MaterialGroup`: its maps and texture for the materials tar, each
lighting's record and render for the renders tar), every file read checked against the
manifest, and their previews drawn."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, field

from pipeline.publish.names import PREVIEW_FIELDS, RENDERS, member_name, tar_rel
from pipeline.publish.previews import maps_preview, render_preview
from pipeline.publish.refusal import Refused
from pipeline.publish.table import file_refs, material_member, material_row, record_member, sample_row
from pipeline.publish.tarsafe import BLOCK, padded
from pipeline.store.bounded_read import read_bytes, resolve_inside
from pipeline.store.folder import iter_manifest
from pipeline.store.layout import Layout
from pipeline.store.records import dumps


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
    scene: bool = False  # the rows have the scene columns (pipeline.publish.scene_fields)

    def rows(self, index: int) -> list[dict]:
        """The samples table's rows of the material's lightings, in the tar pair ``index``."""
        maps = (self.maps_preview.sha256, self.maps_preview.size)
        return [
            sample_row(
                record,
                tar_rel(index, RENDERS),
                *sums,
                {"render_preview": (p.sha256, p.size), "maps_preview": maps},
                self.scene,
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


# --------------------------------------------------------------------------- planning


def manifest_records(layout: Layout):
    """(line number, record) of every non-empty line of the manifest, a line at a time (a
    regular file, bounded: pipeline.store.folder). Publish runs on a validated folder, so
    every line is a record; ``write_publication`` on an unvalidated one stops at the first
    line that is not JSON."""
    for number, _offset, line in iter_manifest(layout):
        if line.strip():
            yield number, json.loads(line)


def material_groups(layout: Layout, records, scene: bool = False) -> Iterator[MaterialGroup]:
    """Members of each material in plan order (the manifest's), one material at a time;
    ``records``: (line number, record) in manifest order; previews not yet drawn; ``scene``:
    rows with the scene columns (pipeline.publish.scene_fields.has_scene_columns)."""
    group = None
    for number, record in records:
        refs = file_refs(record, f"manifest.jsonl line {number}")
        if group is None or group.material_id != record["material_id"]:
            if group is not None:
                yield group
            group = MaterialGroup(record["material_id"], scene=scene)
            for role in ("maps", "texture"):
                if role in refs:
                    ref = refs[role]
                    group.shared.append(PackedMember(ref.member, ref.path, ref.bytes, ref.sha256))
                    group.shared_bytes += BLOCK + padded(ref.bytes)
        record_rel = Layout.record_rel(record["shard"], record["id"])
        group.lightings.append(
            PackedMember(record_member(record["id"]), record_rel, os.path.getsize(layout.path(record_rel)), None)
        )
        render = refs["render"]
        group.lightings.append(PackedMember(render.member, render.path, render.bytes, render.sha256))
        group.records.append(record)
    if group is not None:
        yield group


def draw_previews(layout: Layout, group: MaterialGroup, side: int) -> None:
    """Read the material's files once (each checked against the manifest): the records'
    SHA-256, and the previews of its maps and renders (pipeline.publish.previews)."""
    maps = read_checked(layout, group.shared[0])
    group.maps_preview = derived(
        member_name(group.material_id, PREVIEW_FIELDS["maps_preview"]), maps_preview(maps, side)
    )
    group.render_previews, group.record_sums = [], []
    for i, record in enumerate(group.records):
        record_member_, render_member = group.lightings[2 * i : 2 * i + 2]
        data = read_checked(layout, record_member_)
        group.record_sums.append((hashlib.sha256(data).hexdigest(), len(data)))
        group.lightings[2 * i] = PackedMember(
            record_member_.name, record_member_.source, len(data), hashlib.sha256(data).hexdigest()
        )
        preview = render_preview(read_checked(layout, render_member), maps, side)
        group.render_previews.append(derived(member_name(record["id"], PREVIEW_FIELDS["render_preview"]), preview))


# --------------------------------------------------------------------------- writing


def read_checked(layout: Layout, member: PackedMember) -> bytes:
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
