"""`shaderball validate`: a dataset directory checked against its manifest, its plan and itself.

Three layers of checks (docs/validate.md lists every problem kind with its message):

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

:func:`repair` re-validates, deletes what is bad, re-runs only the affected shards (through
the resumable build with the dataset's recorded Mitsuba variant, which re-renders only
samples whose record does not verify: on a byte-identical dataset a repaired file is the
original's bytes, on a within-noise one (cuda) a new render that every record copy then
lists), rewrites the manifest from the shard markers and validates again.

Library code: nothing here prints; progress goes to a callback. This module holds the two
entry points; the work is split by concern: :mod:`pipeline.check.report` (problem kinds, the
report, its JSON and text), :mod:`pipeline.check.inspect` (one file read, decoded, checked),
:mod:`pipeline.check.crosscheck` (records against the plan, the files and each other) and
:mod:`pipeline.check.repair` (the steps of :func:`repair`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from pipeline.check.crosscheck import (
    State,
    check_extra_files,
    check_files_and_records,
    check_markers,
    check_record_files,
    check_records_against_plan,
    check_root,
    fallback_records,
    load_manifest,
    load_markers,
    load_plan,
    marker_record,
    referenced_files,
    render_present,
)
from pipeline.check.inspect import inspect_all
from pipeline.check.repair import (
    chosen_record,
    delete_extra_files,
    describe_rerenders,
    inspect_unlisted,
    lost_render_digests,
    rebuild,
    remove_file,
    repair_variant,
    restore_spec,
    settle_samples,
    write_good_record_files,
)
from pipeline.check.report import PROBLEM_KINDS, Problem, Problems, Progress, RepairAction, Report
from pipeline.dataset.plan import iter_samples
from pipeline.errors import filesystem_error
from pipeline.run.build import write_manifest
from pipeline.store.folder import shard_ids_on_disk
from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, SPEC_FILE
from pipeline.store.lock import writer_lock

__all__ = ["PROBLEM_KINDS", "Problem", "Progress", "RepairAction", "Report", "repair", "validate"]


def validate(
    root: str, *, fast: bool = False, progress: Callable[[Progress], None] | None = None, threads: int | None = None
) -> Report:
    """Check the dataset in ``root``; return a :class:`Report` (``report.ok`` when valid).

    Raises :class:`ShaderballError` when ``root`` is missing or not a dataset directory.
    ``fast``: sizes, markers and records only (no file is read). ``threads``: files read
    at once (hashing and decompression release the GIL); default: up to 4.
    """
    start = time.perf_counter()
    layout = check_root(root)
    problems = Problems()
    spec, plans, description, spec_ok, description_ok = load_plan(layout, problems)
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
        manifest={},
        markers={},
        record_files={},
        facts={},
        extra_files=[],
        allowed_dirs=set(),
        manifest_dirty=False,
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
    return Report(
        root=root,
        fast=fast,
        expected=expected,
        present=len(present),
        valid=len(valid),
        problems=list(problems),
        flagged=flagged,
        files_checked=len(files),
        bytes_read=bytes_read,
        seconds=time.perf_counter() - start,
        _state=state,
    )


def repair(
    root: str, *, workers: int = 0, progress: Callable[[Progress], None] | None = None, spec_path: str | None = None
) -> tuple[Report, Report, list[RepairAction]]:
    """Fix what :func:`validate` finds; return (report before, report after, actions).

    A writer: it holds ``root`` (pipeline.store.lock) from the first check to the last, so
    it never runs beside a build (FolderBusy, exit code 3, names the build that holds it).
    """
    check_root(root)
    try:
        with writer_lock(root, "validate --repair"):
            return _repair_locked(root, workers=workers, progress=progress, spec_path=spec_path)
    except OSError as exc:
        raise filesystem_error(exc, root, "every write is atomic: fix the cause and run the repair again") from None


def _repair_locked(
    root: str, *, workers: int, progress: Callable[[Progress], None] | None, spec_path: str | None
) -> tuple[Report, Report, list[RepairAction]]:
    """:func:`repair` under the lock.

    Deletes extra files; keeps every sample whose best record (the marker's, the record
    file's, or the manifest's copy) agrees with the plan and with its intact render; deletes
    the other renders and records and every bad material file; re-runs the affected shards
    through the resumable build (``workers`` as for ``shaderball build``), which regenerates
    deleted maps and re-renders only samples left without a verified record; rewrites the
    manifest from the shard markers; validates again.

    A spec snapshot that is unreadable or does not match dataset.json's digest is restored
    from ``spec_path`` when that spec's digest is dataset.json's (else ShaderballError);
    without ``spec_path`` it is not repaired (which side is right is unknown): the actions
    say so and nothing is changed.
    """
    before = validate(root, progress=progress)
    if before.ok:
        return before, before, []
    state, actions = before._state, []
    if (state.plans is None or not state.spec_ok) and spec_path is not None:
        actions.append(restore_spec(state, spec_path))
        current = validate(root, progress=progress)
        if current.ok:
            return before, current, actions
        state = current._state
    if state.plans is None or not state.spec_ok:
        return (
            before,
            before,
            actions
            + [
                RepairAction(
                    "unrepairable",
                    SPEC_FILE,
                    f"{SPEC_FILE}: the spec snapshot is unusable or does not match {DESCRIPTION_FILE}; "
                    "give the spec the dataset was built from (--spec) to restore it; nothing was changed",
                )
            ],
        )
    layout = state.layout
    variant = repair_variant(state)  # the dataset's own, or SetupError before anything changes
    delete_extra_files(state, actions)
    inspect_unlisted(state)
    chosen = {sid: chosen_record(state, sample) for sid, sample in state.planned.items()}
    lost = lost_render_digests(state, chosen)
    affected = settle_samples(state, chosen, actions)
    for shard in state.plans:
        marker = state.markers.get(shard.shard_id)
        if not (
            isinstance(marker, dict)
            and marker.get("complete")
            and marker.get("samples") == [s.sample_id for s in shard.samples]
            and all(marker_record(state, s) == chosen[s.sample_id] for s in shard.samples)
        ):
            affected.add(shard.shard_id)
    write_good_record_files(state, chosen, affected, actions)
    for sid in sorted(affected):
        remove_file(layout.marker(sid))
        actions.append(
            RepairAction(
                "rerun_shard", layout.marker_rel(sid), f"shard {sid}: marker removed; rebuilt from its verified records"
            )
        )
    if affected or not state.description_ok:
        rebuild(root, workers, progress, len(affected), variant)
        actions = describe_rerenders(state, lost, actions)
        if not state.description_ok:
            actions.append(
                RepairAction(
                    "rewrite_description", DESCRIPTION_FILE, f"{DESCRIPTION_FILE}: rewritten from the spec snapshot"
                )
            )
        actions.append(
            RepairAction(
                "rewrite_manifest",
                MANIFEST_FILE,
                f"{MANIFEST_FILE}: rewritten from the shard markers by the resumed build",
            )
        )
    elif state.manifest_dirty:
        write_manifest(layout.root, state.plans)
        actions.append(
            RepairAction("rewrite_manifest", MANIFEST_FILE, f"{MANIFEST_FILE}: rewritten from the shard markers")
        )
    after = validate(root, progress=progress)
    return before, after, actions
