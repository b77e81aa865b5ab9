"""``XPOLYNOM``, OpticStudio's Extended Polynomial: ``z = STANDARD + Σ_t A_t E_t(x / R_n, y / R_n)``,
the terms ``x, y, x², xy, y², x³, ...`` (by degree, within a degree from ``x^d`` down to ``y^d``),
the coefficients in lens units (OpticStudio User Guide, "Extended Polynomial": XDAT 1 the maximum
term number, up to 230; XDAT 2 the normalisation radius; XDAT 3.. the terms; "the 12th term ...
is the coefficient on the term in x²y²", "xy³ ... is term number 13").

deeplens reads it on a flat base (CURV 0) as its XY polynomial, ``a_ij = s A_t / (s R_n)^(i+j)``
with ``s`` mm per lens unit.  Checked here: the sag against that formula written out by hand at
scattered points, in mm and in inches (term order from the manual's own examples); the sag and
the surface normal against optiland's XY polynomial geometry (its own unnormalised ``Σ C_ij x^i
y^j``, given ``C_ij = A / R_n^(i+j)``); a concave parabolic mirror ``z = −0.01 r²`` written as an
Extended Polynomial focuses at ``f = 1 / (4 · 0.01) = 25`` mm (paraxial EFL, and real rays to a
point); the write-back as ``XPOLYNOM``; the refusals, each at its line.
"""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.analysis.spot import spot_diagram
from deeplens.optics.io import ZemaxFileError, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.surfaces import XYPolynomial

RN = 4.0
#: OpticStudio's first 14 terms, written out from the manual (not from deeplens)
MANUAL_TERMS = [(1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3),
                (4, 0), (3, 1), (2, 2), (1, 3), (0, 4)]
#: term number -> A_t (lens units): every term of degree 2 to 4 a different value
A = {3: 0.011, 4: -0.003, 5: 0.017, 6: 2e-3, 7: -1.5e-3, 8: 7e-4, 9: -4e-4,
     10: 3e-4, 11: -2e-4, 12: 1.3e-4, 13: -6e-5, 14: 5e-5}


def xpolynom(a=A, rn=RN, unit="MM", n=14, curv=0.0, extra=()):
    xdat = (f"XDAT 1 {n}", f"XDAT 2 {rn!r}", *[f"XDAT {t + 2} {v!r}" for t, v in sorted(a.items())],
            *extra)
    return singlet(s1_type="XPOLYNOM", s1_extra=xdat, curv1=curv, k=0.0, unit=unit)


def hand_sag(x, y, a=A, rn=RN, scale=1.0):
    """The Extended Polynomial's sag (mm) at ``x, y`` (mm) on a flat base, file lengths times
    ``scale``: ``scale · Σ A_t (x / R)^i (y / R)^j`` with ``R = rn · scale`` (mm)."""
    r = rn * scale
    return scale * sum(v * (x / r) ** MANUAL_TERMS[t - 1][0] * (y / r) ** MANUAL_TERMS[t - 1][1]
                       for t, v in a.items())


POINTS = [(0.0, 0.0), (0.7, -0.2), (-1.9, 1.1), (2.3, 2.9), (-3.1, -0.4), (0.3, -3.6)]


@pytest.mark.parametrize("unit,scale", [("MM", 1.0), ("IN", 25.4)])
def test_sag_is_the_extended_polynomial_formula(tmp_path, unit, scale):
    surf = read_zmx(write(tmp_path, xpolynom(unit=unit))).surfaces[1]
    assert isinstance(surf, XYPolynomial) and float(surf.b) == 0.0
    for x, y in POINTS:   # in file units; the same points in mm
        xm, ym = (torch.tensor(v * scale, dtype=torch.float64) for v in (x, y))
        z = float(surf.sag(xm, ym))
        assert z == pytest.approx(hand_sag(x * scale, y * scale, scale=scale),
                                  abs=1e-14 * scale, rel=1e-13)


def test_manual_term_numbers(tmp_path):
    """The manual's two examples: term 12 is x²y², term 13 is xy³ (XDAT 14, XDAT 15)."""
    for t, (i, j) in ((12, (2, 2)), (13, (1, 3))):
        surf = read_zmx(write(tmp_path, xpolynom({t: 0.5}, rn=2.0), f"t{t}.zmx")).surfaces[1]
        nonzero = {e: float(v) for e, v in zip(surf.terms, surf.a) if float(v) != 0.0}
        assert nonzero == {(i, j): pytest.approx(0.5 / 2.0 ** (i + j), rel=1e-15)}


def test_sag_and_normal_match_optiland(tmp_path):
    """optiland's ``PolynomialGeometry`` (conic + ``Σ C_ij x^i y^j``, its own evaluation) given
    the file's coefficients as ``C_ij = A / R_n^(i+j)``: sag and unit normal to 1e-13."""
    pytest.importorskip("optiland")
    from optiland.coordinate_system import CoordinateSystem
    from optiland.geometries import PolynomialGeometry

    surf = read_zmx(write(tmp_path, xpolynom())).surfaces[1]
    c = [[0.0] * 5 for _ in range(5)]
    for t, v in A.items():
        i, j = MANUAL_TERMS[t - 1]
        c[i][j] = v / RN ** (i + j)
    geo = PolynomialGeometry(CoordinateSystem(), math.inf, 0.0, coefficients=c)
    x = torch.tensor([p[0] for p in POINTS], dtype=torch.float64)
    y = torch.tensor([p[1] for p in POINTS], dtype=torch.float64)
    z_ol = torch.as_tensor(geo.sag(x.numpy(), y.numpy())).double()
    assert torch.allclose(surf.sag(x, y).detach(), z_ol, rtol=1e-13, atol=1e-15)
    nx, ny, nz = (torch.as_tensor(v).double() for v in geo._surface_normal(x.numpy(), y.numpy()))
    z = surf.sag(x, y).detach()
    gx, gy, gz = (g.detach() for g in surf.f_grad(x, y, z))
    norm = torch.sqrt(gx * gx + gy * gy + gz * gz)
    # optiland's normal is (z_x, z_y, -1) normalised; deeplens' f = P - z has (P_x, P_y, -1)
    for a, b in ((gx / norm, nx), (gy / norm, ny), (gz / norm, nz)):
        assert torch.allclose(a, b, rtol=0, atol=1e-14)


REFLECTOR = "\n".join([
    "VERS 80915 83 20100", "MODE SEQ", "UNIT MM X W X CM MR CPMM", "ENPD 2.5E+1", "FTYP 0 0 1 1 0 0 0",
    "XFLN 0", "YFLN 0", "WAVM 1 5.5E-1 1", "PWAV 1",
    "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 2.5E+1",
    "SURF 1", "  STOP", "  TYPE XPOLYNOM", "  CURV 0.0",
    "  XDAT 1 5", "  XDAT 2 1.0", "  XDAT 5 -0.01", "  XDAT 7 -0.01",
    "  DISZ -2.5E+1", "  GLAS MIRROR 0 0 1.5 4.0E+1 0 0 0 0 0 0", "  DIAM 1.5E+1 0 0 0 1",
    "SURF 2", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 1 0 0 0 1"]) + "\n"


def test_parabolic_mirror_focal_length_and_focus(tmp_path):
    """``z = −0.01 (x² + y²)`` is the paraboloid of vertex radius −50 mm: a concave mirror of
    focal length 25 mm, which images an on-axis object at infinity to a point.  The image plane
    25 mm before it: EFL 25 (paraxial), BFL −25 (back along −z, after one mirror), every real
    ray of a 25 mm pupil meets the axis there (RMS spot < 1e-9 mm); the vertex curvature −0.02."""
    text = REFLECTOR.replace("DISZ 2.5E+1\nSURF 1", "DISZ INFINITY\nSURF 1")
    lens = read_zmx(write(tmp_path, text))
    s = lens.surfaces[0]
    assert float(s.paraxial_curvature()) == pytest.approx(-0.02, rel=1e-15)
    p = paraxial(lens)
    assert float(p.efl) == pytest.approx(25.0, rel=1e-12)
    assert float(p.entrance_pupil_diameter) == pytest.approx(25.0, rel=1e-12)
    with torch.no_grad():
        spot = spot_diagram(lens, 0.0, 550.0, "hexapolar:8", pupil="paraxial")
    assert spot.n_rays == spot.n_launched
    assert float(spot.rms_radius) < 1e-9


def test_written_back_as_xpolynom_and_read_again(tmp_path):
    """Written as ``XPOLYNOM`` with ``R_n`` = 1 mm (an order-4 surface: 14 terms), read back to
    the same lens bit for bit; the inch file's lens likewise (its coefficients already in mm)."""
    for unit in ("MM", "IN"):
        lens = read_zmx(write(tmp_path, xpolynom(unit=unit), f"{unit}.zmx"))
        out = tmp_path / f"out_{unit}.zmx"
        write_zmx(lens, out)
        text = out.read_text()
        assert "TYPE XPOLYNOM" in text and "XDAT 1 14" in text and "XDAT 2 1.0" in text
        assert lens_to_dict(read_zmx(out))["surfaces"] == lens_to_dict(lens)["surfaces"]


def test_reflector_round_trip(tmp_path):
    lens = read_zmx(write(tmp_path, REFLECTOR))
    write_zmx(lens, tmp_path / "out.zmx")
    back = read_zmx(tmp_path / "out.zmx")
    assert lens_to_dict(back) == lens_to_dict(lens)


@pytest.mark.parametrize("edit,needle,match", [
    (lambda t: t.replace("CURV 0.0\n  CONI", "CURV 0.01\n  CONI", 1), "CURV 0.01",
     r"SURF 2: an Extended Polynomial \(XPOLYNOM\) on a curved base \(CURV 0.01\) is not read"),
    (lambda t: t.replace("XDAT 1 14", "XDAT 1 231"), "XDAT 1 231",
     r"XPOLYNOM number of terms \(XDAT 1\) must be an integer 1..230, got 231"),
    (lambda t: t.replace("XDAT 1 14", "XDAT 1 13"), "XDAT 16",
     r"XDAT 16 lies beyond the 13 terms XDAT 1 declares"),
    (lambda t: t.replace("XDAT 2 4.0", "XDAT 2 0"), "XDAT 2 0",
     r"XPOLYNOM normalisation radius must be > 0"),
    (lambda t: t.replace("XDAT 2 4.0", "XDAT 2 4.0\n  PARM 1 0.5"), "PARM 1 0.5",
     r"XPOLYNOM PARM 1 is not read"),
])
def test_refused_at_its_line(tmp_path, edit, needle, match):
    text = edit(xpolynom())
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, needle)
