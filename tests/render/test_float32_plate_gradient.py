"""Issue 25, item 13: the float32 gradient of a rendered image with respect to a flat EDOF
plate's x^3 term.

Finding: no float32 cancellation.  The Monte Carlo estimate's gradient is discontinuous in the
lens: bilinear texture sampling has a piecewise-constant derivative that jumps where a ray's
object-plane hit crosses a texel boundary, so any change of 1e-7 in a lens value (float32's
rounding of the prescription, or a float64 curvature times 1 + 1e-7) flips a few rays and moves
the x^3 gradient, a strongly cancelling sum at a flat plate, by up to several per cent, in
float64 as much as in float32.  With a texture whose texels are larger than those moves, float32
equals float64 to within the error estimate below: float32 rounding of the (well-conditioned)
pixel sum plus at most a couple of rays that float32 puts on the other side of a texel or pixel
boundary (docs/guide/numerics.md).  Tolerances are derived from that estimate, computed from the
render itself, not from one machine's outcome: which rays flip depends on the vector unit
(AVX-512, AVX2 and the scalar default path round differently).
"""

from __future__ import annotations

import pytest
import torch

from deeplens.optics.io import load_lens
from deeplens.render import MonteCarloRenderer, Scene, Sensor
from deeplens.training.lens_setup import cubic_phase_plate

EPS32 = torch.finfo(torch.float32).eps
SIZE, SPP = 32, 16


@pytest.fixture
def float64_draws(monkeypatch):
    """The renderer's uniform draws made in float64 and rounded, so that a float32 and a
    float64 render use the same samples (they are drawn in the lens dtype)."""
    rand = torch.rand

    def rand64(*args, dtype=None, **kw):
        return rand(*args, dtype=torch.float64, **kw).to(dtype or torch.get_default_dtype())

    monkeypatch.setattr(torch, "rand", rand64)


def _render(dtype, texels, perturb=0.0, dx3=0.0, grad=False):
    """The weighted image sum ``sum(W * img)`` and the plate (its x^3 coefficient moved by
    ``dx3``), the front curvature scaled by ``1 + perturb``."""
    lens = load_lens("data/lenses/edof_achromat.json").to(dtype)
    with torch.no_grad():
        lens.surfaces[0].c.mul_(1.0 + perturb)
    cubic_phase_plate(lens, 4, 0.0)  # flat
    s = lens.surfaces[4]
    k = s.terms.index((3, 0))
    with torch.no_grad():
        s.a[k].add_(dx3)
    for p in s.a:
        p.requires_grad_(grad)
    sensor = Sensor((SIZE, SIZE), 0.0069, channels=[[587.6]])
    g = torch.Generator().manual_seed(0)
    tex = torch.rand(1, 1, texels, texels, generator=g, dtype=torch.float64)
    img = MonteCarloRenderer(lens, sensor, spp=SPP, adjoint=False)(Scene(tex.to(dtype), 6000.0),
                                                                    seed=3)
    W = torch.rand(img.shape, generator=g, dtype=torch.float64).to(dtype)
    return img, W, s.a[k]


def _x3_gradient(dtype, texels, perturb=0.0):
    img, W, a = _render(dtype, texels, perturb, grad=True)
    (img * W).sum().backward()
    return float(a.grad)


def _float32_error_bound(texels, flips=2, h=1e-8):
    """Error estimate of the float32 x^3 gradient (absolute): ``sum_p |W_p dI_p/da|`` (the
    pixel terms, from a float64 central difference of the image) bounds the sum's rounding as
    ``8 eps32 sum|terms|`` and, divided by the number of rays, the mean size of one ray's
    term; a ray that float32 moves across a texel or pixel boundary changes the sum by about
    that much, and ``flips`` such rays are allowed."""
    with torch.no_grad():
        up, W, _ = _render(torch.float64, texels, dx3=h)
        dn, _, _ = _render(torch.float64, texels, dx3=-h)
    terms = (W * (up - dn) / (2 * h)).abs().sum().item()
    return 8 * EPS32 * terms + flips * terms / (SIZE * SIZE * SPP)


def test_float32_x3_gradient_at_a_flat_plate_equals_float64_for_a_smooth_texture(float64_draws):
    g64, g32 = _x3_gradient(torch.float64, 4), _x3_gradient(torch.float32, 4)
    assert abs(g64) > 1e4
    bound = _float32_error_bound(4)
    # the bound is a small fraction of the gradient: a float32 cancellation (errors of order
    # the gradient itself) cannot pass
    assert bound < 2e-3 * abs(g64)
    assert abs(g32 - g64) <= bound


def test_the_spread_on_a_fine_texture_is_the_gradients_own_discontinuity(float64_draws):
    """On a 64 x 64 texture, float64 with one curvature changed by 1e-7 or 2e-7 (float32's
    rounding of a prescription value is 6e-8 relative) moves the gradient by more than a per
    cent, and by at least as much as float32 does: the estimator, not the precision."""
    g64 = _x3_gradient(torch.float64, 64)
    g32 = _x3_gradient(torch.float32, 64)
    spread = max(abs(_x3_gradient(torch.float64, 64, perturb=p) / g64 - 1)
                 for p in (1e-7, -1e-7, 2e-7, -2e-7))
    assert spread > 0.01
    assert spread >= abs(g32 / g64 - 1)
