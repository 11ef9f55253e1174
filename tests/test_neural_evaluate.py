"""`shaderball evaluate` (issue 22): refusals that name what the user can do, the reference's
spp, the equal-time and mean-image rows, intervals, relMSE of a saturated network."""

import os

import pytest
import torch
from click.testing import CliRunner

from cli import main
from pipeline.neural import runfiles
from pipeline.neural.network import NeuralRenderer

torch.set_num_threads(1)


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _fake_run(folder, resolution):
    """A run folder whose network is ``resolution`` pixels (random weights)."""
    os.makedirs(folder)
    runfiles.write_json(
        os.path.join(folder, runfiles.CONFIG),
        {
            "identity": {"dataset": {}},
            "identity_digest": "fake",
            "network": {"resolution": resolution},
            "tonemap": {"name": "reinhard+srgb", "exposure": 4.0},
        },
    )
    runfiles.save_checkpoint(
        str(folder),
        epoch=1,
        model_state=NeuralRenderer(resolution).state_dict(),
        optimizer_state={},
        history=[],
        identity_digest="fake",
    )


@pytest.mark.slow
def test_a_run_whose_resolution_does_not_divide_the_datasets_names_what_to_do(reference, tmp_path):
    _fake_run(tmp_path / "run48", 48)  # the smoke dataset is 64x64: 48 does not divide it
    result = _invoke("evaluate", tmp_path / "run48", reference, "--split", "all", "--spp", "none")
    assert result.exit_code == 2, result.output
    assert "--resolution" not in result.output.replace("train DATASET --out NEWRUN`, with --resolution", "")
    assert "64x64 renders" in result.output and "trained at 48x48" in result.output
    assert "multiple of 48" in result.output and "shaderball train DATASET" in result.output
    assert not (tmp_path / "run48" / "evaluation-all").exists()
