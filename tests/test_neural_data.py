"""The dataset folder as torch samples: exact values, one read per material's maps,
checked hashes, paths kept inside the dataset, refused folders and resolutions."""

import json
import os
import shutil

import numpy as np
import pytest
import torch

from pipeline.errors import ShaderballError
from pipeline.fields import FieldError
from pipeline.image.tonemap import tonemap
from pipeline.neural.data import box_downsample, open_dataset
from pipeline.store.exr import read_exr

torch.set_num_threads(1)


def _records(root):
    return [json.loads(line) for line in open(os.path.join(root, "manifest.jsonl"))]


def _file(root, record, role):
    return os.path.join(root, next(f["path"] for f in record["files"] if f["role"] == role))


def test_samples_hold_exactly_the_exr_and_manifest_values(reference):
    ds = open_dataset(str(reference))
    records = _records(reference)
    assert len(ds) == len(records) and ds.resolution == records[0]["render"]["resolution"]
    for index in (0, 5):
        item, record = ds[index], records[index]
        maps = read_exr(_file(reference, record, "maps")).layers
        render = read_exr(_file(reference, record, "render")).layers["render"]
        mask = maps["mask"][..., 0]
        assert item["id"] == record["id"] and item["material_id"] == record["material_id"]
        assert item["light"].tolist() == pytest.approx(record["lighting_vector"], abs=0)
        x = item["maps"].numpy()
        assert np.array_equal(x[0:3], maps["diffuse"].astype(np.float32).transpose(2, 0, 1))
        assert np.array_equal(x[3:6], maps["specular"].astype(np.float32).transpose(2, 0, 1))
        normal_colour = (maps["normal"].astype(np.float32) + 1) / 2 * (mask > 0.5)[..., None]
        assert np.allclose(x[6:9], normal_colour.transpose(2, 0, 1), atol=1e-7)
        for c in (9, 10, 11):
            assert np.array_equal(x[c], maps["roughness"][..., 0].astype(np.float32))
        assert np.array_equal(item["mask"].numpy()[0], mask)
        assert np.array_equal(item["target"].numpy(), tonemap(render).transpose(2, 0, 1))
        assert float(x.min()) >= 0 and float(x.max()) <= 1


def test_a_materials_maps_are_read_once_for_all_its_lightings(reference):
    ds = open_dataset(str(reference))
    for i in range(len(ds)):
        ds[i]
    assert ds.maps_reads == len(ds.material_ids) < len(ds)


def test_a_lower_network_resolution_box_averages(reference):
    full, half = open_dataset(str(reference)), open_dataset(str(reference), resolution=32)
    record = _records(reference)[3]
    render = read_exr(_file(reference, record, "render")).layers["render"]
    assert half[3]["maps"].shape == (12, 32, 32)
    assert np.allclose(
        half[3]["maps"].numpy(), full[3]["maps"].numpy().reshape(12, 32, 2, 32, 2).mean((2, 4)), atol=1e-6
    )
    assert np.array_equal(half[3]["target"].numpy(), tonemap(box_downsample(render, 2)).transpose(2, 0, 1))


@pytest.mark.parametrize("resolution,allowed", [(48, "multiple of 16"), (128, "divides the dataset")])
def test_wrong_resolutions_are_refused(reference, resolution, allowed):
    with pytest.raises(ShaderballError, match=f"^resolution: {resolution}.*{allowed}"):
        open_dataset(str(reference), resolution=resolution)


@pytest.fixture
def copy(reference, tmp_path):
    dest = tmp_path / "data"
    shutil.copytree(reference, dest)
    return dest


def _rewrite_manifest(root, edit):
    records = _records(root)
    edit(records)
    (root / "manifest.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def test_a_file_not_matching_its_hash_is_refused_on_first_read(copy):
    path = _file(copy, _records(copy)[0], "render")
    data = bytearray(open(path, "rb").read())
    data[-10] ^= 0xFF
    open(path, "wb").write(bytes(data))
    with pytest.raises(ShaderballError, match="render.exr does not match its SHA-256"):
        open_dataset(str(copy))[0]
    ds = open_dataset(str(copy), check_hashes=False)
    assert ds[1]["id"] == _records(copy)[1]["id"]  # other files read fine


@pytest.mark.parametrize("bad", ["../outside.exr", "/etc/passwd", "shards/../../x.exr", "shards\\s0\\x.exr"])
def test_paths_leaving_the_dataset_are_refused(copy, bad):
    _rewrite_manifest(copy, lambda rs: rs[0]["files"][0].update(path=bad))
    with pytest.raises(ShaderballError, match="file path .*(leaves the folder|is absolute)"):
        open_dataset(str(copy))


def test_a_symbolic_link_out_of_the_dataset_is_refused(copy, tmp_path):
    outside = tmp_path / "outside.exr"
    outside.write_bytes(b"x")
    rel = _records(copy)[0]["files"][0]["path"]
    os.unlink(copy / rel)
    os.symlink(outside, copy / rel)
    with pytest.raises(ShaderballError, match="is refused: .* is a symbolic link .*not followed"):
        open_dataset(str(copy))


def test_missing_and_incomplete_datasets_are_named(copy, tmp_path):
    with pytest.raises(FieldError, match="^dataset: .*nothere.* does not exist"):  # the field, by its name
        open_dataset(str(tmp_path / "nothere"))
    lines = (copy / "manifest.jsonl").read_text().splitlines(keepends=True)
    (copy / "manifest.jsonl").write_text("".join(lines[:-3]))
    with pytest.raises(ShaderballError, match=f"incomplete: the manifest lists {len(lines) - 3} of {len(lines)}"):
        open_dataset(str(copy))
    os.unlink(copy / "manifest.jsonl")
    with pytest.raises(ShaderballError, match="incomplete: no manifest.jsonl"):
        open_dataset(str(copy))


@pytest.mark.slow
def test_worker_processes_give_the_same_batches(reference):
    from torch.utils.data import DataLoader

    ds = open_dataset(str(reference))
    one = [b["target"] for b in DataLoader(ds, batch_size=4, num_workers=0)]
    two = [b["target"] for b in DataLoader(ds, batch_size=4, num_workers=2)]
    assert all(torch.equal(a, b) for a, b in zip(one, two)) and len(one) == len(two)
