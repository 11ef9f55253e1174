"""The network across objects, for real: a tiny build on two objects with the geometry layers,
`train --geometry --held-out-objects`, evaluate's seen and held-out groups; the refusals (no
geometry layers, an unknown object, every object held out); a run without geometry unchanged."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.neural.network import NeuralRenderer, network_from_config, parameter_count
from pipeline.neural.scene_inputs import GEOMETRY_CHANNELS, InputPlan, SampleScene, geometry_channels
from support.scenes import GEOMETRY_LAYERS, cli, small_spec

SPEC = small_spec("objects", materials=8, shard_size=4) + '\n[scene]\nobjects = ["sphere", "torus"]\nscheme = "cycle"\n'
GEOMETRY = GEOMETRY_LAYERS
TRAIN = ("--epochs", "1", "--width", "0.125", "--batch-size", "4", "--loss", "l1", "--precision", "fp32")
EVALUATE = ("--spp", "none", "--no-flip")


def _build(folder: Path, text: str) -> Path:
    spec = folder / "spec.toml"
    spec.write_text(text)
    out = folder / "dataset"
    result = cli("build", spec, "--out", out, "--workers", "0")
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def with_geometry(tmp_path_factory):
    return _build(tmp_path_factory.mktemp("geometry"), SPEC + GEOMETRY)


@pytest.fixture(scope="module")
def without_geometry(tmp_path_factory):
    return _build(tmp_path_factory.mktemp("plain"), SPEC.replace("materials = 8", "materials = 4"))


def test_geometry_and_a_held_out_object_train_and_evaluate_by_group(with_geometry, tmp_path):
    run = tmp_path / "run"
    result = cli("train", with_geometry, "--out", run, "--geometry", "--held-out-objects", "torus", *TRAIN)
    assert result.exit_code == 0, result.output
    config = json.loads((run / "config.json").read_text())
    assert config["network"]["extra_channels"] == GEOMETRY_CHANNELS and "depth" in config["network"]["geometry"]
    assert config["identity"]["geometry"] is True and config["identity"]["held_out_objects"] == ["torus"]
    assert config["split"]["held_out_objects"] == ["torus"]
    # scheme "cycle": odd materials on the torus, all of them held out; no torus material trains
    records = [json.loads(line) for line in (with_geometry / "manifest.jsonl").read_text().splitlines()]
    torus = {r["material_id"] for r in records if r["object"]["name"] == "torus"}
    assert torus and torus <= set(config["split"]["test"]) and not torus & set(config["split"]["train"])
    assert set(config["split"]["train"]) and set(config["split"]["test"]) - torus  # seen objects in test too

    out = tmp_path / "evaluation"
    result = cli("evaluate", run, with_geometry, "--out", out, "--json-out", tmp_path / "r.json", *EVALUATE)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    assert data["inputs"]["geometry"] is True
    for row in data["samples"]:
        assert row["object_group"] == ("held-out" if row["object"] == "torus" else "seen")
    groups = data["by_object_group"]
    assert set(groups) == {"seen", "held-out"} and set(data["by_object"]) == {"sphere", "torus"}
    for name, methods in groups.items():
        network = methods["network"]
        assert network["samples"] == sum(r["object_group"] == name for r in data["samples"])
        assert np.isfinite(network["psnr"]) and network["relmse"] > 0 and 0 < network["ssim"] <= 1
        assert set(network["ci95"]) == {"relmse", "psnr", "ssim"}
        lo, hi = network["ci95"]["psnr"] or (network["psnr"], network["psnr"])
        assert lo <= network["psnr"] <= hi
    assert "mean_image" in groups["held-out"]  # the baseline beside it
    assert "Seen and held-out objects" in (out / "results.md").read_text()
    # infer feeds the run the geometry channels of its own G-buffer
    picture = tmp_path / "ball.exr"
    result = cli("infer", run, "--out", picture, "--elevation", "30", "--roughness", "0.3")
    assert result.exit_code == 0, result.output
    assert picture.stat().st_size > 0


def test_geometry_on_a_dataset_without_its_layers_is_refused_and_nothing_written(without_geometry, tmp_path):
    run = tmp_path / "run"
    result = cli("train", without_geometry, "--out", run, "--geometry", *TRAIN)
    assert result.exit_code == 2, result.output
    assert "--geometry" in result.output and "storage.layers" in result.output
    assert "geometry_normal" in result.output and "depth" in result.output
    assert not run.exists()


@pytest.mark.parametrize(
    "objects, says",
    [("teapot", "teapot: not an object of the dataset"), ("sphere,torus", "every object of the dataset is held out")],
)
def test_a_bad_held_out_object_is_refused(without_geometry, tmp_path, objects, says):
    run = tmp_path / "run"
    result = cli("train", without_geometry, "--out", run, "--held-out-objects", objects, *TRAIN)
    assert result.exit_code == 2, result.output
    assert "--held-out-objects" in result.output and says in result.output
    assert not run.exists()


def test_a_run_without_geometry_keeps_the_papers_network_and_evaluates(without_geometry, tmp_path):
    run = tmp_path / "run"
    result = cli("train", without_geometry, "--out", run, *TRAIN)
    assert result.exit_code == 0, result.output
    config = json.loads((run / "config.json").read_text())
    assert "extra_channels" not in config["network"] and "held_out_objects" not in config["split"]
    assert not {"geometry", "held_out_objects", "environment_code"} & set(config["identity"])
    plain = NeuralRenderer(config["network"]["resolution"], config["network"]["width"])
    assert parameter_count(network_from_config(config["network"])) == parameter_count(plain)
    result = cli("evaluate", run, without_geometry, "--out", tmp_path / "e", *EVALUATE)
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "e" / "results.json").read_text())
    assert data["inputs"] == {"geometry": False, "environment_code": 0}
    assert "by_object_group" not in data and set(data["by_object"]) <= {"sphere", "torus"}


def test_geometry_channels_encode_the_normal_and_standardise_depth_on_the_object():
    mask = np.zeros((4, 4, 1), np.float32)
    mask[1:3, 1:3] = 1
    normal = np.zeros((4, 4, 3), np.float32)
    normal[..., 2] = 1.0
    depth = np.zeros((4, 4, 1), np.float32)
    depth[1:3, 1:3, 0] = [[4.0, 4.2], [4.4, 4.6]]
    chw = geometry_channels({"mask": mask, "geometry_normal": normal, "depth": depth})
    assert chw.shape == (4, 4, 4)
    assert np.allclose(chw[:, 0, 0], 0) and np.allclose(chw[0:3, 1, 1], [0.5, 0.5, 1.0])
    inside = chw[3, 1:3, 1:3]
    assert np.isclose(inside.mean(), 0.5, atol=1e-6) and inside[0, 0] < inside[1, 1]
    assert np.all((inside >= 0) & (inside <= 1))
    # the same shape at another distance gives the same channel
    far = geometry_channels({"mask": mask, "geometry_normal": normal, "depth": depth * 2})
    assert np.allclose(far, chw, atol=1e-6)
    assert geometry_channels({"mask": mask, "geometry_normal": normal, "depth": depth}, factor=2).shape == (4, 2, 2)


def test_environment_codes_give_each_known_map_its_row_and_change_the_output():
    plan = InputPlan(False, 3, ("a" * 64, "b" * 64))
    lit = {"lighting": {"source": "environment", "sha256": "b" * 64, "file": "x.exr", "rotation_deg": 10.0}}
    assert plan.environment_index(SampleScene.of(lit)) == 2
    assert plan.environment_index(SampleScene.of({"lighting": {"elevation_deg": 30.0}})) == 0
    network = network_from_config({"resolution": 16, "width": 0.125, **plan.network_record()})
    torch.manual_seed(0)
    with torch.no_grad():
        network.environment.weight.normal_()
    network.eval()
    maps, light = torch.rand(1, 12, 16, 16), torch.rand(1, 4)
    with torch.no_grad():
        one, two = (network(maps, light, torch.tensor([i])) for i in (1, 2))
    assert not torch.allclose(one, two)


def test_held_out_rotations_move_a_training_materials_lightings_to_test():
    from pipeline.neural.data import ShaderballDataset
    from pipeline.neural.manifest_index import SampleFiles
    from pipeline.neural.splits import split_samples

    ref = ("k", "0" * 64, 1)
    samples, records = [], {}
    for m in range(3):
        for light, rotation in enumerate((10.0, 200.0, 330.0)):
            sid = f"m{m}_l{light}"
            samples.append(SampleFiles(sid, f"m{m}", ref, ref, (0.0, 0.0, 1.0, 0.0)))
            records[sid] = {"lighting": {"source": "environment", "sha256": "a" * 64, "rotation_deg": rotation}}
    source = ShaderballDataset("/nowhere", samples, 16, 1, records=records)
    split = {"train": ["m0", "m1"], "test": ["m2"], "held_out_rotations": [300.0, 360.0]}
    train = [s.id for s in split_samples(source, split, "train").samples]
    test = [s.id for s in split_samples(source, split, "test").samples]
    assert train == ["m0_l0", "m0_l1", "m1_l0", "m1_l1"]
    assert test == ["m0_l2", "m1_l2", "m2_l0", "m2_l1", "m2_l2"]
    assert [s.id for s in split_samples(source, {"train": ["m0"], "test": []}, "train").samples] == [
        "m0_l0",
        "m0_l1",
        "m0_l2",
    ]


ENVIRONMENT_SPEC = (
    SPEC.replace('objects = ["sphere", "torus"]', 'objects = ["sphere"]').replace(
        "lights_per_material = 2", "lights_per_material = 4"
    )
    + '[lighting]\nsource = "environment"\nenvironments = ["maps"]\n'
)


@pytest.fixture(scope="module")
def environment_lit(tmp_path_factory):
    folder = tmp_path_factory.mktemp("environment")
    (folder / "maps").mkdir()
    from pipeline.figures.environments import write_environments

    write_environments(folder / "maps", height=16)
    return _build(folder, ENVIRONMENT_SPEC)


def test_environment_codes_and_held_out_rotations_train_and_evaluate_by_group(environment_lit, tmp_path):
    run = tmp_path / "run"
    result = cli(
        "train", environment_lit, "--out", run, "--environment-code", "2", "--held-out-rotations", "180,360", *TRAIN
    )
    assert result.exit_code == 0, result.output
    config = json.loads((run / "config.json").read_text())
    records = [json.loads(line) for line in (environment_lit / "manifest.jsonl").read_text().splitlines()]
    digests = sorted({r["lighting"]["sha256"] for r in records})
    assert config["network"]["environment_code"] == 2 and len(digests) == 2
    assert set(config["network"]["environments"]) <= set(digests)
    out = tmp_path / "evaluation"
    result = cli("evaluate", run, environment_lit, "--out", out, *EVALUATE)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "results.json").read_text())
    assert data["inputs"]["environment_code"] == 2
    rotation = {r["id"]: r["lighting"]["rotation_deg"] for r in records}
    for row in data["samples"]:
        held = 180.0 <= rotation[row["id"]] <= 360.0
        assert row["rotation_group"] == ("held-out" if held else "seen")
    assert set(data["by_rotation_group"]) == {"seen", "held-out"}
    assert "Seen and held-out map rotations" in (out / "results.md").read_text()
