"""The smoke publication as the Hugging Face clients see it, offline: `datasets.load_dataset`
on the folder (the card's configs) and on the tars (`"webdataset"`), `huggingface_hub`'s card
parser; the previews (deterministic, checked like every member); mlcroissant's floats.

Hugging Face's clients run in a process of their own with every cache under tmp_path and
HF_DATASETS_OFFLINE / HF_HUB_OFFLINE set (support.publishing.hf_env): nothing is downloaded,
nothing is written to the user's cache or into PUB.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.dataset.spec_file import parse_spec
from pipeline.publish.card import EXR_TWO_LINES, exr_check
from pipeline.publish.previews import PREVIEW_SIDE, encode_png, maps_preview, render_preview
from pipeline.publish.refusal import Refused
from pipeline.publish.request import PublishRequest, VerifyRequest
from pipeline.publish.verify import verify
from pipeline.publish.writer import publish
from pipeline.store.exr import read_exr
from support.bombs import png_bomb
from support.publishing import SMOKE, files_of, hf_env, members, reseal, rewrite_tar, sha

pytestmark = pytest.mark.slow  # a smoke build (once per session), a publish, the clients

REPO = Path(__file__).resolve().parents[1]
SHARD_BYTES = 300_000

#: Run by the clients' process: argv[1] is PUB; prints one JSON object.
CLIENTS = r"""
import glob, hashlib, io, json, sys
import datasets
from huggingface_hub import DatasetCard
from datasets.info import DatasetInfosDict

pub, two_lines, check = sys.argv[1], sys.argv[2], sys.argv[3]
out = {}
card = DatasetCard.load(f"{pub}/README.md")
out["configs"] = card.data.configs
out["card_features"] = {
    name: str(info.features) for name, info in DatasetInfosDict.from_dataset_card_data(card.data).items()
}
default = datasets.load_dataset(pub, split="train")
out["default"] = [default.num_rows, default.column_names]
for config in ("renders", "materials"):
    ds = datasets.load_dataset(pub, config, split="train")
    features = ds.features
    raw = ds.cast_column("render.png" if config == "renders" else "maps.png", datasets.Image(decode=False))
    image_column = "render.png" if config == "renders" else "maps.png"
    exr_column = "render.exr" if config == "renders" else "maps.exr"
    row = ds[len(ds) - 1]
    namespace = {"row": row}
    exec(check, namespace)  # the recipes' checked_exr, which the two lines call
    exec(two_lines.replace('"render.exr"', f'"{exr_column}"'), namespace)  # the card's lines, as written
    out[config] = {
        "rows": ds.num_rows,
        "columns": ds.column_names,
        "features": {k: repr(v) for k, v in features.items()},
        "keys": list(ds["__key__"]),
        "json": list(ds["json"]),
        "image_types": sorted({type(f).__name__ for f in [features[image_column]]}),
        "image_size": list(row[image_column].size),
        "image_mode": row[image_column].mode,
        "png_sha256": [hashlib.sha256(r[image_column]["bytes"]).hexdigest() for r in raw],
        "exr_sha256": [hashlib.sha256(r[exr_column]).hexdigest() for r in ds],
        "last_key": row["__key__"],
        "decoded": {k: [list(v.shape), str(v.dtype), v.astype("float64").ravel().tolist()]
                    for k, v in namespace["layers"].items()},
    }
for kind in ("renders", "materials"):
    files = sorted(glob.glob(f"{pub}/shards/{kind}-*.tar"))
    plain = datasets.load_dataset("webdataset", data_files={"train": files}, split="train")
    out[f"plain_{kind}"] = [plain.num_rows, sorted(plain.column_names), repr(plain.features.get("render.png") or plain.features.get("maps.png"))]
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def pub(smoke, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("hub") / "pub"
    publish(PublishRequest(str(smoke), str(out), shard_bytes=SHARD_BYTES))
    return out


@pytest.fixture(scope="module")
def seen(pub, tmp_path_factory) -> dict:
    """What the Hugging Face clients see of the publication (one process, offline)."""
    before = files_of(pub)
    env = hf_env(tmp_path_factory.mktemp("hf"))
    ran = subprocess.run(
        [sys.executable, "-c", CLIENTS, str(pub), EXR_TWO_LINES, "import struct\n" + exr_check(parse_spec(SMOKE))],
        env=env,
        capture_output=True,
        text=True,
        cwd=pub,
    )
    assert ran.returncode == 0, ran.stderr[-4000:]
    assert files_of(pub) == before  # the clients wrote nothing into PUB
    return json.loads(ran.stdout.splitlines()[-1])


def manifest(root: Path) -> list[dict]:
    return [json.loads(line) for line in (root / "manifest.jsonl").read_text().splitlines()]


def rows(pub: Path) -> list[dict]:
    return [json.loads(line) for line in (pub / "samples.jsonl").read_text().splitlines()]


# --------------------------------------------------------------------------- the clients


def test_the_card_parses_with_huggingface_hub_and_declares_two_configs(pub, seen):
    assert EXR_TWO_LINES.rstrip("\n") in (pub / "README.md").read_text()  # the lines the tests run
    assert [(c["config_name"], c.get("default", False)) for c in seen["configs"]] == [
        ("renders", True),
        ("materials", False),
    ]
    assert [c["data_files"] for c in seen["configs"]] == [
        [{"split": "train", "path": "shards/renders-*.tar"}],
        [{"split": "train", "path": "shards/materials-*.tar"}],
    ]
    assert set(seen["card_features"]) == {"renders", "materials"}
    assert "Image(" in seen["card_features"]["renders"] and "Image(" in seen["card_features"]["materials"]


def test_load_dataset_of_the_folder_gives_renders_by_default(seen):
    assert seen["default"] == [16, ["__key__", "render.png", "render.exr", "json", "__url__"]]


def test_the_renders_config_has_a_row_per_sample_with_typed_metadata(smoke, seen):
    renders = seen["renders"]
    records = manifest(smoke)
    assert renders["rows"] == 16 and renders["keys"] == [r["id"] for r in records]
    features = renders["features"]
    assert features["render.png"].startswith("Image(") and features["render.exr"] == "Value('binary')"
    assert "'material': Value('int64')" in features["json"] and "'family': Value('string')" in features["json"]
    assert "'lighting_vector': List(Value('float32'))" in features["json"]
    for got, record in zip(renders["json"], records):
        assert got["seeds"]["material"] == record["seeds"]["material"]  # 63-bit, exact through int64
        assert got["seeds"]["light"] == record["seeds"]["light"] and got["seeds"]["material"] > 2**53
        assert got["lighting"]["turbidity"] == record["lighting"]["turbidity"]  # float64, exact
        assert got["lighting"]["direction"] == record["lighting"]["direction"]
        assert got["lighting_vector"] == record["lighting_vector"]  # float32 values, exact
        assert got["material"]["kind"] == record["material"]["kind"]
        assert got["material"]["family"] == record["material"].get("family")  # a typed null for uniform ones
        files = {f["role"]: f["sha256"] for f in record["files"]}
        assert renders["exr_sha256"][renders["keys"].index(record["id"])] == files["render"]
    assert renders["image_size"] == [64, 64] and renders["image_mode"] == "RGB"


def test_the_materials_config_has_a_row_per_material_joined_by_key(smoke, pub, seen):
    materials = seen["materials"]
    records = manifest(smoke)
    first = {r["material_id"]: r for r in records if r["light_index"] == 0}
    assert materials["rows"] == 8 and materials["keys"] == list(first)
    assert materials["columns"] == ["__key__", "maps.png", "maps.exr", "texture.exr", "json", "__url__"]
    assert "'svbrdf_family': Value('string')" in materials["features"]["json"]
    assert "'seed_material': Value('int64')" in materials["features"]["json"]
    table = {r["material_id"]: r for r in rows(pub)}
    for key, got in zip(materials["keys"], materials["json"]):
        assert got == {k: table[key][k] for k in got}  # the samples table's material columns, typed
        assert got["seed_material"] == first[key]["seeds"]["material"]
    kinds = [j["material_kind"] for j in materials["json"]]
    assert "uniform" in kinds and "svbrdf" in kinds  # so nulls occur on both sides
    assert materials["image_size"] == [4 * 64, 64]
    for key, digest in zip(materials["keys"], materials["exr_sha256"]):
        assert digest == next(f["sha256"] for f in first[key]["files"] if f["role"] == "maps")


def test_previews_loaded_are_the_checksummed_members(pub, seen):
    table = rows(pub)
    assert seen["renders"]["png_sha256"] == [r["render_preview_sha256"] for r in table]
    by_material = {r["material_id"]: r["maps_preview_sha256"] for r in table}
    assert seen["materials"]["png_sha256"] == [by_material[k] for k in seen["materials"]["keys"]]


@pytest.mark.parametrize("config, rel, layer", [("renders", "render", "render"), ("materials", "maps", "diffuse")])
def test_the_cards_two_lines_decode_a_rows_exr_as_the_dataset_holds_it(smoke, seen, config, rel, layer):
    got = seen[config]
    key = got["last_key"]
    record = next(r for r in manifest(smoke) if r["id"] == key or (r["material_id"] == key))
    path = next(f["path"] for f in record["files"] if f["role"] == rel)
    expected = read_exr((smoke / path).read_bytes()).layers
    shape, dtype, values = got["decoded"][layer]
    assert shape == list(expected[layer].shape) and dtype == str(expected[layer].dtype)
    assert np.array_equal(np.asarray(values).reshape(shape), expected[layer].astype(np.float64))
    if config == "materials":
        shape, dtype, values = got["decoded"]["mask.Y"]
        assert np.array_equal(np.asarray(values).reshape(shape), expected["mask"][..., 0].astype(np.float64))


def test_load_dataset_webdataset_on_each_kind_of_tar(seen):
    renders, materials = seen["plain_renders"], seen["plain_materials"]
    assert renders[0] == 16 and renders[1] == ["__key__", "__url__", "json", "render.exr", "render.png"]
    assert materials[0] == 8 and materials[1] == ["__key__", "__url__", "json", "maps.exr", "maps.png", "texture.exr"]
    assert renders[2].startswith("Image(") and materials[2].startswith("Image(")


# --------------------------------------------------------------------------- previews


def test_previews_are_a_pure_function_of_the_exr_files(smoke, pub):
    from PIL import Image

    table = rows(pub)
    tars = {}
    for row in table:
        tars.setdefault(row["shard"], dict(members(pub / row["shard"])))
        tars.setdefault(row["material_shard"], dict(members(pub / row["material_shard"])))
    for row in table[:4] + table[-2:]:
        render = (smoke / f"shards/{row['source_shard']}/{row['render']}").read_bytes()
        maps = (smoke / f"shards/{row['source_shard']}/{row['maps']}").read_bytes()
        png = tars[row["shard"]][row["render_preview"]]
        assert png == render_preview(render, maps, 64) and sha(png) == row["render_preview_sha256"]
        strip = tars[row["material_shard"]][row["maps_preview"]]
        assert strip == maps_preview(maps, 64) and sha(strip) == row["maps_preview_sha256"]
        with Image.open(io.BytesIO(png)) as image:
            assert image.size == (64, 64) and image.mode == "RGB"
            pixels = np.asarray(image)
        assert 0 < pixels.mean() < 255 and pixels.std() > 1  # a picture, not a flat tile
        with Image.open(io.BytesIO(strip)) as image:
            assert image.size == (4 * 64, 64)


def test_png_encoder_round_trips_through_pillow_and_shrinks_large_renders():
    from PIL import Image

    rng = np.random.default_rng(25)
    picture = rng.integers(0, 256, size=(37, 53, 3), dtype=np.uint8)
    with Image.open(io.BytesIO(encode_png(picture))) as image:
        assert np.array_equal(np.asarray(image.convert("RGB")), picture)
    hdr = np.ones((400, 400, 3), np.float32)
    from pipeline.store.exr import encode_exr

    data = encode_exr({"render": hdr}, {})
    with Image.open(io.BytesIO(render_preview(data, None, 400))) as image:
        assert image.size == (200, 200) and max(image.size) <= PREVIEW_SIDE


def test_a_forged_preview_is_refused(pub, tmp_path):
    forged = tmp_path / "pub"
    shutil.copytree(pub, forged)
    table = rows(forged)
    tar = forged / table[0]["shard"]
    name = table[0]["render_preview"]
    items = members(tar)
    rewrite_tar(tar, [(n, d[:-20] + bytes(20) if n == name else d) for n, d in items])  # changed, re-sealed
    reseal(forged)
    with pytest.raises(Refused) as caught:
        verify(VerifyRequest(str(forged)))
    assert caught.value.kind == "member_checksum" and name in str(caught.value)
    # a consistent forgery: the table names the new bytes, which are no PNG
    payload = b"#!/bin/sh\nrm -rf /\n"
    rewrite_tar(tar, [(n, payload if n == name else d) for n, d in items])
    table[0]["render_preview_sha256"], table[0]["render_preview_bytes"] = sha(payload), len(payload)
    from pipeline.store.records import dumps

    (forged / "samples.jsonl").write_text("".join(dumps(r) + "\n" for r in table))
    reseal(forged)
    with pytest.raises(Refused) as caught:
        verify(VerifyRequest(str(forged)))
    assert caught.value.kind == "preview" and f"member '{name}': not a PNG" in str(caught.value)


def forged_preview(pub: Path, tmp_path: Path, column: str, make) -> tuple[Path, str]:
    """A copy of ``pub`` whose first ``column`` preview (render_preview, maps_preview) is
    ``make(its bytes)``, consistently: the table names the new bytes, every checksum resealed."""
    from pipeline.publish.table import material_member, material_row
    from pipeline.store.records import dumps

    forged = tmp_path / f"pub-{column}"
    shutil.copytree(pub, forged)
    table = rows(forged)
    shard = "shard" if column == "render_preview" else "material_shard"
    tar, name = forged / table[0][shard], table[0][column]
    items = members(tar)
    payload = make(dict(items)[name])
    for row in table:
        if row[column] == name and row[shard] == table[0][shard]:
            row[f"{column}_sha256"], row[f"{column}_bytes"] = sha(payload), len(payload)
    changed = {name: payload}
    if column == "maps_preview":  # the material's row member repeats its preview's checksum
        changed[material_member(table[0]["material_id"])] = (dumps(material_row(table[0])) + "\n").encode()
    rewrite_tar(tar, [(n, changed.get(n, d)) for n, d in items])
    (forged / "samples.jsonl").write_text("".join(dumps(r) + "\n" for r in table))
    reseal(forged)
    return forged, name


def _gif(png: bytes) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    with Image.open(io.BytesIO(png)) as image:
        image.convert("RGB").save(out, format="GIF")
    return out.getvalue()


def _bad_crc(png: bytes) -> bytes:
    at = len(png) - 16  # the last IDAT's CRC: the 4 bytes before IEND's 12
    return png[:at] + bytes([png[at] ^ 0xFF]) + png[at + 1 :]


FORGED_PREVIEWS = {
    "truncated halfway": (lambda png: png[: len(png) // 2], "not a whole PNG"),
    "cut before IEND": (lambda png: png[:-12], "not a whole PNG"),
    "a chunk's CRC broken": (_bad_crc, "not a whole PNG"),
    "a GIF of the preview's size": (_gif, "not a PNG"),
    "a PNG of another size": (lambda png: encode_png(np.zeros((256, 256, 3), np.uint8)), "the preview is"),
    "a PNG bomb of 8000 x 8000": (lambda png: png_bomb(8000, 8000, "RGB"), "the preview is"),
}


@pytest.mark.parametrize("column", ["render_preview", "maps_preview"])
@pytest.mark.parametrize("case", sorted(FORGED_PREVIEWS))
def test_verify_decodes_previews_within_their_size_and_refuses_a_broken_one(pub, tmp_path, case, column):
    make, words = FORGED_PREVIEWS[case]
    forged, name = forged_preview(pub, tmp_path, column, make)
    with pytest.raises(Refused) as caught:
        verify(VerifyRequest(str(forged)))
    assert caught.value.kind == "preview", caught.value
    assert f"member '{name}': " in str(caught.value) and words in str(caught.value), str(caught.value)
    assert len(str(caught.value)) < 400


# --------------------------------------------------------------------------- Croissant's floats


def test_croissant_float_error_is_pandas_fast_parser(pub):
    """mlcroissant reads samples.jsonl with ``pandas.read_json(lines=True)``: its default fast
    float parser (``precise_float=False``) is what differs; with ``precise_float=True`` pandas
    reads every float exactly. The bound the tests allow is the one measured here."""
    import pandas as pd

    sys.path.insert(0, str(REPO / "scripts"))
    try:
        from croissant_floats import measure
    finally:
        sys.path.remove(str(REPO / "scripts"))
    measured = measure(str(pub))
    assert measured["records"] == 16 and measured["float_cells"] == 176
    assert 0 < measured["max_relative_difference"] < 1e-12  # tests/test_publish.py: CROISSANT_REL
    table = rows(pub)
    for precise, exact in ((True, True), (False, False)):
        frame = pd.read_json(pub / "samples.jsonl", lines=True, precise_float=precise)
        same = all(
            frame[column][i] == value
            for i, row in enumerate(table)
            for column, value in row.items()
            if isinstance(value, float)
        )
        assert same is exact


def test_publishing_twice_gives_identical_previews_and_card(smoke, pub, tmp_path):
    again = tmp_path / "again"
    publish(PublishRequest(str(smoke), str(again), shard_bytes=SHARD_BYTES))
    assert files_of(again) == files_of(pub)
    assert (
        hashlib.sha256((pub / "README.md").read_bytes()).digest()
        == hashlib.sha256((again / "README.md").read_bytes()).digest()
    )
