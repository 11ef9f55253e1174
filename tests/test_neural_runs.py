"""A run folder across commands (issue 22): fewer --epochs than done, the CSV log, the best
checkpoint beside the last, the warnings of a run that does not learn."""

import json
import os

import pytest
import torch

from pipeline.errors import ShaderballError
from pipeline.neural.train import TrainConfig, train
from support.neural_fakes import FakeSource

torch.set_num_threads(1)


def _config(tmp_path, name="run", **kw):
    base = dict(
        dataset="(in memory)",
        out=str(tmp_path / name),
        epochs=2,
        batch_size=2,
        lr=1e-3,
        loss="l1",
        device="cpu",
        seed=5,
        test_fraction=0.25,
    )
    base.update(kw)
    return TrainConfig(**base)


def _snapshot(folder):
    return {name: (folder / name).read_bytes() for name in sorted(os.listdir(folder))}


def test_fewer_epochs_than_done_is_refused_and_config_json_is_kept(tmp_path):
    source = FakeSource()
    train(_config(tmp_path, epochs=2), source=source)
    before = _snapshot(tmp_path / "run")
    with pytest.raises(ShaderballError, match=r"--epochs: 1 is not allowed; allowed: at least 2: .* already trained 2"):
        train(_config(tmp_path, epochs=1), source=source)
    assert _snapshot(tmp_path / "run") == before
    assert json.loads((tmp_path / "run" / "config.json").read_text())["options"]["epochs"] == 2


def test_the_same_epochs_again_says_nothing_to_do_and_writes_nothing(tmp_path):
    source = FakeSource()
    train(_config(tmp_path, epochs=1), source=source)
    before = _snapshot(tmp_path / "run")
    summary = train(_config(tmp_path, epochs=1), source=source)
    assert summary.nothing_to_do and summary.epochs_done == 1
    assert any("nothing to do" in line for line in summary.lines())
    assert _snapshot(tmp_path / "run") == before
