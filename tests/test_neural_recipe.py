"""The options for a CPU-scale reproduction: --width, --split-seed, --train-materials,
--schedule/--warmup-epochs, the training PSNR per epoch, and a run made before them that
still resumes (its identity unchanged)."""

import json
import math

import pytest
import torch

from pipeline.errors import ShaderballError
from pipeline.neural import runfiles
from pipeline.neural.infer import load_run_model
from pipeline.neural.network import NeuralRenderer, parameter_count
from pipeline.neural.splits import split_materials
from pipeline.neural.train import (
    IDENTITY_FIELDS,
    TrainConfig,
    learning_rate,
    run_identity,
    select_training_materials,
    train,
)
from tests.support.neural_fakes import FakeSource, train_config

torch.set_num_threads(1)


def test_width_scales_the_channels_and_keeps_the_interface():
    full, half = NeuralRenderer(32), NeuralRenderer(32, 0.5)
    assert half.width == 0.5 and half.light_channels == 64
    # the convolutions hold almost every parameter: about a quarter at half the channels
    assert 0.2 < parameter_count(half) / parameter_count(full) < 0.3
    maps, light = torch.rand(2, 12, 32, 32), torch.rand(2, 4)
    assert half(maps, light).shape == full(maps, light).shape == (2, 3, 32, 32)
    assert NeuralRenderer(32, 0.01).encoder[0][0].out_channels == 1  # never 0 channels


@pytest.mark.parametrize("width", [0, -0.5, 1.5, float("nan"), True, "0.5"])
def test_a_width_outside_0_1_is_refused_by_name(tmp_path, width):
    with pytest.raises(ShaderballError, match="^width: "):
        train_config(tmp_path, width=width)


def test_a_narrow_run_is_loaded_at_its_width(tmp_path):
    config = train_config(tmp_path, width=0.25, epochs=1)
    train(config, source=FakeSource(materials=4))
    saved = runfiles.read_config(config.out)
    assert saved["network"]["width"] == 0.25 and saved["identity"]["width"] == 0.25
    model, _ = load_run_model(config.out, torch.device("cpu"))
    assert model.width == 0.25 and parameter_count(model) == saved["network"]["parameters"]


def test_warm_up_then_cosine_decay_is_a_function_of_the_step():
    config = TrainConfig(dataset="d", out="o", epochs=4, lr=1e-3, schedule="cosine", warmup_epochs=1)
    steps = 10
    rates = [learning_rate(config, s, steps) for s in range(4 * steps)]
    assert rates[0] == pytest.approx(1e-4) and rates[steps - 1] == pytest.approx(1e-3)  # linear warm-up
    assert all(a < b for a, b in zip(rates[: steps - 1], rates[1:steps]))
    decay = rates[steps:]
    assert decay[0] == pytest.approx(1e-3) and all(a > b for a, b in zip(decay, decay[1:]))
    assert decay[-1] < 0.01 * 1e-3  # reaches ~0 at the last step of --epochs
    flat = TrainConfig(dataset="d", out="o", epochs=4, lr=1e-3)
    assert {learning_rate(flat, s, steps) for s in range(40)} == {1e-3}


def test_a_cosine_run_killed_mid_way_ends_with_the_same_weights(tmp_path):
    kw = dict(epochs=3, schedule="cosine", warmup_epochs=0.5, seed=2)
    whole = train_config(tmp_path, "whole", **kw)
    train(whole, source=FakeSource(materials=4))

    class Killed(Exception):
        pass

    def kill_in_epoch_3(event):
        if event.get("epoch") == 3 and event.get("batch") == 1:
            raise Killed

    cut = train_config(tmp_path, "cut", **kw)
    with pytest.raises(Killed):
        train(cut, progress=kill_in_epoch_3, source=FakeSource(materials=4))
    assert runfiles.load_checkpoint(cut.out)["epoch"] == 2
    summary = train(cut, source=FakeSource(materials=4))
    assert summary.resumed_from == 2
    a, b = runfiles.load_checkpoint(whole.out)["model"], runfiles.load_checkpoint(cut.out)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    lrs = [e["lr"] for e in runfiles.read_log(cut.out)]
    assert lrs == [e["lr"] for e in runfiles.read_log(whole.out)] and lrs[0] > lrs[1] > lrs[2]


def test_a_cosine_run_is_not_extended_past_its_epochs(tmp_path):
    config = train_config(tmp_path, epochs=1, schedule="cosine")
    train(config, source=FakeSource(materials=4))
    with pytest.raises(ShaderballError, match="another configuration .*epochs"):
        train(train_config(tmp_path, epochs=2, schedule="cosine"), source=FakeSource(materials=4))


def test_training_materials_are_nested_subsets_and_too_many_is_refused():
    ids = [f"m{i:06d}" for i in range(40)]
    small, large = (set(select_training_materials(ids, n, 7)) for n in (5, 20))
    assert len(small) == 5 and len(large) == 20 and small < large
    assert select_training_materials(ids, None, 7) == ids
    assert set(select_training_materials(ids, 5, 8)) != small  # the order comes from the split seed
    with pytest.raises(ShaderballError, match="^train_materials: 41 .*at most 40"):
        select_training_materials(ids, 41, 7)


def test_seeds_share_one_held_out_set_with_a_split_seed(tmp_path):
    source = FakeSource(materials=8)
    for seed in (1, 2):
        train(train_config(tmp_path, f"s{seed}", seed=seed, split_seed=0, epochs=1, train_materials=3), source=source)
    a, b = (runfiles.read_config(str(tmp_path / f"s{seed}")) for seed in (1, 2))
    assert a["split"]["test"] == b["split"]["test"] == split_materials(source.material_ids, 0.25, 0)[1]
    assert a["split"]["train"] == b["split"]["train"] and len(a["split"]["train"]) == 3
    assert not set(a["split"]["train"]) & set(a["split"]["test"])
    assert a["identity_digest"] != b["identity_digest"]  # other weights and order


def test_a_run_made_before_these_options_keeps_its_identity():
    """These options join the identity only when not their defaults: an older run's
    config.json digest is unchanged, so it resumes."""
    identity = run_identity(TrainConfig(dataset="d", out="o"), {"x": 1}, 64, None)
    assert set(identity) == {*IDENTITY_FIELDS, "dataset", "vgg_sha256"}
    changed = run_identity(TrainConfig(dataset="d", out="o", width=0.5, schedule="cosine"), {"x": 1}, 64, None)
    assert changed["width"] == 0.5 and changed["schedule"] == "cosine" and changed["epochs"] == 30


def test_the_log_has_a_training_psnr_per_epoch(tmp_path):
    config = train_config(tmp_path, epochs=2)
    train(config, source=FakeSource(materials=4))
    history = runfiles.read_log(config.out)
    assert all(math.isfinite(e["train_psnr"]) and e["train_eval_loss"] > 0 for e in history)
    header = (tmp_path / "run" / "log.csv").read_text().splitlines()[0].split(",")
    assert {"train_psnr", "train_eval_loss"} <= set(header)
    assert json.loads((tmp_path / "run" / "log.jsonl").read_text().splitlines()[0])["train_psnr"] > 0
