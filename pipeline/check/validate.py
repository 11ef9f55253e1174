"""`shaderball validate`: a dataset directory checked against its manifest, its plan and itself.

Three layers of checks (docs/validate.md lists every problem kind):

- every file against the manifest: it exists, its size and SHA-256 match the record, it
  decodes, its layers, channels, shapes and sample types are the ones the spec asks for;
- every value for sanity: finite, maps in range, normals of unit length inside the mask,
  renders non-negative (or flagged by the render policy), the statistics of the record equal
  the ones recomputed from the file and the ones in the file's header;
- the whole against the plan: no sample missing or extra, no duplicate record, every record's
  plan fields (ids, seeds, requested lighting, material kind, render settings, file paths)
  equal to the plan, the shard markers and per-sample records agreeing with the manifest,
  no file that is not part of the dataset, the spec snapshot intact.

The default mode reads every file once: the bytes it hashes are the bytes it decodes.
``fast=True`` only lists and stats (sizes, markers, records against the plan).

:func:`pipeline.run.repair.repair` (``--repair``, a writer) re-validates, deletes what is bad, re-runs only the affected shards (through
the resumable build with the dataset's recorded Mitsuba variant, which re-renders only
samples whose record does not verify: on a byte-identical dataset a repaired file is the
original's bytes, on a within-noise one (cuda) a new render that every record copy then
lists), rewrites the manifest from the shard markers and validates again.

Library code: nothing here prints; progress goes to a callback. This module holds the entry
point; the work is split by concern: :mod:`pipeline.check.report` (problem kinds, the
report, its JSON and text), :mod:`pipeline.check.inspect` (one file read, decoded, checked),
:mod:`pipeline.check.loading` (the plan, manifest and markers read first),
:mod:`pipeline.check.crosscheck` (records against the plan, the files and each other).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from pipeline.check.byshard import Phases, check_by_shard, check_extra_by_shard, index_manifest
from pipeline.check.crosscheck import (
    check_extra_files,
    check_files_and_records,
    check_markers,
    check_record_files,
    check_records_against_plan,
    fallback_records,
    referenced_files,
    render_present,
)
from pipeline.check.inspect import inspect_all
from pipeline.check.loading import State, check_root, load_manifest, load_markers, load_plan
from pipeline.check.report import PROBLEM_KINDS, Problem, Problems, Progress, RepairAction, Report
from pipeline.dataset.plan import iter_samples
from pipeline.store.folder import shard_ids_on_disk
from pipeline.store.layout import MANIFEST_FILE

__all__ = ["PROBLEM_KINDS", "Problem", "Progress", "RepairAction", "Report", "validate"]


def validate(
    root: str,
    *,
    fast: bool = False,
    progress: Callable[[Progress], None] | None = None,
    threads: int | None = None,
    keep_state: bool = False,
) -> Report:
    """Check the dataset in ``root``; return a :class:`Report` (``report.ok`` when valid).

    Raises :class:`ShaderballError` when ``root`` is missing or not a dataset directory.
    ``fast``: sizes, markers and records only (no file is read). ``threads``: files read
    at once (hashing and decompression release the GIL); default: up to 4.

    A dataset with a plan and a manifest is checked one shard at a time
    (:mod:`pipeline.check.byshard`: memory bounded by a shard). Without either, or with
    ``keep_state`` (repair: it needs every record, file and marker afterwards, in
    ``report._state``), it is checked whole.
    """
    start = time.perf_counter()
    layout = check_root(root)
    problems = Problems()
    spec, plans, description, spec_ok, description_ok = load_plan(layout, problems, keep=keep_state)
    if plans is not None and not keep_state:
        report = _validate_by_shard(
            root, layout, problems, spec, plans, description, spec_ok, description_ok, fast, progress, threads, start
        )
        if report is not None:
            return report
        plans = plans.kept()
    return _validate_whole(
        root, layout, problems, spec, plans, description, spec_ok, description_ok, fast, progress, threads, start
    )


def _validate_whole(
    root, layout, problems: Problems, spec, plans, description, spec_ok, description_ok, fast, progress, threads, start
) -> Report:
    """The report of :func:`validate`, with every record, file and marker held at once (a
    dataset without a plan or manifest, or a repair, which needs them in ``report._state``)."""
    planned = {}
    if plans is not None:
        planned = {s.sample_id: s for s in iter_samples(plans)}
    shard_ids = [s.shard_id for s in plans] if plans is not None else shard_ids_on_disk(layout)
    state = State(
        layout=layout,
        spec=spec,
        plans=plans,
        planned=planned,
        variant=(description or {}).get("variant"),
        spec_ok=spec_ok,
        description_ok=description_ok,
    )
    manifest = load_manifest(layout, problems, len(planned) if plans is not None else None)
    first = {}
    for _source, record in manifest or ():
        first.setdefault(record["id"], record)
    state.markers = load_markers(
        layout, shard_ids, first, {s.shard_id: s.n_renders for s in plans} if plans is not None else None
    )
    records = manifest if manifest is not None else fallback_records(state)
    primary = check_records_against_plan(records, state, problems, from_manifest=manifest is not None)
    files = referenced_files(primary, state)
    bytes_read = inspect_all(layout.root, files, fast, progress, state.facts, threads, start)
    check_files_and_records(primary, files, state, problems, fast)
    check_markers(state, primary, problems, manifest is not None, fast)
    if not fast:
        check_record_files(state, primary, problems)
    check_extra_files(state, primary, problems)
    state.manifest_dirty = manifest is None or any(p.path == MANIFEST_FILE for p in problems)
    tally = _tally(state, primary, problems, description)
    return Report(
        root=root,
        fast=fast,
        problems=list(problems),
        files_checked=len(files),
        bytes_read=bytes_read,
        seconds=time.perf_counter() - start,
        _state=state,
        **tally,
    )


def _tally(state: State, primary: dict, problems: Problems, description) -> dict:
    """Expected, present, valid and flagged renders of a whole check (a report's counts)."""
    plans, planned = state.plans, state.planned
    counts = (description or {}).get("counts")
    recorded = counts.get("renders") if isinstance(counts, dict) else None  # dataset.json: any type
    expected = (
        len(planned)
        if plans is not None
        else recorded
        if isinstance(recorded, int) and not isinstance(recorded, bool) and recorded >= 0
        else len(primary)
    )
    ids = list(planned) if plans is not None else list(primary)
    present = [i for i in ids if i in primary and render_present(primary[i][1], state)]
    named = {p.id for p in problems if p.id is not None}
    valid = [i for i in present if i not in named and primary[i][1].get("material_id") not in named]
    if plans is None:  # nothing is valid against a plan that cannot be made
        valid = []
    flagged = sum(1 for i in present if (primary[i][1].get("stats") or {}).get("flagged"))
    return {"expected": expected, "present": len(present), "valid": len(valid), "flagged": flagged}


def _validate_by_shard(
    root, layout, head: Problems, spec, plans, description, spec_ok, description_ok, fast, progress, threads, start
) -> Report | None:
    """The report of :func:`validate`, checked one shard at a time; None when the manifest
    cannot be read (missing, not a regular file, over its bound): the whole check reports it."""
    phases = Phases()
    try:
        index = index_manifest(layout, plans, phases.parse, phases.order)
    except OSError:
        return None
    state = State(
        layout=layout,
        spec=spec,
        plans=plans,
        planned={},
        variant=(description or {}).get("variant"),
        spec_ok=spec_ok,
        description_ok=description_ok,
    )
    tally = check_by_shard(state, index, phases, fast, progress, threads, start)
    check_extra_by_shard(state, phases, tally)
    problems = Problems(head)
    problems += phases.joined()
    state.manifest_dirty = any(p.path == MANIFEST_FILE for p in problems)
    return Report(
        root=root,
        fast=fast,
        expected=plans.n_renders,
        present=tally.present,
        valid=tally.valid,
        problems=list(problems),
        flagged=tally.flagged,
        files_checked=tally.files,
        bytes_read=tally.bytes_read,
        seconds=time.perf_counter() - start,
        _state=state,
    )
