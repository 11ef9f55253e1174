"""The checks across a dataset: records against the plan, the files and each other (the
manifest, the shard markers, the per-sample record files), and files that are no part of it."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

from pipeline.check.inspect import FileFacts, expectations, render_value_issues
from pipeline.check.report import Problems, summarise
from pipeline.check.request import dir_refused
from pipeline.check.snapshot import read_snapshot
from pipeline.dataset.plan import PLAN_FORMAT, Plan, plan_dataset
from pipeline.dataset.record import lighting_discrepancies, model_record
from pipeline.dataset.spec import spec_digest
from pipeline.errors import USER_ERRORS, short_repr
from pipeline.image.stats import is_bad
from pipeline.store.folder import (
    description_problem,
    field_type_problem,
    is_empty_folder,
    is_temp_file,
    list_bound,
    read_json_checked,
    read_json_in,
    read_manifest,
    record_file_names,
    shard_ids_on_disk,
    structure_problem,
    symlinks_and_odd_files,
    walk_folder,
)
from pipeline.store.layout import DESCRIPTION_FILE, LOCK_FILE, MANIFEST_FILE, SHARDS_DIR, SPEC_FILE, Layout
from pipeline.store.records import RUN_DEPENDENT_STATS, read_json, without_timings

#: Relative tolerance for recomputed float statistics (same pixels, same float64 sums).
STATS_RTOL = 1e-6
#: Keys of a render's statistics recomputed from its pixels (pipeline.image.stats.render_stats).
PIXEL_STATS = ("min", "max", "mean", "nan", "inf", "negative")
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
        problems.add(
            "spec_snapshot",
            None,
            SPEC_FILE,
            f"{SPEC_FILE}: digest {spec_digest(spec)[:12]} differs from "
            f"{DESCRIPTION_FILE}'s spec_digest {str(description.get('spec_digest'))[:12]}: "
            "the snapshot (or the description) was edited after the build",
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


def _close(a, b, rtol: float = 1e-12, atol: float = 1e-12) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, int) and isinstance(b, int):
        return a == b  # 63-bit seeds: a float comparison would miss a change of 1
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(float(a), float(b), rel_tol=rtol, abs_tol=atol)
    return a == b


def _get(record: dict, dotted: str):
    value = record
    for key in dotted.split("."):
        if not isinstance(value, dict):
            return None
        value = value.get(key)
    return value


def expected_files(sample, spec) -> list[tuple[str, str]]:
    out = [
        ("render", Layout.render_rel(sample.shard_id, sample.sample_id)),
        ("maps", Layout.maps_rel(sample.shard_id, sample.material_id)),
    ]
    if spec is None or spec.storage.texture_maps:
        out.append(("texture", Layout.texture_rel(sample.shard_id, sample.material_id)))
    return out


def _plan_discrepancies(record: dict, sample, state: State) -> list[str]:
    """Fields of ``record`` that must equal the plan (and the spec) but do not."""
    spec = state.spec
    wanted = [
        ("id", sample.sample_id),
        ("material_id", sample.material_id),
        ("material_index", sample.material_index),
        ("light_index", sample.light_index),
        ("shard", sample.shard_id),
        ("seeds.material", sample.material_seed),
        ("seeds.light", sample.light_seed),
        ("seeds.render", sample.render_seed),
        ("lighting.requested.elevation_deg", sample.elevation_deg),
        ("lighting.requested.azimuth_deg", sample.azimuth_deg),
        ("lighting.requested.turbidity", sample.turbidity),
        ("material.kind", sample.kind),
    ]
    if sample.svbrdf_family is not None:
        wanted.append(("material.family", sample.svbrdf_family))
    if sample.svbrdf_file is not None:
        wanted.append(("material.file", sample.svbrdf_file))
    if spec is not None:
        r = spec.render
        wanted += [
            ("render.resolution", r.resolution),
            ("render.spp", r.spp),
            ("render.max_depth", r.max_depth),
            ("render.integrator", r.integrator),
            ("render.sun", spec.lighting.sun),
            # absent for the default model (pipeline.dataset.record.model_record)
            ("render.model", model_record(spec.materials.model).get("model")),
        ]
    if state.variant:
        wanted.append(("render.variant", state.variant))
    out = [
        f"{key} is {_get(record, key)!r}, the plan says {value!r}"
        for key, value in wanted
        if not _close(_get(record, key), value)
    ]
    files = record.get("files")
    got = [(f.get("role"), f.get("path")) for f in files if isinstance(f, dict)] if isinstance(files, list) else None
    expected = expected_files(sample, spec)
    if got != expected:
        out.append(f"files lists {got!r}, the layout says {expected!r}")
    return out + lighting_discrepancies(record)


def _header_discrepancies(record: dict, render: FileFacts | None, maps: FileFacts | None) -> list[str]:
    """Fields of ``record`` that the files' own headers contradict, one message per field."""
    checks = []
    meta = render.meta if render is not None else None
    if meta is not None:
        lighting = record.get("lighting") if isinstance(record.get("lighting"), dict) else {}
        header_lighting = meta.get("lighting") or {}
        effective = header_lighting.get("effective") or {}
        checks += [
            ("render", "id", record.get("id"), meta.get("id")),
            ("render", "material_id", record.get("material_id"), meta.get("material_id")),
            ("render", "effects", record.get("effects"), meta.get("effects")),
            ("render", "lighting.requested", lighting.get("requested"), header_lighting.get("requested")),
            (
                "render",
                "lighting.policy",
                lighting.get("policy"),
                {k: v for k, v in header_lighting.items() if k not in ("requested", "effective")},
            ),
        ]
        checks += [
            ("render", f"lighting.{key}", lighting.get(key), effective.get(key))
            for key in ("elevation_deg", "azimuth_deg", "turbidity")
        ]
    maps_meta = maps.meta if maps is not None else None
    if maps_meta is not None:
        checks += [
            ("maps", "material_id", record.get("material_id"), maps_meta.get("id")),
            ("maps", "material", record.get("material"), maps_meta.get("material")),
        ]
    out = []
    for which, key, mine, theirs in checks:
        for sub in _diff_keys(mine, theirs):
            dotted = key if sub == "(record)" else f"{key}.{sub}"
            out.append(
                f"{dotted} is {short_repr(_get_path(mine, sub), 123)}, the {which} file's header says "
                f"{short_repr(_get_path(theirs, sub), 123)}"
            )
    return out


def _get_path(value, dotted: str):
    return value if dotted == "(record)" else _get(value, dotted)


def _stats_discrepancies(record: dict, render: FileFacts) -> list[str]:
    """The record's statistics against the pixels and the header of its render file."""

    stats = record.get("stats") if isinstance(record.get("stats"), dict) else {}
    out = []
    if render.pixel_stats is not None:
        for key in PIXEL_STATS:
            mine, actual = stats.get(key), render.pixel_stats.get(key)
            if not (
                _close(mine, actual, STATS_RTOL, 0.0) if mine is not None and actual is not None else mine == actual
            ):
                out.append(f"stats.{key} is {mine!r}, the pixels give {actual!r}")
        if stats.get("flagged") is not None and bool(stats.get("flagged")) != is_bad(render.pixel_stats):
            out.append(
                f"stats.flagged is {stats.get('flagged')!r}, but the pixels are "
                f"{'bad' if is_bad(render.pixel_stats) else 'clean'}"
            )
    meta = render.meta
    if meta is not None and "stats" in meta:
        stored = {k: v for k, v in stats.items() if k not in RUN_DEPENDENT_STATS}
        header = meta["stats"] if isinstance(meta["stats"], dict) else {}
        keys = sorted(k for k in set(stored) | set(header) if stored.get(k) != header.get(k))
        keys = [k for k in keys if not any(line.startswith(f"stats.{k} ") for line in out)]
        out += [f"stats.{k} is {stored.get(k)!r}, the render file's header says {header.get(k)!r}" for k in keys]
    return out


def _policy_problems(record: dict, render: FileFacts) -> list[tuple[str, str]]:
    """Bad pixels are allowed only in a render the render policy flagged."""
    stats, pixels = record.get("stats") or {}, render.pixel_stats
    if pixels is None or (isinstance(stats, dict) and stats.get("flagged")):
        return []
    return [
        (kind, f"{text} in a render not flagged by the render policy") for kind, text in render_value_issues(pixels)
    ]


def _diff_keys(a, b, prefix: str = "") -> list[str]:
    """Dotted paths where two JSON values differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _diff_keys(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [prefix.rstrip(".") or "(record)"]


def record_ok(record: dict | None, sample, state: State) -> bool:
    """A record repair may keep: plan, headers, stats and its render file all agree."""
    if not isinstance(record, dict) or field_type_problem(record):
        return False
    entries = {e.get("role"): e for e in record.get("files", []) if isinstance(e, dict)}
    render_entry = entries.get("render")
    if render_entry is None or _plan_discrepancies(record, sample, state):
        return False
    render = state.facts.get(render_entry.get("path"))
    if render is None or not render.content_ok or render.sha256 is None:
        return False
    if (render.size, render.sha256) != (render_entry.get("bytes"), render_entry.get("sha256")):
        return False
    maps = state.facts.get((entries.get("maps") or {}).get("path"))
    maps = maps if maps is not None and maps.content_ok and maps.decoded else None
    return not (
        _header_discrepancies(record, render, maps)
        or _stats_discrepancies(record, render)
        or _policy_problems(record, render)
    )


def _copy_faulty(record, sample, state: State, fast: bool) -> bool:
    """Whether one copy of a record is itself wrong (not merely different from another)."""
    if sample is None or not isinstance(record, dict):
        return True
    if fast:
        return bool(_plan_discrepancies(record, sample, state))
    return not record_ok(record, sample, state)


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
        keys = ", ".join(_diff_keys(mine, copy)[:5])
        if _copy_faulty(copy, sample, state, fast):
            problems.add("edited_record", sid, rel, f"{rel}: record for {sid} differs from {source} at {keys}")
        elif not _copy_faulty(mine, sample, state, fast):
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
        if _copy_faulty(content, sample, state, False) or not _copy_faulty(reference, sample, state, False):
            keys = ", ".join(_diff_keys(content, reference)[:5])
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
        messages = _plan_discrepancies(record, sample, state)
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
            messages += [m for m in _header_discrepancies(record, render, maps) if m.split(" ", 1)[0] not in said]
        if messages:
            problems.add("edited_record", sid, source.path, f"{source} ({sid}): {summarise(messages)}")
        if fast or render is None:
            continue
        stats_messages = _stats_discrepancies(record, render)
        if stats_messages:
            problems.add(
                "stats_mismatch", sid, source.path, f"{source} ({sid}) vs {render.rel}: {summarise(stats_messages)}"
            )
        for kind, message in _policy_problems(record, render):
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
