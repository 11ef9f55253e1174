"""Datasets on other objects and under environment maps, built for real: the spec's keys, the
plan's draws, the records, resume and validate naming a changed mesh or map, and a default
spec unchanged by any of it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec_file import parse_spec, parse_spec_text, spec_digest, spec_to_toml
from pipeline.dataset.spec_rules import SpecError
from support.scenes import cli, environment_map, mesh_file, small_spec
from support.scenes import records as dataset_records

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"

BASE = small_spec("scenes", seed=7)


def test_a_spec_without_scene_keys_keeps_its_digest_and_snapshot():
    spec = parse_spec(SMOKE)
    text = SMOKE.read_text() + '\n[scene]\nobjects = ["shaderball"]\nscheme = "random"\n'
    explicit = parse_spec_text(text, base_dir=str(REPO))
    assert spec_digest(explicit) == spec_digest(spec)
    assert spec_to_toml(explicit) == spec_to_toml(spec)
    assert "[scene]" not in spec_to_toml(spec) and "source" not in spec_to_toml(spec)
    plan = plan_dataset(spec)
    assert "object" not in plan[0].materials[0].to_dict()
    assert "environment" not in plan[0].materials[0].samples[0].to_dict()


@pytest.mark.parametrize(
    "extra, field",
    [
        ('[scene]\nobjects = ["teapot"]\n', "scene.objects"),
        ('[scene]\nobjects = ["missing.obj"]\n', "scene.objects"),
        ("[scene]\nobjects = []\n", "scene.objects"),
        ('[scene]\nscheme = "shuffle"\n', "scene.scheme"),
        ('[lighting]\nsource = "environment"\n', "lighting.environments"),
        ('[lighting]\nsource = "moon"\n', "lighting.source"),
        ('[lighting]\nenvironments = ["x.hdr"]\n', "lighting.environments"),
        ("[lighting]\nrotation_deg = [10.0, 400.0]\n", "lighting.rotation_deg"),
        ("[lighting]\nintensity = [0.0, 1.0]\n", "lighting.intensity"),
    ],
)
def test_bad_scene_keys_are_refused_naming_the_field(tmp_path, extra, field):
    with pytest.raises(SpecError) as caught:
        parse_spec_text(BASE + extra, base_dir=str(tmp_path))
    assert field in str(caught.value)


def test_objects_are_drawn_per_material_by_the_declared_scheme(tmp_path):
    mesh = mesh_file(tmp_path)
    text = BASE + f'[scene]\nobjects = ["sphere", "torus", "{mesh.name}"]\nscheme = "cycle"\n'
    spec = parse_spec_text(text, base_dir=str(tmp_path))
    assert spec.scene.objects[2] == str(mesh)  # relative paths are the spec folder's
    materials = [m for shard in plan_dataset(spec) for m in shard.materials]
    assert [m.object for m in materials] == ["sphere", "torus", str(mesh), "sphere"]
    random = parse_spec_text(text.replace('"cycle"', '"random"'), base_dir=str(tmp_path))
    drawn = [m.object for shard in plan_dataset(random) for m in shard.materials]
    again = [m.object for shard in plan_dataset(random) for m in shard.materials]
    assert drawn == again and set(drawn) <= set(spec.scene.objects)
    # the mesh's bytes are in the digest: another file under the same name is another dataset
    before = spec_digest(spec)
    mesh.write_text(mesh.read_text() + "\n# changed\n")
    assert spec_digest(parse_spec_text(text, base_dir=str(tmp_path))) != before


@pytest.fixture(scope="module")
def object_build(tmp_path_factory):
    folder = tmp_path_factory.mktemp("objects")
    mesh = mesh_file(folder)
    spec = folder / "spec.toml"
    spec.write_text(
        BASE
        + f'[scene]\nobjects = ["sphere", "torus", "{mesh.name}", "shaderball"]\nscheme = "cycle"\n'
        + '[storage]\nlayers = ["diffuse", "specular", "roughness", "normal", "mask", "geometry_normal", "depth"]\n'
    )
    out = folder / "out"
    result = cli("build", spec, "--out", out, "--workers", "0")
    assert result.exit_code == 0, result.output
    return spec, out, mesh


def test_each_material_is_rendered_on_its_object_and_the_record_names_it(object_build):
    spec, out, mesh = object_build
    records = {r["id"]: r for r in dataset_records(out)}
    assert len(records) == 8
    names = {r["material_id"]: r["object"]["name"] for r in records.values()}
    assert names == {"m000000": "sphere", "m000001": "torus", "m000002": mesh.name, "m000003": "shaderball"}
    mesh_record = records["m000002_l0"]["object"]
    assert mesh_record["kind"] == "mesh" and mesh_record["uv_source"] in ("file", "xatlas")
    assert len(mesh_record["sha256"]) == 64 and len(mesh_record["file_sha256"]) == 64
    # among other objects the shaderball is named too (a spec of the shaderball alone names none)
    assert records["m000003_l0"]["object"] == {
        "name": "shaderball",
        "kind": "shaderball",
        "sha256": records["m000003_l0"]["object"]["sha256"],
        "uv_source": "built-in",
    }
    from pipeline.store.exr import read_exr

    masks = {}
    for material in ("m000000", "m000001", "m000002", "m000003"):
        shard = "s00000" if material in ("m000000", "m000001") else "s00001"
        maps = read_exr(str(out / "shards" / shard / f"{material}.maps.exr")).layers
        masks[material] = maps["mask"][..., 0] > 0.5
        assert masks[material].any()
        render = read_exr(str(out / "shards" / shard / f"{material}_l0.render.exr")).layers["render"]
        assert np.isfinite(render).all() and (render >= 0).all()
    # four objects, four silhouettes
    keys = list(masks)
    assert all((masks[a] != masks[b]).any() for i, a in enumerate(keys) for b in keys[i + 1 :])
    description = json.loads((out / "dataset.json").read_text())
    assert description["sources"] == {str(mesh): mesh_record["file_sha256"]}


def test_validate_passes_and_names_a_changed_mesh(object_build, tmp_path):
    spec, out, mesh = object_build
    result = cli("validate", out, "--json")
    assert result.exit_code == 0, result.output
    # resume: nothing to do
    again = cli("build", spec, "--out", out, "--workers", "0", "--json")
    assert again.exit_code == 0, again.output
    original = mesh.read_bytes()
    try:
        mesh.write_bytes(original + b"\n# edited\n")
        refused = cli("build", spec, "--out", out, "--workers", "0")
        assert refused.exit_code == 2 and mesh.name in refused.output and "changed" in refused.output
        checked = cli("validate", out)
        assert checked.exit_code != 0 and mesh.name in checked.output and "changed" in checked.output
    finally:
        mesh.write_bytes(original)


@pytest.fixture(scope="module")
def environment_build(tmp_path_factory):
    folder = tmp_path_factory.mktemp("environment")
    maps = folder / "maps"
    maps.mkdir()
    environment_map(maps / "sunny.exr")
    environment_map(maps / "low.exr", sun_row=14, sun_col=10)
    spec = folder / "spec.toml"
    spec.write_text(
        BASE
        + '[scene]\nobjects = ["sphere"]\n'
        + '[lighting]\nsource = "environment"\nenvironments = ["maps"]\nrotation_deg = [0.0, 180.0]\n'
        + "intensity = [0.5, 2.0]\n"
    )
    out = folder / "out"
    result = cli("build", spec, "--out", out, "--workers", "0")
    assert result.exit_code == 0, result.output
    return spec, out, maps


def test_environment_lit_samples_record_their_map_rotation_and_intensity(environment_build):
    spec, out, maps = environment_build
    records = dataset_records(out)
    assert len(records) == 8
    digests = {p.name: __import__("hashlib").sha256(p.read_bytes()).hexdigest() for p in maps.iterdir()}
    plan = {s.sample_id: s for shard in plan_dataset(parse_spec(spec)) for m in shard.materials for s in m.samples}
    for record in records:
        lighting, sample = record["lighting"], plan[record["id"]]
        assert lighting["source"] == "environment" and "elevation_deg" not in lighting
        assert lighting["file"] == Path(sample.environment).name
        assert lighting["sha256"] == digests[lighting["file"]]
        assert lighting["rotation_deg"] == sample.rotation_deg and 0.0 <= sample.rotation_deg <= 180.0
        assert lighting["scale"] == sample.intensity and 0.5 <= sample.intensity <= 2.0
        assert len(record["lighting_vector"]) == 4
        assert record["lighting_vector"][3] == pytest.approx(np.log2(sample.intensity), abs=1e-6)
    assert {r["lighting"]["file"] for r in records} == {"sunny.exr", "low.exr"}
    description = json.loads((out / "dataset.json").read_text())
    assert sorted(Path(p).name for p in description["sources"]) == ["low.exr", "sunny.exr"]
    assert description["counts"]["environments"] == ["low.exr", "sunny.exr"]
    assert cli("validate", out).exit_code == 0


def test_an_environment_lit_scene_holds_the_map_and_no_sun_or_sky(environment_build):
    from pipeline.dataset.materialize import make_material
    from pipeline.render.renderer import scene_dict
    from pipeline.run.shard import sample_light, worker_context

    spec_path, _out, _maps = environment_build
    spec = parse_spec(spec_path)
    material = plan_dataset(spec)[0].materials[0]
    ctx = worker_context(spec, "llvm_ad_rgb", material.object)
    maps, _ = make_material(material, spec)
    scene, lighting, _ = scene_dict(ctx.ball, ctx.camera, maps, sample_light(spec, material.samples[0]), ctx.settings)
    emitters = [
        k for k, v in scene.items() if isinstance(v, dict) and v.get("type") in ("envmap", "sunsky", "directional")
    ]
    assert emitters == ["environment"] and scene["environment"]["type"] == "envmap"
    assert lighting["effective"]["source"] == "environment"


def test_a_changed_map_is_named_by_resume_and_validate(environment_build):
    spec, out, maps = environment_build
    target = maps / "low.exr"
    original = target.read_bytes()
    try:
        environment_map(target, sun_row=20, sun_col=3)
        refused = cli("build", spec, "--out", out, "--workers", "0")
        assert refused.exit_code == 2 and "low.exr" in refused.output and "changed" in refused.output
        checked = cli("validate", out)
        assert checked.exit_code != 0 and "low.exr" in checked.output
    finally:
        target.write_bytes(original)


@pytest.mark.parametrize("bad", ["mesh", "map"])
def test_a_bad_mesh_or_map_stops_the_build_before_anything_is_written(tmp_path, bad):
    from pipeline.store.exr import write_exr

    if bad == "mesh":
        (tmp_path / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 nan 1\nf 1 2 3\n")
        extra = '[scene]\nobjects = ["broken.obj"]\n'
        name = "broken.obj"
    else:
        radiance = np.ones((8, 16, 3), np.float32)
        radiance[3, 5, 1] = -2.0
        write_exr(str(tmp_path / "negative.exr"), {"render": radiance})
        extra = '[lighting]\nsource = "environment"\nenvironments = ["negative.exr"]\n'
        name = "negative.exr"
    spec = tmp_path / "spec.toml"
    spec.write_text(BASE + extra)
    out = tmp_path / "out"
    result = cli("build", spec, "--out", out, "--workers", "0")
    assert result.exit_code == 2, result.output
    assert name in result.output
    assert not out.exists()


# 92.654...: an angle whose composed transform's inverse is an ulp off the one Mitsuba recomputes
@pytest.mark.parametrize("rotation", [130.0, 92.65428164130196, 266.0271646851916])
def test_a_scene_moved_to_another_rotation_of_its_map_renders_the_bytes_of_a_fresh_one(environment_build, rotation):
    """MaterialScene moves an environment-lit scene to another rotation and scale of the same map
    in place; the render equals one of a scene loaded for that lighting, bit for bit (llvm)."""
    from pipeline.dataset.materialize import make_material
    from pipeline.render.mitsuba_env import load_mitsuba
    from pipeline.render.renderer import MaterialScene, render_in_passes
    from pipeline.run.shard import worker_context
    from sky.environment import EnvironmentLight

    spec_path, _out, maps_folder = environment_build
    spec = parse_spec(spec_path)
    material = plan_dataset(spec)[0].materials[0]
    ctx = worker_context(spec, "llvm_ad_rgb", material.object)
    maps, _ = make_material(material, spec)
    mi = load_mitsuba("llvm_ad_rgb")
    path = str(maps_folder / "sunny.exr")
    digest = __import__("hashlib").sha256(Path(path).read_bytes()).hexdigest()
    first, second = EnvironmentLight(path, digest, 10.0, 1.0), EnvironmentLight(path, digest, rotation, 1.7)

    def render(scene):
        return render_in_passes(mi, scene, 4, 11)[..., :3]

    with MaterialScene() as held:
        held.lit(mi, ctx.ball, ctx.camera, maps, first, ctx.settings)
        assert held.step(ctx.ball, ctx.camera, maps, ctx.settings, second) == "light"
        moved, record, _ = held.lit(mi, ctx.ball, ctx.camera, maps, second, ctx.settings)
        assert record["effective"]["rotation_deg"] == rotation
        image_moved = render(moved)
    with MaterialScene() as fresh:
        loaded, _, _ = fresh.lit(mi, ctx.ball, ctx.camera, maps, second, ctx.settings)
        image_fresh = render(loaded)
    assert np.array_equal(image_moved, image_fresh)
    with MaterialScene() as held:
        held.lit(mi, ctx.ball, ctx.camera, maps, first, ctx.settings)
        other = str(maps_folder / "low.exr")
        other_light = EnvironmentLight(other, __import__("hashlib").sha256(Path(other).read_bytes()).hexdigest(), 0.0)
        assert held.step(ctx.ball, ctx.camera, maps, ctx.settings, other_light) == "load"
