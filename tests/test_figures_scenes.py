"""The README's scenes figure (one material on the four built-in objects under the two shipped
environment maps), the maps' generator and the files it wrote, and manifests/scenes.toml:
rendered, written and built for real, at tiny sizes."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli import main
from pipeline.figures import environments as env
from pipeline.figures.scenes import DEFAULT_TILE, ScenesFigureError, environment_lights
from pipeline.render.envmap import read_environment
from sky.directions import sun_direction
from sky.environment import map_direction

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / env.SHIPPED_FOLDER
SPEC = REPO / "manifests" / "scenes.toml"
OBJECTS = ("shaderball", "sphere", "rounded_cube", "torus")
#: Mean absolute difference (of 255) between two tiles' 4x4-pixel block means: at 24 px and 32 spp
#: measured 6.1-10.0 between environments and 7.4-14.6 between objects, 1.2-1.9 between two
#: renders of the same tile with other seeds (the noise this threshold stays clear of).
TILE_DIFFERENCE = 3.5


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _tiles(sheet: np.ndarray, tile: int) -> np.ndarray:
    """(rows, cols, tile, tile, 3) float tiles of a grid, each as 4x4-pixel block means (noise down)."""
    rows, cols = sheet.shape[0] // tile, sheet.shape[1] // tile
    grid = sheet.astype(np.float64).reshape(rows, tile, cols, tile, 3).transpose(0, 2, 1, 3, 4)
    return grid.reshape(rows, cols, tile // 4, 4, tile // 4, 4, 3).mean(axis=(3, 5))


def test_the_figure_is_objects_across_and_environments_down(tmp_path):
    out = tmp_path / "figures" / "scenes.png"
    done = _cli("figures", "scenes", "--out", out, "--tile", 24, "--spp", 32, "--json")
    assert done.exit_code == 0, done.output
    doc = json.loads(done.output[done.output.index("{") :])
    assert (doc["figure"], doc["width"], doc["height"]) == ("scenes", 4 * 24, 2 * 24)
    with Image.open(out) as image:
        assert image.format == "PNG" and image.mode == "RGB" and image.size == (96, 48)
        tiles = _tiles(np.asarray(image), 24)
    assert tiles.shape[:2] == (2, 4)
    for row in range(2):
        for a in range(4):
            assert tiles[row, a].std() > 5.0, f"tile ({row}, {a}) is flat"
            for b in range(a + 1, 4):
                difference = np.abs(tiles[row, a] - tiles[row, b]).mean()
                assert difference > TILE_DIFFERENCE, (OBJECTS[a], OBJECTS[b], row, difference)
    for column in range(4):
        difference = np.abs(tiles[0, column] - tiles[1, column]).mean()
        assert difference > TILE_DIFFERENCE, (OBJECTS[column], difference)


def test_the_figure_refuses_another_figures_options_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for args, message in (
        (["scenes"], "--out: missing; a PNG file for scenes"),
        (["scenes", "--out", "s.png", "--tile", "8"], "--tile: 8 is not allowed"),
        (["scenes", "--out", "s.png", "--spp", "0"], "--spp: 0 is not allowed"),
        (["scenes", "--out", "s.png", "--examples", "2"], "--examples: not an option of scenes; "),
        (["contact-sheet", "--out", "s.png", "--tile", "32"], "--tile: not an option of contact-sheet"),
    ):
        result = _cli("figures", *args)
        assert result.exit_code == 2 and message in result.output, (args, result.output)
    assert not list(tmp_path.iterdir())


def test_a_missing_map_is_named_with_the_command_that_makes_it(tmp_path):
    with pytest.raises(ScenesFigureError, match=r"studio\.exr: no such file; .*scripts/make_environments\.py"):
        environment_lights(tmp_path)
    lights = environment_lights()  # the shipped ones: digested, by absolute path
    assert [Path(light.file).name for light in lights] == ["studio.exr", "outdoor.exr"]
    assert all(Path(light.file).is_absolute() and len(light.digest) == 64 for light in lights)


def test_the_shipped_maps_are_what_the_script_writes(tmp_path):
    out = tmp_path / "maps"
    done = subprocess.run(
        [sys.executable, REPO / "scripts" / "make_environments.py", "--out", out],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr
    for name in env.ENVIRONMENT_NAMES:
        shipped = SHIPPED / f"{name}.exr"
        assert shipped.stat().st_size < 300_000, "the repository ships small maps"
        ours, made = read_environment(shipped), read_environment(out / f"{name}.exr")
        assert ours.shape == (env.DEFAULT_HEIGHT, 2 * env.DEFAULT_HEIGHT, 3)
        # half floats: another CPU's last bits may round to the neighbouring half (2^-11 relative)
        np.testing.assert_allclose(made, ours, rtol=2e-3, atol=1e-4, err_msg=f"{shipped}: re-run the script")


def test_the_script_refuses_a_bad_height_before_it_writes(tmp_path):
    out = tmp_path / "maps"
    done = subprocess.run(
        [sys.executable, REPO / "scripts" / "make_environments.py", "--out", out, "--height", "8"],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert done.returncode == 2 and "error: --height: 8 is not allowed" in done.stderr and "usage:" in done.stderr
    assert "Traceback" not in done.stderr and not out.exists()


def _luminance(radiance: np.ndarray) -> np.ndarray:
    return radiance @ np.array([0.2126, 0.7152, 0.0722])


def _pixel_directions(height: int) -> np.ndarray:
    """Each pixel's world direction as Mitsuba's envmap places it (sky.environment's convention)."""
    u = (np.arange(2 * height) + 0.5) / (2 * height)
    return map_direction(u[None, :], (np.arange(height) / (height - 1))[:, None])


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def test_the_outdoor_map_has_a_small_sun_where_it_says_over_a_sky_and_a_ground():
    radiance = env.outdoor(64)
    luminance = _luminance(radiance)
    directions = _pixel_directions(64)
    azimuth, elevation, _radius, colour = env.SUN
    brightest = directions[np.unravel_index(np.argmax(luminance), luminance.shape)]
    assert _angle_deg(brightest, sun_direction(elevation, azimuth)) < 4.0
    sun = luminance > 100.0
    assert 0 < sun.sum() < 0.005 * sun.size and luminance.max() > 1000.0
    up, down = directions[..., 2] > 0.05, directions[..., 2] < -0.05
    sky = radiance[up & ~sun]
    assert (sky[:, 2] > sky[:, 0]).all(), "the sky is blue"
    assert luminance[down].max() < luminance[up & ~sun].min(), "the ground is darker than the sky"


def test_the_studio_map_is_a_dark_surround_with_its_lights_where_it_says():
    radiance = env.studio(64)
    luminance = _luminance(radiance)
    directions = _pixel_directions(64)
    assert np.median(luminance) < 0.1
    lit = luminance > 1.0
    assert 0 < lit.mean() < 0.15
    for name, azimuth, elevation, _radius, colour in env.STUDIO_LIGHTS:
        nearest = np.argmin(np.linalg.norm(directions - sun_direction(elevation, azimuth), axis=-1))
        assert luminance.flat[nearest] > 0.5 * float(_luminance(np.asarray(colour))), name


def test_the_scenes_spec_builds_on_the_four_objects_under_the_two_maps_and_validates(tmp_path):
    from pipeline.dataset.plan import plan_dataset
    from pipeline.dataset.spec_file import parse_spec
    from pipeline.store.exr import read_exr

    spec = parse_spec(SPEC)
    assert spec.scene.objects == OBJECTS and spec.scene.scheme == "cycle"
    assert spec.lighting.source == "environment"
    assert spec.lighting.environments == tuple(str(SHIPPED / f"{n}.exr") for n in ("studio", "outdoor"))
    assert {"geometry_normal", "depth"} <= set(spec.storage.layers)
    assert (spec.render.resolution, spec.render.spp, spec.dataset.materials, spec.dataset.lights_per_material) == (
        64,
        16,
        8,
        2,
    )
    materials = [m for shard in plan_dataset(spec) for m in shard.materials]
    assert sorted(m.object for m in materials) == sorted(OBJECTS * 2)
    out = tmp_path / "scenes"
    built = _cli("build", SPEC, "--out", out, "--workers", "0")
    assert built.exit_code == 0, built.output
    checked = _cli("validate", out)
    assert checked.exit_code == 0, checked.output
    records = [json.loads(p.read_text()) for p in sorted((out / "shards").rglob("m*.json"))]
    assert len(records) == 16
    assert {r.get("object", {}).get("name", "shaderball") for r in records} == set(OBJECTS)
    for record in records:
        lighting = record["lighting"]
        assert lighting["source"] == "environment" and lighting["file"] in ("studio.exr", "outdoor.exr")
        assert 0.0 <= lighting["rotation_deg"] <= 360.0
    maps = read_exr(str(next((out / "shards").rglob("*.maps.exr")))).layers
    assert {"geometry_normal", "depth"} <= set(maps)


def test_the_readme_shows_the_figure_at_its_defaults_with_its_command():
    with Image.open(REPO / "docs" / "img" / "scenes.png") as image:
        assert image.size == (4 * DEFAULT_TILE, 2 * DEFAULT_TILE)
    readme = (REPO / "README.md").read_text()
    pictures = readme.split("\n## Pictures\n", 1)[1].split("\n## ", 1)[0]
    shown = re.search(r"`(shaderball figures scenes [^`]*)`\):\n\n!\[[^\]]*\]\(([^)]+)\)", pictures)
    assert shown and shown.group(1) == f"shaderball figures scenes --out {shown.group(2)}", shown
