"""The network learns: on a tiny dataset this test builds itself
(24 uniform materials x 2 lightings at 32x32, 4 spp), 16 epochs at the default lr (about
40 s of CPU) end with a held-out PSNR above the training set's mean image's."""

import pytest
import torch
from click.testing import CliRunner

from cli import main
from pipeline.neural.train import TrainConfig, train

SPEC = """
[dataset]
name = "learn-tiny"
version = "1"
seed = 20191117
materials = 24
lights_per_material = 2
svbrdf_fraction = 0.0
shard_size = 12

[materials]
roughness = [0.05, 1.0]
metal_probability = 0.3
svbrdf_folders = []
texture_resolution = 64

[lighting]
elevation_deg = [5.0, 90.0]
azimuth_deg = [0.0, 360.0]
turbidity = [1.0, 10.0]
scheme = "stratified"
sun = "split"

[render]
resolution = 32
spp = 4
max_depth = 8
integrator = "path"
variant = "auto"

[storage]
compression = "zip"
layers = ["diffuse", "specular", "roughness", "normal", "mask"]
texture_maps = true
maps_half = true
"""


@pytest.mark.slow
def test_held_out_psnr_beats_the_mean_training_image(tmp_path):
    torch.set_num_threads(1)
    spec = tmp_path / "learn-tiny.toml"
    spec.write_text(SPEC)
    result = CliRunner().invoke(main, ["build", str(spec), "--out", str(tmp_path / "data")])
    assert result.exit_code == 0, result.output
    config = TrainConfig(
        dataset=str(tmp_path / "data"),
        out=str(tmp_path / "run"),
        epochs=16,
        batch_size=6,
        loss="l1",  # no VGG16 ImageNet weights exist here
        device="cpu",
        seed=0,
        test_fraction=0.25,
    )  # lr: the default
    summary = train(config)
    print(
        f"baseline {summary.baseline_psnr:.2f} dB; held-out PSNR per epoch:",
        [round(h["test_psnr"], 2) for h in summary.history],
    )
    last = summary.history[-1]
    assert summary.baseline_psnr is not None
    assert last["test_psnr"] > summary.baseline_psnr, [round(h["test_psnr"], 2) for h in summary.history]
    assert last["test_loss"] < summary.history[0]["test_loss"]
    assert not last["warnings"]
