"""Thin-lens and flat starts (deeplens.design.search.start).

The best-form bending is checked against third-order theory computed independently here: the
Seidel spherical-aberration sum ``S_I = -sum A^2 y Δ(u/n)`` (``A = n (u + y c)``, slopes
``u = dy/dz``, refraction ``n'u' = n u - y c (n' - n)``) of a paraxial y-u trace in plain
Python, minimised over the bending at fixed power.  ``S_I`` of a thin lens is exactly quadratic
in the bending, so the parabola through three bendings has its vertex at the optimum.
"""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.paraxial import paraxial
from deeplens.design.search.spec import DesignSpec
from deeplens.design.search.start import (StartError, ThinLens, best_form_bending, flat_start,
                                          solve_efl, start_dimensions, thin_lens_solve,
                                          thin_lens_start)


def seidel_spherical(curvatures, thicknesses, n, y0=1.0, u0=0.0):
    """``S_I`` of a singlet in air (plain Python paraxial trace, module docstring)."""
    idx = [1.0, n, 1.0]
    y, u, s = y0, u0, 0.0
    for k, c in enumerate(curvatures):
        n1, n2 = idx[k], idx[k + 1]
        A = n1 * (u + y * c)
        u2 = (n1 * u - y * c * (n2 - n1)) / n2
        s += -A * A * y * (u2 / n2 - u / n1)
        u = u2
        if k < len(thicknesses):
            y = y + thicknesses[k] * u
    return s


def thin_curvatures(phi, n, X):
    return [phi * (X + 1) / (2 * (n - 1)), phi * (X - 1) / (2 * (n - 1))]


def vertex(f, xs):
    """Vertex of the parabola through ``(x, f(x))`` at three ``xs``."""
    (a, b, c) = xs
    fa, fb, fc = f(a), f(b), f(c)
    num = (b - a) ** 2 * (fb - fc) - (b - c) ** 2 * (fb - fa)
    den = (b - a) * (fb - fc) - (b - c) * (fb - fa)
    return b - 0.5 * num / den


@pytest.mark.parametrize("n", [1.5, 1.5168, 1.8])
@pytest.mark.parametrize("s_obj", [math.inf, 300.0, -250.0])
def test_best_form_bending_is_the_seidel_minimum(n, s_obj):
    """X* = -2 (n^2 - 1) p / (n + 2), p = (u + u') / (u - u'), minimises S_I of a thin lens
    (also for finite and virtual objects); at infinity X* = 2 (n^2 - 1) / (n + 2), 5/7 at
    n = 1.5 (radii 1 : -6)."""
    phi = 1.0 / 100.0
    u0 = 0.0 if math.isinf(s_obj) else 1.0 / s_obj
    p = (u0 + (u0 - phi)) / (u0 - (u0 - phi))

    def S(X):
        return seidel_spherical(thin_curvatures(phi, n, X), [0.0], n, 1.0, u0)

    assert vertex(S, (-1.0, 0.3, 2.0)) == pytest.approx(best_form_bending(n, p), abs=1e-9)
    if math.isinf(s_obj):
        assert best_form_bending(n, -1.0) == pytest.approx(2 * (n * n - 1) / (n + 2), rel=1e-15)
    c1, c2 = thin_curvatures(phi, 1.5, best_form_bending(1.5, -1.0))
    assert c1 / c2 == pytest.approx(-6.0, rel=1e-12)


def _spec(**kw):
    base = dict(efl_mm=80.0, fno=4.0, hfov_deg=10.0, elements=3, glasses="SCHOTT", stop=1)
    base.update(kw)
    return DesignSpec(**base)


@pytest.mark.parametrize("kw", [dict(elements=1, stop="front"), dict(elements=2, stop="search"),
                                dict(), dict(object_distance_mm=600.0),
                                dict(elements=4, stop="back", glasses="MODEL"),
                                dict(elements=6, stop="middle", efl_mm=27.4, hfov_deg=21.0)])
def test_thin_lens_start_meets_the_focal_length(kw):
    """Every start the sampler makes has the paraxial EFL of the spec to 1e-9 (relative) and
    the F-number to the same (the stop is sized for the EPD), a real image on the sensor."""
    spec = _spec(**kw)
    U = torch.quasirandom.SobolEngine(start_dimensions(spec.elements), scramble=True,
                                      seed=3).draw(24, dtype=torch.float64)
    made = 0
    for u in U:
        try:
            lens = thin_lens_start(spec, u)
        except StartError:
            continue
        made += 1
        p = paraxial(lens)
        assert abs(float(p.efl) / spec.efl_mm - 1) < 1e-9
        assert abs(float(p.fno) / spec.f_number - 1) < 1e-9
        assert float(p.image_distance) == pytest.approx(float(lens.d_sensor), rel=1e-12)
        assert lens.dtype == torch.float64
    assert made >= 4, f"only {made} of 24 points gave a lens"


def test_thin_lens_solve_is_an_achromat_of_the_right_power():
    """Two elements: f Φ = 1 to rounding (exact rescaling) and primary axial colour
    sum y^2 φ / V = 0 in least squares against the 0.3 prior towards the sampled powers: below
    1 % of one element's term and 1/20 of what the sampled powers (1.5, -0.5) / f leave."""
    spec = _spec(elements=2, stop=0)
    from deeplens.design.search.start import _indices

    glasses = ["N-BK7", "N-SF5"]
    phi, t = thin_lens_solve(spec, [1.5, -0.5], [2.0], glasses)
    tl = ThinLens(phi, glasses, t, [0, 0], "front", 1.0, "+-")
    assert tl.efl() == pytest.approx(spec.efl_mm, rel=1e-12)
    V = [_indices(g, spec)[1] for g in glasses]
    y2 = 1 + t[0] * (-phi[0])
    colour = phi[0] / V[0] + y2 * y2 * phi[1] / V[1]
    assert abs(colour) < 1e-2 * abs(phi[0] / V[0])
    k = [1.5 / spec.efl_mm, -0.5 / spec.efl_mm]
    raw = k[0] / V[0] + (1 - 2.0 * k[0]) ** 2 * k[1] / V[1]
    assert abs(colour) < 0.05 * abs(raw)


@pytest.mark.parametrize("glasses", [("N-BK7", "N-SF5"), ("N-SK16", "F2"), ("N-BAK1", "N-SF6")])
def test_thin_achromat_power_split_is_the_closed_form(glasses):
    """Two thin elements in contact (spacing 0) at d, F, C: the solve's powers are the thin
    achromat's, phi_1 = phi V_1 / (V_1 - V_2), phi_2 = -phi V_2 / (V_1 - V_2).

    The solve is least squares with the colour residual weighted 1e4 against the 0.3 prior
    towards the sampled ``k = f phi`` (module docstring of ``start``), and f Phi = 1 exact: along
    the power-preserving direction ``d = (1, -1)`` it stops at ``s = 0.09 (k - x*).d /
    (1e8 a^2 + 0.18)`` from the exact split ``x* = f phi*`` (``a = 1/V_1 - 1/V_2``), a few
    1e-6 relative; a solve that ignored colour would keep ``k`` (25-50 % away)."""
    spec = _spec(elements=2, stop=0, wavelengths_nm=[486.1327, 587.5618, 656.2725])
    from deeplens.design.search.start import _indices

    k = [1.5, -0.5]
    phi, t = thin_lens_solve(spec, k, [0.0], list(glasses))
    V1, V2 = (_indices(g, spec)[1] for g in glasses)
    f = spec.efl_mm
    exact = [V1 / (V1 - V2) / f, -V2 / (V1 - V2) / f]
    a = 1 / V1 - 1 / V2
    s = 0.09 * ((k[0] - f * exact[0]) - (k[1] - f * exact[1])) / (1e8 * a * a + 0.18)
    for p, q in zip(phi, exact):
        assert abs(f * (p - q)) <= 1.5 * abs(s) + 1e-12
        assert abs(p / q - 1) < 2e-5
    assert sum(phi) == pytest.approx(1 / f, rel=1e-12)


def test_solve_efl_is_exact_and_checks_its_input():
    spec = _spec()
    u = torch.full((start_dimensions(3),), 0.4, dtype=torch.float64)
    lens = thin_lens_start(spec, u)
    solve_efl(lens, 123.4)
    assert float(paraxial(lens).efl) == pytest.approx(123.4, rel=1e-12)


def test_flat_start_and_bad_points():
    spec = _spec()
    u = torch.full((start_dimensions(3),), 0.4, dtype=torch.float64)
    lens = flat_start(spec, u)
    assert all(abs(float(s.c)) < 1e-5 for s in lens.surfaces if hasattr(s, "c"))
    assert float(lens.d_sensor) == spec.efl_mm
    with pytest.raises(ValueError, match="has 14 coordinates, got 3"):
        thin_lens_start(spec, [0.1, 0.2, 0.3])
