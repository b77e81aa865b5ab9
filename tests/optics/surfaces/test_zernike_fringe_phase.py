"""The Zernike Fringe phase surface (OpticStudio's ``FZERNPHA``): the phase against the Fringe
polynomials written out here from the published table (not deeplens' series), closed forms for a
tilt and a defocus term, the paraxial power of the y-z section, float64 gradients against
central differences, and the lens-file round trip."""

from __future__ import annotations

import math

import helpers as H
import pytest
import torch

from deeplens.optics.paraxial import paraxial
from deeplens.optics.surfaces import ZernikeFringePhase

F64 = torch.float64

#: the University of Arizona Fringe polynomials Z1..Z16 as published (Wyant & Creath; OpticStudio
#: prints the same set), in polar form, written out independently of deeplens' series
FRINGE = [
    lambda r, t: torch.ones_like(r),
    lambda r, t: r * torch.cos(t),
    lambda r, t: r * torch.sin(t),
    lambda r, t: 2 * r ** 2 - 1,
    lambda r, t: r ** 2 * torch.cos(2 * t),
    lambda r, t: r ** 2 * torch.sin(2 * t),
    lambda r, t: (3 * r ** 2 - 2) * r * torch.cos(t),
    lambda r, t: (3 * r ** 2 - 2) * r * torch.sin(t),
    lambda r, t: 6 * r ** 4 - 6 * r ** 2 + 1,
    lambda r, t: r ** 3 * torch.cos(3 * t),
    lambda r, t: r ** 3 * torch.sin(3 * t),
    lambda r, t: (4 * r ** 2 - 3) * r ** 2 * torch.cos(2 * t),
    lambda r, t: (4 * r ** 2 - 3) * r ** 2 * torch.sin(2 * t),
    lambda r, t: (10 * r ** 4 - 12 * r ** 2 + 3) * r * torch.cos(t),
    lambda r, t: (10 * r ** 4 - 12 * r ** 2 + 3) * r * torch.sin(t),
    lambda r, t: 20 * r ** 6 - 30 * r ** 4 + 12 * r ** 2 - 1,
]


_single, _parallel = H.single_in_air, H.parallel_rays


def test_phase_is_the_published_fringe_table_in_waves():
    """Φ / 2π = M Σ A_j Z_j (waves) with Z_j from the table above, at points inside and outside
    the normalisation radius; the gradient against the analytic one of a central difference of
    the table (5e-9 rad/mm)."""
    g = torch.Generator().manual_seed(3)
    A = torch.empty(16, dtype=F64).uniform_(-1, 1, generator=g).tolist()
    rn, m = 3.0, 2
    s = ZernikeFringePhase(0.0, 5.0, rn, A, m)
    x = torch.empty(40, dtype=F64).uniform_(-4, 4, generator=g)
    y = torch.empty(40, dtype=F64).uniform_(-4, 4, generator=g)

    def table(x, y):
        r, t = torch.hypot(x, y) / rn, torch.atan2(y, x)
        return m * sum(a * z(r, t) for a, z in zip(A, FRINGE))

    assert torch.allclose(s.phase(x, y) / (2 * math.pi), table(x, y), atol=1e-11, rtol=0)
    h = 1e-5
    gx, gy = s.phase_grad(x, y)
    fx = (table(x + h, y) - table(x - h, y)) / (2 * h) * 2 * math.pi
    fy = (table(x, y + h) - table(x, y - h)) / (2 * h) * 2 * math.pi
    assert torch.allclose(gx, fx, atol=5e-6, rtol=0) and torch.allclose(gy, fy, atol=5e-6, rtol=0)


@pytest.mark.parametrize("wl", [486.1, 656.3])
def test_a_tilt_deflects_every_ray_by_the_same_angle(wl):
    """A_2 (x tilt) and A_3 (y tilt) alone: every ray's direction cosines change by M λ A / R_n
    (λ in mm), whatever its height."""
    rn, a2, a3, m = 4.0, 3.0, -2.0, 1
    out = _single(ZernikeFringePhase(0.0, 5.0, rn, [0.0, a2, a3], m)).trace(
        _parallel([-3.0, 0.0, 1.0, 2.5], [2.0, -1.5, 0.0, 3.0], wl))
    assert out.valid.all()
    lam = wl * 1e-6
    assert torch.allclose(out.d[:, 0], torch.full((4,), m * lam * a2 / rn, dtype=F64),
                          atol=1e-16, rtol=0)
    assert torch.allclose(out.d[:, 1], torch.full((4,), m * lam * a3 / rn, dtype=F64),
                          atol=1e-16, rtol=0)


def test_defocus_is_a_lens_of_the_closed_form_focal_length():
    """A_4 alone: Φ = 2π M A_4 (2ρ² − 1), so a ray at height h leaves with sin θ = 4 M λ A_4 h /
    R_n² = −h / f: f = −R_n² / (4 M λ A_4), exactly (the kick is linear in h); the paraxial EFL
    is f."""
    rn, a4, m, wl = 4.0, -3.0, 1, 550.0
    f = -rn ** 2 / (4 * m * wl * 1e-6 * a4)
    lens = _single(ZernikeFringePhase(0.0, 5.0, rn, [0.0, 0.0, 0.0, a4], m))
    h = torch.tensor([-2.0, -0.5, 1.0, 2.0], dtype=F64)
    out = lens.trace(_parallel(torch.zeros_like(h), h, wl))
    assert torch.allclose(out.d[:, 1], -h / f, atol=1e-16, rtol=0)
    assert float(paraxial(lens, wl).efl) == pytest.approx(f, rel=1e-13)


def test_paraxial_power_is_the_y_section_of_the_phase():
    """Astigmatism A_5 (ρ² cos 2φ: −y²/R_n² along y) has the y power +2 M λ A_5 / R_n² and A_6
    (ρ² sin 2φ) none; spherical A_9 (6ρ⁴ − 6ρ² + 1) the ρ² term's, +12 M λ A_9 / R_n² — both
    against a central difference of the traced y slope at the axis."""
    rn, wl = 4.0, 550.0
    for A in ([0, 0, 0, 0, 1.5], [0, 0, 0, 0, 0, 2.0], [0] * 8 + [0.7], [0] * 11 + [0.4]):
        s = ZernikeFringePhase(0.0, 5.0, rn, A, 1)
        lens = _single(s)
        h = 1e-4
        out = lens.trace(_parallel([0.0, 0.0], [h, -h], wl))
        phi_fd = -float(out.d[0, 1] - out.d[1, 1]) / (2 * h)
        assert float(s.paraxial_phase_power(wl)) == pytest.approx(phi_fd, rel=1e-6, abs=1e-15)
    s = ZernikeFringePhase(0.0, 5.0, rn, [0, 0, 0, 0, 1.5], 1)
    assert float(s.paraxial_phase_power(wl)) == pytest.approx(2 * wl * 1e-6 * 1.5 / rn ** 2,
                                                              rel=1e-14)


def test_gradients_match_central_differences():
    """d/dA_4, d/dA_8 and d/dc of image positions and optical paths of rays through a glass
    singlet whose rear is a Zernike Fringe phase, and of the paraxial EFL, in float64 against
    central differences (relative 1e-6; the FD truncation error of these near-linear
    quantities is far below)."""
    def q(a4, a8, c, grad=False):
        s = ZernikeFringePhase(c, 6.0, 4.0, [0.0, 0.0, 0.1, a4, 0.2, 0.0, 0.0, a8], 1,
                               conic=-0.3)
        params = [s.zernike[3], s.zernike[7], s.c]
        return H.phase_on_singlet_quantities(s, params, grad)

    # coma (A_8) has no paraxial power
    H.assert_value_and_efl_grads_match_fd(q, (-20.0, 5.0, -0.01), (1e-3, 1e-3, 1e-7),
                                          powerless=(1,))


def test_traces_eager_and_round_trips_through_the_lens_file():
    H.assert_phase_round_trips(ZernikeFringePhase(-0.02, 6.0, 4.0, [0.5, 0.0, 1.0, -2.0], -1,
                                                  conic=0.4),
                               "zernike_fringe_phase", "zernike_waves", [0.5, 0.0, 1.0, -2.0])
    assert ZernikeFringePhase(0.0, 6.0, 4.0, [0.5, 0, 0, -2.0, 0, 0, 0, 0, 1.0]).axisymmetric


def test_real_rays_match_rayoptics_diffractive_element():
    """Skew rays through a flat Zernike Fringe phase in air (16 random terms, M = 1, two
    wavelengths): deeplens' directions equal rayoptics' DiffractiveElement (a test-only oracle:
    its own grating law, ``d' = d + M (λ/λ_ref) ∇W + Q N``) given the phase as an optical path
    ``W = λ_ref Σ A_j Z_j`` built from the published table above, its slopes by central
    differences: their round-off, ε |W| / h · λ ≈ 2.2e-16 · 100 waves / 1e-6 mm · 6.6e-4 mm ≈
    1.5e-11 (|W| of order 100 waves at these points), sets the 2e-11 tolerance; the kicks are ~1e-2, so a
    wrong term, sign or factor misses by far more."""
    g = torch.Generator().manual_seed(11)
    A = torch.empty(16, dtype=F64).uniform_(-2, 2, generator=g).tolist()
    rn, ref_nm = 3.0, 550.0

    def waves(x, y):
        xt, yt = torch.tensor(x, dtype=F64), torch.tensor(y, dtype=F64)
        r, t = torch.hypot(xt, yt) / rn, torch.atan2(yt, xt)
        return float(sum(a * z(r, t) for a, z in zip(A, FRINGE)))

    H.assert_directions_match_rayoptics_doe(ZernikeFringePhase(0.0, 5.0, rn, A, 1), waves,
                                            ref_nm * 1e-6, g, 2e-11, ref_nm)
