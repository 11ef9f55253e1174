"""The checks across a dataset: records against the plan, the files and each other (the
manifest, the shard markers, the per-sample record files), and files that are no part of it.
What they read first is pipeline.check.loading; one record's fields against its plan, its
files' headers and its render's pixels, pipeline.check.discrepancies."""

from __future__ import annotations

import os

from pipeline.check.discrepancies import (
    copy_faulty,
    diff_keys,
    expected_files,
    header_discrepancies,
    plan_discrepancies,
    policy_problems,
    stats_discrepancies,
)
from pipeline.check.inspect import FileFacts, expectations
from pipeline.check.loading import ROOT_FILES, Source, State
from pipeline.check.report import Problems, summarise
from pipeline.store.bounded_read import list_bound
from pipeline.store.folder import (
    is_empty_folder,
    is_temp_file,
    read_json_in,
    record_file_names,
    shard_ids_on_disk,
    symlinks_and_odd_files,
    walk_folder,
)
from pipeline.store.layout import LOCK_FILE, MANIFEST_FILE, SHARDS_DIR
from pipeline.store.record_fields import field_type_problem
from pipeline.store.records import without_timings


def _safe_rel(rel) -> bool:
    if not isinstance(rel, str) or not rel or rel.startswith("/") or "\\" in rel:
        return False
    return all(part not in ("", ".", "..") for part in rel.split("/"))


def _file_problems(facts: FileFacts, entry: dict, id_: str, listed_by: str, problems: Problems) -> None:
    rel, recorded = facts.rel, entry.get("bytes")
    if facts.size is None:
        problems.add("missing_file", id_, rel, f"{rel}: missing ({listed_by} lists it for {id_}, {recorded} bytes)")
        return
    if facts.unsafe:
        problems.add("unsafe_path", id_, rel, f"{rel}: {facts.error} ({listed_by} lists it for {id_})")
        return
    if facts.size != recorded:
        how = "truncated" if isinstance(recorded, int) and facts.size < recorded else "grown"
        problems.add(
            "size_mismatch", id_, rel, f"{rel}: {facts.size} bytes, {listed_by} says {recorded}: the file was {how}"
        )
        return
    if facts.sha256 is None:  # not read: fast mode, or reading failed
        if facts.error:
            problems.add("undecodable", id_, rel, f"{rel}: {facts.error}")
        return
    if facts.sha256 != entry.get("sha256"):
        decodes = "it no longer decodes" if facts.error else "it still decodes"
        problems.add(
            "checksum_mismatch",
            id_,
            rel,
            f"{rel}: SHA-256 {facts.sha256[:16]}... differs from {listed_by}'s "
            f"{str(entry.get('sha256'))[:16]}...: the bytes changed ({decodes})",
        )
        return  # content problems of a changed file are a consequence, not news
    if facts.error:
        problems.add("undecodable", id_, rel, f"{rel}: {facts.error}")
        return
    by_kind: dict[str, list[str]] = {}
    for kind, message in facts.issues:
        by_kind.setdefault(kind, []).append(message)
    for kind, messages in by_kind.items():  # one problem per kind and file
        problems.add(kind, id_, rel, f"{rel}: {summarise(messages, 4)}")


def _usable(record) -> bool:
    """A record with an id whose fields have their types (what else is wrong with it, the
    record checks report)."""
    return isinstance(record, dict) and isinstance(record.get("id"), str) and not field_type_problem(record)


def fallback_records(state: State) -> list:
    """Without a manifest: complete markers' records, else each sample's record file."""
    layout, out = state.layout, []
    for sid, marker in state.markers.items():
        if isinstance(marker, dict) and marker.get("complete") and isinstance(marker.get("records"), list):
            out += [(Source(layout.marker_rel(sid)), r) for r in marker["records"] if _usable(r)]
            continue
        try:
            names = record_file_names(layout, sid) or []
        except OSError:
            continue
        for name in names:
            rel = f"{SHARDS_DIR}/{sid}/{name}"
            record = read_json_in(layout, rel)[0]
            if _usable(record):
                out.append((Source(rel), record))
    return out


def check_records_against_plan(records, state: State, problems: Problems, from_manifest: bool) -> dict:
    """sample id -> (source, record) of the first record per id; plan-level problems."""
    primary: dict = {}
    plan_order = {sid: i for i, sid in enumerate(state.planned)}
    last_index = -1
    order_reported = False
    for source, record in records:
        sid = record["id"]
        if sid in primary:
            first = primary[sid][0]
            same = "identical" if record == primary[sid][1] else "different"
            problems.add(
                "duplicate_record",
                sid,
                source.path,
                f"{source}: a second record for {sid} ({same} to the first, at {first})",
            )
            continue
        primary[sid] = (source, record)
        if state.plans is None:
            continue
        if sid not in state.planned:
            problems.add("extra_sample", sid, source.path, f"{source}: record for {sid}, which the plan does not have")
            continue
        if from_manifest and plan_order[sid] < last_index and not order_reported:
            problems.add("edited_record", sid, source.path, f"{source}: record for {sid} is out of plan order")
            order_reported = True
        last_index = max(last_index, plan_order[sid])
    check_missing_samples(state, primary, problems, from_manifest)
    state.manifest = {sid: rec for sid, (src, rec) in primary.items()} if from_manifest else {}
    return primary


def check_missing_samples(state: State, primary: dict, problems: Problems, from_manifest: bool) -> None:
    """Every planned sample of ``state`` without a record in ``primary``."""
    if state.plans is None:
        return
    where = MANIFEST_FILE if from_manifest else "the shard markers or record files"
    for sid, sample in state.planned.items():
        if sid not in primary:
            problems.add(
                "missing_sample",
                sid,
                MANIFEST_FILE if from_manifest else None,
                f"{sid} (shard {sample.shard_id}): planned, but there is no record of it in {where}",
            )


def check_markers(state: State, primary: dict, problems: Problems, have_manifest: bool, fast: bool) -> None:
    """Each planned shard's marker: present, complete, listing its planned samples, and
    holding the same records as the manifest."""
    if state.plans is None:
        return
    layout = state.layout
    for shard in state.plans:
        sid, rel = shard.shard_id, layout.marker_rel(shard.shard_id)
        marker = state.markers.get(sid)
        wanted = [s.sample_id for s in shard.samples]
        if marker is None:
            why = read_json_in(layout, rel, list_bound(len(wanted)))[1]
            why = f"unreadable ({why})" if why and why != "missing" else "missing"
            recorded = sum(1 for s in wanted if s in primary)
            problems.add(
                "incomplete_shard",
                sid,
                rel,
                f"{rel}: {why}; {recorded} of {len(wanted)} samples of shard {sid} have a record",
            )
            continue
        if not isinstance(marker, dict) or not marker.get("complete") or not isinstance(marker.get("records"), list):
            problems.add("incomplete_shard", sid, rel, f"{rel}: does not mark shard {sid} complete")
            continue
        ids = [r.get("id") for r in marker["records"] if isinstance(r, dict)]
        if marker.get("shard") != sid or marker.get("samples") != ids:
            problems.add(
                "edited_record",
                sid,
                rel,
                f"{rel}: its shard ({marker.get('shard')!r}) or sample list disagrees with its records",
            )
        lacking = [s for s in wanted if s not in ids]
        if lacking:
            problems.add(
                "incomplete_shard", sid, rel, f"{rel}: lacks {len(lacking)} planned sample(s): {', '.join(lacking[:5])}"
            )
        strays = [s for s in ids if s not in wanted]
        if strays:
            problems.add(
                "edited_record",
                sid,
                rel,
                f"{rel}: holds record(s) for {', '.join(map(str, strays[:5]))}, not planned in {sid}",
            )
        if have_manifest:
            _compare_copies(
                state,
                primary,
                problems,
                fast,
                rel,
                [r for r in marker["records"] if isinstance(r, dict) and r.get("id") in wanted],
            )


def _compare_copies(state: State, primary: dict, problems: Problems, fast: bool, rel: str, copies: list[dict]) -> None:
    """Copies of records in ``rel`` against the primary ones; a difference is reported on
    the side that is wrong (the primary side's own faults are reported by the record checks)."""
    for copy in copies:
        sid = copy.get("id")
        if not isinstance(sid, str) or sid not in primary or primary[sid][1] is copy or primary[sid][1] == copy:
            continue
        why = field_type_problem(copy)
        if why:
            problems.add("edited_record", sid, rel, f"{rel}: record for {sid}: {why}")
            continue
        if without_timings(primary[sid][1]) == without_timings(copy):
            continue  # two runs of one shard: equal but for the run-dependent render time
        source, mine = primary[sid]
        sample = state.planned.get(sid)
        keys = ", ".join(diff_keys(mine, copy)[:5])
        if copy_faulty(copy, sample, state, fast):
            problems.add("edited_record", sid, rel, f"{rel}: record for {sid} differs from {source} at {keys}")
        elif not copy_faulty(mine, sample, state, fast):
            # Both copies check out (a field no check covers, or a fast check): name both.
            problems.add(
                "edited_record",
                sid,
                source.path,
                f"{source} and {rel} hold different records for {sid}, at {keys}"
                + ("; the full check tells which is right" if fast else ""),
            )


def check_record_files(state: State, primary: dict, problems: Problems) -> None:
    """Per-sample record files (what a resumed build trusts) must match the shard's record."""
    if state.plans is None:
        return
    layout = state.layout
    for sid, sample in state.planned.items():
        rel = layout.record_rel(sample.shard_id, sid)
        path = layout.path(rel)
        if not os.path.lexists(path):
            state.record_files[sid] = None
            continue
        content = read_json_in(layout, rel)[0]
        reference = marker_record(state, sample) or (primary.get(sid) or (None, None))[1]
        state.record_files[sid] = reference if content == reference else content  # one copy
        if reference is None or content == reference:
            continue
        if (
            isinstance(content, dict)
            and isinstance(reference, dict)
            and not field_type_problem(content)
            and without_timings(content) == without_timings(reference)
        ):
            continue  # two runs of one shard: equal but for the run-dependent render time
        if not isinstance(content, dict):
            problems.add("edited_record", sid, rel, f"{rel}: not a JSON record (torn or edited)")
            continue
        why = field_type_problem(content)
        if why:
            problems.add("edited_record", sid, rel, f"{rel}: {why}")
            continue
        if copy_faulty(content, sample, state, False) or not copy_faulty(reference, sample, state, False):
            keys = ", ".join(diff_keys(content, reference)[:5])
            problems.add("edited_record", sid, rel, f"{rel}: differs from the shard's record of {sid} at {keys}")


def marker_record(state: State, sample) -> dict | None:
    marker = state.markers.get(sample.shard_id)
    if not isinstance(marker, dict) or not isinstance(marker.get("records"), list):
        return None
    for record in marker["records"]:
        if isinstance(record, dict) and record.get("id") == sample.sample_id:
            return None if field_type_problem(record) else record  # reported by check_markers
    return None


def referenced_files(primary: dict, state: State) -> dict:
    """rel path -> (first id, entry, listed_by, expectation) of every file a record lists."""
    files: dict = {}
    for sid, (source, record) in primary.items():
        entries = record.get("files")
        if not isinstance(entries, list):
            continue
        sample = state.planned.get(sid)
        expect = expectations(state.spec, sample.kind if sample else None, sample.svbrdf_family if sample else None)
        for entry in entries:
            if not isinstance(entry, dict) or entry.get("role") not in expect:
                continue
            rel = entry.get("path")
            if not _safe_rel(rel) or rel in files:
                continue
            owner = sid if entry["role"] == "render" else record.get("material_id", sid)
            files[rel] = (owner, entry, source.path, expect[entry["role"]])
    return files


def _trusted(facts: FileFacts | None, files: dict) -> bool:
    """Read, decoded, and the bytes its (first) record describes."""
    return (
        facts is not None
        and facts.decoded
        and facts.sha256 is not None
        and facts.sha256 == files.get(facts.rel, (None, {}))[1].get("sha256")
    )


def check_files_and_records(primary: dict, files: dict, state: State, problems: Problems, fast: bool) -> None:
    """File problems (once per file) and each record's agreement with plan, headers, stats."""
    check_files(files, state, problems)
    check_records(primary, files, state, problems, fast)


def check_files(files: dict, state: State, problems: Problems) -> None:
    """Each file's problems, once per file, against its first record."""
    for rel, (owner, entry, listed_by, _expect) in files.items():
        _file_problems(state.facts[rel], entry, owner, listed_by, problems)


def check_records(primary: dict, files: dict, state: State, problems: Problems, fast: bool) -> None:
    """Each record's agreement with its plan, its files' headers and its render's statistics."""
    for sid, (source, record) in primary.items():
        sample = state.planned.get(sid)
        if sample is None:
            continue
        entries = (
            {e.get("role"): e for e in record.get("files", []) if isinstance(e, dict)}
            if isinstance(record.get("files"), list)
            else {}
        )
        messages = plan_discrepancies(record, sample, state)
        for role, entry in entries.items():
            rel = entry.get("path")
            if not _safe_rel(rel):
                messages.append(f"files[{role}].path {rel!r} is not a path inside the dataset")
                continue
            first = files.get(rel)
            if (
                first is not None
                and first[1] is not entry
                and (first[1].get("bytes"), first[1].get("sha256")) != (entry.get("bytes"), entry.get("sha256"))
            ):
                messages.append(f"files[{role}] of {rel} has size/SHA-256 different from {first[0]}'s record")
        render = state.facts.get((entries.get("render") or {}).get("path"))
        maps = state.facts.get((entries.get("maps") or {}).get("path"))
        render = render if _trusted(render, files) else None
        maps = maps if _trusted(maps, files) else None
        if not fast:
            said = {m.split(" ", 1)[0] for m in messages}
            messages += [m for m in header_discrepancies(record, render, maps) if m.split(" ", 1)[0] not in said]
        if messages:
            problems.add("edited_record", sid, source.path, f"{source} ({sid}): {summarise(messages)}")
        if fast or render is None:
            continue
        stats_messages = stats_discrepancies(record, render)
        if stats_messages:
            problems.add(
                "stats_mismatch", sid, source.path, f"{source} ({sid}) vs {render.rel}: {summarise(stats_messages)}"
            )
        for kind, message in policy_problems(record, render):
            problems.add(kind, sid, render.rel, f"{render.rel}: {message}")


def _allowed_files(state: State, primary: dict) -> tuple[set, set]:
    """(files, directories) that belong to the dataset, relative to DIR."""
    layout = state.layout
    files, dirs = {*ROOT_FILES, LOCK_FILE}, {SHARDS_DIR}  # the lock: while a writer runs, or a killed one's
    if state.plans is not None:
        for shard in state.plans:
            dirs.add(f"{SHARDS_DIR}/{shard.shard_id}")
            files.add(layout.marker_rel(shard.shard_id))
            for sample in shard.samples:
                files.add(layout.record_rel(shard.shard_id, sample.sample_id))
                files.update(rel for _role, rel in expected_files(sample, state.spec))
        return files, dirs
    for sid in shard_ids_on_disk(layout):
        dirs.add(f"{SHARDS_DIR}/{sid}")
        files.add(layout.marker_rel(sid))
        try:
            names = record_file_names(layout, sid) or []
        except OSError:
            names = []
        files.update(f"{SHARDS_DIR}/{sid}/{n}" for n in names)
    for _source, record in primary.values():
        for entry in record.get("files") or []:
            if isinstance(entry, dict) and _safe_rel(entry.get("path")):
                files.add(entry["path"])
    return files, dirs


def check_extra_files(
    state: State, primary: dict, problems: Problems, allowed: tuple | None = None, unsafe_listed=None
) -> None:
    """Every entry of the folder that is no part of the dataset. ``allowed``: (files,
    directories) that belong to it, anything ``in`` can ask (default: the sets of
    :func:`_allowed_files`); ``unsafe_listed``: unsafe files a record lists, reported with its
    id (default: from ``state.facts``)."""
    files, dirs = allowed if allowed is not None else _allowed_files(state, primary)
    state.allowed_dirs = dirs
    root = state.layout.root
    odd = dict(symlinks_and_odd_files(root))
    for rel, what in odd.items():
        facts = state.facts.get(rel)
        if (rel in unsafe_listed) if unsafe_listed is not None else (facts is not None and facts.unsafe):
            continue  # a file a record lists: reported with the record's id
        state.extra_files.append(rel)
        problems.add(
            "unsafe_path",
            None,
            rel,
            f"{rel}: {what}; a dataset folder holds only regular files and folders: not followed, not read",
        )
    for rel_dir, subdirs, names in walk_folder(root, skip=odd):  # links: never entered
        for name in subdirs:
            rel = rel_dir + name
            if rel not in dirs and is_empty_folder(root, rel):
                state.extra_files.append(rel)
                problems.add("extra_file", None, rel, f"{rel}/: an empty directory that is no part of the dataset")
        for name in names:
            rel = rel_dir + name
            if rel in files:
                continue
            why = (
                "a temporary file left by an interrupted write"
                if is_temp_file(name)
                else "no part of the dataset: no planned record or marker refers to it"
            )
            state.extra_files.append(rel)
            problems.add("extra_file", None, rel, f"{rel}: {why}")


def render_present(record: dict, state: State) -> bool:
    for entry in record.get("files") or []:
        if isinstance(entry, dict) and entry.get("role") == "render":
            facts = state.facts.get(entry.get("path"))
            return facts is not None and facts.size is not None
    return False
