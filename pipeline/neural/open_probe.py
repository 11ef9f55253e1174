"""What the neural stage does to a dataset before its first step, as one process to measure.

``python -m pipeline.neural.open_probe loader DATASET``
    Opens DATASET (a folder or a publication) as ``train`` does and reads every sample once
    through a DataLoader in this process (no workers, SHA-256 checked): the training
    loader's open and one pass.
``python -m pipeline.neural.open_probe evaluate-setup DATASET``
    What ``evaluate`` does before its first sample: opens DATASET and splits it by material
    (the default held-out fraction) into its test subset.

Each prints one JSON line (samples, seconds); the scale benchmark
(:mod:`pipeline.bench.scale`) runs them as child processes to take their wall time and
peak memory.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from torch.utils.data import DataLoader

from pipeline.errors import USER_ERRORS
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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m pipeline.neural.open_probe", description=__doc__.split("\n\n")[0])
    p.add_argument("probe", choices=PROBES)
    p.add_argument("dataset")
    args = p.parse_args(argv)
    try:
        result = loader_pass(args.dataset) if args.probe == "loader" else evaluate_setup(args.dataset)
    except USER_ERRORS as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
