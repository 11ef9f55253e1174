"""validate one shard at a time: memory bounded by a shard, not by the dataset.

The manifest is read twice, a line at a time. The first pass checks each line (JSON, the
record's field types), finds duplicates, records the plan does not have and records out of
plan order, and keeps a compact index: for every planned sample, the byte offset, length
and line number of its first record (numpy arrays, 20 bytes a render). The second pass
goes shard by shard in plan order: the shard is planned, its records are read back at
their offsets, its marker is read, its files are inspected, and the checks of
:mod:`pipeline.check.crosscheck` run on a :class:`~pipeline.check.loading.State` that
holds this shard alone; then all of it is dropped. Files that are no part of the dataset
are found by one walk of the folder, each shard folder's allowed names made from its plan
when the walk reaches it.

The problems are those the whole-dataset check reports, in the same order on a dataset
whose manifest is in plan order: each kind of check keeps its own list (manifest lines;
duplicates, extras and order; missing samples; files; records; markers; record files;
extra files), joined at the end. What this mode does not do: a file listed by records of
two shards (each record's plan check already reports the second) is inspected in each
shard; records the plan does not have are checked together after the last shard.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field

import numpy as np

from pipeline.check.crosscheck import (
    check_extra_files,
    check_files,
    check_markers,
    check_missing_samples,
    check_record_files,
    check_records,
    referenced_files,
    render_present,
)
from pipeline.check.discrepancies import expected_files
from pipeline.check.inspect import inspect_all
from pipeline.check.loading import ROOT_FILES, Source, State, load_markers, manifest_line_record
from pipeline.check.report import Problems
from pipeline.dataset.plan import Plan, sample_id, shard_id
from pipeline.store.bounded_read import read_line_at
from pipeline.store.folder import SHARD_NAME, iter_manifest
from pipeline.store.layout import LOCK_FILE, MANIFEST_FILE, SHARDS_DIR, Layout

#: A sample id as the plan writes it: ``m<6-digit material>_l<light>``.
_SAMPLE_ID = re.compile(r"^m(\d{6})_l(\d+)\Z", re.ASCII)


def plan_position(plans: Plan, sid: str) -> int | None:
    """The position of sample ``sid`` in plan order (material x lightings + light), or None
    when the plan does not have it: from the id's digits, without planning anything."""
    match = _SAMPLE_ID.match(sid)
    if match is None:
        return None
    material, light = int(match.group(1)), int(match.group(2))
    ds = plans.spec.dataset
    if material >= ds.materials or light >= ds.lights_per_material or sample_id(material, light) != sid:
        return None
    return material * ds.lights_per_material + light


@dataclass
class ManifestIndex:
    """Where the first record of each planned sample lies in the manifest (-1: none), and
    the first record of each sample the plan does not have (few: an edited manifest)."""

    path: str
    offset: np.ndarray  # int64, one per planned render
    length: np.ndarray  # int32
    line: np.ndarray  # int64
    others: dict = field(default_factory=dict)  # sample id -> (offset, length, line)

    def record(self, position: int) -> tuple[Source, dict] | None:
        """(source, record) of the first record of the planned sample at ``position``."""
        offset = int(self.offset[position])
        if offset < 0:
            return None
        return self._read(offset, int(self.length[position]), int(self.line[position]))

    def _read(self, offset: int, length: int, line: int) -> tuple[Source, dict]:
        return Source(MANIFEST_FILE, line), json.loads(read_line_at(self.path, offset, length))

    def other_records(self) -> list[tuple[Source, dict]]:
        return [self._read(*where) for where in self.others.values()]


def index_manifest(layout, plans: Plan, parse: Problems, order: Problems) -> ManifestIndex:
    """One pass over the manifest: line problems into ``parse`` (as
    :func:`pipeline.check.loading.load_manifest` reports them), duplicates, records the
    plan does not have and the first record out of plan order into ``order`` (as
    :func:`pipeline.check.crosscheck.check_records_against_plan`). OSError when the manifest
    cannot be read (the caller then checks the dataset whole, which reports it)."""
    n = plans.n_renders
    index = ManifestIndex(layout.manifest, np.full(n, -1, np.int64), np.zeros(n, np.int32), np.zeros(n, np.int64))
    last, order_reported = -1, False
    for number, offset, raw in iter_manifest(layout, n):
        if not raw.strip():
            continue
        record = manifest_line_record(raw, number, parse)
        if record is None:
            continue
        sid = record["id"]
        position = plan_position(plans, sid)
        first = index.others.get(sid) if position is None else _where(index, position)
        source = Source(MANIFEST_FILE, number)
        if first is not None:
            first_source, first_record = index._read(*first)
            same = "identical" if record == first_record else "different"
            order.add(
                "duplicate_record",
                sid,
                source.path,
                f"{source}: a second record for {sid} ({same} to the first, at {first_source})",
            )
            continue
        if position is None:
            index.others[sid] = (offset, len(raw), number)
            order.add("extra_sample", sid, source.path, f"{source}: record for {sid}, which the plan does not have")
            continue
        index.offset[position], index.length[position], index.line[position] = offset, len(raw), number
        if position < last and not order_reported:
            order.add("edited_record", sid, source.path, f"{source}: record for {sid} is out of plan order")
            order_reported = True
        last = max(last, position)
    return index


def _where(index: ManifestIndex, position: int) -> tuple[int, int, int] | None:
    offset = int(index.offset[position])
    return None if offset < 0 else (offset, int(index.length[position]), int(index.line[position]))


class PlannedFiles:
    """The files that belong to a dataset, asked one at a time (``rel in files``): the top
    files, and in a planned shard's folder its marker, record files and planned files, made
    from that shard's plan when first asked (a walk asks a folder's names together)."""

    def __init__(self, plans: Plan, spec):
        self.plans, self.spec = plans, spec
        self._shard: tuple[int | None, frozenset] = (None, frozenset())

    def __contains__(self, rel) -> bool:
        if rel in ROOT_FILES or rel == LOCK_FILE:
            return True
        parts = rel.split("/")
        index = shard_index(self.plans, parts[1]) if len(parts) == 3 and parts[0] == SHARDS_DIR else None
        if index is None:
            return False
        if self._shard[0] != index:
            self._shard = (index, frozenset(_shard_files(self.plans[index], self.spec)))
        return rel in self._shard[1]


class PlannedDirs:
    """``shards`` and the folder of every planned shard (``rel in dirs``)."""

    def __init__(self, plans: Plan):
        self.plans = plans

    def __contains__(self, rel) -> bool:
        if rel == SHARDS_DIR:
            return True
        parts = rel.split("/")
        return len(parts) == 2 and parts[0] == SHARDS_DIR and shard_index(self.plans, parts[1]) is not None


def shard_index(plans: Plan, name: str) -> int | None:
    """The index of the planned shard whose folder is ``name``, or None."""
    if not SHARD_NAME.match(name):
        return None
    index = int(name[1:])
    return index if index < len(plans) and shard_id(index) == name else None


def _shard_files(shard, spec) -> set[str]:
    files = {Layout.marker_rel(shard.shard_id)}
    for sample in shard.samples:
        files.add(Layout.record_rel(shard.shard_id, sample.sample_id))
        files.update(rel for _role, rel in expected_files(sample, spec))
    return files


@dataclass
class Phases:
    """The problems of each kind of check, joined in the whole check's order at the end."""

    parse: Problems = field(default_factory=Problems)
    order: Problems = field(default_factory=Problems)
    missing: Problems = field(default_factory=Problems)
    files: Problems = field(default_factory=Problems)
    records: Problems = field(default_factory=Problems)
    markers: Problems = field(default_factory=Problems)
    record_files: Problems = field(default_factory=Problems)
    extra: Problems = field(default_factory=Problems)

    def joined(self) -> Problems:
        out = Problems()
        for part in (
            self.parse,
            self.order,
            self.missing,
            self.files,
            self.records,
            self.markers,
            self.record_files,
            self.extra,
        ):
            out += part
        return out

    def sizes(self) -> tuple[int, ...]:
        return tuple(len(p) for p in (self.missing, self.files, self.records, self.markers, self.record_files))

    def since(self, sizes: tuple[int, ...]):
        parts = (self.missing, self.files, self.records, self.markers, self.record_files)
        for part, size in zip(parts, sizes):
            yield from part[size:]


@dataclass
class Tally:
    """What the report counts, summed shard by shard."""

    present: int = 0
    valid: int = 0
    flagged: int = 0
    files: int = 0
    bytes_read: int = 0
    unsafe_listed: set = field(default_factory=set)  # unsafe files records list (few)


def check_by_shard(state: State, index: ManifestIndex, phases: Phases, fast: bool, progress, threads, start) -> Tally:
    """Every shard of ``state.plans`` (a lazy plan) checked alone, then the records the plan
    does not have; ``state`` holds the dataset-wide facts (layout, spec, variant)."""
    plans, spec, tally = state.plans, state.spec, Tally()
    named_before = {p.id for p in (*phases.parse, *phases.order) if p.id is not None}
    total = plans.n_renders + spec.dataset.materials * (2 if spec.storage.texture_maps else 1)
    for number in range(len(plans)):
        shard = plans[number]
        positions = _positions(plans, number)
        primary = {}
        for position in positions:
            found = index.record(position)
            if found is not None:
                primary[found[1]["id"]] = found
        one = _shard_state(state, shard)
        one.markers = load_markers(
            state.layout,
            [shard.shard_id],
            {sid: rec for sid, (_src, rec) in primary.items()},
            {shard.shard_id: shard.n_renders},
        )
        sizes = phases.sizes()
        check_missing_samples(one, primary, phases.missing, True)
        _check_group(one, primary, phases, fast, progress, threads, start, tally, total)
        check_markers(one, primary, phases.markers, True, fast)
        if not fast:
            check_record_files(one, primary, phases.record_files)
        named = named_before | {p.id for p in phases.since(sizes) if p.id is not None}
        _count(one, primary, named, tally)
    others = {rec["id"]: (src, rec) for src, rec in index.other_records()}
    if others:  # records the plan does not have: their files are checked, nothing else
        one = _shard_state(state, None)
        _check_group(one, others, phases, fast, progress, threads, start, tally, total)
    return tally


def _positions(plans: Plan, number: int) -> range:
    lights = plans.spec.dataset.lights_per_material
    materials = plans.material_range(number)
    return range(materials.start * lights, materials.stop * lights)


def _shard_state(state: State, shard) -> State:
    return State(
        layout=state.layout,
        spec=state.spec,
        plans=[shard] if shard is not None else [],
        planned={s.sample_id: s for s in shard.samples} if shard is not None else {},
        variant=state.variant,
        spec_ok=state.spec_ok,
        description_ok=state.description_ok,
    )


def _check_group(
    one: State, primary: dict, phases: Phases, fast, progress, threads, start, tally: Tally, total
) -> None:
    files = referenced_files(primary, one)
    tally.bytes_read += inspect_all(
        one.layout.root,
        files,
        fast,
        progress,
        one.facts,
        threads,
        start,
        done_before=tally.files,
        total=total,
        bytes_before=tally.bytes_read,
    )
    tally.files += len(files)
    tally.unsafe_listed.update(rel for rel, facts in one.facts.items() if facts.unsafe)
    check_files(files, one, phases.files)
    check_records(primary, files, one, phases.records, fast)


def _count(one: State, primary: dict, named: set, tally: Tally) -> None:
    present = [i for i in one.planned if i in primary and render_present(primary[i][1], one)]
    tally.present += len(present)
    tally.valid += sum(1 for i in present if i not in named and primary[i][1].get("material_id") not in named)
    tally.flagged += sum(1 for i in present if (primary[i][1].get("stats") or {}).get("flagged"))


def check_extra_by_shard(state: State, phases: Phases, tally: Tally) -> None:
    """Files no part of the dataset, by one walk with each shard's names made when reached."""
    allowed = (PlannedFiles(state.plans, state.spec), PlannedDirs(state.plans))
    check_extra_files(state, {}, phases.extra, allowed=allowed, unsafe_listed=tally.unsafe_listed)
