"""The Zernike Fringe sag (:class:`~deeplens.optics.surfaces.ZernikeFringeSag`, OpticStudio's
``FZERNSAG``): its written-out reference (the Fringe polynomials of the University of Arizona
FRINGE table, Z37 the 12th-order spherical as OpticStudio prints it, and an independent factorial
sum), the numbering against optiland's independent ``ZernikeFringe`` (terms 1..36; its 37th
differs), the sag of all 37 terms against the factorial sum and optiland, the vertex curvature and
the 37-term limit.  The checks it shares with the Zernike Standard sag (single terms against the
table, the closed form, slopes and parameter derivatives against central differences, the lens
file, trace gradients, rays against optiland's own trace) run for both in
``test_zernike_sag.py``, parametrized over the two coefficient conventions, with this module's
``TERMS``, ``ZC`` and ``sag_np``."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers import disk_xy as _points

from deeplens.optics.surfaces import ZernikeFringeSag, ZernikeSag
from deeplens.optics.surfaces.zernike_sag import fringe_nm

C, K, RN = 1 / 40.0, -0.5, 5.0
ALPHA = [1e-3, 2e-5, -3e-7]                       # r², r⁴, r⁶
# Fringe-ordered A_1..A_16 (mm): piston, tilts, defocus, astigmatism, coma, spherical, trefoil,
# secondary astigmatism and coma, secondary spherical
ZC = [1e-3, 2e-3, -1e-3, 0.01, 2e-3, 3e-3, -1e-3, 1e-3, 5e-4, -5e-4, 4e-4, 3e-4, -2e-4, 1e-4,
      2e-4, -2e-3]

#: the Fringe terms written out (FRINGE manual's table; OpticStudio's Z37)
TERMS = {
    1: lambda p, a: np.ones_like(p),
    2: lambda p, a: p * np.cos(a),
    3: lambda p, a: p * np.sin(a),
    4: lambda p, a: 2 * p ** 2 - 1,
    5: lambda p, a: p ** 2 * np.cos(2 * a),
    6: lambda p, a: p ** 2 * np.sin(2 * a),
    7: lambda p, a: (3 * p ** 3 - 2 * p) * np.cos(a),
    8: lambda p, a: (3 * p ** 3 - 2 * p) * np.sin(a),
    9: lambda p, a: 6 * p ** 4 - 6 * p ** 2 + 1,
    10: lambda p, a: p ** 3 * np.cos(3 * a),
    11: lambda p, a: p ** 3 * np.sin(3 * a),
    12: lambda p, a: (4 * p ** 4 - 3 * p ** 2) * np.cos(2 * a),
    13: lambda p, a: (4 * p ** 4 - 3 * p ** 2) * np.sin(2 * a),
    14: lambda p, a: (10 * p ** 5 - 12 * p ** 3 + 3 * p) * np.cos(a),
    15: lambda p, a: (10 * p ** 5 - 12 * p ** 3 + 3 * p) * np.sin(a),
    16: lambda p, a: 20 * p ** 6 - 30 * p ** 4 + 12 * p ** 2 - 1,
    17: lambda p, a: p ** 4 * np.cos(4 * a),
    18: lambda p, a: p ** 4 * np.sin(4 * a),
    25: lambda p, a: 70 * p ** 8 - 140 * p ** 6 + 90 * p ** 4 - 20 * p ** 2 + 1,
    26: lambda p, a: p ** 5 * np.cos(5 * a),
    35: lambda p, a: (126 * p ** 9 - 280 * p ** 7 + 210 * p ** 5 - 60 * p ** 3 + 5 * p)
    * np.sin(a),
    36: lambda p, a: (252 * p ** 10 - 630 * p ** 8 + 560 * p ** 6 - 210 * p ** 4 + 30 * p ** 2
                      - 1),
    37: lambda p, a: (924 * p ** 12 - 2772 * p ** 10 + 3150 * p ** 8 - 1680 * p ** 6
                      + 420 * p ** 4 - 42 * p ** 2 + 1),
}


def radial(n, m, p):
    """``R_n^|m|(ρ)`` by its factorial sum (independent of the surface's Jacobi recurrence)."""
    m = abs(m)
    return sum((-1) ** s * math.factorial(n - s)
               / (math.factorial(s) * math.factorial((n + m) // 2 - s)
                  * math.factorial((n - m) // 2 - s)) * p ** (n - 2 * s)
               for s in range((n - m) // 2 + 1))


def fringe_np(x, y, zc, rn=RN):
    """``Σ A_j Z_j`` with ``Z_j = R_n^|m| cos/sin(|m| φ)`` for the Fringe ``(n, m)`` of each j."""
    p, a = np.hypot(x, y) / rn, np.arctan2(y, x)
    out = np.zeros_like(p)
    for j, A in enumerate(zc, start=1):
        n, m = fringe_nm(j)
        ang = np.cos(m * a) if m >= 0 else np.sin(-m * a)
        out = out + A * radial(n, m, p) * ang
    return out


def sag_np(x, y, c=C, k=K, alpha=ALPHA, zc=ZC, rn=RN):
    r2 = x * x + y * y
    z = c * r2 / (1 + np.sqrt(1 - (1 + k) * c * c * r2))
    for i, a in enumerate(alpha, start=1):
        z = z + a * r2 ** i
    p, ang = np.hypot(x, y) / rn, np.arctan2(y, x)
    # the written-out table where it has the term, else the factorial sum of that term alone
    return z + sum(zc[j - 1] * TERMS[j](p, ang) if j in TERMS
                   else fringe_np(x, y, [0.0] * (j - 1) + [zc[j - 1]], rn)
                   for j in range(1, len(zc) + 1))


def test_fringe_numbering_matches_optiland_up_to_36():
    """``fringe_nm`` for j <= 36 against optiland's ZernikeFringe numbering (its own ``(n, m) ->
    j`` rule: the University of Arizona order); j = 37 is OpticStudio's 12th-order spherical,
    where optiland's open-ended rule continues with the next group (n = m = 6)."""
    pytest.importorskip("optiland")
    from optiland.zernike import ZernikeFringe

    seen = set()
    for j in range(1, 37):
        n, m = fringe_nm(j)
        assert abs(m) <= n and (n - m) % 2 == 0
        assert ZernikeFringe._index_to_number(n, m) == j
        seen.add((n, m))
    assert len(seen) == 36
    assert fringe_nm(37) == (12, 0) and ZernikeFringe._index_to_number(12, 0) == 49
    for bad in (0, 38):
        with pytest.raises(ValueError, match=r"runs 1..37"):
            fringe_nm(bad)


def test_sag_of_37_terms_is_the_factorial_sum_and_optilands_fringe():
    """37 random coefficients: the Zernike part against the factorial sum (to 1e-13 mm) and,
    for the first 36, against optiland's ZernikeFringe (to 1e-12 mm)."""
    rng = np.random.default_rng(1)
    A = rng.normal(size=37) * 1e-3
    s = ZernikeFringeSag(0.0, 6.0, RN, A.tolist())
    x, y = _points(150, 5.0, seed=2)
    X, Y = torch.tensor(x), torch.tensor(y)
    z = s.sag(X, Y).numpy()
    ref = fringe_np(x, y, A)
    assert np.abs(ref).max() > 1e-3
    assert np.abs(z - ref).max() < 1e-13
    pytest.importorskip("optiland")
    from optiland.zernike import ZernikeFringe

    s36 = ZernikeFringeSag(0.0, 6.0, RN, A[:36].tolist())
    ol = ZernikeFringe(coeffs=A[:36]).poly(np.hypot(x, y) / RN, np.arctan2(y, x))
    assert np.abs(s36.sag(X, Y).numpy() - ol).max() < 1e-12


def test_paraxial_curvature_is_the_mean_vertex_curvature():
    """``c + 2 α_1 + 2 Σ r_n A_j / R_n²`` (the ρ² coefficients r_n of the m = 0 Fringe terms:
    Z4 2, Z9 −6, Z16 12, Z37 −42): half the Laplacian of the sag at the vertex, by second
    differences; the unnormalised Fringe terms, not the Standard ones."""
    zc = ZC + [0.0] * 20 + [4e-4]
    s = ZernikeFringeSag(C, 6.5, RN, zc, conic=K, coefficients=ALPHA)
    h = 1e-3

    def z(x, y):
        return float(sag_np(np.array(x), np.array(y), zc=zc))
    lap = (z(h, 0) + z(-h, 0) + z(0, h) + z(0, -h) - 4 * z(0, 0)) / h ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(lap / 2, rel=1e-5)
    ref = C + 2 * ALPHA[0] + 2 * (2 * ZC[3] - 6 * ZC[8] + 12 * ZC[15] - 42 * 4e-4) / RN ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(ref, rel=1e-14)
    sym = ZernikeFringeSag(C, 6.5, RN, [1e-3, 0, 0, 1e-3, 0, 0, 0, 0, 2e-4])
    assert sym.rotationally_symmetric() and not s.rotationally_symmetric()


def test_constructor_errors():
    with pytest.raises(ValueError, match="ZernikeFringeSag: at most 37 Zernike terms"):
        ZernikeFringeSag(C, 5.0, RN, [0.0] * 38)
    ZernikeSag(C, 5.0, RN, [0.0] * 38)   # the Standard set goes on to 231
