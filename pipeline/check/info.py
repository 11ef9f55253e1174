"""`shaderball info DIR`: what a dataset folder holds, complete or not.

Reads only the folder's own files: the spec snapshot, the description, the shard markers
and, in unfinished shards, the per-sample records (through pipeline.store.folder). Nothing is
rendered, hashed or written; `shaderball validate` is the command that checks files.
Counts come from the spec (materials x lightings, shards), so a build that was stopped
half-way reports how far it got. Where the spec names other objects or environment maps, the
plan's counts say how many materials each object shows and which maps lightings draw from
(:meth:`pipeline.dataset.plan.Plan.summary`); a spec that names neither reports as before.
"""

from __future__ import annotations

import os
import statistics
from array import array
from collections import Counter
from dataclasses import dataclass, field

from pipeline.check.request import InfoRequest, dir_refused
from pipeline.check.snapshot import read_snapshot
from pipeline.dataset.plan import plan_dataset, shard_id
from pipeline.dataset.spec_file import spec_digest
from pipeline.errors import ShaderballError
from pipeline.store.bounded_read import read_json_checked, unsafe_entry
from pipeline.store.folder import (
    disk_usage,
    manifest_record_count,
    read_manifest,
    shard_records,
    symlinks_and_odd_files,
)
from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, Layout

#: Roles of the files a record lists, in the order they are reported.
FILE_ROLES = ("render", "maps", "texture")
#: What each role stores, for the report.
ROLE_NOTES = {"render": "float32", "maps": "screen-space maps", "texture": "texture-space maps"}


def shard_render_counts(spec) -> dict[str, int]:
    """shard id -> renders planned in it, from the spec alone (no planning needed)."""

    ds = spec.dataset
    counts = {}
    for s in range(ds.n_shards):
        first = s * ds.shard_size
        counts[shard_id(s)] = (min(first + ds.shard_size, ds.materials) - first) * ds.lights_per_material
    return counts


#: Effects of pipeline.render.renderer.EffectPlan, in the order they are reported.
EFFECT_ORDER = ("textured", "normal_map", "diffuse_lobe", "specular_lobe")


def _effect_order(name: str) -> tuple[int, str]:
    return (EFFECT_ORDER.index(name) if name in EFFECT_ORDER else len(EFFECT_ORDER), name)


def human_bytes(n: float) -> str:
    """``n`` bytes as people read them: ``512 B``, ``3.2 MiB``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} TiB"


def problems_line(head: str, problems: list[str]) -> str:
    """``head (N; run `shaderball validate`): `` and the first five problems."""
    more = " ..." if len(problems) > 5 else ""
    return f"{head} ({len(problems)}; run `shaderball validate`): " + "; ".join(problems[:5]) + more


@dataclass
class DatasetInfo:
    root: str
    name: str
    version: str
    spec_digest: str
    description: dict | None
    spec_lines: list[str]
    total_renders: int
    total_shards: int
    recorded: int = 0
    shards_complete: int = 0
    shards_started: int = 0
    manifest_records: int | None = None  # lines of manifest.jsonl, None when absent
    files: dict = field(default_factory=dict)  # role -> {"count", "bytes"} (distinct files)
    disk_bytes: int = 0
    temp_files: int = 0
    kinds: dict = field(default_factory=dict)  # "uniform" / "svbrdf" -> materials recorded
    effects: dict = field(default_factory=dict)  # effect -> renders with it on
    flagged: int = 0
    rerendered: int = 0
    noise_relative_median: float | None = None
    #: materials planned on each object (a mesh file by its base name) and the environment maps
    #: lightings draw from (base names), where the spec names them (Plan.summary()); empty else
    objects: dict = field(default_factory=dict)
    environments: list = field(default_factory=list)
    #: what was left out and why: malformed markers or records, paths leaving the folder,
    #: symbolic links or FIFOs in it (``shaderball validate`` checks everything).
    problems: list = field(default_factory=list)

    @property
    def complete(self) -> bool:
        return self.shards_complete == self.total_shards and self.manifest_records == self.total_renders

    def lines(self) -> list[str]:
        d = self.description or {}
        libs = _dict(d.get("libraries"))
        guarantee = _dict(d.get("determinism")).get("guarantee")
        built = (
            (
                f"; built with shaderball {d.get('shaderball', '?')}, mitsuba {libs.get('mitsuba', '?')} "
                f"{d.get('variant', '?')}" + (f" ({guarantee} re-renders)" if isinstance(guarantee, str) else "")
            )
            if d
            else "; no dataset.json yet"
        )
        pct = 100.0 * self.recorded / self.total_renders if self.total_renders else 100.0
        state = "complete" if self.complete else "INCOMPLETE (resume with `shaderball build DIR/spec.toml --out DIR`)"
        manifest = "absent" if self.manifest_records is None else f"{self.manifest_records} records"
        out = [
            f"dataset {self.root}: {self.name} v{self.version}, spec digest {self.spec_digest[:12]}{built}",
            *self.spec_lines,
            f"completion: {state}; {self.recorded}/{self.total_renders} renders recorded ({pct:.1f}%), "
            f"{self.shards_complete}/{self.total_shards} shards complete, "
            f"{self.shards_started - self.shards_complete} in progress; manifest.jsonl {manifest}",
        ]
        parts = [
            f"{self.files[r]['count']} {r} ({ROLE_NOTES[r]}) {human_bytes(self.files[r]['bytes'])}"
            for r in FILE_ROLES
            if r in self.files
        ]
        out.append(
            "files: "
            + (", ".join(parts) if parts else "none recorded yet")
            + f"; {human_bytes(self.disk_bytes)} on disk in all"
            + (f"; {self.temp_files} temporary file(s) of an interrupted write" if self.temp_files else "")
        )
        if self.kinds:
            out.append("materials recorded: " + ", ".join(f"{n} {k}" for k, n in sorted(self.kinds.items())))
        if self.recorded:
            out.append(
                "effects simulated (renders): "
                + ", ".join(f"{name.replace('_', ' ')} {n}/{self.recorded}" for name, n in self.effects.items())
            )
            noise = (
                f"; relative noise (RMS standard error / mean) median {self.noise_relative_median:.3f}"
                if self.noise_relative_median is not None
                else ""
            )
            out.append(f"renders flagged bad: {self.flagged}; re-rendered with a new seed: {self.rerendered}{noise}")
        if self.problems:
            out.append(problems_line("NOT READ", self.problems))
        return out

    def to_dict(self) -> dict:
        from dataclasses import asdict

        out = {**asdict(self), "complete": self.complete}
        for key in ("objects", "environments"):  # a spec naming neither: the document as it was
            if not out[key]:
                del out[key]
        return out


def spec_summary(spec, scene: dict | None = None) -> list[str]:
    """The spec's lines of the report; ``scene``: the plan summary's ``objects`` and
    ``environments`` (:meth:`pipeline.dataset.plan.Plan.summary`), each where it has them."""
    ds, r, lt, st = spec.dataset, spec.render, spec.lighting, spec.storage
    scene = scene or {}
    n_svbrdf = ds.n_svbrdf
    out = [
        f"spec: {ds.materials} materials ({ds.materials - n_svbrdf} uniform, {n_svbrdf} SVBRDF) x "
        f"{ds.lights_per_material} lightings = {ds.n_renders} renders in {ds.n_shards} shards of "
        f"{ds.shard_size} materials; seed {ds.seed}",
        f"render: {r.resolution}x{r.resolution}, {r.spp} spp, max depth {r.max_depth}, {r.integrator}, "
        f"variant {r.variant}; lighting: {lighting_summary(lt)}",
        f"storage: {st.compression}, maps {'half' if st.maps_half else 'float32'} "
        f"({', '.join(st.layers)}), texture-space maps {'on' if st.texture_maps else 'off'}",
    ]
    if scene.get("objects"):
        out.append(f"objects (materials planned, {spec.scene.scheme}): " + counted_names(scene["objects"]))
    if scene.get("environments"):
        out.append(f"environment maps ({len(scene['environments'])}): " + listed_names(scene["environments"]))
    return out


def lighting_summary(lighting) -> str:
    """The lighting's ranges as the report words them: the sun's, or the environment maps'
    (the sun's keys are then unused, so they are not shown)."""
    lt = lighting
    if lt.source == "environment":
        return (
            f"environment maps, one drawn per lighting, rotation {list(lt.rotation_deg)} deg, "
            f"intensity {list(lt.intensity)} (uniform)"
        )
    return (
        f"elevation {list(lt.elevation_deg)} deg, azimuth {list(lt.azimuth_deg)} deg, "
        f"turbidity {list(lt.turbidity)}, {lt.scheme}, sun {lt.sun}"
    )


#: Names a report line lists at most (a folder may hold hundreds of maps).
LISTED_NAMES = 8


def listed_names(names) -> str:
    names = list(names)
    more = f", ... ({len(names) - LISTED_NAMES} more)" if len(names) > LISTED_NAMES else ""
    return ", ".join(names[:LISTED_NAMES]) + more


def counted_names(counts: dict) -> str:
    return listed_names(f"{name} {n}" for name, n in counts.items())


def scene_summary(spec) -> dict:
    """The plan summary's ``objects`` and ``environments`` of ``spec`` (either only where the
    spec names it)."""
    summary = plan_dataset(spec).summary()
    return {key: summary[key] for key in ("objects", "environments") if key in summary}


def _dict(value) -> dict:
    return value if isinstance(value, dict) else {}


def _number(value) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def dataset_info(root: str) -> DatasetInfo:
    """Summarise the dataset folder ``root`` (complete or partial). Malformed or unsafe
    markers, records and files are left out and listed in ``problems``, never followed."""

    layout = Layout(root)
    if not os.path.isdir(root):
        raise dir_refused(root, "is not a folder", owner=InfoRequest)
    if not os.path.lexists(layout.spec):
        raise dir_refused(
            root, "holds no spec.toml (`shaderball build` writes it before anything else)", owner=InfoRequest
        )
    spec = read_snapshot(root)
    counts = shard_render_counts(spec)
    description, why = read_json_checked(layout.description)
    scene, scene_problem = {}, None
    try:
        scene = scene_summary(spec)
    except (ShaderballError, OSError) as exc:  # e.g. an imported SVBRDF folder gone since the build
        scene_problem = f"plan: {exc}"
    info = DatasetInfo(
        root=root,
        name=spec.dataset.name,
        version=spec.dataset.version,
        spec_digest=spec_digest(spec),
        description=description if isinstance(description, dict) else None,
        spec_lines=spec_summary(spec, scene),
        total_renders=sum(counts.values()),
        total_shards=len(counts),
        objects=dict(scene.get("objects", {})),
        environments=list(scene.get("environments", [])),
    )
    if scene_problem is not None:
        info.problems.append(scene_problem)
    if (why is not None and why != "missing") or (why is None and not isinstance(description, dict)):
        info.problems.append(f"{DESCRIPTION_FILE}: {why or 'not a JSON object'}")
    files: dict[str, dict] = {}  # role -> {"count", "bytes"}
    effects: Counter = Counter()
    kinds: dict[str, str] = {}  # material id -> kind: one entry per material
    noise = array("d")
    for shard, renders in counts.items():
        # One shard's records at a time: a record's files lie in its shard's folder
        # (record_problem), so distinct files are counted shard by shard.
        records, complete, started, problems = shard_records(layout, shard, renders)
        info.problems += problems
        info.shards_complete += complete
        info.shards_started += started
        shard_files: dict[str, dict] = {}
        for record in records:
            unsafe = [e["path"] for e in record["files"] if unsafe_entry(root, e["path"])]
            if unsafe:
                info.problems.append(f"record {record['id']}: {unsafe_entry(root, unsafe[0])}")
            info.recorded += 1
            for entry in record["files"]:
                shard_files.setdefault(entry["role"], {})[entry["path"]] = entry["bytes"]
            for name, on in _dict(record.get("effects")).items():
                effects[name] += bool(on)
            kinds[str(record.get("material_id", ""))] = str(_dict(record.get("material")).get("kind", "?"))
            stats = _dict(record.get("stats"))
            info.flagged += bool(stats.get("flagged"))
            info.rerendered += (_number(stats.get("attempts")) or 1) > 1
            if _number(stats.get("noise_relative")) is not None:
                noise.append(_number(stats["noise_relative"]))
        for role, paths in shard_files.items():
            total = files.setdefault(role, {"count": 0, "bytes": 0})
            total["count"] += len(paths)
            total["bytes"] += sum(paths.values())
    info.files = files
    info.effects = {name: effects[name] for name in sorted(effects, key=_effect_order)}
    info.kinds = dict(Counter(kinds.values()))
    info.noise_relative_median = statistics.median(noise) if noise else None
    info.manifest_records = manifest_record_count(layout, info.total_renders)
    if info.manifest_records is None and os.path.lexists(layout.manifest):
        try:
            read_manifest(layout, info.total_renders)
        except OSError as exc:
            info.problems.append(f"{MANIFEST_FILE}: {exc.strerror}")
    info.problems += [f"{rel}: {what}" for rel, what in symlinks_and_odd_files(root)]
    info.disk_bytes, info.temp_files = disk_usage(root)
    return info
