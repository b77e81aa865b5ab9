"""OpticStudio's Extended Odd Asphere (:mod:`deeplens.optics.surfaces.extended_odd_asphere`,
``XOSPHERE``): the sag against its closed form written here in numpy, every term on its power of
``ρ = r / R_n``, slopes and trace gradients against central differences (float64), the same
surface as the odd asphere with ``a_i = A_i / R_n^i``, the vertex curvature, the axis, the lens
file and the compiled tracer's eager fallback."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from deeplens.optics.intersect import intersect
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.options import TraceOptions
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import ExtendedOddAsphere, OddAsphere, Plane
from deeplens.optics.tracer import fused_kind
from helpers import disk_xy

F64 = torch.float64
C, K, RN = 1 / 30.0, -0.6, 2.5
A = [0.0, 1e-2, -4e-3, 2e-3, 5e-4, -3e-4, 4e-5, -2e-6]   # on ρ^1 .. ρ^8, mm


def sag_np(x, y, c=C, k=K, rn=RN, a=A):
    """The closed form, independently of the package: the conic plus Σ A_i (r / R_n)^i."""
    r2 = x * x + y * y
    rho = np.sqrt(r2) / rn
    z = c * r2 / (1 + np.sqrt(1 - (1 + k) * c * c * r2))
    for i, ai in enumerate(a, start=1):
        z = z + ai * rho ** i
    return z


def test_sag_is_the_closed_form():
    x, y = disk_xy()
    s = ExtendedOddAsphere(C, 6.5, RN, A, conic=K)
    z = s.sag(torch.tensor(x), torch.tensor(y)).detach().numpy()
    ref = sag_np(x, y)
    assert np.abs(ref).max() > 0.5
    assert np.abs(z - ref).max() < 1e-13


@pytest.mark.parametrize("i", range(1, 10))
def test_each_term_sits_on_its_power_of_rho(i):
    """A single coefficient ``A_i`` gives exactly ``A_i ρ^i`` (not ``ρ^(i±1)``), the radial
    slope ``i A_i ρ^(i−1) / R_n``, and the derivative ``ρ^i`` in its parameter."""
    a = [0.0] * (i - 1) + [0.3]
    s = ExtendedOddAsphere(0.0, 3.0, RN, a)
    s.a[i - 1].requires_grad_(True)
    r = torch.tensor([0.4, 1.3, 2.9], dtype=F64)
    th = torch.tensor([0.3, 2.0, -1.1], dtype=F64)
    x, y = r * torch.cos(th), r * torch.sin(th)
    rho = r / RN
    z = s.sag(x, y)
    assert z.tolist() == pytest.approx((0.3 * rho ** i).tolist(), rel=1e-14)
    for j in (i - 1, i + 1):
        assert not np.allclose(z.detach().numpy(), (0.3 * rho ** j).numpy(), rtol=1e-3)
    gx, gy = s.sag_grad(x, y)
    radial = (gx * x + gy * y) / r
    assert radial.tolist() == pytest.approx((0.3 * i * rho ** (i - 1) / RN).tolist(), rel=1e-13)
    g, = torch.autograd.grad(z.sum(), s.a[i - 1])
    assert float(g) == pytest.approx(float((rho ** i).sum()), rel=1e-14)


def test_slopes_match_central_differences():
    """``sag_grad`` against central differences of the closed form (h = 1e-6 mm: truncation
    ~h² |z'''| ~ 1e-12, round-off ~1e-16 / h ~ 1e-10), and autograd of the sag to round-off."""
    x, y = disk_xy(100, seed=1)
    keep = np.hypot(x, y) > 0.05
    x, y = x[keep], y[keep]
    s = ExtendedOddAsphere(C, 6.5, RN, [3e-3] + A[1:], conic=K)   # a ρ¹ cone tip too
    X, Y = torch.tensor(x), torch.tensor(y)
    gx, gy = s.sag_grad(X, Y)
    h = 1e-6
    a = [3e-3] + A[1:]
    fx = (sag_np(x + h, y, a=a) - sag_np(x - h, y, a=a)) / (2 * h)
    fy = (sag_np(x, y + h, a=a) - sag_np(x, y - h, a=a)) / (2 * h)
    assert np.abs(gx.numpy() - fx).max() < 1e-8
    assert np.abs(gy.numpy() - fy).max() < 1e-8
    Xg, Yg = X.clone().requires_grad_(True), Y.clone().requires_grad_(True)
    ax, ay = torch.autograd.grad(s.sag(Xg, Yg).sum(), (Xg, Yg))
    assert torch.allclose(ax, gx, atol=1e-14, rtol=0) and torch.allclose(ay, gy, atol=1e-14,
                                                                          rtol=0)


def test_same_surface_as_the_odd_asphere_with_rescaled_coefficients():
    """``a_i = A_i / R_n^i``: the odd asphere's sag, slopes and vertex curvature to round-off."""
    e = ExtendedOddAsphere(C, 6.5, RN, A, conic=K)
    o = OddAsphere(C, 6.5, K, [v / RN ** i for i, v in enumerate(A, 1)])
    x, y = (torch.tensor(v) for v in disk_xy(50, seed=2))
    assert torch.allclose(e.sag(x, y), o.sag(x, y), atol=1e-14, rtol=0)
    for p, q in zip(e.sag_grad(x, y), o.sag_grad(x, y)):
        assert torch.allclose(p, q, atol=1e-14, rtol=0)
    assert float(e.paraxial_curvature()) == pytest.approx(float(o.paraxial_curvature()),
                                                          rel=1e-15)


def test_paraxial_curvature_is_the_vertex_curvature():
    """``c + 2 A_2 / R_n²``: the second derivative of the closed-form sag at the vertex (central
    difference, h = 1e-4 mm: truncation ~h |A_3| / R_n³ relative ~1e-6); no ρ² term: ``c``."""
    s = ExtendedOddAsphere(C, 6.5, RN, A, conic=K)
    assert float(s.paraxial_curvature()) == pytest.approx(C + 2 * A[1] / RN ** 2, rel=1e-15)
    h = 1e-4
    num = 2 * sag_np(np.array(h), np.array(0.0)) / h ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(float(num), rel=1e-5)
    assert float(ExtendedOddAsphere(C, 6.5, RN, [0.0, 0.0, 1e-3]).paraxial_curvature()) == C


def test_axis_is_finite_forward_and_backward():
    """A ρ¹ term (a cone tip): at r = 0 and just off it the sag, slope, normal and every
    derivative are finite; the normal on the axis is the axis."""
    s = ExtendedOddAsphere(C, 6.5, RN, [2e-3] + A[1:], conic=K)
    for p in (s.c, s.k, *s.a):
        p.requires_grad_(True)
    x = torch.tensor([0.0, 1e-200, 1e-160, 1e-6], dtype=F64, requires_grad=True)
    y = torch.tensor([0.0, 0.0, 1e-160, 0.0], dtype=F64, requires_grad=True)
    z = s.sag(x, y)
    gx, gy = s.sag_grad(x, y)
    n = s.normal(torch.stack([x, y, z], -1))
    assert z[0].item() == 0.0 and n[0].tolist() == [0.0, 0.0, -1.0]
    assert float(gx[-1].detach()) == pytest.approx(2e-3 / RN, rel=1e-3)   # the cone's slope
    grads = torch.autograd.grad(z.sum() + gx.sum() + gy.sum() + n.sum(), (x, y, s.c, s.k, *s.a))
    assert all(torch.isfinite(g).all() for g in grads)


def _bisect_hit(o, d, lo=0.0, hi=20.0):
    def g(t):
        p = o + t * d
        return sag_np(p[0], p[1]) - p[2]
    assert g(lo) > 0 > g(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) > 0 else (lo, mid)
    return o + 0.5 * (lo + hi) * d


def test_intersection_matches_bisection():
    """Skew and axial rays: the hit is the bisection's on the closed-form sag to 1e-12 mm."""
    s = ExtendedOddAsphere(C, 6.5, RN, A, conic=K)
    rng = np.random.default_rng(3)
    o = np.column_stack([rng.uniform(-4, 4, 10), rng.uniform(-4, 4, 10), np.full(10, -5.0)])
    d = np.column_stack([rng.uniform(-0.2, 0.2, 10), rng.uniform(-0.2, 0.2, 10), np.ones(10)])
    o, d = np.vstack([o, [0.0, 0.0, -5.0]]), np.vstack([d, [0.0, 0.0, 1.0]])
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    t, x, ok = intersect(s, torch.tensor(o), torch.tensor(d),
                         torch.ones(len(o), dtype=torch.bool), TraceOptions())
    assert ok.all()
    ref = np.array([_bisect_hit(oi, di) for oi, di in zip(o, d)])
    assert np.abs(x.numpy() - ref).max() < 1e-12


def _lens(c=C, k=K, a=A):
    s = ExtendedOddAsphere(c, 6.0, RN, a, conic=k)
    return Lens([s, Plane(6.0)], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 30.0, 0), s


def _rays():
    y = torch.linspace(-4.5, 4.5, 7, dtype=F64)
    o = torch.stack([0.3 * y, y, torch.full_like(y, -1.0)], -1)
    d = torch.tensor([0.0, 0.03, 1.0], dtype=F64)
    return Rays(o, (d / d.norm()).expand(7, 3), 587.0)


@pytest.mark.parametrize("name,h", [("c", 1e-7), ("k", 1e-5), ("a2", 1e-7), ("a3", 1e-7),
                                    ("a6", 1e-7), ("a8", 1e-7)])
def test_trace_gradients_match_central_differences(name, h):
    """d/dθ of (Σ y_image² + Σ opl) through the lens against central differences (float64;
    the steps keep the truncation error ~h² below 1e-6 of the derivative)."""
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
    """No compiled Newton kernels (as the odd asphere): ``fused_kind`` None; the lens file
    round-trips with R_n and the normalised coefficients, tracing the same."""
    lens, s = _lens()
    assert fused_kind(lens, 0) is None
    d = lens_to_dict(lens)
    assert d["surfaces"][0]["type"] == "extended_odd_asphere"
    assert d["surfaces"][0]["rho_coefficients_mm"] == A
    assert d["surfaces"][0]["norm_radius_mm"] == RN
    back = lens_from_dict(d)
    assert lens_to_dict(back) == d
    with torch.no_grad():
        assert torch.equal(lens.trace_to_sensor(_rays()).o, back.trace_to_sensor(_rays()).o)


def test_constructor_errors_and_parameter_scale():
    from deeplens.optics.parameters import parameter_scale

    with pytest.raises(ValueError, match="at most 240 coefficients"):
        ExtendedOddAsphere(C, 5.0, RN, [0.0] * 241)
    with pytest.raises(ValueError, match="conic base"):
        ExtendedOddAsphere(1 / 5.0, 6.0, RN, [0.0, 1e-3]).check()
    lens, s = _lens()
    R = torch.tensor(float(s.semi_diameter), dtype=F64)
    for i in range(len(A)):   # ∂(sag at the rim)/∂A_i = (R / R_n)^i
        s.a[i].requires_grad_(True)
        g, = torch.autograd.grad(s.sag(R, torch.zeros_like(R)), s.a[i])
        assert parameter_scale(lens, f"surfaces.0.a.{i}") == pytest.approx(float(g), rel=1e-14)
