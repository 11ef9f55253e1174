"""The downstream study's figures, decision and pages: ``downstream.json``, ``report.md`` and
``downstream.png`` (network error against build time).

Every figure of a level is paired with the spec's level over the same held-out samples, with
the pixel study's two-level bootstrap crossed (pipeline.study.stats, ``shared_seeds``: the
held-out samples drawn, paired, and the training seeds drawn once per resample for all samples,
since a seed is one network whose error every sample shares): relMSE on the ball and on the
frame as ratios (level over spec), PSNR, SSIM, HDR-FLIP and the ball's luminance bias as
differences (level minus spec). The A/A row is the spec's level trained with
other seeds against it: what "no difference" looks like.

**The rule.** A level passes when its network is not worse beyond its interval in any figure:
the ball's relMSE ratio's lower bound at most 1, PSNR's and SSIM's upper bounds at least 0,
FLIP's lower bound at most 0. The decision is the cheapest passing level by build time (CPU
time; wall time where a GPU renders, :func:`cost_basis`); a level passing at most 1/3 of the
spec's build time is worth shipping as a spec. Passing says "not shown worse", which a study
too small to see a difference also says: the report gives each interval's far bound (the worst
the data allow) beside the verdict.
"""

from __future__ import annotations

import json
import os

import numpy as np

from pipeline.image.chart import BLUE, GREY, ORANGE, PURPLE, RED, chart, png
from pipeline.store.atomic import write_bytes_atomic, write_text_atomic
from pipeline.study.measure import FLOOR_FACTOR
from pipeline.study.request import machine_line
from pipeline.study.stats import CONFIDENCE, paired_ratio

#: (figure, row key, compared as): ratios where the figure is an error of linear radiance.
FIGURES = (
    ("relmse_ball", "relmse_ball", "ratio"),
    ("relmse_frame", "relmse_frame", "ratio"),
    ("psnr", "psnr", "difference"),
    ("ssim", "ssim", "difference"),
    ("flip", "flip", "difference"),
    ("bias_ball", "bias_ball", "difference"),
)
#: Figures the report gives but the rule does not read (a level's frame error, its bias).
NOT_RULED = ("relmse_frame", "bias_ball")
#: A passing level this cheap (build time over the spec's) is worth shipping as a spec.
SHIP_RATIO = 1 / 3
LOSS_COLOURS = (BLUE, RED, ORANGE, PURPLE)
REPORT_FILES = ("downstream.json", "report.md", "downstream.png")


def by_sample(scored: dict, runs: list, key: str) -> dict[str, list[float]]:
    """{sample id: [the figure of each run]} over ``runs`` (one value per training seed)."""
    out: dict[str, list[float]] = {}
    for run in runs:
        for row in scored[run]["rows"]:
            if row.get(key) is not None:
                out.setdefault(row["sample_id"], []).append(float(row[key]))
    return out


def compare(scored: dict, candidate: list, baseline: list) -> dict:
    """Every figure of ``candidate``'s runs against ``baseline``'s, paired by sample."""
    out = {}
    for name, key, how in FIGURES:
        a, b = by_sample(scored, candidate, key), by_sample(scored, baseline, key)
        iv = paired_ratio(a, b, ratio=how == "ratio", shared_seeds=True) if a and b else None
        out[name] = iv.to_dict() if iv else None
    return out


def means(scored: dict, runs: list) -> dict:
    """Each figure's mean over samples of each sample's mean over seeds."""
    out = {}
    for _name, key, _how in FIGURES:
        values = by_sample(scored, runs, key)
        out[key] = float(np.mean([np.mean(v) for v in values.values()])) if values else None
    return out


def misses(cmp: dict) -> list[str]:
    """The figures worse beyond their interval (empty: the level passes)."""
    out = []
    for name, _key, how in FIGURES:
        iv = cmp.get(name)
        if iv is None or name in NOT_RULED:
            continue
        lower_is_better = name in ("relmse_ball", "flip")
        worse = iv["lo"] > (1.0 if how == "ratio" else 0.0) if lower_is_better else iv["hi"] < 0.0
        if worse:
            out.append(name)
    return out


def compare_levels(scored: dict, loss: str, levels: list[int], spec_spp: int, repeats: int, builds: dict) -> dict:
    """Every level of ``loss`` against the spec's level (seeds 0..repeats-1), the A/A row (the
    spec's level, seeds repeats..2 repeats-1) and the cheapest passing level."""
    runs = [r for r in scored if r.loss == loss]
    base = [r for r in runs if r.spp == spec_spp and r.seed < repeats]
    rows = []
    for spp in levels:
        mine = [r for r in runs if r.spp == spp and r.seed < repeats]
        row = _level_row(scored, spp, mine, base, builds, spec_spp)
        rows.append(row)
    aa_runs = [r for r in runs if r.spp == spec_spp and r.seed >= repeats]
    aa = _level_row(scored, spec_spp, aa_runs, base, builds, spec_spp) if aa_runs else None
    if aa:
        aa["label"] = "A/A"
    passing = [row for row in rows if row["passes"]]
    cheapest = min(passing, key=lambda row: (row["build_cost"] or 0.0, row["spp"])) if passing else rows[0]
    return {"loss": loss, "levels": rows, "aa": aa, "cheapest": cheapest["spp"], "any_passes": bool(passing)}


def _level_row(scored, spp, mine, base, builds, spec_spp) -> dict:
    cmp = compare(scored, mine, base) if spp != spec_spp or set(mine) != set(base) else None
    failed = misses(cmp) if cmp else []
    cost, spec_cost = builds[spp]["build_cost"], builds[spec_spp]["build_cost"]
    return {
        "spp": spp,
        "label": f"{spp} spp" + (" (the spec's)" if spp == spec_spp else ""),
        "seeds": sorted(r.seed for r in mine),
        "build_cpu": builds[spp]["build_cpu"],
        "build_wall": builds[spp]["build_wall"],
        "build_cost": cost,
        "targets_relmse_ball": builds[spp].get("targets_relmse_ball"),
        "targets_bias_ball": builds[spp].get("targets_bias_ball"),
        "build_cost_ratio": cost / spec_cost if cost and spec_cost else None,
        "train_s": float(np.mean([scored[r]["train_s"] for r in mine])) if mine else None,
        "means": means(scored, mine),
        "vs_spec": cmp,
        "passes": not failed,
        "misses": failed,
    }


def results(
    req, spec, levels, scored, builds, references, baseline, test_ids, train_ids, flip, command, variant
) -> dict:
    """downstream.json's content: every loss's levels, the decision, the baselines and how."""
    spec_spp = spec.render.spp
    basis = cost_basis(variant)
    losses = [compare_levels(scored, loss, levels, spec_spp, req.repeats, builds) for loss in req.training.losses]
    first = losses[0]
    mean_rows = {"mean_image": {"rows": baseline, "train_s": 0.0}}
    base_runs = [r for r in scored if r.loss == first["loss"] and r.spp == spec_spp and r.seed < req.repeats]
    baseline_cmp = compare({**scored, **mean_rows}, ["mean_image"], base_runs)
    floors = [ref["floor"]["floor_ball"] for ref in references.values()]
    between = []  # each further loss against the first at the same level
    for other in losses[1:]:
        for row in other["levels"]:
            if row["seeds"]:
                mine = [r for r in scored if r.loss == other["loss"] and r.spp == row["spp"] and r.seed < req.repeats]
                theirs = [r for r in scored if r.loss == first["loss"] and r.spp == row["spp"] and r.seed < req.repeats]
                between.append(
                    {"loss": other["loss"], "spp": row["spp"], "vs": first["loss"], **compare(scored, mine, theirs)}
                )
    return {
        "command": command,
        "machine": machine_line(variant),
        "spec": req.spec,
        "spec_spp": spec_spp,
        "cost_basis": basis,
        "resolution": req.resolution or spec.render.resolution,
        "renders_per_build": builds[spec_spp]["renders"],
        "held_out": {"materials": len(test_ids), "samples": len(references), "training_materials": len(train_ids)},
        "reference_spp": req.reference_spp,
        "reference_floor_ball_mean": float(np.mean(floors)) if floors else None,
        # the least network error over the references' own: within FLOOR_FACTOR, they cannot tell levels apart
        "error_over_floor": _error_over_floor(losses, floors),
        "repeats": req.repeats,
        "training": req.training.to_dict(),
        "loss_space": "every loss is taken on the network's images: tone-mapped (Reinhard, the dataset's exposure) "
        "and sRGB-encoded, in [0, 1]; not on linear HDR radiance",
        "flip": flip,
        "confidence": CONFIDENCE,
        "losses": [_with_loss(x) for x in losses],
        "levels": [{**row, "loss": first["loss"]} for row in first["levels"]],
        "aa": first["aa"],
        "mean_image": {"means": means({**scored, **mean_rows}, ["mean_image"]), "vs_spec": baseline_cmp},
        "between_losses": between,
        "decision": decision(first, spec_spp, basis),
    }


def _error_over_floor(losses: list[dict], floors: list[float]) -> float | None:
    errors = [row["means"]["relmse_ball"] for x in losses for row in x["levels"] if row["means"]["relmse_ball"]]
    floor = float(np.mean(floors)) if floors else 0.0
    return min(errors) / floor if errors and floor > 0 else None


def cost_basis(variant: str) -> str:
    """The build time a study compares: CPU time, or wall time where the GPU renders."""
    return "wall" if variant.startswith("cuda") else "CPU"


def _with_loss(x: dict) -> dict:
    return {**x, "levels": [{**row, "loss": x["loss"]} for row in x["levels"]]}


def decision(first: dict, spec_spp: int, basis: str = "CPU") -> dict:
    """The cheapest level whose network is not worse beyond its interval, and what to do;
    ``basis``: the build time compared (CPU; wall on a GPU, whose time CPU time misses)."""
    rows = {row["spp"]: row for row in first["levels"]}
    pick = rows[first["cheapest"]]
    if first["any_passes"] and pick["spp"] != spec_spp:
        ratio = pick["build_cost_ratio"]
        ship = ratio is not None and ratio <= SHIP_RATIO
        worst = (pick["vs_spec"] or {}).get("relmse_ball") or {}
        at = f"at {ratio:.2f}x the spec's build {basis} time" if ratio is not None else "(build time not measured)"
        verdict = (
            f"{pick['spp']} spp passes ({first['loss']}): its network is not worse beyond its interval in any figure, "
            f"{at}; relMSE ratio {worst.get('value', float('nan')):.2f}, at worst {worst.get('hi', float('nan')):.2f}. "
            + (
                f"At most {SHIP_RATIO:.2f}x: worth a spec of its own."
                if ship
                else f"Above {SHIP_RATIO:.2f}x: not worth a spec."
            )
        )
        return {"level": pick["spp"], "passes": True, "ship": ship, "build_cost_ratio": ratio, "verdict": verdict}
    missed = [
        f"{row['spp']} spp: " + ", ".join(f"{name} {_iv_text(row['vs_spec'][name])}" for name in row["misses"])
        for row in first["levels"]
        if row["spp"] != spec_spp and row["misses"]
    ]
    verdict = (
        f"no cheaper level passes ({first['loss']}): " + "; ".join(missed) if missed else "no cheaper level studied"
    )
    return {"level": spec_spp, "passes": False, "ship": False, "build_cost_ratio": 1.0, "verdict": verdict}


def _floor_text(ratio: float | None) -> str:
    if ratio is None:
        return "the networks' error against it not measured"
    if ratio < FLOOR_FACTOR:
        return f"only {ratio:.1f}x below the least network error: too noisy to tell levels apart, raise --reference-spp"
    return f"{ratio:.0f}x below the least network error"


def _iv_text(iv: dict | None, spec: str = ".3g") -> str:
    if not iv:
        return "-"
    return f"{format(iv['value'], spec)} [{format(iv['lo'], spec)}, {format(iv['hi'], spec)}]"


def _fmt(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _percent(value) -> str:
    return "-" if value is None else f"{100 * value:+.1f}"


def _percent_iv(iv: dict | None) -> str:
    if not iv:
        return "-"
    return f"{100 * iv['value']:+.1f} [{100 * iv['lo']:+.1f}, {100 * iv['hi']:+.1f}]"


def markdown(result: dict) -> str:
    """report.md: the command, the machine, the decision, each loss's levels, the baselines."""
    pct = int(round(100 * result["confidence"]))
    lines = [
        "# What the network's accuracy costs in build time",
        "",
        f"`{result['command']}`" if result["command"] else "",
        "",
        f"Machine: {result['machine']}. Spec `{result['spec']}` ({result['renders_per_build']} renders a build, "
        f"{result['resolution']} px, its own {result['spec_spp']} spp); {result['held_out']['samples']} held-out "
        f"samples ({result['held_out']['materials']} materials) scored against references at "
        f"{result['reference_spp']} spp (two halves; their own relMSE on the ball: "
        f"{_fmt(result['reference_floor_ball_mean'], '.3g')}, {_floor_text(result['error_over_floor'])}); "
        f"{result['repeats']} training seeds a level; "
        f"training: {json.dumps(result['training'])}. {result['loss_space']}.",
        "",
        "## Decision",
        "",
        result["decision"]["verdict"],
        "",
        f"Intervals are paired {pct}% bootstrap intervals over held-out samples and training seeds, against the "
        "spec's level: ratios for relMSE (below 1 is better), differences for PSNR and SSIM (above 0 is better) "
        "and HDR-FLIP (below 0 is better). A level passes when no figure is worse beyond its interval. Bias: the "
        "ball's mean luminance against the reference's, in percent (reported, not ruled). Targets' relMSE: the "
        "level's own renders of the held-out samples against the references, the noise its networks learn from.",
    ]
    for x in result["losses"]:
        lines += ["", f"## Loss {x['loss']}", "", _level_table(x["levels"] + ([x["aa"]] if x["aa"] else []))]
    if result["between_losses"]:
        lines += ["", "## Losses against each other (same level, same seeds)", ""]
        lines += [
            "| loss | vs | spp | relMSE ratio (ball) | PSNR diff | SSIM diff | FLIP diff | bias diff % |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for b in result["between_losses"]:
            lines.append(
                f"| {b['loss']} | {b['vs']} | {b['spp']} | {_iv_text(b['relmse_ball'])} | {_iv_text(b['psnr'])} | "
                f"{_iv_text(b['ssim'])} | {_iv_text(b['flip'])} | {_percent_iv(b.get('bias_ball'))} |"
            )
    mi = result["mean_image"]
    lines += [
        "",
        "## Baseline",
        "",
        f"The mean training image (the spec's level): relMSE on the ball {_fmt(mi['means']['relmse_ball'], '.4g')}, "
        f"PSNR {_fmt(mi['means']['psnr'], '.2f')} dB, SSIM {_fmt(mi['means']['ssim'], '.3f')}; against the spec's "
        f"networks: relMSE ratio {_iv_text((mi['vs_spec'] or {}).get('relmse_ball'))}.",
        "",
        "![network error against build time](downstream.png)",
        "",
    ]
    return "\n".join(lines)


def _level_table(rows: list[dict]) -> str:
    head = (
        "| level | build CPU s | wall s | x spec | targets' relMSE | train s | relMSE (ball) | ratio | PSNR dB | diff | SSIM | diff | FLIP | diff "
        "| bias % | diff | passes |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    out = [head]
    for row in (row for row in rows if row["seeds"]):  # a level this loss did not train at: no row
        cmp, mean = row["vs_spec"] or {}, row["means"]
        out.append(
            f"| {row['label']} | {_fmt(row['build_cpu'], '.0f')} | {_fmt(row['build_wall'], '.0f')} | "
            f"{_fmt(row['build_cost_ratio'], '.2f')} | {_fmt(row['targets_relmse_ball'], '.4g')} | "
            f"{_fmt(row['train_s'], '.1f')} | {_fmt(mean['relmse_ball'], '.4g')} | {_iv_text(cmp.get('relmse_ball'))} | "
            f"{_fmt(mean['psnr'], '.2f')} | {_iv_text(cmp.get('psnr'), '.2f')} | {_fmt(mean['ssim'], '.3f')} | "
            f"{_iv_text(cmp.get('ssim'), '.3f')} | {_fmt(mean['flip'], '.4f')} | {_iv_text(cmp.get('flip'), '.4f')} | "
            f"{_percent(mean.get('bias_ball'))} | {_percent_iv(cmp.get('bias_ball'))} | "
            + ("-" if not cmp else ("yes" if row["passes"] else "no: " + ", ".join(row["misses"])))
            + " |"
        )
    return "\n".join(out)


def plot_png(result: dict) -> bytes:
    """Network relMSE on the ball (ratio to the spec's level, with its interval) against the
    build's CPU seconds, one series per loss; the A/A row in grey."""
    series = []
    for colour, x in zip(LOSS_COLOURS, result["losses"]):
        points = []
        for row in x["levels"]:
            if row["build_cost"] is None or not row["seeds"]:
                continue
            iv = (row["vs_spec"] or {}).get("relmse_ball")
            points.append(
                (row["build_cost"], 1.0, 1.0, 1.0)
                if iv is None
                else (row["build_cost"], iv["value"], iv["lo"], iv["hi"])
            )
        series.append((f"{x['loss']}", colour, sorted(points)))
    aa = result["aa"]
    if aa and aa["vs_spec"] and aa["vs_spec"]["relmse_ball"] and aa["build_cost"]:
        iv = aa["vs_spec"]["relmse_ball"]
        series.append(("A/A (spec, other seeds)", GREY, [(aa["build_cost"], iv["value"], iv["lo"], iv["hi"])]))
    image = chart(
        series,
        "network relMSE on the ball / the spec's level's, 95% intervals",
        f"build {result['cost_basis']} seconds (log)",
        log_x=True,
    )
    return png(image)


def write(out: str, result: dict) -> None:
    write_text_atomic(os.path.join(out, "downstream.json"), json.dumps(result, indent=1, sort_keys=True) + "\n")
    write_text_atomic(os.path.join(out, "report.md"), markdown(result))
    write_bytes_atomic(os.path.join(out, "downstream.png"), plot_png(result))
