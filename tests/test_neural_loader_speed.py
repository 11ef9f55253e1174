"""The loader under load: collation is numpy's, on the calling thread, with
the values of torch's default; and the loader's rate with two busy processes beside it stays
a fair share of its rate without them. The figures: ``shaderball neural-bench collate``
(docs/neural.md, "Speed on a CPU")."""

import json
import os
import time

import pytest
import torch
from click.testing import CliRunner
from torch.utils.data import DataLoader, default_collate

from cli import main
from pipeline.image.tonemap import DEFAULT_EXPOSURE
from pipeline.neural import data
from pipeline.neural.bench import busy_processes, measure_loader
from pipeline.neural.data import collate_samples, open_dataset


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        torch.equal(a[k], b[k]) and a[k].dtype == b[k].dtype if isinstance(a[k], torch.Tensor) else a[k] == b[k]
        for k in a
    )


def test_collation_equals_torchs_default(reference):
    ds = open_dataset(str(reference))
    samples = [ds[i] for i in range(5)]
    assert _same(collate_samples(samples), default_collate(samples))


def test_collation_calls_no_torch_kernel(reference, monkeypatch):
    """No torch.stack/cat (whose intra-op threads contend with other work): numpy copies."""
    samples = [open_dataset(str(reference))[i] for i in range(3)]

    def refused(*args, **kwargs):
        raise AssertionError("collation called a torch kernel")

    monkeypatch.setattr(torch, "stack", refused)
    monkeypatch.setattr(torch, "cat", refused)
    batch = collate_samples(samples)
    assert batch["maps"].shape == (3, *samples[0]["maps"].shape)


@pytest.mark.slow
def test_worker_batches_equal_in_process_ones_and_lie_in_shared_memory(reference):
    ds = open_dataset(str(reference))
    one = list(data.batches(ds, 4, 0))
    two = list(data.batches(ds, 4, 2))
    assert len(one) == len(two) and all(_same(a, b) for a, b in zip(one, two))
    assert all(b["maps"].is_shared() for b in two)
    assert list(DataLoader(ds, batch_size=4, collate_fn=collate_samples))[0]["id"] == one[0]["id"]


@pytest.mark.slow
def test_the_loader_keeps_a_fair_share_with_two_busy_processes(reference):
    """3 pairs of passes, each a pass without and a pass with two busy processes beside it, with
    the intra-op threads at the core count: in the best pair the loaded rate stays above a quarter
    of the other. A fair share of 2 cores against 2 spinners is about 2/3 (more when the machine
    is busy already: the pass without is loaded too); torch's collation fell to 1/15 (643 -> 42
    samples/s). A ratio within a pair, run back to back, so the machine's own load changing
    between passes counts little."""
    before = torch.get_num_threads()
    torch.set_num_threads(os.cpu_count() or 1)
    try:
        idle, loaded = [], []
        for _ in range(3):
            idle.append(measure_loader(str(reference), None, DEFAULT_EXPOSURE, True, 6, 0).samples_per_s)
            with busy_processes(2):
                loaded.append(measure_loader(str(reference), None, DEFAULT_EXPOSURE, True, 6, 0).samples_per_s)
    finally:
        torch.set_num_threads(before)
    ratios = [with_busy / without for with_busy, without in zip(loaded, idle)]
    assert max(ratios) >= 0.25, f"without {idle}, with two busy processes {loaded} samples/s"


def test_the_loader_rate_leaves_start_up_out(reference):
    """A first batch that takes half a second (as spawning workers does) is start-up: the
    steady rate counts the samples after it over the time after it."""
    calls = []

    def slow_first(samples):
        if not calls:
            time.sleep(0.5)
        calls.append(len(samples))
        return collate_samples(samples)

    rate = measure_loader(str(reference), None, DEFAULT_EXPOSURE, True, 4, 0, collate=slow_first)
    assert rate.samples == 16 and rate.startup_samples == 4 and calls == [4, 4, 4, 4]
    assert rate.startup_s >= 0.5
    assert rate.steady_samples_per_s > rate.samples_per_s  # the whole pass pays the half second
    whole_s = rate.samples / rate.samples_per_s
    assert rate.steady_samples_per_s == pytest.approx(12 / (whole_s - rate.startup_s), rel=0.05)


def test_train_benchmark_prints_start_up_on_its_own_line(reference):
    args = ["train", str(reference), "--benchmark", "--loss", "l1", "--resolution", "32", "--batch-size", "4"]
    args += ["--loader-workers", "1"]
    text = CliRunner().invoke(main, args)
    assert text.exit_code == 0, text.output
    lines = text.output.splitlines()
    assert lines[0].startswith("loader: ") and "samples/s steady (16 samples" in lines[0], lines
    assert lines[1].startswith("loader start-up: ") and "(4 samples, 1 workers started)" in lines[1], lines
    done = CliRunner().invoke(main, [*args, "--json"])
    assert done.exit_code == 0, done.output
    result = json.loads(done.output)
    assert result["loader_startup_samples"] == 4 and result["loader_startup_s"] > 0
    assert result["loader_samples_per_s"] > 0 and result["loader_overall_samples_per_s"] > 0
