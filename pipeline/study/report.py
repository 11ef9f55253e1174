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
"""

from __future__ import annotations

import csv
import io
import json
import math
import os

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from pipeline.store.atomic import write_bytes_atomic, write_text_atomic
from pipeline.study import stats
from pipeline.study.configs import UNBIASED_FAMILIES, aa_name, paper_name

COLOURS = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
]


def _values(rows, key):
    return [r[key] for r in rows if r.get(key) is not None]


def _median(values):
    return float(np.median(values)) if values else None


def _mean(values):
    return float(np.mean(values)) if values else None


def summarise(rows: list[dict], configs) -> list[dict]:
    by = {}
    for r in rows:
        by.setdefault(r["config"], []).append(r)
    out = []
    for c in configs:
        rs = by.get(c.name, [])
        if not rs:
            continue
        classes = {}
        for cls in sorted({r["material_class"] for r in rs}):
            cr = [r for r in rs if r["material_class"] == cls]
            classes[cls] = {
                "relmse_ball_mean": _mean(_values(cr, "relmse_ball")),
                "cpu_s_median": _median(_values(cr, "build_cpu_s")),
            }
        biases = _values(rs, "bias_ball")
        out.append(
            {
                "config": c.name,
                "family": c.family,
                "post": c.post,
                "spp": c.spp,
                "spp_used_mean": _mean(_values(rs, "spp_used")),
                "spp_used_min": min(_values(rs, "spp_used")),
                "spp_used_max": max(_values(rs, "spp_used")),
                "samples": len({r["sample_id"] for r in rs}),
                "rows": len(rs),
                "relmse_ball_median": _median(_values(rs, "relmse_ball")),
                "relmse_ball_mean": _mean(_values(rs, "relmse_ball")),
                "relmse_frame_median": _median(_values(rs, "relmse_frame")),
                "relmse_ball_no_fireflies_median": _median(_values(rs, "relmse_ball_no_fireflies")),
                "firefly_share_median": _median(_values(rs, "firefly_share")),
                "psnr_mean": _mean(_values(rs, "psnr")),
                "ssim_mean": _mean(_values(rs, "ssim")),
                "flip_mean": _mean(_values(rs, "flip")),
                "bias_ball_mean": _mean(biases),
                "bias_ball_abs_max": max((abs(b) for b in biases), default=None),
                "bias_z_mean": _mean(_values(rs, "bias_z")),
                "error_estimate_mean": _mean(_values(rs, "error_estimate")),
                "cpu_s_sum": float(sum(_values(rs, "cpu_s"))),
                "cpu_s_median": _median(_values(rs, "cpu_s")),
                "build_cpu_s_sum": float(sum(_values(rs, "build_cpu_s"))),
                "build_cpu_s_median": _median(_values(rs, "build_cpu_s")),
                "load_cpu_s_median": _median(_values(rs, "load_cpu_s")),
                "compile_s_sum": float(sum(_values(rs, "compile_s"))),
                "wall_s_median": _median(_values(rs, "wall_s")),
                "reproducible": reproducible(c, rs),
                "below_resolution": sum(1 for r in rs if r["below_resolution"]),
                "ranked": not any(r["below_resolution"] for r in rs),
                "classes": classes,
            }
        )
    return out


def _power_of_two(n: int) -> bool:
    return n > 0 and n & (n - 1) == 0


def reproducible(config, rows: list[dict]) -> bool:
    """Byte-reproducible with several render threads (docs/build.md): every pass a power of
    two after the sampler's rounding. The independent sampler's passes always are; another
    sampler's configuration counts when it is one power-of-two pass rounded to a power of
    two (measured: orthogonal at 32 -> 49 spp gave 0-2 differing pixels between repeats)."""
    if config.changes.get("sampler", "independent") == "independent":
        return True
    if config.passes:  # equal passes, each a power of two taken exactly (no rounding)
        return all(_power_of_two(p) for p in config.passes) and all(r["spp_used"] == config.spp for r in rows)
    return _power_of_two(config.spp) and all(_power_of_two(r["spp_used"]) for r in rows)


def pareto_front(summary: list[dict]) -> list[str]:
    ranked = sorted(
        (s for s in summary if s["ranked"] and s["family"] != "aa"),
        key=lambda s: (s["build_cpu_s_sum"], s["relmse_ball_median"]),
    )
    front, best = [], math.inf
    for s in ranked:
        if s["relmse_ball_median"] < best:
            front.append(s["config"])
            best = s["relmse_ball_median"]
    return front


#: Relative CPU-time difference below which two recipes count as equally fast.
TIME_TIE = 0.05


def comparisons(rows: list[dict], summary: list[dict], recipe_spp: int) -> dict:
    """{config: stats.compare against the recipe, with its decision and flags}."""
    recipe = paper_name(recipe_spp)
    out = {}
    for s in summary:
        if s["config"] == recipe:
            continue
        cmp = stats.compare(rows, s["config"], recipe)
        ok, why = stats.decide(cmp)
        cmp.update(replaces=ok, why=why, flags=stats.flags(cmp))
        out[s["config"]] = cmp
    return out


def worst_class(cmp: dict) -> tuple[str, dict] | None:
    """The material class whose ratio's lower bound is highest (the likeliest to be worse)."""
    classes = [(c, iv) for c, iv in cmp["classes"].items() if iv]
    return max(classes, key=lambda item: (item[1]["lo"], item[1]["value"])) if classes else None


def recommend(summary: list[dict], recipe_spp: int, cmps: dict) -> dict:
    by = {s["config"]: s for s in summary}
    paper = by.get(paper_name(recipe_spp))
    if paper is None:
        return {}

    def pick(families, note):
        ok = [
            s
            for s in summary
            if s["family"] in families
            and s["ranked"]
            and s["reproducible"]
            and s["config"] in cmps
            and cmps[s["config"]]["replaces"]
            and cmps[s["config"]]["cpu"]
        ]
        if not ok:
            return None
        cpu = lambda s: cmps[s["config"]]["cpu"]["value"]  # noqa: E731
        cheapest = min(cpu(s) for s in ok)
        tied = [s for s in ok if cpu(s) <= cheapest * (1 + TIME_TIE)]
        best = min(tied, key=lambda s: (cmps[s["config"]]["ball"]["hi"], cpu(s)))
        c = cmps[best["config"]]
        return {
            "config": best["config"],
            "cpu_ratio_to_paper": c["cpu"]["value"],
            "cpu_ratio": c["cpu"],
            "error_ratio": c["ball"],
            "relmse_ball_median": best["relmse_ball_median"],
            "paper_relmse_ball_median": paper["relmse_ball_median"],
            "bias_ball_mean": best["bias_ball_mean"],
            "note": f"error ratio {_iv(c['ball'])} at build-level CPU ratio {_iv(c['cpu'])}" + note(best),
        }

    return {
        "paper": {
            "config": paper["config"],
            "relmse_ball_median": paper["relmse_ball_median"],
            "cpu_s_sum": paper["build_cpu_s_sum"],
            "note": "the spec's recipe",
        },
        "paper_fast": pick(UNBIASED_FAMILIES, lambda s: ""),
        "denoised": pick(("denoise",), lambda s: f"; biased: ball mean luminance {100 * s['bias_ball_mean']:+.1f}%"),
    }


def family_knees(summary: list[dict], cmps: dict) -> dict:
    """{family: the configuration where it stops paying (stats.stops_paying)}."""
    out = {}
    for fam in sorted({s["family"] for s in summary} - {"aa"}):
        pts = [
            {"config": s["config"], **cmps[s["config"]]} for s in summary if s["family"] == fam and s["config"] in cmps
        ]
        if fam == "ladder":
            recipe = next((s["config"] for s in summary if s["family"] == "ladder" and s["config"] not in cmps), None)
            if recipe:
                one = {"value": 1.0, "lo": 1.0, "hi": 1.0}
                pts.append({"config": recipe, "ball": one, "cpu": one})
        knee = stats.stops_paying(pts)
        if knee:
            point = next(p for p in pts if p["config"] == knee)
            out[fam] = {"config": knee, "efficiency": stats.efficiency(point), "measured": len(pts)}
    return out


def ladder_slope(summary: list[dict], cls: str | None = None) -> float | None:
    """Least-squares slope of log relMSE against log spp over the ranked independent ladder."""
    pts = []
    for s in summary:
        if s["family"] != "ladder" or not s["ranked"]:
            continue
        v = s["relmse_ball_median"] if cls is None else s["classes"].get(cls, {}).get("relmse_ball_mean")
        if v and v > 0:
            pts.append((math.log(s["spp"]), math.log(v)))
    if len(pts) < 2:
        return None
    x, y = np.array(pts).T
    return float(np.polyfit(x, y, 1)[0])


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


FAMILY_COLOURS = {
    "ladder": (31, 119, 180),
    "aa": (120, 120, 120),
    "denoise": (214, 39, 140),  # apart from the ladder's blue: the two are drawn together
    "samplers": (255, 127, 14),
    "passes": (0, 128, 128),
    "depth": (44, 160, 44),
    "rr": (148, 103, 189),
    "sun": (140, 86, 75),
    "clamp": (227, 119, 194),
    "robust": (188, 189, 34),
    "adaptive": (23, 190, 207),
}


def pareto_png(summary: list[dict], cmps: dict, recs: dict, knees: dict, width: int = 900, height: int = 600) -> bytes:
    """Error ratio on the ball against build-level CPU ratio, both to the recipe, log-log:
    every configuration with its 95% intervals, coloured by family; the A/A band (the
    recipe against itself: what no difference looks like); the recipe, the pick and each
    family's point where it stops paying marked; a legend."""
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    fam = {s["config"]: s["family"] for s in summary}
    pts = [(n, c) for n, c in cmps.items() if c.get("ball") and c.get("cpu") and c["ball"]["value"] > 0]
    recipe = recs.get("paper", {}).get("config")
    if not pts:
        draw.text((70, 40), "no comparisons", fill="black", font=font)
        return _png(img)
    plot = _ParetoPlot(draw, font, pts, width, height)
    plot.axes(cmps.get(aa_name(int(recipe.split("/")[1]))) if recipe else None)
    families = [f for f in FAMILY_COLOURS if any(fam.get(n) == f for n, _ in pts)]
    plot.points(pts, fam, families)
    pick = (recs.get("paper_fast") or {}).get("config")
    plot.labels(pts, {k["config"] for k in knees.values()}, pick)
    plot.legend(families, recipe, pick, cmps)
    return _png(img)


class _ParetoPlot:
    """The drawing of :func:`pareto_png`: its frame, log-log axes fitted to the points'
    intervals, and what is drawn on them, in order."""

    def __init__(self, draw, font, pts: list, width: int, height: int):
        self.draw, self.font, self.height = draw, font, height
        left, right, top, bottom = 70, 250, 40, 50
        self.x0, self.x1, self.y0, self.y1 = left, width - right, top, height - bottom
        xs = [math.log10(v) for _, c in pts for v in (c["cpu"]["lo"], c["cpu"]["hi"]) if v > 0] + [0.0]
        ys = [math.log10(v) for _, c in pts for v in (c["ball"]["lo"], c["ball"]["hi"]) if v > 0] + [0.0]
        self.lx0, self.lx1 = math.floor(min(xs) * 4) / 4 - 0.05, math.ceil(max(xs) * 4) / 4 + 0.05
        self.ly0, self.ly1 = math.floor(min(ys) * 4) / 4 - 0.05, math.ceil(max(ys) * 4) / 4 + 0.05

    def xy(self, cpu, err):
        cpu, err = max(cpu, 10**self.lx0), max(err, 10**self.ly0)
        return (
            self.x0 + (math.log10(cpu) - self.lx0) / (self.lx1 - self.lx0) * (self.x1 - self.x0),
            self.y1 - (math.log10(err) - self.ly0) / (self.ly1 - self.ly0) * (self.y1 - self.y0),
        )

    def axes(self, aa: dict | None) -> None:
        """The A/A band, the frame, the ticks, the recipe's lines (1, 1) and the titles."""
        draw, font, xy = self.draw, self.font, self.xy
        x0, x1, y0, y1 = self.x0, self.x1, self.y0, self.y1
        if aa and aa.get("ball"):
            _, ya = xy(10**self.lx0, aa["ball"]["hi"])
            _, yb = xy(10**self.lx0, aa["ball"]["lo"])
            draw.rectangle([x0, ya, x1, yb], fill=(232, 232, 232))
        draw.rectangle([x0, y0, x1, y1], outline="black")
        for tick in (0.1, 0.2, 0.3, 0.5, 1, 2, 3, 5, 10, 20, 50, 100):
            lt = math.log10(tick)
            if self.lx0 <= lt <= self.lx1:
                x, _ = xy(tick, 10**self.ly0)
                draw.line([x, y1, x, y1 + 4], fill="black")
                draw.text((x - 8, y1 + 6), f"{tick:g}", fill="black", font=font)
            if self.ly0 <= lt <= self.ly1:
                _, y = xy(10**self.lx0, tick)
                draw.line([x0 - 4, y, x0, y], fill="black")
                draw.text((x0 - 30, y - 6), f"{tick:g}", fill="black", font=font)
        rx, ry = xy(1.0, 1.0)
        draw.line([x0, ry, x1, ry], fill=(200, 200, 200))
        draw.line([rx, y0, rx, y1], fill=(200, 200, 200))
        draw.text(
            (x0, 8),
            "relMSE on the ball / the recipe's (mean over samples and seeds) vs CPU per render / the recipe's",
            fill="black",
            font=font,
        )
        draw.text(
            (x0, 22), "(build-level CPU time; bars: 95% bootstrap intervals; grey band: A/A)", fill="black", font=font
        )
        draw.text(
            ((x0 + x1) // 2 - 100, self.height - 20),
            "CPU ratio to the recipe, build level (log)",
            fill="black",
            font=font,
        )

    def points(self, pts: list, fam: dict, families: list[str]) -> None:
        """Each family's points, with their intervals, joined by a line in CPU order."""
        draw, xy = self.draw, self.xy
        for f in families:
            colour = FAMILY_COLOURS[f]
            mine = sorted(((n, c) for n, c in pts if fam.get(n) == f), key=lambda nc: nc[1]["cpu"]["value"])
            if len(mine) > 1 and f != "aa":
                draw.line([xy(c["cpu"]["value"], c["ball"]["value"]) for _, c in mine], fill=colour, width=1)
            for _n, c in mine:
                x, y = xy(c["cpu"]["value"], c["ball"]["value"])
                xa, _ = xy(c["cpu"]["lo"], 1.0)
                xb, _ = xy(c["cpu"]["hi"], 1.0)
                _, ya = xy(1.0, c["ball"]["lo"])
                _, yb = xy(1.0, c["ball"]["hi"])
                draw.line([x, ya, x, yb], fill=colour, width=1)
                draw.line([xa, y, xb, y], fill=colour, width=1)
                draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=colour)

    def labels(self, pts: list, knee_names: set, pick: str | None) -> None:
        """The points' names (all of them when few; else the pick's and the knees'), and a
        ring around each knee. A label that would overprint one already drawn is left out
        (report.md lists every point); the pick and the knees are labelled first."""
        draw, xy = self.draw, self.xy
        label_all = len(pts) <= 25
        placed: list[tuple[float, float, float, float]] = []
        for n, c in sorted(pts, key=lambda nc: (nc[0] != pick, nc[0] not in knee_names)):
            if label_all or n in knee_names or n == pick:
                x, y = xy(c["cpu"]["value"], c["ball"]["value"])
                box = draw.textbbox((x + 5, y - 12), n, font=self.font)
                if not any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in placed):
                    placed.append(box)
                    draw.text((x + 5, y - 12), n, fill=(60, 60, 60), font=self.font)
        for n, c in pts:
            if n in knee_names:
                x, y = xy(c["cpu"]["value"], c["ball"]["value"])
                draw.ellipse([x - 7, y - 7, x + 7, y + 7], outline="black", width=1)

    def legend(self, families: list[str], recipe: str | None, pick: str | None, cmps: dict) -> None:
        """The recipe's and the pick's marks, and the legend right of the plot."""
        draw = self.draw
        rx, ry = self.xy(1.0, 1.0)
        draw.rectangle([rx - 5, ry - 5, rx + 5, ry + 5], outline=(214, 39, 40), width=2)
        legend = [
            (f"family: {f}" if f != "aa" else "A/A: the recipe, other seeds", FAMILY_COLOURS[f]) for f in families
        ]
        legend.append((f"recipe: {recipe}", (214, 39, 40)))
        if pick and pick in cmps:
            x, y = self.xy(cmps[pick]["cpu"]["value"], cmps[pick]["ball"]["value"])
            draw.rectangle([x - 6, y - 6, x + 6, y + 6], outline=(0, 150, 0), width=2)
            legend.append((f"paper-fast pick: {pick}", (0, 150, 0)))
        legend.append(("ring: where a family stops paying", (0, 0, 0)))
        legend.append(("grey band: A/A 95% interval", (200, 200, 200)))
        for i, (label, colour) in enumerate(legend):
            y = self.y0 + 6 + 14 * i
            draw.line([self.x1 + 10, y + 6, self.x1 + 28, y + 6], fill=colour, width=3)
            draw.text((self.x1 + 32, y), label[:36], fill="black", font=self.font)


def _png(img) -> bytes:
    out = io.BytesIO()
    img.save(out, format="PNG")
    return out.getvalue()


def ranked_text(s: dict) -> str:
    return "yes" if s["ranked"] else f"no ({s['below_resolution']} below floor)"


def _f(v, spec=".3g"):
    return "-" if v is None else format(v, spec)


def _iv(iv: dict | None, spec: str = ".2f") -> str:
    """An interval dict as "value [lo, hi]"."""
    return "-" if not iv else f"{format(iv['value'], spec)} [{format(iv['lo'], spec)}, {format(iv['hi'], spec)}]"


def claim_line(meta: dict, config: str, cmp: dict) -> str:
    """One recipe's comparison with the recipe, as one line: what docs and spec comments
    quote verbatim (tests/test_study.py checks they do)."""
    req = meta["request"]
    worst = worst_class(cmp)
    verdict = "replaces the recipe" if cmp["replaces"] else f"does not replace the recipe ({cmp['why']})"
    return (
        f"{config} against {meta['recipe_name']} ({req['resolution']}x{req['resolution']}, "
        f"{len(meta['selection'])} samples x {cmp['repeats']} seeds, 95% intervals): "
        f"error ratio on the ball {_iv(cmp['ball'])}; "
        + (f"worst class {worst[0]} {_iv(worst[1])}; " if worst else "")
        + f"frame {_iv(cmp['frame'])}; fireflies ball {_iv(cmp['fireflies_ball'])}, "
        f"frame {_iv(cmp['fireflies_frame'])}; build-level CPU ratio {_iv(cmp['cpu'])}: {verdict}"
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
            f"| {n} | {fam.get(n, '-')} | {_iv(c['ball'])} | "
            + (f"{worst[0]} {_iv(worst[1])}" if worst else "-")
            + f" | {_iv(c['frame'])} | {_iv(c['fireflies_ball'])} | {_iv(c['fireflies_frame'])} | "
            f"{_iv(c['cpu'])} | {_f(eff, '.2f')} | {', '.join(c['flags']) or '-'} | "
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
        L.append(f"| {f} | {k['config']} | {_f(k['efficiency'], '.2f')} | {k['measured']} |")
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
        f"Independent-sampler ladder: log-log slope of median relMSE vs spp {_f(slopes.get('all'), '.2f')} "
        "(1/spp is -1); per class: " + ", ".join(f"{c} {_f(v, '.2f')}" for c, v in slopes.items() if c != "all"),
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
        spp = _f(s["spp_used_mean"], ".0f") + (
            "" if s["spp_used_min"] == s["spp_used_max"] else f" ({s['spp_used_min']}-{s['spp_used_max']})"
        )
        L.append(
            f"| {s['config']}{' (front)' if s['config'] in front else ''}{'' if s['reproducible'] else ' (not reproducible)'} | {s['family']} | {spp} | "
            f"{_f(s['relmse_ball_median'])} | {_f(s['relmse_frame_median'])} | "
            f"{_f(s['relmse_ball_no_fireflies_median'])} | {_f(s['firefly_share_median'], '.2f')} | "
            f"{_f(s['psnr_mean'], '.2f')} | {_f(s['ssim_mean'], '.4f')} | {_f(s['flip_mean'], '.4f')} | "
            f"{_f(None if s['bias_ball_mean'] is None else 100 * s['bias_ball_mean'], '+.2f')}% | "
            f"{_f(s['cpu_s_median'])} | {_f(s['build_cpu_s_median'])} | {_f(s['wall_s_median'])} | "
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
                f"{_f(s['relmse_ball_median'])} | {_f(ratio, '.2f')} |"
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
                f"{_f(s['error_estimate_mean'])} | {_f(s['relmse_ball_median'])} | "
                f"{_f(math.sqrt(s['relmse_ball_median']))} |"
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
                + " | ".join(_f(s["classes"].get(c, {}).get("relmse_ball_mean")) for c in classes)
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
