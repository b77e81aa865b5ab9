"""Gradients of traced rays with respect to every kind of lens parameter (float64).

For every surface type (sphere, conic, even asphere, XY polynomial with b = 0 and b != 0,
B-spline, cylinder, toroid) and every parameter kind (the surface's own prescription values, the thicknesses
``lens.distances[i]``, the decenter ``dx, dy`` and tilt ``tilt_x, tilt_y`` of its element, the
sensor distance ``d_sensor``), three derivatives of a non-constant loss agree to 1e-6:

* the implicit gradient (one differentiable Newton step at the root, paper Eq. 7),
* the gradient through the unrolled Newton iteration,
* a fourth-order central finite difference.

The loss is ``sum over valid rays of w · (x, y)`` on the sensor with fixed random weights ``w``
(every image coordinate contributes, with random signs).  The test lens is
``[surface under test | N-BK7 | sphere] stop [sphere | N-SF5 | plane]``, both elements slightly
decentered and tilted, traced with two collimated fields; its rays keep well inside every clear
aperture so that no finite-difference step changes which rays are valid (checked).

Finite-difference steps ``h`` are chosen per parameter so that the step moves the surface by
about 0.1 µm at r = 3 mm (e.g. ``h = 1e-4 / 3^4`` for a4), and each gradient must move the loss
by more than 1e-7 mm over one step: far above the float64 resolution of the loss (~1e-15), so a
vanishing or disconnected gradient cannot pass.
"""

import pytest
import torch

import helpers as H
from deeplens.optics.intersect import TraceOptions, intersect
from deeplens.optics.lens import Lens
from deeplens.optics.materials import get_material
from deeplens.optics.surfaces import (Aperture, Asphere, BSpline, Cylinder, Plane, Sphere,
                                      Toroid, XYPolynomial)

F64 = torch.float64
R_REF = 3.0  # mm: the radius at which a step's sag change is sized
DZ = 1e-4    # mm: sag change of one finite-difference step
MIN_LOSS_CHANGE = 1e-7  # mm: |grad * h| must exceed this

XY_COEFFS = [0.0, 0.002, -0.001, 0.015, 0.002, 0.018, 1e-4, -2e-4, 3e-4, 1e-4]


def _bspline(n=7, L=8.0):
    h = 2 * L / (n - 3)
    v = -L + (torch.arange(n, dtype=F64) - 1) * h
    X, Y = torch.meshgrid(v, v, indexing="ij")
    g = torch.Generator().manual_seed(1)
    return BSpline(L, (X ** 2 + 0.8 * Y ** 2) / 60 + 0.02 * torch.randn(n, n, generator=g,
                                                                         dtype=F64))


SURFACES = {
    "sphere": lambda: Sphere(1 / 30, 8.0),
    "conic": lambda: Asphere(1 / 30, 8.0, conic=-0.7),
    "asphere": lambda: Asphere(1 / 30, 8.0, conic=-0.5, coefficients=[2e-5, -3e-7]),
    "xy_b0": lambda: XYPolynomial(8.0, XY_COEFFS, b=0.0),
    "xy_b": lambda: XYPolynomial(8.0, [0.01] + XY_COEFFS[1:], b=0.03),
    "bspline": _bspline,
    "cylinder": lambda: Cylinder(1 / 30, 8.0, conic=-0.5, coefficients=[2e-3, 2e-5]),
    "toroid": lambda: Toroid(1 / 30, 8.0, 40.0, conic=-0.5, coefficients=[2e-3, 2e-5]),
}

# (surface kind, parameter name, finite-difference step)
_OWN = [
    ("sphere", "c", 2 * DZ / R_REF ** 2),
    ("conic", "c", 2 * DZ / R_REF ** 2),
    ("conic", "k", 0.25),  # dz/dk ~ c^3 r^4 / 8 = 3.8e-4 mm at r = 3
    ("asphere", "c", 2 * DZ / R_REF ** 2),
    ("asphere", "k", 0.25),
    ("asphere", "a4", DZ / R_REF ** 4),
    ("asphere", "a6", DZ / R_REF ** 6),
]
for _kind in ("xy_b0", "xy_b"):
    _OWN += [(_kind, f"a{m}", DZ / R_REF ** (i + j))
             for m, (i, j) in enumerate(XYPolynomial(1.0, XY_COEFFS).terms)]
    _OWN.append((_kind, "b", 4e-3))  # dz/db ~ z^2 ~ 0.025 mm^2 at r = 3
_OWN += [("bspline", f"C{p}{q}", DZ) for p, q in ((3, 3), (2, 4), (4, 2), (1, 3), (4, 4))]
_OWN += [("cylinder", "c", 2 * DZ / R_REF ** 2), ("cylinder", "k", 0.25),
         ("cylinder", "a2", DZ / R_REF ** 2), ("cylinder", "a4", DZ / R_REF ** 4)]
# the toroid's radius of rotation R: dz/dR = -x^2 / (2 R^2) ~ 2.8e-3 at x = 3, R = 40
_OWN += [("toroid", "c", 2 * DZ / R_REF ** 2), ("toroid", "k", 0.25),
         ("toroid", "a2", DZ / R_REF ** 2), ("toroid", "R", 0.04)]
_LENS = [("distance0", 1e-4), ("distance1", 1e-4), ("distance2", 1e-4), ("dx", 1e-4),
         ("dy", 1e-4), ("tilt_x", 1e-5), ("tilt_y", 1e-5), ("d_sensor", 1e-4)]
CASES = _OWN + [(kind, name, h) for kind in SURFACES for name, h in _LENS]


def make_lens(kind: str) -> Lens:
    surfaces = [SURFACES[kind](), Sphere(-1 / 60, 8.0), Aperture(4.0), Sphere(1 / 40, 7.0),
                Plane(7.0)]
    media = [get_material(m) for m in ("AIR", "N-BK7", "AIR", "AIR", "N-SF5", "AIR")]
    lens = Lens(surfaces, media, [0.0, 4.0, 3.0, 2.0, 3.0], 30.0, stop_index=2)
    assert lens.elements == [(0, 1), (2, 2), (3, 4)]
    with torch.no_grad():
        for m, vals in zip(lens.misalignments, [(0.03, -0.02, 0.004, -0.003), (0, 0, 0, 0),
                                                (-0.02, 0.01, -0.002, 0.003)]):
            for p, v in zip((m.dx, m.dy, m.tilt_x, m.tilt_y), vals):
                p.fill_(v)
    return lens


def make_rays():
    xy = H.disk_points(40, 2.5, seed=3)
    return H.cat_rays(H.collimated(xy, [0.0, 0.0, 1.0], -2.0),
                      H.collimated(xy, [0.04, -0.05, 1.0], -2.0))


WEIGHTS = torch.randn(80, 2, generator=torch.Generator().manual_seed(7), dtype=F64)


def select(lens: Lens, name: str):
    """``(parameter, index or None)`` for a case name."""
    s = lens.surfaces[0]
    if name.startswith("distance"):
        return lens.distances[int(name[-1])], None
    if name in ("dx", "dy", "tilt_x", "tilt_y"):
        return getattr(lens.misalignments[0], name), None
    if name == "d_sensor":
        return lens.d_sensor, None
    if isinstance(s, BSpline):
        return s.coefficients, (int(name[1]), int(name[2]))
    if isinstance(s, XYPolynomial):
        return (s.b, None) if name == "b" else (s.a[int(name[1:])], None)
    if isinstance(s, Cylinder) and name.startswith("a"):
        return s.a[(int(name[1:]) - 2) // 2], None
    if name in ("c", "k", "R"):
        return getattr(s, name), None
    return s.a[(int(name[1:]) - 4) // 2], None


def image_loss(lens, rays, mode="implicit"):
    out = lens.trace_to_sensor(rays, options=TraceOptions(mode=mode))
    return H.weighted_image_sum(out, WEIGHTS), out.valid


@pytest.mark.parametrize("kind,name,h", CASES, ids=[f"{k}-{n}" for k, n, _ in CASES])
def test_implicit_equals_unrolled_equals_finite_difference(kind, name, h):
    lens = make_lens(kind)
    rays = make_rays()
    param, idx = select(lens, name)
    param.requires_grad_(True)
    grads = {}
    for mode in ("implicit", "unrolled"):
        loss, valid = image_loss(lens, rays, mode)
        assert bool(valid.all()), "every test ray must reach the sensor"
        (g,) = torch.autograd.grad(loss, param)
        grads[mode] = float(g[idx] if idx is not None else g)

    def f():
        loss, valid = image_loss(lens, rays)
        assert bool(valid.all()), "a finite-difference step changed which rays are valid"
        return loss

    fd = H.central_fd(f, param, h, idx)
    gi, gu = grads["implicit"], grads["unrolled"]
    assert abs(gi * h) > MIN_LOSS_CHANGE, (gi, h)
    assert H.rel_err(gi, gu) < 1e-6, (gi, gu)
    assert H.rel_err(gi, fd) < 1e-6, (gi, fd)
    assert H.rel_err(gu, fd) < 1e-6, (gu, fd)


def test_rms_spot_gradient_matches_finite_difference():
    """A second, quadratic loss: the centroid-referenced RMS spot radius of one field."""
    lens = make_lens("asphere")
    rays = H.collimated(H.disk_points(60, 2.5, seed=9), [0.0, 0.03, 1.0], -2.0)
    params = [(lens.surfaces[0].c, 2e-5), (lens.surfaces[0].a[0], 1e-6), (lens.d_sensor, 1e-4),
              (lens.misalignments[0].tilt_x, 1e-5)]

    def rms(mode="implicit"):
        out = lens.trace_to_sensor(rays, options=TraceOptions(mode=mode))
        assert bool(out.valid.all())
        xy = out.o[:, :2]
        return torch.sqrt(((xy - xy.mean(0)) ** 2).sum(-1).mean())

    for p, h in params:
        p.requires_grad_(True)
        (gi,) = torch.autograd.grad(rms(), p)
        (gu,) = torch.autograd.grad(rms("unrolled"), p)
        fd = H.central_fd(rms, p, h)
        p.requires_grad_(False)
        assert abs(float(gi) * h) > MIN_LOSS_CHANGE
        assert H.rel_err(gi, gu) < 1e-6 and H.rel_err(gi, fd) < 1e-6, (float(gi), float(gu), fd)


def test_gradients_of_all_parameters_at_once():
    """One backward pass fills the gradient of every unfrozen parameter, equal to the one
    computed for that parameter alone."""
    lens = make_lens("xy_b")
    rays = make_rays()
    names = ["a3", "b", "distance1", "dx", "tilt_y", "d_sensor"]
    chosen = [select(lens, n)[0] for n in names]
    for p in chosen:
        p.requires_grad_(True)
    loss, _ = image_loss(lens, rays)
    loss.backward()
    together = [float(p.grad) for p in chosen]
    for p in chosen:
        p.grad = None
        p.requires_grad_(False)
    for n, g_all in zip(names, together):
        p, _ = select(lens, n)
        p.requires_grad_(True)
        (g,) = torch.autograd.grad(image_loss(lens, rays)[0], p)
        p.requires_grad_(False)
        assert H.rel_err(g, g_all) < 1e-12 and abs(g_all) > 0


def test_bspline_gradient_is_local():
    """Only the 4x4 control points around a hit influence it: coefficients whose support
    (|x - x_p| < 2h with h = 4 mm here) no ray reaches get an exactly zero gradient, the
    others a non-zero one."""
    lens = make_lens("bspline")
    rays = make_rays()
    C = lens.surfaces[0].coefficients
    C.requires_grad_(True)
    (g,) = torch.autograd.grad(image_loss(lens, rays)[0], C)
    # the first surface is decentered by < 0.05 mm; all hits lie within r < 3 mm of its axis,
    # so control points centred at -12 and +12 mm (indices 0 and 6) are out of reach
    assert not bool(g[0].any() or g[-1].any() or g[:, 0].any() or g[:, -1].any())
    assert bool((g[1:-1, 1:-1].abs() > 0).all())


# ----------------------------------------------------------------- regression tests (unrolled)
def test_regression_unrolled_gradient_of_ray_starting_on_surface():
    """A ray whose vertex-plane start ``t0`` already satisfies ``|f| < tol`` used to take no
    recorded Newton step in unrolled mode, so it kept the detached ``t0``: its derivative with
    respect to the XY constant term ``a0`` (which moves the surface along z) was missing
    (autograd error: no graph) instead of ``dz/da0 = 1``."""
    s = XYPolynomial(5.0, [0.0, 0.0, 0.0, 0.01, 0.0, 0.02])
    s.a[0].requires_grad_(True)
    o = torch.tensor([[0.0, 0.0, -1.0], [0.5, 0.3, -1.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], dtype=F64)
    for mode in ("implicit", "unrolled"):
        t, x, ok = intersect(s, o, d, torch.ones(2, dtype=torch.bool), TraceOptions(mode=mode))
        assert bool(ok.all())
        for i in range(2):
            (g,) = torch.autograd.grad(x[i, 2], s.a[0], retain_graph=True)
            assert float(g) == pytest.approx(1.0, abs=1e-12)


def test_regression_unrolled_derivative_converges_with_the_value():
    """The derivative of a Newton iterate lags its value by one step.  Unrolled mode used to
    stop as soon as ``|f| < tol``, leaving a derivative error of the order of the previous
    residual (4e-6 relative on the XY ``b`` gradient of the lens test above).  It must equal
    the implicit-function derivative ``dt/dθ = -(∂f/∂θ) / (d · ∇f)`` to 1e-10."""
    s = XYPolynomial(8.0, XY_COEFFS, b=0.0)
    s.b.requires_grad_(True)
    o = torch.cat([H.disk_points(50, 6.0, seed=2), torch.full((50, 1), -2.0, dtype=F64)], -1)
    d = torch.tensor([0.05, -0.08, 1.0], dtype=F64)
    d = (d / d.norm()).expand(50, 3)
    t, x, ok = intersect(s, o, d, torch.ones(50, dtype=torch.bool),
                         TraceOptions(mode="unrolled"))
    assert bool(ok.all())
    (g,) = torch.autograd.grad(t.sum(), s.b)
    with torch.no_grad():
        X, Y, Z = x.unbind(-1)
        fx, fy, fz = s.f_grad(X, Y, Z)
        expect = (-(Z * Z) / (fx * d[:, 0] + fy * d[:, 1] + fz * d[:, 2])).sum()  # ∂f/∂b = z^2
    assert H.rel_err(g, expect) < 1e-10


@pytest.mark.parametrize("kind", ["sphere", "asphere", "xy_b", "bspline"])
def test_intersection_gradient_matches_implicit_function_theorem(kind):
    """At the level of one intersection: dt/d(origin) for each mode equals the closed form
    ``-(∇f) / (d · ∇f)`` (float64), for rays needing several Newton iterations."""
    s = SURFACES[kind]()
    xy = H.disk_points(30, 5.0, seed=4)
    o = torch.cat([xy, torch.full((30, 1), -1.5, dtype=F64)], -1)
    d = torch.tensor([0.1, 0.05, 1.0], dtype=F64)
    d = (d / d.norm()).expand(30, 3)
    for mode in ("implicit", "unrolled"):
        o_ = o.clone().requires_grad_(True)
        t, x, ok = intersect(s, o_, d, torch.ones(30, dtype=torch.bool),
                             TraceOptions(mode=mode))
        assert bool(ok.all())
        (g,) = torch.autograd.grad(t.sum(), o_)
        with torch.no_grad():
            grad_f = torch.stack(s.f_grad(*x.unbind(-1)), -1)
            expect = -grad_f / (grad_f * d).sum(-1, keepdim=True)
        assert float((g - expect).abs().max()) < 1e-10 * float(expect.abs().max())
