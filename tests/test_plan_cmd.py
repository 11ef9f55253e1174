"""`shaderball plan SPEC` and `shaderball info SPEC`: counts, disk from the store's layout, and
time from the spec's own first renders (real, tiny: the smoke spec's first material)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
PAPER = REPO / "manifests" / "paper.toml"


def _cli(*args):
    from cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def timed() -> dict:
    """`plan SPEC --json` on the smoke spec, one material timed, with a SLURM estimate, in a
    real process (stdout must be one JSON document)."""
    done = subprocess.run(
        [sys.executable, "-m", "cli", "plan", str(SMOKE), "--renders", "1", "--json"]
        + ["--cluster", "slurm", "--jobs", "3", "--cores", "4"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout)


def test_plan_json_has_counts_disk_timing_and_estimates(timed):
    assert set(timed) >= {"spec", "name", "renders", "materials", "uniform", "svbrdf", "lights_per_material"}
    assert set(timed) >= {"shards", "shard_size", "renders_per_shard", "disk", "timing", "estimates", "notes"}
    assert (timed["renders"], timed["materials"], timed["lights_per_material"]) == (16, 8, 2)
    assert timed["uniform"] + timed["svbrdf"] == 8 and timed["svbrdf"] == 4  # svbrdf_fraction 0.5
    assert (timed["shards"], timed["shard_size"], timed["renders_per_shard"]) == (4, 2, 4)
    disk = timed["disk"]
    assert disk["total_bytes"] == disk["render_bytes"] + disk["maps_bytes"] + disk["texture_bytes"]
    assert disk["render_bytes"] == 16 * disk["bytes_per_render"]
    t = timed["timing"]
    # whole materials: the first (two lightings), and the first of the other kind
    assert (t["materials"], t["renders"], t["uniform"], t["svbrdf"]) == (2, 4, 1, 1)
    kinds = t["by_kind"]
    assert {k: v["renders"] for k, v in kinds.items()} == {"uniform": 2, "svbrdf": 2}
    assert t["seconds"] == pytest.approx(sum(v["seconds"] for v in kinds.values()))
    for key in ("seconds_per_render", "cpu_seconds_per_render", "bytes_per_render"):  # the spec's mix: 4 and 4
        assert t[key] == pytest.approx((kinds["uniform"][key] + kinds["svbrdf"][key]) / 2)
    # an svbrdf material's texture maps take room: more bytes per render than a uniform one's
    assert kinds["svbrdf"]["bytes_per_render"] > kinds["uniform"]["bytes_per_render"]
    assert t["threads"] >= 1 and t["bytes_per_render"] > 0 and t["cpu_seconds_per_render"] > 0


def test_plan_estimates_are_per_worker_arithmetic(timed):
    t = timed["timing"]
    here, slurm = timed["estimates"]
    assert here["workers"] == 1 and here["rounds"] == 4
    assert here["seconds"] == pytest.approx(t["setup_s"] + 16 * t["seconds_per_render"])
    assert slurm["workers"] == 3 and slurm["threads_per_worker"] == 4
    assert slurm["rounds"] == math.ceil(4 / 3)
    shard = 4 * t["seconds_per_render"] * t["threads"] / 4
    assert slurm["shard_seconds"] == pytest.approx(shard)
    assert slurm["seconds"] == pytest.approx(t["setup_s"] + 2 * shard)


def test_plan_text_says_time_in_seconds_and_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # the timed build's temporary folder goes here
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    result = _cli("plan", SMOKE, "--renders", "1", "--workers", "2")
    assert result.exit_code == 0, result.output
    assert "renders: 16 = 8 materials (4 uniform, 4 svbrdf) x 2 lightings" in result.output
    assert "time, this machine, in this process (--workers 0): " in result.output
    assert "time, this machine, 2 local worker(s): " in result.output
    assert list(tmp_path.iterdir()) == []  # the timed renders' folder is removed


def test_info_spec_prints_the_plan_without_timing():
    result = _cli("info", PAPER)
    assert result.exit_code == 0, result.output
    assert "renders: 50,000 = 10,000 materials (5,000 uniform, 5,000 svbrdf) x 5 lightings" in result.output
    assert "shards: 500 of 20 materials (100 renders)" in result.output
    assert "timed" not in result.output
    doc = json.loads(_cli("info", PAPER, "--json").output)
    assert doc["timing"] is None and doc["estimates"] == [] and doc["renders"] == 50_000
    # the same figures as plan --no-timing
    assert doc == json.loads(_cli("plan", PAPER, "--no-timing", "--json").output)


def test_disk_estimate_is_the_pixel_data_the_store_writes():
    """An uncompressed EXR of the layers a build writes holds the estimate's pixel bytes plus a
    small header and line table."""
    from pipeline.dataset.spec_file import parse_spec
    from pipeline.store.exr import LAYER_CHANNELS, MATERIAL_MAP_LAYERS, encode_exr, pixel_bytes

    spec = parse_spec(PAPER)
    side = 32
    layers = {name: np.zeros((side, side, len(LAYER_CHANNELS[name])), np.float32) for name in spec.storage.layers}
    encoded = encode_exr(layers, {}, half=MATERIAL_MAP_LAYERS, compression="none")
    expected = pixel_bytes(spec.storage.layers, side, MATERIAL_MAP_LAYERS)
    assert 0 < len(encoded) - expected < 2048
    render = encode_exr({"render": np.zeros((side, side, 3), np.float32)}, {}, compression="none")
    assert 0 < len(render) - pixel_bytes(("render",), side) < 1024


@pytest.mark.parametrize(
    "args, words",
    [
        (["plan", "/nonexistent.toml"], "SPEC"),
        (["plan", str(SMOKE), "--renders", "0"], "--renders"),
        (["plan", str(SMOKE), "--jobs", "2"], "--jobs"),
        (["plan", str(SMOKE), "--cluster", "slurm", "--jobs", "2"], "--cores"),
        (["plan", str(SMOKE), "--cluster", "pbs", "--cores", "2", "--workers", "2"], "--workers"),
        (["plan", str(SMOKE), "--workers", "-1"], "--workers"),
        (["info", str(REPO / "README.md")], "README.md"),
    ],
)
def test_plan_bad_inputs_exit_2_and_render_nothing(args, words, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = _cli(*args)
    assert result.exit_code == 2, result.output
    assert words in result.output
    assert list(tmp_path.iterdir()) == []
