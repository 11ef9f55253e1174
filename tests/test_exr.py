"""EXR storage: layer naming, round trips, half/float choice, determinism, atomicity."""

import os

import numpy as np
import pytest

from pipeline.errors import ShaderballError
from pipeline.store.atomic import sha256_file, write_bytes_atomic
from pipeline.store.exr import REC709_CHROMATICITIES, encode_exr, read_exr, write_exr


def _layers(rng):
    return {
        "render": rng.random((6, 7, 3), dtype=np.float32) * 3e4,
        "roughness": rng.random((6, 7), dtype=np.float32),
        "normal": rng.standard_normal((6, 7, 3)).astype(np.float32),
    }


def test_round_trip_names_and_values(tmp_path):
    rng = np.random.default_rng(1)
    layers = _layers(rng)
    path = tmp_path / "a.exr"
    digest = write_exr(str(path), layers, {"id": "m0001"}, half=("roughness",))
    assert digest == sha256_file(str(path))
    image = read_exr(str(path))
    assert set(image.layers) == {"render", "roughness", "normal"}
    np.testing.assert_array_equal(image.layers["render"], layers["render"])
    assert image.layers["render"].dtype == np.float32
    assert image.layers["roughness"].dtype == np.float16
    np.testing.assert_allclose(image.layers["roughness"][..., 0], layers["roughness"], atol=5e-4)
    assert image.meta == {"id": "m0001"}
    np.testing.assert_allclose(image.chromaticities, REC709_CHROMATICITIES, atol=1e-6)

    import OpenEXR

    names = set(OpenEXR.File(str(path), separate_channels=True).channels())
    assert names == {"render.R", "render.G", "render.B", "roughness.Y", "normal.X", "normal.Y", "normal.Z"}


def test_float32_keeps_values_that_overflow_half():
    big = np.full((2, 2, 3), 7.0e4, np.float32)
    image = read_exr(encode_exr({"render": big}))
    assert np.all(np.isfinite(image.layers["render"]))
    assert image.layers["render"].max() == pytest.approx(7.0e4)


def test_same_pixels_same_bytes():
    rng = np.random.default_rng(2)
    layers = _layers(rng)
    assert encode_exr(layers, {"a": 1, "b": 2}) == encode_exr(dict(layers), {"b": 2, "a": 1})


def test_corrupt_file_is_a_clear_error(tmp_path):
    path = tmp_path / "bad.exr"
    data = encode_exr(_layers(np.random.default_rng(3)))
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ShaderballError, match="bad.exr"):
        read_exr(str(path))


def test_unknown_compression_is_a_bug_not_a_user_error():
    """The spec's storage.compression refuses it first (its field rule); here it is a caller's bug."""
    with pytest.raises(ValueError, match="compression 'lzma'"):
        encode_exr({"mask": np.zeros((2, 2))}, compression="lzma")


def test_atomic_write_leaves_no_temp_files(tmp_path):
    target = tmp_path / "sub" / "f.bin"
    write_bytes_atomic(str(target), b"one")
    write_bytes_atomic(str(target), b"two")
    assert target.read_bytes() == b"two"
    assert os.listdir(target.parent) == ["f.bin"]


def test_atomic_write_has_ordinary_permissions(tmp_path):
    mask = os.umask(0o022)
    os.umask(mask)
    target = tmp_path / "perm.bin"
    write_bytes_atomic(str(target), b"x")
    assert (target.stat().st_mode & 0o777) == (0o666 & ~mask)
