"""``XPOLYNOM``, OpticStudio's Extended Polynomial: ``z = STANDARD + Σ_t A_t E_t(x / R_n, y / R_n)``,
the terms ``x, y, x², xy, y², x³, ...`` (by degree, within a degree from ``x^d`` down to ``y^d``),
the coefficients in lens units (OpticStudio User Guide, "Extended Polynomial": XDAT 1 the maximum
term number, up to 230; XDAT 2 the normalisation radius; XDAT 3.. the terms; "the 12th term ...
is the coefficient on the term in x²y²", "xy³ ... is term number 13").

deeplens reads it on a flat base (CURV 0) as its XY polynomial, ``a_ij = s A_t / (s R_n)^(i+j)``
with ``s`` mm per lens unit, and on a curved base as an ``ExtendedPolynomial`` (the conic plus
the normalised terms).  Checked here: the sag against that formula written out by hand at
scattered points, in mm and in inches, flat and on a conic (term order from the manual's own
examples); the sag and the surface normal against optiland's XY polynomial geometry (its own
conic plus unnormalised ``Σ C_ij x^i y^j``, given ``C_ij = A / R_n^(i+j)``); a concave parabolic
mirror ``z = −0.01 r²`` written as an Extended Polynomial focuses at ``f = 1 / (4 · 0.01) = 25``
mm (paraxial EFL, and real rays to a point); on a conic with no terms the rays land where the
STANDARD conic's do; the curved surface's gradients (c, k, terms) through a real-ray trace
against central differences in float64; the write-back as ``XPOLYNOM`` and the JSON lens file;
the refusals, each at its line.
"""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.analysis.spot import spot_diagram
from deeplens.optics.io import ZemaxFileError, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import ExtendedPolynomial, XYPolynomial

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


def hand_sag(x, y, a=A, rn=RN, scale=1.0, c=0.0, k=0.0):
    """The Extended Polynomial's sag (mm) at ``x, y`` (mm), file lengths times ``scale``:
    ``c' ρ² / (1 + sqrt(1 − (1 + k) c'² ρ²)) + scale · Σ A_t (x / R)^i (y / R)^j`` with ``R =
    rn · scale`` (mm), ``c' = c / scale`` (1/mm), ``ρ² = x² + y²``."""
    r, cm, rho2 = rn * scale, c / scale, x * x + y * y
    z = cm * rho2 / (1 + math.sqrt(1 - (1 + k) * cm * cm * rho2))
    return z + scale * sum(v * (x / r) ** MANUAL_TERMS[t - 1][0]
                           * (y / r) ** MANUAL_TERMS[t - 1][1] for t, v in a.items())


POINTS = [(0.0, 0.0), (0.7, -0.2), (-1.9, 1.1), (2.3, 2.9), (-3.1, -0.4), (0.3, -3.6)]


@pytest.mark.parametrize("unit,scale", [("MM", 1.0), ("IN", 25.4)])
@pytest.mark.parametrize("curv,k", [(0.0, 0.0), (0.0, -3.0), (0.03, -0.5)])
def test_sag_is_the_extended_polynomial_formula(tmp_path, unit, scale, curv, k):
    """Flat (a conic on a flat base adds nothing) and on a conic base."""
    text = xpolynom(unit=unit, curv=curv).replace("CONI 0.0", f"CONI {k}")
    surf = read_zmx(write(tmp_path, text)).surfaces[1]
    if curv == 0.0:
        assert isinstance(surf, XYPolynomial) and float(surf.b) == 0.0
    else:
        assert isinstance(surf, ExtendedPolynomial)
    for x, y in POINTS:   # in file units; the same points in mm
        xm, ym = (torch.tensor(v * scale, dtype=torch.float64) for v in (x, y))
        z = float(surf.sag(xm, ym))
        assert z == pytest.approx(hand_sag(x * scale, y * scale, scale=scale, c=curv, k=k),
                                  abs=1e-14 * scale, rel=1e-13)


def test_manual_term_numbers(tmp_path):
    """The manual's two examples: term 12 is x²y², term 13 is xy³ (XDAT 14, XDAT 15)."""
    for t, (i, j) in ((12, (2, 2)), (13, (1, 3))):
        surf = read_zmx(write(tmp_path, xpolynom({t: 0.5}, rn=2.0), f"t{t}.zmx")).surfaces[1]
        nonzero = {e: float(v) for e, v in zip(surf.terms, surf.a) if float(v) != 0.0}
        assert nonzero == {(i, j): pytest.approx(0.5 / 2.0 ** (i + j), rel=1e-15)}


@pytest.mark.parametrize("curv,k", [(0.0, 0.0), (0.03, -0.5)])
def test_sag_and_normal_match_optiland(tmp_path, curv, k):
    """optiland's ``PolynomialGeometry`` (conic + ``Σ C_ij x^i y^j``, its own evaluation) given
    the file's coefficients as ``C_ij = A / R_n^(i+j)``: sag and unit normal to 1e-13."""
    pytest.importorskip("optiland")
    from optiland.coordinate_system import CoordinateSystem
    from optiland.geometries import PolynomialGeometry

    text = xpolynom(curv=curv).replace("CONI 0.0", f"CONI {k}")
    surf = read_zmx(write(tmp_path, text)).surfaces[1]
    c = [[0.0] * 5 for _ in range(5)]
    for t, v in A.items():
        i, j = MANUAL_TERMS[t - 1]
        c[i][j] = v / RN ** (i + j)
    geo = PolynomialGeometry(CoordinateSystem(), 1.0 / curv if curv else math.inf, k,
                             coefficients=c)
    x = torch.tensor([p[0] for p in POINTS], dtype=torch.float64)
    y = torch.tensor([p[1] for p in POINTS], dtype=torch.float64)
    z_ol = torch.as_tensor(geo.sag(x.numpy(), y.numpy())).double()
    assert torch.allclose(surf.sag(x, y).detach(), z_ol, rtol=1e-13, atol=1e-15)
    nx, ny, nz = (torch.as_tensor(v).double() for v in geo._surface_normal(x.numpy(), y.numpy()))
    z = surf.sag(x, y).detach()
    gx, gy, gz = (g.detach() for g in surf.f_grad(x, y, z))
    norm = torch.sqrt(gx * gx + gy * gy + gz * gz)
    # optiland's normal is (z_x, z_y, -1) normalised; deeplens' f = sag - z has (z_x, z_y, -1)
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


def _trace(lens, wl):
    """Rays (float64) from skew points 50 mm before the first surface towards the lens, landed
    on the image plane: ``(o, valid)``."""
    o = torch.tensor([[0.0, 0.0, -50.0], [1.2, -0.8, -50.0], [-2.1, 1.7, -50.0],
                      [2.5, 2.2, -50.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.01, 1.0], [0.02, -0.01, 1.0], [-0.01, 0.0, 1.0]],
                     dtype=torch.float64)
    out = lens.trace(Rays(o, d / d.norm(dim=-1, keepdim=True), wl),
                     options=TraceOptions(clip_aperture=False))
    return out.o, out.valid


def test_curved_base_without_terms_lands_as_the_conic(tmp_path):
    """An Extended Polynomial on a conic with every term zero is that conic: the same rays land
    where the STANDARD file's do (1e-12 mm)."""
    base = singlet(s1_type="STANDARD", s1_extra=(), curv1=0.03, k=-0.5)
    text = xpolynom({3: 0.0}, curv=0.03).replace("CONI 0.0", "CONI -0.5")
    a = read_zmx(write(tmp_path, text, "a.zmx")).double()
    b = read_zmx(write(tmp_path, base, "b.zmx")).double()
    assert isinstance(a.surfaces[1], ExtendedPolynomial)
    wl = float(a.spec.primary_wavelength_nm)
    with torch.no_grad():
        (oa, va), (ob, vb) = _trace(a, wl), _trace(b, wl)
    assert bool(va.all()) and bool(vb.all())
    assert torch.allclose(oa, ob, rtol=0, atol=1e-12)


def test_curved_base_gradients_match_central_differences(tmp_path):
    """Where four skew rays land on the image plane (a weighted sum of x and y) as a function
    of the base curvature and conic and of three terms (x², x²y, x²y²): autograd against
    central differences in float64 (step 1e-6 relative; truncation O(h²) ~ 1e-12, round-off
    ~ eps/h ~ 1e-10 relative, the trace's Newton tolerance below both)."""
    text = xpolynom(curv=0.03).replace("CONI 0.0", "CONI -0.5")
    lens = read_zmx(write(tmp_path, text)).double()
    surf = lens.surfaces[1]
    wl = float(lens.spec.primary_wavelength_nm)
    w = torch.tensor([0.3, -1.0, 2.0, 0.7], dtype=torch.float64)

    def loss():
        o, valid = _trace(lens, wl)
        assert bool(valid.all())
        return (w * o[:, 0]).sum() + (w * w * o[:, 1]).sum()

    params = {"c": surf.c, "k": surf.k, "x2": surf.poly[2], "x2y": surf.poly[6],
              "x2y2": surf.poly[11]}
    for prm in params.values():
        prm.requires_grad_(True)
    grads = torch.autograd.grad(loss(), list(params.values()))
    for (name, prm), g in zip(params.items(), grads):
        step = 1e-6 * max(abs(float(prm)), 1e-3)
        with torch.no_grad():
            prm += step
            up = float(loss())
            prm -= 2 * step
            down = float(loss())
            prm += step
        fd = (up - down) / (2 * step)
        assert abs(fd) > 1e-6, name                      # the parameter moves the landings
        assert float(g) == pytest.approx(fd, rel=1e-5), name


def test_curved_base_written_back_and_in_a_lens_file(tmp_path):
    """Written as ``XPOLYNOM`` with its CURV, CONI, R_n and terms, and to JSON: both read back
    to the same lens (bit for bit); the paraxial curvature is ``c + (A_x² + A_y²) / R_n²``."""
    from deeplens.optics.io import load_lens, save_lens

    text = xpolynom(curv=0.03).replace("CONI 0.0", "CONI -0.5")
    lens = read_zmx(write(tmp_path, text))
    s = lens.surfaces[1]
    assert float(s.paraxial_curvature()) == pytest.approx(0.03 + (A[3] + A[5]) / RN ** 2,
                                                          rel=1e-15)
    write_zmx(lens, tmp_path / "out.zmx")
    out = (tmp_path / "out.zmx").read_text()
    assert "TYPE XPOLYNOM" in out and "CONI -0.5" in out and "XDAT 2 4.0" in out
    assert lens_to_dict(read_zmx(tmp_path / "out.zmx")) == lens_to_dict(lens)
    save_lens(lens, tmp_path / "out.json")
    assert lens_to_dict(load_lens(tmp_path / "out.json")) == lens_to_dict(lens)


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
    (lambda t: t.replace("XDAT 1 14", "XDAT 1 231"), "XDAT 1 231",
     r"XPOLYNOM number of terms \(XDAT 1\) must be an integer 1..230, got 231"),
    (lambda t: t.replace("XDAT 1 14", "XDAT 1 13"), "XDAT 16",
     r"XDAT 16 lies beyond the 13 terms XDAT 1 declares"),
    (lambda t: t.replace("XDAT 2 4.0", "XDAT 2 0"), "XDAT 2 0",
     r"XPOLYNOM normalisation radius must be > 0"),
    (lambda t: t.replace("XDAT 2 4.0", "XDAT 2 4.0\n  PARM 1 0.5"), "PARM 1 0.5",
     r"XPOLYNOM PARM 1 = 0.5 is not read"),
])
def test_refused_at_its_line(tmp_path, edit, needle, match):
    text = edit(xpolynom())
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, needle)


@pytest.mark.parametrize("curv", [0.0, 0.01])
@pytest.mark.parametrize("terms,exact", [
    ({3: 0.02, 5: 0.02}, True),                                  # (x² + y²) / R_n²
    ({3: 0.02, 5: 0.02, 10: 1e-3, 12: 2e-3, 14: 1e-3}, True),   # ... + (x² + y²)² / R_n⁴
    ({3: 0.02, 5: 0.03}, False),                                 # astigmatic
    ({3: 0.02, 4: 1e-3, 5: 0.02}, False),                        # an xy term
    ({3: 0.02, 5: 0.02, 10: 1e-3, 12: 1e-3, 14: 1e-3}, False),  # x⁴ + x²y² + y⁴
])
def test_x_fields_on_a_non_symmetric_polynomial_are_named_not_exact(tmp_path, curv, terms,
                                                                   exact):
    """x field components become a radial field with one note: 'NOT exact', naming the surface,
    when the polynomial is not a function of r alone, 'exact' when it is (on a flat base an
    XYPolynomial, on a curved one an ExtendedPolynomial).  Term numbers (the manual's order,
    :data:`MANUAL_TERMS`): 3 x², 4 xy, 5 y², 10 x⁴, 12 x²y², 14 y⁴."""
    text = xpolynom(a=terms, curv=curv).replace("XFLN 0 0", "XFLN 0 2")
    with pytest.warns(UserWarning) as rec:
        lens = read_zmx(write(tmp_path, text))
    cls = ExtendedPolynomial if curv else XYPolynomial
    (s,) = [s for s in lens.surfaces if isinstance(s, cls)]
    assert s.rotationally_symmetric() == exact
    notes = [str(w.message) for w in rec if "x field components" in str(w.message)]
    assert len(notes) == 1
    assert ("NOT exact" in notes[0] and cls.__name__ in notes[0]) == (not exact), notes[0]
