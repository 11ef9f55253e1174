"""The training loop on an in-memory dataset: loss falls, files, resume, refusals."""

import json
import os

import pytest
import torch
from PIL import Image

from pipeline.errors import ShaderballError
from pipeline.neural import runfiles
from pipeline.neural.train import epoch_order, train
from support.neural_fakes import RUN_FILES, FakeSource, train_config

torch.set_num_threads(1)


_config = train_config


def _weights(run_dir):
    return runfiles.load_checkpoint(run_dir)["model"]


@pytest.mark.slow
def test_a_tiny_overfit_drives_the_loss_down(tmp_path):
    source = FakeSource(materials=4, lights=3, resolution=32)
    summary = train(_config(tmp_path, epochs=3, test_fraction=0.0, batch_size=2), source=source)
    losses = [h["train_loss"] for h in summary.history]
    assert len(losses) == 3
    assert losses[2] < losses[1] < losses[0]
    assert losses[2] < 0.6 * losses[0]


def test_run_files_progress_and_baseline(tmp_path):
    events = []
    summary = train(_config(tmp_path), progress=events.append, source=FakeSource())
    run = tmp_path / "run"
    assert sorted(os.listdir(run)) == RUN_FILES
    config = json.loads((run / "config.json").read_text())
    assert config["split"] == {"train": ["m000000", "m000002", "m000003"], "test": ["m000001"]}
    assert config["network"]["parameters"] == summary.parameters
    assert config["baseline"]["test_psnr"] == pytest.approx(summary.baseline_psnr)
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [e["epoch"] for e in log] == [1, 2]
    assert {"train_loss", "test_loss", "test_psnr", "samples_per_s", "time_s"} <= set(log[-1])
    assert Image.open(run / "loss.png").size == (640, 400)
    assert events[0] == {"note": "loss: l1 (--loss l1)"} == {"note": summary.loss_reason}
    batches = [e for e in events[1:] if "batch" in e]
    assert [(e["epoch"], e["batch"]) for e in batches] == [(1, 1), (1, 2), (1, 3), (2, 1), (2, 2), (2, 3)]
    # the training steps' time, said once, from the first epoch's steps (3: timed whole, the first left out)
    notes = [e["note"] for e in events[1:] if "note" in e]
    assert notes[0].startswith("training steps: about ") and events.index({"note": notes[0]}) == 3
    assert " for 2 epochs (" in notes[0] and " x 6 steps" in notes[0]
    # then the whole run's, after the first epoch: its training and its scoring, times the epochs
    whole = [e for e in events if e.get("note", "").startswith("estimate: about ")]
    assert len(whole) == 1 and whole[0]["note"] == summary.estimate and " for 2 epochs (" in summary.estimate
    assert whole[0]["train_s"] == log[0]["time_s"] and whole[0]["score_s"] > 0
    assert summary.estimated_seconds == pytest.approx(2 * (whole[0]["train_s"] + whole[0]["score_s"]))
    assert summary.to_dict()["estimated_seconds"] == summary.estimated_seconds
    # and after each epoch: the epochs done of the run's, the time so far, an ETA from the epochs measured
    done = [e for e in events if e.get("note", "").startswith("epoch ")]
    assert [e["note"].split(":")[0] for e in done] == ["epoch 1/2 done", "epoch 2/2 done"]
    assert " so far, ETA " in done[0]["note"] and done[0]["eta_s"] > 0 and done[1]["eta_s"] == 0
    assert events.index(whole[0]) < events.index(done[0]) and done[0]["elapsed_s"] <= done[1]["elapsed_s"]
    assert batches[-1]["eta_s"] == 0 and batches[0]["samples_per_s"] > 0


def test_epoch_order_is_a_pure_function_of_seed_and_epoch():
    assert epoch_order(10, 1, 3) == epoch_order(10, 1, 3)
    assert sorted(epoch_order(10, 1, 3)) == list(range(10))
    assert epoch_order(10, 1, 3) != epoch_order(10, 1, 4)


@pytest.mark.slow
def test_resume_gives_the_weights_of_an_uninterrupted_run(tmp_path):
    source = FakeSource()
    train(_config(tmp_path, "straight", epochs=3), source=source)
    train(_config(tmp_path, "resumed", epochs=1), source=source)
    summary = train(_config(tmp_path, "resumed", epochs=3), source=source)
    assert summary.resumed_from == 1
    a, b = _weights(str(tmp_path / "straight")), _weights(str(tmp_path / "resumed"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    log = (tmp_path / "resumed" / "log.jsonl").read_text().splitlines()
    assert [json.loads(line)["epoch"] for line in log] == [1, 2, 3]


def test_a_finished_run_is_left_as_it_is(tmp_path):
    source = FakeSource()
    train(_config(tmp_path, epochs=1), source=source)
    before = (tmp_path / "run" / "checkpoint.pt").read_bytes()
    summary = train(_config(tmp_path, epochs=1), source=source)
    assert summary.resumed_from == 1 and (tmp_path / "run" / "checkpoint.pt").read_bytes() == before


def _snapshot(folder):
    return {name: (folder / name).read_bytes() for name in sorted(os.listdir(folder))}


def test_a_corrupt_checkpoint_is_refused_and_nothing_is_overwritten(tmp_path):
    source = FakeSource()
    train(_config(tmp_path, epochs=1), source=source)
    ckpt = tmp_path / "run" / "checkpoint.pt"
    ckpt.write_bytes(ckpt.read_bytes()[:1000])
    before = _snapshot(tmp_path / "run")
    with pytest.raises(ShaderballError, match=r"checkpoint.pt: a corrupt checkpoint"):
        train(_config(tmp_path, epochs=2), source=source)
    assert _snapshot(tmp_path / "run") == before


def test_another_configuration_on_a_run_folder_is_refused(tmp_path):
    source = FakeSource()
    train(_config(tmp_path, epochs=1), source=source)
    before = _snapshot(tmp_path / "run")
    with pytest.raises(ShaderballError, match=r"another configuration \(differs in: lr\)"):
        train(_config(tmp_path, epochs=2, lr=5e-3), source=source)
    assert _snapshot(tmp_path / "run") == before


def test_a_folder_with_other_files_is_refused(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "notes.txt").write_text("mine")
    with pytest.raises(ShaderballError, match="^out: .* holds other files"):
        train(_config(tmp_path), source=FakeSource())
    assert os.listdir(tmp_path / "run") == ["notes.txt"]


@pytest.mark.parametrize(
    "field,value",
    [
        ("epochs", 0),
        ("batch_size", 0),
        ("lr", 0.0),
        ("loss", "l3"),
        ("device", "tpu"),
        ("resolution", 50),
        ("test_fraction", 1.0),
        ("seed", -1),
        ("loader_workers", -1),
    ],
)
def test_bad_options_name_themselves(tmp_path, field, value):
    with pytest.raises(ShaderballError, match=f"^{field}: "):  # the field, by its name
        train(_config(tmp_path, **{field: value}), source=FakeSource())
    assert not (tmp_path / "run").exists()


def test_missing_vgg_weights_refuse_before_anything_is_written(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch-home"))
    with pytest.raises(ShaderballError, match="^vgg_weights: "):
        train(_config(tmp_path, loss="l1+vgg"), source=FakeSource())
    assert not (tmp_path / "run").exists()


def test_the_default_loss_is_l1_without_vgg_weights_and_says_so(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch-home"))
    summary = train(_config(tmp_path, loss="auto"), source=FakeSource())
    assert summary.loss == "l1"
    assert summary.loss_reason.startswith("loss: l1 (--loss auto: no VGG16 ImageNet weights at ")
    # the reason is said once, before training (the progress' note); the summary names the loss
    assert summary.loss_reason not in summary.lines() and summary.lines()[0].endswith(", loss l1)")
    assert summary.to_dict()["loss"] == "l1" and summary.to_dict()["loss_reason"] == summary.loss_reason
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["loss"] == {"requested": "auto", "used": "l1", "reason": summary.loss_reason}
    assert config["identity"]["loss"] == "l1"
    # the same run named explicitly resumes it: auto's choice is the run's identity
    again = train(_config(tmp_path, loss="l1", epochs=3), source=FakeSource())
    assert again.resumed_from == 2 and again.epochs_done == 3


def test_the_default_loss_is_the_papers_where_vgg_weights_are_found(tmp_path, monkeypatch):
    from pipeline.neural.vgg import HUB_FILENAME, random_vgg16_state_dict, sha256_of

    home = tmp_path / "torch-home"
    (home / "hub" / "checkpoints").mkdir(parents=True)
    weights = home / "hub" / "checkpoints" / HUB_FILENAME
    torch.save(random_vgg16_state_dict(1), weights)
    monkeypatch.setenv("TORCH_HOME", str(home))
    summary = train(_config(tmp_path, loss="auto", epochs=1, vgg_sha256=sha256_of(weights)), source=FakeSource())
    assert summary.loss == "l1+vgg" and str(weights) in summary.loss_reason
    assert "train_vgg" in summary.history[-1]


def test_the_best_checkpoint_holds_the_weights_only_and_resume_uses_the_last(tmp_path):
    train(_config(tmp_path, epochs=1), source=FakeSource())
    run = tmp_path / "run"
    best = runfiles.load_checkpoint(str(run), checkpoint="best")
    last = runfiles.load_checkpoint(str(run))
    assert "optimizer" not in best and "optimizer" in last
    assert best["model"].keys() == last["model"].keys()
    assert (run / "checkpoint-best.pt").stat().st_size < 0.5 * (run / "checkpoint.pt").stat().st_size
    assert train(_config(tmp_path, epochs=2), source=FakeSource()).resumed_from == 1


def test_a_run_below_the_mean_image_says_so_with_what_to_try():
    from pipeline.neural.train_summary import TrainSummary

    history = [{"epoch": 2, "train_loss": 0.2, "test_loss": 0.3, "test_psnr": 17.01, "lr": 1e-3}]
    below = TrainSummary("RUN", 2, 0, history=history, baseline_psnr=17.30)
    text = below.lines()[-1]
    assert text.startswith("warning: held-out PSNR 17.01 dB after epoch 2 is below the training-set mean image's 17.30")
    assert "--epochs" in text and "--lr" in text and "more training data" in text
    assert below.to_dict()["below_mean_image"] == text.removeprefix("warning: ")
    above = TrainSummary("RUN", 2, 0, history=[dict(history[0], test_psnr=18.0)], baseline_psnr=17.30)
    assert above.below_mean_image is None and not any("mean image's" in line for line in above.lines())
