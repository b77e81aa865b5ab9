"""The biconic (:mod:`deeplens.optics.surfaces.biconic`, OpticStudio's ``BICONICX``): the sag
against its closed form written here in numpy, slopes against central differences, the x and y
sections each in their place (a test that fails if they were swapped), the rotationally
symmetric case equal to the conic (values and a traced lens), the domain (rays beyond it go
invalid, never NaN), ray intersections against a bisection on the closed-form sag, gradients of
a trace against central differences (float64), the lens file, and optiland's biconic (a
test-only oracle) where the two definitions coincide."""

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
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Asphere, Biconic, Plane
from deeplens.optics.tracer import fused_kind
from helpers import disk_xy

F64 = torch.float64
CY, KY, CX, KX = 1 / 30.0, -0.6, 1 / 45.0, 0.8


def sag_np(x, y, cy=CY, ky=KY, cx=CX, kx=KX):
    """OpticStudio's biconic sag, independently of the package."""
    n = cx * x * x + cy * y * y
    q = (1 + kx) * cx * cx * x * x + (1 + ky) * cy * cy * y * y
    return n / (1 + np.sqrt(1 - q))


def conic_np(r, c, k):
    return c * r * r / (1 + np.sqrt(1 - (1 + k) * c * c * r * r))


_points = disk_xy


def test_sag_is_the_closed_form():
    x, y = _points()
    s = Biconic(CY, 6.5, CX, KY, KX)
    z = s.sag(torch.tensor(x), torch.tensor(y)).numpy()
    ref = sag_np(x, y)
    assert np.abs(ref).max() > 0.3
    assert np.abs(z - ref).max() < 1e-14


def test_sections_are_the_x_and_y_conics_not_swapped():
    """y = 0 is the conic (c_x, k_x), x = 0 the conic (c_y, k_y): with c_x != c_y this fails if
    the two were swapped (the difference is 0.1 mm at 6 mm here)."""
    s = Biconic(CY, 6.5, CX, KY, KX)
    r = np.linspace(-6.0, 6.0, 25)
    t = torch.tensor(r)
    zx = s.sag(t, torch.zeros_like(t)).numpy()
    zy = s.sag(torch.zeros_like(t), t).numpy()
    assert np.abs(zx - conic_np(r, CX, KX)).max() < 1e-15
    assert np.abs(zy - conic_np(r, CY, KY)).max() < 1e-15
    assert np.abs(zx - conic_np(r, CY, KY)).max() > 0.1
    # the paraxial data see the y-z section (as for the cylinder and the toroid)
    assert float(s.paraxial_curvature()) == CY


def test_slopes_match_central_differences():
    x, y = _points(100, seed=1)
    s = Biconic(CY, 6.5, CX, KY, KX)
    X, Y = torch.tensor(x), torch.tensor(y)
    gx, gy = s.sag_grad(X, Y)
    h = 1e-6
    fx = (sag_np(x + h, y) - sag_np(x - h, y)) / (2 * h)
    fy = (sag_np(x, y + h) - sag_np(x, y - h)) / (2 * h)
    assert np.abs(gx.numpy()).max() > 0.1 and np.abs(gy.numpy()).max() > 0.1
    assert np.abs(gx.numpy() - fx).max() < 1e-8
    assert np.abs(gy.numpy() - fy).max() < 1e-8
    # autograd of the sag agrees with the analytic slope to round-off
    Xg, Yg = X.clone().requires_grad_(True), Y.clone().requires_grad_(True)
    ax, ay = torch.autograd.grad(s.sag(Xg, Yg).sum(), (Xg, Yg))
    assert torch.allclose(ax, gx, atol=1e-14, rtol=0)
    assert torch.allclose(ay, gy, atol=1e-14, rtol=0)


def test_equal_curvatures_and_conics_are_the_conic():
    """c_x = c_y, k_x = k_y: the rotationally symmetric conic (sag and slopes to round-off), and
    a lens made with it traces as the same lens made with the conic (1e-13 mm)."""
    b = Biconic(CY, 6.5, CY, KY, KY)
    a = Asphere(CY, 6.5, KY)
    x, y = (torch.tensor(v) for v in _points(100, seed=2))
    assert torch.allclose(b.sag(x, y), a.sag(x, y), atol=1e-15, rtol=0)
    for u, v in zip(b.sag_grad(x, y), a.sag_grad(x, y)):
        assert torch.allclose(u, v, atol=1e-15, rtol=0)
    with torch.no_grad():
        ob = _lens(s=b)[0].trace_to_sensor(_rays())
        oa = _lens(s=Asphere(CY, 6.0, KY))[0].trace_to_sensor(_rays())
    assert ob.valid.all() and oa.valid.all()
    assert (ob.o - oa.o).abs().max() < 1e-13 and (ob.d - oa.d).abs().max() < 1e-14
    assert (ob.opl - oa.opl).abs().max() < 1e-12


def test_an_ellipsoid_is_a_biconic():
    """OpticStudio's manual models an ellipsoid of semi-axes a, b, c (along x, y, z; vertex at
    the origin) with its biconic, converting the semi-axes into radii and conics: with
    R_x = a²/c, R_y = b²/c, k_x = a²/c² − 1, k_y = b²/c² − 1 the sag's points satisfy
    x²/a² + y²/b² + (z − c)²/c² = 1 to round-off (the sum of an x conic and a y conic, optiland's
    biconic, would not: it is no quadric)."""
    a, b, c = 8.0, 12.0, 20.0
    s = Biconic(c / b ** 2, 7.0, c / a ** 2, b * b / c ** 2 - 1, a * a / c ** 2 - 1)
    x, y = _points(100, rmax=6.9, seed=4)
    z = s.sag(torch.tensor(x), torch.tensor(y)).numpy()
    resid = x * x / a ** 2 + y * y / b ** 2 + (z - c) ** 2 / c ** 2 - 1
    assert np.abs(resid).max() < 1e-14
    assert np.abs(z).max() > 1.0


def test_domain_marks_rays_invalid_never_nan():
    """Beyond the domain (1 − Q <= 0) ``in_domain`` is False and the sag, slopes and their
    gradients stay finite; a ray that lands there through a lens is invalid, and the gradient
    of a loss over the valid rays has no NaN."""
    s = Biconic(1 / 5.0, 4.0, 1 / 8.0, 0.0, 0.0)
    for p in (s.c, s.k, s.cx, s.kx):
        p.requires_grad_(True)
    x = torch.tensor([0.0, 9.0, 0.0, 1.0], dtype=F64, requires_grad=True)
    y = torch.tensor([0.0, 0.0, 6.0, 1.0], dtype=F64, requires_grad=True)
    assert s.in_domain(x, y).tolist() == [True, False, False, True]
    z = s.sag(x, y)
    gx, gy = s.sag_grad(x, y)
    grads = torch.autograd.grad(z.sum() + gx.sum() + gy.sum(), (x, y, s.c, s.k, s.cx, s.kx))
    assert all(torch.isfinite(g).all() for g in (z, gx, gy, *grads))
    s.check()   # the semi-diameter, 4 mm, lies inside (the y section ends at 5 mm)
    with pytest.raises(ValueError, match="beyond the domain of the biconic.*along y.*< 5 mm"):
        Biconic(1 / 5.0, 5.5, 1 / 8.0).check()
    with pytest.raises(ValueError, match="along x"):
        Biconic(0.0, 9.0, 1 / 8.0).check()
    Biconic(1 / 5.0, 4.9, 1 / 8.0).check()
    # through a lens (unclipped): a parallel beam of 7.5 mm height on a surface whose y section
    # ends at 5 mm
    lens = Lens([Biconic(1 / 5.0, 4.9, 1 / 8.0), Plane(8.0)],
                [Air(), ModelGlass(1.5, 60.0), Air()], [0.0, 6.0], 20.0, 0)
    lens.surfaces[0].c.requires_grad_(True)
    yy = torch.tensor([0.0, 2.0, 4.0, 6.0, 7.5], dtype=F64)
    o = torch.stack([torch.zeros_like(yy), yy, torch.full_like(yy, -1.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(5, 3)
    out = lens.trace_to_sensor(Rays(o, d, 587.0), options=TraceOptions(clip_aperture=False))
    assert out.valid.tolist() == [True, True, True, False, False]
    assert torch.isfinite(out.o).all() and torch.isfinite(out.d).all()
    g, = torch.autograd.grad((out.o[out.valid, 1] ** 2).sum(), lens.surfaces[0].c)
    assert torch.isfinite(g) and abs(float(g)) > 0


def _bisect_hit(o, d, lo=0.0, hi=20.0):
    """The first crossing of the closed-form sag along ``o + t d`` by bisection (numpy)."""
    def g(t):
        p = o + t * d
        return sag_np(p[0], p[1]) - p[2]
    assert g(lo) > 0 > g(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) > 0 else (lo, mid)
    return o + 0.5 * (lo + hi) * d


def test_intersection_matches_bisection():
    """Skew, meridional and axial rays: the hit is the bisection's to 1e-12 mm (float64)."""
    s = Biconic(CY, 6.5, CX, KY, KX)
    rng = np.random.default_rng(3)
    o = np.column_stack([rng.uniform(-4, 4, 12), rng.uniform(-4, 4, 12), np.full(12, -5.0)])
    d = np.column_stack([rng.uniform(-0.3, 0.3, 12), rng.uniform(-0.3, 0.3, 12), np.ones(12)])
    o = np.vstack([o, [0.0, 0.0, -5.0], [0.0, 3.0, -5.0]])
    d = np.vstack([d, [0.0, 0.0, 1.0], [0.0, 0.1, 1.0]])
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    t, x, ok = intersect(s, torch.tensor(o), torch.tensor(d),
                         torch.ones(len(o), dtype=torch.bool), TraceOptions())
    assert ok.all()
    ref = np.array([_bisect_hit(oi, di) for oi, di in zip(o, d)])
    assert np.abs(x.numpy() - ref).max() < 1e-12
    assert np.abs(ref[:, 2]).max() > 0.2


def _lens(cy=CY, ky=KY, cx=CX, kx=KX, s=None):
    s = Biconic(cy, 6.0, cx, ky, kx) if s is None else s
    return Lens([s, Plane(6.0)], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 30.0, 0), s


def _rays():
    """Skew rays (x and y both non-zero) over the aperture."""
    y = torch.linspace(-4.5, 4.5, 7, dtype=F64)
    o = torch.stack([0.6 * y.flip(0), y, torch.full_like(y, -1.0)], -1)
    d = torch.tensor([0.02, 0.03, 1.0], dtype=F64)
    d = (d / d.norm()).expand(7, 3)
    return Rays(o, d, 587.0)


@pytest.mark.parametrize("name,h", [("c", 1e-7), ("k", 1e-5), ("cx", 1e-7), ("kx", 1e-5)])
def test_trace_gradients_match_central_differences(name, h):
    """d/dθ of (Σ (x² + y²) on the image + Σ opl) through the lens, against central differences
    (float64), for c_y, k_y, c_x and k_x."""
    def q(delta):
        v = {"c": CY, "k": KY, "cx": CX, "kx": KX}
        v[name] += delta
        lens, s = _lens(v["c"], v["k"], v["cx"], v["kx"])
        p = getattr(s, name)
        p.requires_grad_(True)
        out = lens.trace_to_sensor(_rays())
        assert out.valid.all()
        return (out.o[:, :2] ** 2).sum() + out.opl.sum(), p

    v, p = q(0.0)
    ad, = torch.autograd.grad(v, p)
    fd = float((q(h)[0] - q(-h)[0]).detach()) / (2 * h)
    assert abs(fd) > 1e-3
    assert float(ad) == pytest.approx(fd, rel=2e-6)


def test_x_and_y_focus_apart():
    """An anamorphic check through the tracer: a thin fan in x focuses where the x curvature
    puts it and a fan in y where the y curvature does (paraxial data take y)."""
    lens, _ = _lens(cy=1 / 30.0, ky=0.0, cx=1 / 60.0, kx=0.0)
    h, w = 1e-4, float(lens.spec.primary_wavelength_nm)

    def focus(ax):
        o = torch.zeros(1, 3, dtype=F64)
        o[0, ax], o[0, 2] = h, -1.0
        out = lens.trace(Rays(o, torch.tensor([[0.0, 0.0, 1.0]], dtype=F64), w))
        return -h / float(out.d[0, ax] / out.d[0, 2])

    n = float(ModelGlass(1.6, 40.0).n(w))
    assert focus(1) == pytest.approx(1 / ((n - 1) / 30.0), rel=1e-6)
    assert focus(0) == pytest.approx(1 / ((n - 1) / 60.0), rel=1e-6)
    assert float(paraxial(lens).efl) == pytest.approx(focus(1), rel=1e-6)


def test_traces_eager_under_the_compiled_tracer_and_saves():
    """No compiled Newton kernels: the fused tracer leaves the surface to the eager path; the
    lens file round-trips bit for bit, and the design step scale of c_x is that of c_y."""
    from deeplens.optics.parameters import parameter_scale

    lens, s = _lens()
    assert fused_kind(lens, 0) is None
    d = lens_to_dict(lens)
    assert d["surfaces"][0] == {"type": "biconic", "semi_diameter_mm": 6.0,
                                "curvature_per_mm": CY, "conic": KY,
                                "curvature_x_per_mm": CX, "conic_x": KX,
                                "distance_mm": 0.0, "material": d["surfaces"][0]["material"]}
    back = lens_from_dict(d)
    assert lens_to_dict(back) == d
    with torch.no_grad():
        a = lens.trace_to_sensor(_rays())
        b = back.trace_to_sensor(_rays())
    assert torch.equal(a.o, b.o)
    assert parameter_scale(lens, "surfaces.0.cx") == parameter_scale(lens, "surfaces.0.c") == 18.0
    # the conic scales are ∂(rim sag)/∂k of each section, by autograd of the surface's own sag
    R = torch.tensor(6.0, dtype=F64)
    for name, at in (("k", (R * 0, R)), ("kx", (R, R * 0))):
        p = getattr(s, name)
        p.requires_grad_(True)
        g, = torch.autograd.grad(s.sag(*at), p)
        p.requires_grad_(False)
        assert parameter_scale(lens, f"surfaces.0.{name}") == pytest.approx(abs(float(g)),
                                                                           rel=1e-12)


def test_optilands_biconic_agrees_on_the_axes_and_where_one_curvature_is_zero():
    """optiland's ``BiconicGeometry`` is the sum of an x conic and a y conic: it agrees with
    OpticStudio's biconic (deeplens') on the two axes and everywhere when c_x or c_y is 0 (a
    cylinder, both ways round), and differs off the axes otherwise (why the .zmx oracle uses
    OpticStudio's formula, not optiland's geometry)."""
    pytest.importorskip("optiland")
    from optiland.coordinate_system import CoordinateSystem
    from optiland.geometries import BiconicGeometry

    x, y = _points(100, seed=5)
    for cy, cx in ((CY, 0.0), (0.0, CX)):
        # optiland's argument order is (radius_x, radius_y, conic_x, conic_y)
        ol = BiconicGeometry(CoordinateSystem(), 1 / cx if cx else math.inf,
                             1 / cy if cy else math.inf, KX, KY)
        z_ol = np.asarray(ol.sag(x, y), dtype=float)
        z_dl = Biconic(cy, 6.5, cx, KY, KX).sag(torch.tensor(x), torch.tensor(y)).numpy()
        assert np.abs(z_ol - z_dl).max() < 1e-14
        assert np.abs(z_dl).max() > 0.1
    ol = BiconicGeometry(CoordinateSystem(), 1 / CX, 1 / CY, KX, KY)
    s = Biconic(CY, 6.5, CX, KY, KX)
    r = np.linspace(-6, 6, 13)
    t = torch.tensor(r)
    assert np.abs(np.asarray(ol.sag(r, 0 * r)) - s.sag(t, 0 * t).numpy()).max() < 1e-14
    assert np.abs(np.asarray(ol.sag(0 * r, r)) - s.sag(0 * t, t).numpy()).max() < 1e-14
    off = np.abs(np.asarray(ol.sag(x, y), dtype=float)
                 - s.sag(torch.tensor(x), torch.tensor(y)).numpy()).max()
    assert off > 1e-3
