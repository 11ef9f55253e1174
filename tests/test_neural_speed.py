"""train's speed options: bf16 autocast still learns, channels-last
computes the same step, --threads holds for the call only, and what a CPU cannot do is refused.
Their rates: ``shaderball neural-bench train-options`` (docs/neural.md, "Speed on a CPU")."""

import pytest
import torch

from pipeline.errors import ShaderballError
from pipeline.neural import runfiles, speed
from pipeline.neural.loss import RenderLoss
from pipeline.neural.network import NeuralRenderer
from pipeline.neural.train import train
from support.neural_fakes import FakeSource, epoch_threads, train_config

torch.set_num_threads(1)


def _run(tmp_path, name, **options):
    source = FakeSource(materials=8, lights=2, resolution=32, seed=3)
    config = train_config(tmp_path, name, epochs=4, batch_size=4, test_fraction=0.25, **options)
    return train(config, source=source)


@pytest.mark.slow
def test_bf16_learns_like_fp32(tmp_path):
    fp32 = _run(tmp_path, "fp32", precision="fp32")
    bf16 = _run(tmp_path, "bf16", precision="bf16")
    first, last = bf16.history[0]["test_loss"], bf16.history[-1]["test_loss"]
    reference = fp32.history[-1]["test_loss"]
    print(f"held-out loss after 4 epochs: fp32 {reference:.5f}, bf16 {last:.5f} (bf16 epoch 1: {first:.5f})")
    assert last < first
    assert abs(last - reference) <= 0.2 * reference + 0.005, (reference, last)
    weights = runfiles.load_checkpoint(bf16.run_dir)["model"]
    assert all(
        w.dtype == torch.float32 for w in weights.values() if w.is_floating_point()
    )  # autocast keeps float32 weights


def test_channels_last_computes_the_same_loss_and_gradients():
    torch.manual_seed(0)
    model, loss_fn = NeuralRenderer(32), RenderLoss("l1")
    maps, light, target = torch.rand(2, 12, 32, 32), torch.rand(2, 4), torch.rand(2, 3, 32, 32)
    results = []
    for channels_last in (False, True):
        forward = speed.step_forward(model, loss_fn, channels_last, compile=False)
        fmt = speed.memory_format(channels_last)
        model.zero_grad()
        loss = loss_fn(forward(maps.to(memory_format=fmt), light), target.to(memory_format=fmt))
        loss.backward()
        results.append((float(loss), [p.grad.clone() for p in model.parameters()]))
    assert model.output.weight.is_contiguous(memory_format=torch.channels_last)
    assert results[0][0] == pytest.approx(results[1][0], rel=1e-5)
    assert all(torch.allclose(a, b, rtol=1e-3, atol=1e-6) for a, b in zip(results[0][1], results[1][1]))


def test_threads_hold_for_the_call_only(tmp_path, monkeypatch):
    seen = epoch_threads(monkeypatch)
    before = torch.get_num_threads()
    _run(tmp_path, "threads", threads=2)
    assert seen == [2] * 4 and torch.get_num_threads() == before


def test_auto_precision_is_bf16_on_a_cpu_with_bf16_instructions_and_fp32_else(tmp_path):
    summary = _run(tmp_path, "auto", precision="auto")
    ran = runfiles.read_config(summary.run_dir)["options"]["precision"]
    assert ran == ("bf16" if speed.native_bf16() else "fp32")
    assert speed.resolve_precision("auto", torch.device("cuda")) == "fp32"


@pytest.mark.parametrize(
    "options, match",
    [
        ({"precision": "fp16"}, "^precision: .*fp32 or bf16 on a CPU"),
        ({"precision": "int8"}, r'^precision: .*"fp32", "bf16", "fp16"'),
        ({"threads": -1}, "^threads: "),
    ],
)
def test_refused_speed_options(tmp_path, options, match):
    with pytest.raises(ShaderballError, match=match):
        _run(tmp_path, "refused", **options)
    assert not (tmp_path / "refused").exists()
