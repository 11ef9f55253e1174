"""The study's outputs: study.json, study.csv, pareto.png, report.md, and the recipes the
evidence supports.

Per configuration over the samples: the median and mean relMSE on the ball (and per
material class, with the noise of that mean from the per-pixel terms), the frame's
relMSE, PSNR/SSIM/HDR-FLIP means, the firefly share, the ball's mean-luminance bias, spp
used and CPU/wall seconds. A configuration with any row below the reference's resolution
is reported but not ranked.

**paper-fast**: the byte-reproducible configuration of an unbiased family
(configs.UNBIASED_FAMILIES) with the lowest summed CPU time whose median relMSE on the
ball is at most the spec recipe's
and whose mean relMSE in every material class is at most the recipe's plus twice the
noise of the difference; CPU times within 5% count as a tie, broken by the smallest
worst-class ratio to the recipe. The same rule picks the best denoised recipe, whose bias is
reported beside it.
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
from pipeline.study.configs import UNBIASED_FAMILIES, paper_name

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
            se = math.sqrt(sum((r["relmse_ball_se"] or 0.0) ** 2 for r in cr)) / len(cr)
            classes[cls] = {
                "relmse_ball_mean": _mean(_values(cr, "relmse_ball")),
                "se": se,
                "cpu_s_median": _median(_values(cr, "cpu_s")),
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
                "samples": len(rs),
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
    return _power_of_two(config.spp) and all(_power_of_two(r["spp_used"]) for r in rows)


def pareto_front(summary: list[dict]) -> list[str]:
    ranked = sorted((s for s in summary if s["ranked"]), key=lambda s: (s["cpu_s_sum"], s["relmse_ball_median"]))
    front, best = [], math.inf
    for s in ranked:
        if s["relmse_ball_median"] < best:
            front.append(s["config"])
            best = s["relmse_ball_median"]
    return front


def meets(candidate: dict, paper: dict) -> bool:
    """At most the recipe's median relMSE, and no class worse than the recipe's beyond noise."""
    if candidate["relmse_ball_median"] > paper["relmse_ball_median"]:
        return False
    for cls, p in paper["classes"].items():
        c = candidate["classes"].get(cls)
        if c is None or c["relmse_ball_mean"] > p["relmse_ball_mean"] + 2 * math.hypot(c["se"], p["se"]):
            return False
    return True


#: Relative CPU-time difference below which two recipes count as equally fast.
TIME_TIE = 0.05


def worst_class_ratio(candidate: dict, paper: dict) -> float:
    """The largest ratio, over material classes, of the candidate's mean relMSE to the recipe's."""
    return max(
        candidate["classes"][c]["relmse_ball_mean"] / p["relmse_ball_mean"]
        for c, p in paper["classes"].items()
        if p["relmse_ball_mean"]
    )


def recommend(summary: list[dict], recipe_spp: int) -> dict:
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
            and s["config"] != paper["config"]
            and meets(s, paper)
        ]
        if not ok:
            return None
        # CPU times within TIME_TIE of the cheapest are equal on this evidence (repeat runs on
        # a shared machine move by more); among those the one whose worst material class is
        # least above the recipe's wins.
        cheapest = min(s["cpu_s_sum"] for s in ok)
        tied = [s for s in ok if s["cpu_s_sum"] <= cheapest * (1 + TIME_TIE)]
        best = min(tied, key=lambda s: (worst_class_ratio(s, paper), s["cpu_s_sum"]))
        ratio = best["cpu_s_sum"] / paper["cpu_s_sum"]
        return {
            "config": best["config"],
            "cpu_ratio_to_paper": ratio,
            "worst_class_ratio": worst_class_ratio(best, paper),
            "relmse_ball_median": best["relmse_ball_median"],
            "paper_relmse_ball_median": paper["relmse_ball_median"],
            "bias_ball_mean": best["bias_ball_mean"],
            "note": f"{ratio:.2f} x the paper recipe's CPU time at median relMSE "
            f"{best['relmse_ball_median']:.3g} vs {paper['relmse_ball_median']:.3g}" + note(best),
        }

    return {
        "paper": {
            "config": paper["config"],
            "relmse_ball_median": paper["relmse_ball_median"],
            "cpu_s_sum": paper["cpu_s_sum"],
            "note": "the spec's recipe",
        },
        "paper_fast": pick(UNBIASED_FAMILIES, lambda s: ""),
        "denoised": pick(("denoise",), lambda s: f"; biased: ball mean luminance {100 * s['bias_ball_mean']:+.1f}%"),
    }


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


def pareto_png(summary: list[dict], front: list[str], recs: dict, width: int = 820, height: int = 560) -> bytes:
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    left, right, top, bottom = 80, 280, 36, 50
    x0, x1, y0, y1 = left, width - right, top, height - bottom
    pts = [s for s in summary if s["relmse_ball_median"] and s["cpu_s_median"]]
    if not pts:
        draw.text((x0, y0), "no measurements", fill="black", font=font)
        return _png(img)
    xs = [math.log10(s["cpu_s_median"]) for s in pts]
    ys = [math.log10(s["relmse_ball_median"]) for s in pts]
    for s in pts:
        for c in s["classes"].values():
            if c["relmse_ball_mean"] and c["cpu_s_median"]:
                xs.append(math.log10(c["cpu_s_median"]))
                ys.append(math.log10(c["relmse_ball_mean"]))
    lx0, lx1 = math.floor(min(xs) * 2) / 2, math.ceil(max(xs) * 2) / 2 + 1e-9
    ly0, ly1 = math.floor(min(ys) * 2) / 2, math.ceil(max(ys) * 2) / 2 + 1e-9

    def xy(cpu, err):
        return (
            x0 + (math.log10(cpu) - lx0) / (lx1 - lx0) * (x1 - x0),
            y1 - (math.log10(err) - ly0) / (ly1 - ly0) * (y1 - y0),
        )

    draw.rectangle([x0, y0, x1, y1], outline="black")
    for e in range(math.floor(lx0), math.ceil(lx1) + 1):
        if lx0 <= e <= lx1:
            x, _ = xy(10**e, 10**ly0)
            draw.line([x, y1, x, y1 + 4], fill="black")
            draw.text((x - 12, y1 + 6), f"1e{e}", fill="black", font=font)
    for e in range(math.floor(ly0), math.ceil(ly1) + 1):
        if ly0 <= e <= ly1:
            _, y = xy(10**lx0, 10**e)
            draw.line([x0 - 4, y, x0, y], fill="black")
            draw.text((x0 - 40, y - 6), f"1e{e}", fill="black", font=font)
    draw.text(
        (x0, 10),
        "relMSE on the ball (median over samples; per class: mean) vs CPU seconds per render",
        fill="black",
        font=font,
    )
    draw.text(((x0 + x1) // 2 - 60, height - 20), "CPU seconds per render (log)", fill="black", font=font)
    for s in pts:  # every configuration: grey
        x, y = xy(s["cpu_s_median"], s["relmse_ball_median"])
        fill = (170, 170, 170) if s["ranked"] else (225, 225, 225)
        draw.ellipse([x - 2, y - 2, x + 2, y + 2], fill=fill)
    ladder = sorted((s for s in pts if s["family"] == "ladder"), key=lambda s: s["spp"])
    classes = sorted({c for s in ladder for c in s["classes"]})
    legend = []
    for i, cls in enumerate(classes):
        colour = COLOURS[i % len(COLOURS)]
        line = [
            xy(s["classes"][cls]["cpu_s_median"], s["classes"][cls]["relmse_ball_mean"])
            for s in ladder
            if cls in s["classes"] and s["classes"][cls]["relmse_ball_mean"]
        ]
        if len(line) > 1:
            draw.line(line, fill=colour, width=1)
        legend.append((f"ladder, {cls}", colour))
    by = {s["config"]: s for s in pts}
    fl = [xy(by[n]["cpu_s_median"], by[n]["relmse_ball_median"]) for n in front if n in by]
    if len(fl) > 1:
        draw.line(fl, fill="black", width=2)
    legend.append(("Pareto front (median)", (0, 0, 0)))
    marks = [
        ("paper", (214, 39, 40), "paper recipe"),
        ("paper_fast", (0, 150, 0), "paper-fast"),
        ("denoised", (0, 90, 200), "denoised pick"),
    ]
    for key, colour, label in marks:
        rec = recs.get(key)
        if rec and rec["config"] in by:
            x, y = xy(by[rec["config"]]["cpu_s_median"], by[rec["config"]]["relmse_ball_median"])
            draw.rectangle([x - 5, y - 5, x + 5, y + 5], outline=colour, width=2)
            legend.append((f"{label}: {rec['config']}", colour))
    for i, (label, colour) in enumerate(legend):
        y = y0 + 6 + 14 * i
        draw.line([x1 + 10, y + 6, x1 + 28, y + 6], fill=colour, width=3)
        draw.text((x1 + 32, y), label[:44], fill="black", font=font)
    return _png(img)


def _png(img) -> bytes:
    out = io.BytesIO()
    img.save(out, format="PNG")
    return out.getvalue()


def ranked_text(s: dict) -> str:
    return "yes" if s["ranked"] else f"no ({s['below_resolution']} below floor)"


def _f(v, spec=".3g"):
    return "-" if v is None else format(v, spec)


def report_markdown(
    meta: dict, summary: list[dict], recs: dict, front: list[str], slopes: dict, rows: list[dict] = ()
) -> str:
    req = meta["request"]
    L = [
        f"# Accuracy study: {os.path.basename(meta['spec'])}",
        "",
        f"{len(meta['selection'])} samples, {req['resolution']}x{req['resolution']}, references at "
        f"{req['reference_spp']} spp (two halves), variant {meta['variant']}, {meta['cpu_count']} CPUs. "
        f"relMSE = mean (x - ref)^2 / (ref^2 + {meta['relmse_eps']}) over the ball's pixels and channels. "
        f"A configuration with any sample within {meta['floor_factor']:g}x of its reference's floor is marked "
        "and not ranked. CPU and wall seconds: the render alone, kernels warm, plus any post-process.",
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
    L += [
        "",
        f"Independent-sampler ladder: log-log slope of median relMSE vs spp {_f(slopes.get('all'), '.2f')} "
        "(1/spp is -1); per class: " + ", ".join(f"{c} {_f(v, '.2f')}" for c, v in slopes.items() if c != "all"),
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
    L += [
        "",
        "## Every configuration",
        "",
        "| config | family | spp used | relMSE ball (median) | relMSE frame | w/o fireflies | firefly share | "
        "PSNR | SSIM | FLIP | ball bias | CPU s | wall s | ranked |",
        "|" + "---|" * 14,
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
            f"{_f(s['cpu_s_median'])} | {_f(s['wall_s_median'])} | "
            f"{ranked_text(s)} |"
        )
    paper_name_ = recs.get("paper", {}).get("config")
    L += [
        "",
        f"## Fireflies at the recipe ({paper_name_})",
        "",
        f"relMSE on the ball with and without its brightest {100 * meta['firefly_share']:g}% of pixels (by the "
        "render's luminance).",
        "",
        "| sample | class | relMSE | without the brightest | their share |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        if r["config"] == paper_name_:
            L.append(
                f"| {r['sample_id']} | {r['material_class']} | {r['relmse_ball']:.3g} | "
                f"{r['relmse_ball_no_fireflies']:.3g} | {r['firefly_share']:.2f} |"
            )
    L += [
        "",
        "## Biased remedies: what they cost in light",
        "",
        "| config | ball bias (mean) | largest \\|bias\\| of a sample | relMSE ball (median) | CPU ratio to paper |",
        "|---|---|---|---|---|",
    ]
    paper = next((s for s in summary if s["config"] == recs.get("paper", {}).get("config")), None)
    for s in summary:
        if s["family"] in ("clamp", "robust", "denoise", "depth") and s["bias_ball_mean"] is not None:
            ratio = s["cpu_s_sum"] / paper["cpu_s_sum"] if paper else None
            L.append(
                f"| {s['config']} | {100 * s['bias_ball_mean']:+.2f}% | {100 * s['bias_ball_abs_max']:.2f}% | "
                f"{_f(s['relmse_ball_median'])} | {_f(ratio, '.2f')} |"
            )
    L += [
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
    classes = sorted({c for s in summary for c in s["classes"]})
    L += [
        "",
        "## Per material class (mean relMSE on the ball)",
        "",
        "| config | " + " | ".join(classes) + " |",
        "|---|" + "---|" * len(classes),
    ]
    for s in summary:
        if s["family"] in ("ladder", "denoise", "adaptive", "samplers"):
            L.append(
                f"| {s['config']} | "
                + " | ".join(_f(s["classes"].get(c, {}).get("relmse_ball_mean")) for c in classes)
                + " |"
            )
    return "\n".join(L) + "\n"


def write_outputs(out: str, meta: dict, rows: list[dict], configs) -> dict:
    summary = summarise(rows, configs)
    recs = recommend(summary, meta["recipe"]["spp"])
    front = pareto_front(summary)
    classes = sorted({r["material_class"] for r in rows})
    slopes = {"all": ladder_slope(summary), **{c: ladder_slope(summary, c) for c in classes}}
    doc = {
        "meta": meta,
        "summary": summary,
        "pareto_front": front,
        "recommendations": recs,
        "ladder_slopes": slopes,
        "rows": rows,
    }
    write_text_atomic(os.path.join(out, "study.json"), json.dumps(doc, indent=1, allow_nan=False) + "\n")
    write_csv(os.path.join(out, "study.csv"), rows)
    write_bytes_atomic(os.path.join(out, "pareto.png"), pareto_png(summary, front, recs))
    write_text_atomic(os.path.join(out, "report.md"), report_markdown(meta, summary, recs, front, slopes, rows))
    return recs
