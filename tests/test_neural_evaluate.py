"""`shaderball evaluate`: refusals that name what the user can do, the reference's
spp, the equal-time and mean-image rows, intervals, relMSE of a saturated network."""

import json
import os

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from cli import main
from pipeline.image.tonemap import inverse_tonemap
from pipeline.neural import runfiles
from pipeline.neural.scores import NETWORK_Y_CAP
from support.neural_fakes import untrained_run

torch.set_num_threads(1)


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.mark.slow
def test_a_run_whose_resolution_does_not_divide_the_datasets_names_what_to_do(reference, tmp_path):
    untrained_run(tmp_path / "run48", 48)  # the smoke dataset is 64x64: 48 does not divide it
    result = _invoke("evaluate", tmp_path / "run48", reference, "--split", "all", "--spp", "none")
    assert result.exit_code == 2, result.output
    assert "--resolution" not in result.output.replace("train DATASET --out NEWRUN`, with --resolution", "")
    assert "64x64 renders" in result.output and "trained at 48x48" in result.output
    assert "multiple of 48" in result.output and "shaderball train DATASET" in result.output
    assert not (tmp_path / "run48" / "evaluation-all").exists()


@pytest.fixture(scope="module")
def trained(reference, tmp_path_factory):
    out = tmp_path_factory.mktemp("ev22") / "run"
    args = ["--loss", "l1", "--resolution", "32", "--batch-size", "4", "--seed", "3", "--epochs", "1"]
    result = _invoke("train", reference, "--out", out, *args)
    assert result.exit_code == 0, result.output
    return out


@pytest.mark.slow
def test_evaluate_records_reference_spp_equal_time_mean_image_and_intervals(trained, reference, tmp_path):
    json_path = tmp_path / "eval.json"
    result = _invoke(
        "evaluate", trained, reference, "--split", "all", "--spp", "1,8", "--no-denoise", "--limit", 6,
        "--json-out", json_path, "--out", tmp_path / "ev",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads(json_path.read_text())
    assert data["reference_spp"] == 16  # manifests/smoke.toml
    assert set(data["mean"]) == {"network", "mean_image", "nearest_sample", "pt_equal_time", "pt1", "pt8"}
    for row in data["samples"]:  # another material's render, never the sample's own
        assert row["nearest_sample"]["neighbour"].split("_")[0] != row["material_id"]
    eq = data["equal_time"]
    assert eq["spp"] >= 1 and eq["network_cpu_s"] > 0 and set(eq["pt_cpu_s"]) == {"1", "64"}
    assert all(r["pt_equal_time"]["spp"] == eq["spp"] for r in data["samples"])
    # 8 spp is more than a quarter of 16: said; 1 spp is not
    assert any(n.startswith("pt8:") and "optimistic" in n for n in data["notes"])
    assert not any(n.startswith("pt1:") for n in data["notes"])
    for method, m in data["mean"].items():
        lo, hi = m["ci95"]["psnr"]
        assert lo <= m["psnr"] <= hi, method
    assert data["mean"]["mean_image"]["time_s"] == 0.0
    table = (tmp_path / "ev" / "results.md").read_text()
    assert "references of 16 spp" in table and "| mean training image |" in table
    assert "| nearest training sample (same class, lighting) |" in table
    assert f"| path tracing, equal CPU time ({eq['spp']} spp) |" in table


@pytest.mark.slow
def test_a_saturated_network_has_a_bounded_relmse(reference, tmp_path):
    untrained_run(tmp_path / "sat", 32, digest="fake")
    ckpt = runfiles.load_checkpoint(str(tmp_path / "sat"))
    last_bias = [k for k in ckpt["model"] if k.endswith(".bias")][-1]
    ckpt["model"][last_bias].fill_(50.0)  # sigmoid(50): every output value 1
    runfiles.save_checkpoint(
        str(tmp_path / "sat"),
        epoch=1,
        model_state=ckpt["model"],
        optimizer_state={},
        history=[],
        identity_digest="fake",
    )
    json_path = tmp_path / "eval.json"
    result = _invoke("evaluate", tmp_path / "sat", reference, "--split", "all", "--spp", "none", "--limit", 2,
                     "--json-out", json_path)  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads(json_path.read_text())
    net = data["mean"]["network"]
    assert net["saturated"] == 1.0
    assert any(n.startswith("network: 100.0% of its output values are saturated") for n in data["notes"])
    # uncapped, an output of 1 inverts to 2.5e5 and relMSE is ~1e12; capped, at most
    # (the cap's radiance)^2 / 0.01 whatever the reference
    cap = float(inverse_tonemap(np.float32(NETWORK_Y_CAP), 4.0))
    assert net["relmse"] <= cap**2 / 0.01 < 1e6


@pytest.mark.slow
def test_evaluate_report_has_classes_with_intervals_a_learning_curve_and_a_grid(trained, reference, tmp_path):
    report_dir = tmp_path / "ev"
    result = _invoke(
        "evaluate", trained, reference, "--split", "all", "--spp", "1", "--limit", 8, "--report",
        "--out", report_dir,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert sorted(os.listdir(report_dir)) == [  # one folder, one grid
        "grid.png", "learning-curve.csv", "learning-curve.png", "report.json", "report.md", "results.json",
        "results.md",
    ]  # fmt: skip
    assert sorted(os.listdir(tmp_path)) == ["ev"]
    # progress as a build shows it: samples done, rate, ETA and what runs now, on stderr
    assert "8/8 samples 100.0%" in result.output and "ETA" in result.output
    assert "equal time (the network's CPU time" in result.output
    data = json.loads((report_dir / "report.json").read_text())
    assert {"pt_equal_time", "pt_equal_time+oidn", "pt1", "pt1+oidn"} <= set(data["mean"])
    classes = {r["class"] for r in data["samples"]}
    assert classes <= {"uniform dielectric", "uniform metal", "svbrdf"} and "svbrdf" in classes
    assert set(data["by_class"]) == classes
    for name, methods in data["by_class"].items():
        assert {"network", "mean_image", "nearest_sample", "pt_equal_time"} <= set(methods), name
        for method, m in methods.items():
            members = [r for r in data["samples"] if r["class"] == name and method in r]
            assert m["samples"] == len(members)
            assert m["psnr"] == pytest.approx(np.mean([r[method]["psnr"] for r in members]))
            ci = m["ci95"]["psnr"]
            assert (ci is None) == (m["materials"] < 2), (name, method)
            assert ci is None or ci[0] <= m["psnr"] <= ci[1]
    history = data["history"]
    assert len(history) == 1 and history[0]["train_psnr"] > 0
    curve = (report_dir / "learning-curve.csv").read_text().splitlines()
    assert curve[0].split(",") == list(runfiles.CSV_COLUMNS) and len(curve) == 2
    text = (report_dir / "report.md").read_text()
    assert "## Per material class" in text and "![grid](grid.png)" in text
    # headed by the command that wrote it (the same options again), the machine and the date
    head = text.splitlines()[2]
    command = f"shaderball evaluate {trained} {reference} --split all --out {report_dir} --spp 1 --limit 8 --report"
    assert head.startswith(f"Written by `{command}` on 20") and head.endswith(" UTC.")
    assert text.splitlines()[4].startswith("Machine: ") and "torch device cpu" in text.splitlines()[4]
    assert "path tracing, equal CPU time" in text and "+ OIDN (its time added)" in text
    # the table shows the CPU times the equal-time row matched, as results.json has them
    equal = data["equal_time"]
    row = next(line for line in text.splitlines() if line.startswith("| path tracing, equal CPU time ("))
    assert row.rstrip(" |").endswith(f"{1000 * equal['pt_cpu_s_at_spp']:.1f}")
    net = next(line for line in text.splitlines() if line.startswith("| neural renderer |"))
    assert net.rstrip(" |").endswith(f"{1000 * equal['network_cpu_s']:.1f}")
    assert f"on one torch thread, {1000 * equal['network_cpu_s']:.1f} ms, matched by path tracing at" in text
    from PIL import Image

    with Image.open(report_dir / "grid.png") as grid:  # a row per sample shown: at most 2 per class
        assert grid.height > 64 * len(classes)


def test_evaluate_into_a_file_is_refused_before_anything_is_written(trained, reference, tmp_path):
    (tmp_path / "afile").write_text("x")
    result = _invoke("evaluate", trained, reference, "--split", "all", "--spp", "none", "--out", tmp_path / "afile")
    assert result.exit_code == 2 and "--out" in result.output
    assert sorted(os.listdir(tmp_path)) == ["afile"] and (tmp_path / "afile").read_text() == "x"


def test_equal_time_spp_solves_the_line_and_never_runs_away_on_noise():
    from pipeline.neural.equal_time import equal_time_spp

    # 0.1 s fixed + 0.01 s per spp: the network's 0.3 s buys 20 spp; less than 1 spp's time: 1
    assert equal_time_spp(0.3, {1: 0.11, 64: 0.74}) == 20
    assert equal_time_spp(0.01, {1: 0.11, 64: 0.74}) == 1
    # measured beside other work, 64 spp took less CPU than 1 spp; a fit through both would give 4096
    assert equal_time_spp(0.42, {1: 0.121, 64: 0.115}) == round(0.42 / (0.115 / 64))
    assert equal_time_spp(0.018, {1: 0.121, 64: 0.115}) == 1  # faster than either render
    assert equal_time_spp(1e9, {1: 0.11, 64: 0.74}) == 4096  # the ladder's top, no further


def test_no_flip_leaves_hdr_flip_out_and_says_so(trained, reference, tmp_path):
    json_path = tmp_path / "e.json"
    result = _invoke("evaluate", trained, reference, "--split", "all", "--spp", "none", "--limit", 2, "--no-flip",
                     "--json-out", json_path, "--out", tmp_path / "ev")  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads(json_path.read_text())
    assert all(r["network"]["flip"] is None and r["network"]["psnr"] > 0 for r in data["samples"])
    assert "HDR-FLIP: left out (--no-flip)" in data["notes"]
