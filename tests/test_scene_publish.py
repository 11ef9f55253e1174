"""A dataset on other objects under environment maps, built for real (32 px, 4 spp, geometry
layers stored), published, verified and unpacked: the samples table, the card, Croissant and
the Hugging Face configs name the object and the map (by digest: neither travels in the
publication); the torch loader gives each sample its scene; a forged record is refused."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import mlcroissant as mlc
import numpy as np
import pytest
import torch

from pipeline.publish.refusal import Refused
from pipeline.publish.request import VerifyRequest
from pipeline.publish.scene_fields import OBJECT_COLUMNS, SCENE_COLUMNS, has_scene_columns, scene_problem
from pipeline.publish.table import COLUMNS, sample_row
from pipeline.publish.verify import verify
from pipeline.publish.writer import write_publication
from pipeline.store.exr import read_exr
from pipeline.store.records import dumps
from support.publishing import files_of, hf_env
from support.scenes import cli, environment_map, small_spec

pytestmark = pytest.mark.slow  # a real build, publishes, the Hugging Face client in a process

SPEC = (
    small_spec("scene-publish", materials=3)
    + """
[scene]
objects = ["sphere", "{mesh}", "shaderball"]
scheme = "cycle"

[lighting]
source = "environment"
environments = ["maps"]
rotation_deg = [0.0, 180.0]
intensity = [0.5, 2.0]

[storage]
layers = ["diffuse", "specular", "roughness", "normal", "mask", "geometry_normal", "depth"]
"""
)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """(spec folder, dataset folder, publication): a sphere, a mesh file and the shaderball
    under two maps."""
    import trimesh

    folder = tmp_path_factory.mktemp("scene-publish")
    trimesh.creation.cone(radius=0.4, height=1.0, sections=24).export(folder / "wedge.obj")
    (folder / "maps").mkdir()
    environment_map(folder / "maps" / "sunny.exr", 6, 40)
    environment_map(folder / "maps" / "low.exr", 14, 10)
    spec = folder / "spec.toml"
    spec.write_text(SPEC.replace("{mesh}", "wedge.obj"))
    out, pub = folder / "out", folder / "pub"
    built = cli("build", spec, "--out", out, "--workers", "0")
    assert built.exit_code == 0, built.output
    published = cli("publish", out, "--out", pub)
    assert published.exit_code == 0, published.output
    return folder, out, pub


def _rows(pub: Path) -> list[dict]:
    return [json.loads(line) for line in (pub / "samples.jsonl").read_text().splitlines()]


def _manifest(root: Path) -> list[dict]:
    return [json.loads(line) for line in (root / "manifest.jsonl").read_text().splitlines()]


def test_it_verifies_and_unpacks_to_the_dataset_byte_for_byte(scene, tmp_path):
    _folder, out, pub = scene
    verified = cli("verify", pub, "--json")
    assert verified.exit_code == 0, verified.output
    unpacked = tmp_path / "unpacked"
    result = cli("unpack", pub, "--out", unpacked)
    assert result.exit_code == 0, result.output
    assert files_of(unpacked) == files_of(out)  # validated by unpack too
    # the maps members hold the geometry layers, as the folder's files do
    with tarfile.open(pub / "shards" / "materials-000000.tar") as tar:
        name = next(n for n in tar.getnames() if n.endswith(".maps.exr"))
        layers = read_exr(tar.extractfile(name).read(), name).layers
    assert {"geometry_normal", "depth", "mask"} <= set(layers)


def test_rows_name_each_sample_s_object_and_map_by_digest(scene):
    folder, out, pub = scene
    assert has_scene_columns(json.loads((out / "dataset.json").read_text()))
    maps = {p.name: _sha(p) for p in (folder / "maps").iterdir()}
    records = {r["id"]: r for r in _manifest(out)}
    rows = _rows(pub)
    assert len(rows) == 6 and {r["object"] for r in rows} == {"sphere", "wedge.obj", "shaderball"}
    for row in rows:
        record = records[row["id"]]
        assert set(row) == set(COLUMNS) | set(SCENE_COLUMNS)  # one schema for every row
        assert row["light_source"] == "environment"
        assert row["environment_sha256"] == maps[row["environment"]] == record["lighting"]["sha256"]
        assert row["environment_rotation_deg"] == record["lighting"]["rotation_deg"]
        assert row["environment_scale"] == record["lighting"]["scale"]
        assert row["object_sha256"] == record["object"]["sha256"] and len(row["object_sha256"]) == 64
        assert row["object_kind"] == record["object"]["kind"]  # the shaderball named among other objects too
        if row["object"] == "wedge.obj":
            assert row["object_kind"] == "mesh" and row["object_file_sha256"] == _sha(folder / "wedge.obj")
    # a material's row (its materials-tar member) carries its object
    with tarfile.open(pub / "shards" / "materials-000000.tar") as tar:
        material = json.loads(tar.extractfile("m000001.json").read())
    assert material["object"] == "wedge.obj" and set(OBJECT_COLUMNS) <= set(material)


def test_the_card_and_croissant_name_the_fields_and_say_files_travel_by_digest(scene, monkeypatch):
    folder, out, pub = scene
    card = (pub / "README.md").read_text()
    for column in SCENE_COLUMNS:
        assert f"| `{column}` |" in card
    assert "travel by digest" in card and "geometry_normal.X/Y/Z" in card and "depth.Z" in card
    for path in [folder / "wedge.obj", *(folder / "maps").iterdir()]:
        assert _sha(path) in card  # each file the reader may check a copy against
    assert "sun scheme" not in card  # no sun was rendered
    metadata = json.loads((pub / "croissant.json").read_text())
    names = {f["name"] for f in metadata["recordSet"][0]["field"]}
    assert set(SCENE_COLUMNS) | {"geometry_normal", "depth"} <= names
    tool = Path(sys.executable).with_name("mlcroissant")
    checked = subprocess.run([str(tool), "validate", "--jsonld", str(pub / "croissant.json")], capture_output=True)
    assert checked.returncode == 0, checked.stderr[-2000:]

    def no_extraction(*args, **kwargs):
        raise AssertionError("mlcroissant extracted an archive")

    monkeypatch.setattr(tarfile.TarFile, "extractall", no_extraction)
    records = list(mlc.Dataset(str(pub / "croissant.json")).records("samples"))
    expected = _manifest(out)
    assert [r["samples/object_sha256"].decode() if r["samples/object_sha256"] else None for r in records] == [
        (e.get("object") or {}).get("sha256") for e in expected
    ]
    assert [r["samples/environment"].decode() for r in records] == [e["lighting"]["file"] for e in expected]
    assert all(r["samples/geometry_normal"].decode().endswith(".maps.exr") for r in records)


HF_CLIENT = r"""
import json, sys
import datasets
pub = sys.argv[1]
renders = datasets.load_dataset(pub, "renders", split="train")
materials = datasets.load_dataset(pub, "materials", split="train")
print(json.dumps({
    "object": [r["object"] for r in renders["json"]],
    "lighting": [{k: r["lighting"][k] for k in ("source", "file", "sha256", "scale")} for r in renders["json"]],
    "material_object": [r["object"] for r in materials["json"]],
}))
"""


def test_hugging_face_datasets_reads_the_object_and_the_map(scene, tmp_path):
    _folder, out, pub = scene
    copy = tmp_path / "pub"
    shutil.copytree(pub, copy)  # the client writes nothing into PUB, and may read only a copy
    done = subprocess.run(
        [sys.executable, "-c", HF_CLIENT, str(copy)], capture_output=True, text=True, env=hf_env(tmp_path)
    )
    assert done.returncode == 0, done.stderr[-3000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    expected = _manifest(out)
    assert [o["name"] if o else None for o in got["object"]] == [(e.get("object") or {}).get("name") for e in expected]
    for lighting, record in zip(got["lighting"], expected):
        assert lighting["source"] == "environment" and lighting["file"] == record["lighting"]["file"]
        assert lighting["sha256"] == record["lighting"]["sha256"]
        assert lighting["scale"] == pytest.approx(record["lighting"]["scale"], rel=1e-12)
    assert got["material_object"] == ["sphere", "wedge.obj", "shaderball"]


@pytest.mark.parametrize("source", ["folder", "publication"])
def test_the_loader_gives_each_sample_its_scene_and_stored_geometry(scene, source):
    from pipeline.neural.data import GEOMETRY_KEYS, SCENE_KEYS, open_dataset, with_scene

    _folder, out, pub = scene
    plain = open_dataset(str(out if source == "folder" else pub))
    view = with_scene(plain)
    records = {r["id"]: r for r in _manifest(out)}
    for index in range(len(view)):
        item, before = view[index], plain[index]
        assert not set(SCENE_KEYS) & set(before) and not set(GEOMETRY_KEYS) & set(before)  # opt in
        record = records[item["id"]]
        assert item["object"] == (record.get("object") or {}).get("name", "shaderball")
        assert item["light_source"] == "environment" and item["environment"] == record["lighting"]["file"]
        assert torch.equal(item["maps"], before["maps"]) and torch.equal(item["target"], before["target"])
        maps_rel = next(f["path"] for f in record["files"] if f["role"] == "maps")
        layers = read_exr(str(out / maps_rel)).layers
        assert item["geometry_normal"].shape == (3, 32, 32) and item["depth"].shape == (1, 32, 32)
        np.testing.assert_array_equal(item["geometry_normal"].numpy(), layers["geometry_normal"].transpose(2, 0, 1))
        np.testing.assert_array_equal(item["depth"].numpy()[0], layers["depth"].reshape(32, 32))
        inside = layers["mask"][..., 0] > 0.5
        assert (item["depth"][0].numpy()[inside] > 0).all()
    # at half the resolution each layer is the mean of 2 x 2 pixels, as the maps are
    half = with_scene(open_dataset(str(out), resolution=16))
    full = view[0]["depth"][0].numpy().astype(np.float64)
    expected = full.reshape(16, 2, 16, 2).mean(axis=(1, 3))
    np.testing.assert_allclose(half[0]["depth"][0].numpy(), expected, rtol=1e-6)
    assert half.subset(["m000000"])[0]["object"] == "sphere"


def test_geometry_absent_from_a_maps_file_is_not_invented():
    from pipeline.neural.data import geometry_tensors, scene_fields

    layers = {"mask": np.ones((4, 4, 1), np.float32), "depth": np.full((4, 4, 1), 2.0, np.float32)}
    got = geometry_tensors(layers)
    assert set(got) == {"depth"} and got["depth"].shape == (1, 4, 4)
    assert geometry_tensors({"mask": layers["mask"]}) == {}
    assert scene_fields({"lighting": {"elevation_deg": 30.0}}) == {
        "object": "shaderball",
        "light_source": "sun_sky",
        "environment": "",
    }


def _forge(out: Path, copy: Path, change) -> None:
    """The dataset folder ``out`` copied to ``copy`` with ``change`` applied to the first
    material's records wherever a record is kept (manifest, marker, record files): a
    consistent forgery, which only the record's own checks can refuse."""
    shutil.copytree(out, copy)

    def fix(record: dict) -> dict:
        if record["material_id"] == "m000001":
            change(record)
        return record

    manifest = copy / "manifest.jsonl"
    manifest.write_text("".join(dumps(fix(json.loads(line))) + "\n" for line in manifest.read_text().splitlines()))
    for marker_path in copy.glob("shards/*/COMPLETE.json"):
        marker = json.loads(marker_path.read_text())
        marker["records"] = [fix(r) for r in marker["records"]]
        marker_path.write_text(dumps(marker) + "\n")
    for record_path in copy.glob("shards/*/m*_l*.json"):
        record_path.write_text(dumps(fix(json.loads(record_path.read_text()))) + "\n")


@pytest.mark.parametrize(
    "where, value, words",
    [
        ("object.sha256", 12345, "not a string"),
        ("object.sha256", "not-a-digest", "not a SHA-256"),
        ("object.file_sha256", "ABCDEF" * 10 + "ABCD", "not a SHA-256"),
        ("lighting.sha256", "", "not a SHA-256"),
        ("lighting.scale", -1.0, "not a finite number > 0"),
        ("lighting.source", "moon", "not one of sun_sky, environment"),
    ],
)
def test_verify_refuses_a_forged_scene_field(scene, tmp_path, where, value, words):
    _folder, out, _pub = scene
    section, name = where.split(".")

    def change(record: dict) -> None:
        record[section][name] = value

    _forge(out, tmp_path / "forged", change)
    pub = tmp_path / "pub"
    write_publication(str(tmp_path / "forged"), str(pub), contact_sheet=False)  # no validation first
    with pytest.raises(Refused) as refused:
        verify(VerifyRequest(str(pub)))
    assert refused.value.kind == "bad_record" and where in str(refused.value) and words in str(refused.value)
    assert "manifest.jsonl line 3:" in str(refused.value)  # m000001's first lighting


def test_a_default_publication_has_no_scene_columns(scene):
    """A dataset whose counts name no objects or maps (every default spec's) publishes the
    table it always did: no scene column, the same row from the same record."""
    _folder, out, _pub = scene
    assert not has_scene_columns({"counts": {"materials": 8, "renders": 16}})
    record = {k: v for k, v in next(iter(_manifest(out))).items() if k != "object"}  # a default spec's record
    previews = {"render_preview": ("0" * 64, 1), "maps_preview": ("0" * 64, 1)}
    assert set(sample_row(record, "shards/renders-000000.tar", "0" * 64, 1, previews)) == set(COLUMNS)
    assert scene_problem({"lighting": {"elevation_deg": 10.0}}) is None
