"""PSNR / SSIM: protocol details (clamp, 8-bit rounding, cap) and an independent SSIM check."""
import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from gsz.evaluation.metrics import (PSNR_CAP_DB, gaussian_window_1d, mse, psnr, quantize_8bit, ssim,
                                    ssim_map, to_uint8)


def _ssim_scipy(a, b):
    """Independent reference: the 3DGS SSIM formula on scipy's gaussian_filter.

    mode='constant' = zero padding like F.conv2d(padding=5); truncate chosen so the radius is 5
    (an 11-tap window); sigma 1.5; mean over every pixel and channel.
    """
    def filt(x):
        return gaussian_filter(x, sigma=1.5, mode="constant", cval=0.0, truncate=5.0 / 1.5)

    vals = []
    for ch in range(a.shape[2]):
        x, y = a[..., ch].astype(np.float64), b[..., ch].astype(np.float64)
        mx, my = filt(x), filt(y)
        vx, vy, cxy = filt(x * x) - mx * mx, filt(y * y) - my * my, filt(x * y) - mx * my
        c1, c2 = 0.01 ** 2, 0.03 ** 2
        vals.append(((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2)))
    return float(np.mean(vals))


def _photo_like(seed, h=72, w=96):
    """A smooth image with edges (not white noise): blurred blocks plus a gradient."""
    rng = np.random.default_rng(seed)
    img = np.kron(rng.random((-(-h // 8), -(-w // 8), 3)), np.ones((8, 8, 1)))[:h, :w]
    img = gaussian_filter(img, sigma=(1.0, 1.0, 0))
    img += np.linspace(0, 0.2, w)[None, :, None]
    return np.clip(img, 0, 1)


def test_psnr_known_values():
    a = np.zeros((10, 20, 3))
    b = np.full((10, 20, 3), 0.1)
    assert psnr(a, b) == pytest.approx(20.0)           # MSE 0.01 -> 20 dB
    assert psnr(a, b, max_val=2.0) == pytest.approx(20.0 + 20 * math.log10(2))
    b[0, 0, 0] = 0.5                                     # one pixel off, rest identical
    c = np.zeros_like(a)
    c[0, 0, 0] = 0.5
    assert psnr(a, c) == pytest.approx(10 * math.log10(600 / 0.25))


def test_psnr_identical_is_cap_and_monotone():
    a = _photo_like(0)
    assert psnr(a, a) == PSNR_CAP_DB == 100.0
    assert psnr(a, a, cap=60.0) == 60.0
    rng = np.random.default_rng(1)
    noise = rng.standard_normal(a.shape)
    vals = [psnr(a, a + s * noise) for s in (0.005, 0.02, 0.08)]
    assert vals[0] > vals[1] > vals[2] and all(math.isfinite(v) for v in vals)
    # Tiny (but nonzero) differences never exceed the cap.
    assert psnr(a, a + 1e-9) == PSNR_CAP_DB


def test_clamping_and_8bit_rounding():
    a = np.full((4, 4, 3), 0.5)
    over = a.copy()
    over[0, 0] = [1.7, -0.3, np.nan]   # unclamped render values / a broken pixel
    ref = a.copy()
    ref[0, 0] = [1.0, 0.0, 0.0]
    assert mse(over, ref) == 0.0       # clamped to [0,1], NaN -> 0
    q = quantize_8bit(np.array([[[0.0, 0.5, 1.2]]]))
    assert np.allclose(q, [[[0, 128 / 255, 1]]])
    assert to_uint8(np.array([[[0.0, 0.5, 1.2]]])).tolist() == [[[0, 128, 255]]]
    # On 8-bit content, differences below half a level vanish under the protocol's rounding;
    # a full level does not.
    x = quantize_8bit(_photo_like(3))
    assert psnr(x, x + 0.0015) < PSNR_CAP_DB
    assert psnr(quantize_8bit(x), quantize_8bit(x + 0.0015)) == PSNR_CAP_DB
    assert psnr(quantize_8bit(x), quantize_8bit(np.clip(x + 1 / 255, 0, 1))) < 60


def test_ssim_matches_independent_scipy_implementation():
    a = _photo_like(4)
    rng = np.random.default_rng(5)
    for sigma in (0.01, 0.05, 0.2):
        b = np.clip(a + sigma * rng.standard_normal(a.shape), 0, 1)
        assert ssim(a, b) == pytest.approx(_ssim_scipy(a, b), abs=1e-10)
    # Non-square, odd sizes and a blur (structure change rather than noise).
    a = _photo_like(6, h=41, w=67)
    b = gaussian_filter(a, sigma=(2, 2, 0))
    assert ssim(a, b) == pytest.approx(_ssim_scipy(a, b), abs=1e-10)


def test_ssim_properties():
    a = _photo_like(7)
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    rng = np.random.default_rng(8)
    noise = rng.standard_normal(a.shape)
    vals = [ssim(a, np.clip(a + s * noise, 0, 1)) for s in (0.01, 0.05, 0.2)]
    assert 1.0 > vals[0] > vals[1] > vals[2] > 0.0
    b = np.clip(a + 0.05 * noise, 0, 1)
    assert ssim(a, b) == pytest.approx(ssim(b, a), abs=1e-12)     # symmetric
    assert ssim_map(a, b).shape == a.shape
    g = gaussian_window_1d()
    assert g.shape == (11,) and g.sum() == pytest.approx(1.0) and np.argmax(g) == 5


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="shapes differ"):
        psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(ValueError, match="H, W, 3"):
        ssim(np.zeros((4,)), np.zeros((4,)))
