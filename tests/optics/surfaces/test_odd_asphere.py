"""The odd asphere (:mod:`deeplens.optics.surfaces.odd_asphere`, OpticStudio's ``ODDASPHE``): the
sag against its closed form written here in numpy, slopes against central differences, every
power in its place, the cone tip at r = 0 finite in forward and backward, ray intersections
against a bisection on the closed-form sag, gradients of a trace against central differences,
and the lens file."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from deeplens.optics.intersect import intersect
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.options import TraceOptions
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Asphere, OddAsphere, Plane
from deeplens.optics.tracer import fused_kind
from helpers import disk_xy

F64 = torch.float64
C, K = 1 / 30.0, -0.6
A = [2e-3, 1e-3, -3e-4, 2e-5, 4e-6, -3e-7, 1e-8, -2e-10]   # r^1 .. r^8


def sag_np(x, y, c=C, k=K, a=A):
    """The closed form, independently of the package."""
    r2 = x * x + y * y
    r = np.sqrt(r2)
    z = c * r2 / (1 + np.sqrt(1 - (1 + k) * c * c * r2))
    for i, ai in enumerate(a, start=1):
        z = z + ai * r ** i
    return z


_points = disk_xy


def test_sag_is_the_closed_form():
    x, y = _points()
    s = OddAsphere(C, 6.5, K, A)
    z = s.sag(torch.tensor(x), torch.tensor(y)).detach().numpy()
    ref = sag_np(x, y)
    assert np.abs(ref).max() > 0.5
    assert np.abs(z - ref).max() < 1e-14


@pytest.mark.parametrize("i", range(1, 9))
def test_each_power_sits_in_its_place(i):
    """A single coefficient on ``r^i`` gives exactly ``a r^i`` (not ``r^(i±1)``), its slope
    ``i a r^(i−1)`` along the radius, and the ``i``-th parameter's derivative ``r^i``."""
    a = [0.0] * (i - 1) + [0.3]
    s = OddAsphere(0.0, 3.0, 0.0, a)
    s.a[i - 1].requires_grad_(True)
    r = torch.tensor([0.4, 1.3, 2.5], dtype=F64)
    th = torch.tensor([0.3, 2.0, -1.1], dtype=F64)
    x, y = r * torch.cos(th), r * torch.sin(th)
    z = s.sag(x, y)
    assert z.tolist() == pytest.approx((0.3 * r ** i).tolist(), rel=1e-14)
    for j in (i - 1, i + 1):
        assert not np.allclose(z.detach().numpy(), (0.3 * r ** j).numpy(), rtol=1e-3)
    gx, gy = s.sag_grad(x, y)
    radial = (gx * x + gy * y) / r
    assert radial.tolist() == pytest.approx((0.3 * i * r ** (i - 1)).tolist(), rel=1e-13)
    g, = torch.autograd.grad(z.sum(), s.a[i - 1])
    assert float(g) == pytest.approx(float((r ** i).sum()), rel=1e-14)


def test_slopes_match_central_differences():
    x, y = _points(100, seed=1)
    keep = np.hypot(x, y) > 0.05
    x, y = x[keep], y[keep]
    s = OddAsphere(C, 6.5, K, A)
    X, Y = torch.tensor(x), torch.tensor(y)
    gx, gy = s.sag_grad(X, Y)
    h = 1e-6
    fx = (sag_np(x + h, y) - sag_np(x - h, y)) / (2 * h)
    fy = (sag_np(x, y + h) - sag_np(x, y - h)) / (2 * h)
    assert np.abs(gx.numpy() - fx).max() < 1e-8
    assert np.abs(gy.numpy() - fy).max() < 1e-8
    # and autograd of the sag agrees with the analytic slope to round-off
    Xg, Yg = X.clone().requires_grad_(True), Y.clone().requires_grad_(True)
    ax, ay = torch.autograd.grad(s.sag(Xg, Yg).sum(), (Xg, Yg))
    assert torch.allclose(ax, gx, atol=1e-14, rtol=0) and torch.allclose(ay, gy, atol=1e-14,
                                                                          rtol=0)


def test_even_terms_only_equal_the_even_asphere():
    """Coefficients on r⁴, r⁶ only: the same surface as an :class:`Asphere` (sag and slopes to
    round-off), the odd part never used."""
    odd = OddAsphere(C, 6.5, K, [0.0, 0.0, 0.0, 2e-5, 0.0, -3e-7])
    even = Asphere(C, 6.5, K, [2e-5, -3e-7])
    x, y = (torch.tensor(v) for v in _points(50, seed=2))
    assert torch.allclose(odd.sag(x, y), even.sag(x, y), atol=1e-15, rtol=0)
    for a, b in zip(odd.sag_grad(x, y), even.sag_grad(x, y)):
        assert torch.allclose(a, b, atol=1e-15, rtol=0)


def test_axis_is_finite_forward_and_backward():
    """At r = 0 (and below the safe radius, 1e-200 mm) the sag, the slope, the normal and every
    derivative are finite; the slope there is the even part's (0 on the axis), so the normal is
    the axis (0, 0, −1); just off the axis the cone's slope a_1 is there."""
    s = OddAsphere(C, 6.5, K, A)
    for p in (s.c, s.k, *s.a):
        p.requires_grad_(True)
    x = torch.tensor([0.0, 1e-200, 0.0, 1e-160, 1e-6], dtype=F64, requires_grad=True)
    y = torch.tensor([0.0, 0.0, -1e-200, 1e-160, 0.0], dtype=F64, requires_grad=True)
    z = s.sag(x, y)
    gx, gy = s.sag_grad(x, y)
    n = s.normal(torch.stack([x, y, z], -1))
    assert torch.isfinite(z).all() and torch.isfinite(gx).all() and torch.isfinite(n).all()
    assert z[0].item() == 0.0 and gx[0].item() == 0.0 and gy[0].item() == 0.0
    assert n[0].tolist() == [0.0, 0.0, -1.0]
    assert float(gx[-1].detach()) == pytest.approx(A[0], rel=1e-3)   # the cone's slope at r = 1e-6
    loss = (z.sum() + gx.sum() + gy.sum() + n.sum())
    grads = torch.autograd.grad(loss, (x, y, s.c, s.k, *s.a))
    assert all(torch.isfinite(g).all() for g in grads)
    # in float32 too (its safe radius is 3e-10 mm)
    s32 = OddAsphere(C, 6.5, K, A)
    x32 = torch.tensor([0.0, 1e-20, 1e-12, 1e-3], dtype=torch.float32, requires_grad=True)
    y32 = torch.zeros_like(x32, requires_grad=True)
    z32 = s32.sag(x32, y32)
    g32 = s32.sag_grad(x32, y32)
    gr = torch.autograd.grad(z32.sum() + g32[0].sum() + g32[1].sum(), (x32, y32))
    assert all(torch.isfinite(t).all() for t in (z32, *g32, *gr))


def test_paraxial_curvature_is_the_vertex_curvature():
    """``c + 2 a_2``: the second derivative of the sag at the vertex (without an r¹ term, whose
    cone has no curvature to measure)."""
    s = OddAsphere(C, 6.5, K, [0.0] + A[1:])
    assert float(s.paraxial_curvature()) == C + 2 * A[1]
    h = 1e-4
    num = 2 * sag_np(np.array(h), np.array(0.0), a=[0.0] + A[1:]) / h ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(float(num), rel=1e-5)
    assert float(OddAsphere(C, 6.5, K, [1e-3]).paraxial_curvature()) == C


def _bisect_hit(o, d, a=A, c=C, k=K, lo=0.0, hi=20.0):
    """The first crossing of the closed-form sag along ``o + t d`` by bisection (numpy)."""
    def g(t):
        p = o + t * d
        return sag_np(p[0], p[1], c, k, a) - p[2]
    assert g(lo) > 0 > g(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) > 0 else (lo, mid)
    return o + 0.5 * (lo + hi) * d


def test_intersection_matches_bisection():
    """Meridional, skew and axial rays, one of them through the cone tip itself: the hit is
    the bisection's to 1e-12 mm (float64)."""
    s = OddAsphere(C, 6.5, K, A)
    rng = np.random.default_rng(3)
    o = np.column_stack([rng.uniform(-4, 4, 12), rng.uniform(-4, 4, 12), np.full(12, -5.0)])
    d = np.column_stack([rng.uniform(-0.2, 0.2, 12), rng.uniform(-0.2, 0.2, 12), np.ones(12)])
    o = np.vstack([o, [0.0, 0.0, -5.0], [-1.0, 0.0, -10.0]])   # along the axis; through the tip
    d = np.vstack([d, [0.0, 0.0, 1.0], [1.0, 0.0, 10.0]])
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    t, x, ok = intersect(s, torch.tensor(o), torch.tensor(d),
                         torch.ones(len(o), dtype=torch.bool), TraceOptions())
    assert ok.all()
    ref = np.array([_bisect_hit(oi, di) for oi, di in zip(o, d)])
    assert np.abs(x.numpy() - ref).max() < 1e-12
    assert np.abs(x[-2:].numpy()).max() < 1e-15   # both meet the surface at its tip


def _lens(c=C, k=K, a=A):
    s = OddAsphere(c, 6.0, k, a)
    return Lens([s, Plane(6.0)], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 30.0, 0), s


def _rays():
    y = torch.linspace(-4.5, 4.5, 7, dtype=F64)
    o = torch.stack([0.3 * y, y, torch.full_like(y, -1.0)], -1)
    d = torch.tensor([0.0, 0.03, 1.0], dtype=F64)
    d = (d / d.norm()).expand(7, 3)
    return Rays(o, d, 587.0)


def test_a_ray_through_the_tip_traces_finite_gradients():
    """A ray on the axis meets the cone's tip: it leaves along the axis (the normal there is the
    axis), and the gradients of its image point and path through the lens are finite."""
    lens, s = _lens()
    for p in (s.c, s.k, *s.a):
        p.requires_grad_(True)
    o = torch.tensor([[0.0, 0.0, -1.0]], dtype=F64, requires_grad=True)
    d = torch.tensor([[0.0, 0.0, 1.0]], dtype=F64)
    out = lens.trace_to_sensor(Rays(o, d, 587.0))
    assert out.valid.all() and out.o[0, :2].tolist() == [0.0, 0.0]
    grads = torch.autograd.grad(out.o.sum() + out.opl.sum(), (o, s.c, s.k, *s.a))
    assert all(torch.isfinite(g).all() for g in grads)


@pytest.mark.parametrize("name,h", [("c", 1e-7), ("k", 1e-5), ("a1", 1e-7), ("a2", 1e-7),
                                    ("a3", 1e-8), ("a5", 1e-10)])
def test_trace_gradients_match_central_differences(name, h):
    """d/dθ of (Σ y_image² + Σ opl) through the lens, against central differences (float64)."""
    def q(delta):
        c, k, a = C, K, list(A)
        if name == "c":
            c += delta
        elif name == "k":
            k += delta
        else:
            a[int(name[1:]) - 1] += delta
        lens, s = _lens(c, k, a)
        p = {"c": s.c, "k": s.k}.get(name) or s.a[int(name[1:]) - 1]
        p.requires_grad_(True)
        out = lens.trace_to_sensor(_rays())
        assert out.valid.all()
        return (out.o[:, 1] ** 2).sum() + out.opl.sum(), p

    v, p = q(0.0)
    ad, = torch.autograd.grad(v, p)
    fd = float((q(h)[0] - q(-h)[0]).detach()) / (2 * h)
    assert abs(fd) > 1e-3
    assert float(ad) == pytest.approx(fd, rel=2e-6)


def test_traces_eager_under_the_compiled_tracer_and_saves():
    """No compiled Newton kernels: the fused tracer leaves the surface to the eager path
    (``fused_kind`` None), whose result is the generic one; the lens file round-trips."""
    lens, s = _lens()
    assert fused_kind(lens, 0) is None
    d = lens_to_dict(lens)
    assert d["surfaces"][0]["type"] == "odd_asphere"
    assert d["surfaces"][0]["radial_coefficients"] == A
    back = lens_from_dict(d)
    assert lens_to_dict(back) == d
    with torch.no_grad():
        a = lens.trace_to_sensor(_rays())
        b = back.trace_to_sensor(_rays())
    assert torch.equal(a.o, b.o)


def test_constructor_and_domain_errors():
    with pytest.raises(ValueError, match="at most 20 coefficients"):
        OddAsphere(C, 5.0, 0.0, [0.0] * 21)
    with pytest.raises(ValueError, match="conic base"):
        OddAsphere(1 / 5.0, 6.0, 0.0, [1e-3]).check()
    assert math.isfinite(float(OddAsphere(0.0, 6.0, 0.0, [1e-3]).sag(
        torch.tensor(1e30, dtype=F64), torch.tensor(0.0, dtype=F64))))


def test_parameter_scale_is_the_rim_sag_derivative():
    """``parameter_scale`` (the design/training step scale): ∂(sag at the rim)/∂a_i = R^i, by
    autograd of the surface's own sag."""
    from deeplens.optics.parameters import parameter_scale

    lens, s = _lens()
    R = torch.tensor(float(s.semi_diameter), dtype=F64)
    for i in range(len(A)):
        s.a[i].requires_grad_(True)
        g, = torch.autograd.grad(s.sag(R, torch.zeros_like(R)), s.a[i])
        assert parameter_scale(lens, f"surfaces.0.a.{i}") == pytest.approx(float(g), rel=1e-14)


@pytest.mark.parametrize("mode", ["surface", "lens"])
def test_fused_tracer_runs_it_eager_with_the_same_values_and_gradients(uncompiled, mode):
    """The double Gauss with its first surface an odd asphere (its even terms plus r¹, r³, r⁵):
    the fused tracer's logic (``uncompiled``: the kernels' arithmetic without the compiler)
    leaves it to the eager path between its fused runs; rays, paths and gradients (c, a_1, a_3
    of the odd asphere, a later sphere's c) equal the eager tracer's."""
    import helpers as H

    from deeplens.optics.io import load_lens

    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    s0 = lens.surfaces[0]
    a4, a6, a8 = (float(v) for v in s0.a)
    odd = OddAsphere(float(s0.c), float(s0.semi_diameter), float(s0.k),
                     [1e-4, 0.0, -2e-5, a4, 3e-7, a6, 0.0, a8])
    lens.surfaces[0] = odd
    assert fused_kind(lens, 0) is None and fused_kind(lens, 4) is not None
    params = [odd.c, odd.a[0], odd.a[2], lens.surfaces[4].c]
    for p in params:
        p.requires_grad_(True)
    H.assert_compiled_run_equals_eager(lens, params, mode)
