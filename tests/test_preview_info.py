"""`shaderball preview` and `shaderball info` on complete and partial datasets, and their bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"


def _cli(*args):
    from cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A two-render dataset (one uniform, one SVBRDF material; two shards), built in-process."""
    from pipeline.run.build import build
    from pipeline.run.cluster.options import ClusterOptions

    text = SMOKE.read_text()
    for key, value in (("materials", 2), ("lights_per_material", 1), ("shard_size", 1)):
        lines = text.splitlines()
        lines = [f"{key} = {value}" if line.split("=")[0].strip() == key else line for line in lines]
        text = "\n".join(lines) + "\n"
    base = tmp_path_factory.mktemp("tiny")
    spec = base / "tiny.toml"
    spec.write_text(text)
    out = base / "dataset"
    assert build(str(spec), str(out), cluster=ClusterOptions(workers=0)).rendered == 2
    return out


def _partial(dataset: Path, tmp_path: Path, *, drop_render: bool) -> Path:
    """A copy as a build stopped in its second shard: no marker, no manifest (and no render)."""
    out = tmp_path / "partial"
    shutil.copytree(dataset, out)
    (out / "manifest.jsonl").unlink()
    (out / "shards" / "s00001" / "COMPLETE.json").unlink()
    if drop_render:
        for p in (out / "shards" / "s00001").glob("m000001_l0*"):
            p.unlink()
    return out


# ---------------------------------------------------------------- info


def test_info_of_a_complete_dataset(dataset):
    result = _cli("info", dataset)
    assert result.exit_code == 0, result.output
    text = result.output
    assert "completion: complete; 2/2 renders recorded (100.0%), 2/2 shards complete" in text
    assert "2 materials (1 uniform, 1 SVBRDF) x 1 lightings = 2 renders in 2 shards" in text
    assert "64x64, 16 spp" in text and "maps half" in text
    info = json.loads(_cli("info", dataset, "--json").output)
    assert info["complete"] and info["recorded"] == 2 and info["total_renders"] == 2
    assert info["files"]["render"]["count"] == 2 and info["files"]["maps"]["count"] == 2
    on_disk = sum(p.stat().st_size for p in dataset.rglob("*") if p.is_file())
    assert info["disk_bytes"] == on_disk
    assert info["kinds"] == {"uniform": 1, "svbrdf": 1}
    assert info["effects"]["specular_lobe"] == 2 and info["effects"]["textured"] == 1


@pytest.mark.parametrize("drop_render", [False, True])
def test_info_of_a_partial_dataset(dataset, tmp_path, drop_render):
    out = _partial(dataset, tmp_path, drop_render=drop_render)
    result = _cli("info", out)
    assert result.exit_code == 0, result.output
    recorded = 1 if drop_render else 2
    assert "INCOMPLETE" in result.output
    assert f"{recorded}/2 renders recorded" in result.output
    assert "1/2 shards complete, 1 in progress; manifest.jsonl absent" in result.output


def test_info_refuses_a_folder_that_is_not_a_dataset(tmp_path):
    (tmp_path / "x.txt").write_text("hello")
    result = _cli("info", tmp_path)
    assert result.exit_code == 2
    assert "holds no spec.toml" in result.output
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"]
    assert _cli("info", tmp_path / "missing").exit_code == 2


# ---------------------------------------------------------------- preview


def _png(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


def test_preview_shows_each_render_beside_its_four_maps(dataset, tmp_path):
    from pipeline.check.preview import COLUMNS, GAP, HEADER_HEIGHT, LABEL_WIDTH

    out = tmp_path / "sheet.png"
    result = _cli("preview", dataset, "--out", out, "--tile", 64)
    assert result.exit_code == 0, result.output
    assert "2 samples (2/2 renders recorded)" in result.output
    assert "m000000_l0, m000001_l0" in result.output
    sheet = _png(out)
    assert sheet.shape == (HEADER_HEIGHT + 2 * (64 + GAP) + GAP, LABEL_WIDTH + len(COLUMNS) * (64 + GAP) + GAP, 3)
    for row in range(2):
        y = HEADER_HEIGHT + row * (64 + GAP)
        label = sheet[y : y + 64, :LABEL_WIDTH]
        assert (label > 150).any()  # text was drawn
        for col in range(len(COLUMNS)):
            x = LABEL_WIDTH + col * (64 + GAP) + GAP
            tile = sheet[y : y + 64, x : x + 64].astype(int)
            assert tile.std() > 3, (row, COLUMNS[col])  # a picture, not a blank tile


def test_preview_of_a_partial_dataset_shows_what_is_there(dataset, tmp_path):
    out = _partial(dataset, tmp_path, drop_render=True)
    result = _cli("preview", out, "--out", tmp_path / "p.png")
    assert result.exit_code == 0, result.output
    assert "1 samples (1/2 renders recorded)" in result.output


@pytest.mark.parametrize(
    "args, message",
    [
        (["--out", "{tmp}/sheet.jpg"], "--out: "),
        (
            ["--out", "{tmp}/sheet.png", "--rows", "0"],
            "--rows: 0 is not allowed; an integer from 1 to 200",
        ),
        (["--out", "{tmp}/sheet.png", "--tile", "8"], "--tile: 8 is not allowed"),
    ],
)
def test_preview_bad_options_exit_2_and_write_nothing(dataset, tmp_path, args, message):
    result = _cli("preview", dataset, *[a.format(tmp=tmp_path) for a in args])
    assert result.exit_code == 2 and message in result.output, result.output
    assert list(tmp_path.iterdir()) == []


def test_preview_refuses_a_folder_that_is_not_a_dataset(tmp_path):
    result = _cli("preview", tmp_path, "--out", tmp_path / "p.png")
    assert result.exit_code == 2 and "DIR: " in result.output
    assert list(tmp_path.iterdir()) == []


def test_choose_samples_spreads_evenly_and_keeps_the_ends():
    from pipeline.check.preview import choose_samples

    records = [{"id": f"m{i:06d}_l0"} for i in range(16)]
    chosen = [r["id"] for r in choose_samples(list(reversed(records)), 8)]
    assert len(chosen) == 8 == len(set(chosen))
    assert chosen[0] == "m000000_l0" and chosen[-1] == "m000015_l0" and chosen == sorted(chosen)
    assert len(choose_samples(records[:3], 8)) == 3


def test_map_tiles_encode_maps_for_display():
    from pipeline.check.preview import map_tiles

    mask = np.ones((2, 2, 1), np.float32)
    mask[0, 0] = 0.0
    normal = np.zeros((2, 2, 3), np.float32)
    normal[..., 2] = 1.0
    tiles = map_tiles(
        {
            "diffuse": np.full((2, 2, 3), 0.5, np.float32),
            "roughness": np.full((2, 2, 1), 0.5, np.float32),
            "normal": normal,
            "mask": mask,
        }
    )
    assert tuple(tiles["normal"][1, 1]) == (128, 128, 255) and tuple(tiles["normal"][0, 0]) == (0, 0, 0)
    assert tuple(tiles["roughness"][0, 0]) == (128, 128, 128)  # raw, not sRGB-encoded
    assert tuple(tiles["diffuse"][0, 0]) == (188, 188, 188)  # linear 0.5 is sRGB 188
    assert tiles["specular"] is None  # a layer the spec did not store
