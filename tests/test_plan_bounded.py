"""`shaderball plan` times a spec in bounded time whatever its settings: a render too large
to time (4096 px at 65536 spp would take days) is timed at small settings, its time fitted
per setting varied and extrapolated to the spec's, and the plan says how."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.bench.estimate import (
    TIMED_LIGHTS,
    TIMING_RESOLUTIONS,
    TIMING_SPP,
    TIMING_TEXELS,
    Estimate,
    PlanReport,
    Timing,
    extrapolate,
    first_materials,
    timing_plan,
)
from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec import parse_spec

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
PAPER = REPO / "manifests" / "paper.toml"


def smoke_at(tmp_path: Path, **values) -> Path:
    """The smoke spec with some of its settings replaced (``key = value`` lines)."""
    lines = []
    for line in SMOKE.read_text().splitlines():
        key = line.split("=")[0].strip()
        lines.append(f"{key} = {values[key]}" if key in values else line)
    path = tmp_path / "spec.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_spec_up_to_the_papers_render_is_timed_at_its_own_settings():
    for spec in (SMOKE, PAPER):
        plan = timing_plan(parse_spec(spec))
        assert not plan.extrapolated and len(plan.points("svbrdf")) == 1


def test_each_setting_too_large_to_time_is_timed_at_two_small_values(tmp_path):
    spec = parse_spec(smoke_at(tmp_path, resolution=4096, spp=65536, texture_resolution=4096))
    plan = timing_plan(spec)
    assert plan.extrapolated and plan.spec == (4096, 65536, 4096)
    assert (plan.resolutions, plan.spp, plan.texels) == (TIMING_RESOLUTIONS, TIMING_SPP, TIMING_TEXELS)
    assert len(plan.points("svbrdf")) == 4 and len(plan.points("uniform")) == 3
    # only the spp too large: the resolution is the spec's own
    plan = timing_plan(parse_spec(smoke_at(tmp_path, spp=65536)))
    assert (plan.resolutions, plan.spp, plan.texels) == ((64,), TIMING_SPP, (64,))
    text = plan.describe()["text"]
    assert text.startswith("the spec's 65536 spp would take too long to time: renders timed at 64 px, 16 spp")
    assert plan.describe()["model"] == "a + c x pixels x spp"


def test_the_extrapolation_recovers_a_linear_model():
    """Figures made by t = a + b pixels + c pixels spp + d texels at the timed settings give
    back t at the spec's settings."""
    a, b, c, d = 0.05, 2e-7, 6e-7, 3e-8

    def seconds(res, spp, texels):
        return a + b * res**2 + c * res**2 * spp + d * texels**2

    plan = timing_plan(parse_spec(SMOKE))
    plan = type(plan)(TIMING_RESOLUTIONS, TIMING_SPP, TIMING_TEXELS, (4096, 65536, 4096), True)
    timed = {p: {"seconds_per_render": seconds(*p)} for p in plan.points("svbrdf")}
    value, fit = extrapolate(plan, timed, "seconds_per_render")
    assert value == pytest.approx(seconds(4096, 65536, 4096), rel=1e-9)
    assert (fit["a_s"], fit["b_s_per_pixel"], fit["c_s_per_pixel_spp"], fit["d_s_per_texel"]) == pytest.approx(
        (a, b, c, d)
    )
    # noise that makes more spp look faster: the samples are taken to be the whole render
    timed[(128, 64, 1024)]["seconds_per_render"] = timed[(128, 16, 1024)]["seconds_per_render"] / 2
    value, fit = extrapolate(plan, timed, "seconds_per_render")
    assert fit["c_s_per_pixel_spp"] > 0 and value > max(t["seconds_per_render"] for t in timed.values())


def test_at_most_a_few_lightings_of_a_material_are_timed(tmp_path):
    plans = plan_dataset(parse_spec(smoke_at(tmp_path, lights_per_material=1000)))
    chosen = first_materials(plans, 4, ("uniform", "svbrdf"), TIMED_LIGHTS)
    assert [m.n_lights for m in chosen] == [TIMED_LIGHTS] * len(chosen)
    assert chosen[0].samples[:TIMED_LIGHTS] == plans[0].materials[0].samples[:TIMED_LIGHTS]


@pytest.mark.slow
def test_plan_of_a_spec_at_extreme_settings_is_timed_in_bounded_time(tmp_path):
    """4096 px at 65536 spp: about 15 s on 2 cores (timing at those settings: days a render)."""
    spec = smoke_at(tmp_path, resolution=4096, spp=65536)
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "cli", "plan", str(spec), "--json"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=REPO,
    )
    seconds = time.monotonic() - started
    assert done.returncode == 0, done.stderr[-3000:]
    assert seconds < 120, seconds
    assert "at small settings, extrapolated to its own" in done.stderr
    doc = json.loads(done.stdout)
    timing = doc["timing"]
    extrapolation = timing["extrapolation"]
    assert extrapolation["spec"] == [4096, 65536, 64]
    assert extrapolation["timed_at"] == [[128, 16, 64], [64, 16, 64], [128, 64, 64]]
    assert "4096x4096 px, 65536 spp would take too long to time" in extrapolation["text"]
    for kind in timing["by_kind"].values():
        assert [t["resolution"] for t in kind["timed"]] == [128, 64, 128]
        # a render at the spec's settings is at least 4096^2 x 65536 / (128^2 x 64) = 65536 times the base's
        base = kind["timed"][0]["seconds_per_render"]
        assert kind["seconds_per_render"] > 1000 * base and kind["fit"]["c_s_per_pixel_spp"] > 0
    doc.pop("ok"), doc.pop("exit")
    report = PlanReport(**{**doc, "timing": Timing(**timing), "estimates": [Estimate(**e) for e in doc["estimates"]]})
    lines = report.lines()
    assert any(line.startswith("extrapolated: the spec's 4096x4096 px, 65536 spp") for line in lines), lines
    assert any("at each of 3 settings" in line and "extrapolated" in line for line in lines), lines
