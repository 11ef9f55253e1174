"""Paired error ratios with bootstrap intervals, and the rule that lets one recipe replace another.

A study renders every configuration of every sample with R seeds (``repeats``). For a
figure F (relMSE on the ball, on the frame, the fireflies' part of it, CPU seconds) the
ratio of a configuration to the recipe is mean_s mean_k F(c, s, k) / mean_s mean_k F(recipe,
s, k): the ratio of the mean over samples of each sample's mean over seeds (the mean error
a dataset of those samples would have). Paired: the same samples enter both means.

**Interval.** A two-level percentile bootstrap (:data:`BOOTSTRAP_RESAMPLES` resamples,
seed :data:`BOOTSTRAP_SEED`, so a report is reproducible): draw the samples with
replacement (the same draw for both configurations: paired), then for each drawn sample
draw its seeds with replacement, separately for each configuration (their seeds are
independent); the 2.5% and 97.5% quantiles of the resampled ratio are its 95% interval.
Samples are the larger source of spread (materials differ by 100x in error), seeds the one
the old single-seed study could not see; both are in the interval.

**The rule** (:func:`decide`): a configuration replaces the recipe only where the upper
bound of its overall ratio is at most 1, no material class has a ratio whose lower bound
is above 1 (worse beyond its interval), and neither its frame error nor its fireflies are
worse beyond their intervals (those are the flags). The A/A row (the recipe against itself
with other seeds) shows the noise floor: its interval is what "no difference" looks like.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 20230923
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Interval:
    """A point estimate and its 95% interval."""

    value: float
    lo: float
    hi: float

    def to_dict(self) -> dict:
        return {"value": self.value, "lo": self.lo, "hi": self.hi}

    def text(self, spec: str = ".2f") -> str:
        return f"{format(self.value, spec)} [{format(self.lo, spec)}, {format(self.hi, spec)}]"


def by_sample(rows: list[dict], config: str, key: str) -> dict[str, list[float]]:
    """{sample_id: [value of each repeat]} of one configuration (None values left out)."""
    out: dict[str, list[float]] = {}
    for r in rows:
        if r["config"] == config and r.get(key) is not None:
            out.setdefault(r["sample_id"], []).append(float(r[key]))
    return out


def _matrix(values: dict[str, list[float]], samples: list[str]) -> np.ndarray:
    """(samples, repeats) with NaN padding where a sample has fewer repeats."""
    width = max(len(values[s]) for s in samples)
    m = np.full((len(samples), width), np.nan)
    for i, s in enumerate(samples):
        m[i, : len(values[s])] = values[s]
    return m


def _resample_means(m: np.ndarray, draw: np.ndarray, rng: np.random.Generator, shared: bool = False) -> np.ndarray:
    """Mean over drawn samples of each drawn sample's mean over its seeds drawn with replacement
    (``shared``: one draw of seeds for every sample of a resample: column k is one seed's
    network, whose errors every sample shares; every sample then has every seed)."""
    counts = np.sum(~np.isnan(m), axis=1)  # seeds per sample
    picked_counts = counts[draw]  # (B, n)
    width = m.shape[1]
    if shared:
        if counts.min() < width:
            raise ValueError("shared seeds: every sample needs a value of every seed")
        seeds = np.broadcast_to(
            np.floor(rng.random((draw.shape[0], 1, width)) * width).astype(int), (*draw.shape, width)
        )
    else:  # seed k of a drawn sample: uniform among its own seeds (floor(u * count))
        seeds = np.floor(rng.random((*draw.shape, width)) * picked_counts[..., None]).astype(int)
    values = m[draw[..., None], seeds]  # (B, n, width)
    return values.mean(axis=2).mean(axis=1)


def paired_ratio(
    candidate: dict[str, list[float]],
    baseline: dict[str, list[float]],
    samples: list[str] | None = None,
    resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
    ratio: bool = True,
    shared_seeds: bool = False,
) -> Interval | None:
    """Ratio of mean (over samples) per-sample means (over seeds), candidate over baseline,
    with its two-level bootstrap interval; None without a common sample or a zero baseline.
    ``ratio=False``: the difference, candidate minus baseline, instead (figures such as PSNR
    and SSIM, whose ratio means nothing). ``shared_seeds``: value k of every sample comes from
    one seed's whole object (a trained network), so seeds are drawn once per resample for all
    samples (a crossed bootstrap): a network better or worse on every sample widens the
    interval as it should, where independent draws per sample would average it away."""
    common = [s for s in (samples or sorted(candidate)) if candidate.get(s) and baseline.get(s)]
    if not common:
        return None
    a, b = _matrix(candidate, common), _matrix(baseline, common)
    point_a, point_b = float(np.mean(np.nanmean(a, axis=1))), float(np.mean(np.nanmean(b, axis=1)))
    if ratio and point_b <= 0:
        return None
    point = point_a / point_b if ratio else point_a - point_b
    rng = np.random.default_rng(seed)
    draw = rng.integers(0, len(common), (resamples, len(common)))
    ra, rb = _resample_means(a, draw, rng, shared_seeds), _resample_means(b, draw, rng, shared_seeds)
    # A resample whose baseline mean is 0 has no ratio: left out (JSON has no infinity).
    values = (ra / np.where(rb > 0, rb, 1.0))[rb > 0] if ratio else ra - rb
    if not values.size:
        return None
    alpha = (1 - CONFIDENCE) / 2
    lo, hi = np.quantile(values, [alpha, 1 - alpha])
    return Interval(point, float(lo), float(hi))


#: (figure, row key): the ratios computed for every configuration against the recipe.
FIGURES = (
    ("ball", "relmse_ball"),
    ("frame", "relmse_frame"),
    ("fireflies_ball", "firefly_relmse_ball"),
    ("fireflies_frame", "firefly_relmse_frame"),
    ("cpu", "build_cpu_s"),
)


def compare(rows: list[dict], config: str, recipe: str, recipe_rows: list[dict] | None = None) -> dict:
    """Every figure's ratio of ``config`` to ``recipe`` (intervals), overall and per class.

    ``recipe_rows``: the rows standing for the recipe (default: those named ``recipe``)."""
    mine = [r for r in rows if r["config"] == config]
    base = recipe_rows if recipe_rows is not None else [r for r in rows if r["config"] == recipe]
    base = [{**r, "config": "__recipe__"} for r in base]
    both = mine + base
    out: dict = {}
    for name, key in FIGURES:
        iv = paired_ratio(by_sample(both, config, key), by_sample(both, "__recipe__", key))
        out[name] = iv.to_dict() if iv else None
    classes = {}
    for cls in sorted({r["material_class"] for r in mine}):
        samples = sorted({r["sample_id"] for r in mine if r["material_class"] == cls})
        iv = paired_ratio(by_sample(both, config, "relmse_ball"), by_sample(both, "__recipe__", "relmse_ball"), samples)
        classes[cls] = iv.to_dict() if iv else None
    out["classes"] = classes
    out["repeats"] = max((len(v) for v in by_sample(mine, config, "relmse_ball").values()), default=0)
    return out


def worse_beyond(iv: dict | None) -> bool:
    """Worse than the recipe beyond the interval: the ratio's lower bound above 1."""
    return bool(iv and iv["lo"] > 1.0)


def flags(cmp: dict) -> list[str]:
    """What is worse than the recipe beyond its interval, besides the ball's ranking figure."""
    out = []
    if worse_beyond(cmp.get("frame")):
        out.append("frame worse")
    if worse_beyond(cmp.get("fireflies_ball")) or worse_beyond(cmp.get("fireflies_frame")):
        out.append("more fireflies")
    return out


def decide(cmp: dict) -> tuple[bool, str]:
    """(replaces the recipe?, why): the rule of the module's docstring."""
    ball = cmp.get("ball")
    if not ball:
        return False, "no paired samples"
    if ball["hi"] > 1.0:
        return False, f"error ratio's upper bound {ball['hi']:.2f} > 1"
    worse = [c for c, iv in cmp["classes"].items() if worse_beyond(iv)]
    if worse:
        return False, "worse beyond the interval in " + ", ".join(worse)
    flagged = flags(cmp)
    if flagged:
        return False, ", ".join(flagged)
    return True, "upper bound <= 1, no class worse beyond its interval"


def efficiency(point: dict) -> float | None:
    """Monte Carlo efficiency relative to the recipe: 1 / (error ratio x CPU ratio)."""
    ball, cpu = point.get("ball"), point.get("cpu")
    if not ball or not cpu or ball["value"] <= 0 or cpu["value"] <= 0:
        return None
    return 1.0 / (ball["value"] * cpu["value"])


def stops_paying(points: list[dict]) -> str | None:
    """Where a family stops paying: its configuration of highest Monte Carlo efficiency
    (1 / (error x time), :func:`efficiency`). Along a 1/spp ladder efficiency is flat; a
    stratifying sampler gains it where it beats 1/spp, a depth or roulette cut where the
    time saved outweighs the bias. Past this point each extra CPU second lowers the error
    less than in proportion: more time no longer pays at the family's best rate.

    ``points``: dicts with ``config``, ``ball`` and ``cpu`` (interval dicts of the ratios)."""
    scored = [(efficiency(p), p["config"]) for p in points]
    scored = [(e, c) for e, c in scored if e is not None]
    return max(scored)[1] if scored else None


def finite_or_none(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x
