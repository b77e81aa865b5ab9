"""The closed-form intersection of spheres and conics against the generic Newton path.

``intersect`` solves ``A s^2 + 2 B s + C = 0`` in closed form on a quadric surface (no Newton
iterations) and starts an asphere's Newton iteration from its conic base's root;
``TraceOptions(closed_form=False)`` runs the generic Newton path from the vertex plane on
every surface (the code before the fast path).  Checked in float64:

* the same rays are valid, and ``t`` and the hit points agree to 1e-12 mm, for spheres and conics
  of both signs (prolate, paraboloid, hyperboloid, oblate), forward and backward rays, grazing
  rays included;
* the closed form's autograd derivative w.r.t. ``c``, ``k``, the ray origin and direction equals
  a central finite difference (to 1e-8 relative) and the implicit Newton derivative;
* a whole lens (the shipped double Gauss, its first surface an asphere): spots and the gradient of
  the RMS spot w.r.t. every curvature agree between the two paths, and with finite differences;
* an asphere converges in at most two Newton updates from the conic root, where the vertex-plane
  start needs more.
"""

import math

import helpers as H
import pytest
import torch

from deeplens.optics.intersect import TraceOptions, intersect
from deeplens.optics.io import load_lens
from deeplens.optics.sampling import field_rays
from deeplens.optics.surfaces import Asphere, Sphere

F64 = torch.float64
FAST = TraceOptions(tol=1e-13)
GENERIC = TraceOptions(tol=1e-13, closed_form=False)

QUADRICS = {
    "sphere+": lambda: Sphere(1 / 12.0, 9.0),
    "sphere-": lambda: Sphere(-1 / 10.0, 8.0),
    "prolate": lambda: Asphere(1 / 15.0, 9.0, conic=-0.6),
    "paraboloid": lambda: Asphere(-1 / 20.0, 9.0, conic=-1.0),
    "hyperboloid": lambda: Asphere(1 / 8.0, 7.0, conic=-2.5),
    "oblate": lambda: Asphere(1 / 20.0, 6.0, conic=2.0),
}


def _rays(n, sd, z0, max_angle, seed, direction=1.0):
    """Rays from ``z = z0`` through points within ``0.95 sd`` of the vertex plane, up to
    ``max_angle`` rad off the axis; ``direction = -1`` mirrors them to travel towards -z."""
    g = torch.Generator().manual_seed(seed)
    r = 0.95 * sd * torch.sqrt(torch.rand(n, generator=g, dtype=F64))
    phi = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    target = torch.stack([r * torch.cos(phi), r * torch.sin(phi), torch.zeros_like(r)], -1)
    th = max_angle * torch.sqrt(torch.rand(n, generator=g, dtype=F64))
    ps = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    d = torch.stack([torch.sin(th) * torch.cos(ps), torch.sin(th) * torch.sin(ps),
                     torch.cos(th)], -1)
    o = target + (z0 / d[:, 2]).unsqueeze(-1) * d
    flip = torch.tensor([1.0, 1.0, direction], dtype=F64)
    return o * flip, d * flip


@pytest.mark.parametrize("direction", [1.0, -1.0], ids=["forward", "backward"])
@pytest.mark.parametrize("name", list(QUADRICS))
def test_closed_form_equals_newton(name, direction):
    s = QUADRICS[name]()
    o, d = _rays(600, float(s.semi_diameter), -12.0, 0.6, seed=len(name), direction=direction)
    valid = torch.ones(len(o), dtype=torch.bool)
    t, x, ok = intersect(s, o, d, valid, FAST)
    t_n, x_n, ok_n = intersect(s, o, d, valid, GENERIC)
    assert torch.equal(ok, ok_n)
    assert int(ok.sum()) > 300
    assert float((t - t_n)[ok].abs().max()) < 1e-12
    assert float((x - x_n)[ok].abs().max()) < 1e-12
    X, Y, Z = x[ok].unbind(-1)
    assert float(s.f(X, Y, Z).abs().max()) < 1e-12
    assert bool(torch.isfinite(t).all() and torch.isfinite(x).all())


def test_closed_form_grazing_rays_equal_newton():
    """Rays at 80-89.9 deg incidence cross a strongly curved cap twice; both paths return the
    crossing in the ray's direction of travel (the closed form picks it by the sign of
    d · ∇F, Newton by starting near it)."""
    s = Sphere(1 / 10.0, 9.0)
    o, d = [], []
    for r0 in (2.0, 5.0, 8.0):
        z = 10.0 - math.sqrt(100.0 - r0 * r0)
        P = torch.tensor([0.0, r0, z], dtype=F64)
        n = (torch.tensor([0.0, 0.0, 10.0], dtype=F64) - P) / 10.0  # inward: +z component
        tang = torch.tensor([0.0, n[2], -n[1]], dtype=F64)
        tang = tang if tang[2] > 0 else -tang
        for inc in (80.0, 88.0, 89.9):
            a = math.radians(inc)
            di = math.cos(a) * n + math.sin(a) * tang
            o.append(P - 5.0 * di)
            d.append(di)
    o, d = torch.stack(o), torch.stack(d)
    valid = torch.ones(len(o), dtype=torch.bool)
    t, _, ok = intersect(s, o, d, valid, FAST)
    t_n, _, ok_n = intersect(s, o, d, valid, GENERIC)
    assert bool(ok.all()) and bool(ok_n.all())
    assert float((t - 5.0).abs().max()) < 1e-10
    assert float((t - t_n).abs().max()) < 1e-12


@pytest.mark.parametrize("name", ["sphere-", "prolate", "hyperboloid"])
def test_closed_form_gradient_equals_finite_differences(name):
    """d/dθ of a weighted sum of hit points through the closed form, for θ = c, k, a ray
    origin and a ray direction component: equal to a 4th-order central difference and to the
    implicit (Eq. 7) Newton derivative."""
    s = QUADRICS[name]()
    o, d = _rays(40, float(s.semi_diameter) * 0.8, -6.0, 0.3, seed=3)
    o = o.clone().requires_grad_(True)
    d = d.clone().requires_grad_(True)
    valid = torch.ones(len(o), dtype=torch.bool)
    w = torch.randn(len(o), 3, generator=torch.Generator().manual_seed(9), dtype=F64)
    s.c.requires_grad_(True)
    s.k.requires_grad_(True)

    def loss(opt):
        t, x, ok = intersect(s, o, d, valid, opt)
        assert bool(ok.all())
        return (x * w).sum() + t.sum()

    params = [s.c, s.k, o, d]
    g_fast = torch.autograd.grad(loss(FAST), params)
    g_newton = torch.autograd.grad(loss(GENERIC), params)
    cases = [(s.c, None, 1e-5), (s.k, None, 1e-4), (o, (7, 0), 1e-4), (o, (3, 2), 1e-4),
             (d, (5, 1), 1e-5)]
    for p, idx, h in cases:
        g = g_fast[[id(q) for q in params].index(id(p))]
        gn = g_newton[[id(q) for q in params].index(id(p))]
        ga, gb = (g, gn) if idx is None else (g[idx], gn[idx])
        fd = H.central_fd(lambda: loss(FAST), p, h, idx)
        assert abs(float(ga)) * h > 1e-7  # the parameter moves the loss
        assert H.rel_err(ga, fd) < 1e-8, (p.shape, idx, float(ga), fd)
        assert H.rel_err(ga, gb) < 1e-10


def test_asphere_newton_starts_at_the_conic_root():
    """An even asphere (up to 20 µm from its conic base) converges within two Newton updates
    from its conic base's root (391 of 392 rays to 1e-12 mm); from the vertex plane 26 do.
    The roots agree."""
    s = Asphere(1 / 9.0, 6.0, conic=-0.8, coefficients=[2e-5, -1e-7])
    o, d = _rays(400, 6.0, -5.0, 0.4, seed=4)
    valid = torch.ones(len(o), dtype=torch.bool)
    two = {"tol": 1e-12, "max_iter": 2}
    with pytest.warns(RuntimeWarning, match="did not converge"):
        _, _, ok_vertex = intersect(s, o, d, valid, TraceOptions(closed_form=False, **two))
    t, _, ok = intersect(s, o, d, valid, TraceOptions(**two))
    t_ref, _, ok_ref = intersect(s, o, d, valid, GENERIC)
    assert int(ok_ref.sum()) > 350 and not bool((ok & ~ok_ref).any())
    assert int(ok.sum()) >= int(ok_ref.sum()) - 2
    assert int(ok_vertex.sum()) < 0.2 * int(ok.sum())
    assert float((t - t_ref)[ok].abs().max()) < 1e-12


def _double_gauss_spot(lens, opt, n=300):
    xy = H.disk_points(n, 2.2, seed=1)
    rays = field_rays(lens, 5.0, H.WAVELENGTH_D, xy, 6.0)
    out = lens.trace_to_sensor(rays, options=opt)
    pts = out.o[..., :2][out.valid]
    rms = torch.sqrt(((pts - pts.mean(0)) ** 2).sum(-1).mean())
    return out, rms


def test_double_gauss_fast_path_equals_newton():
    """Whole lens, float64: the same valid rays, spot points to 1e-11 mm, and the gradient of
    the RMS spot w.r.t. every curvature equal between the paths and to finite differences."""
    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    curv = [s.c for s in lens.surfaces if hasattr(s, "c")]
    for c in curv:
        c.requires_grad_(True)
    out, rms = _double_gauss_spot(lens, FAST)
    out_n, rms_n = _double_gauss_spot(lens, GENERIC)
    assert torch.equal(out.valid, out_n.valid) and int(out.valid.sum()) > 250
    assert float((out.o - out_n.o)[out.valid].abs().max()) < 1e-11
    g = torch.autograd.grad(rms, curv)
    g_n = torch.autograd.grad(rms_n, curv)
    assert H.rel_err(torch.stack(g), torch.stack(g_n)) < 1e-8
    for i in (1, 4, len(curv) - 1):  # a front, a middle and the last sphere
        fd = H.central_fd(lambda: _double_gauss_spot(lens, FAST)[1], curv[i], 1e-6)
        assert abs(float(g[i])) * 1e-6 > 1e-9
        assert H.rel_err(g[i], fd) < 1e-6, (i, float(g[i]), fd)


def test_fused_quadric_step_equals_intersect_then_refract():
    """``Lens.trace_surface`` on a sphere or conic runs the per-component ``trace_quadric``; it
    equals ``intersect`` followed by ``refract`` at ``surface.normal`` (float64, values and the
    gradients w.r.t. c, k, the vertex position and the incoming rays), including rays that miss
    the aperture or are totally internally reflected."""
    from deeplens.optics.lens import Lens
    from deeplens.optics.materials import get_material
    from deeplens.optics.rays import Rays
    from deeplens.optics.refract import refract

    surf = Asphere(-1 / 6.0, 5.0, conic=-0.4)  # strong: some rays TIR going into air
    lens = Lens([Sphere(1 / 20.0, 9.0), surf], [get_material("AIR"), get_material("N-SF5"),
                get_material("AIR")], [0.0, 3.0], 10.0, 0)
    surf.c.requires_grad_(True)
    surf.k.requires_grad_(True)
    lens.distances[1].requires_grad_(True)
    o, d = _rays(300, 6.0, 1.0, 0.5, seed=11)
    o = o.clone().requires_grad_(True)
    rays = Rays(o, d, H.WAVELENGTH_D, opl=torch.full((300,), 2.0, dtype=F64))
    n = lens.indices(rays.wavelength)
    z = lens.z_vertices()
    out = lens.trace_surface(1, rays, n[1], n[2], z)
    # the same through the generic functions
    t, x, ok = intersect(surf, rays.o - torch.stack([0 * z[1], 0 * z[1], z[1]]), rays.d,
                         rays.valid)
    d_t, ok = refract(rays.d, surf.normal(x), n[1] / n[2], ok)
    x = x + torch.stack([0 * z[1], 0 * z[1], z[1]])
    assert torch.equal(out.valid, ok)
    assert 50 < int(ok.sum()) < 280  # misses and TIR as well as hits
    w = torch.randn(300, 3, generator=torch.Generator().manual_seed(1), dtype=F64)
    params = [surf.c, surf.k, lens.distances[1], o]
    for a, b in ((out.o, x), (out.d, d_t), (out.opl, rays.opl + n[1] * t)):
        assert float((a - b).abs().max()) < 1e-13
        la = (a * (w if a.dim() == 2 else w[:, 0])).sum()
        lb = (b * (w if b.dim() == 2 else w[:, 0])).sum()
        for ga, gb in zip(torch.autograd.grad(la, params, retain_graph=True),
                          torch.autograd.grad(lb, params, retain_graph=True)):
            assert H.rel_err(ga, gb) < 1e-12
