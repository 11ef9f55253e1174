"""`shaderball train`, `infer` and `evaluate` end to end on the smoke dataset; bad input
exits 2 with a message naming the thing and writes nothing; kill -9 then resume."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch
from click.testing import CliRunner
from PIL import Image

from cli import main
from pipeline.neural import runfiles
from pipeline.store.exr import read_exr
from support.neural_fakes import RUN_FILES

torch.set_num_threads(1)
TRAIN = ["--loss", "l1", "--resolution", "32", "--batch-size", "4", "--lr", "1e-3", "--seed", "3"]


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def run(reference, tmp_path_factory):
    out = tmp_path_factory.mktemp("neural") / "run"
    result = _invoke("train", reference, "--out", out, "--epochs", 1, *TRAIN)
    assert result.exit_code == 0, result.output
    assert "held-out loss" in result.output and "baseline" in result.output
    return out


@pytest.mark.slow
def test_train_writes_the_run_files(run):
    assert sorted(os.listdir(run)) == RUN_FILES
    assert json.loads((run / "config.json").read_text())["network"]["resolution"] == 32


@pytest.mark.slow
def test_infer_writes_the_estimate_and_says_the_time_split(run, tmp_path):
    out, png = tmp_path / "ball.exr", tmp_path / "ball.png"
    result = _invoke("infer", run, "--out", out, "--png", png, "--elevation", 30, "--roughness", 0.5)
    assert result.exit_code == 0, result.output
    assert "maps" in result.output and "network" in result.output and " ms" in result.output
    layers = read_exr(out).layers
    assert layers["render"].shape == (32, 32, 3) and float(layers["render"].min()) >= 0
    assert {"diffuse", "specular", "roughness", "normal", "mask"} <= set(layers)
    assert Image.open(png).size == (32, 32)


@pytest.mark.slow
def test_evaluate_writes_table_grid_and_json(run, reference, tmp_path):
    json_path = tmp_path / "eval.json"
    result = _invoke(
        "evaluate", run, reference, "--spp", "1,2", "--limit", 2, "--json-out", json_path, "--out", tmp_path / "ev"
    )
    assert result.exit_code == 0, result.output
    data = json.loads(json_path.read_text())
    assert len(data["samples"]) == 2
    assert set(data["mean"]) == {
        "network",
        "mean_image",
        "nearest_sample",
        "pt_equal_time",
        "pt_equal_time+oidn",
        *("pt1", "pt1+oidn", "pt1+oidn-colour", "pt2", "pt2+oidn", "pt2+oidn-colour"),
    }
    for scores in data["mean"].values():
        assert 0 < scores["ssim"] <= 1 and scores["psnr"] > 5 and scores["flip"] is not None
    # more samples per pixel come closer to the reference
    assert data["mean"]["pt2"]["relmse"] < data["mean"]["pt1"]["relmse"]
    table = (tmp_path / "ev" / "results.md").read_text()
    assert "| neural renderer |" in table and "| path tracing, 2 spp + OIDN |" in table
    assert Image.open(tmp_path / "ev" / "grid.png").size[0] > 4 * 32


@pytest.mark.slow
def test_train_with_no_loss_named_trains_and_says_which(reference, tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch-home"))  # no VGG16 weights, as on a fresh machine
    out = tmp_path / "run"
    result = _invoke("train", reference, "--out", out, "--epochs", 1, "--resolution", 32, "--batch-size", 4)
    assert result.exit_code == 0, result.output
    assert "loss: l1 (--loss auto: no VGG16 ImageNet weights at " in result.output
    assert json.loads((out / "config.json").read_text())["loss"]["used"] == "l1"
    args = ("--out", out, "--epochs", 1, "--resolution", 32, "--batch-size", 4, "--json")
    doc = json.loads(_invoke("train", reference, *args).output)
    assert doc["nothing_to_do"] and doc["loss"] == "l1" and doc["loss_reason"].startswith("loss: l1 (--loss auto")


def _snapshot(folder):
    return {
        p: open(os.path.join(folder, p), "rb").read()
        for p in sorted(os.listdir(folder))
        if os.path.isfile(os.path.join(folder, p))
    }


@pytest.mark.slow
def test_bad_input_exits_2_naming_it_and_writes_nothing(run, reference, tmp_path, monkeypatch):
    cases = [
        (["train", tmp_path / "nothere", "--out", tmp_path / "r1", *TRAIN], "nothere"),
        (["train", reference, "--out", tmp_path / "r2", "--loss", "l1", "--resolution", "48"], "--resolution: 48"),
        (["train", reference, "--out", tmp_path / "r3", "--resolution", "32", "--loss", "l1+vgg"], "--vgg-weights"),
        (["train", reference, "--resolution", "32"], "--out"),
        (
            [
                "train",
                reference,
                "--out",
                tmp_path / "r4",
                "--loss",
                "l1",
                "--vgg-weights",
                tmp_path / "no.pth",
                "--loss",
                "l1+vgg",
            ],
            "no.pth",
        ),
        (["infer", tmp_path / "norun", "--out", tmp_path / "x.exr"], "norun"),
        (["evaluate", run, tmp_path / "nothere"], "nothere"),
        (["evaluate", run, reference, "--spp", "0"], "--spp"),
    ]
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch-home"))
    for args, named in cases:
        result = _invoke(*args)
        assert result.exit_code == 2, (args, result.output)
        assert "error:" in result.output and named in result.output, (args, result.output)
    assert os.listdir(tmp_path) == []  # no run folder, no output file


@pytest.mark.slow
def test_a_corrupt_checkpoint_exits_2_and_nothing_is_overwritten(run, reference, tmp_path):
    broken = tmp_path / "run"
    broken.mkdir()
    for name, data in _snapshot(run).items():
        (broken / name).write_bytes(data[: len(data) // 2] if name == "checkpoint.pt" else data)
    before = _snapshot(broken)
    for args in (
        ["train", reference, "--out", broken, "--epochs", 2, *TRAIN],
        ["infer", broken, "--out", tmp_path / "x.exr"],
        ["evaluate", broken, reference, "--spp", "none"],
    ):
        result = _invoke(*args)
        assert result.exit_code == 2 and "checkpoint.pt: a corrupt checkpoint" in result.output, result.output
    assert _snapshot(broken) == before and not (tmp_path / "x.exr").exists()


def _train_process(reference, out, epochs):
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [
        sys.executable,
        "-c",
        "import torch; torch.set_num_threads(1); import cli; cli.main()",
        "train",
        str(reference),
        "--out",
        str(out),
        "--epochs",
        str(epochs),
        *TRAIN,
    ]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


@pytest.mark.slow
def test_kill_9_then_the_same_command_resumes_to_the_same_weights(reference, tmp_path):
    straight = _train_process(reference, tmp_path / "straight", 3)
    assert straight.wait(timeout=600) == 0, straight.stderr.read().decode()
    killed = _train_process(reference, tmp_path / "killed", 3)
    log = tmp_path / "killed" / "log.jsonl"
    deadline = time.monotonic() + 600
    while not (log.exists() and log.read_text().count("\n") >= 1) and time.monotonic() < deadline:
        assert killed.poll() is None, killed.stderr.read().decode()
        time.sleep(0.05)
    os.kill(killed.pid, signal.SIGKILL)  # during epoch 2
    killed.wait()
    assert runfiles.load_checkpoint(str(tmp_path / "killed"))["epoch"] == 1
    again = _train_process(reference, tmp_path / "killed", 3)
    assert again.wait(timeout=600) == 0, again.stderr.read().decode()
    a = runfiles.load_checkpoint(str(tmp_path / "straight"))["model"]
    b = runfiles.load_checkpoint(str(tmp_path / "killed"))["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert [json.loads(line)["epoch"] for line in log.read_text().splitlines()] == [1, 2, 3]


@pytest.mark.slow
def test_infer_and_evaluate_take_checkpoint_best_last_or_a_file(run, reference, tmp_path):
    for which in ("best", "last", run / "checkpoint-best.pt"):
        result = _invoke("infer", run, "--out", tmp_path / "b.exr", "--checkpoint", which)
        assert result.exit_code == 0, result.output
    result = _invoke(
        "evaluate", run, reference, "--spp", "none", "--limit", 1, "--checkpoint", "best", "--out", tmp_path / "ev"
    )
    assert result.exit_code == 0, result.output
    result = _invoke("infer", run, "--out", tmp_path / "x.exr", "--checkpoint", tmp_path / "none.pt")
    assert result.exit_code == 2 and "--checkpoint" in result.output and "none.pt" in result.output
