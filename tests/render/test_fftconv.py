"""``correlate_valid`` (the PSF renderer's convolution by FFT) against ``F.conv2d``."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from deeplens.render.fftconv import correlate_valid


def test_equals_conv2d_with_gradients():
    """Values and both gradients equal ``F.conv2d``'s (float64, non-square, asymmetric)."""
    g = torch.Generator().manual_seed(0)
    x = torch.rand(3, 1, 20, 23, generator=g, dtype=torch.float64, requires_grad=True)
    k = torch.rand(4, 1, 5, 7, generator=g, dtype=torch.float64, requires_grad=True)
    w = torch.rand(3, 4, 16, 17, generator=g, dtype=torch.float64)
    a = correlate_valid(x, k)
    b = F.conv2d(x, k)
    assert a.shape == b.shape
    assert torch.allclose(a, b, rtol=0, atol=1e-12)
    ga = torch.autograd.grad((a * w).sum(), (x, k))
    gb = torch.autograd.grad((b * w).sum(), (x, k))
    for u, v in zip(ga, gb):
        assert torch.allclose(u, v, rtol=0, atol=1e-11)


def test_float32_rounding_is_small():
    """float32 at the EDOF diffraction kernel's size (K = 85 on a 64-pixel frame)."""
    g = torch.Generator().manual_seed(1)
    x = torch.rand(2, 1, 148, 148, generator=g)
    k = torch.rand(3, 1, 85, 85, generator=g)
    k = k / k.sum((-1, -2), keepdim=True)
    ref = F.conv2d(x.double(), k.double())
    assert float((correlate_valid(x, k).double() - ref).abs().max() / ref.abs().max()) < 2e-5


def test_refuses_bad_shapes():
    with pytest.raises(ValueError, match=r"\(B, 1, H, W\)"):
        correlate_valid(torch.zeros(1, 2, 8, 8), torch.zeros(1, 1, 3, 3))
    with pytest.raises(ValueError, match="larger than the image"):
        correlate_valid(torch.zeros(1, 1, 4, 4), torch.zeros(1, 1, 5, 5))
