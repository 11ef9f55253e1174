"""The study's outputs: study.json, study.csv, pareto.png, report.md, and the recipes the
evidence supports.

Per configuration over the samples and seeds: the median and mean relMSE on the ball (and
per material class), the frame's relMSE, PSNR/SSIM/HDR-FLIP means, the firefly share, the
ball's mean-luminance bias, spp used, and CPU/wall seconds (the render alone, and
``build_cpu_s``: what a build pays per render, pipeline/study/run.py). A configuration with
any row below the reference's resolution is reported but not ranked.

Every configuration is compared with the spec's recipe by paired ratios with 95%
bootstrap intervals over samples and seeds (:mod:`pipeline.study.stats`): relMSE on the
ball (the ranking figure), per material class, on the frame, the fireflies' part of the
error on the ball and on the frame, and build-level CPU time. The A/A row is the recipe
against itself with other seeds: the noise floor.

**paper-fast**: among the ranked, byte-reproducible configurations of an unbiased family
(configs.UNBIASED_FAMILIES) that the rule of :func:`pipeline.study.stats.decide` lets
replace the recipe (upper bound of the ball's error ratio <= 1, no material class worse
beyond its interval, frame and fireflies not worse beyond theirs), the one with the lowest
build-level CPU ratio; ratios within 5% count as a tie, broken by the lower upper bound of
the error ratio. The same rule picks the best denoised recipe, whose bias is reported
beside it.

The figures and recipes are made in pipeline.study.evidence, pareto.png in
pipeline.study.pareto_plot; this module writes the files.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os

from pipeline.store.atomic import write_bytes_atomic, write_text_atomic
from pipeline.study import stats
from pipeline.study.configs import aa_name, paper_name
from pipeline.study.evidence import (
    comparisons,
    family_knees,
    interval_text,
    ladder_slope,
    number_text,
    pareto_front,
    recommend,
    summarise,
    worst_class,
)
from pipeline.study.pareto_plot import pareto_png

# --------------------------------------------------------------------------- files


def write_csv(path: str, rows: list[dict]) -> None:
    columns = []
    for r in rows:
        columns.extend(k for k in r if k not in columns)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, buf.getvalue())


def ranked_text(s: dict) -> str:
    return "yes" if s["ranked"] else f"no ({s['below_resolution']} below floor)"


def claim_line(meta: dict, config: str, cmp: dict) -> str:
    """One recipe's comparison with the recipe, as one line: what docs and spec comments
    quote verbatim (tests/test_study.py checks they do)."""
    req = meta["request"]
    worst = worst_class(cmp)
    verdict = "replaces the recipe" if cmp["replaces"] else f"does not replace the recipe ({cmp['why']})"
    return (
        f"{config} against {meta['recipe_name']} ({req['resolution']}x{req['resolution']}, "
        f"{len(meta['selection'])} samples x {cmp['repeats']} seeds, 95% intervals): "
        f"error ratio on the ball {interval_text(cmp['ball'])}; "
        + (f"worst class {worst[0]} {interval_text(worst[1])}; " if worst else "")
        + f"frame {interval_text(cmp['frame'])}; fireflies ball {interval_text(cmp['fireflies_ball'])}, "
        f"frame {interval_text(cmp['fireflies_frame'])}; build-level CPU ratio {interval_text(cmp['cpu'])}: {verdict}"
    )


def decision_section(meta: dict, summary: list[dict], cmps: dict, knees: dict) -> list[str]:
    aa = aa_name(meta["recipe"]["spp"])
    order = [aa] + [s["config"] for s in summary if s["config"] in cmps and s["config"] != aa]
    fam = {s["config"]: s["family"] for s in summary}
    L = [
        "## Against the recipe, with 95% intervals",
        "",
        f"Each ratio: mean over samples of each sample's mean over its {meta['repeats']} seeds, this "
        f"configuration over the recipe ({meta['recipe_name']}); interval: 95% two-level bootstrap "
        f"(samples, then seeds; {stats.BOOTSTRAP_RESAMPLES} resamples, seed {stats.BOOTSTRAP_SEED}). "
        "The A/A row is the recipe against itself with other seeds: the noise floor. Rule: a configuration "
        "replaces the recipe only where the upper bound of its ball ratio is <= 1, no material class's "
        "lower bound is > 1, and neither its frame error nor its fireflies are worse beyond their "
        "intervals (flags). CPU: build level (render + post-process + scene load / lightings per material "
        "+ kernel compilation as a build pays it).",
        "",
        "| config | family | relMSE ball ratio | worst class | frame ratio | fireflies ball | fireflies frame "
        "| CPU ratio (build) | efficiency | flags | replaces the recipe |",
        "|" + "---|" * 11,
    ]
    for n in order:
        c = cmps[n]
        worst = worst_class(c)
        eff = stats.efficiency(c)
        L.append(
            f"| {n} | {fam.get(n, '-')} | {interval_text(c['ball'])} | "
            + (f"{worst[0]} {interval_text(worst[1])}" if worst else "-")
            + f" | {interval_text(c['frame'])} | {interval_text(c['fireflies_ball'])} | {interval_text(c['fireflies_frame'])} | "
            f"{interval_text(c['cpu'])} | {number_text(eff, '.2f')} | {', '.join(c['flags']) or '-'} | "
            f"{'**yes**' if c['replaces'] else 'no: ' + c['why']} |"
        )
    L += [
        "",
        "Efficiency: 1 / (relMSE ratio x CPU ratio), the recipe's = 1. Where each family stops paying "
        "(its most efficient configuration measured; past it, more CPU time lowers the error less "
        "than in proportion):",
        "",
        "| family | stops paying at | efficiency | configurations measured |",
        "|---|---|---|---|",
    ]
    for f, k in knees.items():
        L.append(f"| {f} | {k['config']} | {number_text(k['efficiency'], '.2f')} | {k['measured']} |")
    L += ["", "### Claims (quoted verbatim by docs/accuracy.md and spec comments)", ""]
    L += [f"- {claim_line(meta, n, cmps[n])}" for n in order]
    L.append("")
    return L


def report_markdown(
    meta: dict,
    summary: list[dict],
    recs: dict,
    front: list[str],
    slopes: dict,
    rows: list[dict] = (),
    cmps: dict | None = None,
    knees: dict | None = None,
) -> str:
    L = [
        *_head_section(meta, recs),
        *decision_section(meta, summary, cmps or {}, knees or {}),
        f"Independent-sampler ladder: log-log slope of median relMSE vs spp {number_text(slopes.get('all'), '.2f')} "
        "(1/spp is -1); per class: "
        + ", ".join(f"{c} {number_text(v, '.2f')}" for c, v in slopes.items() if c != "all"),
        *_samples_section(meta),
        *_configs_section(summary, front),
        *_fireflies_section(meta, recs, rows),
        *_biased_section(summary, recs),
        *_adaptive_section(summary),
        *_classes_section(summary),
    ]
    return "\n".join(L) + "\n"


def _head_section(meta: dict, recs: dict) -> list[str]:
    """The title, the command, machine and set-up, and the recommendations."""
    req = meta["request"]
    L = [
        f"# Accuracy study: {os.path.basename(meta['spec'])}",
        "",
        f"Written by `{meta['command']}` on {meta['date']}.",
        "",
        f"Machine: {meta['machine']}.",
        "",
        f"{len(meta['selection'])} samples x {meta.get('repeats', 1)} seeds, {req['resolution']}x{req['resolution']}, "
        f"references at "
        f"{req['reference_spp']} spp (two halves), variant {meta['variant']}, {meta['cpu_count']} CPUs. "
        f"relMSE = mean (x - ref)^2 / (ref^2 + {meta['relmse_eps']}) over the ball's pixels and channels. "
        f"A configuration with any sample within {meta['floor_factor']:g}x of its reference's floor is marked "
        "and not ranked. CPU and wall seconds: the render alone, kernels warm, plus any post-process; "
        "build CPU s: what a build pays per render (also the scene load / lightings per material and "
        "kernel compilation as a build pays it). Medians over samples and seeds.",
        "",
        "## Recommendations",
        "",
    ]
    for key, label in (
        ("paper", "paper recipe"),
        ("paper_fast", "paper-fast (no denoiser, unbiased)"),
        ("denoised", "denoised"),
    ):
        rec = recs.get(key)
        L.append(
            f"- **{label}**: "
            + (f"`{rec['config']}`: {rec['note']}" if rec else "none of the measured configurations qualifies")
        )
    L.append("")
    return L


def _samples_section(meta: dict) -> list[str]:
    L = [
        "",
        "## Samples",
        "",
        "| sample | class | sun elevation | turbidity | roughness | corner | floor (ball) |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in meta["selection"]:
        f = meta["references"][s["sample_id"]]
        L.append(
            f"| {s['sample_id']} | {s['material_class']} | {s['elevation_deg']:.1f} | {s['turbidity']:.2f} | "
            f"{s['roughness']:.2f} | {'/'.join(s['corner'])} | {f['floor_ball']:.2e} |"
        )
    return L


def _configs_section(summary: list[dict], front: list[str]) -> list[str]:
    L = [
        "",
        "## Every configuration",
        "",
        "| config | family | spp used | relMSE ball (median) | relMSE frame | w/o fireflies | firefly share | "
        "PSNR | SSIM | FLIP | ball bias | CPU s | build CPU s | wall s | ranked |",
        "|" + "---|" * 15,
    ]
    for s in summary:
        spp = number_text(s["spp_used_mean"], ".0f") + (
            "" if s["spp_used_min"] == s["spp_used_max"] else f" ({s['spp_used_min']}-{s['spp_used_max']})"
        )
        L.append(
            f"| {s['config']}{' (front)' if s['config'] in front else ''}{'' if s['reproducible'] else ' (not reproducible)'} | {s['family']} | {spp} | "
            f"{number_text(s['relmse_ball_median'])} | {number_text(s['relmse_frame_median'])} | "
            f"{number_text(s['relmse_ball_no_fireflies_median'])} | {number_text(s['firefly_share_median'], '.2f')} | "
            f"{number_text(s['psnr_mean'], '.2f')} | {number_text(s['ssim_mean'], '.4f')} | {number_text(s['flip_mean'], '.4f')} | "
            f"{number_text(None if s['bias_ball_mean'] is None else 100 * s['bias_ball_mean'], '+.2f')}% | "
            f"{number_text(s['cpu_s_median'])} | {number_text(s['build_cpu_s_median'])} | {number_text(s['wall_s_median'])} | "
            f"{ranked_text(s)} |"
        )
    return L


def _fireflies_section(meta: dict, recs: dict, rows: list[dict]) -> list[str]:
    paper_name_ = recs.get("paper", {}).get("config")
    L = [
        "",
        f"## Fireflies at the recipe ({paper_name_})",
        "",
        f"relMSE on the ball with and without its brightest {100 * meta['firefly_share']:g}% of pixels (by the "
        "render's luminance), each seed.",
        "",
        "| sample | seed | class | relMSE | without the brightest | their share |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["config"] == paper_name_:
            L.append(
                f"| {r['sample_id']} | {r.get('repeat', 0)} | {r['material_class']} | {r['relmse_ball']:.3g} | "
                f"{r['relmse_ball_no_fireflies']:.3g} | {r['firefly_share']:.2f} |"
            )
    return L


def _biased_section(summary: list[dict], recs: dict) -> list[str]:
    L = [
        "",
        "## Biased remedies: what they cost in light",
        "",
        "| config | ball bias (mean) | largest \\|bias\\| of a sample | relMSE ball (median) | CPU ratio to paper |",
        "|---|---|---|---|---|",
    ]
    paper = next((s for s in summary if s["config"] == recs.get("paper", {}).get("config")), None)
    for s in summary:
        if s["family"] in ("clamp", "robust", "denoise", "depth") and s["bias_ball_mean"] is not None:
            ratio = s["build_cpu_s_sum"] / paper["build_cpu_s_sum"] if paper else None
            L.append(
                f"| {s['config']} | {100 * s['bias_ball_mean']:+.2f}% | {100 * s['bias_ball_abs_max']:.2f}% | "
                f"{number_text(s['relmse_ball_median'])} | {number_text(ratio, '.2f')} |"
            )
    return L


def _adaptive_section(summary: list[dict]) -> list[str]:
    L = [
        "",
        "## Adaptive rendering",
        "",
        "| config | spp used: mean (min-max) | estimate at stop (mean) | relMSE ball (median) | "
        "sqrt(relMSE) (median) |",
        "|---|---|---|---|---|",
    ]
    for s in summary:
        if s["family"] == "adaptive":
            L.append(
                f"| {s['config']} | {s['spp_used_mean']:.0f} ({s['spp_used_min']}-{s['spp_used_max']}) | "
                f"{number_text(s['error_estimate_mean'])} | {number_text(s['relmse_ball_median'])} | "
                f"{number_text(math.sqrt(s['relmse_ball_median']))} |"
            )
    return L


def _classes_section(summary: list[dict]) -> list[str]:
    classes = sorted({c for s in summary for c in s["classes"]})
    L = [
        "",
        "## Per material class (mean relMSE on the ball)",
        "",
        "| config | " + " | ".join(classes) + " |",
        "|---|" + "---|" * len(classes),
    ]
    for s in summary:
        if s["family"] in ("ladder", "aa", "denoise", "adaptive", "samplers", "passes"):
            L.append(
                f"| {s['config']} | "
                + " | ".join(number_text(s["classes"].get(c, {}).get("relmse_ball_mean")) for c in classes)
                + " |"
            )
    return L


def write_outputs(out: str, meta: dict, rows: list[dict], configs) -> dict:
    meta = {**meta, "recipe_name": paper_name(meta["recipe"]["spp"]), "repeats": meta.get("repeats", 1)}
    summary = summarise(rows, configs)
    cmps = comparisons(rows, summary, meta["recipe"]["spp"])
    recs = recommend(summary, meta["recipe"]["spp"], cmps)
    knees = family_knees(summary, cmps)
    front = pareto_front(summary)
    classes = sorted({r["material_class"] for r in rows})
    slopes = {"all": ladder_slope(summary), **{c: ladder_slope(summary, c) for c in classes}}
    doc = {
        "meta": meta,
        "summary": summary,
        "comparisons": cmps,
        "claims": {n: claim_line(meta, n, c) for n, c in cmps.items()},
        "stops_paying": knees,
        "pareto_front": front,
        "recommendations": recs,
        "ladder_slopes": slopes,
        "rows": rows,
    }
    write_text_atomic(os.path.join(out, "study.json"), json.dumps(doc, indent=1, allow_nan=False) + "\n")
    write_csv(os.path.join(out, "study.csv"), rows)
    write_bytes_atomic(os.path.join(out, "pareto.png"), pareto_png(summary, cmps, recs, knees))
    write_text_atomic(
        os.path.join(out, "report.md"), report_markdown(meta, summary, recs, front, slopes, rows, cmps, knees)
    )
    return recs
