"""Each surface's maths and each law is written once (issue 24): a bug planted in the one
definition changes the eager tracer and the fused (compiled) path alike.

The bug is planted by swapping the code of the shared function (what editing its source does),
then the same rays are traced eagerly and through the fused path (its plain Python kernels, as
``tests/optics/test_compiled.py``'s ``uncompiled`` fixture; the inductor-compiled kernels run the
same functions, checked by a ``slow`` test).  For each bug: the traced values change (the bug is
visible), and the eager and fused results still agree to rounding, with the bug (one definition,
not two that a test holds equal).
"""

from __future__ import annotations

import contextlib

import helpers as H
import pytest
import torch

from deeplens.optics import intersect as I
from deeplens.optics import refract as R
from deeplens.optics.options import TraceOptions
from deeplens.optics.io import load_lens
from deeplens.optics.rays import Rays
from deeplens.optics.sampling import field_rays
from deeplens.optics.surfaces import asphere as A
from deeplens.optics.surfaces import xy_polynomial as XY

EAGER = TraceOptions()
FUSED = TraceOptions(compile="surface")
LENS_RUN = TraceOptions(compile="lens")


@contextlib.contextmanager
def planted(fn, buggy):
    """``fn`` runs ``buggy``'s code (same module globals) inside the block."""
    saved = fn.__code__
    fn.__code__ = buggy.__code__
    try:
        yield
    finally:
        fn.__code__ = saved


# ---- the bugs: each a plausible slip in one shared definition -------------------------------
def even_poly_one_power_short(s, coeffs):
    p = torch.zeros_like(s)
    for a in reversed(list(coeffs)):
        p = (p + a.to(s)) * s
    return p


def xy_poly_slope_without_exponent(x, y, coeffs, terms, order: int):
    px, py = [torch.ones_like(x)], [torch.ones_like(y)]
    for _ in range(order):
        px.append(px[-1] * x)
        py.append(py[-1] * y)
    P, Px, Py = torch.zeros_like(x), torch.zeros_like(x), torch.zeros_like(x)
    for a, (i, j) in zip(coeffs, terms):
        a = a.to(x)
        P = P + a * px[i] * py[j]
        if i:
            Px = Px + a * px[i - 1] * py[j]  # planted: (a * i) lost its exponent
        if j:
            Py = Py + (a * j) * px[i] * py[j - 1]
    return P, Px, Py


def conic_quadric_wrong_sign(ox, oy, oz, dx, dy, dz, c, k):
    c, k1 = c.to(ox), 1.0 + k.to(ox)
    ck = c * k1
    A_ = c * (dx * dx + dy * dy) + ck * (dz * dz)
    B = c * (ox * dx + oy * dy) + (ck * oz + 1.0) * dz  # planted: + 1 instead of - 1
    C_ = c * (ox * ox + oy * oy) + (ck * oz - 2.0) * oz
    return A_, B, C_, ck, c


def snell_plus_eta_cos(cos_i, eta, ok):
    k = 1.0 - (eta * eta) * (1.0 - cos_i * cos_i)
    ok = ok & (k > 0)
    sqrt_k = torch.sqrt(torch.where(ok, k, torch.ones_like(k)))
    return torch.copysign(sqrt_k, cos_i) + eta * cos_i, ok  # planted: + eta cos


def hit_mask_behind_accepted(t, X, Y, Z, ok, tol, inside=None, backward=False):
    with torch.no_grad():
        if inside is not None:
            ok = ok & inside
        return ok & torch.isfinite(t)  # planted: the "ahead of the ray" check is gone


BUGS = {
    "asphere_even_poly": (A.even_poly, even_poly_one_power_short, "thorlabs_acl5040u.json"),
    "xy_poly_slope": (XY.xy_poly, xy_poly_slope_without_exponent, "edof_achromat.json"),
    "conic_quadric": (A.conic_quadric, conic_quadric_wrong_sign, "cooke_triplet.json"),
    "snell": (R.snell_coefficient, snell_plus_eta_cos, "double_gauss.json"),
}


def _trace(lens, opt, behind=False):
    """Forward rays of a 3-degree field; ``behind``: started between the first two vertices,
    so that the first surface lies behind them (a correct tracer drops them there)."""
    n = 200
    if behind:
        z = lens.z_vertices().detach()
        xy = H.disk_points(n, 1.0, seed=3)
        o = torch.cat([xy, torch.full((n, 1), float(z[0] + z[1]) / 2, dtype=torch.float64)], -1)
        d = torch.tensor([0.0, 0.02, 1.0], dtype=torch.float64).expand(n, 3)
        return lens.trace_to_sensor(Rays(o, d, H.WAVELENGTH_D), options=opt)
    rays = field_rays(lens, 3.0, H.WAVELENGTH_D, H.disk_points(n, 3.0, seed=2), 0.0)
    return lens.trace_to_sensor(rays, options=opt)


def _params(lens):
    ps = [p for n, p in lens.named_parameters() if not n.startswith("misalignments")]
    for p in ps:
        p.requires_grad_(True)
    return ps


def _result(lens, params, opt, behind=False):
    out = _trace(lens, opt, behind)
    v = out.valid
    w = torch.randn(out.o.shape, generator=torch.Generator().manual_seed(4), dtype=out.o.dtype)
    loss = (out.o[v] * w[v]).sum() + (out.d[v] * w[v]).sum() + out.opl[v].sum()
    grads = torch.autograd.grad(loss, params, allow_unused=True)
    flat = torch.cat([g.reshape(-1) if g is not None else torch.zeros(p.numel(), dtype=p.dtype)
                      for p, g in zip(params, grads)])
    return out, flat


def _maxabs(t) -> float:
    return float(t.detach().abs().max()) if t.numel() else 0.0


def _close(a, b, gtol=1e-9):
    out_a, g_a = a
    out_b, g_b = b
    if not torch.equal(out_a.valid, out_b.valid):
        return False
    v = out_a.valid
    return all(_maxabs((x - y)[v]) < 1e-11 for x, y in
               ((out_a.o, out_b.o), (out_a.d, out_b.d), (out_a.opl, out_b.opl))) and \
        H.rel_err(g_a, g_b) < gtol


def _changed(a, b):
    """The rays or the gradients differ beyond rounding."""
    out_a, g_a = a
    out_b, g_b = b
    if not torch.equal(out_a.valid, out_b.valid):
        return True
    v = out_a.valid
    return _maxabs((out_a.o - out_b.o)[v]) > 1e-6 or H.rel_err(g_a, g_b) > 1e-6


@pytest.mark.parametrize("bug", sorted(BUGS))
def test_a_bug_in_the_one_definition_reaches_eager_and_fused_alike(uncompiled, bug):
    fn, buggy, lens_file = BUGS[bug]
    lens = load_lens(H.LENS_DIR / lens_file)
    params = _params(lens)
    clean = _result(lens, params, EAGER)
    assert _close(clean, _result(lens, params, FUSED))  # the two paths agree without the bug
    with planted(fn, buggy):
        eager = _result(lens, params, EAGER)
        fused = _result(lens, params, FUSED)
        with torch.no_grad():
            run = _trace(lens, LENS_RUN)
    assert _changed(clean, eager), "the planted bug does not change the eager trace"
    assert _changed(clean, fused), "the planted bug does not change the fused trace"
    assert _close(eager, fused), "eager and fused disagree: the maths is written twice"
    assert torch.equal(run.valid, eager[0].valid)


def test_a_bug_in_hit_acceptance_reaches_eager_and_fused_alike(uncompiled):
    """Rays started past the first surface: without the "ahead of the ray" check they are
    accepted at hits behind them (eager and fused alike)."""
    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    params = _params(lens)
    clean = _result(lens, params, EAGER, behind=True)
    assert _close(clean, _result(lens, params, FUSED, behind=True))
    with planted(I.hit_mask, hit_mask_behind_accepted):
        eager = _result(lens, params, EAGER, behind=True)
        fused = _result(lens, params, FUSED, behind=True)
    assert not bool(clean[0].valid.any())  # a correct tracer drops every ray
    assert _changed(clean, eager) and _changed(clean, fused)
    assert _close(eager, fused)
