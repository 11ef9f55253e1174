"""evaluate's scores by scene: per object, seen against held-out objects (a run trained with
``--held-out-objects``), and seen against held-out map rotations (``--held-out-rotations``),
each mean with its 95% interval as evaluate gives the material classes'
(:func:`pipeline.neural.report.bootstrap_ci95`: materials resampled, since a material's
lightings are correlated)."""

from __future__ import annotations

import numpy as np

from pipeline.neural.report import bootstrap_ci95
from pipeline.neural.scene_inputs import SampleScene

#: The figures reported per group.
GROUP_METRICS = ("relmse", "psnr", "ssim")
#: The methods compared per group (where a row holds them).
GROUP_METHODS = ("network", "mean_image")
SEEN, HELD_OUT = "seen", "held-out"
#: The keys :func:`scene_fields` adds to a row (not methods: method_means leaves them out).
SCENE_KEYS = ("object", "environment", "object_group", "rotation_group")


def scene_fields(record: dict, split: dict) -> dict:
    """A row's scene: its object, and where the run's ``split`` (config.json's) held objects or
    rotations out, which group the sample is in."""
    scene = SampleScene.of(record)
    fields = {"object": scene.object}
    if scene.light_source != "sun_sky":
        fields["environment"] = scene.environment_file
    if split.get("held_out_objects"):
        fields["object_group"] = HELD_OUT if scene.object in split["held_out_objects"] else SEEN
    rotations = split.get("held_out_rotations")
    if rotations and scene.rotation_deg is not None:
        inside = float(rotations[0]) <= scene.rotation_deg <= float(rotations[1])
        fields["rotation_group"] = HELD_OUT if inside else SEEN
    return fields


def group_means(rows: list[dict], key: str) -> dict:
    """{group: {method: {metric: mean, ci95: {metric: [lo, hi] or None}, samples, materials}}} of
    the rows that have ``key``, grouped by its value (sorted)."""
    out = {}
    for name in sorted({r[key] for r in rows if key in r}):
        members = [r for r in rows if r.get(key) == name]
        out[name] = {}
        for method in GROUP_METHODS:
            have = [r for r in members if method in r]
            if not have:
                continue
            groups = [r["material_id"] for r in have]
            entry = {}
            for metric in GROUP_METRICS:
                values = [r[method].get(metric) for r in have]
                ok = all(v is not None and np.isfinite(v) for v in values)
                entry[metric] = float(np.mean(values)) if ok else None
            entry["ci95"] = {m: bootstrap_ci95([r[method].get(m) for r in have], groups) for m in GROUP_METRICS}
            entry["samples"], entry["materials"] = len(have), len(set(groups))
            out[name][method] = entry
    return out


def scene_results(rows: list[dict]) -> dict:
    """results.json's groups: ``by_object`` always; ``by_object_group`` and ``by_rotation_group``
    where the rows carry them."""
    results = {"by_object": group_means(rows, "object")}
    for key in ("object_group", "rotation_group"):
        if any(key in r for r in rows):
            results[f"by_{key}"] = group_means(rows, key)
    return results


def _cell(entry: dict, metric: str, spec: str) -> str:
    value, ci = entry.get(metric), (entry.get("ci95") or {}).get(metric)
    if value is None:
        return "-"
    return f"{value:{spec}} [{ci[0]:{spec}}, {ci[1]:{spec}}]" if ci else f"{value:{spec}}"


def scene_table(results: dict, objects_held: list | None = None) -> str:
    """Markdown: one table per grouping of :func:`scene_results`, network and mean image."""
    held = set(objects_held or ())
    titles = {
        "by_object": "Per object" + (" (held out: " + ", ".join(sorted(held)) + ")" if held else ""),
        "by_object_group": "Seen and held-out objects",
        "by_rotation_group": "Seen and held-out map rotations",
    }
    lines = []
    for key, title in titles.items():
        if key not in results:
            continue
        lines += [
            "",
            f"### {title}",
            "",
            "| group | method | relMSE [95%] | PSNR (dB) [95%] | SSIM [95%] | samples (materials) |",
            "|---|---|---|---|---|---|",
        ]
        for name, methods in results[key].items():
            label = f"{name} (held out)" if name in held else name
            for method, entry in methods.items():
                cells = [_cell(entry, "relmse", ".4g"), _cell(entry, "psnr", ".2f"), _cell(entry, "ssim", ".4f")]
                lines.append(
                    f"| {label} | {method} | {' | '.join(cells)} | {entry['samples']} ({entry['materials']}) |"
                )
    if lines:
        lines += ["", "95% intervals: percentile bootstrap over the group's materials (2000 resamples, fixed seed)."]
    return "\n".join(lines) + "\n"
