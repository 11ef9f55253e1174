"""The accuracy study (pipeline/study, `shaderball study`) and the renderer options it measures.

A tiny study (32x32, a short spp ladder, references at 512 spp) runs end to end and is
checked for what the study claims: the independent sampler's error falls as 1/spp, the
reference's floor is computed two ways that agree and is enforced, OIDN lowers the error
at low spp, outputs are written and a killed study resumes. The adaptive renderer stops at
its target, is byte-identical when repeated and its stopping rule is checked for bias by
a paired test. Bad options and spec fields are refused with exit code 2, nothing written.
"""

from __future__ import annotations

import json
import math
import os
import re

import numpy as np
import pytest
from click.testing import CliRunner

import cli
from geometry import build_shaderball, default_camera
from materials.maps import MaterialMaps
from pipeline.dataset.spec_file import parse_spec_text, spec_digest
from pipeline.dataset.spec_rules import SpecError
from pipeline.errors import ShaderballError
from pipeline.image.metrics import RELMSE_EPS as NEURAL_EPS
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.limits import SAMPLERS
from pipeline.render.mitsuba_env import SHORT_VARIANTS
from pipeline.render.renderer import (
    RELMSE_EPS,
    PassSum,
    RenderSettings,
    adaptive_stages,
    relative_error,
    render_pass,
    render_sample,
    render_scene,
    scene_dict,
)
from pipeline.study.configs import study_configs
from pipeline.study.request import StudyRequest
from pipeline.study.run import run_study
from pipeline.ui.command import command_line
from sky import Light
from support import VARIANT

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHORT = next(k for k, v in SHORT_VARIANTS.items() if v == VARIANT)
LADDER = (1, 2, 4, 8, 16, 32, 64, 256)
REFERENCE_SPP = 512


def study_command(req: StudyRequest) -> str:
    """The heading `shaderball study` gives the report: every option that is set."""
    return command_line("study", req, every=True, skip=("scan",))


REPEATS = 2
#: Stated range of the log-log slope of relMSE against spp for the independent sampler
#: (Monte Carlo: -1; fireflies at low spp and the finite reference flatten it a little).
SLOPE_RANGE = (-1.25, -0.75)
GOLD = MaterialMaps(
    np.full((1, 1, 3), 0.05, np.float32),
    np.full((1, 1, 3), (0.95, 0.7, 0.3), np.float32),
    np.full((1, 1), 0.15, np.float32),
    np.full((1, 1, 3), (0.0, 0.0, 1.0), np.float32),
)
LIGHT = Light(35.0, 300.0, 3.0)


def tiny_spec(tmp_path) -> str:
    text = open(os.path.join(REPO, "manifests", "smoke.toml"), encoding="utf-8").read()
    text = re.sub(r'variant = "auto"', f'variant = "{SHORT}"', text)
    path = tmp_path / "tiny.toml"
    path.write_text(text, encoding="utf-8")
    return str(path)


@pytest.fixture(scope="module")
def tiny_study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("study")
    req = StudyRequest(
        spec=tiny_spec(tmp),
        out=str(tmp / "out"),
        draws=3,
        reference_spp=REFERENCE_SPP,
        resolution=32,
        ladder=LADDER,
        configs=("ladder", "denoise"),
        flip=False,
        scan=8,
        repeats=REPEATS,
    )
    summary = run_study(req, command=study_command(req))
    with open(tmp / "out" / "study.json", encoding="utf-8") as fh:
        return req, summary, json.load(fh)


@pytest.mark.slow
def test_tiny_study_independent_error_falls_as_one_over_spp(tiny_study):
    _, _, doc = tiny_study
    slope = doc["ladder_slopes"]["all"]
    assert SLOPE_RANGE[0] <= slope <= SLOPE_RANGE[1], slope
    by = {s["config"]: s for s in doc["summary"]}
    errors = [by[f"independent/{n}"]["relmse_ball_median"] for n in LADDER]
    assert errors[0] > 20 * errors[-2], errors  # 1 spp vs 64 spp: about 64x


@pytest.mark.slow
def test_tiny_study_reference_floor_is_computed_and_enforced(tiny_study):
    _, _, doc = tiny_study
    for sample_id, ref in doc["meta"]["references"].items():
        assert 0 < ref["floor_ball"] < 1, sample_id
        # Two estimates of the reference's own error: the moment integrator's and the halves'.
        assert 1 / 3 < ref["floor_moment_ball"] / ref["floor_halves_ball"] < 3, ref
    rows = doc["rows"]
    for r in rows:
        assert r["below_resolution"] == (r["relmse_ball"] < 10 * r["floor_ball"])
    flagged = {r["config"] for r in rows if r["below_resolution"]}
    assert "independent/256" in flagged  # 256 spp against a 512-spp reference: not resolvable
    ranked = {s["config"] for s in doc["summary"] if s["ranked"]}
    assert not flagged & ranked
    assert not flagged & set(doc["pareto_front"])
    assert all(rec is None or rec["config"] not in flagged for rec in doc["recommendations"].values())
    assert "independent/1" in ranked and "independent/16" in ranked


@pytest.mark.slow
def test_tiny_study_denoiser_lowers_error_at_low_spp(tiny_study):
    _, _, doc = tiny_study
    by = {(r["sample_id"], r["config"]): r for r in doc["rows"] if r["repeat"] == 0}
    for sample in doc["meta"]["selection"]:
        for n in (1, 2):
            raw = by[(sample["sample_id"], f"independent/{n}")]["relmse_ball"]
            assert by[(sample["sample_id"], f"oidn+independent/{n}")]["relmse_ball"] < raw
            assert by[(sample["sample_id"], f"oidn-color+independent/{n}")]["relmse_ball"] < raw


@pytest.mark.slow
def test_tiny_study_writes_its_outputs_and_resumes(tiny_study):
    req, summary, doc = tiny_study
    out = req.out
    assert summary.rendered == summary.rows == len(doc["rows"]) == 3 * REPEATS * len(doc["meta"]["configs"])
    with open(os.path.join(out, "study.csv"), encoding="utf-8") as fh:
        assert len(fh.read().splitlines()) == len(doc["rows"]) + 1
    with open(os.path.join(out, "pareto.png"), "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    report = open(os.path.join(out, "report.md"), encoding="utf-8").read()
    assert "paper recipe" in report and "independent/16" in report
    # Headed by the command that wrote it (the same request again), the machine and the date.
    head = report.splitlines()[2]
    assert head.startswith(f"Written by `{study_command(req)}` on 20") and head.endswith(" UTC.")
    assert study_command(req).startswith(f"shaderball study {req.spec} --out {req.out} --draws 3 ")
    assert "--resolution 32" in head and "--configs ladder,denoise" in head and "--no-flip" in head
    assert report.splitlines()[4].startswith("Machine: ") and "CPUs" in report.splitlines()[4]
    # A study killed after its references and one sample: the rest is measured, the rest kept.
    first = doc["meta"]["selection"][0]["sample_id"]
    os.remove(os.path.join(out, "rows", f"{first}.json"))
    ref_path = os.path.join(out, "references", f"{first}.npz")
    ref_mtime = os.stat(ref_path).st_mtime_ns
    again = run_study(req)
    per_sample = REPEATS * len(doc["meta"]["configs"])
    assert again.rendered == per_sample and again.reused == 2 * per_sample
    assert os.stat(ref_path).st_mtime_ns == ref_mtime
    redo = json.load(open(os.path.join(out, "study.json"), encoding="utf-8"))
    old = {(r["sample_id"], r["config"], r["repeat"]): r["relmse_ball"] for r in doc["rows"]}
    new = {(r["sample_id"], r["config"], r["repeat"]): r["relmse_ball"] for r in redo["rows"]}
    assert old == new  # deterministic seeds: the re-measured sample gives the same errors
    # Another request on the same folder is refused and leaves it alone.
    before = sorted(os.listdir(out))
    with pytest.raises(ShaderballError, match="another request"):
        run_study(StudyRequest(**{**req.__dict__, "draws": 2}))
    assert sorted(os.listdir(out)) == before


@pytest.mark.slow
def test_tiny_study_reports_intervals_and_the_aa_row(tiny_study):
    """Every configuration is rendered with its own seeds per repeat; every comparison with
    the recipe carries a 95% interval; the report prints the A/A row, whose interval holds 1."""
    _, _, doc = tiny_study
    seeds = {}
    for r in doc["rows"]:
        seeds.setdefault((r["sample_id"], r["config"]), set()).add(r["seed"])
    assert all(len(v) == REPEATS for v in seeds.values())  # independent seeds per repeat
    recipe = {r["seed"] for r in doc["rows"] if r["config"] == "independent/16"}
    aa = {r["seed"] for r in doc["rows"] if r["config"] == "A/A independent/16"}
    assert aa and not aa & recipe  # the A/A row: the recipe with other seeds
    cmps = doc["comparisons"]
    assert "independent/16" not in cmps and "A/A independent/16" in cmps
    for name, c in cmps.items():
        for fig in ("ball", "frame", "cpu"):
            assert c[fig]["lo"] <= c[fig]["value"] <= c[fig]["hi"], (name, fig, c[fig])
        assert c["repeats"] == REPEATS
    assert cmps["A/A independent/16"]["ball"]["lo"] <= 1 <= cmps["A/A independent/16"]["ball"]["hi"]
    assert cmps["independent/1"]["ball"]["lo"] > 1 and not cmps["independent/1"]["replaces"]
    report = open(os.path.join(tiny_study[0].out, "report.md"), encoding="utf-8").read()
    assert "| A/A independent/16 | aa | " in report and "95%" in report
    assert re.search(r"\| independent/1 \| ladder \| [0-9.]+ \[[0-9.]+, [0-9.]+\] \|", report)
    # The files as they are now (the resume test may have rewritten them: timings move).
    current = json.load(open(os.path.join(tiny_study[0].out, "study.json"), encoding="utf-8"))
    for line in current["claims"].values():
        assert f"- {line}" in report
    assert doc["stops_paying"]["ladder"]["config"].startswith("independent/")
    for r in doc["rows"]:
        assert r["build_cpu_s"] >= r["cpu_s"] >= 0 and r["load_cpu_s"] >= 0 and r["compile_s"] >= 0


def test_configurations_vary_one_thing_from_the_recipe():
    configs = study_configs(150, "split", (1, 16, 1024), ("ladder", "samplers", "depth", "adaptive"))
    names = [c.name for c in configs]
    assert "independent/150" in names and len(names) == len(set(names))
    assert {c.changes["sampler"] for c in configs if c.family == "samplers"} == set(SAMPLERS[1:])
    assert all(c.changes["max_depth"] != 8 for c in configs if c.family == "depth")
    assert {c.spp for c in configs if c.family == "adaptive"} == {
        150
    }  # the cap: the largest rung <= 4 x 150 (the recipe is one)


# --------------------------------------------------------------------------- renderer options


@pytest.fixture(scope="module")
def scene_setup(mi):
    ball, camera = build_shaderball(), default_camera()
    return ball, camera, load_gbuffer(ball, camera, 16, VARIANT)


def test_default_settings_leave_the_scene_as_it_was(scene_setup):
    ball, camera, _ = scene_setup
    desc, _, _ = scene_dict(ball, camera, GOLD, LIGHT, RenderSettings(resolution=16, spp=4, variant=VARIANT))
    assert desc["integrator"] == {"type": "moment", "nested": {"type": "path", "max_depth": 8}}
    assert desc["sensor"]["sampler"]["type"] == "independent"
    assert RELMSE_EPS == NEURAL_EPS


def test_adaptive_render_stops_at_its_target_and_is_byte_identical(scene_setup):
    ball, camera, gbuffer = scene_setup
    totals = [sum(sum(s) for s in adaptive_stages(256)[: i + 1]) for i in range(len(adaptive_stages(256)))]
    assert totals == [16, 32, 64, 128, 256] and adaptive_stages(150)[-1] == [16, 4, 2]
    used = {}
    for target in (0.3, 0.09, 0.001):
        settings = RenderSettings(resolution=16, spp=256, target_error=target, variant=VARIANT)
        a = render_sample(ball, camera, GOLD, LIGHT, settings, 5, mask=gbuffer.mask)
        b = render_sample(ball, camera, GOLD, LIGHT, settings, 5, mask=gbuffer.mask)
        assert a.image.tobytes() == b.image.tobytes() and a.variance.tobytes() == b.variance.tobytes()
        spp, err = a.stats["spp_used"], a.stats["error_estimate"]
        assert spp in totals and a.stats["target_error"] == target
        assert err <= target or spp == 256
        if 16 < spp < 256:  # it stopped at the first stage that met the target: the one before did not
            capped = RenderSettings(resolution=16, spp=spp // 2, target_error=target, variant=VARIANT)
            before = render_sample(ball, camera, GOLD, LIGHT, capped, 5, mask=gbuffer.mask)
            assert before.stats["spp_used"] == spp // 2 and before.stats["error_estimate"] > target
        used[target] = spp
    assert used[0.3] <= used[0.09] <= used[0.001] == 256
    assert 16 < used[0.09] < 256  # a stop between the first stage and the cap was exercised
    assert used[0.3] < 256


def test_adaptive_stopping_is_not_biased(mi, scene_setup):
    """Paired check of the stopping rule. For each seed every stage is rendered (to the cap)
    and the estimate where the adaptive rule stops is compared with the full render of the
    same passes: E[full] is the unbiased mean, so the mean of (stopped - full) over seeds is
    the stopping bias, measured with far less noise than two independent renders give. The
    emulation is the renderer's own: its stopped image is checked bit for bit against
    render_scene for the first seeds."""
    ball, camera, gbuffer = scene_setup
    settings = RenderSettings(resolution=16, spp=256, variant=VARIANT)
    scene = mi.load_dict(scene_dict(ball, camera, GOLD, LIGHT, settings)[0])
    mask, target, cap = gbuffer.mask, 0.15, 256
    luma = np.array([0.2126, 0.7152, 0.0722])
    diffs, stops = [], []
    for seed in range(80):
        acc, k, stopped = PassSum(), 0, None
        for stage in adaptive_stages(cap):
            for n in stage:
                acc.add(*render_pass(mi, scene, n, seed, k))
                k += 1
            if stopped is None and relative_error(acc.mean(), acc.spp, mask) <= target:
                stopped = (acc.mean()[..., :3].astype(np.float32), acc.spp)
        full = acc.mean()[..., :3].astype(np.float32)
        stopped = stopped or (full, cap)
        if seed < 3:
            direct = render_scene(mi, scene, cap, seed, target_error=target, mask=mask)
            assert direct.image.tobytes() == stopped[0].tobytes() and direct.spp_used == stopped[1]
        diffs.append(float((stopped[0][mask] @ luma).mean() - (full[mask] @ luma).mean()))
        stops.append(stopped[1])
    diffs = np.array(diffs)
    assert len(set(stops)) > 1, stops  # the rule really stopped at different points
    z = diffs.mean() / (diffs.std(ddof=1) / math.sqrt(len(diffs)))
    assert abs(z) < 4, (z, diffs.mean())


def test_sampler_records_the_spp_it_used_and_clamp_bounds_every_pixel(scene_setup):
    ball, camera, gbuffer = scene_setup
    ortho = RenderSettings(resolution=16, spp=16, sampler="orthogonal", variant=VARIANT)
    r = render_sample(ball, camera, GOLD, LIGHT, ortho, 3, mask=gbuffer.mask)
    assert r.stats["spp_used"] == 25  # Mitsuba's orthogonal sampler: a prime squared
    plain = render_sample(ball, camera, GOLD, LIGHT, RenderSettings(resolution=16, spp=16, variant=VARIANT), 3)
    assert "spp_used" not in plain.stats  # default renders keep the stats they always had
    clamped = render_sample(
        ball, camera, GOLD, LIGHT, RenderSettings(resolution=16, spp=16, clamp=0.05, variant=VARIANT), 3
    )
    y = clamped.image @ np.array([0.2126, 0.7152, 0.0722])
    assert y.max() <= 0.05 * (1 + 1e-4)  # box filter: a pixel is a mean of clamped paths
    assert (plain.image @ np.array([0.2126, 0.7152, 0.0722])).max() > 0.05


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "args, option",
    [
        (["--draws", "0"], "--draws"),
        (["--reference-spp", "3"], "--reference-spp"),
        (["--reference-spp", "1000"], "--reference-spp"),  # less than twice the largest spp (1024)
        (["--resolution", "8"], "--resolution"),
        (["--ladder", "0,4"], "--ladder"),
        (["--ladder", "a,b"], "--ladder"),
        (["--configs", "ladder,bogus"], "--configs"),
        (["--only", "independent/3"], "--only"),
        (["--repeats", "0"], "--repeats"),
    ],
)
def test_bad_study_options_exit_2_and_write_nothing(tmp_path, args, option):
    out = tmp_path / "out"
    result = CliRunner().invoke(cli.main, ["study", tiny_spec(tmp_path), "--out", str(out), *args])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: {option}: ") and "allowed" in result.output, result.output
    assert not out.exists()


def test_study_request_keeps_its_ladder_sorted_and_its_families_in_order(tmp_path):
    from pipeline.study.configs import FAMILIES

    spec = tiny_spec(tmp_path)
    req = StudyRequest(spec=spec, out=str(tmp_path / "o"), ladder=(8, 2, 8), configs="all")
    assert req.ladder == (2, 8) and req.configs == FAMILIES
    req = StudyRequest(spec=spec, out=str(tmp_path / "o"), configs=("clamp", "denoise"))
    assert req.configs == ("ladder", "denoise", "clamp")  # the ladder always, in FAMILIES' order
    with pytest.raises(ShaderballError, match=r"^configs: .* is not allowed; all, or comma-separated names"):
        StudyRequest(spec=spec, out=str(tmp_path / "o"), configs=("bogus",))


def test_a_study_folder_of_another_request_is_refused_naming_out(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "request.json").write_text('{"samples": 1}')
    result = CliRunner().invoke(cli.main, ["study", tiny_spec(tmp_path), "--out", str(out), "--draws", "2"])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f'error: --out: "{out}" holds a study of another request (differs in '), (
        result.output
    )
    assert sorted(p.name for p in out.iterdir()) == ["request.json"]


@pytest.mark.parametrize(
    "field, value, allowed",
    [
        ("sampler", '"sobol"', "independent"),
        ("rr_depth", "0", "from 1 to 64"),
        ("clamp", "-1.0", "from 0 to"),
        ("target_error", "2.0", "from 0 to 1"),
        ("target_error", "nan", "finite"),
    ],
)
def test_bad_render_fields_are_refused(tmp_path, field, value, allowed):
    text = f'[dataset]\nname = "x"\nseed = 1\nmaterials = 1\n[render]\n{field} = {value}\n'
    with pytest.raises(SpecError, match=re.escape(f"render.{field}")) as err:
        parse_spec_text(text)
    assert allowed in str(err.value)
    spec = tmp_path / "bad.toml"
    spec.write_text(text, encoding="utf-8")
    out = tmp_path / "out"
    result = CliRunner().invoke(cli.main, ["build", str(spec), "--out", str(out), "--workers", "0"])
    assert result.exit_code == 2 and f"render.{field}" in result.output
    assert not out.exists()


def test_new_fields_at_their_defaults_keep_the_digest():
    base = '[dataset]\nname = "x"\nseed = 1\nmaterials = 1\n'
    explicit = base + '[render]\nsampler = "independent"\nrr_depth = 5\nclamp = 0.0\ntarget_error = 0.0\n'
    assert spec_digest(parse_spec_text(base)) == spec_digest(parse_spec_text(explicit))
    assert spec_digest(parse_spec_text(base + '[render]\nsampler = "stratified"\n')) != spec_digest(
        parse_spec_text(base)
    )
