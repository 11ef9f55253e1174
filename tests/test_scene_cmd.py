"""`shaderball scene`: the three files, their contents, and refusal of a bad resolution."""

import os

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli import main
from geometry import ShaderballParams, build_shaderball
from geometry.ply import read_ply
from pipeline.errors import ShaderballError
from pipeline.render.scene_command import SceneRequest
from pipeline.store.exr import read_exr


@pytest.fixture()
def cache_env(tmp_path_factory, monkeypatch):
    cache = str(tmp_path_factory.getbasetemp() / "shaderball-cache")
    monkeypatch.setenv("SHADERBALL_CACHE", cache)
    return cache


def test_scene_command_writes_mesh_gbuffer_and_preview(cache_env, tmp_path, mi):
    out = tmp_path / "scene"
    result = CliRunner().invoke(main, ["scene", "--out", str(out), "--resolution", "32"])
    assert result.exit_code == 0, result.output
    assert sorted(os.listdir(out)) == ["gbuffer.exr", "preview.png", "shaderball.ply"]
    assert "seams:" in result.output and "% of ball pixels within 2 px" in result.output

    ball = build_shaderball(ShaderballParams(), cache_dir=cache_env)
    mesh = read_ply(str(out / "shaderball.ply"))
    np.testing.assert_array_equal(mesh["uv"], ball.material_uv)
    np.testing.assert_array_equal(mesh["faces"], ball.material_mesh.faces)

    import OpenEXR

    channels = set(OpenEXR.File(str(out / "gbuffer.exr"), separate_channels=True).channels())
    assert channels == {"uv.U", "uv.V", "normal.X", "normal.Y", "normal.Z", "mask.Y", "depth.Z"}
    layers = read_exr(str(out / "gbuffer.exr")).layers
    mask = layers["mask"][..., 0]
    assert set(np.unique(mask)) == {0.0, 1.0}

    preview = Image.open(out / "preview.png")
    assert preview.size == (64, 32) and preview.mode == "RGB"
    pixels = np.asarray(preview)
    render, panel = pixels[:, :32], pixels[:, 32:]
    # The mask panel is white (or seam-tinted) exactly where the G-buffer mask is set.
    assert np.array_equal(panel.sum(-1) > 3 * 40, mask > 0.5)
    # The render shows the checker: the ball's pixels vary far more than flat shading would.
    assert render[mask > 0.5].std() > 20


@pytest.mark.parametrize("resolution", [8, 5000])
def test_bad_resolution_is_refused_and_nothing_written(cache_env, tmp_path, resolution):
    out = tmp_path / "scene"
    with pytest.raises(ShaderballError) as info:  # the library names the field by its own name
        SceneRequest(out=str(out), resolution=resolution)
    assert str(info.value).startswith(f"resolution: {resolution} is not allowed; ") and "4096" in str(info.value)
    assert not out.exists()

    result = CliRunner().invoke(main, ["scene", "--out", str(out), "--resolution", str(resolution)])
    assert result.exit_code == 2
    assert "error: --resolution" in result.output
    assert not out.exists()
