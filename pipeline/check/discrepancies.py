"""One record against what it must agree with: its plan and spec (:func:`plan_discrepancies`),
its files' EXR headers, its render's pixels and statistics, the render policy; and
:func:`record_ok`, whether repair may keep a record."""

from __future__ import annotations

import math

from pipeline.check.inspect import FileFacts, render_value_issues
from pipeline.check.loading import State
from pipeline.dataset.record import lighting_discrepancies, model_record
from pipeline.dataset.spec import DEFAULT_OBJECTS
from pipeline.errors import short_repr
from pipeline.image.stats import is_bad
from pipeline.store.layout import Layout
from pipeline.store.record_fields import field_type_problem
from pipeline.store.records import RUN_DEPENDENT_STATS

#: Relative tolerance for recomputed float statistics (same pixels, same float64 sums).
STATS_RTOL = 1e-6
#: Keys of a render's statistics recomputed from its pixels (pipeline.image.stats.render_stats).
PIXEL_STATS = ("min", "max", "mean", "nan", "inf", "negative")


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


def plan_discrepancies(record: dict, sample, state: State) -> list[str]:
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
        *((f"lighting.requested.{key}", value) for key, value in sample.requested_lighting().items()),
        ("material.kind", sample.kind),
    ]
    if spec is not None:  # absent where the spec names the shaderball alone (pipeline.run.shard.object_record)
        wanted.append(("object.name", None if spec.scene.objects == DEFAULT_OBJECTS else sample.object_name))
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


def header_discrepancies(record: dict, render: FileFacts | None, maps: FileFacts | None) -> list[str]:
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
            for key in ("elevation_deg", "azimuth_deg", "turbidity", "source", "sha256", "rotation_deg", "scale")
        ]
    maps_meta = maps.meta if maps is not None else None
    if maps_meta is not None:
        checks += [
            ("maps", "material_id", record.get("material_id"), maps_meta.get("id")),
            ("maps", "material", record.get("material"), maps_meta.get("material")),
        ]
    out = []
    for which, key, mine, theirs in checks:
        for sub in diff_keys(mine, theirs):
            dotted = key if sub == "(record)" else f"{key}.{sub}"
            out.append(
                f"{dotted} is {short_repr(_get_path(mine, sub), 123)}, the {which} file's header says "
                f"{short_repr(_get_path(theirs, sub), 123)}"
            )
    return out


def _get_path(value, dotted: str):
    return value if dotted == "(record)" else _get(value, dotted)


def stats_discrepancies(record: dict, render: FileFacts) -> list[str]:
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


def policy_problems(record: dict, render: FileFacts) -> list[tuple[str, str]]:
    """Bad pixels are allowed only in a render the render policy flagged."""
    stats, pixels = record.get("stats") or {}, render.pixel_stats
    if pixels is None or (isinstance(stats, dict) and stats.get("flagged")):
        return []
    return [
        (kind, f"{text} in a render not flagged by the render policy") for kind, text in render_value_issues(pixels)
    ]


def diff_keys(a, b, prefix: str = "") -> list[str]:
    """Dotted paths where two JSON values differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += diff_keys(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [prefix.rstrip(".") or "(record)"]


def record_ok(record: dict | None, sample, state: State) -> bool:
    """A record repair may keep: plan, headers, stats and its render file all agree."""
    if not isinstance(record, dict) or field_type_problem(record):
        return False
    entries = {e.get("role"): e for e in record.get("files", []) if isinstance(e, dict)}
    render_entry = entries.get("render")
    if render_entry is None or plan_discrepancies(record, sample, state):
        return False
    render = state.facts.get(render_entry.get("path"))
    if render is None or not render.content_ok or render.sha256 is None:
        return False
    if (render.size, render.sha256) != (render_entry.get("bytes"), render_entry.get("sha256")):
        return False
    maps = state.facts.get((entries.get("maps") or {}).get("path"))
    maps = maps if maps is not None and maps.content_ok and maps.decoded else None
    return not (
        header_discrepancies(record, render, maps)
        or stats_discrepancies(record, render)
        or policy_problems(record, render)
    )


def copy_faulty(record, sample, state: State, fast: bool) -> bool:
    """Whether one copy of a record is itself wrong (not merely different from another)."""
    if sample is None or not isinstance(record, dict):
        return True
    if fast:
        return bool(plan_discrepancies(record, sample, state))
    return not record_ok(record, sample, state)
