"""What validate and repair read of a dataset before they check it: the folder (refused when
it is no dataset), the plan from its spec snapshot and description, manifest.jsonl a line at a
time, the shard markers; and :class:`State`, everything validate learns, kept for repair."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

from pipeline.check.report import Problems
from pipeline.check.request import dir_refused
from pipeline.check.snapshot import read_snapshot
from pipeline.dataset.plan import PLAN_FORMAT, Plan, plan_dataset
from pipeline.dataset.spec_file import source_changes, spec_digest
from pipeline.errors import USER_ERRORS, short_repr
from pipeline.store.bounded_read import list_bound, read_json_checked, structure_problem
from pipeline.store.folder import read_json_in, read_manifest
from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, SPEC_FILE, Layout
from pipeline.store.record_fields import description_problem, field_type_problem
from pipeline.store.records import read_json

#: Files at the top of DIR that belong to the dataset.
ROOT_FILES = (SPEC_FILE, DESCRIPTION_FILE, MANIFEST_FILE)


@dataclass
class Source:
    """Where a record was read: 'manifest.jsonl line 3' or a marker or record file."""

    path: str
    line: int | None = None

    def __str__(self) -> str:
        return f"{self.path} line {self.line}" if self.line else self.path


@dataclass
class State:
    """Everything validate learned, kept for repair."""

    layout: Layout
    spec: object | None
    plans: Plan | None
    planned: dict  # sample id -> SamplePlan, plan order
    variant: str | None
    spec_ok: bool
    description_ok: bool
    # what the checks fill in, empty at the start
    manifest: dict = field(default_factory=dict)  # sample id -> first manifest record
    markers: dict = field(default_factory=dict)  # shard id -> marker dict or None
    record_files: dict = field(default_factory=dict)  # sample id -> record file content or None
    facts: dict = field(default_factory=dict)  # rel path -> FileFacts
    extra_files: list[str] = field(default_factory=list)
    allowed_dirs: set = field(default_factory=set)
    manifest_dirty: bool = False


def check_root(root: str) -> Layout:
    if not os.path.exists(root):
        raise dir_refused(root, "does not exist")
    if not os.path.isdir(root):
        raise dir_refused(root, "is not a folder")
    layout = Layout(root)
    if not any(os.path.lexists(os.path.join(root, name)) for name in ROOT_FILES):
        raise dir_refused(root, f"is not a shaderball dataset: it holds none of {', '.join(ROOT_FILES)}")
    return layout


def load_plan(layout: Layout, problems: Problems, keep: bool = True):
    """(spec, plans, description, spec_ok, description_ok); spec and plans None if unusable.
    ``keep``: every shard planned now and kept (a reader that holds every record anyway);
    else a lazy plan, each shard made when asked for."""

    description = read_json(layout.description)
    description_ok = isinstance(description, dict)
    typed = description_problem(description) if description_ok else None
    if typed:
        problems.add(
            "spec_snapshot",
            None,
            DESCRIPTION_FILE,
            f"{DESCRIPTION_FILE}: {typed}; it records the spec digest, variant and counts",
        )
        description, description_ok = None, False
    elif not description_ok:
        what = read_json_checked(layout.description)[1] or "not a JSON object"
        problems.add(
            "spec_snapshot",
            None,
            DESCRIPTION_FILE,
            f"{DESCRIPTION_FILE}: {what}; it records the spec digest, variant and counts",
        )
        description = None
    if not os.path.lexists(layout.spec):
        problems.add(
            "spec_snapshot", None, SPEC_FILE, f"{SPEC_FILE}: missing; the dataset cannot be checked against its plan"
        )
        return None, None, description, False, description_ok
    try:
        spec = read_snapshot(layout.root)
    except USER_ERRORS as exc:
        problems.add(
            "spec_snapshot",
            None,
            SPEC_FILE,
            f"{SPEC_FILE}: unreadable ({exc}); the dataset cannot be checked against its plan",
        )
        return None, None, description, False, description_ok
    if description is not None and description.get("spec_digest") != spec_digest(spec):
        changed = source_changes(description.get("sources"), spec)
        problems.add(
            "spec_snapshot",
            None,
            SPEC_FILE,
            f"{SPEC_FILE}: digest {spec_digest(spec)[:12]} differs from "
            f"{DESCRIPTION_FILE}'s spec_digest {str(description.get('spec_digest'))[:12]}: "
            + (
                "a file the spec names is not the one the dataset was built from: " + "; ".join(changed)
                if changed
                else "the snapshot (or the description) was edited after the build"
            ),
        )
        spec_ok = False
    else:
        spec_ok = True
    plan_format = description.get("plan_format", 1) if description is not None else PLAN_FORMAT
    if plan_format != PLAN_FORMAT:
        problems.add(
            "spec_snapshot",
            None,
            DESCRIPTION_FILE,
            f"{DESCRIPTION_FILE}: planned with plan format {short_repr(plan_format)}; this shaderball plans "
            f"format {PLAN_FORMAT} (docs/spec.md, 'The same plan on every machine') and cannot check its "
            "records against their plan: validate it with the shaderball that built it",
        )
        return spec, None, description, False, description_ok
    try:
        plans = plan_dataset(spec)
        plans = plans.kept() if keep else plans
    except USER_ERRORS as exc:
        problems.add("spec_snapshot", None, SPEC_FILE, f"{SPEC_FILE}: cannot be planned ({exc})")
        return spec, None, description, False, description_ok
    return spec, plans, description, spec_ok, description_ok


def load_manifest(layout: Layout, problems: Problems, renders: int | None = None):
    """[(source, record)] of manifest.jsonl, or None when there is no manifest (or it cannot
    be read: not a regular file, or larger than ``renders`` records can be)."""
    try:
        data = read_manifest(layout, renders)
    except FileNotFoundError:
        problems.add(
            "missing_manifest",
            None,
            MANIFEST_FILE,
            f"{MANIFEST_FILE}: missing (an unfinished build, or deleted); records are "
            "taken from the shard markers and per-sample record files",
        )
        return None
    except OSError as exc:
        problems.add("missing_manifest", None, MANIFEST_FILE, f"{MANIFEST_FILE}: cannot be read ({exc.strerror})")
        return None
    out = []
    for number, raw in enumerate(data.split(b"\n"), start=1):
        if not raw.strip():
            continue
        record = manifest_line_record(raw, number, problems)
        if record is not None:
            out.append((Source(MANIFEST_FILE, number), record))
    return out


def manifest_line_record(raw: bytes, number: int, problems: Problems) -> dict | None:
    """The record on manifest line ``number``, or None with its problem added."""
    too_much = structure_problem(raw)
    if too_much:
        problems.add("edited_record", None, MANIFEST_FILE, f"{MANIFEST_FILE} line {number}: {too_much}")
        return None
    try:
        record = json.loads(raw)
    except RecursionError:
        problems.add(
            "edited_record",
            None,
            MANIFEST_FILE,
            f"{MANIFEST_FILE} line {number}: not a JSON record (nested too deeply)",
        )
        return None
    except ValueError as exc:
        problems.add("edited_record", None, MANIFEST_FILE, f"{MANIFEST_FILE} line {number}: not a JSON record ({exc})")
        return None
    if not isinstance(record, dict) or not isinstance(record.get("id"), str):
        problems.add(
            "edited_record",
            None,
            MANIFEST_FILE,
            f"{MANIFEST_FILE} line {number}: not a record (a JSON object with an id)",
        )
        return None
    why = field_type_problem(record)
    if why:
        problems.add(
            "edited_record", record["id"], MANIFEST_FILE, f"{MANIFEST_FILE} line {number} ({record['id']}): {why}"
        )
        return None
    return record


def load_markers(layout: Layout, shard_ids, known: dict, renders: dict | None = None) -> dict:
    """shard id -> marker (None when missing or torn). A marker's record equal to the one in
    ``known`` (id -> manifest record) is replaced by that object: one copy in memory, not two
    (a record is ~11 kB as Python objects; the paper's dataset has 50,000)."""
    markers = {}
    for sid in shard_ids:
        marker = read_json_in(layout, layout.marker_rel(sid), list_bound((renders or {}).get(sid)))[0]
        if isinstance(marker, dict) and isinstance(marker.get("records"), list):
            marker["records"] = [
                known[r["id"]]
                if isinstance(r, dict) and isinstance(r.get("id"), str) and known.get(r["id"]) == r
                else r
                for r in marker["records"]
            ]
        markers[sid] = marker
    return markers
