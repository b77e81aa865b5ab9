"""The Binary 2 diffractive surface (:mod:`deeplens.optics.surfaces.binary2`, OpticStudio's
``BINARY_2``): zero phase is the bare even asphere, a flat ``A_1`` lens focuses at the closed-form
``f = -π R_n² / (M A_1 λ)`` (1/λ dispersion, real and paraxial), the ray law against the local
grating equation computed here and against optiland's phase surface (a test-only oracle), the
optical path against Malus' theorem (a hyperbolic phase: one optical path to the focus), and
gradients against central differences in float64."""

from __future__ import annotations

import math
import warnings

import helpers
import pytest
import torch

from deeplens.optics.options import TraceOptions
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Asphere, Binary2, Plane
from deeplens.optics.tracer import fused_kind

F64 = torch.float64


def _single(surface, n_after=1.0, mirror=False, dist=10.0):
    """One surface at z = 0 (the stop), air before, a non-dispersive medium of index ``n_after``
    (air for a mirror) after, the sensor ``dist`` mm away along the direction of travel."""
    after = Air() if mirror or n_after == 1.0 else ModelGlass(n_after, math.inf)
    return Lens([surface], [Air(), after], [0.0], -dist if mirror else dist, 0,
                mirrors=(0,) if mirror else ())


def _parallel(h, wavelength, x=None):
    """Rays along +z at heights ``h`` (y; ``x`` too if given), starting at z = -1."""
    h = torch.as_tensor(h, dtype=F64)
    xx = torch.zeros_like(h) if x is None else torch.as_tensor(x, dtype=F64)
    o = torch.stack([xx, h, torch.full_like(h, -1.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand_as(o)
    return Rays(o, d, wavelength)


def _skew(n=24, seed=0, wavelength=587.0, spread=2.5):
    g = torch.Generator().manual_seed(seed)
    th = torch.empty(n, dtype=F64).uniform_(-12, 12, generator=g).deg2rad()
    ph = torch.empty(n, dtype=F64).uniform_(-12, 12, generator=g).deg2rad()
    d = torch.stack([torch.sin(ph), torch.sin(th), torch.cos(th) * torch.cos(ph)], -1)
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    o = torch.empty(n, 3, dtype=F64).uniform_(-spread, spread, generator=g)
    o[:, 2] = -2.0
    return Rays(o, d, wavelength)


@pytest.mark.parametrize("mirror", [False, True])
def test_zero_phase_is_the_bare_even_asphere(mirror):
    """All A_i = 0 on a curved conic with a4, a6: the same hits, directions and optical paths
    as the plain Asphere, bit for bit (the kick is 0, the phase path 0)."""
    b = Binary2(1 / 35.0, 6.0, 3.0, [0.0, 0.0], 1, conic=-0.7, coefficients=[2e-5, -3e-7])
    a = Asphere(1 / 35.0, 6.0, conic=-0.7, coefficients=[2e-5, -3e-7])
    rays = _skew()
    ob = _single(b, 1.6, mirror=mirror).trace_to_sensor(rays)
    oa = _single(a, 1.6, mirror=mirror).trace_to_sensor(rays)
    assert ob.valid.all() and torch.equal(ob.valid, oa.valid)
    assert (ob.o - oa.o).abs().max() <= 1e-14
    assert (ob.d - oa.d).abs().max() <= 1e-15
    assert (ob.opl - oa.opl).abs().max() <= 1e-14


@pytest.mark.parametrize("wl", [486.1, 587.6, 656.3])
def test_flat_a1_lens_focuses_at_the_closed_form_focal_length(wl):
    """Only A_1, flat, in air: a parallel ray at height h leaves with sin θ' = -h / f, f = -π
    R_n² / (M A_1 λ), so it crosses the axis at z = f sqrt(1 - (h/f)²) (exact, not only
    paraxially); the paraxial EFL is f at every wavelength (f λ constant: 1/λ dispersion)."""
    rn, a1, m = 5.0, -1800.0, 1
    f = -math.pi * rn ** 2 / (m * a1 * wl * 1e-6)
    lens = _single(Binary2(0.0, 6.0, rn, [a1], m))
    h = torch.tensor([-4.0, -1.0, 0.3, 2.0, 5.0], dtype=F64)
    out = lens.trace(_parallel(h, wl))
    assert out.valid.all()
    assert torch.allclose(out.d[:, 1], -h / f, atol=1e-15, rtol=0)
    z_cross = out.o[:, 2] - out.o[:, 1] * out.d[:, 2] / out.d[:, 1]
    expect = f * torch.sqrt(1 - (h / f) ** 2)
    assert torch.allclose(z_cross, expect, atol=1e-11 * f, rtol=0)
    p = paraxial(lens, wl)
    assert float(p.efl) == pytest.approx(f, rel=1e-14)
    # the 1/λ dispersion: f λ is the same at every wavelength (f(486.1) > f(656.3) is the
    # opposite of glass)
    assert float(p.efl) * wl == pytest.approx(-math.pi * rn ** 2 / (m * a1 * 1e-6), rel=1e-14)


def test_sign_of_the_order_and_the_power_of_rho():
    """M = -1 with A_1 > 0 is the same lens as M = +1 with A_1 < 0; M = +1 with A_1 > 0
    diverges (d_y has the sign of h).  A lone A_2 kicks by λ/(2π) M A_2 4 r³ / R_n⁴ (a wrong
    power of ρ, or a wrong sign, fails here)."""
    wl, rn = 550.0, 4.0
    h = torch.tensor([-3.0, 0.5, 2.5], dtype=F64)
    conv = _single(Binary2(0.0, 5.0, rn, [-1000.0], 1)).trace(_parallel(h, wl))
    flip = _single(Binary2(0.0, 5.0, rn, [1000.0], -1)).trace(_parallel(h, wl))
    div = _single(Binary2(0.0, 5.0, rn, [1000.0], 1)).trace(_parallel(h, wl))
    assert (conv.d[:, 1] * h < 0).all() and (div.d[:, 1] * h > 0).all()
    assert torch.equal(conv.d, flip.d)
    assert torch.allclose(div.d[:, 1], -conv.d[:, 1], atol=1e-16, rtol=0)
    a2, m = 80.0, 2
    out = _single(Binary2(0.0, 5.0, rn, [0.0, a2], m)).trace(_parallel(h, wl))
    kick = wl * 1e-6 / (2 * math.pi) * m * a2 * 4 * h ** 3 / rn ** 4
    assert torch.allclose(out.d[:, 1], kick, atol=1e-16, rtol=0)
    assert float(kick.abs().max()) > 1e-3


def test_direction_obeys_the_local_grating_equation_on_a_curved_base():
    """On a sphere into glass, skew rays: at deeplens' hit point the outgoing direction is
    n' d' = n d + λ/(2π) ∇_t Φ + γ N with the sphere's normal, the phase gradient and the
    tangential projection computed here, γ from |d'| = 1 on the far side."""
    c, rn, A, m, wl, n2 = 1 / 25.0, 3.0, [-600.0, 40.0, -5.0], -1, 600.0, 1.7
    lens = _single(Binary2(c, 5.0, rn, A, m), n2)
    rays = _skew(32, seed=3, wavelength=wl)
    out = lens.trace(rays)
    assert out.valid.all()
    x, y, z = out.o.unbind(-1)
    N = torch.stack([c * x, c * y, c * z - 1.0], -1)
    N = N / torch.linalg.vector_norm(N, dim=-1, keepdim=True)
    rho2 = (x * x + y * y) / rn ** 2
    dphi_dr2 = m * sum((i + 1) * a * rho2 ** i for i, a in enumerate(A)) / rn ** 2
    g = torch.stack([2 * x * dphi_dr2, 2 * y * dphi_dr2, torch.zeros_like(x)], -1)
    v = rays.d + wl * 1e-6 / (2 * math.pi) * g
    t = v - (v * N).sum(-1, keepdim=True) * N
    t = t / n2
    dn = torch.sqrt(1 - (t * t).sum(-1, keepdim=True))
    expect = t + dn * torch.sign((rays.d * N).sum(-1, keepdim=True)) * N
    assert (out.d - expect).abs().max() <= 2e-15
    # the kick is not negligible here (the test would pass without the phase otherwise)
    bare = _single(Asphere(c, 5.0), n2).trace(rays)
    assert (bare.d - out.d).abs().max() > 1e-3


def test_reflecting_binary2_follows_the_same_law():
    """GLAS MIRROR: d' = t + λ/(2π n) ∇_t Φ - sqrt(...) N back towards the object."""
    c, rn, A, wl = -1 / 40.0, 3.0, [-500.0, 30.0], 520.0
    lens = _single(Binary2(c, 5.0, rn, A, 1), mirror=True)
    rays = _skew(16, seed=5, wavelength=wl)
    out = lens.trace(rays)
    assert out.valid.all() and (out.d[:, 2] < 0).all()
    x, y, z = out.o.unbind(-1)
    N = torch.stack([c * x, c * y, c * z - 1.0], -1)
    N = N / torch.linalg.vector_norm(N, dim=-1, keepdim=True)
    rho2 = (x * x + y * y) / rn ** 2
    dphi_dr2 = sum((i + 1) * a * rho2 ** i for i, a in enumerate(A)) / rn ** 2
    g = torch.stack([2 * x * dphi_dr2, 2 * y * dphi_dr2, torch.zeros_like(x)], -1)
    v = rays.d + wl * 1e-6 / (2 * math.pi) * g
    t = v - (v * N).sum(-1, keepdim=True) * N
    dn = torch.sqrt(1 - (t * t).sum(-1, keepdim=True))
    expect = t - dn * torch.sign((rays.d * N).sum(-1, keepdim=True)) * N
    assert (out.d - expect).abs().max() <= 2e-15


def _hyperbolic(f, wl0, rn, terms=10):
    """A_i (M = 1) of Φ = -(2π/λ0) (sqrt(r² + f²) - f), the series of sqrt(1 + u) - 1 in
    u = r²/f² = ρ² R_n²/f²: a perfect lens at λ0."""
    k = 2 * math.pi / (wl0 * 1e-6)
    out, binom = [], 1.0
    for i in range(1, terms + 1):
        binom *= (0.5 - (i - 1)) / i     # C(1/2, i)
        out.append(-k * f * binom * (rn * rn / (f * f)) ** i)
    return out


def test_optical_path_obeys_malus_with_a_hyperbolic_phase():
    """A flat surface with the hyperbolic phase focuses a plane wave perfectly at λ0: every
    ray is aimed at (0, 0, f), and the optical path from the plane z = -1 to the focus is the
    same for all (1e-12 mm), which holds only with + λ Φ / 2π in the path (with the phase
    left out the spread is the sag of the wavefront, ~0.1 mm here)."""
    f, wl0, rn = 40.0, 632.8, 4.0
    surf = Binary2(0.0, 5.0, rn, _hyperbolic(f, wl0, rn), 1)
    lens = _single(surf, dist=f)
    g = torch.Generator().manual_seed(1)
    xy = torch.empty(40, 2, dtype=F64).uniform_(-2.8, 2.8, generator=g)
    out = lens.trace(_parallel(xy[:, 1], wl0, x=xy[:, 0]))
    assert out.valid.all()
    to_focus = torch.tensor([0.0, 0.0, f], dtype=F64) - out.o
    dist = torch.linalg.vector_norm(to_focus, dim=-1)
    assert (out.d - to_focus / dist[:, None]).abs().max() <= 1e-14
    total = out.opl + dist
    assert float(total.max() - total.min()) <= 1e-12
    geometric = (out.opl - surf.phase_opl(out.o, wl0)) + dist
    assert float(geometric.max() - geometric.min()) > 1e-2


def test_evanescent_rays_are_invalid_with_finite_values():
    """Beyond the radius where λ |∇Φ| / 2π > 1 no order propagates: those rays go invalid,
    keep finite values, and the valid ones still give finite gradients."""
    s = Binary2(0.0, 5.0, 1.0, [-2e4], 1)
    s.A[0].requires_grad_(True)
    lens = _single(s)
    wl = 600.0
    # |sin θ'| = h / f with f = π / (2e4 λ) = 0.2618 mm
    h = torch.tensor([0.1, 0.2, 0.3, 1.0], dtype=F64)
    out = lens.trace_to_sensor(_parallel(h, wl))
    assert out.valid.tolist() == [True, True, False, False]
    assert torch.isfinite(out.o).all() and torch.isfinite(out.d).all()
    (out.o[:, 1] * out.valid).sum().backward()
    assert torch.isfinite(s.A[0].grad) and float(s.A[0].grad) != 0.0


def test_matches_optilands_phase_surface():
    """optiland's radial phase on a plane (``RadialPhaseProfile`` + ``PhaseInteractionModel``,
    k'_∥ = k_∥ + ∇φ, OPD + φ/k0) with φ's coefficients M A_i / R_n^{2i}, into n = 1.5: skew
    rays leave in the same direction and land on the image 20 mm behind at the same position
    with the same optical path (1e-12)."""
    pytest.importorskip("optiland")
    from optiland.materials import IdealMaterial
    from optiland.optic import Optic
    from optiland.phase.radial import RadialPhaseProfile

    m, rn, A, wl = 1, 4.0, [-900.0, 35.0, -2.0], 550.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = Optic()
        op.add_surface(index=0, thickness=math.inf)
        op.add_surface(index=1, thickness=20.0, is_stop=True, material=IdealMaterial(n=1.5),
                       phase_profile=RadialPhaseProfile(
                           [m * a / rn ** (2 * (i + 1)) for i, a in enumerate(A)]))
        op.add_surface(index=2)
        op.set_aperture(aperture_type="EPD", value=6.0)
        op.set_field_type("angle")
        op.add_field(y=0)
        op.add_field(y=10)
        op.add_wavelength(wl / 1000, is_primary=True)
    lens = Lens([Binary2(0.0, 5.0, rn, A, m)], [Air(), ModelGlass(1.5, math.inf)], [0.0],
                20.0, 0)
    checked = 0
    for H, P in [((0.0, 0.0), (0.0, 1.0)), ((0.3, 0.8), (-0.4, 0.6)),
                 ((0.0, 1.0), (0.7, -0.7)), ((1.0, 0.0), (0.2, 0.9))]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            op.trace_generic(Hx=H[0], Hy=H[1], Px=P[0], Py=P[1], wavelength=wl / 1000)
            sg = op.surface_group

        def at(name, i, sg=sg):
            return float(torch.as_tensor(getattr(sg, name)).reshape(3, -1)[i, 0])

        o = torch.tensor([[at("x", 0), at("y", 0), at("z", 0)]], dtype=F64)
        d = torch.tensor([[at("L", 0), at("M", 0), at("N", 0)]], dtype=F64)
        out = lens.trace_to_sensor(Rays(o, d, wl), options=TraceOptions(clip_aperture=False))
        assert bool(out.valid[0])
        got = out.o[0].tolist() + out.d[0].tolist() + [float(out.opl[0])]
        # optiland's direction on the image plane is refracted again into its air: the
        # direction is taken after the phase surface (index 1), position and path on the image
        ref = ([at(k, 2) for k in ("x", "y", "z")] + [at(k, 1) for k in ("L", "M", "N")]
               + [at("opd", 2)])
        assert got == pytest.approx(ref, abs=1e-12), (H, P)
        checked += 1
    assert checked == 4


def test_gradients_match_central_differences():
    """d/dA_1, d/dA_2 and d/dc (the Binary 2 base) of image positions and optical paths of skew
    rays through a glass singlet whose rear is a Binary 2, and of the paraxial EFL, in float64
    against central differences."""
    def build(a1, a2, c):
        b = Binary2(c, 6.0, 4.0, [a1, a2], 1, conic=-0.3)
        lens = Lens([Asphere(1 / 30.0, 6.0), b], [Air(), ModelGlass(1.6, 40.0), Air()],
                    [0.0, 3.0], 30.0, 0)
        return lens, b

    def q(a1, a2, c, grad=False):
        lens, b = build(a1, a2, c)
        if grad:
            for p in (b.A[0], b.A[1], b.c):
                p.requires_grad_(True)
        out = lens.trace_to_sensor(_skew(12, seed=7, spread=1.5))
        assert out.valid.all()
        val = (out.o[:, 1] ** 2 + out.o[:, 0] * out.o[:, 1]).sum() + 0.1 * out.opl.sum()
        return val, paraxial(lens).efl, [b.A[0], b.A[1], b.c]

    # A_2 has no paraxial power
    helpers.assert_value_and_efl_grads_match_fd(q, (-300.0, 20.0, -0.01), (1e-3, 1e-3, 1e-7),
                                                powerless=(1,))


def test_traces_eager_and_round_trips_through_the_lens_file():
    lens = Lens([Plane(8.0), Binary2(-0.02, 6.0, 4.0, [-300.0, 20.0], -2, conic=0.4,
                                     coefficients=[1e-5])],
                [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 20.0, 0)
    assert fused_kind(lens, 1) is None
    d = lens_to_dict(lens)
    s = d["surfaces"][1]
    assert s["type"] == "binary2" and s["order"] == -2 and s["norm_radius_mm"] == 4.0
    assert s["phase_coefficients"] == [-300.0, 20.0] and s["aspheric"] == [1e-5]
    assert lens_to_dict(lens_from_dict(d)) == d


def test_cardinal_points_see_the_diffractive_power():
    """analysis.cardinal's system matrix adds the same power: its EFL is the closed form's at
    two wavelengths (a surface type ignored there would give an infinite EFL)."""
    from deeplens.analysis.cardinal import cardinal_points

    rn, a1 = 5.0, -1800.0
    lens = Lens([Binary2(0.0, 6.0, rn, [a1], 1)], [Air(), Air()], [0.0], 50.0, 0)
    for wl in (486.1, 656.3):
        f = -math.pi * rn ** 2 / (a1 * wl * 1e-6)
        assert float(cardinal_points(lens, wl).efl) == pytest.approx(f, rel=1e-13)
