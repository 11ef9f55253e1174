"""`shaderball evaluate RUN DATASET --reference DIR`: the network scored against another build of
the same samples (the same spec but for render.spp), never against DATASET's own noisy renders;
a build of another spec is refused naming --reference, before anything is written."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner

from cli import main
from support.neural_fakes import untrained_run

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
torch.set_num_threads(1)
#: The cheapest evaluation: two samples, the network and its baselines only.
CHEAP = ("--split", "all", "--spp", "none", "--no-flip", "--no-denoise", "--limit", "2")


def _build(tmp_path: Path, name: str, **changes) -> Path:
    """The smoke spec with ``changes`` (``key = value`` lines replaced), built into a folder."""
    text = SMOKE.read_text()
    for key, value in changes.items():
        text, n = re.subn(rf"(?m)^{key} = \S+", f"{key} = {value}", text)
        assert n == 1, key
    spec = tmp_path / f"{name}.toml"
    spec.write_text(text)
    out = tmp_path / name
    done = subprocess.run(
        [sys.executable, "-m", "cli", "build", str(spec), "--out", str(out), "--workers", "0"],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return out


def _evaluate(*args):
    return CliRunner().invoke(main, ["evaluate", *map(str, args)])


@pytest.mark.slow
def test_the_network_is_scored_against_the_reference_build(reference, tmp_path):
    run = tmp_path / "run"
    torch.manual_seed(0)
    untrained_run(run, 32)
    clean = _build(tmp_path, "clean", spp=64)  # the smoke spec at 64 spp instead of 16
    own = _evaluate(run, reference, *CHEAP, "--out", tmp_path / "own")
    against = _evaluate(run, reference, *CHEAP, "--reference", clean, "--out", tmp_path / "clean-eval")
    assert own.exit_code == 0 and against.exit_code == 0, (own.output, against.output)
    mine = json.loads((tmp_path / "own" / "results.json").read_text())
    theirs = json.loads((tmp_path / "clean-eval" / "results.json").read_text())
    assert (mine["reference"], mine["reference_spp"]) == (None, 16)
    assert (theirs["reference"], theirs["reference_spp"]) == (str(clean.resolve()), 64)
    assert [s["id"] for s in theirs["samples"]] == [s["id"] for s in mine["samples"]]
    for a, b in zip(mine["samples"], theirs["samples"]):  # the same network output, other references
        assert a["network"]["psnr"] != b["network"]["psnr"], a["id"]
        assert all(isinstance(v, float) for v in (a["network"]["psnr"], b["network"]["psnr"]))


@pytest.mark.slow
def test_a_build_of_another_spec_is_refused_before_anything_is_written(reference, tmp_path):
    run = tmp_path / "run"
    torch.manual_seed(0)
    untrained_run(run, 32)
    other = _build(tmp_path, "other", seed=7, materials=2, shard_size=1)
    out = tmp_path / "eval"
    refused = _evaluate(run, reference, *CHEAP, "--reference", other, "--out", out)
    assert refused.exit_code == 2, refused.output
    message = refused.output.strip()
    assert message.startswith(f'error: --reference: "{other}" was built from another spec: '), message
    assert "dataset.seed" in message and "dataset.materials" in message, message
    assert "with another render.spp" in message, message
    assert not out.exists()


def test_a_reference_that_is_no_dataset_is_refused_by_its_own_name(reference, tmp_path):
    run = tmp_path / "run"
    torch.manual_seed(0)
    untrained_run(run, 32)
    out = tmp_path / "eval"
    not_a_folder = reference / "manifest.jsonl"
    refused = _evaluate(run, reference, *CHEAP, "--reference", not_a_folder, "--out", out)
    assert refused.exit_code == 2, refused.output
    assert refused.output.startswith(f'error: --reference: "{not_a_folder}" is not a folder; '), refused.output
    assert not out.exists()
