"""The check stages and `plan` on datasets of other objects and under environment maps, built for
real (32 px, 4 spp): `info` shows materials per object and the maps (their ranges, not the sun's),
`preview` labels name the object and the map, `plan` times every object and map, and
`validate --repair` refuses a dataset whose mesh or map is missing or changed. A spec that names
neither reports as before."""

from __future__ import annotations

import json
import math
import os
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from pipeline.bench.first_renders import (
    COVER_LIGHTS,
    TIMED_LIGHTS,
    covering_materials,
    first_materials,
    scene_costs,
)
from pipeline.check.preview import (
    FULL_STEP_LINES,
    GAP,
    HEADER_HEIGHT,
    contact_sheet,
    label_text,
    line_step,
)
from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec_file import parse_spec, parse_spec_text
from support.scenes import cli, environment_map, mesh_file, small_spec
from support.scenes import records as dataset_records

BASE = small_spec("stages")
ENVIRONMENT = (
    '[lighting]\nsource = "environment"\nenvironments = ["maps"]\nrotation_deg = [0.0, 180.0]\nintensity = [0.5, 2.0]\n'
)


def _json(result) -> dict:
    return json.loads(result.output[result.output.index("{") :])


def _scene_folder(folder: Path, objects: str = '["sphere", "wedge.obj"]', materials: int = 4, lights: int = 2) -> Path:
    """A spec (in ``folder``, with its mesh file and two maps) on ``objects`` under the maps."""
    mesh_file(folder)
    (folder / "maps").mkdir()
    environment_map(folder / "maps" / "sunny.exr")
    environment_map(folder / "maps" / "low.exr", sun_row=14, sun_col=10)
    spec = folder / "spec.toml"
    counts = BASE.replace("materials = 4", f"materials = {materials}").replace(
        "lights_per_material = 2", f"lights_per_material = {lights}"
    )
    spec.write_text(counts + f'[scene]\nobjects = {objects}\nscheme = "cycle"\n' + ENVIRONMENT)
    return spec


@pytest.fixture(scope="module")
def scene_build(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene-stages")
    spec = _scene_folder(folder)
    out = folder / "out"
    result = cli("build", spec, "--out", out, "--workers", "0")
    assert result.exit_code == 0, result.output
    return spec, out


@pytest.fixture(scope="module")
def default_build(tmp_path_factory):
    """A spec naming no object and no map: the shaderball under the sun."""
    folder = tmp_path_factory.mktemp("default-stages")
    spec = folder / "spec.toml"
    spec.write_text(BASE)
    out = folder / "out"
    result = cli("build", spec, "--out", out, "--workers", "0")
    assert result.exit_code == 0, result.output
    return spec, out


# --------------------------------------------------------------------------- info


def test_info_shows_materials_per_object_and_the_maps_instead_of_the_sun(scene_build):
    spec, out = scene_build
    text = cli("info", out)
    assert text.exit_code == 0, text.output
    lines = text.output.splitlines()
    assert "objects (materials planned, cycle): sphere 2, wedge.obj 2" in lines
    assert "environment maps (2): low.exr, sunny.exr" in lines
    render = next(line for line in lines if line.startswith("render:"))
    assert "lighting: environment maps" in render and "rotation [0.0, 180.0] deg" in render
    assert "intensity [0.5, 2.0]" in render and "elevation" not in render and "turbidity" not in render
    doc = _json(cli("info", out, "--json"))
    # the plan's counts are the records': materials per object as built
    built = Counter(
        r.get("object", {}).get("name", "shaderball") for r in dataset_records(out) if r["light_index"] == 0
    )
    assert doc["objects"] == dict(built) == {"sphere": 2, "wedge.obj": 2}
    assert (
        doc["environments"] == sorted({r["lighting"]["file"] for r in dataset_records(out)}) == ["low.exr", "sunny.exr"]
    )
    # `info SPEC` (the plan without timing) says the same
    planned = cli("info", spec)
    assert planned.exit_code == 0, planned.output
    assert "objects (materials planned, cycle): sphere 2, wedge.obj 2" in planned.output
    assert "2 map(s): low.exr, sunny.exr" in planned.output and "rotation [0.0, 180.0] deg" in planned.output
    doc = _json(cli("plan", spec, "--no-timing", "--json"))
    assert doc["objects"] == {"sphere": 2, "wedge.obj": 2} and doc["environments"] == ["low.exr", "sunny.exr"]
    assert doc["scheme"] == "cycle" and "environment maps" in doc["lighting"]


def test_info_of_a_spec_naming_neither_has_no_scene_keys(default_build):
    spec, out = default_build
    doc = _json(cli("info", out, "--json"))
    assert "objects" not in doc and "environments" not in doc
    assert "elevation [5.0, 90.0] deg" in doc["spec_lines"][1]
    assert not any(line.startswith(("objects", "environment maps")) for line in doc["spec_lines"])
    planned = _json(cli("plan", spec, "--no-timing", "--json"))
    assert not {"objects", "environments", "lighting", "scheme"} & set(planned)


# --------------------------------------------------------------------------- preview


def test_preview_labels_name_the_object_and_the_map(scene_build, tmp_path):
    from PIL import Image

    _spec, out = scene_build
    png = tmp_path / "sheet.png"
    result = cli("preview", out, "--out", png, "--json")
    assert result.exit_code == 0, result.output
    samples = _json(result)["samples"]
    records = {r["id"]: r for r in dataset_records(out)}
    chosen = [records[s] for s in samples]
    for record in chosen:
        lines = label_text(record, show_object=True)
        lighting = record["lighting"]
        assert lines[2] == f"on {record['object']['name']}"
        assert lines[3:6] == [
            f"map {lighting['file']}",
            f"rotation {lighting['rotation_deg']:.1f} deg",
            f"scale {lighting['scale']:.2f}",
        ]
        assert not any(line.startswith(("sun ", "turbidity")) for line in lines)
    # the sheet written is the one drawn with those labels, not the one without the objects'
    drawn = np.asarray(Image.open(png).convert("RGB"))
    tile = (drawn.shape[0] - HEADER_HEIGHT - GAP) // len(chosen) - GAP
    with_objects = contact_sheet(str(out), chosen, tile, 32, [], show_objects=True)
    without = contact_sheet(str(out), chosen, tile, 32, [], show_objects=False)
    assert np.array_equal(drawn, with_objects)
    assert not np.array_equal(drawn, without)


def test_labels_of_sun_lit_samples_on_objects_and_on_the_shaderball():
    record = {
        "id": "m000003_l1",
        "material": {"kind": "uniform"},
        "lighting": {
            "elevation_deg": 30.0,
            "azimuth_deg": 40.0,
            "turbidity": 3.0,
            "requested": {"elevation_deg": 30.0},
        },
        "stats": {},
    }
    sun = ["sun elevation 30.0 deg", "sun azimuth 40.0 deg", "turbidity 3.00"]
    assert label_text(record) == ["m000003_l1", "uniform", *sun]  # as it always was
    assert label_text(record, show_object=True) == ["m000003_l1", "uniform", "on shaderball", *sun]
    on_torus = {**record, "object": {"name": "torus", "kind": "primitive"}}
    assert label_text(on_torus, show_object=True)[2] == "on torus"
    long_name = {**record, "object": {"name": "a-very-long-mesh-file-name-indeed.obj"}}
    assert len(label_text(long_name, show_object=True)[2]) <= len("on ") + 24
    # the longest label (raised sun, flagged, on an object) stays in its row; shorter ones as ever
    assert line_step(FULL_STEP_LINES, 128) == 17 and line_step(FULL_STEP_LINES, 40) == 17
    step = line_step(FULL_STEP_LINES + 1, 128)
    assert 4 + step * FULL_STEP_LINES + 12 <= 128 + GAP


def test_preview_of_a_spec_naming_neither_draws_no_object(default_build, tmp_path):
    _spec, out = default_build
    result = cli("preview", out, "--out", tmp_path / "sheet.png", "--json")
    assert result.exit_code == 0, result.output
    records = {r["id"]: r for r in dataset_records(out)}
    assert all("object" not in records[s] for s in _json(result)["samples"])


# --------------------------------------------------------------------------- plan


def test_plan_times_every_object_and_map(tmp_path):
    spec_path = _scene_folder(tmp_path, objects='["sphere", "torus", "wedge.obj"]', materials=6)
    result = cli("plan", spec_path, "--renders", "1", "--workers", "0", "--json")
    assert result.exit_code == 0, result.output
    doc = _json(result)
    timing = doc["timing"]
    assert list(timing["by_object"]) == ["sphere", "torus", "wedge.obj"]
    spec = parse_spec(spec_path)
    drawn = {os.path.basename(s.environment) for sh in plan_dataset(spec) for m in sh.materials for s in m.samples}
    assert set(timing["by_environment"]) == drawn
    for group in (*timing["by_object"].values(), *timing["by_environment"].values()):
        assert group["renders"] >= 1 and group["render_s"] > 0
        assert math.isfinite(group["seconds_per_render"]) and group["seconds_per_render"] > 0
    assert math.isfinite(timing["scene_weight"]) and timing["scene_weight"] > 0
    # the first material and one of each kind: the objects and maps they lack were added
    assert timing["renders"] < sum(g["renders"] for g in timing["by_object"].values())
    text = cli("plan", spec_path, "--renders", "1", "--workers", "0")
    assert text.exit_code == 0, text.output
    per_object = next(line for line in text.output.splitlines() if line.startswith("time per object"))
    assert all(name in per_object for name in ("sphere", "torus", "wedge.obj"))
    assert any(line.startswith("time per environment map") for line in text.output.splitlines())


def test_plan_of_a_spec_naming_neither_has_no_scene_timing(default_build):
    spec, _out = default_build
    result = cli("plan", spec, "--renders", "1", "--workers", "0", "--json")
    assert result.exit_code == 0, result.output
    timing = _json(result)["timing"]
    assert not {"by_object", "by_environment", "scene_weight"} & set(timing)
    text = cli("plan", spec, "--renders", "1", "--workers", "0").output
    assert "time per object" not in text and "time per environment map" not in text


def test_covering_materials_add_one_lighting_for_each_object_and_map_missing(tmp_path):
    spec_path = _scene_folder(
        tmp_path, objects='["sphere", "torus", "rounded_cube", "wedge.obj"]', materials=12, lights=TIMED_LIGHTS + 2
    )
    spec = parse_spec(spec_path)
    plans = plan_dataset(spec)
    chosen = first_materials(plans, 1, (), TIMED_LIGHTS)
    assert len(chosen) == 1 and chosen[0].n_lights == TIMED_LIGHTS
    # a material cut to its first lightings keeps its maps, rotations and intensities with them
    whole = plans[0].materials[0]
    assert chosen[0].environment == whole.environment[:TIMED_LIGHTS]
    assert [s.rotation_deg for s in chosen[0].samples] == [s.rotation_deg for s in whole.samples[:TIMED_LIGHTS]]
    extra = covering_materials(plans, chosen, spec.scene.objects, plans.environments)
    assert all(m.n_lights == COVER_LIGHTS for m in extra)
    assert {m.object for m in chosen + extra} == set(spec.scene.objects)
    timed_maps = {s.environment for m in chosen + extra for s in m.samples}
    assert timed_maps == set(plans.environments)
    # each added lighting is the plan's own: its map, rotation and seed
    planned = {(s.material_id, s.render_seed): s for sh in plans for m in sh.materials for s in m.samples}
    for m in extra:
        s = m.samples[0]
        original = planned[(m.material_id, s.render_seed)]
        assert (s.environment, s.rotation_deg, s.intensity) == (
            original.environment,
            original.rotation_deg,
            original.intensity,
        )
    # a spec naming neither adds nothing
    default = plan_dataset(parse_spec_text(BASE))
    assert covering_materials(default, first_materials(default, 1, (), TIMED_LIGHTS), (), ()) == []


def test_scene_costs_weigh_the_spec_figure_to_its_shares():
    # the base renders are all on A (1 s); B, added to cover it, costs 3 s a render
    times = [("A", None, 1.0), ("A", None, 1.0), ("B", None, 3.0)]
    by_object, by_map, weight = scene_costs(times, 2, {"A": 0.5, "B": 0.5}, {})
    assert by_map == {}
    assert by_object["A"]["relative"] == pytest.approx(1.0)
    assert by_object["B"]["relative"] == pytest.approx(3.0)
    assert (by_object["A"]["renders"], by_object["B"]["renders"]) == (2, 1)
    assert weight == pytest.approx(2.0)  # half the spec's renders cost 3x the timed mix
    _o, by_map, weight = scene_costs(
        [("A", "x.exr", 2.0), ("A", "y.exr", 2.0)], 2, {"A": 1.0}, {"x.exr": 0.5, "y.exr": 0.5}
    )
    assert weight == pytest.approx(1.0) and set(by_map) == {"x.exr", "y.exr"}


# --------------------------------------------------------------------------- validate --repair


def _tree(root: Path) -> list[tuple[str, int, int]]:
    return sorted((p.relative_to(root).as_posix(), p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*"))


@pytest.mark.parametrize(
    "target, how, key",
    [
        ("wedge.obj", "changed", "scene.objects"),
        ("wedge.obj", "missing", "scene.objects"),
        ("maps/low.exr", "changed", "lighting.environments"),
        ("maps/low.exr", "missing", "lighting.environments"),
    ],
)
def test_repair_refuses_a_dataset_whose_mesh_or_map_is_missing_or_changed(scene_build, tmp_path, target, how, key):
    spec, out = scene_build
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    (copy / "shards" / "s00000" / "m000000_l0.render.exr").unlink()  # something a repair would fix
    path = spec.parent / target
    original = path.read_bytes()
    try:
        if how == "missing":
            path.unlink()
        elif path.suffix == ".obj":
            path.write_bytes(original + b"\n# edited\n")
        else:
            environment_map(path, sun_row=20, sun_col=3)
        before = _tree(copy)
        for extra in ((), ("--spec", spec)):
            refused = cli("validate", copy, "--repair", *extra)
            assert refused.exit_code == 2, refused.output
            assert f'"{path}" ({key}) {"is missing" if how == "missing" else "changed"}' in refused.output
            assert "nothing was written" in refused.output
            assert _tree(copy) == before
        # validate names the file too (a missing mesh leaves the snapshot unreadable: by its key)
        checked = cli("validate", copy)
        assert checked.exit_code != 0 and str(path) in checked.output
        if how == "missing":
            assert ("scene.objects" if path.suffix == ".obj" else f'"{path}" is missing') in checked.output
    finally:
        path.write_bytes(original)
    # the same files back: the repair goes ahead and the dataset validates
    repaired = cli("validate", copy, "--repair")
    assert repaired.exit_code == 0, repaired.output
    assert (copy / "shards" / "s00000" / "m000000_l0.render.exr").is_file()
