"""`shaderball train DATASET --benchmark`: loader, training and inference rates.

- loader: EXR reading, SHA-256 check, decoding and assembly of every sample of the
  dataset through a DataLoader with the given workers, from a fresh dataset object (so
  the per-process maps cache starts empty, as in a first epoch);
- training: steps of the network with the chosen loss on random inputs at the dataset's
  network resolution (a randomly initialised VGG16 stands in for ImageNet weights: the
  rate does not depend on the weights' values);
- inference: the network at batch 1, mean of repeated timed calls after a warm-up.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from torch.utils.data import DataLoader

from pipeline.neural.data import open_dataset
from pipeline.neural.loss import RenderLoss
from pipeline.neural.network import NeuralRenderer
from pipeline.neural.train import TrainConfig, pick_device
from pipeline.neural.vgg import RELU3_3, random_vgg16_state_dict, vgg16_features


@dataclass
class BenchResult:
    resolution: int
    device: str
    workers: int
    loader_samples: int
    loader_samples_per_s: float
    loader_hash_checked: bool
    train_batch: int
    train_samples_per_s: float
    train_loss: str
    infer_ms: float
    threads: int

    def lines(self) -> list[str]:
        return [
            f"loader: {self.loader_samples_per_s:.1f} samples/s ({self.loader_samples} samples at "
            f"{self.resolution}x{self.resolution}, {self.workers} workers, SHA-256 "
            f"{'checked' if self.loader_hash_checked else 'not checked'})",
            f"training: {self.train_samples_per_s:.2f} samples/s (batch {self.train_batch}, {self.train_loss}, "
            f"{self.device}, {self.threads} torch threads)",
            f"inference: {self.infer_ms:.1f} ms per image (batch 1, {self.device})",
        ]

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def loader_rate(config: TrainConfig) -> tuple[int, float, int]:
    dataset = open_dataset(config.dataset, resolution=config.resolution, exposure=config.exposure,
                           check_hashes=config.check_hashes)
    loader = DataLoader(dataset, batch_size=config.batch_size, num_workers=config.workers,
                        persistent_workers=False)
    started, count = time.perf_counter(), 0
    for batch in loader:
        count += batch["maps"].shape[0]
    return count, count / (time.perf_counter() - started), dataset.resolution


def benchmark(config: TrainConfig, steps: int = 5, infer_repeats: int = 10) -> BenchResult:
    """Loader, training and inference rates for ``config``; writes nothing."""
    config.check()
    device = pick_device(config.device)
    count, rate, resolution = loader_rate(config)
    model = NeuralRenderer(resolution).to(device)
    if config.loss == "l1+vgg":
        vgg = vgg16_features(upto=RELU3_3)
        vgg.load_state_dict({k.removeprefix("features."): v for k, v in random_vgg16_state_dict(0).items()
                             if int(k.split(".")[1]) <= RELU3_3})
        loss_fn = RenderLoss("l1+vgg", vgg.eval().requires_grad_(False), config.vgg_weight).to(device)
    else:
        loss_fn = RenderLoss("l1").to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    maps = torch.rand(config.batch_size, 12, resolution, resolution, device=device)
    light = torch.rand(config.batch_size, 4, device=device)
    target = torch.rand(config.batch_size, 3, resolution, resolution, device=device)

    def step():
        optimizer.zero_grad(set_to_none=True)
        loss_fn(model(maps, light), target).backward()
        optimizer.step()

    step()
    _sync(device)
    started = time.perf_counter()
    for _ in range(steps):
        step()
    _sync(device)
    train_rate = steps * config.batch_size / (time.perf_counter() - started)

    model.eval()
    with torch.no_grad():
        one, one_light = maps[:1], light[:1]
        model(one, one_light)
        _sync(device)
        started = time.perf_counter()
        for _ in range(infer_repeats):
            model(one, one_light)
        _sync(device)
        infer_ms = (time.perf_counter() - started) / infer_repeats * 1000
    return BenchResult(resolution, str(device), config.workers, count, rate, config.check_hashes,
                       config.batch_size, train_rate, config.loss, infer_ms, torch.get_num_threads())
