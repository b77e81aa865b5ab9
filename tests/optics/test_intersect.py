"""Ray-surface intersection (paper Sec. II-C, Eq. 6-7): values against independent results.

* sphere: the Newton solution equals the closed-form root of the quadratic
  ``|o + t d - C|^2 = R^2`` (the root on the vertex-side hemisphere) to 1e-10 mm, float64;
* asphere, XY polynomial (b = 0 and b != 0), B-spline: the hit point satisfies ``f = 0`` to the
  tolerance, lies on the ray, and is the root found by an independent bisection;
* both gradient modes return the same values; misses, surfaces behind the ray and grazing rays
  are marked invalid with finite outputs.
"""

import math

import pytest
import torch

from deeplens.optics.intersect import TraceOptions, default_tolerance, intersect
from deeplens.optics.surfaces import Asphere, BSpline, Plane, Sphere, XYPolynomial

F64 = torch.float64


def _random_rays(n, sd, z0=-3.0, max_angle=0.35, seed=0, dtype=F64):
    """Rays from the plane z = z0 aimed at points within ``0.9 sd`` of the vertex plane,
    with directions up to ``max_angle`` rad off axis."""
    g = torch.Generator().manual_seed(seed)
    r = 0.9 * sd * torch.sqrt(torch.rand(n, generator=g, dtype=F64))
    phi = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    target = torch.stack([r * torch.cos(phi), r * torch.sin(phi), torch.zeros_like(r)], -1)
    th = max_angle * torch.sqrt(torch.rand(n, generator=g, dtype=F64))
    ps = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    d = torch.stack([torch.sin(th) * torch.cos(ps), torch.sin(th) * torch.sin(ps), torch.cos(th)],
                    -1)
    o = target + (z0 / d[:, 2]).unsqueeze(-1) * d
    return o.to(dtype), d.to(dtype)


def _sphere_closed_form(c, o, d):
    """Root of |o + t d - C|^2 = R^2 (C = (0, 0, R)) on the hemisphere that contains the
    vertex, and whether it exists."""
    R = 1.0 / c
    C = torch.tensor([0.0, 0.0, R], dtype=o.dtype)
    oc = o - C
    b = (oc * d).sum(-1)
    cc = (oc * oc).sum(-1) - R * R
    disc = b * b - cc
    ok = disc >= 0
    s = torch.sqrt(disc.clamp_min(0))
    t1, t2 = -b - s, -b + s
    # vertex-side hemisphere: (z - R) has the sign opposite to R
    z1 = o[:, 2] + t1 * d[:, 2]
    on_near = (z1 - R) * R < 0
    return torch.where(on_near, t1, t2), ok


@pytest.mark.parametrize("radius", [25.0, -25.0, 12.0, -9.0])
@pytest.mark.parametrize("mode", ["implicit", "unrolled"])
def test_sphere_matches_closed_form_quadratic(radius, mode):
    sd = 0.8 * abs(radius)
    s = Sphere(1.0 / radius, sd)
    # start before the whole cap (|sag| < |R|), so every hit lies ahead of its ray
    o, d = _random_rays(500, sd, z0=-abs(radius) - 1.0, seed=int(abs(radius)))
    valid = torch.ones(500, dtype=torch.bool)
    t, x, ok = intersect(s, o, d, valid, TraceOptions(mode=mode))
    t_ref, exists = _sphere_closed_form(1.0 / radius, o, d)
    assert bool(exists.all())
    x_ref = o + t_ref.unsqueeze(-1) * d
    inside = (x_ref[:, :2] ** 2).sum(-1) <= sd * sd
    assert bool(inside.sum() > 400)
    assert torch.equal(ok, inside)
    assert float((t - t_ref)[ok].abs().max()) < 1e-10
    assert float((x - x_ref)[ok].abs().max()) < 1e-10


def test_sphere_reverse_rays_match_closed_form():
    """Rays travelling towards -z (backward tracing) hit the same cap."""
    s = Sphere(1 / 20.0, 15.0)
    o, d = _random_rays(300, 15.0, z0=-21.0, seed=5)
    o, d = o * torch.tensor([1.0, 1.0, -1.0], dtype=F64), d * torch.tensor([1.0, 1.0, -1.0],
                                                                              dtype=F64)
    t, x, ok = intersect(s, o, d, torch.ones(300, dtype=torch.bool))
    t_ref, exists = _sphere_closed_form(1 / 20.0, o, d)
    x_ref = o + t_ref.unsqueeze(-1) * d
    assert torch.equal(ok, exists & ((x_ref[:, :2] ** 2).sum(-1) <= 15.0 ** 2))
    assert bool(ok.sum() > 250)
    assert bool((d[:, 2] < 0).all() and (t[ok] > 0).all())
    assert float((t - t_ref)[ok].abs().max()) < 1e-10


def test_sphere_float32_within_float32_tolerance():
    s = Sphere(1 / 25.0, 20.0).to(torch.float32)
    o, d = _random_rays(300, 20.0, seed=2)
    t, x, ok = intersect(s, o.float(), d.float(), torch.ones(300, dtype=torch.bool))
    assert t.dtype == torch.float32
    t_ref, _ = _sphere_closed_form(1 / 25.0, o, d)
    assert bool(ok.sum() > 250)
    assert float((t.double() - t_ref)[ok].abs().max()) < 5e-5


@pytest.mark.parametrize("mode", ["implicit", "unrolled"])
def test_float32_far_origin_meets_a_tight_tolerance(mode):
    """Regression: rays starting 100 mm before the surface (a backward ray from the sensor) in
    float32.  Evaluating f at ``o + t d`` has a rounding error of about |o| eps = 6e-6 mm there,
    so tolerances below it dropped up to 76 % of the rays; the iteration now runs from the
    re-based origin ``o + t0 d``.  Every ray stays valid and the hit point is at the closed-form
    root to float32 accuracy near the vertex.  (f's own rounding, |x| eps, still bounds the
    tolerance a float32 surface can meet.)"""
    s = Sphere(1 / 25.0, 6.0).to(torch.float32)  # |x| <= 6 mm: f itself is good to ~5e-7 mm
    o, d = _random_rays(400, 6.0, z0=-100.0, max_angle=0.05, seed=5)
    t_ref, ok_ref = _sphere_closed_form(1 / 25.0, o, d)
    assert bool(ok_ref.all())
    x_ref = o + t_ref.unsqueeze(-1) * d
    for tol in (2e-6, 1e-6):
        opt = TraceOptions(tol=tol, mode=mode)
        t, x, ok = intersect(s, o.float(), d.float(), torch.ones(400, dtype=torch.bool), opt)
        assert bool(ok.all()), f"tol {tol}: {int((~ok).sum())} of 400 rays dropped"
        assert float((x.double() - x_ref).abs().max()) < 5e-6  # |x| <= 6 mm
        assert float((t.double() - t_ref).abs().max()) < 5e-5  # |t| ~ 100 mm: 100 eps-ish


def _bisect_root(surface, o, d, lo, hi, iters=200):
    """Independent root of f(o + t d) = 0 on [lo, hi] by bisection (float64)."""
    def g(t):
        p = o + t.unsqueeze(-1) * d
        return surface.f(p[:, 0], p[:, 1], p[:, 2])

    glo = g(lo)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        gm = g(mid)
        same = torch.sign(gm) == torch.sign(glo)
        lo = torch.where(same, mid, lo)
        glo = torch.where(same, gm, glo)
        hi = torch.where(same, hi, mid)
    return 0.5 * (lo + hi)


def _freeform_surfaces():
    g = torch.Generator().manual_seed(11)
    n, L = 8, 6.0
    h = 2 * L / (n - 3)
    v = -L + (torch.arange(n, dtype=F64) - 1) * h
    X, Y = torch.meshgrid(v, v, indexing="ij")
    grid = (X ** 2 - 0.5 * Y ** 2) / 40 + 0.05 * torch.randn(n, n, generator=g, dtype=F64)
    return {
        "asphere": Asphere(1 / 15.0, 6.0, conic=-1.8, coefficients=[3e-4, -2e-6, 1e-8]),
        "oblate_conic": Asphere(1 / 20.0, 6.0, conic=2.5),
        "xy_b0": XYPolynomial(6.0, [0.02, 0.01, -0.02, 0.03, 0.01, 0.02, 1e-3, -2e-3, 5e-4,
                                    1e-3], b=0.0),
        "xy_b": XYPolynomial(6.0, [0.02, 0.01, -0.02, 0.03, 0.01, 0.02, 1e-3, -2e-3, 5e-4,
                                   1e-3], b=0.05),
        "bspline": BSpline(L, grid),
    }


@pytest.mark.parametrize("name", list(_freeform_surfaces()))
@pytest.mark.parametrize("mode", ["implicit", "unrolled"])
def test_freeform_hit_on_surface_and_on_ray(name, mode):
    s = _freeform_surfaces()[name]
    o, d = _random_rays(400, 6.0, seed=3)
    t, x, ok = intersect(s, o, d, torch.ones(400, dtype=torch.bool), TraceOptions(mode=mode))
    assert bool(ok.sum() > 300)
    X, Y, Z = x[ok].unbind(-1)
    assert float(s.f(X, Y, Z).abs().max()) < default_tolerance(F64)
    # on the ray: x - o parallel to d, at a positive distance
    rel = x[ok] - o[ok]
    assert float(torch.linalg.cross(rel, d[ok]).norm(dim=-1).max()) < 1e-12
    assert bool((t[ok] > 0).all())
    # the same root as an independent bisection around it
    t_b = _bisect_root(s, o[ok], d[ok], t[ok] - 0.2, t[ok] + 0.2)
    assert float((t_b - t[ok]).abs().max()) < 1e-10


def test_modes_agree_on_values():
    for s in _freeform_surfaces().values():
        o, d = _random_rays(200, 6.0, seed=4)
        v = torch.ones(200, dtype=torch.bool)
        ti, xi, oki = intersect(s, o, d, v, TraceOptions(mode="implicit"))
        tu, xu, oku = intersect(s, o, d, v, TraceOptions(mode="unrolled"))
        assert torch.equal(oki, oku)
        assert float((ti - tu)[oki].abs().max()) < 1e-12


def test_plane_closed_form():
    s = Plane(5.0)
    o, d = _random_rays(100, 5.0, seed=6)
    t, x, ok = intersect(s, o, d, torch.ones(100, dtype=torch.bool))
    assert bool(ok.all())
    assert torch.allclose(t, -o[:, 2] / d[:, 2], rtol=0, atol=1e-13)
    assert float(x[:, 2].abs().max()) < 1e-13


def test_incoming_invalid_stays_invalid():
    s = Sphere(1 / 20.0, 10.0)
    o, d = _random_rays(50, 10.0, seed=7)
    valid = torch.arange(50) % 2 == 0
    _, _, ok = intersect(s, o, d, valid)
    assert not bool(ok[~valid].any())
    assert bool(ok[valid].all())


def test_miss_is_invalid_and_finite():
    """A ray passing beside a small sphere (negative discriminant) and one that hits outside the
    clear aperture are invalid, with finite t and x."""
    s = Sphere(1 / 5.0, 4.0)
    o = torch.tensor([[8.0, 0.0, -1.0], [4.5, 0.0, -1.0], [0.0, 0.0, -1.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0]] * 3, dtype=F64)
    for mode in ("implicit", "unrolled"):
        t, x, ok = intersect(s, o, d, torch.ones(3, dtype=torch.bool), TraceOptions(mode=mode))
        assert ok.tolist() == [False, False, True]
        assert bool(torch.isfinite(t).all() and torch.isfinite(x).all())
    # without aperture clipping the ray at r = 4.5 < R is valid, the one at r = 8 > R is not
    _, _, ok = intersect(s, o, d, torch.ones(3, dtype=torch.bool),
                         TraceOptions(clip_aperture=False))
    assert ok.tolist() == [False, True, True]


def test_surface_behind_ray_is_invalid():
    s = Sphere(1 / 20.0, 10.0)
    o = torch.tensor([[0.5, 0.0, 2.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0]], dtype=F64)
    t, x, ok = intersect(s, o, d, torch.ones(1, dtype=torch.bool))
    assert not bool(ok[0])
    assert bool(torch.isfinite(t).all())


def test_ray_parallel_to_vertex_plane_is_invalid():
    s = Sphere(1 / 20.0, 10.0)
    o = torch.tensor([[-20.0, 0.0, 0.5], [-20.0, 0.0, 0.5]], dtype=F64)
    d = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 1e-14]], dtype=F64)
    t, x, ok = intersect(s, o, d, torch.ones(2, dtype=torch.bool))
    assert not bool(ok.any())
    assert bool(torch.isfinite(t).all() and torch.isfinite(x).all())


def test_out_of_conic_domain_is_invalid():
    """An oblate ellipsoid (k > 0) is defined only for r < 1 / (c sqrt(1 + k))."""
    s = Asphere(1 / 10.0, 4.0, conic=3.0)  # domain r < 5 mm
    o = torch.tensor([[5.5, 0.0, -1.0], [3.0, 0.0, -1.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=F64)
    t, x, ok = intersect(s, o, d, torch.ones(2, dtype=torch.bool),
                         TraceOptions(clip_aperture=False))
    assert ok.tolist() == [False, True]
    assert bool(torch.isfinite(t).all() and torch.isfinite(x).all())


def test_nonconvergence_is_invalid():
    """One Newton step cannot reach 1e-10 on a strongly aspheric surface: invalid, finite."""
    s = Asphere(1 / 8.0, 6.0, conic=-2.0, coefficients=[1e-3])
    o, d = _random_rays(50, 6.0, seed=8)
    t, x, ok = intersect(s, o, d, torch.ones(50, dtype=torch.bool), TraceOptions(max_iter=1))
    t2, x2, ok2 = intersect(s, o, d, torch.ones(50, dtype=torch.bool))
    assert bool(ok2.sum() > 40)
    assert int(ok.sum()) < int(ok2.sum())
    assert bool(torch.isfinite(t).all())


def test_intersect_options_validation():
    with pytest.raises(ValueError, match="mode"):
        TraceOptions(mode="fast")
    with pytest.raises(ValueError, match="max_iter"):
        TraceOptions(max_iter=0)
    with pytest.raises(ValueError, match="tol"):
        TraceOptions(tol=0.0)
    assert default_tolerance(F64) == 1e-10
    assert default_tolerance(torch.float32) == 1e-5


@pytest.mark.parametrize("radius", [20.0, -20.0])
@pytest.mark.parametrize("direction", [1.0, -1.0], ids=["forward", "backward"])
def test_grazing_incidence_finds_the_first_crossing(radius, direction):
    """Rays travelling along ``direction`` in z that meet the cap at P with incidence 60 to 89.9
    deg: Newton must return P (t = 10), not the exit point of the chord through the sphere
    (2 R cos(inc) further on)."""
    s = Sphere(1 / radius, 9.0)
    o, d, p = [], [], []
    for r0 in (2.0, 6.0, 8.5):
        for inc in (60.0, 85.0, 89.0, 89.9):
            R = radius
            P = torch.tensor([-r0, 0.0, R - math.copysign(1.0, R) * math.sqrt(R * R - r0 * r0)],
                             dtype=F64)
            n = (P - torch.tensor([0.0, 0.0, R], dtype=F64)) / R
            n = n if n[2] * direction > 0 else -n      # the normal along the travel direction
            tang = torch.tensor([n[2], 0.0, -n[0]], dtype=F64)
            tang = tang if tang[2] * direction > 0 else -tang
            a = math.radians(inc)
            di = math.cos(a) * n + math.sin(a) * tang
            o.append(P - 10.0 * di)
            d.append(di)
            p.append(P)
    o, d, p = torch.stack(o), torch.stack(d), torch.stack(p)
    t, x, ok = intersect(s, o, d, torch.ones(len(o), dtype=torch.bool))
    assert bool(ok.all())
    assert float((t - 10.0).abs().max()) < 1e-9
    assert float((x - p).abs().max()) < 1e-9


# ---------------------------------------------------------------- issue 12, defects 1 and 3
def _stray_and_good_rays(dtype):
    """One on-axis ray and one stray ray 1e-6 degrees from grazing (|d_z| ~ 1.7e-8): its
    vertex-plane hit ``t0`` is ~1.7e8 mm away, where the asphere's polynomial overflows float32."""
    th = math.radians(90 - 1e-6)
    o = torch.tensor([[0.0, 0.5, -3.0], [0.0, 0.0, -3.0]], dtype=dtype)
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, math.sin(th), math.cos(th)]], dtype=dtype)
    return o, d


@pytest.mark.parametrize("mode", ["implicit", "unrolled"])
def test_grazing_stray_ray_keeps_other_rays_gradients_finite(mode):
    """Regression (issue 12, defect 1): in float32 the differentiable Newton step evaluated the
    residual of a ray that had already failed at ``o + t0 d`` (1.7e8 mm away), the sag
    overflowed to inf and the masked ``0 * inf`` turned the *other* ray's gradient with respect
    to a shared parameter (a misalignment tilt) into NaN.  The good ray's gradient must equal
    the one it has when traced alone."""
    from deeplens.optics.io import load_lens
    from deeplens.optics.rays import Rays

    from helpers import LENS_DIR, WAVELENGTH_D

    lens = load_lens(LENS_DIR / "double_gauss.json").float()
    tilt = lens.misalignments[0].tilt_x
    tilt.requires_grad_(True)
    opt = TraceOptions(mode=mode)
    o, d = _stray_and_good_rays(torch.float32)
    out = lens.trace_to_sensor(Rays(o, d, WAVELENGTH_D), options=opt)
    assert out.valid.tolist() == [True, False]
    (g_both,) = torch.autograd.grad(out.o[0, 1], tilt)
    alone = lens.trace_to_sensor(Rays(o[:1], d[:1], WAVELENGTH_D), options=opt)
    (g_alone,) = torch.autograd.grad(alone.o[0, 1], tilt)
    assert bool(torch.isfinite(g_both)), f"gradient {float(g_both)}"
    assert float(g_alone) != 0.0
    assert float(g_both) == pytest.approx(float(g_alone), rel=1e-6)


def _scaled_double_gauss(k):
    """The double Gauss with every length multiplied by ``k`` (curvatures / k, a_{2i} k^(1-2i))."""
    from deeplens.optics.io import lens_from_dict, lens_to_dict, load_lens

    from helpers import LENS_DIR

    spec = lens_to_dict(load_lens(LENS_DIR / "double_gauss.json"))
    for s in spec["surfaces"]:
        s["distance_mm"] *= k
        s["semi_diameter_mm"] *= k
        if "curvature_per_mm" in s:
            s["curvature_per_mm"] /= k
        if "aspheric" in s:
            s["aspheric"] = [a * k ** (1 - 2 * (i + 2)) for i, a in enumerate(s["aspheric"])]
    spec["sensor"]["distance_mm"] *= k
    if spec["sensor"].get("semi_diameter_mm"):
        spec["sensor"]["semi_diameter_mm"] *= k
    return lens_from_dict(spec)


def _valid_count(lens, dtype):
    from deeplens.optics.sampling import field_rays, random_disk

    from helpers import WAVELENGTH_D

    lens = lens.to(dtype)
    pupil = random_disk(2000, seed=3, dtype=dtype) * 0.6 * float(lens.surfaces[0].semi_diameter)
    rays = field_rays(lens, 10.5, WAVELENGTH_D, pupil, float(lens.z_vertices()[0]))
    with torch.no_grad():
        return int(lens.trace_to_sensor(rays).valid.sum())


@pytest.mark.parametrize("scale", [100.0, 1000.0])
def test_float32_large_lens_keeps_the_rays_float64_keeps(scale):
    """Regression (issue 12, defect 3): with an absolute 1e-5 mm tolerance, float32 rays through
    the double Gauss scaled x100 (x1000) were silently dropped once rounding of coordinates of
    hundreds of mm exceeded it (867 (633) of float64's 902 rays here).  The tolerance now
    follows the coordinates' scale."""
    lens = _scaled_double_gauss(scale)
    n64 = _valid_count(lens, torch.float64)
    assert n64 > 800
    assert _valid_count(lens, torch.float32) == n64


def test_rays_lost_to_rounding_raise_a_warning(monkeypatch):
    """The safety net of defect 3: with the tolerance forced back to the absolute 1e-5 mm, the
    rays of the x1000 lens that stall short of it are reported (not dropped silently)."""
    import deeplens.optics.intersect as mod

    lens = _scaled_double_gauss(1000.0)
    monkeypatch.setattr(mod, "_ROUNDING_ULPS", 0.0)
    with pytest.warns(RuntimeWarning, match=r"rays did not converge on a \w+ .*float32"):
        _valid_count(lens, torch.float32)


def test_tolerance_floor_follows_coordinates():
    """``max(tol, 4 eps |x|_inf)``: the user's tolerance near the vertex, rounding far out."""
    import deeplens.optics.intersect as mod

    x = torch.tensor([[0.0, 1.0, 0.0], [0.0, -3000.0, 10.0]], dtype=torch.float32)
    tol = mod._tolerance(1e-5, x)
    assert float(tol[0]) == pytest.approx(1e-5)
    assert float(tol[1]) == pytest.approx(4 * torch.finfo(torch.float32).eps * 3000.0)
