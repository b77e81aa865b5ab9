"""The Wiener front end against an independent closed form, and its noise ratio's range in the
lens dtype (issue 25, item 11 and "tests that a wrong implementation must not pass")."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from deeplens.optics.io import load_lens
from deeplens.render import Sensor
from deeplens.training.lens_setup import cubic_phase_plate
from deeplens.training.wiener import DepthWienerFilter, nsr_range


def _camera(dtype):
    lens = load_lens("data/lenses/edof_achromat.json").to(dtype)
    cubic_phase_plate(lens, 4, 0.005)
    return lens, Sensor((16, 16), 0.0069, channels=[[587.6]])


def _circular_blur_matrix(k: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """``A`` (h w, h w): the circular true convolution with ``k`` (K, K, centre K // 2), built
    pixel by pixel from shifted copies (no FFT)."""
    K, c = k.shape[-1], k.shape[-1] // 2
    eye = torch.eye(h * w, dtype=k.dtype).reshape(h * w, h, w)
    out = torch.zeros_like(eye)
    for u in range(K):
        for v in range(K):
            out = out + k[u, v] * torch.roll(eye, (u - c, v - c), (1, 2))
    return out.reshape(h * w, h * w).T


@pytest.mark.parametrize("nsr", [1e-3, 5e-2])
def test_output_equals_the_regularised_least_squares_deconvolution(nsr):
    """At one depth the filter is ``argmin |k * x - y|^2 + nsr |x|^2`` over the mirrored,
    circularly extended image, cropped: solved here by the normal equations
    ``(A^T A + nsr I) x = A^T y`` with a dense convolution matrix (no FFT)."""
    lens, sensor = _camera(torch.float64)
    wf = DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=4096, nsr=nsr,
                           learn_nsr=False)
    g = torch.Generator().manual_seed(1)
    y = torch.rand(1, 1, 8, 10, generator=g, dtype=torch.float64)
    ext = F.pad(y, (5, 5, 4, 4), mode="reflect")  # half the size on every side
    k = wf.psfs(ext.shape[-2:])[0, 0]
    assert 5 <= k.shape[-1] < 16 and float(k.sum()) == pytest.approx(1.0)
    A = _circular_blur_matrix(k, *ext.shape[-2:])
    rhs = A.T @ ext.reshape(-1)
    x = torch.linalg.solve(A.T @ A + nsr * torch.eye(A.shape[0], dtype=A.dtype), rhs)
    x = x.reshape(ext.shape[-2:])[4:12, 5:15]
    out = wf(y)[0, 0]
    assert torch.allclose(out, x, rtol=0, atol=1e-9 * float(x.abs().max()))


@pytest.mark.parametrize("nsr", [1e-46, 1e-20, 1e20, 1e39])
def test_a_noise_ratio_float32_cannot_hold_is_refused_with_the_range(nsr):
    lens, sensor = _camera(torch.float32)
    with pytest.raises(ValueError, match=r"model.deconvolution.nsr: .* float32 lens .*1.08e-19 "
                                         r".. 1.84e\+19"):
        DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=1024, nsr=nsr)


def test_float64_lens_holds_what_float32_cannot():
    lens, sensor = _camera(torch.float64)
    wf = DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=1024, nsr=1e30)
    assert float(wf.nsr().detach()[0]) == pytest.approx(1e30)
    assert nsr_range(torch.float64)[1] == pytest.approx(math.sqrt(torch.finfo(torch.float64).max))


@pytest.mark.parametrize("nsr", [1.2e-19, 1.7e19])
def test_float32_at_the_ends_of_the_range_has_finite_nonzero_gradients(nsr):
    lens, sensor = _camera(torch.float32)
    wf = DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=1024, nsr=nsr)
    y = torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0))
    out = wf(y)
    (out * y).sum().backward()
    assert torch.isfinite(out).all()
    grad = wf.log_nsr.grad
    assert torch.isfinite(grad).all() and float(grad.abs().min()) > 0


def test_a_learned_noise_ratio_that_drifts_out_stays_finite():
    lens, sensor = _camera(torch.float32)
    wf = DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=1024, nsr=1e-2)
    with torch.no_grad():
        wf.log_nsr.fill_(200.0)  # exp(200) overflows float32
    out = wf(torch.rand(1, 1, 16, 16))
    out.sum().backward()
    assert torch.isfinite(wf.nsr()).all() and torch.isfinite(out).all()
    assert torch.isfinite(wf.log_nsr.grad).all()
