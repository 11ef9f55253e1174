"""HDR environment maps: the Radiance reader's bounds, the map gate, and Mitsuba's envmap lit
as sky.environment states it (white furnace, importance sampling, rotation, scale).

Every map is made here: RGBE files by the small encoder below, EXR files by the project's
writer or OpenEXR, sunny skies by numpy."""

import math
import tracemalloc

import numpy as np
import OpenEXR
import pytest

from pipeline.render.envmap import (
    ENVIRONMENT_EXR_BOUNDS,
    EnvironmentMapError,
    clear_environment_cache,
    environment_emitter_dict,
    environment_light_dict,
    load_environment,
    read_environment,
)
from pipeline.store.exr import write_exr
from pipeline.store.exrheader import check_header
from pipeline.store.hdrfile import HdrRefused, decode_hdr, read_hdr
from sky import SkyError
from sky.directions import sun_angles, sun_direction
from sky.environment import EnvironmentLight, map_direction
from support import VARIANT
from support.exrcraft import exr, required, zeros_exr

LIMITS = {"max_pixels": 1 << 20, "max_side": 2048}


# ---- a tiny RGBE encoder (Radiance's float2rgbe and its new-style RLE) -------------------------


def rgbe_bytes(radiance: np.ndarray) -> np.ndarray:
    """(H, W, 3) float -> (H, W, 4) uint8, as Radiance's setcolr: mantissas scaled by the
    largest channel's frexp."""
    brightest = radiance.max(axis=2)
    mantissa, exponent = np.frexp(brightest)
    scale = np.where(brightest > 1e-32, mantissa * 256.0 / np.where(brightest > 0, brightest, 1.0), 0.0)
    out = np.zeros(radiance.shape[:2] + (4,), np.uint8)
    out[..., :3] = np.clip(radiance * scale[..., None], 0, 255).astype(np.uint8)
    out[..., 3] = np.where(brightest > 1e-32, exponent + 128, 0)
    return out


def rle_channel(values: np.ndarray) -> bytes:
    """One channel of one scanline: runs of 4 or more as (128 + n, byte), the rest literal."""
    out, i, n = bytearray(), 0, len(values)
    while i < n:
        run = 1
        while i + run < n and run < 127 and values[i + run] == values[i]:
            run += 1
        if run >= 4:
            out += bytes([128 + run, values[i]])
            i += run
            continue
        start = i
        while i < n and i - start < 128:
            ahead = values[i : i + 4]
            if len(ahead) == 4 and np.all(ahead == ahead[0]):
                break
            i += 1
        out += bytes([i - start]) + bytes(values[start:i])
    return bytes(out)


def hdr_file(radiance: np.ndarray, rle: bool = True, header: bytes = b"FORMAT=32-bit_rle_rgbe\n") -> bytes:
    rgbe = rgbe_bytes(radiance)
    height, width = rgbe.shape[:2]
    body = bytearray()
    for row in rgbe:
        if rle:
            body += bytes([2, 2, width >> 8, width & 0xFF])
            for channel in range(4):
                body += rle_channel(row[:, channel])
        else:
            body += row.tobytes()
    return b"#?RADIANCE\n" + header + b"\n" + f"-Y {height} +X {width}\n".encode() + bytes(body)


def sky_map(height: int = 32, seed: int = 0) -> np.ndarray:
    """A lat-long map with smooth gradients (long runs in RLE) and noise (literal runs)."""
    rng = np.random.default_rng(seed)
    v = np.linspace(0.0, 1.0, height)[:, None, None]
    image = np.broadcast_to(np.array([0.3, 0.5, 1.0]) * (1.2 - v), (height, 2 * height, 3)).copy()
    image[height // 2 :, : height // 2] *= rng.uniform(0.5, 1.5, (height - height // 2, height // 2, 3))
    image[3, 5] = [5000.0, 4000.0, 3000.0]  # a sun, far above the rest
    return image.astype(np.float32)


def _close_to_rgbe(decoded: np.ndarray, original: np.ndarray) -> None:
    """Within RGBE's precision: half a step of 1/256 of a pixel's brightest channel."""
    tolerance = original.max(axis=2, keepdims=True) / 256.0 * 1.01
    assert np.all(np.abs(decoded - original) <= tolerance)


# ---- the Radiance reader ------------------------------------------------------------------------


@pytest.mark.parametrize("rle", [True, False], ids=["rle", "flat"])
def test_hdr_round_trip(tmp_path, rle):
    image = sky_map()
    path = tmp_path / "sky.hdr"
    path.write_bytes(hdr_file(image, rle=rle))
    decoded = read_hdr(path, **LIMITS)
    assert decoded.dtype == np.float32 and decoded.shape == image.shape
    _close_to_rgbe(decoded, image)
    assert decoded[3, 5, 0] == pytest.approx(5000.0, rel=1 / 128)  # the sun keeps its radiance
    np.testing.assert_array_equal(read_environment(path), decoded)


def test_hdr_rle_files_are_smaller_and_read_the_same():
    image = sky_map()
    rle, flat = hdr_file(image, rle=True), hdr_file(image, rle=False)
    assert len(rle) < len(flat)
    np.testing.assert_array_equal(decode_hdr(rle, "a", **LIMITS), decode_hdr(flat, "b", **LIMITS))


def test_hdr_exposure_divides_the_pixels():
    image = sky_map()
    plain = decode_hdr(hdr_file(image), "x", **LIMITS)
    header = b"FORMAT=32-bit_rle_rgbe\nEXPOSURE=2\nEXPOSURE=4\n"
    np.testing.assert_allclose(decode_hdr(hdr_file(image, header=header), "x", **LIMITS), plain / 8.0, rtol=1e-6)


def _rle_line(width: int, channels: list[bytes]) -> bytes:
    return bytes([2, 2, width >> 8, width & 0xFF]) + b"".join(channels)


HEAD = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n"


@pytest.mark.parametrize(
    "data, words",
    [
        # a run of 127 in an 8-pixel line: the RLE bomb
        (
            HEAD + b"-Y 1 +X 8\n" + _rle_line(8, [bytes([255, 7])] * 4),
            "a run of 127 at pixel 0 passes the scanline's 8",
        ),
        # literal bytes past the line's end
        (
            HEAD + b"-Y 1 +X 8\n" + _rle_line(8, [bytes([6]) + bytes(6), bytes([3, 1, 2, 3])] * 2),
            "a run of 3 at pixel 6",
        ),
        (HEAD + b"-Y 1 +X 8\n" + _rle_line(8, [bytes([0, 0, 0])] * 4), "a run of length 0"),
        (HEAD + b"-Y 1 +X 8\n" + bytes([2, 2, 0, 9]) + bytes([136, 1]) * 4, "says it is 9 pixels wide"),
        (
            HEAD + b"-Y 2 +X 8\n" + _rle_line(8, [bytes([136, 1])] * 4) * 2 + b"junk",
            "4 byte(s) after the last scanline",
        ),
        (HEAD + b"-Y 1 +X 4\n" + bytes([1, 1, 1, 9]) + bytes(12), "old-style run-length codes"),
        (HEAD + b"+Y 1 +X 4\n" + bytes(16), "orientation"),
        (HEAD + b"-Y 1 -X 4\n" + bytes(16), "orientation"),
        (HEAD + b"-X 4 -Y 1\n" + bytes(16), "orientation"),
        (HEAD + b"hello\n" + bytes(16), "resolution line"),
        (b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 4\n" + bytes(16), "pixel format"),
        (b"#?RADIANCE\nEXPOSURE=-1\n\n-Y 1 +X 4\n" + bytes(16), "EXPOSURE must be"),
        (b"P6\n4 1\n255\n" + bytes(12), "not a Radiance file"),
        (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n" + b"# comment\n" * 10000, "no end of header"),
    ],
)
def test_hdr_files_outside_the_reader_are_refused(data, words):
    with pytest.raises(HdrRefused) as info:
        decode_hdr(data, "bad.hdr", **LIMITS)
    assert "bad.hdr" in str(info.value) and words in str(info.value)


@pytest.mark.parametrize("rle", [True, False], ids=["rle", "flat"])
def test_truncated_hdr_files_are_refused(rle):
    data = hdr_file(sky_map(), rle=rle)
    for cut in (len(data) - 1, len(data) - 150, len(data) // 2, 60):
        with pytest.raises(HdrRefused, match="cut short|ends inside|ends before"):
            decode_hdr(data[:cut], "cut.hdr", **LIMITS)


def test_a_huge_declared_size_is_refused_before_anything_is_allocated():
    tracemalloc.start()
    try:
        for resolution, words in [
            (b"-Y 1000000 +X 2000000", "at most 2048 per side"),
            (b"-Y 1024 +X 2048", "1048576 pixels in all"),  # each side within, the product not
            (b"-Y 1024 +X 1024", "the file is cut short"),  # within the limits, but 40 bytes of it
        ]:
            with pytest.raises(HdrRefused, match=words):
                decode_hdr(HEAD + resolution + b"\n" + bytes([2, 2, 4, 0, 255, 1]) * 4, "bomb.hdr", **LIMITS)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, f"{peak} bytes allocated to refuse a header"


# ---- the map gate: both formats ---------------------------------------------------------------


def _bare_rgb_exr(path, image: np.ndarray, half: bool = False) -> None:
    """An EXR with bare R, G, B (and A) channels, as HDRI sites publish them."""
    dtype = np.float16 if half else np.float32
    channels = {c: np.ascontiguousarray(image[..., i], dtype=dtype) for i, c in enumerate("RGB")}
    channels["A"] = np.ones(image.shape[:2], dtype)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(str(path))


@pytest.mark.parametrize("half", [False, True], ids=["float", "half"])
def test_exr_maps_with_bare_rgb_or_a_render_layer_are_read(tmp_path, half):
    image = sky_map()
    _bare_rgb_exr(tmp_path / "bare.exr", image, half=half)
    read = read_environment(tmp_path / "bare.exr")
    assert read.dtype == np.float32 and read.shape == image.shape
    np.testing.assert_allclose(read, image, rtol=1e-3 if half else 0.0)
    write_exr(str(tmp_path / "layer.exr"), {"render": image})
    np.testing.assert_array_equal(read_environment(tmp_path / "layer.exr"), image)


@pytest.mark.parametrize(
    "value, words",
    [(-0.5, "1 pixel(s) with negative"), (math.nan, "[nan, "), (math.inf, "infinite radiance")],
)
def test_negative_nan_and_infinite_radiance_are_refused_naming_the_pixel(tmp_path, value, words):
    """EXR maps only: RGBE has no sign, no NaN, and its largest exponent is finite."""
    image = sky_map()
    image[7, 11, 0] = value
    image[20, 3, 2] = value
    path = tmp_path / "bad.exr"
    write_exr(str(path), {"render": image})
    with pytest.raises(EnvironmentMapError) as info:
        read_environment(path)
    message = str(info.value)
    assert str(path) in message and "2 pixel(s)" in message and "row 7, column 11" in message
    assert words.replace("1 pixel(s)", "2 pixel(s)") in message and "finite and >= 0" in message


@pytest.mark.parametrize("suffix", [".exr", ".hdr"])
def test_maps_that_are_not_two_to_one_are_refused_before_decoding(tmp_path, suffix):
    image = np.ones((32, 48, 3), np.float32)
    path = tmp_path / f"square{suffix}"
    if suffix == ".exr":
        write_exr(str(path), {"render": image})
    else:
        path.write_bytes(hdr_file(image))
    with pytest.raises(EnvironmentMapError, match=r"48 x 32 pixels is not a lat-long .* twice its height") as info:
        read_environment(path)
    assert str(path) in str(info.value)
    # a header alone, no pixels: refused for its shape, so the shape is checked before decoding
    if suffix == ".exr":
        path.write_bytes(exr(required(4000, 3000, ("B", "G", "R")), chunks=3000 // 16 + 1))
    else:
        path.write_bytes(HEAD + b"-Y 3000 +X 4000\n")
    with pytest.raises(EnvironmentMapError, match=r"4000 x 3000 pixels is not a lat-long"):
        read_environment(path)


def test_a_4k_map_passes_and_a_map_over_the_limits_is_refused_from_its_header(tmp_path):
    names = ("B", "G", "R")
    four_k = tmp_path / "4k.exr"
    four_k.write_bytes(zeros_exr(required(4096, 2048, names), 4096, 2048, 3))
    assert read_environment(four_k).shape == (2048, 4096, 3)
    hdr_4k = tmp_path / "4k.hdr"
    hdr_4k.write_bytes(hdr_file(np.full((2048, 4096, 3), 0.25, np.float32)))
    assert float(read_environment(hdr_4k)[1000, 3000, 1]) == pytest.approx(0.25, rel=1 / 128)
    big = tmp_path / "16k.exr"
    big.write_bytes(zeros_exr(required(16384, 8192, names), 16384, 16, 3)[:4096])  # a header says enough
    with pytest.raises(EnvironmentMapError, match="16384 x 8192 pixels; at most 8192 x 8192"):
        read_environment(big)
    big_hdr = tmp_path / "16k.hdr"
    big_hdr.write_bytes(HEAD + b"-Y 8192 +X 16384\n")
    with pytest.raises(EnvironmentMapError, match="at most 8192 per side"):
        read_environment(big_hdr)
    assert check_header(four_k.read_bytes()[:4096], "4k", ENVIRONMENT_EXR_BOUNDS).width == 4096


def test_exr_maps_without_colour_channels_and_other_files_are_refused(tmp_path):
    write_exr(str(tmp_path / "maps.exr"), {"roughness": np.ones((8, 16), np.float32)})
    with pytest.raises(EnvironmentMapError, match=r"its layers are 1 \('roughness'\); R, G, B channels"):
        read_environment(tmp_path / "maps.exr")
    (tmp_path / "photo.png").write_bytes(b"\x89PNG")
    with pytest.raises(EnvironmentMapError, match="suffix '.png'; .exr or .hdr is required"):
        read_environment(tmp_path / "photo.png")
    with pytest.raises(EnvironmentMapError, match="missing.hdr"):
        read_environment(tmp_path / "missing.hdr")
    (tmp_path / "junk.exr").write_bytes(b"junk" * 10)
    with pytest.raises(EnvironmentMapError, match="junk.exr: not an EXR file"):
        read_environment(tmp_path / "junk.exr")


def test_the_cache_decodes_a_map_once_and_notices_a_changed_file(tmp_path):
    clear_environment_cache()
    path = tmp_path / "sky.hdr"
    path.write_bytes(hdr_file(sky_map(seed=1)))
    first, again = load_environment(path), load_environment(path)
    assert again is first and not first.radiance.flags.writeable
    light = EnvironmentLight(str(path), first.digest, 30.0)
    entry = environment_light_dict(light, variant=VARIANT)
    assert entry["bitmap"] is environment_light_dict(light, variant=VARIANT)["bitmap"]  # converted once
    path.write_bytes(hdr_file(sky_map(seed=2)))
    changed = load_environment(path)
    assert changed.digest != first.digest and not np.array_equal(changed.radiance, first.radiance)
    with pytest.raises(EnvironmentMapError, match="not the .* recorded when the lighting was planned"):
        environment_light_dict(light, variant=VARIANT)
    clear_environment_cache()


def test_the_emitter_dict_refuses_bad_radiance_rotation_and_scale(mi):
    good = np.ones((8, 16, 3), np.float32)
    with pytest.raises(EnvironmentMapError, match="not a lat-long"):
        environment_emitter_dict(np.ones((8, 8, 3), np.float32), 0.0, 1.0, variant=VARIANT)
    bad = good.copy()
    bad[2, 3, 1] = -1.0
    with pytest.raises(EnvironmentMapError, match="row 2, column 3"):
        environment_emitter_dict(bad, 0.0, 1.0, variant=VARIANT)
    with pytest.raises(SkyError, match="environment.rotation_deg"):
        environment_emitter_dict(good, 400.0, 1.0, variant=VARIANT)
    with pytest.raises(SkyError, match="environment.scale"):
        environment_emitter_dict(good, 0.0, 0.0, variant=VARIANT)


# ---- Mitsuba: the envmap as the conventions say -----------------------------------------------


def _eval_world(emitter, directions: np.ndarray, mi) -> np.ndarray:
    """The emitter's RGB radiance seen looking along each world direction (N, 3)."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, directions.shape[0])
    si.wi = mi.Vector3f(*(-directions.T.astype(np.float32)))
    return np.array(emitter.eval(si)).T


def _grid(step_deg: float = 0.5):
    elevation = np.arange(-89.0, 89.0 + 1e-9, step_deg)
    azimuth = np.arange(0.0, 360.0, step_deg)
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    return el.ravel(), az.ravel(), sun_direction(el, az).reshape(-1, 3)


def _angle_deg(a, b) -> float:
    return math.degrees(math.acos(float(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.parametrize("rotation", [0.0, 37.0, 90.0, 200.0, 333.0])
def test_rotating_the_map_moves_a_bright_spot_by_the_rotation(mi, rotation):
    height, row, col = 32, 10, 40
    image = np.full((height, 2 * height, 3), 0.01, np.float32)
    image[row, col] = 1000.0
    emitter = mi.load_dict(environment_emitter_dict(image, rotation, 1.0, variant=VARIANT))
    el, az, dirs = _grid()
    peak = int(np.argmax(_eval_world(emitter, dirs, mi)[:, 0]))
    # Mitsuba's envmap: column j at u = (j + 0.5) / W, row i at v = i / (H - 1)
    expected = map_direction((col + 0.5) / (2 * height), row / (height - 1), rotation)
    assert _angle_deg(dirs[peak], expected) < 0.75, (el[peak], az[peak], sun_angles(expected))
    unrotated_az = sun_angles(map_direction((col + 0.5) / (2 * height), row / (height - 1)))[1]
    moved = (az[peak] - unrotated_az - rotation + 180.0) % 360.0 - 180.0
    assert abs(moved) < 0.75


def sunny_map(height: int = 128, sun_el: float = 45.0, sun_az: float = 60.0, sun_radiance: float = 2e4):
    """A blue sky gradient over a grey ground, and a small very bright sun disc (3 degrees)."""
    v = (np.arange(height) + 0.0) / (height - 1)
    u = (np.arange(2 * height) + 0.5) / (2 * height)
    dirs = map_direction(u[None, :], v[:, None])
    elevation = np.degrees(np.arcsin(np.clip(dirs[..., 2], -1, 1)))
    sky = np.where(elevation[..., None] > 0, np.array([0.4, 0.6, 1.0]) * (1.0 - 0.5 * dirs[..., 2:3]), 0.2)
    sun = sun_direction(sun_el, sun_az)
    in_sun = np.degrees(np.arccos(np.clip(dirs @ sun, -1, 1))) < 3.0
    sky[in_sun] = sun_radiance
    return sky.astype(np.float32), sun


def _emitter_in_scene(mi, radiance, rotation=0.0, scale=1.0):
    scene = mi.load_dict(
        {
            "type": "scene",
            "light": environment_emitter_dict(radiance, rotation, scale, variant=VARIANT),
            "ball": {"type": "sphere", "radius": 1.0},
        }
    )
    return scene, scene.emitters()[0]


def _irradiance_estimates(mi, emitter, rng, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample estimates of the irradiance on an upward-facing point at the origin (normal
    +z): with the emitter's own importance sampling, and with uniform sphere sampling."""
    import drjit as dr

    it = dr.zeros(mi.Interaction3f, n)
    it.p = mi.Point3f(0.0, 0.0, 0.0)
    unit = np.minimum(rng.random((2, n)), 1.0 - 2.0**-24).astype(np.float32)  # float32 rounds some to 1.0
    sample = mi.Point2f(*unit)
    ds, weight = emitter.sample_direction(it, sample)
    importance = np.array(weight)[1] * np.maximum(np.array(ds.d)[2], 0.0)
    z = rng.uniform(-1.0, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    radial = np.sqrt(1.0 - z * z)
    dirs = np.stack([radial * np.cos(phi), radial * np.sin(phi), z], axis=1)
    uniform = 4.0 * np.pi * _eval_world(emitter, dirs, mi)[:, 1] * np.maximum(z, 0.0)
    return importance, uniform


def test_importance_sampling_beats_uniform_sampling_of_a_sunny_map(mi):
    radiance, sun = sunny_map()
    _, emitter = _emitter_in_scene(mi, radiance)
    reference_is, reference_uniform = _irradiance_estimates(mi, emitter, np.random.default_rng(1000), 1 << 21)
    reference = reference_is.mean()
    # both estimators are unbiased: the same irradiance within their noise (5 standard errors)
    standard_error = reference_uniform.std() / math.sqrt(reference_uniform.size)
    assert abs(reference_uniform.mean() - reference) < 5.0 * standard_error
    assert reference > 0.5 * sun[2] * 2e4 * 2 * np.pi * (1 - math.cos(math.radians(3.0)))  # the sun dominates
    ratios = []
    for seed in range(5):
        importance, uniform = _irradiance_estimates(mi, emitter, np.random.default_rng(seed), 1 << 16)
        var_importance = np.mean((importance - reference) ** 2)
        var_uniform = np.mean((uniform - reference) ** 2)
        ratios.append(var_importance / var_uniform)
    print(
        f"variance of importance / uniform sampling, 5 seeds of 65536 samples: {', '.join(f'{r:.3g}' for r in ratios)}"
    )
    assert max(ratios) < 0.5, ratios


def _render(mi, scene_dict: dict, spp: int, seed: int) -> np.ndarray:
    scene = mi.load_dict(scene_dict)
    return np.array(mi.render(scene, spp=spp, seed=seed))


def _ball_scene(mi, emitter: dict, integrator: dict, resolution: int = 16, spp: int = 16, reflectance=1.0) -> dict:
    T = mi.ScalarTransform4f
    return {
        "type": "scene",
        "integrator": integrator,
        "light": emitter,
        "ball": {
            "type": "sphere",
            "radius": 1.0,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": reflectance}},
        },
        "camera": {
            "type": "perspective",
            "fov": 30.0,
            "to_world": T().look_at(origin=[0.0, -5.0, 0.5], target=[0.0, 0.0, 0.0], up=[0.0, 0.0, 1.0]),
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": spp},
        },
    }


def test_white_furnace_a_white_ball_in_a_constant_map_vanishes(mi):
    """A white diffuse ball under a constant map reflects exactly the map's radiance: the
    picture is that radiance everywhere, within the noise of 64 samples a pixel."""
    level = 0.7
    constant = np.full((32, 64, 3), level, np.float32)
    path = {"type": "path", "max_depth": 64, "rr_depth": 64}
    emitter = environment_emitter_dict(constant, 123.0, 1.0, variant=VARIANT)
    image = _render(mi, _ball_scene(mi, emitter, path, spp=64), 64, 5)
    assert np.all(np.isfinite(image)) and image.min() >= 0.0
    assert image.mean() == pytest.approx(level, rel=0.01)
    assert np.abs(image - level).max() < 0.15 * level  # every pixel, ball and background alike


def test_scale_multiplies_the_render(mi):
    radiance, _ = sunny_map(64)
    direct = {"type": "direct"}
    one = _render(
        mi,
        _ball_scene(mi, environment_emitter_dict(radiance, 40.0, 1.0, variant=VARIANT), direct, reflectance=0.5),
        16,
        3,
    )
    two = _render(
        mi,
        _ball_scene(mi, environment_emitter_dict(radiance, 40.0, 2.0, variant=VARIANT), direct, reflectance=0.5),
        16,
        3,
    )
    assert one.mean() > 0.0
    np.testing.assert_allclose(two, 2.0 * one, rtol=1e-4, atol=1e-6)


def _plane_scene(mi, emitter: dict, integrator: dict, spp: int) -> dict:
    """An upward-facing white-ish square seen from above: every point sees the whole upper
    hemisphere, so every pixel is the same irradiance times albedo / pi."""
    T = mi.ScalarTransform4f
    return {
        "type": "scene",
        "integrator": integrator,
        "light": emitter,
        "floor": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
        "camera": {
            "type": "orthographic",
            "to_world": T().look_at(origin=[0.0, 0.0, 5.0], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0])
            @ T().scale([0.5, 0.5, 1.0]),
            "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": spp},
        },
    }


def test_emitter_sampling_beats_bsdf_sampling_in_a_render(mi):
    """The direct integrator with emitter samples only vs BSDF samples only, on a sunlit
    diffuse floor: squared error per pixel against a high-sample reference, over seeds."""
    radiance, _ = sunny_map(64)
    emitter = environment_emitter_dict(radiance, 0.0, 1.0, variant=VARIANT)
    reference_scene = mi.load_dict(_plane_scene(mi, emitter, {"type": "direct"}, 256))
    reference = float(np.array(mi.render(reference_scene, spp=256, seed=99))[..., 1].mean())
    errors = {}
    for name, integrator in {
        "emitter": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "bsdf": {"type": "direct", "emitter_samples": 0, "bsdf_samples": 1},
    }.items():
        scene = mi.load_dict(_plane_scene(mi, emitter, integrator, 4))
        images = np.stack([np.array(mi.render(scene, spp=4, seed=seed))[..., 1] for seed in range(8)])
        errors[name] = float(np.mean((images - reference) ** 2))
    ratio = errors["emitter"] / errors["bsdf"]
    print(f"squared error, emitter / BSDF sampling (direct, 4 spp, 8 seeds, reference {reference:.3g}): {ratio:.4g}")
    assert ratio < 0.5, errors
