"""sky.environment: the record of an environment light, its conventions, file listing, rotations."""

import hashlib
import json
import math

import numpy as np
import pytest

from sky import SkyError
from sky.directions import sun_angles
from sky.environment import (
    ENVIRONMENT_SUFFIXES,
    ROTATION_RANGE,
    SCALE_RANGE,
    EnvironmentLight,
    list_environment_files,
    map_azimuth_deg,
    map_direction,
    sample_rotations,
)

DIGEST = hashlib.sha256(b"a map").hexdigest()


def _light(**changes):
    values = {"file": "/maps/studio.hdr", "digest": DIGEST, "rotation_deg": 30.0, "scale": 2.0} | changes
    return EnvironmentLight(**values)


def test_the_record_is_json_with_the_base_name_and_digest():
    record = _light().to_dict()
    assert record == {
        "source": "environment",
        "file": "studio.hdr",
        "sha256": DIGEST,
        "rotation_deg": 30.0,
        "scale": 2.0,
    }
    assert json.loads(json.dumps(record)) == record
    assert EnvironmentLight("/m/x.exr", DIGEST, 0.0).scale == 1.0


@pytest.mark.parametrize(
    "field, value, words",
    [
        ("rotation_deg", -1.0, "environment.rotation_deg: -1.0 is not allowed; a finite number from 0 to 360"),
        ("rotation_deg", math.nan, "environment.rotation_deg: nan"),
        ("rotation_deg", "90", "environment.rotation_deg"),
        ("scale", 0.0, "environment.scale: 0.0 is not allowed; a finite number from 0.0001 to 10000"),
        ("scale", math.inf, "environment.scale: inf"),
        ("scale", True, "environment.scale: true"),
        ("digest", "abc", "environment.sha256"),
        ("digest", DIGEST.upper(), "environment.sha256"),
        ("file", "maps/studio.hdr", "environment.file"),
        ("file", "/maps/studio.png", "environment.file"),
    ],
)
def test_bad_values_are_refused_naming_the_field(field, value, words):
    with pytest.raises(SkyError) as info:
        _light(**{field: value})
    assert words in str(info.value)


def test_the_ranges_are_declared_once_and_hold_their_ends():
    assert ROTATION_RANGE == (0.0, 360.0) and SCALE_RANGE == (1e-4, 1e4)
    for rotation in ROTATION_RANGE:
        for scale in SCALE_RANGE:
            assert _light(rotation_deg=rotation, scale=scale).scale == scale


def test_the_lighting_vector_is_the_maps_centre_direction_and_its_stops():
    vector = _light(rotation_deg=0.0, scale=1.0).lighting_vector()
    assert vector.dtype == np.float32 and vector.shape == (4,)
    np.testing.assert_allclose(vector, [0.0, 1.0, 0.0, 0.0], atol=1e-7)  # in front of the camera
    turned = _light(rotation_deg=90.0, scale=8.0).lighting_vector()
    np.testing.assert_allclose(turned, [-1.0, 0.0, 0.0, 3.0], atol=1e-6)  # +y turned 90 deg ccw: -x
    assert _light(scale=0.25).lighting_vector()[3] == pytest.approx(-2.0)
    for r in np.linspace(0.0, 360.0, 13):
        v = _light(rotation_deg=float(r)).lighting_vector()
        assert np.linalg.norm(v[:3]) == pytest.approx(1.0, abs=1e-6) and v[2] == 0.0


def test_the_centre_column_looks_ahead_and_u_grows_to_the_viewers_right():
    # camera on -y looking along +y: the map's centre is ahead (azimuth 90), its right (+x) is u > 0.5
    assert map_azimuth_deg(0.5) == pytest.approx(90.0)
    assert map_azimuth_deg(0.75) == pytest.approx(0.0)  # +x
    assert map_azimuth_deg(0.25) == pytest.approx(180.0)  # -x
    np.testing.assert_allclose(map_direction(0.5, 0.5), [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(map_direction(0.3, 0.0), [0.0, 0.0, 1.0], atol=1e-12)  # top row: zenith
    np.testing.assert_allclose(map_direction(0.3, 1.0), [0.0, 0.0, -1.0], atol=1e-12)


@pytest.mark.parametrize("rotation", [0.0, 10.0, 90.0, 245.5, 359.0])
def test_rotating_a_map_moves_every_azimuth_by_the_rotation(rotation):
    u = np.linspace(0.0, 1.0, 37)
    for v in (0.2, 0.5, 0.8):
        before = np.array(sun_angles(map_direction(u, v)))
        after = np.array(sun_angles(map_direction(u, v, rotation)))
        np.testing.assert_allclose(after[0], before[0], atol=1e-9)  # elevation kept
        off = np.mod(after[1] - before[1] - rotation + 180.0, 360.0) - 180.0  # moved by `rotation`, mod a turn
        np.testing.assert_allclose(off, 0.0, atol=1e-9)


def test_files_are_listed_sorted_absolute_and_without_repeats(tmp_path, monkeypatch):
    maps = tmp_path / "maps"
    (maps / "deeper").mkdir(parents=True)
    for name in ("b.hdr", "a.EXR", "notes.txt", "deeper/c.hdr"):
        (maps / name).write_bytes(b"x")
    (tmp_path / "single.exr").write_bytes(b"x")
    monkeypatch.chdir(tmp_path)
    found = list_environment_files(["maps", str(maps / "b.hdr"), "single.exr"])
    assert found == (str(maps / "a.EXR"), str(maps / "b.hdr"), str(tmp_path / "single.exr"))
    assert ENVIRONMENT_SUFFIXES == (".exr", ".hdr")


def test_listing_refuses_missing_paths_wrong_suffixes_and_finding_nothing(tmp_path):
    (tmp_path / "photo.png").write_bytes(b"x")
    (tmp_path / "empty").mkdir()
    cases = [
        ([str(tmp_path / "missing.hdr")], "an existing file or folder"),
        ([str(tmp_path / "photo.png")], "a file ending in .exr or .hdr"),
        ([str(tmp_path / "empty")], "at least one .exr or .hdr map"),
        ([], "at least one"),
        (str(tmp_path), "a list of files or folders"),
    ]
    for paths, words in cases:
        with pytest.raises(SkyError, match="environment.files") as info:
            list_environment_files(paths)
        assert words in str(info.value)


def test_rotations_are_uniform_in_the_range_and_deterministic():
    a = sample_rotations(np.random.default_rng(7), 4000, (30.0, 120.0))
    b = sample_rotations(np.random.default_rng(7), 4000, [30.0, 120.0])
    assert np.array_equal(a, b) and a.dtype == np.float64
    assert a.min() >= 30.0 and a.max() < 120.0
    counts, _ = np.histogram(a, bins=9, range=(30.0, 120.0))
    assert counts.min() > 350 and counts.max() < 550  # 444 expected per bin
    assert sample_rotations(np.random.default_rng(1), 0, ROTATION_RANGE).shape == (0,)
    assert not np.array_equal(a, sample_rotations(np.random.default_rng(8), 4000, (30.0, 120.0)))


@pytest.mark.parametrize("bad", [(-10.0, 20.0), (0.0, 400.0), (90.0, 30.0), (0.0,), "0,360"])
def test_rotation_ranges_outside_one_turn_are_refused(bad):
    with pytest.raises(SkyError, match="environment.rotation_deg"):
        sample_rotations(np.random.default_rng(0), 3, bad)


def test_rotations_need_a_generator():
    with pytest.raises(TypeError, match="Generator"):
        sample_rotations(np.random.RandomState(0), 3, ROTATION_RANGE)


def test_a_folders_hidden_files_are_not_maps(tmp_path):
    from sky.environment import list_environment_files

    (tmp_path / "sky.exr").write_bytes(b"x")
    (tmp_path / "._sky.exr").write_bytes(b"x")  # macOS's resource fork beside a copied map
    assert list_environment_files([str(tmp_path)]) == (str(tmp_path / "sky.exr"),)
