"""The third-order merit's gradient (deeplens.design.search.seidel.third_order_rms).

The Seidel screen moves thousands of thin systems by Adam on this merit, so its autograd
gradient is what steers the screen: checked here against central finite differences in
float64 on the shipped Cooke triplet, for every curvature and every spacing, with and without
the closed-form refocus.
"""

import pytest
import torch

from deeplens.design.search import seidel as sd
from deeplens.optics.io import load_lens

WL = [486.1327, 587.5618, 656.2725]


def _merit(sysd, c, d, refocus):
    s = sd.ParaxialSystem(c, d, sysd.n, sysd.stop, sysd.primary)
    return sd.third_order_rms(s, 10.0, 20.0, [0.0, 0.7, 1.0], [1.0, 1.0, 1.0],
                              [1.0, 1.0, 1.0], rings=4, refocus=refocus)[0]


@pytest.mark.numerics
@pytest.mark.parametrize("refocus", [True, False])
def test_third_order_rms_gradient_matches_central_differences(refocus):
    lens = load_lens("data/lenses/cooke_triplet.json").to(torch.float64)
    sysd = sd.lens_system(lens, WL)
    c = sysd.c.clone().requires_grad_(True)
    d = sysd.d.clone().requires_grad_(True)
    f = _merit(sysd, c, d, refocus)
    gc, gd = torch.autograd.grad(f, (c, d))

    def fd(x, which, j, h):
        xp, xm = x.detach().clone(), x.detach().clone()
        xp[0, j] += h
        xm[0, j] -= h
        args = (lambda v: (v, sysd.d)) if which == "c" else (lambda v: (sysd.c, v))
        return float((_merit(sysd, *args(xp), refocus) - _merit(sysd, *args(xm), refocus))
                     / (2 * h))

    # the merit is smooth (a rational function of c and d, a square root away from 0), so the
    # central difference's truncation error is O(h² f''') and its round-off O(eps |f| / h):
    # h = 1e-5 of each variable's scale balances both near 1e-9 relative.  The tolerance is
    # 1e-6 of the gradient's largest component, far above both, far below a wrong term.
    for name, x, g, scale in (("c", sysd.c, gc, float(sysd.c.abs().max())),
                              ("d", sysd.d, gd, float(sysd.d[0, 1:].abs().max()))):
        h = 1e-5 * scale
        tol = 1e-6 * float(g.abs().max())
        for j in range(x.shape[1]):
            if name == "d" and j == 0:          # d[:, 0] is unused: its gradient is exactly 0
                assert float(g[0, 0]) == 0.0
                continue
            num = fd(x, name, j, h)
            assert abs(float(g[0, j]) - num) <= tol, \
                f"d merit / d {name}[{j}]: autograd {float(g[0, j])}, central difference {num}"
    # the gradient is not trivially zero: the Cooke triplet is not at a third-order optimum
    assert float(gc.abs().max()) > 1.0
