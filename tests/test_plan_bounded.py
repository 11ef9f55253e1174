"""`shaderball plan` times a spec with bounded work whatever its settings: a render too large
to time (4096 px at 65536 spp would take days) is timed at small settings, its time fitted
per setting varied and extrapolated to the spec's, and the plan says how. The work is counted
(renders, their pixels and samples), not timed: a clock would measure the machine's load."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from pipeline.bench.estimate import Estimate, PlanReport
from pipeline.bench.first_renders import (
    TIMED_LIGHTS,
    TIMING_RESOLUTIONS,
    TIMING_SPP,
    TIMING_TEXELS,
    Timing,
    extrapolate,
    first_materials,
    timing_plan,
)
from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec_file import parse_spec

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


#: Runs the CLI with Mitsuba's ``render`` counted: each call's film width, height and spp, printed
#: as JSON on stderr's last line.
COUNTED = (
    "import json, runpy, sys\n"
    "from pipeline.render.mitsuba_env import load_mitsuba, resolve_variant\n"
    "mi = load_mitsuba(resolve_variant('auto'))\n"
    "real, renders = mi.render, []\n"
    "def counted(scene, *args, **kwargs):\n"
    "    width, height = scene.sensors()[0].film().crop_size()\n"
    "    renders.append([int(width), int(height), kwargs.get('spp')])\n"
    "    return real(scene, *args, **kwargs)\n"
    "mi.render = counted\n"
    "sys.argv = ['cli', *sys.argv[1:]]\n"
    "try:\n    runpy.run_module('cli', run_name='__main__')\nexcept SystemExit as exc:\n    code = exc.code\n"
    "else:\n    code = 0\n"
    "print('RENDERS', json.dumps(renders), file=sys.stderr); sys.exit(code)"
)


@pytest.mark.slow
def test_plan_of_a_spec_at_extreme_settings_renders_only_small_settings(tmp_path):
    """4096 px at 65536 spp (days a render): the plan's work is bounded by what it renders,
    counted call by call, not by a clock: the renders it reports timing, each at most 128 px
    and 64 spp, and one-sample renders that compile the kernels. (About 15 s on 2 cores.)"""
    spec = smoke_at(tmp_path, resolution=4096, spp=65536)
    done = subprocess.run(
        [sys.executable, "-c", COUNTED, "plan", str(spec), "--json"],
        capture_output=True,
        text=True,
        timeout=600,  # 20x its time on 2 busy cores: a plan rendering at the spec's settings fails, not hangs
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    tag, counted = done.stderr.strip().splitlines()[-1].split(" ", 1)
    renders = [(width, height, spp) for width, height, spp in json.loads(counted)]
    assert tag == "RENDERS" and renders, done.stderr[-3000:]
    assert all(width <= 128 and height <= 128 and spp <= 64 for width, height, spp in renders), renders
    pixel_samples = sum(width * height * spp for width, height, spp in renders)
    assert pixel_samples < 4096**2 * 65536 / 10_000, pixel_samples  # a ten-thousandth of one render
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
    # the renders it reports timing are the renders it made; the rest are kernels compiled at 1 spp
    reported = Counter()
    for kind in timing["by_kind"].values():
        for t in kind["timed"]:
            reported[t["resolution"], t["resolution"], t["spp"]] += t["renders"]
    assert Counter(r for r in renders if r[2] > 1) == reported, (reported, renders)
    doc.pop("ok"), doc.pop("exit")
    report = PlanReport(**{**doc, "timing": Timing(**timing), "estimates": [Estimate(**e) for e in doc["estimates"]]})
    lines = report.lines()
    assert any(line.startswith("extrapolated: the spec's 4096x4096 px, 65536 spp") for line in lines), lines
    assert any("at each of 3 settings" in line and "extrapolated" in line for line in lines), lines
