"""The depth-invariance merit (classical EDOF plate design): its OTF against closed forms, its
gradient against float64 central differences, and a designed plate that beats its cubic start."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.design.depth_invariance import (DepthInvarianceMerit, frequency_grid,
                                              geometric_otf)
from deeplens.design.lensopt import optimize_lens
from deeplens.design.variables import Variables
from deeplens.training.lens_setup import build_lens

LENS = "data/lenses/edof_achromat.json"
PLATE = [f"surfaces.4.a.{k}" for k in range(3, 10)]
DEPTHS = [4500.0, 5500.0, 6500.0, 8000.0]
WAVES = [656.3, 587.6, 486.1]


def _lens(alpha_mm=0.005):
    return build_lens(LENS, PLATE, "float64", plate="cubic", plate_surface=4,
                      plate_alpha_mm=alpha_mm, focus_mm=5760.0)


def test_geometric_otf_matches_closed_forms():
    f = frequency_grid(3)
    # half-plane, no zero frequency, no -f duplicates, Nyquist reached
    assert f.shape[0] == 4 * 7 - 4 and float(f.abs().max()) == 0.5
    assert not any(bool(((f + g).abs().sum(-1) < 1e-12).any()) for g in f)
    # two points at +-a on x: H(f) = cos(2 pi fx a), no imaginary part
    a = 0.7
    p = torch.tensor([[a, 0.0], [-a, 0.0]], dtype=torch.float64)
    re, im = geometric_otf(p, torch.ones(2), f)
    assert torch.allclose(re, torch.cos(2 * math.pi * f[:, 0] * a), atol=1e-14)
    assert torch.allclose(im, torch.zeros_like(im), atol=1e-14)
    # one point at (u, v): H = exp(-2 pi i f.(u, v)); a zero-weight point is ignored
    p = torch.tensor([[0.3, -1.1], [9.0, 9.0]], dtype=torch.float64)
    re, im = geometric_otf(p, torch.tensor([1.0, 0.0]), f)
    ph = -2 * math.pi * (f[:, 0] * 0.3 - f[:, 1] * 1.1)
    assert torch.allclose(re, torch.cos(ph), atol=1e-14)
    assert torch.allclose(im, torch.sin(ph), atol=1e-14)


def test_no_plate_is_far_from_depth_invariant_and_a_cubic_plate_is_closer():
    """Without a plate the PSF goes from 3.2 px to 0.6 px and back over the range; the cubic
    plate of 5 um keeps it near 5.4-6.3 px (configs/eval.yaml): the merit must rank them so."""
    kw = dict(sampling="grid:16", n_freq=3)
    flat = DepthInvarianceMerit(DEPTHS, WAVES, 0.0069, **kw).prepare(_lens(0.0))
    cubic = DepthInvarianceMerit(DEPTHS, WAVES, 0.0069, **kw).prepare(_lens(0.005))
    assert float(flat.invariance(_lens(0.0))) > 3 * float(cubic.invariance(_lens(0.005)))
    assert 4.5 < cubic.blur_px < 7.5 and flat.blur_px < 3.0


def test_depth_invariance_gradient_matches_central_differences():
    lens = _lens(0.005)
    m = DepthInvarianceMerit(DEPTHS[::3], WAVES[1:2], 0.0069, blur_px=5.0, sampling="grid:12",
                             n_freq=2).prepare(lens)
    v = Variables(lens, PLATE)
    x0 = v.x0()
    w = torch.linspace(-1.0, 1.0, m.residuals(lens).numel(), dtype=torch.float64)

    def f(x):  # a weighted sum of every residual (invariance and blur)
        return (v.call(m.residuals, x) * w).sum()

    x = x0.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(f(x), x)
    h = 1e-6
    fd = torch.stack([(f(x0 + h * e) - f(x0 - h * e)) / (2 * h)
                      for e in torch.eye(len(x0), dtype=torch.float64)])
    assert float(g.abs().max()) > 1e-3  # the merit really depends on the plate
    assert torch.allclose(g, fd, rtol=1e-5, atol=1e-7 * float(fd.abs().max()))


@pytest.mark.slow
def test_designed_plate_beats_its_cubic_start_at_the_same_blur():
    lens = _lens(0.005)
    m = DepthInvarianceMerit(DEPTHS, WAVES, 0.0069, sampling="grid:24", n_freq=4).prepare(lens)
    start, blur = float(m.invariance(lens)), m.blur_px
    res = optimize_lens(lens, Variables(lens, PLATE), m, method="dls", steps=6,
                        jacobian_mode="central")
    assert res.merit_after < res.merit_before
    m2 = DepthInvarianceMerit(DEPTHS, WAVES, 0.0069, sampling="grid:24", n_freq=4).prepare(lens)
    assert float(m2.invariance(lens)) < 0.8 * start
    assert m2.blur_px == pytest.approx(blur, rel=0.03)
