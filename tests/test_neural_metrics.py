"""Evaluation metrics against reference implementations on known images."""

import math

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from pipeline.image.metrics import hdr_flip, psnr8, relmse, ssim8


def _pair(seed=0, shape=(48, 41, 3), noise=25):
    rng = np.random.default_rng(seed)
    ref = rng.integers(0, 256, shape).astype(np.uint8)
    test = np.clip(ref.astype(int) + rng.integers(-noise, noise + 1, shape), 0, 255).astype(np.uint8)
    return test, ref


def _ssim_direct(a, b):
    """Wang et al.'s ssim_index.m: filter2(window, img, 'valid') with an 11x11 Gaussian, sigma 1.5."""
    x = np.arange(-5, 6)
    g = np.exp(-(x[:, None] ** 2 + x[None, :] ** 2) / (2 * 1.5**2))
    g /= g.sum()
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    out = []
    for c in range(a.shape[2]):
        p, q = a[..., c].astype(float), b[..., c].astype(float)
        h, w = p.shape

        def valid(img, h=h, w=w):
            return np.array([[np.sum(g * img[i : i + 11, j : j + 11]) for j in range(w - 10)] for i in range(h - 10)])

        mp, mq = valid(p), valid(q)
        vp, vq, cpq = valid(p * p) - mp**2, valid(q * q) - mq**2, valid(p * q) - mp * mq
        out.append(np.mean(((2 * mp * mq + c1) * (2 * cpq + c2)) / ((mp**2 + mq**2 + c1) * (vp + vq + c2))))
    return float(np.mean(out))


def test_ssim_matches_scikit_image_standard_arguments():
    for seed in range(3):
        test, ref = _pair(seed)
        expected = structural_similarity(
            test, ref, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255, channel_axis=-1
        )
        assert ssim8(test, ref) == pytest.approx(expected, abs=1e-12)


def test_ssim_matches_the_direct_valid_window_formula():
    test, ref = _pair(5, shape=(24, 20, 3))
    assert ssim8(test, ref) == pytest.approx(_ssim_direct(test, ref), abs=1e-10)


def test_ssim_of_identical_images_is_one_and_falls_with_noise():
    _, ref = _pair()
    assert ssim8(ref, ref) == pytest.approx(1.0)
    assert ssim8(*_pair(noise=5)) > ssim8(*_pair(noise=40)) > 0


def test_psnr_matches_scikit_image_and_a_hand_value():
    test, ref = _pair(1)
    assert psnr8(test, ref) == pytest.approx(peak_signal_noise_ratio(ref, test, data_range=255), abs=1e-12)
    ref = np.full((8, 8, 3), 100, np.uint8)
    assert psnr8(ref + 1, ref) == pytest.approx(20 * math.log10(255), abs=1e-12)  # MSE 1
    assert psnr8(ref, ref) == math.inf


def test_ldr_metrics_refuse_float_images():
    with pytest.raises(TypeError, match="8-bit"):
        psnr8(np.zeros((4, 4, 3)), np.zeros((4, 4, 3), np.uint8))


def test_relmse_known_value():
    ref = np.array([0.0, 1.0, 10.0])
    test = np.array([0.1, 1.1, 10.0])
    expected = (0.01 / 0.01 + 0.01 / 1.01 + 0.0) / 3
    assert relmse(test, ref) == pytest.approx(expected)


def test_hdr_flip_is_zero_for_equal_images_and_grows_with_error():
    rng = np.random.default_rng(0)
    ref = (rng.random((32, 32, 3)) * 4).astype(np.float32)
    assert hdr_flip(ref, ref) == pytest.approx(0.0, abs=1e-6)
    small, large = hdr_flip(ref * 1.05, ref), hdr_flip(ref * 2.0, ref)
    assert 0 < small < large
