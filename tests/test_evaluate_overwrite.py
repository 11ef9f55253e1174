"""`shaderball evaluate` never writes over an earlier evaluation without being asked: a folder
that holds one is refused before anything runs (naming it, its files and --overwrite), and
--overwrite replaces it whole (no earlier report left beside new results); a folder of other
files is written into."""

from __future__ import annotations

import os

import pytest
import torch
from click.testing import CliRunner

from cli import main
from pipeline.neural.evaluate import EVALUATION_FILES
from pipeline.neural.report import REPORT_FILES
from support.neural_fakes import untrained_run

torch.set_num_threads(1)
#: The cheapest evaluation: one sample, the network and its baselines only.
CHEAP = ("--split", "all", "--spp", "none", "--no-flip", "--no-denoise", "--limit", "1")


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _state(folder):
    return {name: (os.stat(folder / name).st_mtime_ns, (folder / name).read_bytes()) for name in os.listdir(folder)}


@pytest.mark.slow
def test_an_earlier_evaluation_is_refused_unless_overwrite_which_replaces_it_whole(reference, tmp_path):
    run = tmp_path / "run"
    torch.manual_seed(0)
    untrained_run(run, 32)
    folder = run / "evaluation-all"  # the default folder: the same for every evaluation of the split
    first = _invoke("evaluate", run, reference, *CHEAP, "--report")
    assert first.exit_code == 0, first.output
    assert set(os.listdir(folder)) == set(EVALUATION_FILES + REPORT_FILES)
    before = _state(folder)

    again = _invoke("evaluate", run, reference, *CHEAP)
    assert again.exit_code == 2, again.output
    assert again.output.startswith(f'error: --out: "{folder}" holds an earlier evaluation ('), again.output
    assert "results.json" in again.output and "report.md" in again.output and "--overwrite" in again.output
    assert "samples" not in again.output  # refused before the first sample, not after the evaluation
    assert _state(folder) == before

    replaced = _invoke("evaluate", run, reference, *CHEAP, "--overwrite")
    assert replaced.exit_code == 0, replaced.output
    assert sorted(os.listdir(folder)) == sorted(EVALUATION_FILES)  # the earlier report is gone with it
    assert _state(folder)["results.json"] != before["results.json"]

    mine = tmp_path / "mine"  # a folder of the user's own files but no evaluation: written into
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    done = _invoke("evaluate", run, reference, *CHEAP, "--out", mine)
    assert done.exit_code == 0, done.output
    assert sorted(os.listdir(mine)) == sorted([*EVALUATION_FILES, "notes.txt"])
    assert (mine / "notes.txt").read_text() == "mine"
