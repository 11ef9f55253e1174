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
the resumable build, which re-renders only samples whose record does not verify; renders are
deterministic, so a repaired file is byte-identical to the original), rewrites the manifest
from the shard markers and validates again.

Library code: nothing here prints; progress goes to a callback.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from pipeline.dataset.plan import iter_samples, plan_dataset
from pipeline.dataset.spec import parse_spec, spec_digest, spec_to_toml
from pipeline.errors import USER_ERRORS, ShaderballError, short_repr
from pipeline.render.stats import is_bad, render_stats
from pipeline.run.build import build, write_manifest
from pipeline.store.atomic import write_text_atomic
from pipeline.store.exr import read_exr
from pipeline.store.folder import is_temp_file, read_manifest, record_file_names, shard_ids_on_disk
from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, SHARDS_DIR, SPEC_FILE, Layout
from pipeline.store.records import RUN_DEPENDENT_STATS, dumps, read_json, without_timings
from sky import Light

#: Every problem kind, with what it means (docs/validate.md gives an example message for each).
PROBLEM_KINDS: dict[str, str] = {
    "missing_file": "a file a record lists does not exist",
    "size_mismatch": "a file's size differs from its record (truncated, or appended to)",
    "checksum_mismatch": "a file's SHA-256 differs from its record (its bytes changed)",
    "undecodable": "a file cannot be read or is not a readable EXR",
    "bad_layers": "an EXR lacks a layer or has an extra one, or a layer has the wrong "
                  "channels, size or sample type",
    "non_finite": "NaN or infinite values in maps, or in a render that is not flagged",
    "out_of_range": "map values outside [0, 1], a mask other than 0/1, maps non-zero outside the mask",
    "normal_not_unit": "normals whose length differs from 1 by more than the half-float tolerance",
    "negative_render": "negative values in a render that is not flagged",
    "stats_mismatch": "a record's render statistics differ from the file's pixels or header",
    "missing_sample": "a planned render has no record",
    "extra_sample": "a record for a render the plan does not have",
    "duplicate_record": "a second record for the same render",
    "edited_record": "a record disagrees with the plan, with its files' headers or with the "
                     "shard marker's copy",
    "extra_file": "a file under DIR that is no part of the dataset",
    "spec_snapshot": "spec.toml unreadable, or its digest differs from dataset.json's",
    "missing_manifest": "no manifest.jsonl (an unfinished build); records come from the shards",
    "incomplete_shard": "a shard without a complete marker, or a marker missing samples",
}

#: Largest |length - 1| of a stored normal: half floats carry 11 significant bits, so a unit
#: vector rounded per component is off by up to ~1e-3 in length; measured here: <= 2.5e-4.
NORMAL_TOLERANCE = 2e-3
#: Relative tolerance for recomputed float statistics (same pixels, same float64 sums).
STATS_RTOL = 1e-6
#: Keys of a render's statistics recomputed from its pixels (pipeline.render.stats.render_stats).
PIXEL_STATS = ("min", "max", "mean", "nan", "inf", "negative")
#: Layers of the texture-space maps file.
TEXTURE_LAYERS = ("diffuse", "specular", "roughness", "normal")
#: Channels of each map layer (pipeline.store.exr naming).
MAP_CHANNELS = {"diffuse": 3, "specular": 3, "roughness": 1, "normal": 3, "mask": 1}
#: Layers stored as half floats when ``storage.maps_half`` (the mask is always float32).
HALF_LAYERS = ("diffuse", "specular", "roughness", "normal")
#: Files at the top of DIR that belong to the dataset.
ROOT_FILES = (SPEC_FILE, DESCRIPTION_FILE, MANIFEST_FILE)


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class Problem:
    """One thing wrong. ``id``: the sample, material or shard it concerns (None for the
    dataset as a whole); ``path``: the file, relative to DIR with forward slashes."""

    kind: str
    id: str | None
    path: str | None
    message: str

    def to_dict(self) -> dict:
        return {"kind": self.kind, "id": self.id, "path": self.path, "message": self.message}


@dataclass(frozen=True)
class Progress:
    """What a progress callback receives: once per file checked, once per repair step."""

    stage: str  # "check" or "repair"
    done: int
    total: int
    path: str
    bytes_read: int
    elapsed_s: float


@dataclass(frozen=True)
class RepairAction:
    action: str  # delete_extra, regenerate, rerender, rewrite_record, rerun_shard, ...
    path: str | None
    message: str

    def to_dict(self) -> dict:
        return {"action": self.action, "path": self.path, "message": self.message}


@dataclass
class Report:
    """The result of :func:`validate`. Counts are of renders (planned samples)."""

    root: str
    fast: bool
    expected: int
    present: int
    valid: int
    problems: list[Problem]
    flagged: int = 0
    files_checked: int = 0
    bytes_read: int = 0
    seconds: float = 0.0
    # What repair() needs; not part of the JSON report.
    _state: _State | None = field(default=None, repr=False, compare=False)

    @property
    def ok(self) -> bool:
        return not self.problems

    def counts(self) -> dict[str, int]:
        return dict(Counter(p.kind for p in self.problems))

    def to_dict(self) -> dict:
        return {
            "root": self.root,
            "mode": "fast" if self.fast else "full",
            "ok": self.ok,
            "expected": self.expected,
            "present": self.present,
            "valid": self.valid,
            "flagged": self.flagged,
            "files_checked": self.files_checked,
            "bytes_read": self.bytes_read,
            "seconds": round(self.seconds, 3),
            "problem_counts": self.counts(),
            "problems": [p.to_dict() for p in self.problems],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=False)

    def lines(self, limit: int = 50) -> list[str]:
        """A human summary: a head line, one line per problem (at most ``limit``), a tally."""
        mode = "fast check (sizes and markers)" if self.fast else "full check"
        head = (f"{self.root}: {self.expected} renders expected, {self.present} present, "
                f"{self.valid} valid; {mode} of {self.files_checked} files, "
                f"{self.bytes_read / 1e6:.1f} MB read, {self.seconds:.1f} s")
        if self.ok:
            return [head, "valid: no problems found"]
        out = [head] + [f"{p.kind}: {p.message}" for p in self.problems[:limit]]
        if len(self.problems) > limit:
            out.append(f"... and {len(self.problems) - limit} more")
        tally = ", ".join(f"{kind} {n}" for kind, n in self.counts().items())
        out.append(f"INVALID: {len(self.problems)} problem(s): {tally}")
        return out


# --------------------------------------------------------------------------- the dataset


@dataclass
class _Source:
    """Where a record was read: 'manifest.jsonl line 3' or a marker or record file."""

    path: str
    line: int | None = None

    def __str__(self) -> str:
        return f"{self.path} line {self.line}" if self.line else self.path


@dataclass
class _FileFacts:
    """What one read of a file showed. ``sha256`` is None when not read (fast, missing)."""

    rel: str
    size: int | None
    sha256: str | None = None
    error: str | None = None
    layers: dict[str, tuple[tuple[int, ...], str]] | None = None
    meta_json: str | None = None  # the header's metadata, kept as text: ~4x smaller than dicts
    issues: list[tuple[str, str]] = field(default_factory=list)
    pixel_stats: dict | None = None

    @property
    def meta(self) -> dict | None:
        if self.meta_json is None:
            return None
        meta = json.loads(self.meta_json)
        return meta if isinstance(meta, dict) else {}

    @property
    def decoded(self) -> bool:
        return self.layers is not None

    @property
    def content_ok(self) -> bool:
        return self.size is not None and self.error is None and not self.issues


@dataclass(frozen=True)
class _Expect:
    role: str
    layers: dict[str, tuple[int, str]] | None  # name -> (channels, dtype name); None: any
    shape: tuple[int, int] | None


@dataclass
class _State:
    """Everything validate learned, kept for repair."""

    layout: Layout
    spec: object | None
    plans: list | None
    planned: dict  # sample id -> SamplePlan, plan order
    variant: str | None
    spec_ok: bool
    description_ok: bool
    manifest: dict  # sample id -> first manifest record
    markers: dict  # shard id -> marker dict or None
    record_files: dict  # sample id -> record file content or None
    facts: dict  # rel path -> _FileFacts
    extra_files: list[str]
    allowed_dirs: set
    manifest_dirty: bool


class _Problems(list):
    def add(self, kind: str, id_: str | None, path: str | None, message: str) -> None:
        self.append(Problem(kind, id_, path, message))


def _check_root(root: str) -> Layout:
    if not os.path.exists(root):
        raise ShaderballError(f"DIR: {root!r} does not exist; give a dataset directory "
                              "written by `shaderball build`")
    if not os.path.isdir(root):
        raise ShaderballError(f"DIR: {root!r} is not a directory; give a dataset directory "
                              "written by `shaderball build`")
    layout = Layout(root)
    if not any(os.path.exists(os.path.join(root, name)) for name in ROOT_FILES):
        raise ShaderballError(f"DIR: {root!r} is not a shaderball dataset: it holds none of "
                              f"{', '.join(ROOT_FILES)}")
    return layout


def _load_plan(layout: Layout, problems: _Problems):
    """(spec, plans, description, spec_ok, description_ok); spec and plans None if unusable."""

    description = read_json(layout.description)
    description_ok = isinstance(description, dict)
    if not description_ok:
        what = "missing" if not os.path.exists(layout.description) else "not a JSON object"
        problems.add("spec_snapshot", None, DESCRIPTION_FILE,
                     f"{DESCRIPTION_FILE}: {what}; it records the spec digest, variant and counts")
        description = None
    if not os.path.exists(layout.spec):
        problems.add("spec_snapshot", None, SPEC_FILE,
                     f"{SPEC_FILE}: missing; the dataset cannot be checked against its plan")
        return None, None, description, False, description_ok
    try:
        spec = parse_spec(layout.spec)
    except USER_ERRORS as exc:
        problems.add("spec_snapshot", None, SPEC_FILE,
                     f"{SPEC_FILE}: unreadable ({exc}); the dataset cannot be checked against its plan")
        return None, None, description, False, description_ok
    if description is not None and description.get("spec_digest") != spec_digest(spec):
        problems.add("spec_snapshot", None, SPEC_FILE,
                     f"{SPEC_FILE}: digest {spec_digest(spec)[:12]} differs from "
                     f"{DESCRIPTION_FILE}'s spec_digest {str(description.get('spec_digest'))[:12]}: "
                     "the snapshot (or the description) was edited after the build")
        spec_ok = False
    else:
        spec_ok = True
    try:
        plans = plan_dataset(spec)
    except USER_ERRORS as exc:
        problems.add("spec_snapshot", None, SPEC_FILE, f"{SPEC_FILE}: cannot be planned ({exc})")
        return spec, None, description, False, description_ok
    return spec, plans, description, spec_ok, description_ok


def _load_manifest(layout: Layout, problems: _Problems):
    """[(source, record)] of manifest.jsonl, or None when there is no manifest."""
    try:
        data = read_manifest(layout)
    except FileNotFoundError:
        problems.add("missing_manifest", None, MANIFEST_FILE,
                     f"{MANIFEST_FILE}: missing (an unfinished build, or deleted); records are "
                     "taken from the shard markers and per-sample record files")
        return None
    except OSError as exc:
        problems.add("missing_manifest", None, MANIFEST_FILE,
                     f"{MANIFEST_FILE}: cannot be read ({exc.strerror})")
        return None
    out = []
    for number, raw in enumerate(data.split(b"\n"), start=1):
        if not raw.strip():
            continue
        try:
            record = json.loads(raw)
        except ValueError as exc:
            problems.add("edited_record", None, MANIFEST_FILE,
                         f"{MANIFEST_FILE} line {number}: not a JSON record ({exc})")
            continue
        if not isinstance(record, dict) or not isinstance(record.get("id"), str):
            problems.add("edited_record", None, MANIFEST_FILE,
                         f"{MANIFEST_FILE} line {number}: not a record (a JSON object with an id)")
            continue
        out.append((_Source(MANIFEST_FILE, number), record))
    return out


def _load_markers(layout: Layout, shard_ids, known: dict) -> dict:
    """shard id -> marker (None when missing or torn). A marker's record equal to the one in
    ``known`` (id -> manifest record) is replaced by that object: one copy in memory, not two
    (a record is ~11 kB as Python objects; the paper's dataset has 50,000)."""
    markers = {}
    for sid in shard_ids:
        marker = read_json(layout.marker(sid))
        if isinstance(marker, dict) and isinstance(marker.get("records"), list):
            marker["records"] = [known[r["id"]] if isinstance(r, dict) and r.get("id") in known
                                 and known[r["id"]] == r else r for r in marker["records"]]
        markers[sid] = marker
    return markers


# --------------------------------------------------------------------------- file checks


def _expectations(spec, material_kind: str | None, family: str | None) -> dict[str, _Expect]:
    """What each role's EXR must hold, from the spec (None: only what every file needs)."""
    if spec is None:
        return {"render": _Expect("render", {"render": (3, "float32")}, None),
                "maps": _Expect("maps", None, None), "texture": _Expect("texture", None, None)}
    res = (spec.render.resolution, spec.render.resolution)
    storage = spec.storage

    def dtype(name):
        return "float16" if storage.maps_half and name in HALF_LAYERS else "float32"

    maps = {name: (MAP_CHANNELS[name], dtype(name)) for name in storage.layers}
    texture = {name: (MAP_CHANNELS[name], dtype(name)) for name in TEXTURE_LAYERS}
    if material_kind == "uniform":
        texture_shape = (1, 1)
    elif family is not None:
        texture_shape = (spec.materials.texture_resolution,) * 2
    else:
        texture_shape = None  # imported maps keep their file's size
    return {"render": _Expect("render", {"render": (3, "float32")}, res),
            "maps": _Expect("maps", maps, res),
            "texture": _Expect("texture", texture, texture_shape)}


def layer_issues(layers: dict[str, np.ndarray], expect: _Expect) -> list[tuple[str, str]]:
    """bad_layers issues: missing or extra layers, wrong channels, size or sample type."""
    issues = []
    if expect.layers is None:
        return issues
    missing = [n for n in expect.layers if n not in layers]
    extra = [n for n in layers if n not in expect.layers]
    if missing:
        issues.append(("bad_layers", f"layer(s) {', '.join(missing)} missing"))
    if extra:
        issues.append(("bad_layers", f"unexpected layer(s) {', '.join(sorted(extra))}"))
    for name, (channels, dtype) in expect.layers.items():
        arr = layers.get(name)
        if arr is None:
            continue
        if arr.shape[2] != channels:
            issues.append(("bad_layers", f"layer {name} has {arr.shape[2]} channel(s), expected {channels}"))
        if expect.shape is not None and tuple(arr.shape[:2]) != expect.shape:
            issues.append(("bad_layers", f"layer {name} is {arr.shape[1]}x{arr.shape[0]} pixels, "
                                         f"expected {expect.shape[1]}x{expect.shape[0]}"))
        if arr.dtype.name != dtype:
            issues.append(("bad_layers", f"layer {name} is {arr.dtype.name}, expected {dtype}"))
    return issues


def _range_text(values: np.ndarray) -> str:
    return f"min {float(values.min()):.6g}, max {float(values.max()):.6g}"


def map_value_issues(layers: dict[str, np.ndarray], screen_space: bool) -> list[tuple[str, str]]:
    """Sanity of material maps: finite, albedos and roughness in [0, 1], mask 0/1, unit
    normals (inside the mask for screen-space maps), nothing outside the mask."""
    issues = []
    inside = None
    if screen_space and "mask" in layers:
        inside = np.asarray(layers["mask"][..., 0], np.float32) > 0.5
    for name in ("diffuse", "specular", "roughness", "normal", "mask"):
        if name not in layers:
            continue
        values = np.asarray(layers[name], np.float32)
        finite = np.isfinite(values)
        if not finite.all():
            n_nan, n_inf = int(np.isnan(values).sum()), int(np.isinf(values).sum())
            issues.append(("non_finite", f"layer {name} has {n_nan} NaN and {n_inf} infinite value(s)"))
        values = np.where(finite, values, 0.0)
        if name in ("diffuse", "specular", "roughness"):
            bad = (values < 0) | (values > 1)
            if bad.any():
                issues.append(("out_of_range", f"layer {name} has {int(bad.sum())} value(s) outside "
                                               f"[0, 1] ({_range_text(values[bad])})"))
        elif name == "mask":
            bad = (values != 0) & (values != 1)
            if bad.any():
                issues.append(("out_of_range", f"layer mask has {int(bad.sum())} value(s) other than "
                                               f"0 and 1 ({_range_text(values[bad])})"))
        elif name == "normal" and values.shape[-1] == 3 and (inside is not None or not screen_space):
            length = np.sqrt(np.sum(values.astype(np.float64) ** 2, axis=-1))
            deviation = np.abs(length - 1.0)
            if inside is not None and inside.shape == deviation.shape:
                deviation = deviation[inside]
            bad = deviation > NORMAL_TOLERANCE
            if bad.any():
                where = "inside the mask " if inside is not None else ""
                issues.append(("normal_not_unit",
                               f"layer normal: {int(bad.sum())} pixel(s) {where}not of unit length "
                               f"(worst |length - 1| = {float(deviation.max()):.3g}; tolerance "
                               f"{NORMAL_TOLERANCE:g})"))
        if inside is not None and name != "mask" and values.shape[:2] == inside.shape:
            outside = np.any(values[~inside] != 0, axis=-1)
            if outside.any():
                issues.append(("out_of_range", f"layer {name} is non-zero at {int(outside.sum())} "
                                               "pixel(s) outside the mask"))
    return issues


def _inspect(root: str, rel: str, expect: _Expect, recorded_bytes, fast: bool) -> _FileFacts:
    """Stat (fast) or read, hash, decode and check one file, reading it once."""

    path = os.path.join(root, *rel.split("/"))
    try:
        size = os.stat(path).st_size
    except OSError:
        return _FileFacts(rel, None)
    if not os.path.isfile(path):
        return _FileFacts(rel, size, error="not a regular file")
    facts = _FileFacts(rel, size)
    if fast or (recorded_bytes is not None and size != recorded_bytes):
        return facts  # a size mismatch is reported as such; its content is not the record's
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        facts.error = f"cannot be read ({exc.strerror})"
        return facts
    facts.sha256 = hashlib.sha256(data).hexdigest()
    try:
        image = read_exr(data)
    except USER_ERRORS as exc:
        facts.error = str(exc).replace("<bytes>", "").replace("EXR :", "EXR:").strip()
        return facts
    facts.layers = {name: (tuple(arr.shape), arr.dtype.name) for name, arr in image.layers.items()}
    facts.meta_json = json.dumps(image.meta, separators=(",", ":"))
    facts.issues = layer_issues(image.layers, expect)
    if expect.role == "render":
        if "render" in image.layers:
            facts.pixel_stats = render_stats(image.layers["render"])
    else:
        facts.issues += map_value_issues(image.layers, screen_space=expect.role == "maps")
    return facts


def _safe_rel(rel) -> bool:
    if not isinstance(rel, str) or not rel or rel.startswith("/") or "\\" in rel:
        return False
    return all(part not in ("", ".", "..") for part in rel.split("/"))


def _file_problems(facts: _FileFacts, entry: dict, id_: str, listed_by: str, problems: _Problems) -> None:
    rel, recorded = facts.rel, entry.get("bytes")
    if facts.size is None:
        problems.add("missing_file", id_, rel,
                     f"{rel}: missing ({listed_by} lists it for {id_}, {recorded} bytes)")
        return
    if facts.error == "not a regular file":
        problems.add("undecodable", id_, rel, f"{rel}: not a regular file")
        return
    if facts.size != recorded:
        how = "truncated" if isinstance(recorded, int) and facts.size < recorded else "grown"
        problems.add("size_mismatch", id_, rel,
                     f"{rel}: {facts.size} bytes, {listed_by} says {recorded}: the file was {how}")
        return
    if facts.sha256 is None:  # not read: fast mode, or reading failed
        if facts.error:
            problems.add("undecodable", id_, rel, f"{rel}: {facts.error}")
        return
    if facts.sha256 != entry.get("sha256"):
        decodes = "it no longer decodes" if facts.error else "it still decodes"
        problems.add("checksum_mismatch", id_, rel,
                     f"{rel}: SHA-256 {facts.sha256[:16]}... differs from {listed_by}'s "
                     f"{str(entry.get('sha256'))[:16]}...: the bytes changed ({decodes})")
        return  # content problems of a changed file are a consequence, not news
    if facts.error:
        problems.add("undecodable", id_, rel, f"{rel}: {facts.error}")
        return
    by_kind: dict[str, list[str]] = {}
    for kind, message in facts.issues:
        by_kind.setdefault(kind, []).append(message)
    for kind, messages in by_kind.items():  # one problem per kind and file
        problems.add(kind, id_, rel, f"{rel}: {_summarise(messages, 4)}")


# --------------------------------------------------------------------------- record checks


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


def _expected_files(sample, spec) -> list[tuple[str, str]]:
    out = [("render", Layout.render_rel(sample.shard_id, sample.sample_id)),
           ("maps", Layout.maps_rel(sample.shard_id, sample.material_id))]
    if spec is None or spec.storage.texture_maps:
        out.append(("texture", Layout.texture_rel(sample.shard_id, sample.material_id)))
    return out


def _plan_discrepancies(record: dict, sample, state: _State) -> list[str]:
    """Fields of ``record`` that must equal the plan (and the spec) but do not."""
    spec = state.spec
    wanted = [
        ("id", sample.sample_id), ("material_id", sample.material_id),
        ("material_index", sample.material_index), ("light_index", sample.light_index),
        ("shard", sample.shard_id),
        ("seeds.material", sample.material_seed), ("seeds.light", sample.light_seed),
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
        wanted += [("render.resolution", r.resolution), ("render.spp", r.spp),
                   ("render.max_depth", r.max_depth), ("render.integrator", r.integrator),
                   ("render.sun", spec.lighting.sun)]
    if state.variant:
        wanted.append(("render.variant", state.variant))
    out = [f"{key} is {_get(record, key)!r}, the plan says {value!r}"
           for key, value in wanted if not _close(_get(record, key), value)]
    files = record.get("files")
    got = [(f.get("role"), f.get("path")) for f in files if isinstance(f, dict)] \
        if isinstance(files, list) else None
    expected = _expected_files(sample, spec)
    if got != expected:
        out.append(f"files lists {got!r}, the layout says {expected!r}")
    return out + _lighting_discrepancies(record)


def _lighting_discrepancies(record: dict) -> list[str]:
    """The effective lighting's direction and lighting vector follow from its angles."""

    lighting = record.get("lighting") if isinstance(record.get("lighting"), dict) else {}
    try:
        light = Light.from_dict(lighting)
    except Exception as exc:  # missing keys, out-of-range values: the message says which
        return [f"lighting is not a valid light ({exc})"]
    out = []
    direction = lighting.get("direction")
    try:
        if not np.allclose(np.asarray(direction, np.float64), light.direction, rtol=0, atol=1e-9):
            out.append(f"lighting.direction {direction!r} does not follow from elevation_deg "
                       f"{light.elevation_deg!r} and azimuth_deg {light.azimuth_deg!r}")
    except (TypeError, ValueError):
        out.append(f"lighting.direction is {direction!r}, not a 3-vector")
    vector = record.get("lighting_vector")
    try:
        if not np.allclose(np.asarray(vector, np.float64), light.lighting_vector(), rtol=0, atol=1e-6):
            out.append(f"lighting_vector {vector!r} does not follow from the effective lighting "
                       f"(direction and turbidity {light.turbidity!r})")
    except (TypeError, ValueError):
        out.append(f"lighting_vector is {vector!r}, not a 4-vector")
    seeds, stats = record.get("seeds") or {}, record.get("stats") or {}
    if isinstance(seeds, dict) and isinstance(stats, dict) and seeds.get("render_used") != stats.get("seed"):
        out.append(f"seeds.render_used is {seeds.get('render_used')!r}, stats.seed is {stats.get('seed')!r}")
    return out


def _header_discrepancies(record: dict, render: _FileFacts | None, maps: _FileFacts | None) -> list[str]:
    """Fields of ``record`` that the files' own headers contradict, one message per field."""
    checks = []
    meta = render.meta if render is not None else None
    if meta is not None:
        lighting = record.get("lighting") if isinstance(record.get("lighting"), dict) else {}
        header_lighting = meta.get("lighting") or {}
        effective = header_lighting.get("effective") or {}
        checks += [("render", "id", record.get("id"), meta.get("id")),
                   ("render", "material_id", record.get("material_id"), meta.get("material_id")),
                   ("render", "effects", record.get("effects"), meta.get("effects")),
                   ("render", "lighting.requested", lighting.get("requested"), header_lighting.get("requested")),
                   ("render", "lighting.policy", lighting.get("policy"),
                    {k: v for k, v in header_lighting.items() if k not in ("requested", "effective")})]
        checks += [("render", f"lighting.{key}", lighting.get(key), effective.get(key))
                   for key in ("elevation_deg", "azimuth_deg", "turbidity")]
    maps_meta = maps.meta if maps is not None else None
    if maps_meta is not None:
        checks += [("maps", "material_id", record.get("material_id"), maps_meta.get("id")),
                   ("maps", "material", record.get("material"), maps_meta.get("material"))]
    out = []
    for which, key, mine, theirs in checks:
        for sub in _diff_keys(mine, theirs):
            dotted = key if sub == "(record)" else f"{key}.{sub}"
            out.append(f"{dotted} is {short_repr(_get_path(mine, sub), 123)}, the {which} file's header says "
                       f"{short_repr(_get_path(theirs, sub), 123)}")
    return out


def _get_path(value, dotted: str):
    return value if dotted == "(record)" else _get(value, dotted)


def _stats_discrepancies(record: dict, render: _FileFacts) -> list[str]:
    """The record's statistics against the pixels and the header of its render file."""

    stats = record.get("stats") if isinstance(record.get("stats"), dict) else {}
    out = []
    if render.pixel_stats is not None:
        for key in PIXEL_STATS:
            mine, actual = stats.get(key), render.pixel_stats.get(key)
            if not (_close(mine, actual, STATS_RTOL, 0.0) if mine is not None and actual is not None
                    else mine == actual):
                out.append(f"stats.{key} is {mine!r}, the pixels give {actual!r}")
        if stats.get("flagged") is not None and bool(stats.get("flagged")) != is_bad(render.pixel_stats):
            out.append(f"stats.flagged is {stats.get('flagged')!r}, but the pixels are "
                       f"{'bad' if is_bad(render.pixel_stats) else 'clean'}")
    meta = render.meta
    if meta is not None and "stats" in meta:
        stored = {k: v for k, v in stats.items() if k not in RUN_DEPENDENT_STATS}
        header = meta["stats"] if isinstance(meta["stats"], dict) else {}
        keys = sorted(k for k in set(stored) | set(header) if stored.get(k) != header.get(k))
        keys = [k for k in keys if not any(line.startswith(f"stats.{k} ") for line in out)]
        out += [f"stats.{k} is {stored.get(k)!r}, the render file's header says {header.get(k)!r}"
                for k in keys]
    return out


def _policy_problems(record: dict, render: _FileFacts) -> list[tuple[str, str]]:
    """Bad pixels are allowed only in a render the render policy flagged."""
    stats, pixels = record.get("stats") or {}, render.pixel_stats
    if pixels is None or (isinstance(stats, dict) and stats.get("flagged")):
        return []
    out = []
    if pixels["nan"] or pixels["inf"]:
        out.append(("non_finite", f"{pixels['nan']} NaN and {pixels['inf']} infinite value(s) in a "
                                  "render not flagged by the render policy"))
    if pixels["negative"]:
        out.append(("negative_render", f"{pixels['negative']} negative value(s) (min "
                                       f"{pixels['min']:.6g}) in a render not flagged by the render policy"))
    return out


def _diff_keys(a, b, prefix: str = "") -> list[str]:
    """Dotted paths where two JSON values differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _diff_keys(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [prefix.rstrip(".") or "(record)"]


def _summarise(messages: list[str], limit: int = 3) -> str:
    text = "; ".join(messages[:limit])
    return text + (f"; and {len(messages) - limit} more" if len(messages) > limit else "")


def _record_ok(record: dict | None, sample, state: _State) -> bool:
    """A record repair may keep: plan, headers, stats and its render file all agree."""
    if not isinstance(record, dict):
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
    return not (_header_discrepancies(record, render, maps) or _stats_discrepancies(record, render)
                or _policy_problems(record, render))


# --------------------------------------------------------------------------- validate


def validate(root: str, *, fast: bool = False, progress: Callable[[Progress], None] | None = None,
             threads: int | None = None) -> Report:
    """Check the dataset in ``root``; return a :class:`Report` (``report.ok`` when valid).

    Raises :class:`ShaderballError` when ``root`` is missing or not a dataset directory.
    ``fast``: sizes, markers and records only (no file is read). ``threads``: files read
    at once (hashing and decompression release the GIL); default: up to 4.
    """
    start = time.perf_counter()
    layout = _check_root(root)
    problems = _Problems()
    spec, plans, description, spec_ok, description_ok = _load_plan(layout, problems)
    planned = {}
    if plans is not None:
        planned = {s.sample_id: s for s in iter_samples(plans)}
    shard_ids = [s.shard_id for s in plans] if plans is not None else shard_ids_on_disk(layout)
    state = _State(layout=layout, spec=spec, plans=plans, planned=planned,
                   variant=(description or {}).get("variant"), spec_ok=spec_ok,
                   description_ok=description_ok, manifest={}, markers={},
                   record_files={}, facts={}, extra_files=[], allowed_dirs=set(),
                   manifest_dirty=False)
    manifest = _load_manifest(layout, problems)
    first = {}
    for _source, record in manifest or ():
        first.setdefault(record["id"], record)
    state.markers = _load_markers(layout, shard_ids, first)
    records = manifest if manifest is not None else _fallback_records(state)
    primary = _check_records_against_plan(records, state, problems, from_manifest=manifest is not None)
    files = _referenced_files(primary, state)
    bytes_read = _inspect_all(layout.root, files, fast, progress, state, threads, start)
    _check_files_and_records(primary, files, state, problems, fast)
    _check_markers(state, primary, problems, manifest is not None, fast)
    if not fast:
        _check_record_files(state, primary, problems)
    _check_extra_files(state, primary, problems)
    state.manifest_dirty = manifest is None or any(p.path == MANIFEST_FILE for p in problems)

    expected = len(planned) if plans is not None else int(
        ((description or {}).get("counts") or {}).get("renders") or len(primary))
    ids = list(planned) if plans is not None else list(primary)
    present = [i for i in ids if i in primary and _render_present(primary[i][1], state)]
    named = {p.id for p in problems if p.id is not None}
    valid = [i for i in present if i not in named and primary[i][1].get("material_id") not in named]
    if plans is None:  # nothing is valid against a plan that cannot be made
        valid = []
    flagged = sum(1 for i in present if (primary[i][1].get("stats") or {}).get("flagged"))
    return Report(root=root, fast=fast, expected=expected, present=len(present), valid=len(valid),
                  problems=list(problems), flagged=flagged, files_checked=len(files),
                  bytes_read=bytes_read, seconds=time.perf_counter() - start, _state=state)


def _copy_faulty(record, sample, state: _State, fast: bool) -> bool:
    """Whether one copy of a record is itself wrong (not merely different from another)."""
    if sample is None or not isinstance(record, dict):
        return True
    if fast:
        return bool(_plan_discrepancies(record, sample, state))
    return not _record_ok(record, sample, state)


def _fallback_records(state: _State) -> list:
    """Without a manifest: complete markers' records, else each sample's record file."""
    layout, out = state.layout, []
    for sid, marker in state.markers.items():
        if isinstance(marker, dict) and marker.get("complete") and isinstance(marker.get("records"), list):
            out += [(_Source(layout.marker_rel(sid)), r) for r in marker["records"] if isinstance(r, dict)]
            continue
        try:
            names = record_file_names(layout, sid) or []
        except OSError:
            continue
        for name in names:
            rel = f"{SHARDS_DIR}/{sid}/{name}"
            record = read_json(layout.path(rel))
            if isinstance(record, dict) and isinstance(record.get("id"), str):
                out.append((_Source(rel), record))
    return out


def _check_records_against_plan(records, state: _State, problems: _Problems, from_manifest: bool) -> dict:
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
            problems.add("duplicate_record", sid, source.path,
                         f"{source}: a second record for {sid} ({same} to the first, at {first})")
            continue
        primary[sid] = (source, record)
        if state.plans is None:
            continue
        if sid not in state.planned:
            problems.add("extra_sample", sid, source.path,
                         f"{source}: record for {sid}, which the plan does not have")
            continue
        if from_manifest and plan_order[sid] < last_index and not order_reported:
            problems.add("edited_record", sid, source.path,
                         f"{source}: record for {sid} is out of plan order")
            order_reported = True
        last_index = max(last_index, plan_order[sid])
    if state.plans is not None:
        where = MANIFEST_FILE if from_manifest else "the shard markers or record files"
        for sid, sample in state.planned.items():
            if sid not in primary:
                problems.add("missing_sample", sid, MANIFEST_FILE if from_manifest else None,
                             f"{sid} (shard {sample.shard_id}): planned, but there is no record of it in {where}")
    state.manifest = {sid: rec for sid, (src, rec) in primary.items()} if from_manifest else {}
    return primary


def _check_markers(state: _State, primary: dict, problems: _Problems, have_manifest: bool,
                   fast: bool) -> None:
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
            exists = os.path.exists(layout.marker(sid))
            recorded = sum(1 for s in wanted if s in primary)
            problems.add("incomplete_shard", sid, rel,
                         f"{rel}: {'unreadable (torn or not JSON)' if exists else 'missing'}; "
                         f"{recorded} of {len(wanted)} samples of shard {sid} have a record")
            continue
        if not isinstance(marker, dict) or not marker.get("complete") or \
                not isinstance(marker.get("records"), list):
            problems.add("incomplete_shard", sid, rel, f"{rel}: does not mark shard {sid} complete")
            continue
        ids = [r.get("id") for r in marker["records"] if isinstance(r, dict)]
        if marker.get("shard") != sid or marker.get("samples") != ids:
            problems.add("edited_record", sid, rel,
                         f"{rel}: its shard ({marker.get('shard')!r}) or sample list disagrees with "
                         "its records")
        lacking = [s for s in wanted if s not in ids]
        if lacking:
            problems.add("incomplete_shard", sid, rel,
                         f"{rel}: lacks {len(lacking)} planned sample(s): {', '.join(lacking[:5])}")
        strays = [s for s in ids if s not in wanted]
        if strays:
            problems.add("edited_record", sid, rel,
                         f"{rel}: holds record(s) for {', '.join(map(str, strays[:5]))}, "
                         f"not planned in {sid}")
        if have_manifest:
            _compare_copies(state, primary, problems, fast, rel,
                            [r for r in marker["records"] if isinstance(r, dict) and r.get("id") in wanted])


def _compare_copies(state: _State, primary: dict, problems: _Problems, fast: bool, rel: str,
                    copies: list[dict]) -> None:
    """Copies of records in ``rel`` against the primary ones; a difference is reported on
    the side that is wrong (the primary side's own faults are reported by the record checks)."""
    for copy in copies:
        sid = copy.get("id")
        if sid not in primary or primary[sid][1] is copy or primary[sid][1] == copy:
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
            problems.add("edited_record", sid, source.path,
                         f"{source} and {rel} hold different records for {sid}, at {keys}"
                         + ("; the full check tells which is right" if fast else ""))


def _check_record_files(state: _State, primary: dict, problems: _Problems) -> None:
    """Per-sample record files (what a resumed build trusts) must match the shard's record."""
    if state.plans is None:
        return
    layout = state.layout
    for sid, sample in state.planned.items():
        rel = layout.record_rel(sample.shard_id, sid)
        path = layout.path(rel)
        if not os.path.exists(path):
            state.record_files[sid] = None
            continue
        content = read_json(path)
        reference = _marker_record(state, sample) or (primary.get(sid) or (None, None))[1]
        state.record_files[sid] = reference if content == reference else content  # one copy
        if reference is None or content == reference:
            continue
        if isinstance(content, dict) and isinstance(reference, dict) and \
                without_timings(content) == without_timings(reference):
            continue  # two runs of one shard: equal but for the run-dependent render time
        if not isinstance(content, dict):
            problems.add("edited_record", sid, rel, f"{rel}: not a JSON record (torn or edited)")
            continue
        if _copy_faulty(content, sample, state, False) or not _copy_faulty(reference, sample, state, False):
            keys = ", ".join(_diff_keys(content, reference)[:5])
            problems.add("edited_record", sid, rel,
                         f"{rel}: differs from the shard's record of {sid} at {keys}")


def _marker_record(state: _State, sample) -> dict | None:
    marker = state.markers.get(sample.shard_id)
    if not isinstance(marker, dict) or not isinstance(marker.get("records"), list):
        return None
    for record in marker["records"]:
        if isinstance(record, dict) and record.get("id") == sample.sample_id:
            return record
    return None


def _referenced_files(primary: dict, state: _State) -> dict:
    """rel path -> (first id, entry, listed_by, expectation) of every file a record lists."""
    files: dict = {}
    for sid, (source, record) in primary.items():
        entries = record.get("files")
        if not isinstance(entries, list):
            continue
        sample = state.planned.get(sid)
        expect = _expectations(state.spec, sample.kind if sample else None,
                               sample.svbrdf_family if sample else None)
        for entry in entries:
            if not isinstance(entry, dict) or entry.get("role") not in expect:
                continue
            rel = entry.get("path")
            if not _safe_rel(rel) or rel in files:
                continue
            owner = sid if entry["role"] == "render" else record.get("material_id", sid)
            files[rel] = (owner, entry, source.path, expect[entry["role"]])
    return files


def _inspect_all(root: str, files: dict, fast: bool, progress, state: _State, threads, start) -> int:
    total, bytes_read = len(files), 0
    items = list(files.items())

    def one(item):
        rel, (_owner, entry, _src, expect) = item
        return _inspect(root, rel, expect, entry.get("bytes"), fast)

    n_threads = threads or min(4, os.cpu_count() or 1)
    with ThreadPoolExecutor(max_workers=max(1, n_threads)) as pool:
        for done, facts in enumerate(pool.map(one, items), start=1):
            state.facts[facts.rel] = facts
            if facts.sha256 is not None:
                bytes_read += facts.size or 0
            if progress is not None:
                progress(Progress("check", done, total, facts.rel, bytes_read, time.perf_counter() - start))
    return bytes_read


def _trusted(facts: _FileFacts | None, files: dict) -> bool:
    """Read, decoded, and the bytes its (first) record describes."""
    return facts is not None and facts.decoded and facts.sha256 is not None and \
        facts.sha256 == files.get(facts.rel, (None, {}))[1].get("sha256")


def _check_files_and_records(primary: dict, files: dict, state: _State, problems: _Problems,
                             fast: bool) -> None:
    """File problems (once per file) and each record's agreement with plan, headers, stats."""
    for rel, (owner, entry, listed_by, _expect) in files.items():
        _file_problems(state.facts[rel], entry, owner, listed_by, problems)
    for sid, (source, record) in primary.items():
        sample = state.planned.get(sid)
        if sample is None:
            continue
        entries = {e.get("role"): e for e in record.get("files", []) if isinstance(e, dict)} \
            if isinstance(record.get("files"), list) else {}
        messages = _plan_discrepancies(record, sample, state)
        for role, entry in entries.items():
            rel = entry.get("path")
            if not _safe_rel(rel):
                messages.append(f"files[{role}].path {rel!r} is not a path inside the dataset")
                continue
            first = files.get(rel)
            if first is not None and first[1] is not entry and \
                    (first[1].get("bytes"), first[1].get("sha256")) != (entry.get("bytes"), entry.get("sha256")):
                messages.append(f"files[{role}] of {rel} has size/SHA-256 different from {first[0]}'s record")
        render = state.facts.get((entries.get("render") or {}).get("path"))
        maps = state.facts.get((entries.get("maps") or {}).get("path"))
        render = render if _trusted(render, files) else None
        maps = maps if _trusted(maps, files) else None
        if not fast:
            said = {m.split(" ", 1)[0] for m in messages}
            messages += [m for m in _header_discrepancies(record, render, maps)
                         if m.split(" ", 1)[0] not in said]
        if messages:
            problems.add("edited_record", sid, source.path,
                         f"{source} ({sid}): {_summarise(messages)}")
        if fast or render is None:
            continue
        stats_messages = _stats_discrepancies(record, render)
        if stats_messages:
            problems.add("stats_mismatch", sid, source.path,
                         f"{source} ({sid}) vs {render.rel}: {_summarise(stats_messages)}")
        for kind, message in _policy_problems(record, render):
            problems.add(kind, sid, render.rel, f"{render.rel}: {message}")


def _allowed_files(state: _State, primary: dict) -> tuple[set, set]:
    """(files, directories) that belong to the dataset, relative to DIR."""
    layout = state.layout
    files, dirs = set(ROOT_FILES), {SHARDS_DIR}
    if state.plans is not None:
        for shard in state.plans:
            dirs.add(f"{SHARDS_DIR}/{shard.shard_id}")
            files.add(layout.marker_rel(shard.shard_id))
            for sample in shard.samples:
                files.add(layout.record_rel(shard.shard_id, sample.sample_id))
                files.update(rel for _role, rel in _expected_files(sample, state.spec))
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


def _check_extra_files(state: _State, primary: dict, problems: _Problems) -> None:
    files, dirs = _allowed_files(state, primary)
    state.allowed_dirs = dirs
    root = state.layout.root
    for folder, subdirs, names in os.walk(root):
        rel_dir = os.path.relpath(folder, root).replace(os.sep, "/")
        rel_dir = "" if rel_dir == "." else rel_dir + "/"
        for name in sorted(subdirs):
            rel = rel_dir + name
            if rel not in dirs and not os.listdir(os.path.join(folder, name)):
                state.extra_files.append(rel)
                problems.add("extra_file", None, rel, f"{rel}/: an empty directory that is no part of the dataset")
        subdirs.sort()
        for name in sorted(names):
            rel = rel_dir + name
            if rel in files:
                continue
            why = ("a temporary file left by an interrupted write" if is_temp_file(name)
                   else "no part of the dataset: no planned record or marker refers to it")
            state.extra_files.append(rel)
            problems.add("extra_file", None, rel, f"{rel}: {why}")


def _render_present(record: dict, state: _State) -> bool:
    for entry in record.get("files") or []:
        if isinstance(entry, dict) and entry.get("role") == "render":
            facts = state.facts.get(entry.get("path"))
            return facts is not None and facts.size is not None
    return False


# --------------------------------------------------------------------------- repair


def repair(root: str, *, workers: int = 0, progress: Callable[[Progress], None] | None = None,
           spec_path: str | None = None) -> tuple[Report, Report, list[RepairAction]]:
    """Fix what :func:`validate` finds; return (report before, report after, actions).

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
        actions.append(_restore_spec(state, spec_path))
        current = validate(root, progress=progress)
        if current.ok:
            return before, current, actions
        state = current._state
    if state.plans is None or not state.spec_ok:
        return before, before, actions + [RepairAction(
            "unrepairable", SPEC_FILE,
            f"{SPEC_FILE}: the spec snapshot is unusable or does not match {DESCRIPTION_FILE}; "
            "give the spec the dataset was built from (--spec) to restore it; nothing was changed")]
    layout = state.layout
    _delete_extra_files(state, actions)
    _inspect_unlisted(state)
    chosen = {sid: _chosen(state, sample) for sid, sample in state.planned.items()}
    affected = _settle_samples(state, chosen, actions)
    for shard in state.plans:
        marker = state.markers.get(shard.shard_id)
        if not (isinstance(marker, dict) and marker.get("complete")
                and marker.get("samples") == [s.sample_id for s in shard.samples]
                and all(_marker_record(state, s) == chosen[s.sample_id] for s in shard.samples)):
            affected.add(shard.shard_id)
    _write_good_record_files(state, chosen, affected, actions)
    for sid in sorted(affected):
        _remove(layout.marker(sid))
        actions.append(RepairAction("rerun_shard", layout.marker_rel(sid),
                                    f"shard {sid}: marker removed; rebuilt from its verified records"))
    if affected or not state.description_ok:
        _rebuild(root, workers, progress, len(affected))
        if not state.description_ok:
            actions.append(RepairAction("rewrite_description", DESCRIPTION_FILE,
                                        f"{DESCRIPTION_FILE}: rewritten from the spec snapshot"))
        actions.append(RepairAction("rewrite_manifest", MANIFEST_FILE,
                                    f"{MANIFEST_FILE}: rewritten from the shard markers by the resumed build"))
    elif state.manifest_dirty:

        write_manifest(layout.root, state.plans)
        actions.append(RepairAction("rewrite_manifest", MANIFEST_FILE,
                                    f"{MANIFEST_FILE}: rewritten from the shard markers"))
    after = validate(root, progress=progress)
    return before, after, actions


def _restore_spec(state: _State, spec_path: str) -> RepairAction:
    """Write ``spec_path`` as the snapshot, if it is the spec dataset.json says was built."""

    description = read_json(state.layout.description)
    recorded = description.get("spec_digest") if isinstance(description, dict) else None
    if not recorded:
        raise ShaderballError(f"--spec: {DESCRIPTION_FILE} of {state.layout.root!r} is missing or has no "
                              "spec_digest, so no spec can be confirmed as the one it was built from")
    spec = parse_spec(spec_path)
    if spec_digest(spec) != recorded:
        raise ShaderballError(f"--spec: {spec_path!r} has digest {spec_digest(spec)[:12]}, "
                              f"{DESCRIPTION_FILE} says the dataset was built from {recorded[:12]}: "
                              "not this dataset's spec")
    write_text_atomic(state.layout.spec, spec_to_toml(spec))
    return RepairAction("restore_spec", SPEC_FILE, f"{SPEC_FILE}: restored from {spec_path} (digest "
                                                   f"{recorded[:12]} matches {DESCRIPTION_FILE})")


def _remove(path: str) -> bool:
    try:
        os.remove(path)
        return True
    except FileNotFoundError:
        return False


def _delete_extra_files(state: _State, actions: list) -> None:
    """Delete extra files, then the directories they leave empty (unless the layout's)."""
    root = state.layout.root
    for rel in state.extra_files:
        path = state.layout.path(rel)
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
        else:
            _remove(path)
        actions.append(RepairAction("delete_extra", rel, f"{rel}: deleted (no part of the dataset)"))
    for rel in state.extra_files:
        parent = os.path.dirname(rel)
        while parent and parent not in state.allowed_dirs:
            try:
                os.rmdir(os.path.join(root, *parent.split("/")))
            except OSError:
                break  # not empty, or gone
            parent = os.path.dirname(parent)


def _inspect_unlisted(state: _State) -> None:
    """Read the planned files no manifest record listed (a torn or lost manifest line), so
    the marker's or record file's copy can be judged."""
    for sample in state.planned.values():
        expect = _expectations(state.spec, sample.kind, sample.svbrdf_family)
        for role, rel in _expected_files(sample, state.spec):
            if rel not in state.facts:
                state.facts[rel] = _inspect(state.layout.root, rel, expect[role], None, False)


def _candidates(state: _State, sample) -> list[dict]:
    """The copies of a sample's record, the marker's first (the manifest is made from it)."""
    out = []
    for record in (_marker_record(state, sample), state.record_files.get(sample.sample_id),
                   state.manifest.get(sample.sample_id)):
        if isinstance(record, dict) and record not in out:
            out.append(record)
    return out


def _chosen(state: _State, sample) -> dict | None:
    """The record repair keeps for ``sample``: the first copy that checks out, preferring one
    whose material entries match intact material files."""
    good = [r for r in _candidates(state, sample) if _record_ok(r, sample, state)]

    def material_match(record):
        for entry in record.get("files", [])[1:]:
            facts = state.facts.get(entry.get("path"))
            if facts is not None and facts.content_ok and facts.sha256 is not None and \
                    (facts.size, facts.sha256) != (entry.get("bytes"), entry.get("sha256")):
                return False
        return True

    preferred = [r for r in good if material_match(r)]
    return (preferred or good or [None])[0]


def _settle_samples(state: _State, chosen: dict, actions: list) -> set:
    """Delete renders without a good record, and material files that are bad; return the
    shards this touches."""
    layout, affected = state.layout, set()
    for sid, sample in state.planned.items():
        if chosen[sid] is not None:
            continue
        affected.add(sample.shard_id)
        rel = layout.render_rel(sample.shard_id, sid)
        _remove(layout.path(rel))
        _remove(layout.path(layout.record_rel(sample.shard_id, sid)))
        state.record_files[sid] = None
        actions.append(RepairAction("rerender", rel, f"{rel}: no intact copy of its record and file; re-rendered"))
    for shard in state.plans:
        for material in shard.materials:
            kept = [chosen[s.sample_id] for s in material.samples]
            for role, rel in _expected_files(material.samples[0], state.spec)[1:]:
                facts = state.facts.get(rel)
                entries = {(e.get("bytes"), e.get("sha256")) for r in kept if r
                           for e in r.get("files", []) if isinstance(e, dict) and e.get("path") == rel}
                if facts is not None and facts.content_ok and facts.sha256 is not None and \
                        (facts.size, facts.sha256) in entries:
                    continue
                affected.add(shard.shard_id)
                _remove(layout.path(rel))
                actions.append(RepairAction("regenerate", rel, f"{rel}: bad or missing {role} file; regenerated"))
    return affected


def _write_good_record_files(state: _State, chosen: dict, affected: set, actions: list) -> None:
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


def _rebuild(root: str, workers: int, progress, n_shards: int) -> None:
    """Resume the build: the shards without a marker are rebuilt, the manifest rewritten."""

    def forward(p):
        if progress is not None:
            progress(Progress("repair", p.done, p.total, f"{n_shards} shard(s)", 0, p.elapsed_s))

    build(Layout(root).spec, root, workers=workers, progress=forward)
