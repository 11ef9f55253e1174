"""The neural stage on a CUDA device: device auto-selection, a training step and the
inference time. Skipped, with the reason, where torch sees no CUDA device (CI here)."""

import time

import pytest
import torch

from pipeline.neural.loss import RenderLoss
from pipeline.neural.network import NeuralRenderer
from pipeline.neural.train import pick_device

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device; torch sees none"),
]


def test_auto_picks_cuda():
    assert pick_device("auto").type == "cuda"


def test_a_training_step_at_400_on_cuda_lowers_the_loss():
    torch.manual_seed(0)
    model = NeuralRenderer(400).cuda()
    loss_fn = RenderLoss("l1").cuda()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    maps, light = torch.rand(2, 12, 400, 400, device="cuda"), torch.rand(2, 4, device="cuda")
    target = torch.rand(2, 3, 400, 400, device="cuda") * 0.2
    losses = []
    for _ in range(5):
        optimizer.zero_grad()
        loss = loss_fn(model(maps, light), target)
        loss.backward()
        optimizer.step()
        losses.append(float(loss))
    assert losses[-1] < losses[0]


def test_inference_at_400_is_milliseconds():
    model = NeuralRenderer(400).cuda().eval()
    maps, light = torch.rand(1, 12, 400, 400, device="cuda"), torch.rand(1, 4, device="cuda")
    with torch.no_grad():
        for _ in range(3):
            model(maps, light)
        torch.cuda.synchronize()
        started = time.perf_counter()
        for _ in range(20):
            model(maps, light)
        torch.cuda.synchronize()
    ms = (time.perf_counter() - started) / 20 * 1000
    assert ms < 50, f"{ms:.1f} ms per 400x400 image"  # a loose bound: `train --benchmark --device cuda` measures it
