"""The one gate before any EXR or outside image is decoded (pipeline.store.exrheader,
materials.imagefile): what a header may say, given what is expected of the file. Fast: real
files, written by OpenEXR or by tests/support/bombs.py, never decoded when refused."""

from __future__ import annotations

import io

import numpy as np
import pytest

from materials.errors import MaterialError
from materials.imagefile import read_image
from pipeline.errors import ShaderballError
from pipeline.publish.exrcheck import member_bounds
from pipeline.store.exr import encode_exr, layer_bounds, read_exr
from pipeline.store.exrheader import DEFAULT_BOUNDS, ExrBounds, ExrRefused, check_header
from support.bombs import exr_bomb, png_bomb

RENDER_64 = layer_bounds(64, ("render",))


def _render(side: int) -> bytes:
    return encode_exr({"render": np.ones((side, side, 3), np.float32)})


def test_a_render_of_the_expected_size_passes_and_decodes():
    header = check_header(_render(64), "r", RENDER_64)
    assert (header.width, header.height, header.decoded_bytes) == (64, 64, 64 * 64 * 3 * 4)
    assert read_exr(_render(64), "r", RENDER_64).layers["render"].shape == (64, 64, 3)


def test_a_file_decoding_to_more_than_twice_the_expected_image_is_refused_from_its_header():
    bomb = exr_bomb(1024, 1024, {"render": ("R", "G", "B")})  # 12.6 MB decoded, 30 kB on disk
    with pytest.raises(ExrRefused) as caught:
        check_header(bomb, "m.render.exr", RENDER_64)
    assert caught.value.reason == (
        "EXR header says 1024 x 1024 pixels of 3 channel(s): 12.6 MB decoded; at most 1.05 MB are "
        "decoded for a file expected to hold 64 x 64 pixels of 3 channel(s)"
    )
    big = layer_bounds(1024, ("render",))
    assert big.decoded_bytes == 2 * 1024 * 1024 * 12 and check_header(bomb, "m", big).width == 1024
    with pytest.raises(ShaderballError, match=r"^cannot decode EXR m.render.exr: EXR header says 1024 x 1024"):
        read_exr(bomb, "m.render.exr", RENDER_64)


def test_nothing_expected_leaves_the_budget():
    assert DEFAULT_BOUNDS.decoded_bytes == 256 << 20
    small_budget = ExrBounds(budget_bytes=1 << 20)
    with pytest.raises(ExrRefused, match="at most 1.05 MB are decoded$"):
        check_header(exr_bomb(512, 512, {"render": ("R", "G", "B")}), "x", small_budget)


def test_exact_bounds_refuse_another_size_even_when_smaller():
    exact = layer_bounds(64, ("render",), exact=True)
    with pytest.raises(ExrRefused) as caught:
        check_header(_render(32), "r", exact)
    assert caught.value.reason == (
        "EXR header says its data window is 32 x 32 pixels; expected 64 x 64 (the spec's resolution)"
    )
    assert check_header(_render(32), "r", RENDER_64).width == 32  # validate decodes it and says why


def test_tiled_and_multi_part_files_are_refused():
    import OpenEXR

    pixels = {"render": np.zeros((32, 32, 3), np.float32)}
    tiles = OpenEXR.TileDescription()
    tiles.xSize = tiles.ySize = 16
    tiled, parts = io.BytesIO(), io.BytesIO()
    OpenEXR.File({"type": OpenEXR.tiledimage, "tiles": tiles}, pixels).write(tiled)
    two = [OpenEXR.Part({"type": OpenEXR.scanlineimage}, pixels, name=n) for n in ("a", "b")]
    OpenEXR.File(two).write(parts)
    for data in (tiled.getvalue(), parts.getvalue()):
        with pytest.raises(ExrRefused, match="only single-part scanline files"):
            check_header(data, "t", DEFAULT_BOUNDS)


def test_more_than_64_channels_or_a_window_past_the_side_cap_are_refused():
    with pytest.raises(ExrRefused, match="more than 64 channels"):
        check_header(exr_bomb(16, 16, {"c": tuple(str(i) for i in range(65))}), "c", DEFAULT_BOUNDS)
    with pytest.raises(ExrRefused, match="data window is 8192 x 16 pixels; at most 4096 x 4096"):
        check_header(exr_bomb(8192, 16, {"render": ("R", "G", "B")}), "w", DEFAULT_BOUNDS)


def test_a_publication_bounds_its_members_by_its_spec():
    from pathlib import Path

    spec = (Path(__file__).resolve().parents[1] / "manifests" / "smoke.toml").read_bytes()
    bounds = member_bounds(spec)
    assert bounds["render"].shape == (64, 64) and bounds["render"].channels == 3
    assert bounds["maps"].channels == 11 + 4 and bounds["texture"].shape == (64, 64)  # maps + geometry layers
    imported = member_bounds(spec.replace(b"svbrdf_folders = []", b'svbrdf_folders = ["/x"]'))
    assert imported["texture"].shape is None and imported["render"].shape == (64, 64)
    for broken in (b"\xff\xfe", b"[render]\nresolution = 1e9\n", b"[" * 5000):
        assert {b.shape for b in member_bounds(broken).values()} == {None}


def test_an_image_over_its_size_is_refused_from_its_header():
    with pytest.raises(MaterialError) as caught:
        read_image(png_bomb(3000, 100), "big.png", 2048, 2048)
    assert str(caught.value) == (
        "big.png: the image is 3000 x 100 pixels; at most 2048 x 2048 are read (its header was read, no pixel decoded)"
    )
    pixels, full_scale = read_image(png_bomb(20, 10, "RGB"), "ok.png", 2048, 2048)
    assert pixels.shape == (10, 20, 3) and pixels.dtype == np.uint8 and full_scale == 255.0
    with pytest.raises(MaterialError, match="refused by Pillow's pixel limit"):
        read_image(png_bomb(7000, 7000), "huge.png", 100_000, 100_000)  # 49 M pixels: over Pillow's limit
    with pytest.raises(MaterialError, match="cut.png: cannot read image"):
        read_image(png_bomb(64, 64)[:50], "cut.png", 2048, 2048)
