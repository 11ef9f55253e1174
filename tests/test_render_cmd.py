"""`shaderball render`: a real render to EXR + PNG, its statistics, and every bad-input path."""

import os

import numpy as np
import pytest
from click.testing import CliRunner

from cli import main
from pipeline.store.exr import read_exr

SMALL = ["--resolution", "48", "--spp", "4"]
#: The render of the first tests: a seeded material and sun, rendered twice to the same bytes.
BALL = [
    *SMALL,
    *("--diffuse", "0.6,0.3,0.1", "--roughness", "0.2", "--seed", "5"),
    *("--elevation", "30", "--azimuth", "0", "--turbidity", "3"),
]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("render")
    exr, png = out / "ball.exr", out / "ball.png"
    result = CliRunner().invoke(main, ["render", *BALL, "--out", str(exr), "--png", str(png)])
    assert result.exit_code == 0, result.output
    return exr, png, result.output


def test_render_writes_layers_and_stats(rendered):
    exr, png, output = rendered
    image = read_exr(str(exr))
    assert set(image.layers) == {"render", "diffuse", "specular", "roughness", "normal", "mask"}
    render = image.layers["render"]
    assert render.shape == (48, 48, 3) and render.dtype == np.float32
    assert np.isfinite(render).all() and (render >= 0).all() and render.max() > 0
    stats = image.meta["stats"]
    for key in ("time_s", "spp", "min", "max", "nan", "inf", "negative", "noise_rmse"):
        assert key in stats
    assert stats["spp"] == 4 and stats["nan"] == stats["inf"] == stats["negative"] == 0
    assert stats["max"] == pytest.approx(float(render.max()))
    assert image.meta["lighting"]["changed"] is False
    mask = image.layers["mask"][..., 0] > 0.5
    np.testing.assert_allclose(
        image.layers["diffuse"][mask], np.broadcast_to([0.6, 0.3, 0.1], (mask.sum(), 3)), atol=1e-3
    )
    assert "NaN 0, Inf 0, negative 0" in output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_same_seed_same_bytes(rendered, tmp_path):
    exr, _, _ = rendered
    again = tmp_path / "again.exr"
    assert CliRunner().invoke(main, ["render", *BALL, "--out", str(again)]).exit_code == 0
    first, second = read_exr(str(exr)), read_exr(str(again))
    np.testing.assert_array_equal(first.layers["render"], second.layers["render"])


def test_low_sun_is_raised_and_recorded(tmp_path):
    out = tmp_path / "low.exr"
    result = CliRunner().invoke(main, ["render", *SMALL, "--elevation", "0", "--turbidity", "10", "--out", str(out)])
    assert result.exit_code == 0, result.output
    meta = read_exr(str(out)).meta
    assert meta["lighting"]["changed"] is True
    assert meta["lighting"]["effective"]["elevation_deg"] > 0
    assert meta["lighting_vector"][2] > 0  # the network is told the effective sun
    assert "elevation_deg 0 ->" in result.output
    assert meta["stats"]["negative"] == 0 and meta["stats"]["nan"] == 0


@pytest.mark.parametrize(
    "args, option",
    [
        (["--elevation", "90.5"], "--elevation"),
        (["--elevation", "-5"], "--elevation"),
        (["--elevation", "nan"], "--elevation"),
        (["--turbidity", "0.99"], "--turbidity"),
        (["--turbidity", "10.01"], "--turbidity"),
        (["--azimuth", "inf"], "--azimuth"),
        (["--diffuse", "1.5,0,0"], "--diffuse"),
        (["--diffuse", "0.5,0.5"], "--diffuse"),
        (["--diffuse", "red"], "--diffuse"),
        (["--specular", "-0.1,0,0"], "--specular"),
        (["--roughness", "1.2"], "--roughness"),
        (["--normal", "0,0,-1"], "--normal"),
        (["--normal", "0,0,0"], "--normal"),
        (["--spp", "0"], "--spp"),
        (["--resolution", "8"], "--resolution"),
        (["--resolution", "5000"], "--resolution"),
        (["--max-depth", "0"], "--max-depth"),
        (["--seed", "-1"], "--seed"),
        (["--seed", str(2**32)], "--seed"),
        (["--svbrdf", "/nonexistent/material.png"], "--svbrdf"),
    ],
)
def test_bad_option_exits_2_names_it_and_writes_nothing(tmp_path, args, option):
    out, png = tmp_path / "x.exr", tmp_path / "x.png"
    result = CliRunner().invoke(main, ["render", "--out", str(out), "--png", str(png), *args])
    assert result.exit_code == 2, result.output
    assert f"error: {option}: " in result.output
    assert "is not allowed; " in result.output or "does not exist; " in result.output
    assert not out.exists() and not png.exists()


def test_bad_output_paths(tmp_path):
    runner = CliRunner()
    result = runner.invoke(main, ["render", "--out", str(tmp_path / "x.png")])
    assert result.exit_code == 2 and "--out" in result.output and ".exr" in result.output
    result = runner.invoke(main, ["render", "--out", str(tmp_path / "x.exr"), "--png", str(tmp_path / "x.jpg")])
    assert result.exit_code == 2 and "--png" in result.output
    readonly = tmp_path / "ro"
    readonly.mkdir()
    os.chmod(readonly, 0o500)
    try:
        if os.access(readonly, os.W_OK):  # root ignores permissions: nothing to test
            return
        result = runner.invoke(main, ["render", "--out", str(readonly / "x.exr")])
        assert result.exit_code == 2 and "writable" in result.output
    finally:
        os.chmod(readonly, 0o700)


def test_help_explains_units_and_ranges():
    result = CliRunner().invoke(main, ["render", "--help"])
    assert result.exit_code == 0
    for text in ("degrees in [0, 90]", "[1, 10]", "1 to 65536", "16 to 4096", "linear RGB"):
        assert text in " ".join(result.output.split())
