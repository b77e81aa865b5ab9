"""Image metrics against known values: PSNR of a known MSE, SSIM against scikit-image's
independent implementation, radial band masks, and masked metrics on a full mask."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from deeplens.training.metrics import band_masks, masked_psnr, masked_ssim, psnr, ssim

skimage_metrics = pytest.importorskip("skimage.metrics")


def pair(seed: int = 0, shape=(2, 3, 48, 40)):
    """A fixed image and a blurred, noisy, darkened copy of it (values in [0, 1])."""
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=g, dtype=torch.float64)
    x = torch.nn.functional.avg_pool2d(x, 3, stride=1, padding=1)  # some structure
    y = 0.8 * torch.nn.functional.avg_pool2d(x, 5, stride=1, padding=2) + 0.05
    y = (y + 0.05 * torch.randn(shape, generator=g, dtype=torch.float64)).clamp(0, 1)
    return x, y


# ---------------------------------------------------------------- PSNR
def test_psnr_of_a_known_mse():
    t = torch.full((1, 3, 16, 16), 0.5, dtype=torch.float64)
    assert float(psnr(t + 0.1, t)) == pytest.approx(20.0, abs=1e-9)  # MSE 0.01
    assert float(psnr(t - 0.01, t)) == pytest.approx(40.0, abs=1e-9)  # MSE 1e-4
    # half the pixels off by 0.2, half exact: MSE 0.02
    p = t.clone()
    p[..., :8, :] += 0.2
    assert float(psnr(p, t)) == pytest.approx(10 * math.log10(1 / 0.02), abs=1e-9)


def test_psnr_averages_the_per_image_values_of_a_batch():
    t = torch.full((2, 1, 8, 8), 0.5, dtype=torch.float64)
    p = t.clone()
    p[0] += 0.1  # 20 dB
    p[1] += 0.01  # 40 dB
    assert float(psnr(p, t)) == pytest.approx(30.0, abs=1e-9)  # not 10 log10(1 / mean MSE)


def test_psnr_clamps_the_prediction_to_the_valid_range():
    t = torch.full((1, 1, 8, 8), 0.9, dtype=torch.float64)
    assert float(psnr(t + 0.5, t)) == pytest.approx(20.0, abs=1e-9)  # 1.4 -> 1.0: error 0.1


# ---------------------------------------------------------------- SSIM
def test_ssim_of_an_image_with_itself_is_one():
    x, _ = pair()
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-8)
    assert float(masked_ssim(x, x, torch.ones(x.shape[-2:], dtype=torch.bool))) == \
        pytest.approx(1.0, abs=1e-8)


def skimage_ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """scikit-image's SSIM map (Gaussian window sigma 1.5, 11 taps, population covariance,
    data range 1: Wang et al. 2004) of two 2-D images."""
    _, smap = skimage_metrics.structural_similarity(
        a, b, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
        full=True)
    return smap


def test_ssim_matches_scikit_image():
    x, y = pair()
    H, W = x.shape[-2:]
    r = 5  # window radius: skimage's mean drops r pixels on every side
    inner = torch.zeros(H, W, dtype=torch.bool)
    inner[r:H - r, r:W - r] = True
    # skimage's own mean SSIM (border cropped), averaged over images and channels
    ref_inner = np.mean([skimage_metrics.structural_similarity(
        x[b, c].numpy(), y[b, c].numpy(), data_range=1.0, gaussian_weights=True, sigma=1.5,
        use_sample_covariance=False) for b in range(x.shape[0]) for c in range(x.shape[1])])
    assert 0.2 < ref_inner < 0.9  # a pair with something to measure
    assert float(masked_ssim(y, x, inner)) == pytest.approx(ref_inner, abs=1e-6)
    # the full map: kornia pads by reflection without repeating the edge (numpy's 'reflect');
    # skimage's map of the so-padded images, cropped back, is the reference for every pixel
    full = []
    for b in range(x.shape[0]):
        for c in range(x.shape[1]):
            a = np.pad(y[b, c].numpy(), r, mode="reflect")
            t = np.pad(x[b, c].numpy(), r, mode="reflect")
            full.append(skimage_ssim_map(a, t)[r:-r, r:-r].mean())
    assert float(ssim(y, x)) == pytest.approx(float(np.mean(full)), abs=1e-6)


# ---------------------------------------------------------------- bands and masks
@pytest.mark.parametrize("shape", [(16, 16), (15, 22), (1, 9)])
def test_band_masks_partition_the_pixels(shape):
    edges = [0.0, 0.3, 0.6, 1.0]
    m = band_masks(shape, edges)
    assert m.shape == (3, *shape) and m.dtype == torch.bool
    assert torch.equal(m.sum(0), torch.ones(shape, dtype=m.sum(0).dtype))  # each pixel once
    # the band of each pixel is the one its normalised radius falls in (computed here)
    H, W = shape
    y = torch.arange(H, dtype=torch.float64) + 0.5 - H / 2
    x = torch.arange(W, dtype=torch.float64) + 0.5 - W / 2
    rho = torch.sqrt(y[:, None] ** 2 + x[None] ** 2) / math.hypot(H / 2, W / 2)
    expect = torch.bucketize(rho, torch.tensor(edges[1:-1], dtype=torch.float64), right=True)
    assert torch.equal(m.to(torch.int64).argmax(0), expect)


def test_band_masks_centre_and_corners():
    m = band_masks((20, 20), [0.0, 0.5, 1.0])
    assert bool(m[0, 9:11, 9:11].all()) and bool(m[1, 0, 0]) and bool(m[1, -1, -1])
    assert not bool(m[0, 0, 0])


def test_masked_metrics_equal_the_unmasked_ones_on_a_full_mask():
    x, y = pair(seed=1)
    full = torch.ones(x.shape[-2:], dtype=torch.bool)
    assert float(masked_psnr(y, x, full)) == pytest.approx(float(psnr(y, x)), rel=1e-12)
    assert float(masked_ssim(y, x, full)) == pytest.approx(float(ssim(y, x)), rel=1e-12)
    # and on a half mask, the PSNR of exactly those pixels
    half = torch.zeros_like(full)
    half[: x.shape[-2] // 2] = True
    top = slice(0, x.shape[-2] // 2)
    assert float(masked_psnr(y, x, half)) == pytest.approx(
        float(psnr(y[..., top, :], x[..., top, :])), rel=1e-12)
