"""A ray whose vertex-plane point lies outside a sphere's domain can still meet the sphere.

The closed-form quadric intersection solves for the ray's crossing from its vertex-plane point.
A steep ray near a strongly curved surface (the chief ray of a wide-angle lens's edge field at a
rear surface concave towards the image: a 28 mm camera lens, set 12's
``ob_US002779239_Example01P``) crosses that plane beyond ``|R|``, where the sphere has no point,
and yet meets the sphere's branch (the hemisphere towards the vertex) further on.  Such rays
were marked invalid ("kept for identical results" with the Newton path's start); OpticStudio's
standard surface is the exact sphere, so they are now solved from the line's point nearest the
vertex instead (not from the origin, which may lie far away: float32 digits).

Checked against the textbook sphere intersection (both roots, the first one ahead on the
branch) in float64, on both closed-form paths (:func:`intersect` and the fused
:func:`trace_quadric`), the hit's derivative in the curvature against central differences,
and float32 hits of far origins against a rounding bound.
"""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.intersect import TraceOptions, intersect, trace_quadric
from deeplens.optics.surfaces import Sphere

F64 = torch.float64

# (curvature 1/mm, origin (y, z) in the vertex frame, direction (dy, dz) before normalising)
CASES = {
    # concave towards the image, the ray inside the sphere leaving through its branch
    # (the 28 mm lens's surface 10 at 35 deg: vertex-plane point at y = 7.14 > |R| = 6.89)
    "concave": (-0.145180023228804, (4.4579, -3.9439), (0.5629, 0.8265)),
    # convex towards the object, a ray running in towards the axis from beyond the rim
    "convex": (0.2, (7.0, -1.0), (-0.6, 0.8)),
}


def _sphere_hit(c, o, d):
    """The first crossing ahead of ``o + t d`` (2-D, ``(y, z)``, vertex at the origin) with the
    sphere ``y² + (z − R)² = R²`` on its branch ``1 − c z > 0``: the textbook quadratic."""
    R = 1.0 / c
    oy, oz = o
    dy, dz = d
    b = oy * dy + (oz - R) * dz
    cc = oy * oy + (oz - R) ** 2 - R * R
    disc = b * b - cc
    ts = sorted(t for t in (-b - math.sqrt(disc), -b + math.sqrt(disc))
                if t > 0 and 1 - c * (oz + t * dz) > 0)
    t = ts[0]
    return t, (oy + t * dy, oz + t * dz)


def _rays(o, d):
    dn = math.hypot(*d)
    oo = torch.tensor([[0.0, o[0], o[1]]], dtype=F64)
    dd = torch.tensor([[0.0, d[0] / dn, d[1] / dn]], dtype=F64)
    return oo, dd


@pytest.mark.parametrize("case", list(CASES))
def test_the_case_crosses_the_vertex_plane_beyond_the_domain(case):
    c, o, d = CASES[case]
    y_v = o[0] - o[1] * d[0] / d[1]
    assert abs(y_v) > abs(1 / c)          # no point of the sphere there


@pytest.mark.parametrize("case", list(CASES))
def test_intersect_meets_the_branch_where_the_sphere_is(case):
    c, o, d = CASES[case]
    dn = math.hypot(*d)
    t_ref, (y_ref, z_ref) = _sphere_hit(c, o, (d[0] / dn, d[1] / dn))
    oo, dd = _rays(o, d)
    s = Sphere(c, 0.999 * abs(1 / c)).to(F64)
    t, x, ok = intersect(s, oo, dd, torch.tensor([True]), TraceOptions())
    assert bool(ok[0])
    assert float(t[0]) == pytest.approx(t_ref, abs=1e-12)
    assert float(x[0, 1]) == pytest.approx(y_ref, abs=1e-12)
    assert float(x[0, 2]) == pytest.approx(z_ref, abs=1e-12)


@pytest.mark.parametrize("case", list(CASES))
def test_the_fused_step_meets_it_too(case):
    c, o, d = CASES[case]
    dn = math.hypot(*d)
    _, (y_ref, z_ref) = _sphere_hit(c, o, (d[0] / dn, d[1] / dn))
    oo, dd = _rays(o, d)
    s = Sphere(c, 0.999 * abs(1 / c)).to(F64)
    z_v = torch.tensor(3.0, dtype=F64)    # the vertex 3 mm along the axis: a global frame
    x, _, ok, _ = trace_quadric(s, oo + torch.tensor([0.0, 0.0, 3.0], dtype=F64), dd,
                                torch.tensor([True]), torch.zeros(1, dtype=F64), z_v, 1.0, 1.5)
    assert bool(ok[0])
    assert float(x[0, 1]) == pytest.approx(y_ref, abs=1e-12)
    assert float(x[0, 2]) == pytest.approx(z_ref + 3.0, abs=1e-12)


@pytest.mark.parametrize("case", list(CASES))
def test_a_line_that_misses_the_branch_stays_invalid(case):
    """Moved sideways by twice the radius, the same ray misses the sphere altogether."""
    c, o, d = CASES[case]
    oo, dd = _rays((o[0] + math.copysign(2.0 / abs(c), o[0]), o[1]), d)
    s = Sphere(c, 0.999 * abs(1 / c)).to(F64)
    _, _, ok = intersect(s, oo, dd, torch.tensor([True]), TraceOptions(clip_aperture=False))
    assert not bool(ok[0])


@pytest.mark.parametrize("case", list(CASES))
def test_the_hits_derivative_in_the_curvature_matches_central_differences(case):
    """float64; step 1e-6 / mm: truncation ~ h² |y'''| and rounding ~ eps |y| / h, both below
    1e-8 here, so 1e-7 relative is a bound, not a fit."""
    c, o, d = CASES[case]
    oo, dd = _rays(o, d)

    def hit_y(cv):
        s = Sphere(cv, 0.999 * abs(1 / c)).to(F64)
        _, x, ok = intersect(s, oo, dd, torch.tensor([True]), TraceOptions(clip_aperture=False))
        assert bool(ok[0])
        return x[0, 1]

    s = Sphere(c, 0.999 * abs(1 / c)).to(F64)
    s.c.requires_grad_(True)
    _, x, ok = intersect(s, oo, dd, torch.tensor([True]), TraceOptions(clip_aperture=False))
    (g,) = torch.autograd.grad(x[0, 1], s.c)
    h = 1e-6
    with torch.no_grad():
        fd = (float(hit_y(c + h)) - float(hit_y(c - h))) / (2 * h)
    assert float(g) == pytest.approx(fd, rel=1e-7)


def _sphere_hit_of(c, o, d):
    """:func:`_sphere_hit` for a direction ``d`` of any length (float64 tensors ``(3,)`` in,
    the hit ``(3,)`` and the cosine of its incidence out): the reference for float32 inputs,
    taken from the same rounded numbers."""
    R = 1.0 / c
    ctr = torch.tensor([0.0, 0.0, R], dtype=F64)
    a = float(d @ d)
    b = float((o - ctr) @ d)
    cc = float((o - ctr) @ (o - ctr)) - R * R
    sq = math.sqrt(b * b - a * cc)
    ts = sorted(t for t in ((-b - sq) / a, (-b + sq) / a)
                if t > 0 and 1 - c * float(o[2] + t * d[2]) > 0)
    x = o + ts[0] * d
    cos_i = abs(float((x - ctr) @ d)) / (abs(R) * math.sqrt(a))
    return x, cos_i


@pytest.mark.parametrize("back", [300.0, 1000.0])
@pytest.mark.parametrize("case", list(CASES))
def test_a_far_origin_keeps_float32_digits(case, back):
    """The same ray started ``back`` mm further back along its line, in float32, on both
    closed-form paths: the roots are solved from the line's point nearest the vertex, not from
    the origin.  Bound, against the float64 hit of the same rounded inputs: forming the base
    point ``o + t0 d`` rounds by ~2 eps |o| (as the vertex-plane start of every other ray does),
    and its coefficients, within ~|R| of the vertex, carry ~eps |R|² |c|, which moves the root
    by ~eps |R| / cos(incidence): ``eps (2 |o| + 16 |R| / cos)``.  From the origin, ``C``
    carries eps |o|² |c| and the hit was off by 2e-4 mm (300 mm) to 8e-3 mm (1000 mm), 3 to 40
    times the bound; now 1e-5 mm at most."""
    c, o, d = CASES[case]
    dn = math.hypot(*d)
    u = (d[0] / dn, d[1] / dn)
    oo, dd = _rays((o[0] - back * u[0], o[1] - back * u[1]), d)
    o32, d32 = oo.float(), dd.float()
    x_ref, cos_i = _sphere_hit_of(c, o32[0].double(), d32[0].double())
    eps = torch.finfo(torch.float32).eps
    bound = eps * (2 * float(o32.abs().max()) + 16 * abs(1 / c) / cos_i)
    s = Sphere(c, 0.999 * abs(1 / c)).to(torch.float32)
    _, x, ok = intersect(s, o32, d32, torch.tensor([True]), TraceOptions())
    assert bool(ok[0])
    assert float((x[0].double() - x_ref).abs().max()) < bound
    shift = torch.tensor([0.0, 0.0, 3.0])
    xf, _, okf, _ = trace_quadric(s, o32 + shift, d32, torch.tensor([True]),
                                  torch.zeros(1), torch.tensor(3.0), 1.0, 1.5)
    assert bool(okf[0])
    # the shifted origin is rounded anew: the reference of those inputs
    x_ref_f, _ = _sphere_hit_of(c, (o32 + shift)[0].double() - shift.double(), d32[0].double())
    assert float((xf[0].double() - shift.double() - x_ref_f).abs().max()) < bound
