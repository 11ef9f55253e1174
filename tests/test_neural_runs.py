"""A run folder across commands: fewer --epochs than done, the CSV log, the best
checkpoint beside the last, the warnings of a run that does not learn."""

import json
import os

import pytest
import torch

from pipeline.fields import FieldError
from pipeline.neural.train import train
from support.neural_fakes import FakeSource, train_config

torch.set_num_threads(1)


_config = train_config


def _snapshot(folder):
    return {name: (folder / name).read_bytes() for name in sorted(os.listdir(folder))}


def test_fewer_epochs_than_done_is_refused_and_config_json_is_kept(tmp_path):
    source = FakeSource()
    train(_config(tmp_path, epochs=2), source=source)
    before = _snapshot(tmp_path / "run")
    with pytest.raises(FieldError, match=r"^epochs: 1 is not allowed; at least 2: .* already trained 2"):
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


def test_a_csv_log_and_the_best_checkpoint_beside_the_last(tmp_path):
    import csv

    from pipeline.neural import runfiles

    summary = train(_config(tmp_path, epochs=3), source=FakeSource())
    run = tmp_path / "run"
    assert {"log.csv", "checkpoint-best.pt", "checkpoint.pt"} <= set(os.listdir(run))
    rows = list(csv.DictReader((run / "log.csv").open()))
    assert list(rows[0]) == list(runfiles.CSV_COLUMNS)
    assert [int(r["epoch"]) for r in rows] == [1, 2, 3]
    for row, entry in zip(rows, summary.history):
        assert float(row["test_psnr"]) == entry["test_psnr"] and float(row["lr"]) == 1e-3
        assert float(row["train_loss"]) == entry["train_loss"] and float(row["time_s"]) > 0
    best_epoch = max(summary.history, key=lambda h: h["test_psnr"])["epoch"]
    best = runfiles.load_checkpoint(str(run), checkpoint="best")
    assert best["epoch"] == best_epoch
    assert runfiles.load_checkpoint(str(run), checkpoint="last")["epoch"] == 3
    by_file = runfiles.load_checkpoint(str(run), checkpoint=str(run / "checkpoint-best.pt"))
    assert all(torch.equal(by_file["model"][k], best["model"][k]) for k in best["model"])


def test_no_held_out_split_no_best_checkpoint_and_best_is_refused_by_name(tmp_path):
    from pipeline.neural import runfiles

    train(_config(tmp_path, epochs=1, test_fraction=0.0), source=FakeSource())
    assert not (tmp_path / "run" / "checkpoint-best.pt").exists()
    with pytest.raises(FieldError, match="^checkpoint: best: the run has no .*checkpoint-best.pt.*; last$"):
        runfiles.load_checkpoint(str(tmp_path / "run"), checkpoint="best")
    with pytest.raises(FieldError, match="^checkpoint: .*nope.pt.*no such file"):
        runfiles.load_checkpoint(str(tmp_path / "run"), checkpoint=str(tmp_path / "nope.pt"))


def test_a_run_forced_to_saturate_says_so_with_what_to_try(tmp_path, caplog):
    events = []
    with caplog.at_level("WARNING", logger="pipeline.neural.train"):
        summary = train(_config(tmp_path, epochs=2, lr=10.0), progress=events.append, source=FakeSource())
    last = summary.history[-1]
    assert last["test_saturated"] > 0.99
    assert any("saturated" in w and "--lr 1" in w for w in last["warnings"]), last["warnings"]
    assert any("did not move" in w for w in last["warnings"]), last["warnings"]
    shown = [e["warning"] for e in events if "warning" in e]
    assert shown and all(w in shown for w in last["warnings"])
    assert any("saturated" in r.getMessage() for r in caplog.records)
    assert any(line.startswith("warning: ") for line in summary.lines())
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert log[-1]["warnings"] == last["warnings"]
    assert "saturated" in (tmp_path / "run" / "log.csv").read_text()


def test_a_run_that_learns_has_no_warnings(tmp_path):
    summary = train(_config(tmp_path, epochs=2), source=FakeSource())
    assert all(h["warnings"] == [] for h in summary.history)
    assert summary.history[-1]["test_saturated"] < 0.5
