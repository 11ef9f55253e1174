"""`shaderball validate --repair`: :func:`repair` fixes what :func:`pipeline.check.validate.validate`
finds. Its steps: settle which record each sample keeps, delete what is bad, and resume the
build for the shards this touches. A writer, so it lives with the build, above the checks.

A dataset whose mesh files or environment maps (dataset.json's ``sources``) are missing or
changed is refused before anything is written (:func:`changed_sources`): its samples would be
re-rendered from other files, a dataset of two scenes."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from typing import NamedTuple

import tomllib

from pipeline.check.crosscheck import marker_record
from pipeline.check.discrepancies import expected_files, record_ok
from pipeline.check.inspect import expectations, inspect_file
from pipeline.check.loading import State, check_root
from pipeline.check.report import Progress, RepairAction, Report
from pipeline.check.request import ValidateRequest
from pipeline.check.snapshot import read_snapshot
from pipeline.check.validate import validate
from pipeline.dataset.spec_file import parse_spec, source_files, spec_digest, spec_to_toml
from pipeline.errors import USER_ERRORS, SetupError, ShaderballError, filesystem_error, quoted
from pipeline.render.mitsuba_env import BYTE_IDENTICAL, determinism, resolve_variant
from pipeline.run.build import build, write_manifest
from pipeline.run.cluster.options import ClusterOptions
from pipeline.run.out_folder import recorded_guarantee
from pipeline.store.atomic import sha256_file, write_text_atomic
from pipeline.store.folder import read_spec_snapshot
from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, SPEC_FILE, Layout
from pipeline.store.lock import writer_lock
from pipeline.store.records import dumps, read_json


def restore_spec(state: State, spec_path: str) -> RepairAction:
    """Write ``spec_path`` as the snapshot, if it is the spec dataset.json says was built."""

    description = read_json(state.layout.description)
    recorded = description.get("spec_digest") if isinstance(description, dict) else None
    if not recorded:
        raise ValidateRequest.field_error(
            "spec",
            spec_path,
            "a dataset whose dataset.json records its spec's digest",
            what=f"cannot be checked: {DESCRIPTION_FILE} of {quoted(state.layout.root)} is missing or has no "
            "spec_digest, so no spec can be confirmed as the one it was built from",
        )
    spec = parse_spec(spec_path)
    if spec_digest(spec) != recorded:
        raise ValidateRequest.field_error(
            "spec",
            spec_path,
            "the spec this dataset was built from",
            what=f"{quoted(spec_path)} has digest {spec_digest(spec)[:12]}, "
            f"{DESCRIPTION_FILE} says the dataset was built from {recorded[:12]}: not this dataset's spec",
        )
    write_text_atomic(state.layout.spec, spec_to_toml(spec))
    return RepairAction(
        "restore_spec",
        SPEC_FILE,
        f"{SPEC_FILE}: restored from {spec_path} (digest {recorded[:12]} matches {DESCRIPTION_FILE})",
    )


#: The spec keys that name files, as a refusal names them.
SOURCE_KEYS = (("scene", "objects"), ("lighting", "environments"))


def changed_sources(layout: Layout) -> list[str]:
    """The mesh files and environment maps the dataset was built from (dataset.json's
    ``sources``: path -> SHA-256) that are missing or changed now, and those the spec names
    that it was not built from: one phrase each, naming the file and the spec key naming it.
    Empty where the snapshot's digest is dataset.json's (its files are digested in it), where
    dataset.json records no file, or cannot be read (validate reports that)."""
    description = read_json(layout.description)
    recorded = description.get("sources") if isinstance(description, dict) else None
    if not isinstance(recorded, dict) or not recorded:
        return []
    try:
        spec = read_snapshot(layout.root)
        if spec_digest(spec) == description.get("spec_digest"):
            return []
    except (*USER_ERRORS, OSError):  # a named file gone makes the snapshot unreadable
        spec = None
    keys = _source_keys(layout)
    out = []
    for path, digest in sorted(recorded.items()):
        if not isinstance(path, str) or not isinstance(digest, str):
            continue  # validate names a malformed dataset.json
        where = f"{quoted(path)} ({_naming_key(keys, path)})"
        if not os.path.isfile(path):
            out.append(f"{where} is missing (SHA-256 {digest[:12]} when built)")
            continue
        try:
            now = sha256_file(path)
        except OSError as exc:
            out.append(f"{where} cannot be read ({exc.strerror})")
            continue
        if now != digest:
            out.append(f"{where} changed (SHA-256 {digest[:12]} when built, {now[:12]} now)")
    if spec is not None:
        new = sorted(set(source_files(spec)) - set(recorded))
        out += [f"{quoted(path)} ({_naming_key(keys, path)}) is new: the dataset was not built with it" for path in new]
    return out


def _source_keys(layout: Layout) -> dict[str, list]:
    """``section.key`` -> the paths the snapshot lists under it (read as TOML only: a snapshot
    naming a missing file does not parse as a spec); empty where it cannot be read."""
    try:
        table = tomllib.loads(read_spec_snapshot(layout).decode("utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return {}
    out = {}
    for section, key in SOURCE_KEYS:
        items = table.get(section, {}).get(key, []) if isinstance(table.get(section), dict) else []
        out[f"{section}.{key}"] = (
            [os.path.normpath(i) for i in items if isinstance(i, str)] if isinstance(items, list) else []
        )
    return out


def _naming_key(keys: dict[str, list], path: str) -> str:
    """The spec key naming ``path``: listing it, or the folder it lies in."""
    for key, items in keys.items():
        if path in items or os.path.dirname(path) in items:
            return key
    return "named by the spec"


def refuse_changed_sources(layout: Layout) -> None:
    """ShaderballError (exit code 2) naming each mesh file or map that is missing or changed
    since the build (:func:`changed_sources`); nothing is written."""
    changed = changed_sources(layout)
    if changed:
        raise ShaderballError(
            f"{quoted(layout.root)}: not repaired: the files the spec names are not those the dataset was built "
            "from: " + "; ".join(changed) + ". Repairing would render its samples from other files and mix two "
            f"scenes in one dataset; nothing was written. Put each file back as it was ({DESCRIPTION_FILE}'s "
            "sources give its SHA-256), or build the spec into a new folder"
        )


def remove_file(path: str) -> bool:
    try:
        os.remove(path)
        return True
    except FileNotFoundError:
        return False


def delete_extra_files(state: State, actions: list) -> None:
    """Delete extra files, then the directories they leave empty (unless the layout's)."""
    root = state.layout.root
    for rel in state.extra_files:
        path = state.layout.path(rel)
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
        else:
            remove_file(path)
        actions.append(RepairAction("delete_extra", rel, f"{rel}: deleted (no part of the dataset)"))
    for rel in state.extra_files:
        parent = os.path.dirname(rel)
        while parent and parent not in state.allowed_dirs:
            try:
                os.rmdir(os.path.join(root, *parent.split("/")))
            except OSError:
                break  # not empty, or gone
            parent = os.path.dirname(parent)


def inspect_unlisted(state: State) -> None:
    """Read the planned files no manifest record listed (a torn or lost manifest line), so
    the marker's or record file's copy can be judged."""
    for sample in state.planned.values():
        expect = expectations(state.spec, sample.kind, sample.svbrdf_family)
        for role, rel in expected_files(sample, state.spec):
            if rel not in state.facts:
                state.facts[rel] = inspect_file(state.layout.root, rel, expect[role], None, False)


def _candidates(state: State, sample) -> list[dict]:
    """The copies of a sample's record, the marker's first (the manifest is made from it)."""
    out = []
    for record in (
        marker_record(state, sample),
        state.record_files.get(sample.sample_id),
        state.manifest.get(sample.sample_id),
    ):
        if isinstance(record, dict) and record not in out:
            out.append(record)
    return out


def chosen_record(state: State, sample) -> dict | None:
    """The record repair keeps for ``sample``: the first copy that checks out, preferring one
    whose material entries match intact material files."""
    good = [r for r in _candidates(state, sample) if record_ok(r, sample, state)]

    def material_match(record):
        for entry in record.get("files", [])[1:]:
            facts = state.facts.get(entry.get("path"))
            if (
                facts is not None
                and facts.content_ok
                and facts.sha256 is not None
                and (facts.size, facts.sha256) != (entry.get("bytes"), entry.get("sha256"))
            ):
                return False
        return True

    preferred = [r for r in good if material_match(r)]
    return (preferred or good or [None])[0]


def settle_samples(state: State, chosen: dict, actions: list) -> set:
    """Delete renders without a good record, and material files that are bad; return the
    shards this touches."""
    layout, affected = state.layout, set()
    for sid, sample in state.planned.items():
        if chosen[sid] is not None:
            continue
        affected.add(sample.shard_id)
        rel = layout.render_rel(sample.shard_id, sid)
        remove_file(layout.path(rel))
        remove_file(layout.path(layout.record_rel(sample.shard_id, sid)))
        state.record_files[sid] = None
        actions.append(RepairAction("rerender", rel, f"{rel}: no intact copy of its record and file; re-rendered"))
    for shard in state.plans:
        for material in shard.materials:
            kept = [chosen[s.sample_id] for s in material.samples]
            for role, rel in expected_files(material.samples[0], state.spec)[1:]:
                facts = state.facts.get(rel)
                entries = {
                    (e.get("bytes"), e.get("sha256"))
                    for r in kept
                    if r
                    for e in r.get("files", [])
                    if isinstance(e, dict) and e.get("path") == rel
                }
                if (
                    facts is not None
                    and facts.content_ok
                    and facts.sha256 is not None
                    and (facts.size, facts.sha256) in entries
                ):
                    continue
                affected.add(shard.shard_id)
                remove_file(layout.path(rel))
                actions.append(RepairAction("regenerate", rel, f"{rel}: bad or missing {role} file; regenerated"))
    return affected


def write_good_record_files(state: State, chosen: dict, affected: set, actions: list) -> None:
    """Record files must say what the kept records say: a resumed build trusts a record file
    whose files verify, whatever else it says. Missing ones are written in affected shards."""

    layout = state.layout
    for sid, sample in state.planned.items():
        good, current = chosen[sid], state.record_files.get(sid)
        if good is None or current == good or (current is None and sample.shard_id not in affected):
            continue
        rel = layout.record_rel(sample.shard_id, sid)
        write_text_atomic(layout.path(rel), dumps(good) + "\n")
        actions.append(RepairAction("rewrite_record", rel, f"{rel}: rewritten from the intact copy"))


def recorded_variant(state: State) -> str | None:
    """The Mitsuba variant the dataset was rendered with: dataset.json's, else the one every
    record copy names (a lost dataset.json); None when neither says."""
    if state.variant:
        return state.variant
    named = {
        r.get("render", {}).get("variant")
        for sample in state.planned.values()
        for r in _candidates(state, sample)
        if isinstance(r.get("render"), dict)
    }
    named.discard(None)
    return named.pop() if len(named) == 1 else None


def repair_variant(state: State) -> str | None:
    """The variant a repair renders with: the recorded one, resolved (not what the spec's
    ``auto`` would pick on this machine, which may be another backend); SetupError, saying
    where the repair can run, when it cannot be used here."""
    recorded = recorded_variant(state)
    if recorded is None:
        return None
    try:
        return resolve_variant(recorded)
    except SetupError as exc:
        raise SetupError(
            f"{DESCRIPTION_FILE}: the dataset was rendered with Mitsuba variant {recorded}, which "
            f"cannot be used here ({exc}); a repair re-renders with the dataset's own variant, "
            "so run it on a machine where that variant works; nothing was changed"
        ) from None


def lost_render_digests(state: State, chosen: dict) -> dict[str, set]:
    """For every sample that will be re-rendered, the SHA-256 its record copies gave its render."""
    lost = {}
    for sid, sample in state.planned.items():
        if chosen[sid] is None:
            lost[sid] = {
                e.get("sha256")
                for r in _candidates(state, sample)
                for e in r.get("files", [])
                if isinstance(e, dict) and e.get("role") == "render"
            }
    return lost


def describe_rerenders(state: State, lost: dict[str, set], actions: list) -> list:
    """The ``rerender`` actions, each told what its new render is against the lost copy.

    Under the byte-identical guarantee the new render has the recorded bytes (else the
    message says so: the lost copy was not what this dataset renders). Under within-noise
    (docs/manifest.md) a new render with other bytes is the expected outcome, not a
    corruption: its record, the shard's marker and the manifest all list the new file.
    """
    guarantee = recorded_guarantee(state.layout.root) or determinism(state.variant or "")
    out = []
    for action in actions:
        sid = os.path.basename(action.path or "").removesuffix(".render.exr")
        if action.action != "rerender" or sid not in lost:
            out.append(action)
            continue
        record = read_json(state.layout.path(state.layout.record_rel(state.planned[sid].shard_id, sid)))
        digest = next((e.get("sha256") for e in (record or {}).get("files", []) if e.get("role") == "render"), None)
        if digest is None:
            note = "not re-rendered (the build did not finish it)"
        elif not lost[sid]:
            note = "no copy of its record said what the lost file held"
        elif digest in lost[sid]:
            note = "byte-identical to the lost copy"
        elif guarantee == BYTE_IDENTICAL:
            note = (
                "its bytes differ from the lost copy's recorded SHA-256 although this dataset's re-renders "
                "are byte-identical: the lost copy was not this installation's render"
            )
        else:
            note = (
                f"a new render, not the lost copy's bytes ({guarantee} dataset: equal within noise); "
                "its record, the shard marker and the manifest list the new file"
            )
        out.append(RepairAction(action.action, action.path, f"{action.message}: {note}"))
    return out


def rebuild(root: str, workers: int, progress, n_shards: int, variant: str | None = None) -> None:
    """Resume the build with ``variant`` (the dataset's): the shards without a marker are
    rebuilt, the manifest rewritten."""

    def forward(p):
        if progress is not None:
            progress(Progress("repair", p.done, p.total, f"{n_shards} shard(s)", 0, p.elapsed_s))

    build(Layout(root).spec, root, cluster=ClusterOptions(workers=workers), progress=forward, variant=variant)


class Repaired(NamedTuple):
    """What a repair did: the report before, the report after, the actions between."""

    before: Report
    after: Report
    actions: list[RepairAction]

    @property
    def exit_code(self) -> int:
        return self.after.exit_code

    def to_dict(self) -> dict:
        done = {"before": self.before.to_dict(), "actions": [a.to_dict() for a in self.actions]}
        return {**self.after.to_dict(), "repair": done}

    def lines(self) -> list[str]:
        head = f"before repair: {len(self.before.problems)} problem(s); {len(self.actions)} action(s)"
        return [head, *(f"  {a.action}: {a.message}" for a in self.actions), *self.after.lines()]


def validate_or_repair(request: ValidateRequest, *, progress: Callable[[Progress], None] | None = None):
    """`shaderball validate`: the :class:`Report` of ``request.directory``, or with
    ``request.repair`` what the repair did (:class:`Repaired`); exit code 1 where the dataset
    is (still) not valid."""
    if not request.repair:
        return validate(request.directory, fast=request.fast, progress=progress)
    return repair(request.directory, workers=request.workers, progress=progress, spec_path=request.spec)


def repair(
    root: str, *, workers: int = 0, progress: Callable[[Progress], None] | None = None, spec_path: str | None = None
) -> Repaired:
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
) -> Repaired:
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
    refuse_changed_sources(Layout(root))
    before = validate(root, progress=progress, keep_state=True)
    if before.ok:
        return Repaired(before, before, [])
    state, actions = before._state, []
    if (state.plans is None or not state.spec_ok) and spec_path is not None:
        actions.append(restore_spec(state, spec_path))
        current = validate(root, progress=progress, keep_state=True)
        if current.ok:
            return Repaired(before, current, actions)
        state = current._state
    if state.plans is None or not state.spec_ok:
        return Repaired(before, before, actions + [unrepairable_spec()])
    variant = repair_variant(state)  # the dataset's own, or SetupError before anything changes
    affected, lost = settle_files(state, actions)
    actions = resume_build(root, state, affected, lost, actions, workers=workers, progress=progress, variant=variant)
    after = validate(root, progress=progress)
    return Repaired(before, after, actions)


def unrepairable_spec() -> RepairAction:
    """What a repair says when the spec snapshot is unusable and no ``--spec`` can restore it."""
    return RepairAction(
        "unrepairable",
        SPEC_FILE,
        f"{SPEC_FILE}: the spec snapshot is unusable or does not match {DESCRIPTION_FILE}; "
        "give the spec the dataset was built from (--spec) to restore it; nothing was changed",
    )


def settle_files(state: State, actions: list) -> tuple[set, dict[str, set]]:
    """Delete what is extra or bad, write the kept records and remove the markers of the shards
    this touches; (those shards, the SHA-256 the record copies gave each render to redo)."""
    delete_extra_files(state, actions)
    inspect_unlisted(state)
    chosen = {sid: chosen_record(state, sample) for sid, sample in state.planned.items()}
    lost = lost_render_digests(state, chosen)
    affected = settle_samples(state, chosen, actions)
    affected |= stale_shards(state, chosen)
    write_good_record_files(state, chosen, affected, actions)
    for sid in sorted(affected):
        remove_file(state.layout.marker(sid))
        actions.append(
            RepairAction(
                "rerun_shard",
                state.layout.marker_rel(sid),
                f"shard {sid}: marker removed; rebuilt from its verified records",
            )
        )
    return affected, lost


def stale_shards(state: State, chosen: dict) -> set:
    """The shards whose marker is not the complete one of their plan and kept records: the
    manifest is made from markers, so these are rebuilt."""
    stale = set()
    for shard in state.plans:
        marker = state.markers.get(shard.shard_id)
        if not (
            isinstance(marker, dict)
            and marker.get("complete")
            and marker.get("samples") == [s.sample_id for s in shard.samples]
            and all(marker_record(state, s) == chosen[s.sample_id] for s in shard.samples)
        ):
            stale.add(shard.shard_id)
    return stale


def resume_build(
    root: str,
    state: State,
    affected: set,
    lost: dict[str, set],
    actions: list,
    *,
    workers: int,
    progress: Callable[[Progress], None] | None,
    variant: str | None,
) -> list[RepairAction]:
    """Rebuild the ``affected`` shards (and dataset.json when bad) with the resumable build, or
    only rewrite a dirty manifest; ``actions`` with what that did."""
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
        write_manifest(state.layout.root, state.plans)
        actions.append(
            RepairAction("rewrite_manifest", MANIFEST_FILE, f"{MANIFEST_FILE}: rewritten from the shard markers")
        )
    return actions
