"""The grid sag surface (:class:`~deeplens.optics.surfaces.GridSag`, OpticStudio's ``GRID_SAG``):
the bicubic interpolant reproduces bicubic polynomials exactly and a quartic with the Hermite
remainder, a sphere sampled with its exact derivatives within the bicubic error bound; slopes and
trace gradients (in a node's sag and slope) against central differences in float64; a flat-base
grid of a sphere traces like the sphere, its paraxial curvature the closed form of the
interpolant's; outside the grid rays miss; the lens file round-trips."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import GridSag, Plane, Sphere
from deeplens.optics.surfaces.grid_sag import grid_slopes
from deeplens.optics.tracer import fused_kind

F64 = torch.float64


def nodes(nx, ny, hx, hy, dec=(0.0, 0.0)):
    """``(X, Y)`` ``(ny, nx)`` node coordinates (rows of rising y), centred on ``dec``."""
    x = dec[0] + (torch.arange(nx, dtype=F64) - 0.5 * (nx - 1)) * hx
    y = dec[1] + (torch.arange(ny, dtype=F64) - 0.5 * (ny - 1)) * hy
    Y, X = torch.meshgrid(y, x, indexing="ij")
    return X, Y


def sampled(f, nx, ny, hx, hy, dec=(0.0, 0.0), curvature=0.0, sd=10.0, **kw):
    """A :class:`GridSag` whose nodes carry ``f``'s value, slopes and cross derivative
    (``f(X, Y) -> (z, z_x, z_y, z_xy)``)."""
    X, Y = nodes(nx, ny, hx, hy, dec)
    z, zx, zy, zxy = f(X, Y)
    return GridSag(curvature, sd, (hx, hy), z, zx, zy, zxy, decenter=dec, **kw)


def sphere(c):
    def f(X, Y):
        q = torch.sqrt(1 - c * c * (X * X + Y * Y))
        return (c * (X * X + Y * Y) / (1 + q), c * X / q, c * Y / q, c ** 3 * X * Y / q ** 3)
    return f


def inside(n, s, seed=0):
    """``n`` random points inside surface ``s``'s grid."""
    (x0, x1), (y0, y1) = s.grid_extent()
    g = torch.Generator().manual_seed(seed)
    return (x0 + (x1 - x0) * torch.rand(n, generator=g, dtype=F64),
            y0 + (y1 - y0) * torch.rand(n, generator=g, dtype=F64))


# a bicubic polynomial sum a_pq x^p y^q (p, q <= 3) and its derivatives
RNG = np.random.default_rng(3)
A = torch.tensor(RNG.normal(size=(4, 4)) * [[1, 0.3, 0.1, 0.03]] * np.array([[1], [0.3], [0.1],
                                                                             [0.03]]), dtype=F64)


def bicubic(X, Y):
    P = [torch.ones_like(X), X, X * X, X ** 3]
    Q = [torch.ones_like(Y), Y, Y * Y, Y ** 3]
    dP = [torch.zeros_like(X), torch.ones_like(X), 2 * X, 3 * X * X]
    dQ = [torch.zeros_like(Y), torch.ones_like(Y), 2 * Y, 3 * Y * Y]
    z = sum(A[p, q] * P[p] * Q[q] for p in range(4) for q in range(4))
    zx = sum(A[p, q] * dP[p] * Q[q] for p in range(4) for q in range(4))
    zy = sum(A[p, q] * P[p] * dQ[q] for p in range(4) for q in range(4))
    zxy = sum(A[p, q] * dP[p] * dQ[q] for p in range(4) for q in range(4))
    return z, zx, zy, zxy


def test_reproduces_a_bicubic_polynomial_exactly():
    """Every polynomial of degree <= 3 in x and in y is reproduced with its slopes, on a
    non-square, unequally spaced, decentred grid (so that x and y cannot be taken for each
    other, nor a derivative for one per cell)."""
    s = sampled(bicubic, 7, 5, 0.8, 1.3, dec=(0.35, -0.2))
    x, y = inside(400, s)
    z, zx, zy, _ = bicubic(x, y)
    assert s.sag(x, y).tolist() == pytest.approx(z.tolist(), abs=1e-12)
    gx, gy = s.sag_grad(x, y)
    assert gx.tolist() == pytest.approx(zx.tolist(), abs=1e-12)
    assert gy.tolist() == pytest.approx(zy.tolist(), abs=1e-12)


def test_quartic_error_is_the_hermite_remainder():
    """For ``z = x⁴`` (exact derivatives) the interpolant misses by the cubic Hermite remainder
    ``(x − x_i)² (x − x_{i+1})²`` exactly (f⁗/4! = 1), whatever y."""
    s = sampled(lambda X, Y: (X ** 4, 4 * X ** 3, 0 * X, 0 * X), 6, 5, 1.1, 0.9, dec=(0.2, 0.0))
    x, y = inside(200, s, seed=1)
    (x0, _), _ = s.grid_extent()
    i = torch.clamp(torch.floor((x - x0) / 1.1), 0, 4)
    a = x0 + 1.1 * i
    ref = x ** 4 - (x - a) ** 2 * (x - a - 1.1) ** 2
    assert s.sag(x, y).tolist() == pytest.approx(ref.tolist(), abs=1e-12)


def _max_derivative(f, X, Y, nx_, ny_):
    """max |∂^(nx_+ny_) f / ∂x^nx_ ∂y^ny_| over the points ``(X, Y)`` (autograd, float64)."""
    X = X.clone().requires_grad_(True)
    Y = Y.clone().requires_grad_(True)
    g = f(X, Y)
    for var in [X] * nx_ + [Y] * ny_:
        g, = torch.autograd.grad(g.sum(), var, create_graph=True)
    return float(g.detach().abs().max())


def test_sphere_within_the_bicubic_error_bound():
    """A sphere (R 100 mm) sampled on OpticStudio's sample grid (25 x 25 at 0.875 mm) with its
    exact slopes and cross derivative: the sag error stays within the tensor-product Hermite bound
    ``h⁴/384 (max|z_xxxx| + max|z_yyyy| + h/4 max|z_xyyyy|)`` (module docstring of
    ``grid_sag``), the derivatives' maxima taken over a fine sample that includes the corners,
    where they peak; and it is not far below it (the bound is the error's size)."""
    c, h = 0.01, 0.875
    s = sampled(sphere(c), 25, 25, h, h)
    Xf, Yf = nodes(85, 85, 0.25, 0.25)

    def z(X, Y):
        r2 = X * X + Y * Y
        return c * r2 / (1 + torch.sqrt(1 - c * c * r2))

    bound = h ** 4 / 384 * (_max_derivative(z, Xf, Yf, 4, 0) + _max_derivative(z, Xf, Yf, 0, 4)
                            + h / 4 * _max_derivative(z, Xf, Yf, 1, 4))
    Xe, Ye = nodes(200, 200, 21.0 / 199, 21.0 / 199)
    err = float((s.sag(Xe, Ye) - z(Xe, Ye)).abs().max())
    assert err <= bound
    assert err > bound / 20


def test_slopes_match_central_differences():
    """``sag_grad`` against central differences of ``sag`` (float64, step 1e-6 mm: truncation
    ~1e-12, rounding ~1e-10), at points off the grid lines (where the curvature jumps)."""
    X, Y = nodes(9, 8, 1.2, 1.0, dec=(0.1, 0.3))
    g = torch.Generator().manual_seed(5)
    bump = 0.05 * torch.randn(X.shape, generator=g, dtype=F64)

    def f(X, Y):
        z, zx, zy, zxy = sphere(0.02)(X, Y)
        return z + bump, zx + bump.roll(1, 0), zy - bump.roll(1, 1), zxy + 0.1 * bump
    s = sampled(f, 9, 8, 1.2, 1.0, dec=(0.1, 0.3), curvature=0.01, conic=-0.5,
                coefficients=[1e-3, -2e-5])
    x, y = inside(300, s, seed=2)
    (x0, _), (y0, _) = s.grid_extent()
    off = ((((x - x0) / 1.2) % 1 - 0.5).abs() < 0.49) & ((((y - y0) / 1.0) % 1 - 0.5).abs() < 0.49)
    x, y = x[off], y[off]
    e = 1e-6
    fx = (s.sag(x + e, y) - s.sag(x - e, y)) / (2 * e)
    fy = (s.sag(x, y + e) - s.sag(x, y - e)) / (2 * e)
    gx, gy = s.sag_grad(x, y)
    assert (gx - fx).abs().max() < 1e-8 and (gy - fy).abs().max() < 1e-8
    assert float(gx.abs().max()) > 0.1


def test_sag_and_slopes_are_continuous_across_grid_lines():
    """On both sides of an x and a y grid line (1e-9 mm apart) sag and slopes agree to the
    step times the curvature, the curvature not (a C¹ interpolant)."""
    s = sampled(lambda X, Y: (X ** 4 + X * Y ** 3, 4 * X ** 3 + Y ** 3, 3 * X * Y ** 2, 3 * Y ** 2),
                6, 6, 1.0, 1.0)
    t = torch.linspace(-2.4, 2.4, 13, dtype=F64)
    for line in (0.5, -1.5):
        for xa, ya, xb, yb in ((line - 1e-9, t, line + 1e-9, t), (t, line - 1e-9, t, line + 1e-9)):
            xa, ya = torch.broadcast_tensors(torch.as_tensor(xa, dtype=F64),
                                             torch.as_tensor(ya, dtype=F64))
            xb, yb = torch.broadcast_tensors(torch.as_tensor(xb, dtype=F64),
                                             torch.as_tensor(yb, dtype=F64))
            assert (s.sag(xa, ya) - s.sag(xb, yb)).abs().max() < 1e-7
            for ga, gb in zip(s.sag_grad(xa, ya), s.sag_grad(xb, yb)):
                assert (ga - gb).abs().max() < 1e-7


def test_paraxial_curvature_of_a_sphere_grid_is_the_interpolants():
    """A flat base plus a grid of a sphere with a node at the vertex: on the grid line y = 0
    the interpolant is the 1-D Hermite cubic of ``c x²/2 + c³ x⁴/8 + c⁵ x⁶/16 + ...``, whose
    one-sided second derivatives at the node are both ``c − c³h²/4 − 3c⁵h⁴/8 + O(c⁷h⁶)``: the
    paraxial curvature.  With an even asphere base and a decentred grid (the vertex inside a
    cell), it is ``c + 2α_1`` plus the grid's mean second derivative there, checked against
    central differences of the slopes."""
    c, h = 0.01, 0.875
    s = sampled(sphere(c), 25, 25, h, h)
    ref = c - c ** 3 * h * h / 4 - 3 * c ** 5 * h ** 4 / 8
    assert float(s.paraxial_curvature()) == pytest.approx(ref, rel=1e-11)
    assert abs(float(s.paraxial_curvature()) - c) > 1e-8
    s2 = sampled(sphere(0.03), 9, 7, 1.1, 0.9, dec=(0.37, -0.21), curvature=0.01,
                 coefficients=[2e-3])
    e = 1e-5
    t = torch.tensor([-e, e], dtype=F64)
    gx, _ = s2.sag_grad(t, torch.zeros_like(t))
    _, gy = s2.sag_grad(torch.zeros_like(t), t)
    lap = 0.5 * ((gx[1] - gx[0]) + (gy[1] - gy[0])) / (2 * e)
    assert float(s2.paraxial_curvature()) == pytest.approx(float(lap), rel=1e-8)


def test_outside_the_grid_rays_miss():
    """Beyond the outer nodes the surface is not defined: ``in_domain`` is false, the sag stays
    finite (as every surface's must), and a ray that meets the base there is invalid."""
    s = sampled(sphere(0.01), 5, 5, 1.0, 1.0, sd=3.0)
    x = torch.tensor([0.0, 1.99, 2.01, 0.0, -2.01], dtype=F64)
    y = torch.tensor([0.0, 1.99, 0.0, -2.01, 0.0], dtype=F64)
    assert s.in_domain(x, y).tolist() == [True, True, False, False, False]
    assert torch.isfinite(s.sag(x * 10, y * 10)).all()
    lens = Lens([s, Plane(3.0)], [Air(), ModelGlass(1.5, 60.0), Air()], [0.0, 2.0], 20.0, 0)
    o = torch.tensor([[0.0, 1.0, -1.0], [0.0, 2.5, -1.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], dtype=F64)
    out = lens.trace_to_sensor(Rays(o, d, 587.0), options=TraceOptions(clip_aperture=False))
    assert out.valid.tolist() == [True, False]


def _bumpy(dz=0.0, dzx=0.0, node=(7, 7)):
    X, Y = nodes(13, 13, 1.75, 1.75)
    z, zx, zy, zxy = sphere(0.02)(X, Y)
    z = z + 0.01 * torch.sin(X) * torch.cos(0.7 * Y)
    z[node] += dz
    zx = zx.clone()
    zx[node] += dzx
    s = GridSag(0.0, 6.0, (1.75, 1.75), z, zx, zy, zxy)
    return Lens([s, Plane(6.0)], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 30.0, 0), s


def _rays():
    y = torch.linspace(-4.5, 4.5, 7, dtype=F64)
    o = torch.stack([0.3 * y, y, torch.full_like(y, -1.0)], -1)
    d = torch.tensor([0.01, 0.03, 1.0], dtype=F64)
    return Rays(o, (d / d.norm()).expand(7, 3), 587.0)


@pytest.mark.parametrize("which,h", [("z", 1e-6), ("zx", 1e-6)])
def test_trace_gradient_in_a_grid_value_matches_central_differences(which, h):
    """d/dθ of (Σ x_image² + Σ y_image² + Σ opl) through the lens, θ one node's sag (mm) or
    x slope, against central differences (float64; truncation ~h², rounding ~eps/h, both
    below 1e-6 relative)."""
    def q(delta):
        lens, s = _bumpy(**({"dz": delta} if which == "z" else {"dzx": delta}))
        p = s.grid_z if which == "z" else s.grid_dz_dx
        p.requires_grad_(True)
        out = lens.trace_to_sensor(_rays())
        assert out.valid.all()
        return (out.o[:, :2] ** 2).sum() + out.opl.sum(), p

    v, p = q(0.0)
    ad, = torch.autograd.grad(v, p)
    fd = float((q(h)[0] - q(-h)[0]).detach()) / (2 * h)
    assert abs(fd) > 1e-3
    assert float(ad[7, 7]) == pytest.approx(fd, rel=2e-6)
    assert float(ad[0, 0]) == 0.0   # no ray comes near the corner node


def test_a_flat_base_grid_of_a_sphere_traces_like_the_sphere():
    """A plano-convex singlet whose front is OpticStudio's sample grid (a flat base plus a
    sphere of R 100 mm, 25 x 25 nodes at 0.875 mm): real rays land where the Sphere's do within
    the grid's slope error (measured on the surface) times the path to the image, and the EFL is
    the sphere's times 1 / (1 − c²h²/4 − ...) (its paraxial curvature)."""
    c, h = 0.01, 0.875
    s = sampled(sphere(c), 25, 25, h, h, sd=9.5)
    mats = [Air(), ModelGlass(1.5168, 64.17), Air()]
    grid = Lens([s, Plane(9.5)], mats, [0.0, 5.0], 189.0, 0)
    ref = Lens([Sphere(c, 9.5), Plane(9.5)], mats, [0.0, 5.0], 189.0, 0)
    assert fused_kind(grid, 0) is None   # traced eagerly, between fused runs
    r = torch.linspace(-8.5, 8.5, 13, dtype=F64)
    o = torch.stack([0.4 * r, r, torch.full_like(r, -1.0)], -1)
    for d in ([0.0, 0.0, 1.0], [0.02, -0.05, 1.0]):
        d = torch.tensor(d, dtype=F64)
        rays = Rays(o, (d / d.norm()).expand(13, 3), 587.6)
        with torch.no_grad():
            a, b = grid.trace_to_sensor(rays), ref.trace_to_sensor(rays)
        assert a.valid.all() and b.valid.all()
        xs, ys = a.o[:, 0], a.o[:, 1]
        Xe, Ye = nodes(120, 120, 19.0 / 119, 19.0 / 119)
        gx, gy = s.sag_grad(Xe, Ye)
        ex, ey = sphere(c)(Xe, Ye)[1:3]
        slope_err = float(torch.maximum((gx - ex).abs(), (gy - ey).abs()).max())
        tol = 2 * 190.0 * slope_err + 1e-9     # (n − 1) Δslope ≈ Δangle, times the path
        assert (a.o - b.o).abs().max() < tol, (xs, ys)
    efl_g, efl_s = float(paraxial(grid).efl), float(paraxial(ref).efl)
    assert efl_s * c / float(s.paraxial_curvature()) == pytest.approx(efl_g, rel=1e-12)
    assert efl_g / efl_s - 1 == pytest.approx(c * c * h * h / 4, rel=1e-3)


def test_lens_file_round_trip_and_errors():
    """The JSON lens file keeps every grid (same class, same trace); a derivative grid of
    another shape is refused naming its field."""
    lens, s = _bumpy()
    d = lens_to_dict(lens)
    e = d["surfaces"][0]
    assert e["type"] == "grid_sag" and e["grid_spacing_mm"] == [1.75, 1.75]
    assert e["grid_sag_mm"] == s.grid_z.tolist() and e["grid_dz_dx"] == s.grid_dz_dx.tolist()
    back = lens_from_dict(d)
    assert type(back.surfaces[0]) is GridSag and lens_to_dict(back) == d
    with torch.no_grad():
        assert torch.equal(lens.trace_to_sensor(_rays()).o, back.trace_to_sensor(_rays()).o)
    d["surfaces"][0]["grid_dz_dy"] = [[0.0] * 13] * 12
    with pytest.raises(Exception, match=r"surfaces\[0\]\.grid_dz_dy: has 12 rows of 13"):
        lens_from_dict(d)


def test_constructor_errors():
    with pytest.raises(ValueError, match="spacing must be two numbers of mm > 0"):
        GridSag(0.0, 1.0, (0.0, 1.0), [[0.0] * 3] * 3)
    with pytest.raises(ValueError, match="at least 2 nodes"):
        GridSag(0.0, 1.0, (1.0, 1.0), [[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"grid_dz_dx has shape \(3, 2\)"):
        GridSag(0.0, 1.0, (1.0, 1.0), [[0.0] * 3] * 3, dz_dx=[[0.0] * 2] * 3)


def test_finite_difference_slopes_are_exact_for_quadratics():
    """``grid_slopes`` (for files with sag values only): exact for ``a + bx + cy + dx² + exy +
    fy²``, edges included."""
    X, Y = nodes(6, 5, 0.7, 1.3)
    z = 1 + 2 * X - 3 * Y + 0.5 * X * X + 0.25 * X * Y - 0.4 * Y * Y
    zx, zy, zxy = grid_slopes(z, 0.7, 1.3)
    assert torch.allclose(zx, 2 + X + 0.25 * Y, atol=1e-12)
    assert torch.allclose(zy, -3 + 0.25 * X - 0.8 * Y, atol=1e-12)
    assert torch.allclose(zxy, torch.full_like(X, 0.25), atol=1e-12)


def test_parameter_scales_are_the_largest_sag_change_per_node_value():
    """``parameter_scale`` of the grids (one scale per tensor: per node value) is the largest
    ``|∂ sag / ∂θ|`` of one interior node's value over the four cells around it (the sag is
    linear in the grid values: the change of the sag when the value moves by 1, on a fine
    sample): 1 for its sag, ``4/27 h`` for its slopes, ``(4/27)² h_x h_y`` for its cross
    derivative; the base's curvature keeps ``R²/2``."""
    from deeplens.optics.parameters import parameter_scale

    lens, s = _bumpy()
    X, Y = nodes(121, 121, 3.5 / 120, 3.5 / 120, dec=(1.75, 1.75))   # around node (7, 7)
    for name in ("grid_z", "grid_dz_dx", "grid_dz_dy", "grid_d2z_dxdy"):
        p = getattr(s, name)
        with torch.no_grad():
            z0 = s.sag(X, Y)
            p[7, 7] += 1.0
            ref = float((s.sag(X, Y) - z0).abs().max())
            p[7, 7] -= 1.0
        assert parameter_scale(lens, f"surfaces.0.{name}") == pytest.approx(ref, rel=1e-3), name
    assert parameter_scale(lens, "surfaces.0.c") == pytest.approx(6.0 ** 2 / 2)


@pytest.mark.parametrize("mode", ["surface", "lens"])
def test_fused_tracer_runs_it_eager_with_the_same_values_and_gradients(uncompiled, mode):
    """The double Gauss with its first surface a grid sag (its asphere's base, the even terms
    on the grid: a 35 x 35 grid of the asphere's polynomial part plus a small bump): the fused
    tracer's logic (``uncompiled``) leaves it to the eager path between its fused runs; rays,
    paths and gradients (the grid's base curvature, every node's sag, a later sphere's c) equal
    the eager tracer's."""
    import helpers as H

    from deeplens.optics.io import load_lens
    from deeplens.optics.sampling import field_rays

    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    s0 = lens.surfaces[0]
    sd = float(s0.semi_diameter)
    a4, a6, a8 = (float(v) for v in s0.a)

    def f(X, Y):
        r2 = X * X + Y * Y
        bump = 1e-4 * torch.sin(X) * torch.cos(Y)
        return (a4 * r2 ** 2 + a6 * r2 ** 3 + a8 * r2 ** 4 + bump,
                (4 * a4 * r2 + 6 * a6 * r2 ** 2 + 8 * a8 * r2 ** 3) * X
                + 1e-4 * torch.cos(X) * torch.cos(Y),
                (4 * a4 * r2 + 6 * a6 * r2 ** 2 + 8 * a8 * r2 ** 3) * Y
                - 1e-4 * torch.sin(X) * torch.sin(Y),
                4 * (2 * a4 + 6 * a6 * r2 + 12 * a8 * r2 ** 2) * X * Y
                - 1e-4 * torch.cos(X) * torch.sin(Y))
    gs = sampled(f, 35, 35, 2 * sd / 34, 2 * sd / 34, curvature=float(s0.c), sd=sd,
                 conic=float(s0.k))
    lens.surfaces[0] = gs
    assert fused_kind(lens, 0) is None and fused_kind(lens, 4) is not None
    params = [gs.c, gs.grid_z, lens.surfaces[4].c]
    for p in params:
        p.requires_grad_(True)
    rays = field_rays(lens, 10.0, H.WAVELENGTH_D, H.disk_points(120, 2.6, seed=2), 6.0)

    def run(opt):
        out = lens.trace_to_sensor(rays, options=opt)
        v = out.valid
        return out, torch.autograd.grad((out.o[v] ** 2).sum() + out.opl[v].sum(), params)

    a, ga = run(TraceOptions(compile=False))
    b, gb = run(TraceOptions(compile=mode))
    assert torch.equal(a.valid, b.valid) and 0.3 * len(a.valid) < int(a.valid.sum())
    v = a.valid
    for x, y in ((a.o, b.o), (a.d, b.d), (a.opl, b.opl)):
        assert float((x - y)[v].detach().abs().max()) < 1e-12
    for x, y in zip(ga, gb):
        assert float(x.abs().max()) > 0
        assert torch.allclose(x, y, rtol=1e-10, atol=1e-12 * float(x.abs().max()))


def test_float32_sag_within_its_rounding():
    """The sphere grid evaluated in float32 (points and grids) against float64: within the
    rounding of the 16 Hermite terms (each basis value <= 1 in size) and of the coordinates
    (eps |x| times the slope): ``32 eps (max|z| + h max|z_x| + h max|z_y| + h² max|z_xy|) +
    4 eps max|x| max|slope|``."""
    c, h = 0.01, 0.875
    s = sampled(sphere(c), 25, 25, h, h)
    x, y = inside(2000, s, seed=4)
    z64 = s.sag(x, y)
    z32 = s.float().sag(x.float(), y.float())
    assert z32.dtype == torch.float32
    eps = float(torch.finfo(torch.float32).eps)
    Z, Zx, Zy, Zxy = (float(g.abs().max()) for g in (s.grid_z, s.grid_dz_dx, s.grid_dz_dy,
                                                      s.grid_d2z_dxdy))
    bound = 32 * eps * (Z + h * Zx + h * Zy + h * h * Zxy) + 4 * eps * 10.5 * max(Zx, Zy)
    err = float((z32.double() - z64).abs().max())
    assert err < bound
    assert err > 0
