"""The depth-averaged Wiener front end (deeplens.training.wiener)."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from helpers import central_fd

from deeplens.optics.io import load_lens
from deeplens.render import Sensor
from deeplens.render.psf import psf
from deeplens.training.lens_setup import cubic_phase_plate
from deeplens.training.metrics import psnr
from deeplens.training.wiener import DepthWienerFilter, depth_change


@pytest.fixture(scope="module")
def coded():
    """The EDOF lens with a 5 um cubic plate (float64) and a 24 x 24 sensor of 6.9 um."""
    lens = load_lens("data/lenses/edof_achromat.json").to(torch.float64)
    cubic_phase_plate(lens, 4, 0.005)
    return lens, Sensor((24, 24), 0.0069, channels=[[587.6]])


def _blur(x, k):
    """True convolution of ``x`` (B, 1, H, W) with ``k`` (K, K) by conv2d (an independent path
    from the filter's FFT), the scene mirrored beyond the frame."""
    K = k.shape[-1]
    xe = F.pad(x, (K // 2,) * 4, mode="reflect")
    return F.conv2d(xe, k.flip(-1, -2)[None, None])


def _otfs(lens, sensor, depths, size=32):
    """Per-depth OTFs ``(D, size, size // 2 + 1)`` of the on-axis PSF, the kernel centre
    wrapped to the origin by hand (independent of the filter's roll)."""
    Hs = []
    for d in depths:
        k = psf(lens, sensor, (0.0, 0.0), d, 587.6, n_rays=64 * 64, sampling="grid:64",
                max_kernel=size - 1)
        K = k.shape[-1]
        full = torch.zeros(size, size, dtype=k.dtype)
        for a in range(K):
            for b in range(K):
                full[(a - K // 2) % size, (b - K // 2) % size] += k[a, b]
        Hs.append(torch.fft.rfft2(full))
    return torch.stack(Hs)


def _plate_x3(alpha_mm: float):
    """A float64 EDOF lens with a cubic plate of ``alpha_mm`` and its x^3 coefficient, set to
    require gradients."""
    lens = load_lens("data/lenses/edof_achromat.json").to(torch.float64)
    cubic_phase_plate(lens, 4, alpha_mm)
    a = lens.surfaces[4].a[6]  # the x^3 coefficient
    a.requires_grad_(True)
    return lens, a


def test_one_depth_inverts_the_lens_blur(coded):
    """With one depth and a small noise ratio the filter undoes the PSF it traced (centring
    and orientation right: an unflipped or shifted kernel does not), far better than a
    regularised one."""
    lens, sensor = coded
    wf = DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=16384, nsr=1e-6,
                           learn_nsr=False)
    k = wf.psfs((48, 48))[0, 0]
    assert k.shape[-1] >= 9 and math.isclose(float(k.sum()), 1.0, rel_tol=1e-9)
    g = torch.Generator().manual_seed(0)
    x = F.avg_pool2d(torch.rand(2, 1, 48, 48, generator=g, dtype=torch.float64), 2)
    y = _blur(x, k)
    inner = (..., slice(6, -6), slice(6, -6))
    sharp = psnr(wf(y)[inner], x[inner])
    flipped = psnr(wf(_blur(x, k.flip(-1, -2)))[inner], x[inner])
    shifted = psnr(wf(torch.roll(y, 1, -1))[inner], x[inner])
    assert float(psnr(y[inner], x[inner])) < 25 < 30 < float(sharp)
    assert max(float(flipped), float(shifted)) < float(sharp) - 10


def test_moments_are_the_mean_over_depths_uniform_in_inverse_depth(coded):
    lens, sensor = coded
    wf = DepthWienerFilter(lens, sensor, [4500.0, 8000.0], depths=3, rays=4096, nsr=1e-2)
    mid = 2 / (1 / 4500 + 1 / 8000)
    assert wf.depths_mm == pytest.approx([8000.0, mid, 4500.0])
    ch, h2 = wf.otf_moments((32, 32))
    assert ch.shape == h2.shape == (1, 32, 17)
    Hs = _otfs(lens, sensor, wf.depths_mm)
    assert torch.allclose(ch[0], Hs.conj().mean(0), atol=1e-12)
    assert torch.allclose(h2[0], (Hs.abs() ** 2).mean(0), atol=1e-12)
    # |E conj H|^2 <= E |H|^2 (Jensen), strictly where the PSF changes with depth
    assert bool((ch.abs() ** 2 <= h2 + 1e-12).all())


def test_gradient_to_the_plate_matches_central_differences(coded):
    _, sensor = coded
    lens, a = _plate_x3(0.0025)
    wf = DepthWienerFilter(lens, sensor, [4500.0, 8000.0], depths=2, rays=4096, nsr=1e-2)
    g = torch.Generator().manual_seed(3)
    y = torch.rand(1, 1, 24, 24, generator=g, dtype=torch.float64)
    w = torch.randn(1, 1, 24, 24, generator=g, dtype=torch.float64)

    def loss():
        return (wf(y) * w).sum()

    (grad,) = torch.autograd.grad(loss(), a)
    # the splat is piecewise linear in the hit positions: a small step
    fd = central_fd(loss, a, 1e-6 * float(a.detach().abs()))
    assert abs(fd) > 0
    assert float(grad) == pytest.approx(fd, rel=2e-3)


def test_gradient_to_the_noise_ratio_matches_central_differences(coded):
    """The learned ``log nsr`` (float64 for a float64 lens): its gradient through the filter
    against float64 central differences, per channel of a two-channel sensor."""
    lens, _ = coded
    sensor = Sensor((24, 24), 0.0069, channels=[[486.1], [656.3]])
    wf = DepthWienerFilter(lens, sensor, [4500.0, 8000.0], depths=2, rays=1024, nsr=3e-2)
    assert wf.log_nsr.dtype == torch.float64
    g = torch.Generator().manual_seed(4)
    y = torch.rand(1, 2, 24, 24, generator=g, dtype=torch.float64)
    w = torch.randn(1, 2, 24, 24, generator=g, dtype=torch.float64)

    def loss():
        return (wf(y) * w).sum()

    (grad,) = torch.autograd.grad(loss(), wf.log_nsr)
    for c in range(2):
        fd = central_fd(loss, wf.log_nsr, 1e-4, index=c)
        assert abs(fd) > 1e-3
        assert float(grad[c]) == pytest.approx(fd, rel=1e-6)


def test_noise_ratio_is_learned_and_frozen_lens_moments_are_cached(coded):
    lens, sensor = coded
    wf = DepthWienerFilter(lens, sensor, [4500.0, 8000.0], depths=2, rays=1024, nsr=0.05)
    assert [n for n, _ in wf.named_parameters()] == ["log_nsr"]
    assert float(wf.nsr().detach()) == pytest.approx(0.05)
    y = torch.rand(1, 1, 24, 24, dtype=torch.float64)
    out = wf(y)
    (g,) = torch.autograd.grad(out.square().sum(), wf.log_nsr)
    assert float(g.abs()) > 0
    first = wf._cache[1]
    wf(y)
    assert wf._cache[1] is first  # the lens did not change: no new trace
    with torch.no_grad():
        lens.surfaces[4].a[6] += 1e-5
    wf(y)
    assert wf._cache[1] is not first  # a changed lens (parameter version) is traced again
    fixed = DepthWienerFilter(lens, sensor, [6000.0], learn_nsr=False)
    assert list(fixed.parameters()) == []


@pytest.mark.parametrize("kw, match", [({"depths": 0}, "depths"), ({"rays": 10}, "rays"),
                                        ({"nsr": 0.0}, "nsr"), ({"nsr": float("nan")}, "nsr")])
def test_bad_settings_are_refused_by_name(coded, kw, match):
    lens, sensor = coded
    with pytest.raises(ValueError, match=f"model.deconvolution.{match}"):
        DepthWienerFilter(lens, sensor, [4500.0, 8000.0], **kw)


def test_depth_change_is_the_fraction_of_otf_power_that_varies_with_depth():
    """``depth_change`` against the per-depth OTFs written out (variance over depths of each
    frequency, summed, over the mean power), 0 for one depth, and smaller for a stronger cubic
    plate (Dowski and Cathey: the cubic plate's PSF changes little with depth)."""
    sensor = Sensor((24, 24), 0.0069, channels=[[587.6]])
    R = {}
    for alpha in (0.00125, 0.005):
        lens = load_lens("data/lenses/edof_achromat.json").to(torch.float64)
        cubic_phase_plate(lens, 4, alpha)
        wf = DepthWienerFilter(lens, sensor, [4500.0, 8000.0], depths=3, rays=4096)
        R[alpha] = float(depth_change(*wf.otf_moments((32, 32))))
        Hs = _otfs(lens, sensor, wf.depths_mm)
        var = (Hs.abs() ** 2).mean(0) - Hs.mean(0).abs() ** 2
        ref = float(var.sum() / (Hs.abs() ** 2).mean(0).sum())
        assert R[alpha] == pytest.approx(ref, rel=1e-9)
        one = DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=4096)
        assert abs(float(depth_change(*one.otf_moments((32, 32))))) < 1e-12
    assert 0 < R[0.005] < 0.5 * R[0.00125] < 1


def test_depth_change_gradient_to_the_plate_matches_central_differences(coded):
    _, sensor = coded
    lens, a = _plate_x3(0.0025)
    wf = DepthWienerFilter(lens, sensor, [4500.0, 8000.0], depths=3, rays=4096)

    def R():
        return depth_change(*wf.otf_moments((32, 32)))

    (grad,) = torch.autograd.grad(R(), a)
    fd = central_fd(R, a, 1e-6 * float(a.detach().abs()))
    assert abs(fd) > 0
    assert float(grad) == pytest.approx(fd, rel=2e-3)
