"""The accuracy study's statistics on synthetic numbers (pipeline/study/stats.py, report.py).

Paired bootstrap ratios over samples and seeds: an A/A comparison's interval holds 1; a
recipe twice as noisy is refused; one material class 3x worse is refused although the
overall ratio is below 1 (the per-pixel spread the old rule used let exactly that through);
frame errors and fireflies worse beyond their intervals flag a recipe; the interval is
reproducible; where a family stops paying is computed.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.study import stats
from pipeline.study.configs import Config
from pipeline.study.evidence import comparisons, recommend, summarise

CLASSES = ("dielectric", "metal", "bricks", "tiles")  # in order of error: dielectric smallest
SAMPLES = 16
REPEATS = 3


def rows_for(config, scale, rng, class_scale=None, frame_scale=1.0, firefly_scale=1.0, cpu=1.0):
    """Rows of one configuration: per sample a true error spanning 100x across samples,
    times ``scale`` (and ``class_scale[cls]``), each seed's measurement with 20% noise."""
    out = []
    for i in range(SAMPLES):
        cls = CLASSES[i * len(CLASSES) // SAMPLES]
        truth = 1e-4 * 10 ** (2 * i / (SAMPLES - 1)) * scale * (class_scale or {}).get(cls, 1.0)
        for k in range(REPEATS):
            noise = rng.gamma(25.0, 1 / 25.0)  # mean 1, sd 0.2
            out.append(
                {
                    "sample_id": f"s{i:02d}",
                    "material_class": cls,
                    "config": config,
                    "repeat": k,
                    "relmse_ball": truth * noise,
                    "relmse_frame": 2 * truth * frame_scale * rng.gamma(25.0, 1 / 25.0),
                    "firefly_relmse_ball": 0.05 * truth * firefly_scale * rng.gamma(25.0, 1 / 25.0),
                    "firefly_relmse_frame": 0.05 * truth * firefly_scale * rng.gamma(25.0, 1 / 25.0),
                    "build_cpu_s": cpu * rng.gamma(400.0, 1 / 400.0),
                }
            )
    return out


def test_aa_interval_contains_one_and_is_reproducible():
    rng = np.random.default_rng(1)
    rows = rows_for("recipe", 1.0, rng) + rows_for("aa", 1.0, rng)
    a = stats.compare(rows, "aa", "recipe")
    assert a["ball"]["lo"] < 1 < a["ball"]["hi"]
    assert a["ball"]["hi"] / a["ball"]["lo"] < 1.5  # 16 samples x 3 seeds resolve ~20%
    assert a["cpu"]["lo"] < 1 < a["cpu"]["hi"]
    assert stats.compare(rows, "aa", "recipe") == a  # fixed bootstrap seed: the same interval
    ok, _ = stats.decide(a)
    assert not ok  # no better than the recipe: its upper bound is above 1


def test_a_recipe_twice_as_bad_is_refused_and_one_better_is_taken():
    rng = np.random.default_rng(2)
    rows = rows_for("recipe", 1.0, rng) + rows_for("worse", 2.0, rng) + rows_for("better", 0.6, rng)
    worse, better = stats.compare(rows, "worse", "recipe"), stats.compare(rows, "better", "recipe")
    assert worse["ball"]["lo"] > 1.5 and not stats.decide(worse)[0]
    assert better["ball"]["hi"] < 1 and stats.decide(better) == (
        True,
        "upper bound <= 1, no class worse beyond its interval",
    )


def test_a_three_times_worse_class_is_refused_although_the_mean_is_lower():
    rng = np.random.default_rng(3)
    rows = rows_for("recipe", 1.0, rng) + rows_for("mixed", 0.5, rng, class_scale={"dielectric": 6.0})
    c = stats.compare(rows, "mixed", "recipe")
    assert c["ball"]["hi"] < 1  # overall it looks better: the dielectric samples have small errors
    assert c["classes"]["dielectric"]["lo"] > 1  # 3x worse, beyond its interval
    ok, why = stats.decide(c)
    assert not ok and "dielectric" in why


@pytest.mark.parametrize(
    "kwargs, flag", [({"frame_scale": 3.0}, "frame worse"), ({"firefly_scale": 4.0}, "more fireflies")]
)
def test_frame_and_fireflies_worse_beyond_the_interval_are_flagged(kwargs, flag):
    rng = np.random.default_rng(4)
    rows = rows_for("recipe", 1.0, rng) + rows_for("cand", 0.6, rng, **kwargs)
    c = stats.compare(rows, "cand", "recipe")
    assert flag in stats.flags(c)
    ok, why = stats.decide(c)
    assert not ok and flag in why


def test_the_report_picks_the_cheapest_recipe_the_rule_accepts():
    rng = np.random.default_rng(5)
    configs = [
        Config("independent/150", "ladder", 150),
        Config("fast-bad", "samplers", 64, {"sampler": "multijitter"}),
        Config("fast-good", "samplers", 64, {"sampler": "stratified"}),
        Config("slow-good", "samplers", 128, {"sampler": "stratified"}),
    ]
    rows = (
        rows_for("independent/150", 1.0, rng)
        + rows_for("fast-bad", 0.5, rng, class_scale={"dielectric": 6.0}, cpu=0.4)
        + rows_for("fast-good", 0.8, rng, cpu=0.45)
        + rows_for("slow-good", 0.4, rng, cpu=0.9)
    )
    for r in rows:
        r.update(
            spp_used=64,
            below_resolution=False,
            cpu_s=r["build_cpu_s"],
            wall_s=r["build_cpu_s"],
            post=None,
        )
    summary = summarise(rows, configs)
    cmps = comparisons(rows, summary, 150)
    recs = recommend(summary, 150, cmps)
    assert not cmps["fast-bad"]["replaces"] and "dielectric" in cmps["fast-bad"]["why"]
    assert recs["paper_fast"]["config"] == "fast-good"
    assert recs["paper_fast"]["error_ratio"]["hi"] <= 1


def test_where_a_family_stops_paying_is_its_most_efficient_point():
    one = {"value": 1.0, "lo": 1.0, "hi": 1.0}

    def iv(v):
        return {"value": v, "lo": v * 0.9, "hi": v * 1.1}

    # A depth family: depth 2 is biased (error 3x), 4 as good as 8 at 0.9x time, 12 costs more.
    pts = [
        {"config": "depth2", "ball": iv(3.0), "cpu": iv(0.6)},
        {"config": "depth4", "ball": iv(1.0), "cpu": iv(0.9)},
        {"config": "depth8", "ball": one, "cpu": one},
        {"config": "depth12", "ball": iv(1.0), "cpu": iv(1.1)},
    ]
    assert stats.stops_paying(pts) == "depth4"
    assert stats.efficiency(pts[1]) == pytest.approx(1 / 0.9)
    assert stats.stops_paying([]) is None
