"""`train --devices N`: DistributedDataParallel on the CPU (gloo) in two processes against one.

Tolerance: the first step's loss (the same weights; only BatchNorm's and the loss's sums are
added in another order) within 1e-5 relative. Later steps within 2e-3 relative: DDP's averaged
gradient is the whole batch's mean gradient up to summation order, but Adam divides each gradient
by its own running magnitude, so float noise in components whose gradient is near zero (e.g. the
conv biases before a BatchNorm, zero in exact arithmetic) becomes updates of the learning rate's
size. The one-process run itself moves as much with another thread count or memory format
(measured: 4e-4 relative at step 3, 2e-2 at step 5), so a few steps only are compared.
BatchNorm's statistics are the whole batch's (CpuSyncBatchNorm), not each rank's.
"""

import subprocess
import sys

import pytest
import torch
from torch.utils.data.distributed import DistributedSampler

from pipeline.errors import ShaderballError
from pipeline.fields import FieldError
from pipeline.neural import runfiles
from pipeline.neural.config import TrainConfig
from pipeline.neural.distributed import FAIL_HOOK, Ranks
from pipeline.neural.infer import load_run_model
from pipeline.neural.train import train
from support.neural_fakes import RUN_FILES, FakeSource, train_config

torch.set_num_threads(1)
FIRST_STEP_RTOL = 1e-5
LATER_STEPS_RTOL = 2e-3


def _losses(events):
    return [e["loss"] for e in events if "loss" in e]


def test_a_batch_not_divisible_by_the_devices_is_refused_naming_both():
    with pytest.raises(FieldError) as caught:
        TrainConfig(dataset="x", out="y", batch_size=5, devices=2)
    assert caught.value.name == "batch_size" and "{devices}" in caught.value.allowed
    assert TrainConfig(dataset="x", out="y", batch_size=6, devices=3).devices == 3


@pytest.mark.parametrize("length,world", [(10, 1), (10, 2), (9, 2), (7, 4), (2, 3)])
def test_the_shards_are_distributed_samplers_and_one_process_keeps_the_order(length, world):
    order = torch.randperm(length, generator=torch.Generator().manual_seed(length)).tolist()
    for rank in range(world):
        sampler = DistributedSampler(range(length), num_replicas=world, rank=rank, shuffle=False)
        assert Ranks(rank, world, torch.device("cpu")).shard(order) == [order[i] for i in sampler]
    assert Ranks(0, 1, torch.device("cpu")).shard(order) == order


@pytest.mark.slow
def test_two_processes_train_as_one_and_the_checkpoint_loads_and_resumes(tmp_path):
    source = FakeSource(materials=4, lights=2)  # 6 training samples: 3 batches of 2, 1 a process
    one_events, two_events = [], []
    kw = dict(epochs=1, batch_size=2, threads=1)
    one = train(train_config(tmp_path, "one", **kw), progress=one_events.append, source=source)
    two = train(train_config(tmp_path, "two", devices=2, **kw), progress=two_events.append, source=source)
    a, b = _losses(one_events), _losses(two_events)
    assert len(a) == len(b) == 3
    assert b[0] == pytest.approx(a[0], rel=FIRST_STEP_RTOL)
    assert b[1:] == pytest.approx(a[1:], rel=LATER_STEPS_RTOL)
    assert two.history[0]["train_loss"] == pytest.approx(one.history[0]["train_loss"], rel=LATER_STEPS_RTOL)
    assert two.history[0]["test_loss"] == pytest.approx(one.history[0]["test_loss"], rel=1e-2)
    assert two.device == "2 x cpu (DistributedDataParallel)" and two_events[0] == one_events[0]
    run = tmp_path / "two"
    assert sorted(p.name for p in run.iterdir()) == RUN_FILES  # rank 0's files, no other
    model, _ = load_run_model(str(run), torch.device("cpu"))  # a plain network: infer's
    assert not model.training
    again = train(train_config(tmp_path, "two", devices=2, **dict(kw, epochs=2)), source=source)
    assert again.resumed_from == 1 and [h["epoch"] for h in again.history] == [1, 2]
    assert runfiles.load_checkpoint(str(run))["epoch"] == 2


@pytest.mark.slow
@pytest.mark.parametrize("how", ["raise", "kill"])
def test_a_rank_that_dies_ends_the_run_with_one_line(tmp_path, how):
    script = (
        "import sys; sys.path.insert(0, 'tests')\n"
        "from support.neural_fakes import FakeSource, train_config\n"
        "from pipeline.neural.train import train\n"
        "from pipeline.errors import ShaderballError\n"
        "if __name__ == '__main__':\n"
        "    try:\n"
        f"        train(train_config(__import__('pathlib').Path({str(tmp_path)!r}), devices=2, threads=1), "
        "source=FakeSource())\n"
        "    except ShaderballError as exc:\n"
        "        print('error:', exc, file=sys.stderr); sys.exit(2)\n"
    )
    hook = "1:2" if how == "raise" else "1:2:kill"
    done = subprocess.run(
        [sys.executable, "-c", script],
        env={**__import__("os").environ, FAIL_HOOK: hook},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert "Traceback" not in done.stderr and len(lines) == 1, done.stderr
    cause = "failed: RuntimeError: " + FAIL_HOOK if how == "raise" else "ended by signal SIGKILL"
    assert lines[0].startswith(f"error: training process 1 of 2 {cause}"), lines
    assert "the same command resumes it" in lines[0]


def test_a_refusal_in_a_rank_is_the_one_process_refusal(tmp_path):
    train(train_config(tmp_path, epochs=1), source=FakeSource())
    with pytest.raises(ShaderballError, match="is a run of another configuration"):
        train(train_config(tmp_path, epochs=2, lr=0.5, devices=2, threads=1), source=FakeSource())
