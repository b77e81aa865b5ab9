"""The Binary 1 phase surface (OpticStudio's ``BINARY_1``): the phase against the x-y polynomial
written out here term by term from OpticStudio's published order (not deeplens' series), closed
forms for a tilt and an ``x² + y²`` lens, the paraxial power of the y-z section, real rays
against rayoptics' DiffractiveElement, float64 gradients against central differences, and the
lens-file round trip."""

from __future__ import annotations

import math

import helpers as H
import pytest
import torch

from deeplens.optics.paraxial import paraxial
from deeplens.optics.surfaces import Binary1

F64 = torch.float64

#: OpticStudio's Extended Polynomial terms 1..14 as the User Guide lists them ("the first term is
#: x, then y, then x*x, x*y, y*y, etc."; term 12 is x²y², term 13 xy³), written out by hand
TERMS = [
    lambda x, y: x, lambda x, y: y,
    lambda x, y: x * x, lambda x, y: x * y, lambda x, y: y * y,
    lambda x, y: x ** 3, lambda x, y: x * x * y, lambda x, y: x * y * y, lambda x, y: y ** 3,
    lambda x, y: x ** 4, lambda x, y: x ** 3 * y, lambda x, y: x * x * y * y,
    lambda x, y: x * y ** 3, lambda x, y: y ** 4,
]


_single, _parallel = H.single_in_air, H.parallel_rays


def test_phase_is_the_published_term_order_in_radians():
    """Φ = M Σ A_t E_t(x/R_n, y/R_n) (radians) with E_t from the list above, at points inside and
    outside R_n; the gradient against a central difference of the list (5e-6 rad/mm: h² Φ'''
    of these cubic-to-quartic terms is far below)."""
    g = torch.Generator().manual_seed(3)
    A = torch.empty(14, dtype=F64).uniform_(-1, 1, generator=g).tolist()
    rn, m = 3.0, 2
    s = Binary1(0.0, 5.0, rn, A, m)
    x = torch.empty(40, dtype=F64).uniform_(-4, 4, generator=g)
    y = torch.empty(40, dtype=F64).uniform_(-4, 4, generator=g)

    def table(x, y):
        return m * sum(a * e(x / rn, y / rn) for a, e in zip(A, TERMS))

    assert torch.allclose(s.phase(x, y), table(x, y), atol=1e-12, rtol=0)
    h = 1e-5
    gx, gy = s.phase_grad(x, y)
    fx = (table(x + h, y) - table(x - h, y)) / (2 * h)
    fy = (table(x, y + h) - table(x, y - h)) / (2 * h)
    assert torch.allclose(gx, fx, atol=5e-6, rtol=0) and torch.allclose(gy, fy, atol=5e-6, rtol=0)


@pytest.mark.parametrize("wl", [486.1, 656.3])
def test_a_tilt_deflects_every_ray_by_the_same_angle(wl):
    """A_1 (x) and A_2 (y) alone: every ray's direction cosines change by M λ A / (2π R_n)
    (λ in mm), whatever its height."""
    rn, a1, a2, m = 4.0, 300.0, -200.0, 1
    out = _single(Binary1(0.0, 5.0, rn, [a1, a2], m)).trace(
        _parallel([-3.0, 0.0, 1.0, 2.5], [2.0, -1.5, 0.0, 3.0], wl))
    assert out.valid.all()
    lam = wl * 1e-6
    for k, a in ((0, a1), (1, a2)):
        want = torch.full((4,), m * lam * a / (2 * math.pi * rn), dtype=F64)
        assert torch.allclose(out.d[:, k], want, atol=1e-16, rtol=0)


def test_a_rotationally_symmetric_square_is_a_lens_of_the_closed_form_focal_length():
    """A_3 = A_5 = a (x² + y²) alone: a ray at height h leaves with sin θ = M λ a h / (π R_n²)
    = −h / f, f = −π R_n² / (M λ a), exactly (the kick is linear in h), along x and y; the
    paraxial EFL is f."""
    rn, a, m, wl = 4.0, -1500.0, 1, 550.0
    f = -math.pi * rn ** 2 / (m * wl * 1e-6 * a)
    s = Binary1(0.0, 5.0, rn, [0.0, 0.0, a, 0.0, a], m)
    lens = _single(s)
    h = torch.tensor([-2.0, -0.5, 1.0, 2.0], dtype=F64)
    out = lens.trace(_parallel(torch.zeros_like(h), h, wl))
    assert torch.allclose(out.d[:, 1], -h / f, atol=1e-16, rtol=0)
    out = lens.trace(_parallel(h, torch.zeros_like(h), wl))
    assert torch.allclose(out.d[:, 0], -h / f, atol=1e-16, rtol=0)
    assert float(paraxial(lens, wl).efl) == pytest.approx(f, rel=1e-13)
    assert s.axisymmetric


def test_paraxial_power_is_the_y_section_of_the_phase():
    """y² (A_5) gives the y power −M λ A_5 / (π R_n²); x² (A_3), xy (A_4), y³ and x²y² none —
    against a central difference of the traced y slope at the axis."""
    rn, wl = 4.0, 550.0
    for A in ([0, 0, 0, 0, 800.0], [0, 0, 700.0], [0, 0, 0, 500.0], [0] * 8 + [300.0],
              [0] * 11 + [200.0]):
        s = Binary1(0.0, 5.0, rn, A, 1)
        h = 1e-4
        out = _single(s).trace(_parallel([0.0, 0.0], [h, -h], wl))
        phi_fd = -float(out.d[0, 1] - out.d[1, 1]) / (2 * h)
        assert float(s.paraxial_phase_power(wl)) == pytest.approx(phi_fd, rel=1e-6, abs=1e-15)
    s = Binary1(0.0, 5.0, rn, [0, 0, 0, 0, 800.0], 1)
    assert float(s.paraxial_phase_power(wl)) == pytest.approx(
        -wl * 1e-6 * 800.0 / (math.pi * rn ** 2), rel=1e-14)


def test_real_rays_match_rayoptics_diffractive_element():
    """Skew rays through a flat Binary 1 phase in air (14 random terms, M = 1, two wavelengths):
    deeplens' directions equal rayoptics' DiffractiveElement (a test-only oracle: its own grating
    law, ``d' = d + M (λ/λ_ref) ∇W + Q N``) given the phase as an optical path ``W = λ_ref Φ /
    2π`` built from the term list above, its slopes by central differences: their round-off,
    ε |W| / h ≈ 2.2e-16 · 2e-3 mm / 1e-6 mm ≈ 5e-13, and truncation, h² W''' ≈ 1e-12 · 1e-2,
    are below the 1e-11 tolerance; the kicks are ~1e-2, so a wrong term, sign or factor misses
    by far more."""
    g = torch.Generator().manual_seed(11)
    A = torch.empty(14, dtype=F64).uniform_(-40, 40, generator=g).tolist()
    rn, ref_nm = 3.0, 550.0

    def radians(x, y):
        return sum(a * e(x / rn, y / rn) for a, e in zip(A, TERMS))

    H.assert_directions_match_rayoptics_doe(Binary1(0.0, 5.0, rn, A, 1), radians,
                                            ref_nm * 1e-6 / (2 * math.pi), g, 1e-11, ref_nm)


def test_gradients_match_central_differences():
    """d/dA_2, d/dA_5, d/dA_8 and d/dc of image positions and optical paths of rays through a
    glass singlet whose rear is a Binary 1 phase, and of the paraxial EFL, in float64 against
    central differences (relative 1e-6; the FD truncation error of these near-linear quantities
    is far below)."""
    def q(a2, a5, a8, c, grad=False):
        s = Binary1(c, 6.0, 4.0, [5.0, a2, -40.0, 3.0, a5, 0.0, 0.0, a8], 1, conic=-0.3)
        params = [s.poly[1], s.poly[4], s.poly[7], s.c]
        return H.phase_on_singlet_quantities(s, params, grad)

    # a tilt (A_2) and xy² (A_8) have no paraxial power
    H.assert_value_and_efl_grads_match_fd(q, (20.0, -60.0, 15.0, -0.01), (1e-2, 1e-2, 1e-2, 1e-7),
                                          powerless=(0, 2))


def test_traces_eager_and_round_trips_through_the_lens_file():
    H.assert_phase_round_trips(Binary1(-0.02, 6.0, 4.0, [0.5, 0.0, 10.0, -2.0], -1, conic=0.4),
                               "binary1", "phase_terms_rad", [0.5, 0.0, 10.0, -2.0])
    # (x² + y²) and (x² + y²)² = x⁴ + 2x²y² + y⁴: symmetric; x⁴ + x²y² + y⁴ is not
    sym = [0.0] * 5 + [0.0] * 4 + [1.0, 0.0, 2.0, 0.0, 1.0]
    sym[2] = sym[4] = -3.0
    assert Binary1(0.0, 6.0, 4.0, sym).axisymmetric
    sym[11] = 1.0
    assert not Binary1(0.0, 6.0, 4.0, sym).axisymmetric
