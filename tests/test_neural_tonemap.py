"""The one HDR <-> [0, 1] tone map of the neural stage."""

import numpy as np
import pytest

from pipeline.image.tonemap import (
    DEFAULT_EXPOSURE,
    hdr_to_srgb8,
    inverse_tonemap,
    srgb_decode,
    srgb_encode,
    to_srgb8,
    tonemap,
)


def test_known_values():
    # exposure 4: 0.25 -> 1 -> reinhard 0.5 -> sRGB 0.7354
    assert DEFAULT_EXPOSURE == 4.0
    assert tonemap(np.array([0.25]))[0] == pytest.approx(1.055 * 0.5 ** (1 / 2.4) - 0.055, abs=1e-7)
    assert tonemap(np.array([0.0]))[0] == 0.0
    assert tonemap(np.array([1e30]))[0] == pytest.approx(1.0)
    assert tonemap(np.array([0.25]), exposure=1.0)[0] == pytest.approx(srgb_encode(np.array(0.2)), abs=1e-7)


def test_round_trip_over_the_renders_range():
    x = np.concatenate([np.geomspace(1e-5, 2e4, 2000), [0.0]]).astype(np.float32)
    back = inverse_tonemap(tonemap(x))
    rel = np.abs(back - x) / np.maximum(x, 1e-3)
    # float32 y has steps of 6e-8 near 1, where a highlight of 2e4 lies 1.2e-5 below 1
    assert rel[x <= 100].max() < 2e-4  # the curve is computed in float32
    assert rel.max() < 3e-2
    assert np.all(np.diff(tonemap(np.sort(x))) >= 0)  # monotonic


def test_srgb_curve_is_inverted():
    y = np.linspace(0, 1, 1001)
    assert np.allclose(srgb_encode(srgb_decode(y)), y, atol=1e-12)


def test_negative_nan_count_as_zero_and_one_stays_finite():
    y = tonemap(np.array([-3.0, np.nan, np.inf]))
    assert list(y[:2]) == [0.0, 0.0] and y[2] == pytest.approx(1.0, abs=1e-6)
    assert np.isfinite(inverse_tonemap(np.array([1.0])))
    assert inverse_tonemap(np.array([1.0]))[0] == pytest.approx(1e6 / DEFAULT_EXPOSURE, rel=1e-3)


def test_eight_bit_rounds_half_up_and_clamps():
    assert list(to_srgb8(np.array([0.0, 0.5 / 255, 1.0, 1.5, -1.0]))) == [0, 1, 255, 255, 0]
    assert hdr_to_srgb8(np.array([[[0.25, 0.0, 1e9]]])).tolist() == [[[188, 0, 255]]]


def test_both_tone_maps_share_one_curve_and_overflow_to_white():
    from pipeline.image.tonemap import preview_srgb8, reinhard

    v = np.array([0.0, 1.0, 3.0, np.inf], np.float32)
    assert reinhard(v).tolist() == [0.0, 0.5, 0.75, 1.0] and reinhard(v).dtype == np.float32
    # a pixel whose exposed value overflows float32 is white, not an undefined cast of NaN
    image = np.full((2, 2, 3), 3e38, np.float32)
    assert preview_srgb8(image, exposure=4.0).tolist() == np.full((2, 2, 3), 255).tolist()
    assert tonemap(image).max() == pytest.approx(1.0)
