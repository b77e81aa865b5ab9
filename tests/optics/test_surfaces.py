"""Surfaces: sag and implicit-function values against independent closed forms, analytic
derivatives against autograd, domains and apertures, finiteness outside the domain, and
constructor errors."""

import math

import pytest
import torch

from deeplens.optics.surfaces import (
    SURFACE_TYPES, Aperture, Asphere, BSpline, Cylinder, Plane, Sphere, Toroid, XYPolynomial,
)
from deeplens.optics.surfaces.xy_polynomial import xy_terms

F64 = torch.float64


def _points(n, r, seed=0, dtype=F64):
    g = torch.Generator().manual_seed(seed)
    rr = r * torch.sqrt(torch.rand(n, generator=g, dtype=F64))
    phi = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    return (rr * torch.cos(phi)).to(dtype), (rr * torch.sin(phi)).to(dtype)


def _bspline_grid(n, L):
    """Positions of the control points: basis p is centred on the knot -L + (p - 1) h."""
    h = 2 * L / (n - 3)
    return -L + (torch.arange(n, dtype=F64) - 1) * h, h


def _surfaces():
    g = torch.Generator().manual_seed(3)
    return {
        "sphere": Sphere(1 / 12.0, 8.0),
        "concave": Sphere(-1 / 20.0, 8.0),
        "conic": Asphere(1 / 15.0, 8.0, conic=-2.2),
        "oblate": Asphere(1 / 20.0, 8.0, conic=1.5),
        "asphere": Asphere(1 / 15.0, 8.0, conic=-0.6, coefficients=[2e-4, -3e-6, 1e-8, 4e-11]),
        "flat_asphere": Asphere(0.0, 8.0, coefficients=[1e-4]),
        "xy_b0": XYPolynomial(8.0, [0.01, 0.02, -0.01, 0.03, 0.005, 0.02, 1e-3, -2e-3, 5e-4,
                                    1e-3], b=0.0),
        "xy_b": XYPolynomial(8.0, [0.01, 0.02, -0.01, 0.03, 0.005, 0.02, 1e-3, -2e-3, 5e-4,
                                   1e-3], b=0.04),
        "bspline": BSpline(8.0, 0.3 * torch.randn(7, 9, generator=g, dtype=F64)),
        "plane": Plane(8.0),
        "cylinder": Cylinder(1 / 15.0, 8.0, conic=-0.6, coefficients=[1e-3, 2e-4, -3e-6]),
        "cylinder_rect": Cylinder(-1 / 20.0, 8.0, half_widths=(7.0, 5.0)),
        "toroid": Toroid(1 / 15.0, 8.0, 25.0, conic=-0.6, coefficients=[1e-3, 2e-4]),
        "toroid_saddle": Toroid(-1 / 20.0, 8.0, 30.0),
    }


@pytest.mark.parametrize("name", list(_surfaces()))
def test_analytic_derivatives_match_autograd(name):
    s = _surfaces()[name]
    x, y = _points(300, 7.5, seed=1)
    z = (s.sag(x, y) + 0.3 * torch.sin(3 * x)).requires_grad_(True)  # on and off the surface
    x.requires_grad_(True)
    y.requires_grad_(True)
    fx, fy, fz = s.f_grad(x, y, z)
    gx, gy, gz = torch.autograd.grad(s.f(x, y, z).sum(), (x, y, z), allow_unused=True,
                                     materialize_grads=True)
    for a, b in ((fx, gx), (fy, gy), (fz, gz)):
        assert float((a - b).detach().abs().max()) < 1e-12
    if hasattr(s, "sag_grad") and not s.is_flat:
        sx, sy = s.sag_grad(x, y)
        hx, hy = torch.autograd.grad(s.sag(x, y).sum(), (x, y), allow_unused=True,
                                     materialize_grads=True)
        assert float((sx - hx).detach().abs().max()) < 1e-12
        assert float((sy - hy).detach().abs().max()) < 1e-12


@pytest.mark.parametrize("name", list(_surfaces()))
def test_sag_is_a_root_of_f(name):
    s = _surfaces()[name]
    x, y = _points(300, 7.5, seed=2)
    z = s.sag(x, y)
    assert float(s.f(x, y, z).abs().max()) < 1e-14


@pytest.mark.parametrize("R", [12.0, -20.0, 9.0])
def test_sphere_sag_closed_form(R):
    s = Sphere(1 / R, 0.99 * abs(R))
    x, y = _points(500, 0.99 * abs(R), seed=3)
    r2 = x * x + y * y
    expect = R - math.copysign(1.0, R) * torch.sqrt(R * R - r2)
    assert float((s.sag(x, y) - expect).abs().max()) < 1e-12


@pytest.mark.parametrize("k", [-2.2, -1.0, -0.5, 0.7, 3.0])
def test_conic_sag_satisfies_quadric(k):
    """A conic of radius R and conic constant k is the quadric r^2 - 2 R z + (1 + k) z^2 = 0."""
    R = 15.0
    sd = 0.95 * R / math.sqrt(1 + k) if k > -1 else 10.0
    s = Asphere(1 / R, sd, conic=k)
    x, y = _points(500, sd, seed=4)
    z = s.sag(x, y)
    q = x * x + y * y - 2 * R * z + (1 + k) * z * z
    assert float(q.abs().max()) < 1e-11
    if k == -1.0:  # paraboloid
        assert torch.allclose(z, (x * x + y * y) / (2 * R), atol=1e-14)


def test_asphere_polynomial_terms():
    coeffs = [2e-4, -3e-6, 1e-8, 4e-11, -1e-13]
    s = Asphere(1 / 15.0, 8.0, conic=-0.6, coefficients=coeffs)
    base = Asphere(1 / 15.0, 8.0, conic=-0.6)
    x, y = _points(300, 8.0, seed=5)
    r2 = x * x + y * y
    poly = sum(a * r2 ** (i + 2) for i, a in enumerate(coeffs))
    assert float((s.sag(x, y) - base.sag(x, y) - poly).abs().max()) < 1e-13


def test_xy_term_order():
    assert xy_terms(2) == [(0, 0), (0, 1), (1, 0), (0, 2), (1, 1), (2, 0)]
    assert len(xy_terms(5)) == 21


def test_xy_polynomial_explicit_and_implicit():
    coeffs = [0.01, 0.02, -0.01, 0.03, 0.005, 0.02, 1e-3, -2e-3, 5e-4, 1e-3]
    x, y = _points(300, 8.0, seed=6)
    # b = 0: z = sum a_m x^i y^j in the documented order 1, y, x, y^2, xy, x^2, y^3, xy^2, ...
    monomials = [torch.ones_like(x), y, x, y * y, x * y, x * x, y ** 3, x * y * y, x * x * y,
                 x ** 3]
    P = sum(a * m for a, m in zip(coeffs, monomials))
    s0 = XYPolynomial(8.0, coeffs, b=0.0)
    assert float((s0.sag(x, y) - P).abs().max()) < 1e-15
    # b != 0: the near root of b z^2 - z + P = 0
    b = 0.04
    sb = XYPolynomial(8.0, coeffs, b=b)
    near = (1 - torch.sqrt(1 - 4 * b * P)) / (2 * b)
    assert float((sb.sag(x, y) - near).abs().max()) < 1e-14
    # the vertex curvature of z ~ a_x2 x^2 + a_y2 y^2 is the mean of 2 a_x2 and 2 a_y2
    assert float(sb.paraxial_curvature()) == pytest.approx(0.02 + 0.03, abs=1e-15)


def test_xy_domain_with_b():
    s = XYPolynomial(8.0, [0.0, 0.0, 0.0, 0.5, 0.0, 0.5], b=0.5)  # 1 - 4 b P >= 0: r^2 <= 1
    x = torch.tensor([0.0, 0.9, 1.1], dtype=F64)
    assert s.in_domain(x, torch.zeros_like(x)).tolist() == [True, True, False]
    assert bool(torch.isfinite(s.sag(x, torch.zeros_like(x))).all())


def test_bspline_reproduces_constant_linear_and_quadratic():
    n, L = 9, 5.0
    v, h = _bspline_grid(n, L)
    x, y = _points(400, 5.0 * 0.999, seed=7)
    keep = (x.abs() <= L) & (y.abs() <= L)
    x, y = x[keep], y[keep]
    X, Y = torch.meshgrid(v, v, indexing="ij")
    ones = BSpline(L, torch.ones(n, n, dtype=F64))
    assert float((ones.sag(x, y) - 1).abs().max()) < 1e-14  # partition of unity
    lin = BSpline(L, 2 * X - 3 * Y)
    assert float((lin.sag(x, y) - (2 * x - 3 * y)).abs().max()) < 1e-13  # linear precision
    sx, sy = lin.sag_grad(x, y)
    assert float((sx - 2).abs().max()) < 1e-13 and float((sy + 3).abs().max()) < 1e-13
    # sum_p t_p^2 N_p(x) = x^2 + h^2 / 3 (the variance of the uniform cubic B-spline)
    c = 0.05
    quad = BSpline(L, 0.5 * c * (X ** 2 + Y ** 2))
    expect = 0.5 * c * (x * x + y * y + 2 * h * h / 3)
    assert float((quad.sag(x, y) - expect).abs().max()) < 1e-13
    assert float(quad.paraxial_curvature()) == pytest.approx(c, rel=1e-9)


def test_bspline_c2_across_knots():
    s = _surfaces()["bspline"]
    L = 8.0
    h = 2 * L / (7 - 3)
    knots = torch.tensor([-L + h, -L + 2 * h, -L + 3 * h], dtype=F64)
    e = 1e-7
    y = torch.full_like(knots, 1.3)
    for k in (0, 1, 2):
        a, b = s.sag(knots - e, y), s.sag(knots + e, y)
        assert float((a - b).abs().max()) < 1e-6
        da, db = s.sag_grad(knots - e, y)[0], s.sag_grad(knots + e, y)[0]
        assert float((da - db).abs().max()) < 1e-5


def test_bspline_domain_is_the_square():
    s = BSpline(4.0, torch.zeros(5, 5, dtype=F64))
    x = torch.tensor([3.9, 4.1, 3.9, -4.0], dtype=F64)
    y = torch.tensor([3.9, 0.0, -4.2, 4.0], dtype=F64)
    assert s.in_domain(x, y).tolist() == [True, False, False, True]


def test_conic_domain_and_check():
    s = Asphere(1 / 10.0, 4.0, conic=3.0)  # defined for r < 10 / 2 = 5 mm
    r = torch.tensor([4.99, 5.01], dtype=F64)
    assert s.in_domain(r, torch.zeros_like(r)).tolist() == [True, False]
    s.check()
    with pytest.raises(ValueError, match="domain"):
        Asphere(1 / 10.0, 5.5, conic=3.0).check(where="surface 2: ")


def test_apertures():
    circ = Aperture(2.0)
    x = torch.tensor([1.9, 2.1, 1.5], dtype=F64)
    y = torch.tensor([0.0, 0.0, 1.5], dtype=F64)
    assert circ.in_aperture(x, y).tolist() == [True, False, False]
    rect = Aperture(shape="rect", half_width_x=2.0, half_width_y=1.0)
    assert rect.in_aperture(x, y).tolist() == [True, False, False]
    assert rect.in_aperture(torch.tensor([1.9]), torch.tensor([0.9])).tolist() == [True]
    assert float(rect.semi_diameter) == pytest.approx(math.sqrt(5.0))
    assert circ.is_flat and Plane(1.0).is_flat and not Sphere(0.1, 1.0).is_flat


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("name", list(_surfaces()) + ["steep", "xy_b_out"])
def test_finite_outside_domain_with_finite_derivatives(name, dtype):
    """The tracer evaluates surfaces on invalid rays too (masked afterwards): values and
    derivatives, in x and in every parameter, must stay finite up to 50 semi-diameters away."""
    extra = {"steep": Sphere(1 / 8.0, 7.99),
             "xy_b_out": XYPolynomial(8.0, [0.0, 0.0, 0.0, 0.5, 0.0, 0.5], b=0.5)}
    s = extra[name] if name in extra else _surfaces()[name]
    s = s.to(dtype)
    params = list(s.parameters())
    for p in params:
        p.requires_grad_(True)
    x, y = _points(400, 400.0, seed=8, dtype=dtype)
    x = torch.cat([x, torch.tensor([0.0, 8.0, 7.99999, -8.0], dtype=dtype)])
    y = torch.cat([y, torch.tensor([8.0, 0.0, 0.0, 8.0], dtype=dtype)])
    x.requires_grad_(True)
    z = torch.linspace(-5, 5, x.shape[0], dtype=dtype)
    outs = [s.f(x, y, z), *s.f_grad(x, y, z), s.sag(x, y)]
    for o in outs:
        assert bool(torch.isfinite(o).all())
    total = sum(o.sum() for o in outs)
    if total.requires_grad:
        grads = torch.autograd.grad(total, params + [x], allow_unused=True)
        for g in grads:
            assert g is None or bool(torch.isfinite(g).all())


def test_parameters_are_frozen_float64():
    for s in _surfaces().values():
        for p in s.parameters():
            assert p.dtype == F64 and not p.requires_grad


def test_registry():
    assert {"asphere", "plane", "aperture", "xy_polynomial", "bspline"} <= set(SURFACE_TYPES)
    assert SURFACE_TYPES["asphere"] is Asphere


def test_constructor_errors():
    with pytest.raises(ValueError, match="semi_diameter"):
        Sphere(0.1, 0.0)
    with pytest.raises(ValueError, match="semi_diameter"):
        Plane(float("nan"))
    with pytest.raises(ValueError, match="at most 9"):
        Asphere(0.1, 1.0, coefficients=[0.0] * 10)
    with pytest.raises(ValueError, match="finite"):
        Asphere(float("inf"), 1.0)
    with pytest.raises(ValueError, match=r"\(J\+1\)\(J\+2\)/2"):
        XYPolynomial(1.0, [0.0] * 4)
    with pytest.raises(ValueError, match="4x4"):
        BSpline(1.0, torch.zeros(3, 5))
    with pytest.raises(ValueError, match="shape"):
        Aperture(1.0, shape="hexagon")
    with pytest.raises(ValueError, match="half_width"):
        Aperture(shape="rect", half_width_x=1.0)


# ---------------------------------------------------------------- issue 12, defect 5
def _folded_xy(sd=7.0):
    """z = 0.2 r^2 with b = 0.06/mm: 1 - 4 b P = 0 (the fold) at r = sqrt(1 / 0.048) = 4.564 mm."""
    return XYPolynomial(sd, [0.0, 0.0, 0.0, 0.2, 0.0, 0.2], b=0.06)


def test_xy_polynomial_aperture_beyond_its_fold_is_rejected():
    """Regression (issue 12, defect 5): a clear aperture beyond the fold of 1 - 4 b P was
    accepted (an asphere's conic domain is checked); the message names the fold radius."""
    with pytest.raises(ValueError, match=r"surface 3: semi-diameter 7 mm .* fold\) by r = 4\.5"):
        _folded_xy(7.0).check(where="surface 3: ")
    _folded_xy(4.5).check()  # inside the fold
    # only the extreme of P over the disk counts: a tilted P folds first along +y
    XYPolynomial(4.5, [0.0, 0.0, 0.0, 0.2, 0.0, 0.2], b=-0.06).check()  # b P < 0: no fold
    with pytest.raises(ValueError, match="fold"):
        XYPolynomial(4.5, [0.0, 0.2, 0.0, 0.2, 0.0, 0.2], b=0.06).check()


def test_xy_polynomial_hits_lie_on_the_vertex_sheet():
    """Regression (issue 12, defect 5): b z^2 + P - z = 0 has a second root beyond the fold
    plane z = 1/2b; Newton reached it for about 2 % of the rays entering near or beyond the
    fold and kept them as valid hits off the sag.  Every valid hit must lie on the sag."""
    from deeplens.optics.intersect import intersect

    s = _folded_xy(7.0)
    g = torch.Generator().manual_seed(0)
    n = 5000
    r = 7.0 * torch.sqrt(torch.rand(n, generator=g, dtype=F64))
    ph = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    th = 0.3 * torch.rand(n, generator=g, dtype=F64)
    ps = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    d = torch.stack([th.sin() * ps.cos(), th.sin() * ps.sin(), th.cos()], -1)
    o = torch.stack([r * ph.cos(), r * ph.sin(), torch.zeros_like(r)], -1) - 3.0 / d[:, 2:] * d
    t, x, ok = intersect(s, o, d, torch.ones(n, dtype=torch.bool))
    assert int(ok.sum()) > 1500
    off = (x[:, 2] - s.sag(x[:, 0], x[:, 1])).abs()[ok]
    assert float(off.max()) < 1e-8, f"{int((off > 1e-8).sum())} hits on the far sheet"


def test_cylinder_closed_form_and_aperture():
    """z depends on y only: the conic section plus a2 y² + a4 y⁴; the rectangle clips."""
    c, k, a2, a4 = 1 / 15.0, -0.6, 1e-3, 2e-4
    s = Cylinder(c, 8.0, conic=k, coefficients=[a2, a4], half_widths=(7.0, 5.0))
    y = torch.tensor([0.0, 1.0, -3.0, 4.5], dtype=F64)
    for x in (0.0, 2.5, -6.0):
        xs = torch.full_like(y, x)
        want = c * y ** 2 / (1 + torch.sqrt(1 - (1 + k) * c * c * y ** 2)) + a2 * y ** 2 + a4 * y ** 4
        torch.testing.assert_close(s.sag(xs, y), want, rtol=0, atol=1e-15)
    assert float(s.paraxial_curvature()) == pytest.approx(c + 2 * a2, rel=1e-15)
    inside = s.in_aperture(torch.tensor([6.9, 7.1, 0.0, 0.0], dtype=F64),
                           torch.tensor([0.0, 0.0, 4.9, 5.1], dtype=F64))
    assert inside.tolist() == [True, False, True, False]
    with pytest.raises(ValueError, match="beyond the domain"):
        Cylinder(1 / 4.0, 8.0, half_widths=(3.0, 5.0)).check()
    d = s.to_dict()
    assert Cylinder.from_dict(_Entry(d), d["semi_diameter_mm"]).to_dict() == d


class _Entry:
    """The lens-file reader's entry interface, over a plain dict."""

    def __init__(self, d):
        self.d = d

    def has(self, key):
        return key in self.d

    def get(self, key, kind="number", default=None):
        return self.d.get(key, default)

    def fail(self, key, msg):
        raise ValueError(f"{key}: {msg}")


def test_aperture_central_obscuration():
    a = Aperture(5.0, obscuration=2.0)
    x = torch.tensor([0.0, 1.99, 2.01, 4.99, 5.01], dtype=F64)
    assert a.in_aperture(x, torch.zeros_like(x)).tolist() == [False, False, True, True, False]
    d = a.to_dict()
    assert d["obscuration_mm"] == 2.0
    assert float(Aperture.from_dict(_Entry(d), 5.0).obscuration) == 2.0
    assert "obscuration_mm" not in Aperture(5.0).to_dict()
    for bad in ((5.0, "circle", 6.0), (5.0, "circle", -1.0)):
        with pytest.raises(ValueError, match="central obscuration"):
            Aperture(bad[0], bad[1], obscuration=bad[2])
    with pytest.raises(ValueError, match="central obscuration"):
        Aperture(None, "rect", 2.0, 1.0, obscuration=0.5)


def test_asphere_clear_radius_narrower_than_its_semi_diameter():
    """A clear aperture narrower than the semi-diameter (a CLAP under an EPD-sized stop): rays
    beyond it are blocked, the semi-diameter (the paraxial stop radius) stays; saved in the
    lens file, not in ``state_dict``."""

    s = Asphere(0.05, 7.5, clear_radius=6.75)
    x = torch.tensor([0.0, 6.7499, 6.7501, 7.4], dtype=F64)
    assert s.in_aperture(x, torch.zeros_like(x)).tolist() == [True, True, False, False]
    assert s.in_aperture(torch.zeros_like(x), x).tolist() == [True, True, False, False]
    assert float(s.semi_diameter) == 7.5 and "clear_radius" not in s.state_dict()
    d = s.to_dict()
    assert d["clear_radius_mm"] == 6.75
    assert float(Asphere.from_dict(_Entry(d), 7.5).clear_radius) == 6.75
    assert "clear_radius_mm" not in Asphere(0.05, 7.5).to_dict()
    assert Asphere(0.05, 7.5).in_aperture(x, torch.zeros_like(x)).tolist() == [True] * 4
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="clear radius"):
            Asphere(0.05, 7.5, clear_radius=bad)
    with pytest.raises(ValueError, match="clear radius"):
        Asphere(0.05, 7.5, obscuration=3.0, clear_radius=2.0).check()


def test_toroid_closed_forms():
    """The toroid's sections and special cases: with ``R = 1/c`` (k = 0) the profile circle
    turns about its own centre, a sphere; the x section at y = 0 is a circle of radius ``R``;
    the y section is the cylinder's profile; ``x^2 >= rho^2`` is outside the domain."""
    x, y = _points(500, 7.5, seed=11)
    for R in (12.0, -20.0):
        assert float((Toroid(1 / R, 8.0, R).sag(x, y) - Sphere(1 / R, 8.0).sag(x, y)).abs().max()
                     ) < 1e-12
    t = Toroid(1 / 15.0, 8.0, 25.0, conic=-0.6, coefficients=[1e-3, 2e-4])
    zero = torch.zeros_like(x)
    circle = 25.0 - torch.sqrt(25.0 ** 2 - x * x)
    assert float((t.sag(x, zero) - circle).abs().max()) < 1e-12
    cyl = Cylinder(1 / 15.0, 8.0, conic=-0.6, coefficients=[1e-3, 2e-4])
    assert float((t.sag(zero, y) - cyl.sag(zero, y)).abs().max()) < 1e-14
    # a torus point: its distance from the axis (x = 0, z = R) equals rho = R - z_y(y)
    z = t.sag(x, y)
    rho = 25.0 - cyl.sag(zero, y)
    assert float((torch.sqrt(x * x + (25.0 - z) ** 2) - rho).abs().max()) < 1e-12
    small = Toroid(0.0, 8.0, 3.0)
    xx = torch.tensor([2.9, 3.1], dtype=F64)
    assert small.in_domain(xx, torch.zeros_like(xx)).tolist() == [True, False]


def test_toroid_slopes_match_central_differences():
    t = Toroid(1 / 15.0, 8.0, -25.0, conic=-0.6, coefficients=[1e-3, 2e-4])
    x, y = _points(200, 7.5, seed=12)
    h = 1e-6
    sx, sy = t.sag_grad(x, y)
    fx = (t.sag(x + h, y) - t.sag(x - h, y)) / (2 * h)
    fy = (t.sag(x, y + h) - t.sag(x, y - h)) / (2 * h)
    assert float((sx - fx).abs().max()) < 1e-8 and float((sy - fy).abs().max()) < 1e-8


def test_toroid_file_entry_and_checks():
    t = Toroid(1 / 15.0, 8.0, 25.0, conic=-0.6, coefficients=[1e-3], half_widths=(6.0, 5.0))
    d = t.to_dict()
    assert d["type"] == "toroid" and d["radius_of_rotation_mm"] == 25.0
    back = Toroid.from_dict(_Entry(d), 8.0)
    x, y = _points(100, 5.0, seed=13)
    assert torch.equal(back.sag(x, y), t.sag(x, y))
    for bad in (0.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="radius of rotation"):
            Toroid(1 / 15.0, 8.0, bad)
    with pytest.raises(ValueError, match="radius of rotation"):
        Toroid(0.0, 8.0, 7.0).check()


def test_asphere_decentred_clear_aperture():
    """An off-axis opening: rays are kept within ``clear_radius`` of ``clear_decenter`` (and
    within the semi-diameter about the vertex); saved in the lens file."""
    s = Asphere(-1 / 190.6, 216.0, conic=-1.0, clear_radius=25.4, clear_decenter=(0.0, 190.6))
    y = torch.tensor([0.0, 165.3, 165.1, 215.9, 216.1, -190.6], dtype=F64)
    assert s.in_aperture(torch.zeros_like(y), y).tolist() == [False, True, False, True, False,
                                                              False]
    x = torch.tensor([25.3, 25.5], dtype=F64)
    assert s.in_aperture(x, torch.full_like(x, 190.6)).tolist() == [True, False]
    d = s.to_dict()
    assert d["clear_decenter_mm"] == [0.0, 190.6] and d["clear_radius_mm"] == 25.4
    back = Asphere.from_dict(_Entry(d), 216.0)
    assert back.clear_decenter.tolist() == [0.0, 190.6]
    assert "clear_decenter_mm" not in Asphere(0.05, 7.5, clear_radius=6.0).to_dict()
    with pytest.raises(ValueError, match="needs a clear_radius"):
        Asphere(0.05, 7.5, clear_decenter=(1.0, 0.0))
    with pytest.raises(ValueError, match="two finite numbers"):
        Asphere(0.05, 7.5, clear_radius=2.0, clear_decenter=(math.nan, 0.0))


def test_asphere_rectangular_decentred_opening():
    """A rectangular opening (Zemax's SQAP, with OBDC an off-axis mirror's): rays are kept
    within the half-widths of ``clear_rect`` about ``clear_decenter``; the clear radius defaults
    to its half-diagonal; saved in the lens file."""
    s = Asphere(-2.8e-4, 900.0, clear_rect=(424.0, 192.0), clear_decenter=(0.0, -397.0))
    assert float(s.clear_radius) == math.hypot(424.0, 192.0)
    x = torch.tensor([0.0, 423.9, 424.1, 0.0, 0.0, 0.0, 0.0], dtype=F64)
    y = torch.tensor([-397.0, -397.0, -397.0, -205.1, -204.9, -588.9, -589.1], dtype=F64)
    assert s.in_aperture(x, y).tolist() == [True, True, False, True, False, True, False]
    d = s.to_dict()
    assert d["clear_rect_mm"] == [424.0, 192.0] and d["clear_decenter_mm"] == [0.0, -397.0]
    back = Asphere.from_dict(_Entry(d), 900.0)
    assert back.clear_rect.tolist() == [424.0, 192.0]
    assert torch.equal(back.in_aperture(x, y), s.in_aperture(x, y))
    assert "clear_rect_mm" not in Asphere(0.05, 7.5, clear_radius=6.0).to_dict()
    for bad in ((0.0, 1.0), (1.0,), (math.inf, 1.0)):
        with pytest.raises(ValueError, match="clear_rect"):
            Asphere(0.05, 7.5, clear_rect=bad)
