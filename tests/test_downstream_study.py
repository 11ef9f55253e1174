"""`shaderball study --downstream`: the smoke spec built at a ladder of spp, the same network
trained on each level with seeds, scored against references of the held-out samples; the
levels carry build CPU time and paired intervals; a re-run resumes and gives the same figures;
another request, or options of the other mode, are refused with nothing written."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cli import main
from pipeline.downstream import report
from pipeline.downstream.request import NetworkTraining, StudyCommandRequest
from pipeline.downstream.run import Clock, Run
from pipeline.downstream.score import image_row
from pipeline.fields import FieldError
from pipeline.image.tonemap import DEFAULT_EXPOSURE, tonemap
from pipeline.study.stats import paired_ratio

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
#: The command the issue names for this check, on the smoke spec.
CHECK = ("--downstream", "--ladder", "4,16", "--repeats", "2", "--epochs", "1", "--resolution", "32")
CHECK += ("--reference-spp", "256")


def _study(out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "cli", "study", str(SMOKE), "--out", str(out), *CHECK, *extra, "--json"],
        cwd=REPO,
        capture_output=True,
        text=True,
    )


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("downstream") / "study"
    done = _study(out)
    assert done.returncode == 0, done.stderr[-3000:]
    return out, done


def _figures(result: dict) -> list:
    """Every figure of the study but its timings."""
    return [
        [(row["spp"], row["means"], row["vs_spec"], row["passes"]) for row in loss["levels"]]
        for loss in result["losses"]
    ] + [result["aa"]["vs_spec"], result["decision"]["level"], result["mean_image"]["means"]]


@pytest.mark.slow
def test_levels_carry_build_time_and_intervals(study):
    out, done = study
    result = json.loads((out / "downstream.json").read_text())
    assert json.loads(done.stdout)["levels"] == [4, 16]
    assert [row["spp"] for row in result["levels"]] == [4, 16]
    for row in result["levels"]:
        assert row["build_cpu"] > 0 and row["train_s"] > 0 and row["build_cost"] == row["build_cpu"]  # on the CPU
        assert row["seeds"] == [0, 1]
    cheap = result["levels"][0]
    for name in ("relmse_ball", "psnr", "ssim", "flip"):
        iv = cheap["vs_spec"][name]
        assert iv["lo"] <= iv["value"] <= iv["hi"], (name, iv)
    assert result["levels"][1]["vs_spec"] is None  # the spec's level is the baseline
    # the targets' own error against the references falls as 1/spp (4x the samples: about a quarter)
    noisy, clean = (row["targets_relmse_ball"] for row in result["levels"])
    assert 2.0 < noisy / clean < 8.0, (noisy, clean)
    assert result["aa"]["seeds"] == [2, 3] and result["aa"]["vs_spec"]["relmse_ball"]["lo"] > 0
    assert result["held_out"] == {"materials": 2, "samples": 4, "training_materials": 6}
    assert result["reference_spp"] == 256 and 0 < result["reference_floor_ball_mean"] < 0.05
    assert result["error_over_floor"] > 10  # the references resolve the networks' error
    assert result["decision"]["level"] in (4, 16) and result["decision"]["verdict"]
    assert "tone-mapped" in result["loss_space"] and -1 < result["levels"][0]["means"]["bias_ball"] < 1
    # L2 at the spec's level and at the cheapest level L1 passes (or the cheapest where none does)
    l2 = {row["spp"]: row for row in result["losses"][1]["levels"]}
    assert result["losses"][1]["loss"] == "l2" and all(l2[spp]["seeds"] == [0, 1] for spp in (4, 16))
    assert {b["spp"] for b in result["between_losses"]} == {4, 16}
    text = (out / "report.md").read_text()
    assert text.splitlines()[2].startswith("`shaderball study ") and "--downstream" in text.splitlines()[2]
    assert "--draws" not in text and "--configs" not in text  # the pixel study's options are not the command's
    assert "## Decision" in text and "A/A" in text and (out / "downstream.png").read_bytes()[:4] == b"\x89PNG"
    runs = sorted(p.name for p in (out / "runs").iterdir())
    assert runs[:4] == ["l1-spp16-seed0", "l1-spp16-seed1", "l1-spp16-seed2", "l1-spp16-seed3"]
    assert sum(name.startswith("l2-") for name in runs) == 4
    # the plan and an estimate come before the first step
    lines = done.stderr.splitlines()
    assert lines[0].startswith("plan: 2 builds of 16 renders") and any(x.startswith("estimate: ") for x in lines[:4])
    assert any("ETA" in x for x in lines)


@pytest.mark.slow
def test_a_killed_study_resumes_with_the_same_figures(study, tmp_path):
    out, _done = study
    copy = tmp_path / "study"
    shutil.copytree(out, copy, copy_function=os.link)  # hard links: the runs' checkpoints are ~2 GB
    first = json.loads((out / "downstream.json").read_text())
    # what a kill leaves: a run, a score, a reference and the results missing, a build without its marker
    shutil.rmtree(copy / "runs" / "l1-spp4-seed1")
    (copy / "scores" / "l2-spp16-seed0.json").unlink()
    reference = sorted((copy / "references").iterdir())[0]
    reference.unlink()
    (copy / "downstream.json").unlink()
    kept = (copy / "runs" / "l1-spp16-seed0" / "checkpoint.pt").stat().st_mtime_ns
    done = _study(copy)
    assert done.returncode == 0, done.stderr[-3000:]
    again = json.loads((copy / "downstream.json").read_text())
    assert _figures(again) == _figures(first)
    assert (copy / "runs" / "l1-spp4-seed1" / "checkpoint.pt").exists() and reference.exists()
    assert (copy / "runs" / "l1-spp16-seed0" / "checkpoint.pt").stat().st_mtime_ns == kept  # not trained again


def test_another_request_in_the_folder_is_refused(tmp_path):
    out = tmp_path / "study"
    out.mkdir()
    (out / "request.json").write_text(json.dumps({"spec_digest": "x"}))
    done = CliRunner().invoke(main, ["study", str(SMOKE), "--out", str(out), *CHECK])
    assert done.exit_code == 2 and "--out" in done.output and "another request" in done.output
    assert sorted(os.listdir(out)) == ["request.json"]


@pytest.mark.parametrize(
    "args, named",
    [
        (("--epochs", "3"), "--epochs"),  # a network option without --downstream
        (("--losses", "l2"), "--losses"),
        (("--downstream", "--only", "independent/4"), "--only"),
        (("--downstream", "--configs", "ladder"), "--configs"),
        (("--downstream", "--draws", "3"), "--draws"),
        (("--downstream", "--resolution", "40"), "--resolution"),  # the network takes multiples of 16
        (("--downstream", "--test-fraction", "0"), "--test-fraction"),
        (("--downstream", "--losses", "l3"), "--losses"),
        (("--downstream", "--losses", "l1,l1"), "--losses"),
    ],
)
def test_options_of_the_other_mode_are_refused(tmp_path, args, named):
    done = CliRunner().invoke(main, ["study", str(SMOKE), "--out", str(tmp_path / "s"), *args])
    assert done.exit_code == 2, done.output
    assert named in done.output
    assert not (tmp_path / "s").exists()


def test_a_spec_without_texture_maps_is_refused(tmp_path):
    spec = tmp_path / "flat.toml"
    spec.write_text(SMOKE.read_text().replace("texture_maps = true", "texture_maps = false"))
    done = CliRunner().invoke(main, ["study", str(spec), "--out", str(tmp_path / "s"), *CHECK])
    assert done.exit_code == 2 and "texture_maps" in done.output, done.output
    assert not (tmp_path / "s").exists()


def test_the_request_refuses_from_python_too():
    with pytest.raises(FieldError, match="epochs: trains networks"):
        StudyCommandRequest(spec=str(SMOKE), out="x", training=NetworkTraining(epochs=2))
    req = StudyCommandRequest(spec=str(SMOKE), out="x", downstream=True, training={"epochs": 2, "losses": ("l2",)})
    assert req.training.losses == ("l2",) and "draws" in req.unused() and "epochs" not in req.unused()


def test_seeds_shared_by_every_sample_widen_the_interval():
    """A network (a seed) better or worse on every sample: drawn once for all samples, the
    interval holds that spread; drawn per sample, it averages away."""
    rng = np.random.default_rng(1)
    base = {f"s{i}": list(rng.uniform(0.9, 1.1, 3)) for i in range(60)}
    network = (0.8, 1.0, 1.25)  # each seed's network, on every sample
    cand = {k: [v * f for v, f in zip(vs, network)] for k, vs in base.items()}
    per_sample, crossed = paired_ratio(cand, base), paired_ratio(cand, base, shared_seeds=True)
    assert crossed.hi - crossed.lo > 3 * (per_sample.hi - per_sample.lo)
    assert crossed.lo < 0.9 and crossed.hi > 1.1


def test_a_row_scores_the_picture_against_the_reference_in_linear_radiance():
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.02, 0.3, (16, 16, 3)).astype(np.float32)
    mask = np.zeros((16, 16), bool)
    mask[4:12, 4:12] = True
    exact = image_row("s", tonemap(ref), ref, mask, DEFAULT_EXPOSURE, flip=False)
    darker = image_row("s", tonemap(ref * 0.5), ref, mask, DEFAULT_EXPOSURE, flip=False)
    assert exact["relmse_ball"] < 1e-4 and abs(exact["bias_ball"]) < 1e-3
    assert darker["bias_ball"] == pytest.approx(-0.5, abs=0.01) and darker["relmse_ball"] > 0.1
    assert darker["psnr"] < exact["psnr"] and darker["flip"] is None


def test_paired_difference_interval_covers_a_known_shift():
    base = {f"s{i}": [float(i), float(i)] for i in range(30)}  # seeds alike: only samples are drawn
    shifted = {k: [v + 2.0 for v in vs] for k, vs in base.items()}
    iv = paired_ratio(shifted, base, ratio=False)
    assert iv.value == pytest.approx(2.0) and iv.lo == pytest.approx(2.0) and iv.hi == pytest.approx(2.0)
    noisy = {k: [v + (1.0 if int(k[1:]) % 2 else -1.0) for v in vs] for k, vs in base.items()}
    iv = paired_ratio(noisy, base, ratio=False)
    assert iv.lo < 0 < iv.hi


def _scored(shift: float) -> dict:
    """Synthetic scores: the cheap level's relMSE ``shift`` times the spec level's, per sample."""
    scored = {}
    for spp, factor in ((4, shift), (16, 1.0)):
        for seed in range(2):
            rows = [
                {
                    "sample_id": f"s{i}",
                    "relmse_ball": factor * (0.1 + 0.01 * i) * (1 + 0.01 * seed),
                    "relmse_frame": 0.1,
                    "psnr": 30.0 - (factor - 1) * 10 + 0.1 * seed,
                    "ssim": 0.9,
                    "flip": 0.1 * factor,
                }
                for i in range(20)
            ]
            scored[Run("l1", spp, seed)] = {"rows": rows, "train_s": 1.0}
    return scored


@pytest.mark.parametrize("shift, passes", [(1.0, True), (1.5, False)])
def test_a_level_passes_only_when_no_figure_is_worse_beyond_its_interval(shift, passes):
    builds = {spp: {"build_cpu": cost, "build_wall": cost, "build_cost": cost} for spp, cost in ((4, 1.0), (16, 4.0))}
    first = report.compare_levels(_scored(shift), "l1", [4, 16], 16, 2, builds)
    cheap = first["levels"][0]
    assert cheap["passes"] is passes
    decision = report.decision(first, 16)
    assert decision["level"] == (4 if passes else 16)
    if passes:
        assert decision["ship"] and "0.25x" in decision["verdict"]
    else:
        assert "relmse_ball" in cheap["misses"] and "4 spp: relmse_ball 1.5" in decision["verdict"]


def test_the_eta_scales_the_estimate_by_what_the_steps_took():
    seen = []
    clock = Clock({"build 4": 10.0, "build 16": 40.0, "run a": 100.0, "run b": 100.0}, seen.append)
    clock.step("build 4", "b4", seconds=20.0)  # rendering takes twice its estimate
    assert seen[-1]["eta_s"] == pytest.approx(80.0 + 200.0)
    clock.step("run a", "a", seconds=50.0)  # training half
    assert seen[-1]["eta_s"] == pytest.approx(80.0 + 50.0)
    clock.step("build 16", "b16", seconds=None)  # kept from an earlier run: no measurement
    assert seen[-1]["eta_s"] == pytest.approx(50.0) and seen[-1]["done"] == 3
