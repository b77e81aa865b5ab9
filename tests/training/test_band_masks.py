"""Radial field bands of the image (per-band metrics of the wide-field experiment)."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.training.metrics import band_masks, masked_psnr, psnr


def test_bands_partition_the_image_and_follow_the_radius():
    H, W = 30, 50
    m = band_masks((H, W), [0.0, 0.25, 0.5, 1.0])
    assert m.shape == (3, H, W) and m.dtype == torch.bool
    assert torch.equal(m.sum(0), torch.ones(H, W, dtype=m.sum(0).dtype))  # one band per pixel
    assert m[0, H // 2, W // 2] and m[0, H // 2 - 1, W // 2 - 1]      # the centre: band 0
    for i, j in ((0, 0), (0, W - 1), (H - 1, 0), (H - 1, W - 1)):    # corners: the last band
        assert m[2, i, j]
    # symmetric under both flips (the optical axis is the image centre)
    assert torch.equal(m, m.flip(-1)) and torch.equal(m, m.flip(-2))


def test_band_areas_are_annuli_of_the_half_diagonal():
    """``rho = r / r_corner``: the inner disc rho < 0.5 covers pi (0.5 r_c)^2 of the image."""
    H = W = 200
    m = band_masks((H, W), [0.0, 0.5, 1.0])
    rc = 0.5 * math.hypot(H, W)
    expected = math.pi * (0.5 * rc) ** 2 / (H * W)
    assert float(m[0].float().mean()) == pytest.approx(expected, rel=5e-3)
    assert float(m[1].float().mean()) == pytest.approx(1 - expected, rel=5e-3)
    # bands that do not start at 0 leave the centre out
    ring = band_masks((H, W), [0.33, 0.66])
    assert not ring[0, H // 2, W // 2] and ring[0].any()


def test_masked_psnr_on_the_full_mask_is_psnr():
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(2, 3, 16, 16, generator=g), torch.rand(2, 3, 16, 16, generator=g)
    full = band_masks((16, 16), [0.0, 1.0])[0]
    assert full.all()
    assert float(masked_psnr(a, b, full)) == pytest.approx(float(psnr(a, b)), rel=1e-6)
