"""Issue 25, item 13: the float32 gradient of a rendered image with respect to a flat EDOF
plate's x^3 term.

Finding: no float32 cancellation.  The Monte Carlo estimate's gradient is discontinuous in the
lens: bilinear texture sampling has a piecewise-constant derivative that jumps where a ray's
object-plane hit crosses a texel boundary, so any change of 1e-7 in a lens value (float32's
rounding of the prescription, or a float64 curvature times 1 + 1e-7) flips a few rays and moves
the x^3 gradient, a strongly cancelling sum at a flat plate, by several per cent, in float64 as
much as in float32.  With a texture whose texels are larger than those moves, float32 equals
float64 to 1e-5.  (docs/guide/numerics.md)
"""

from __future__ import annotations

import pytest
import torch

from deeplens.optics.io import load_lens
from deeplens.render import MonteCarloRenderer, Scene, Sensor
from deeplens.training.lens_setup import cubic_phase_plate


@pytest.fixture
def float64_draws(monkeypatch):
    """The renderer's uniform draws made in float64 and rounded, so that a float32 and a
    float64 render use the same samples (they are drawn in the lens dtype)."""
    rand = torch.rand

    def rand64(*args, dtype=None, **kw):
        return rand(*args, dtype=torch.float64, **kw).to(dtype or torch.get_default_dtype())

    monkeypatch.setattr(torch, "rand", rand64)


def _x3_gradient(dtype, texels, perturb=0.0):
    lens = load_lens("data/lenses/edof_achromat.json").to(dtype)
    with torch.no_grad():
        lens.surfaces[0].c.mul_(1.0 + perturb)
    cubic_phase_plate(lens, 4, 0.0)  # flat
    s = lens.surfaces[4]
    for p in s.a:
        p.requires_grad_(True)
    sensor = Sensor((32, 32), 0.0069, channels=[[587.6]])
    g = torch.Generator().manual_seed(0)
    tex = torch.rand(1, 1, texels, texels, generator=g, dtype=torch.float64)
    img = MonteCarloRenderer(lens, sensor, spp=16, adjoint=False)(Scene(tex.to(dtype), 6000.0),
                                                                  seed=3)
    W = torch.rand(img.shape, generator=g, dtype=torch.float64).to(dtype)
    (img * W).sum().backward()
    return float(s.a[s.terms.index((3, 0))].grad)


def test_float32_x3_gradient_at_a_flat_plate_equals_float64_for_a_smooth_texture(float64_draws):
    g64, g32 = _x3_gradient(torch.float64, 4), _x3_gradient(torch.float32, 4)
    assert abs(g64) > 1e4
    assert g32 == pytest.approx(g64, rel=1e-5)


def test_the_spread_on_a_fine_texture_is_the_gradients_own_discontinuity(float64_draws):
    """On a 64 x 64 texture float32 differs from float64 by several per cent, and so does
    float64 with one curvature changed by 1e-7: the estimator, not the precision."""
    g64 = _x3_gradient(torch.float64, 64)
    g32 = _x3_gradient(torch.float32, 64)
    g64p = _x3_gradient(torch.float64, 64, perturb=1e-7)
    assert abs(g32 / g64 - 1) > 0.02
    assert abs(g64p / g64 - 1) > 0.5 * abs(g32 / g64 - 1)
