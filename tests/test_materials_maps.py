"""Materials without Mitsuba: map containers, normal encodings, samplers, the Deschaintre importer."""

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

import materials
from materials import (
    SVBRDF_FAMILIES,
    MaterialMaps,
    UniformMaterial,
    UniformRanges,
    decode_normal_map,
    encode_normal_map,
    load_deschaintre,
    normals_from_height,
    sample_svbrdf,
    sample_uniform,
)
from materials.colorspace import srgb_decode
from materials.errors import MaterialError


def test_package_imports_without_mitsuba():
    code = "import sys, materials; sys.exit(1 if any(m.startswith(('mitsuba', 'drjit')) for m in sys.modules) else 0)"
    assert subprocess.run([sys.executable, "-c", code], cwd=materials.__path__[0] + "/..").returncode == 0


# ---- MaterialMaps / UniformMaterial --------------------------------------------------------


def _uniform_example():
    return UniformMaterial(diffuse=(0.5, 0.25, 0.1), specular=(0.04,) * 3, roughness=0.3, normal=(0.0, 0.6, 0.8))


def test_uniform_material_round_trip():
    u = _uniform_example()
    maps = u.to_maps((4, 6))
    assert maps.resolution == (4, 6)
    assert maps.diffuse.dtype == np.float32 and maps.diffuse.shape == (4, 6, 3)
    assert maps.roughness.shape == (4, 6)
    assert maps.is_uniform()
    back = maps.uniform_values()
    assert back is not None
    np.testing.assert_allclose(back.diffuse, u.diffuse, rtol=1e-6)
    np.testing.assert_allclose(back.normal, u.normal, rtol=1e-6)
    assert maps.check() is maps


def test_maps_are_read_only_copies():
    source = np.zeros((2, 2, 3), np.float32)
    normal = np.zeros((2, 2, 3), np.float32)
    normal[..., 2] = 1
    maps = MaterialMaps(diffuse=source, specular=source, roughness=np.zeros((2, 2)), normal=normal)
    source[0, 0, 0] = 1.0
    assert maps.diffuse[0, 0, 0] == 0.0
    with pytest.raises(ValueError):
        maps.diffuse[0, 0, 0] = 1.0
    assert maps.is_uniform()
    varied = MaterialMaps(diffuse=source, specular=maps.specular, roughness=maps.roughness, normal=normal)
    assert not varied.is_uniform() and varied.uniform_values() is None


@pytest.mark.parametrize(
    "name, index, value, message",
    [
        ("diffuse", (1, 0, 2), np.nan, "diffuse"),
        ("specular", (0, 1, 0), 1.5, "specular"),
        ("roughness", (1, 1), -0.1, "roughness"),
        ("normal", (0, 0, 2), -1.0, "normal"),
        ("normal", (1, 1, 0), 0.5, "normal"),
    ],
)
def test_check_names_map_and_value(name, index, value, message):
    maps = _uniform_example().to_maps(2)
    arrays = {k: np.array(getattr(maps, k)) for k in ("diffuse", "specular", "roughness", "normal")}
    arrays[name][index] = value
    with pytest.raises(MaterialError, match=message) as info:
        MaterialMaps(**arrays).check()
    assert str(index[:2])[:-1] in str(info.value)


def test_shape_errors_name_the_map():
    ok = _uniform_example().to_maps(3)
    with pytest.raises(MaterialError, match="roughness"):
        MaterialMaps(diffuse=ok.diffuse, specular=ok.specular, roughness=ok.diffuse, normal=ok.normal)
    with pytest.raises(MaterialError, match="resolution"):
        MaterialMaps(diffuse=ok.diffuse, specular=ok.specular, roughness=np.zeros((2, 3)), normal=ok.normal)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(diffuse=(1.2, 0, 0)), "diffuse"),
        (dict(roughness=2.0), "roughness"),
        (dict(normal=(0, 0, -1)), "normal"),
        (dict(normal=(0, 0, 0)), "normal"),
    ],
)
def test_uniform_material_rejects_bad_values(kwargs, field):
    args = dict(diffuse=(0.5,) * 3, specular=(0.04,) * 3, roughness=0.5)
    args.update(kwargs)
    with pytest.raises(MaterialError, match=field):
        UniformMaterial(**args)


# ---- normals ---------------------------------------------------------------------------------


def test_normal_encoding_round_trip_and_repairs():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(50, 3))
    n[:, 2] = np.abs(n[:, 2]) + 0.1
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    encoded = encode_normal_map(n)
    assert encoded.min() >= 0 and encoded.max() <= 1
    decoded, repaired = decode_normal_map(encoded)
    np.testing.assert_allclose(decoded, n, atol=1e-6)
    assert repaired == 0
    bad = np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.0], [1.0, 0.5, 0.5]])  # zero, facing away, tangent
    fixed, repaired = decode_normal_map(bad)
    assert repaired == 3
    np.testing.assert_allclose(np.linalg.norm(fixed, axis=1), 1, atol=1e-6)
    assert np.all(fixed[:, 2] > 0)
    np.testing.assert_allclose(fixed[0], [0, 0, 1])


def test_normals_from_height_orientation_and_scale():
    size = 64
    u = (np.arange(size) + 0.5) / size
    ramp_right = np.tile(np.sin(2 * np.pi * u)[None, :], (size, 1))  # rises towards +u near u = 0
    n = normals_from_height(ramp_right, depth=0.01)
    # Slope at u ~ 0: d/du (0.01 sin(2 pi u)) = 0.0628 -> normal tilts towards -x.
    np.testing.assert_allclose(n[10, 0, 0], -0.0628 / np.sqrt(1 + 0.0628**2), rtol=5e-3)
    assert abs(n[10, 0, 1]) < 1e-9
    # Height rising up the picture (towards row 0) tilts the normal towards -y.
    rises_up = np.tile(np.sin(2 * np.pi * u)[::-1, None], (1, size))
    n_up = normals_from_height(rises_up, depth=0.01)
    assert n_up[size - 1, 5, 1] < -0.05 and abs(n_up[size - 1, 5, 0]) < 1e-9
    # Resolution independent: same surface at twice the resolution, same normal.
    u2 = (np.arange(2 * size) + 0.5) / (2 * size)
    n2 = normals_from_height(np.tile(np.sin(2 * np.pi * u2)[None, :], (2 * size, 1)), depth=0.01)
    np.testing.assert_allclose(n2[0, 0, 0], n[0, 0, 0], rtol=0.02)


# ---- uniform sampler -----------------------------------------------------------------------


def test_uniform_sampler_reproducible_and_in_range():
    a = [sample_uniform(np.random.default_rng(s)) for s in range(300)]
    b = [sample_uniform(np.random.default_rng(s)) for s in range(300)]
    assert [m.as_dict() for m in a] == [m.as_dict() for m in b]
    assert a[0].to_maps(8).tobytes() == b[0].to_maps(8).tobytes()
    assert len({m.roughness for m in a}) == 300
    ranges = UniformRanges()
    d = np.array([m.diffuse for m in a])
    s = np.array([m.specular for m in a])
    r = np.array([m.roughness for m in a])
    n = np.array([m.normal for m in a])
    assert np.all(d + s <= 1.0 + 1e-6)
    assert np.all((r >= ranges.roughness[0]) & (r <= ranges.roughness[1]))
    tilt = np.degrees(np.arccos(np.clip(n[:, 2], -1, 1)))
    assert tilt.max() <= ranges.normal_tilt_max_deg + 1e-3
    flat = np.mean(n[:, 2] == 1.0)
    assert 0.4 < flat < 0.6
    metal = np.mean(s.max(axis=1) > 0.15)  # dielectrics have s <= 0.08
    assert 0.2 < metal < 0.4
    # roughness spread over its range: every tenth of [0.05, 1] is hit
    assert len(np.unique(np.floor((r - 0.05) / 0.095))) == 10
    for m in a[:20]:
        m.to_maps(2).check()


def test_uniform_ranges_check_names_field():
    with pytest.raises(MaterialError, match=r"UniformRanges.roughness: \[0.5, 0.2\] is not allowed; a pair"):
        UniformRanges(roughness=(0.5, 0.2))
    with pytest.raises(MaterialError, match="metal_probability: 1.5 is not allowed; a finite number from 0 to 1"):
        UniformRanges(metal_probability=1.5)
    with pytest.raises(MaterialError, match="normal_tilt_max_deg"):
        UniformRanges(normal_tilt_max_deg=90.0)
    ranges = UniformRanges(roughness=(0.3, 0.3), metal_probability=1.0, flat_normal_probability=1.0)
    m = sample_uniform(np.random.default_rng(1), ranges)
    assert m.roughness == pytest.approx(0.3) and m.normal == (0.0, 0.0, 1.0) and min(m.specular) > 0.2


def test_samplers_require_a_generator():
    with pytest.raises(MaterialError, match="Generator"):
        sample_uniform(np.random.RandomState(0))
    with pytest.raises(MaterialError, match="Generator"):
        sample_svbrdf(0, "tiles", 32)


# ---- procedural SVBRDFs ----------------------------------------------------------------------


@pytest.mark.parametrize("family", SVBRDF_FAMILIES)
def test_svbrdf_family_valid_reproducible_tileable(family):
    a = sample_svbrdf(np.random.default_rng(11), family, (48, 64))
    b = sample_svbrdf(np.random.default_rng(11), family, (48, 64))
    c = sample_svbrdf(np.random.default_rng(12), family, (48, 64))
    assert a.resolution == (48, 64)
    a.check()
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()
    assert not a.is_uniform()
    assert np.all(a.diffuse + a.specular <= 1.0 + 1e-6)
    # Tileable: the wrap-around seam is a step like those inside the map (a grout line or a
    # stone edge may fall on it, so compare with the largest interior step, with slack).
    for m in (a.diffuse, a.roughness, a.normal):
        assert _seam_ratio(m) < 1.5


def _seam_ratio(m):
    m = m.reshape(m.shape[0], m.shape[1], -1)
    cols = np.abs(np.diff(m, axis=1)).mean(axis=(0, 2))
    rows = np.abs(np.diff(m, axis=0)).mean(axis=(1, 2))
    seam_u = np.abs(m[:, 0] - m[:, -1]).mean()
    seam_v = np.abs(m[0] - m[-1]).mean()
    return max(seam_u / max(cols.max(), 1e-12), seam_v / max(rows.max(), 1e-12))


def test_a_non_tileable_map_fails_the_seam_check():
    # Guard for the test above: a ramp has a seam far above its interior steps.
    ramp = np.tile(np.linspace(0, 1, 64)[None, :], (64, 1))
    assert _seam_ratio(ramp) > 10
    rng = np.random.default_rng(0)
    blobs = np.cumsum(np.cumsum(rng.normal(size=(64, 64)), axis=0), axis=1)  # smooth, not periodic
    assert _seam_ratio(blobs) > 1.5


def test_svbrdf_families_have_their_character():
    def stats(family, seed):
        m = sample_svbrdf(np.random.default_rng(seed), family, 96)
        return m

    for seed in range(3):
        metal = stats("brushed_metal", seed)
        assert metal.specular.mean() > 0.2 and metal.diffuse.mean() < 0.05
        tiles = stats("tiles", seed)
        glossy = np.median(tiles.roughness)
        assert glossy < 0.45 and np.percentile(tiles.roughness, 99) > glossy + 0.2  # glossy tiles, rough grout
        bricks = stats("bricks", seed)
        assert np.median(bricks.roughness) > 0.5
        hue_red = bricks.diffuse[..., 0].mean() > bricks.diffuse[..., 2].mean()
        assert hue_red
        paint = stats("worn_paint", seed)
        exposed = np.mean(np.abs(paint.specular[..., 0] - 0.04) > 0.01) + np.mean(paint.roughness > 0.74)
        assert 0.0 < exposed
        stones = stats("stones", seed)
        assert stones.normal[..., 2].min() < 0.95  # domed stones
        stains = stats("stains", seed)
        assert stains.specular.max() < 0.1 and np.ptp(stains.diffuse.mean(axis=-1)) > 0.1


def test_svbrdf_rejects_bad_arguments():
    with pytest.raises(MaterialError, match="family: 'wood' is not one of stains"):
        sample_svbrdf(np.random.default_rng(0), "wood", 32)
    with pytest.raises(MaterialError, match="resolution"):
        sample_svbrdf(np.random.default_rng(0), "tiles", 4)


# ---- Deschaintre importer ----------------------------------------------------------------------


def _panels(size=8, seed=0):
    rng = np.random.default_rng(seed)
    photo = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
    n = rng.normal(size=(size, size, 3))
    n[..., 2] = np.abs(n[..., 2]) + 0.5
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    normal = np.round((n + 1) / 2 * 255).astype(np.uint8)
    diffuse = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
    rough = np.repeat(rng.integers(0, 256, (size, size, 1), dtype=np.uint8), 3, axis=-1)
    spec = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
    return photo, normal, diffuse, rough, spec


def test_load_strip_raw_default(tmp_path):
    photo, normal, diffuse, rough, spec = _panels()
    path = tmp_path / "0001;material.png"
    Image.fromarray(np.concatenate([photo, normal, diffuse, rough, spec], axis=1)).save(path)
    maps = load_deschaintre(path)
    assert maps.resolution == (8, 8)
    np.testing.assert_allclose(maps.diffuse, diffuse / 255.0, atol=1e-7)
    np.testing.assert_allclose(maps.specular, spec / 255.0, atol=1e-7)
    np.testing.assert_allclose(maps.roughness, rough[..., 0] / 255.0, atol=1e-7)
    expected_n = normal / 255.0 * 2 - 1
    expected_n /= np.linalg.norm(expected_n, axis=-1, keepdims=True)
    np.testing.assert_allclose(maps.normal, expected_n, atol=1e-6)
    maps.check()


def test_load_strip_srgb_per_map(tmp_path):
    photo, normal, diffuse, rough, spec = _panels(seed=3)
    path = tmp_path / "strip.png"
    Image.fromarray(np.concatenate([photo, normal, diffuse, rough, spec], axis=1)).save(path)
    albedo_srgb = load_deschaintre(path, colorspace="srgb")
    np.testing.assert_allclose(albedo_srgb.diffuse, srgb_decode(diffuse / 255.0), atol=1e-6)
    np.testing.assert_allclose(albedo_srgb.specular, srgb_decode(spec / 255.0), atol=1e-6)
    np.testing.assert_allclose(albedo_srgb.roughness, rough[..., 0] / 255.0, atol=1e-7)
    only_diffuse = load_deschaintre(path, colorspace={"diffuse": "srgb"})
    np.testing.assert_allclose(only_diffuse.specular, spec / 255.0, atol=1e-7)
    rough_srgb = load_deschaintre(path, colorspace={"roughness": "srgb"})
    np.testing.assert_allclose(rough_srgb.roughness, srgb_decode(rough[..., 0] / 255.0), atol=1e-6)
    # the 8-bit value 128 decodes to 0.2158 in sRGB, stays 0.502 raw
    assert srgb_decode(128 / 255.0) == pytest.approx(0.2158605, rel=1e-5)


def test_load_folder_of_maps(tmp_path):
    photo, normal, diffuse, rough, spec = _panels(size=6, seed=5)
    for name, image in dict(normal=normal, diffuse=diffuse, specular=spec).items():
        Image.fromarray(image).save(tmp_path / f"0042_{name}.png")
    Image.fromarray(rough[..., 0]).save(tmp_path / "roughness.png")  # single-channel grey
    Image.fromarray(photo).save(tmp_path / "photo.jpg")  # ignored
    maps = load_deschaintre(tmp_path)
    np.testing.assert_allclose(maps.diffuse, diffuse / 255.0, atol=1e-7)
    np.testing.assert_allclose(maps.roughness, rough[..., 0] / 255.0, atol=1e-7)
    strip = tmp_path / "strip.png"
    Image.fromarray(np.concatenate([photo, normal, diffuse, rough, spec], axis=1)).save(strip)
    assert load_deschaintre(strip).tobytes() == maps.tobytes()


def test_load_16_bit_grey_roughness(tmp_path):
    photo, normal, diffuse, rough, spec = _panels(size=4, seed=8)
    for name, image in dict(normal=normal, diffuse=diffuse, specular=spec).items():
        Image.fromarray(image).save(tmp_path / f"{name}.png")
    values = np.array([[0, 1000, 40000, 65535]] * 4, dtype=np.uint16)
    Image.fromarray(values).save(tmp_path / "roughness.png")
    maps = load_deschaintre(tmp_path)
    np.testing.assert_allclose(maps.roughness, values / 65535.0, atol=1e-7)


def test_importer_errors(tmp_path):
    bad = tmp_path / "bad.png"
    Image.fromarray(np.zeros((8, 42, 3), np.uint8)).save(bad)
    with pytest.raises(MaterialError, match="width 42 is not a multiple of 5"):
        load_deschaintre(bad)
    with pytest.raises(MaterialError, match="colorspace: 'linear' is not one of raw, srgb"):
        load_deschaintre(bad, colorspace="linear")
    with pytest.raises(MaterialError, match="colorspace.normal"):
        load_deschaintre(bad, colorspace={"normal": "srgb"})
    with pytest.raises(MaterialError, match="map 'albedo'"):
        load_deschaintre(bad, colorspace={"albedo": "srgb"})
    folder = tmp_path / "maps"
    folder.mkdir()
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(folder / "diffuse.png")
    with pytest.raises(MaterialError, match="no specular map"):
        load_deschaintre(folder)
    with pytest.raises(MaterialError, match="neither a file nor a directory"):
        load_deschaintre(tmp_path / "missing.png")
