"""OpticStudio's Irregular surface (:class:`~deeplens.optics.surfaces.Irregular`, ``IRREGULA``):
the sag against the User Guide's formula written independently (polar form, ``w = ρ sin(φ + θ)``),
on the surface's own frame placed by the coordinate break it is defined by; slopes and every
parameter's derivative against central differences (float64); a trace gradient; closed-form
reductions: no terms, decenter or tilt is the STANDARD conic, ``Zs`` alone the even asphere's
``r⁴`` term, a decentred and tilted conic the conic between the two coordinate breaks of
OpticStudio's definition; the paraxial curvature against the sag's second derivative; the lens
file round-trips."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Asphere, CoordinateBreak, Irregular, Plane

F64 = torch.float64
# the OpticStudio sample's values (mm, degrees), with a non-zero angle and conic added
C, K, RMAX = 0.009889001, -0.3, 24.0
DEC, TILT_DEG = (-4.0, 0.5), (0.1, -0.07)
ZS, ZA, ZC, TH_DEG = -0.0666667, -0.3, 0.1, 25.0


def _surface(decenter=DEC, tilt_deg=TILT_DEG, zs=ZS, za=ZA, zc=ZC, th_deg=TH_DEG, k=K, sd=20.0):
    return Irregular(C, sd, RMAX, conic=k, decenter=decenter,
                     tilt=tuple(math.radians(t) for t in tilt_deg), z_spherical=zs,
                     z_astigmatism=za, z_coma=zc, angle=math.radians(th_deg))


def _closed_form(xs, ys, zs=ZS, za=ZA, zc=ZC, th_deg=TH_DEG, k=K):
    """The User Guide's sag in the surface's frame, polar form (float64 numbers)."""
    r2 = xs * xs + ys * ys
    rho, phi = math.sqrt(r2) / RMAX, math.atan2(ys, xs)
    w = rho * math.sin(phi + math.radians(th_deg))   # the coordinate along the line at θ from y
    base = C * r2 / (1 + math.sqrt(1 - (1 + k) * C * C * r2))
    return base + zs * rho ** 4 + za * w * w + zc * rho * rho * w


POINTS = [(0.0, 0.0), (3.0, -7.5), (-12.0, 4.0), (15.5, 9.0), (-1.0, -18.0), (11.0, 0.0)]


def test_the_sag_is_the_user_guides_formula_in_the_tilted_decentred_frame():
    """Points ``p = δ + R p'`` (``R`` the coordinate break's rotation for the same tilts, order 0)
    of the closed-form surface satisfy ``f(p) = 0`` and ``sag(x, y) = z`` (1e-12 mm)."""
    s = _surface()
    cb = CoordinateBreak(*DEC, *(math.radians(t) for t in TILT_DEG))
    R = cb.rotation(torch.zeros((), dtype=F64))
    for xs, ys in POINTS:
        pp = torch.tensor([xs, ys, _closed_form(xs, ys)], dtype=F64)
        p = R @ pp + torch.tensor([*DEC, 0.0], dtype=F64)
        x, y, z = p.unbind()
        assert abs(float(s.f(x, y, z))) < 1e-12
        assert float(s.sag(x, y)) == pytest.approx(float(z), abs=1e-12)
        assert float(s.own_sag(torch.tensor(xs, dtype=F64), torch.tensor(ys, dtype=F64))) == \
            pytest.approx(_closed_form(xs, ys), abs=1e-14)


def test_astigmatism_and_coma_lie_along_the_line_at_theta_from_y():
    """With θ = 0 the astigmatism is ``Za (y/r_max)²`` and the coma ``Zc ρ² y / r_max``: nothing
    on the x axis, odd in y; at θ = 90° they lie along x."""
    for th, (xs, ys) in ((0.0, (0.0, 12.0)), (90.0, (12.0, 0.0))):
        s = _surface(decenter=(0.0, 0.0), tilt_deg=(0.0, 0.0), zs=0.0, k=0.0, th_deg=th)
        t = torch.tensor
        on = float(s.own_sag(t(xs, dtype=F64), t(ys, dtype=F64)))
        back = float(s.own_sag(t(-xs, dtype=F64), t(-ys, dtype=F64)))
        across = float(s.own_sag(t(ys, dtype=F64), t(xs, dtype=F64)))
        base = C * 144.0 / (1 + math.sqrt(1 - C * C * 144.0))
        assert on - base == pytest.approx(ZA * 0.25 + ZC * 0.125, rel=1e-12)
        assert back - base == pytest.approx(ZA * 0.25 - ZC * 0.125, rel=1e-12)
        assert across - base == pytest.approx(0.0, abs=1e-15)


def test_slopes_and_parameter_derivatives_match_central_differences():
    """``f_grad`` against central differences of ``f`` in x, y, z, and autograd's ``∂f/∂θ`` for
    every parameter against central differences (float64: truncation ~h², rounding ~1e-16/h)."""
    s = _surface()
    g = torch.Generator().manual_seed(1)
    x, y = (torch.rand(40, generator=g, dtype=F64) * 30 - 15 for _ in range(2))
    z = s.sag(x, y) + 0.05 * torch.randn(40, generator=g, dtype=F64)
    h = 1e-6
    fx, fy, fz = s.f_grad(x, y, z)
    for got, dx in ((fx, (h, 0, 0)), (fy, (0, h, 0)), (fz, (0, 0, h))):
        fd = (s.f(x + dx[0], y + dx[1], z + dx[2]) - s.f(x - dx[0], y - dx[1], z - dx[2])) / (2 * h)
        assert torch.allclose(got, fd, rtol=1e-7, atol=1e-9)
    for name in ("c", "k", "dx", "dy", "tilt_x", "tilt_y", "zs", "za", "zc", "angle"):
        p = getattr(s, name)
        p.requires_grad_(True)
        ad, = torch.autograd.grad(s.f(x, y, z).sum(), p)
        p.requires_grad_(False)
        hp = 1e-6 * max(1.0, abs(float(p)))
        with torch.no_grad():
            p += hp
            up = float(s.f(x, y, z).sum())
            p -= 2 * hp
            down = float(s.f(x, y, z).sum())
            p += hp
        fd = (up - down) / (2 * hp)
        assert abs(fd) > 1e-6, name
        assert float(ad) == pytest.approx(fd, rel=1e-6), name


def _singlet(front, n=1.5168):
    mats = [Air(), ModelGlass(n, 64.17), Air()]
    return Lens([front, Plane(20.0)], mats, [0.0, 8.0], 90.0, 0)


def _rays(n=9, slope=(0.0, 0.0)):
    r = torch.linspace(-14.0, 14.0, n, dtype=F64)
    o = torch.stack([0.3 * r, r, torch.full_like(r, -2.0)], -1)
    d = torch.tensor([slope[0], slope[1], 1.0], dtype=F64)
    return Rays(o, (d / d.norm()).expand(n, 3), 587.6)


def test_without_terms_decenter_or_tilt_it_is_the_standard_conic():
    s = _surface(decenter=(0.0, 0.0), tilt_deg=(0.0, 0.0), zs=0.0, za=0.0, zc=0.0)
    a = Asphere(C, 20.0, conic=K)
    g = torch.Generator().manual_seed(2)
    x, y = (torch.rand(50, generator=g, dtype=F64) * 28 - 14 for _ in range(2))
    assert torch.equal(s.sag(x, y), a.sag(x, y))
    for rays in (_rays(), _rays(slope=(0.03, -0.05))):
        with torch.no_grad():
            p, q = _singlet(s).trace_to_sensor(rays), _singlet(a).trace_to_sensor(rays)
        assert p.valid.all() and q.valid.all()
        assert torch.allclose(p.o, q.o, rtol=0, atol=1e-12)
        assert torch.allclose(p.d, q.d, rtol=0, atol=1e-14)


def test_spherical_term_alone_is_the_even_aspheres_r4_term():
    s = _surface(decenter=(0.0, 0.0), tilt_deg=(0.0, 0.0), za=0.0, zc=0.0)
    a = Asphere(C, 20.0, conic=K, coefficients=[ZS / RMAX ** 4])
    g = torch.Generator().manual_seed(3)
    x, y = (torch.rand(50, generator=g, dtype=F64) * 28 - 14 for _ in range(2))
    assert torch.allclose(s.sag(x, y), a.sag(x, y), rtol=0, atol=1e-15)


def test_a_decentred_tilted_conic_traces_as_the_conic_between_two_coordinate_breaks():
    """OpticStudio: "the tilt and decenter values work exactly like the coordinate break ...
    undone after the ray is traced to the surface".  The same conic between a break (decenter,
    tilt x, tilt y, order 0) and the break that undoes it (the values negated, order 1): real
    rays on the sensor agree to 1e-11 mm."""
    s = _surface(zs=0.0, za=0.0, zc=0.0)
    a, b = (math.radians(t) for t in TILT_DEG)
    cb1 = CoordinateBreak(DEC[0], DEC[1], a, b, 0.0, 20.0)
    cb2 = CoordinateBreak(-DEC[0], -DEC[1], -a, -b, 0.0, 20.0, order=1)
    glass = ModelGlass(1.5168, 64.17)
    ref = Lens([cb1, Asphere(C, 20.0, conic=K), cb2, Plane(20.0)],
               [Air(), Air(), glass, glass, Air()], [0.0, 0.0, 0.0, 8.0], 90.0, 1)
    for rays in (_rays(), _rays(slope=(0.03, -0.05))):
        with torch.no_grad():
            p, q = _singlet(s).trace_to_sensor(rays), ref.trace_to_sensor(rays)
        assert p.valid.all() and q.valid.all()
        assert torch.allclose(p.o, q.o, rtol=0, atol=1e-11)
        assert torch.allclose(p.d, q.d, rtol=0, atol=1e-13)


def test_trace_gradient_matches_central_differences():
    """d/dθ of Σ (x² + y²) on the sensor plus Σ opl, θ = Zc, tilt_x, dx (float64)."""
    for name, h in (("zc", 1e-5), ("tilt_x", 1e-6), ("dx", 1e-5)):
        def q(delta):
            s = _surface()
            with torch.no_grad():
                getattr(s, name).add_(delta)
            getattr(s, name).requires_grad_(True)
            out = _singlet(s).trace_to_sensor(_rays(slope=(0.01, 0.02)))
            assert out.valid.all()
            return (out.o[:, :2] ** 2).sum() + out.opl.sum(), getattr(s, name)

        v, p = q(0.0)
        ad, = torch.autograd.grad(v, p)
        fd = float((q(h)[0] - q(-h)[0]).detach()) / (2 * h)
        assert abs(fd) > 1e-3, name
        assert float(ad) == pytest.approx(fd, rel=1e-5), name


def test_paraxial_curvature_is_the_y_section_at_the_vertex():
    """``c + 2 Za cos²θ / r_max²`` against the second difference of the sag along y at the
    vertex (no decenter or tilt; truncation ~h² z'''' ≈ 1e-10, rounding 1e-16/h²)."""
    s = _surface(decenter=(0.0, 0.0), tilt_deg=(0.0, 0.0))
    h = 1e-3
    y = torch.tensor([-h, 0.0, h], dtype=F64)
    z = s.sag(torch.zeros(3, dtype=F64), y)
    second = float((z[0] - 2 * z[1] + z[2]) / h ** 2)
    want = C + 2 * ZA * math.cos(math.radians(TH_DEG)) ** 2 / RMAX ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(want, rel=1e-15)
    assert second == pytest.approx(want, rel=1e-7)


def test_lens_file_round_trip():
    lens = _singlet(_surface())
    d = lens_to_dict(lens)
    e = d["surfaces"][0]
    assert e["type"] == "irregular" and e["r_max_mm"] == RMAX
    assert e["tilt_x_rad"] == math.radians(TILT_DEG[0]) and e["z_coma_mm"] == ZC
    back = lens_from_dict(d)
    assert lens_to_dict(back) == d
    rays = _rays(slope=(0.01, 0.02))
    with torch.no_grad():
        assert torch.equal(back.trace_to_sensor(rays).o, lens.trace_to_sensor(rays).o)
