"""The study's evidence: each configuration summarised over its samples and seeds
(:func:`summarise`), compared with the spec's recipe by paired ratios (:func:`comparisons`),
its Pareto front, and the recipes the evidence supports (:func:`recommend`: paper-fast and
the best denoised recipe, by the rule of pipeline.study.stats.decide)."""

from __future__ import annotations

import math

import numpy as np

from pipeline.study import stats
from pipeline.study.configs import UNBIASED_FAMILIES, paper_name


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
            "note": f"error ratio {interval_text(c['ball'])} at build-level CPU ratio {interval_text(c['cpu'])}"
            + note(best),
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


def number_text(v, spec=".3g"):
    return "-" if v is None else format(v, spec)


def interval_text(iv: dict | None, spec: str = ".2f") -> str:
    """An interval dict as "value [lo, hi]"."""
    return "-" if not iv else f"{format(iv['value'], spec)} [{format(iv['lo'], spec)}, {format(iv['hi'], spec)}]"
