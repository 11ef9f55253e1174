"""What the neural stage does to a dataset before its first step, as one process to measure.

``scripts/open_probe.py loader DATASET``
    Opens DATASET (a folder or a publication) as ``train`` does and reads every sample once
    through a DataLoader in this process (no workers, SHA-256 checked): the training
    loader's open and one pass.
``scripts/open_probe.py evaluate-setup DATASET``
    What ``evaluate`` does before its first sample: opens DATASET and splits it by material
    (the default held-out fraction) into its test subset.

Each prints one JSON line (samples, seconds); the scale benchmark
(:mod:`pipeline.bench.scale`) runs them as child processes to take their wall time and
peak memory.
"""

from __future__ import annotations

import time

from torch.utils.data import DataLoader

from pipeline.neural.data import collate_samples, open_dataset
from pipeline.neural.splits import split_materials
from pipeline.neural.train import TrainConfig

PROBES = ("loader", "evaluate-setup")


def loader_pass(root: str, batch_size: int = 16) -> dict:
    """Open ``root`` and read every sample once (workers 0, hashes checked)."""
    started = time.perf_counter()
    dataset = open_dataset(root, check_hashes=True)
    opened = time.perf_counter()
    count = 0
    for batch in DataLoader(dataset, batch_size=batch_size, num_workers=0, collate_fn=collate_samples):
        count += len(batch["id"])
    return {"samples": len(dataset), "read": count, "open_s": opened - started, "pass_s": time.perf_counter() - opened}


def evaluate_setup(root: str) -> dict:
    """Open ``root`` and take its held-out subset as ``evaluate`` takes a run's."""
    started = time.perf_counter()
    dataset = open_dataset(root, check_hashes=True)
    _train, test_ids = split_materials(dataset.material_ids, TrainConfig.test_fraction, 0)
    test = dataset.subset(test_ids)
    return {"samples": len(dataset), "test": len(test), "setup_s": time.perf_counter() - started}


def run_probe(probe: str, root: str) -> dict:
    """One of :data:`PROBES` on ``root``."""
    return loader_pass(root) if probe == "loader" else evaluate_setup(root)
