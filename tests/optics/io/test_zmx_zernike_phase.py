"""``TYPE FZERNPHA`` (OpticStudio's Zernike Fringe Phase) in ``.zmx`` files: read into
:class:`~deeplens.optics.surfaces.ZernikeFringePhase` (``XDAT 1`` the number of terms, ``XDAT 2``
the normalisation radius, ``XDAT 3..`` the Fringe coefficients in waves), checked against the
numbers OpticStudio itself stored in its sample file "Test_Spherical" (automatic semi-diameters:
the marginal ray's heights, to the 10 digits printed), written back, and odd records refused on
their line."""

from __future__ import annotations

import pytest
import torch
from test_zmx import assert_refused_on_line, assert_written_back, write

from deeplens.optics.io import lens_to_dict
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import IdealLens, ZernikeFringePhase
from helpers import read_zmx_quiet

F64 = torch.float64

#: OpticStudio's sample "Test_Spherical" (a Zernike Fringe Phase, A_1 = -2, A_4 = -3, A_9 = -1:
#: Σ A_j Z_j = -6 ρ⁴, R_n 4 mm, before a paraxial lens of f = 100 mm, EPD 4 mm, 0.55 µm): the
#: semi-diameters OpticStudio computed at the plane 98 mm behind the lens ("MARGINAL FOCUS") and
#: at the paraxial focus, i.e. the marginal ray's |y| there
OS_MARGINAL_98 = 4.250034392839e-4
OS_PARAXIAL_100 = 4.125000350947e-2


def phase_file(body=None, unit="MM", s=1.0):
    """The Test_Spherical layout written afresh: FZERNPHA (``body`` replaces its records), a
    paraxial lens f = 100, planes at 98 and 100 mm; ``s`` mm per ``unit``."""
    if body is None:
        body = ["PARM 0 1", "PARM 1 0", "XDAT 1 9", f"XDAT 2 {4 / s!r}", "XDAT 3 -2",
                "XDAT 4 0", "XDAT 5 0", "XDAT 6 -3", "XDAT 7 0", "XDAT 8 0", "XDAT 9 0",
                "XDAT 10 0", "XDAT 11 -1"]
    lines = ["VERS 130724 162 23203", "MODE SEQ", "NAME spherical by a phase",
             f"UNIT {unit} X W X CM MR CPMM", f"ENPD {4 / s!r}", "FTYP 0 0 1 1 0 0 0",
             "XFLN 0", "YFLN 0", "WAVM 1 0.55 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE FZERNPHA", "  CURV 0.0", *[f"  {b}" for b in body],
             "  DISZ 0", f"  DIAM {2.5 / s!r} 0 0 0 1 \"\"",
             "SURF 2", "  TYPE PARAXIAL", "  CURV 0.0", f"  PARM 1 {100 / s!r}", "  PARM 2 0",
             f"  DISZ {98 / s!r}", f"  DIAM {2.5 / s!r} 0 0 0 1 \"\"",
             "SURF 3", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {2 / s!r}",
             "SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_marginal_ray_meets_opticstudios_own_numbers(tmp_path, unit, s):
    """The records read (R_n a length, the A_j unscaled waves); the marginal ray (y = 2 mm,
    parallel) crosses the planes 98 and 100 mm behind the paraxial lens where OpticStudio put
    it: 1e-13 mm from its printed values (13 digits; radians instead of waves, another order
    or R_n misread would miss by far more)."""
    lens = read_zmx_quiet(write(tmp_path, phase_file(s=s, unit=unit)))
    z = lens.surfaces[0]
    assert isinstance(z, ZernikeFringePhase) and isinstance(lens.surfaces[1], IdealLens)
    assert float(z.norm_radius) == pytest.approx(4.0, rel=1e-14)
    assert [float(a) for a in z.zernike] == [-2.0, 0.0, 0.0, -3.0, 0.0, 0.0, 0.0, 0.0, -1.0]
    y0 = float(lens.spec.aperture_value) / 2   # the marginal ray: 2 mm (to 1 ulp in inches)
    assert y0 == pytest.approx(2.0, rel=1e-15)
    o = torch.tensor([[0.0, y0, -1.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0]], dtype=F64)
    out = lens.trace(Rays(o, d, 550.0))
    assert out.valid.all()
    y98 = out.o[0, 1] + (98.0 - out.o[0, 2]) * out.d[0, 1] / out.d[0, 2]
    y100 = out.o[0, 1] + (100.0 - out.o[0, 2]) * out.d[0, 1] / out.d[0, 2]
    assert abs(float(y98)) == pytest.approx(OS_MARGINAL_98, abs=1e-13)
    assert abs(float(y100)) == pytest.approx(OS_PARAXIAL_100, abs=1e-13)
    assert float(y98) < 0 and float(y100) < 0   # it crosses the axis before 98 mm


def test_write_and_read_back(tmp_path):
    assert_written_back(tmp_path, read_zmx_quiet(write(tmp_path, phase_file())),
                        ["TYPE FZERNPHA", "PARM 0 1", "XDAT 1 9", "XDAT 11 -1.0"])


def test_an_order_other_than_one_is_not_written(tmp_path):
    lens = read_zmx_quiet(write(tmp_path, phase_file()))
    lens.surfaces[0].order = 2
    with pytest.raises(ZemaxFileError, match="order 2 is not written"):
        write_zmx(lens, tmp_path / "out.zmx")


@pytest.mark.parametrize("body,needle,match", [
    (["PARM 0 2", "XDAT 1 4", "XDAT 2 4", "XDAT 6 1"], "PARM 0 2",
     r"FZERNPHA PARM 0 = 2.0 is refused: only 1 is read"),
    (["XDAT 1 4", "XDAT 2 4", "XDAT 6 1"], "TYPE FZERNPHA",
     r"FZERNPHA PARM 0 = None is refused"),
    (["PARM 0 1", "PARM 3 0.5", "XDAT 1 4", "XDAT 2 4"], "PARM 3",
     r"FZERNPHA PARM 3 = 0.5 is not read \(no stored OpticStudio source gives its meaning"),
    (["PARM 0 1", "XDAT 1 38", "XDAT 2 4"], "XDAT 1",
     r"FZERNPHA XDAT 1 \(the number of Zernike terms\) must be an integer 0..37"),
    (["PARM 0 1", "XDAT 1 4", "XDAT 2 0", "XDAT 6 1"], "XDAT 2",
     r"FZERNPHA XDAT 2 \(the normalisation radius\) must be > 0"),
    (["PARM 0 1", "XDAT 1 2", "XDAT 2 4", "XDAT 6 1"], "XDAT 6",
     r"XDAT 6 lies beyond the 2 Zernike terms"),
])
def test_odd_records_are_refused_on_their_line(tmp_path, body, needle, match):
    assert_refused_on_line(tmp_path, phase_file(body), needle, match)


def test_a_semi_diameter_beyond_the_radius_warns_of_the_extrapolation(tmp_path):
    text = phase_file().replace("XDAT 2 4.0", "XDAT 2 1.5")
    with pytest.warns(UserWarning, match="the Zernike phase is continued beyond it"):
        read_zmx(write(tmp_path, text))


def test_a_zeroed_flat_phase_between_equal_media_is_a_dummy(tmp_path):
    """A flat FZERNPHA whose coefficients are all 0 (as OpticStudio's tolerancing files leave one
    at an off-axis mirror's vertex plane) adds no phase: merged into the gaps as a flat STANDARD
    dummy (the same lens); with a non-zero term, or as the stop, it is kept."""
    body = ["PARM 0 1", "XDAT 1 9", "XDAT 2 4", "XDAT 6 0", "XDAT 11 0"]
    text = phase_file(body).replace("  STOP\n", "")
    text = text.replace("SURF 2\n", "SURF 2\n  STOP\n", 1)
    zeroed = read_zmx_quiet(write(tmp_path, text, "zero.zmx"))
    plain = read_zmx_quiet(write(tmp_path, text.replace("TYPE FZERNPHA", "TYPE STANDARD"),
                                 "plain.zmx"))
    assert not any(isinstance(s, ZernikeFringePhase) for s in zeroed.surfaces)
    a, b = lens_to_dict(zeroed), lens_to_dict(plain)
    a.pop("name", None), b.pop("name", None)
    assert a == b
    kept = read_zmx_quiet(write(tmp_path, text.replace("XDAT 6 0", "XDAT 6 0.5"), "kept.zmx"))
    assert isinstance(kept.surfaces[0], ZernikeFringePhase)
    stop = read_zmx_quiet(write(tmp_path, phase_file(body), "stop.zmx"))
    assert isinstance(stop.surfaces[0], ZernikeFringePhase) and not len(stop.surfaces[0].zernike)


#: OpticStudio's short-course sample "zern2" (a Zernike Fringe Phase with 25 terms, R_n 20 mm,
#: before two BK7 singlets, EPD 40 mm, 0.55 µm): its phase coefficients (XDAT 3.., waves) and the
#: automatic semi-diameters OpticStudio stored at the four lens surfaces and the image, which for
#: this field-free file are the height of the marginal ray at -y (the largest of the four
#: pupil-edge rays)
ZERN2_XDAT = {3: -2.4073e-2, 4: 7.52071e-1, 5: -1.504, 6: -2.4391e-2, 7: 1.2279e-2,
              8: 1.6372e-2, 9: 3.86047e-1, 10: -7.7209e-1, 11: -5.68e-4, 14: 2.32e-4,
              15: 3.09e-4, 16: 6.814e-3, 17: -1.3628e-2, 18: 1.66e-4, 25: 1.06e-4, 26: -2.12e-4,
              27: 4.41e-4}
ZERN2_OS_HEIGHTS = (20.00058834765, 19.30924436727, 10.32721651527, 10.01239399033,
                    10.01993642299)


def zern2_file():
    """The zern2 layout written afresh (its two zero coordinate breaks left out)."""
    xdat = [f"  XDAT {j} {v!r}" for j, v in sorted(ZERN2_XDAT.items())]
    lines = ["VERS 80915 2 20100", "MODE SEQ", "NAME zern2", "UNIT MM X W X CM MR CPMM",
             "ENPD 40", "GCAT SCHOTT", "FTYP 0 0 1 1 0 0 1", "XFLD 0", "YFLD 0", "WAVL 0.55",
             "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  TYPE FZERNPHA", "  CURV 0.0", "  PARM 0 1", "  PARM 1 0",
             "  XDAT 1 25", "  XDAT 2 20", *xdat, "  DISZ 0", "  DIAM 20 0 0 0 1",
             "SURF 2", "  STOP", "  TYPE STANDARD", "  CURV 0.014856710990000001",
             "  DISZ 10", "  GLAS BK7 0 0 1.5 40 0 0 0 0 0 0", "  DIAM 20.00058834765 0 0 0 1",
             "SURF 3", "  TYPE STANDARD", "  CURV -0.0020168851199", "  DISZ 50",
             "  DIAM 19.30924436727 0 0 0 1",
             "SURF 4", "  TYPE STANDARD", "  CURV -0.0192441958", "  DISZ 5",
             "  GLAS BK7 0 0 1.5 40 0 0 0 0 0 0", "  DIAM 10.32721651527 0 0 0 1",
             "SURF 5", "  TYPE STANDARD", "  CURV 0.013667634425", "  DISZ 20",
             "  DIAM 10.01239399033 0 0 0 1",
             "SURF 6", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 10.01993642299 0 0 0 1"]
    return "\n".join(lines) + "\n"


def test_zern2_marginal_ray_meets_opticstudios_semi_diameters(tmp_path):
    """17 non-zero Fringe terms (piston, tilts, defocus, astigmatism, coma, spherical, trefoil
    and higher, up to Z25): the -y marginal ray (apertures opened) meets the two singlets and
    the image at the heights OpticStudio computed, to 1e-10 mm (its 13 printed digits; the
    ±x and +y rays, and the same phase in radians, miss by > 1e-4 mm)."""
    lens = read_zmx_quiet(write(tmp_path, zern2_file()))
    assert isinstance(lens.surfaces[0], ZernikeFringePhase)
    assert len(lens.surfaces[0].zernike) == 25
    with torch.no_grad():
        for s in lens.surfaces:
            s.semi_diameter.fill_(30.0)
    o = torch.tensor([[0.0, -20.0, -1.0]], dtype=F64)
    out, hits = lens.trace(Rays(o, torch.tensor([[0.0, 0.0, 1.0]], dtype=F64), 550.0),
                           record=True)
    assert out.valid.all()
    z = float(lens.z_sensor())
    img = out.o + out.d * (z - out.o[:, 2:3]) / out.d[:, 2:3]
    heights = [float(torch.hypot(h[0, 0], h[0, 1])) for h in hits[1:]]
    heights.append(float(torch.hypot(img[0, 0], img[0, 1])))
    assert heights == pytest.approx(list(ZERN2_OS_HEIGHTS), abs=1e-10)


@pytest.mark.parametrize("a5,exact", [(0.5, False), (0.0, True)])
def test_x_fields_on_an_astigmatic_phase_are_named_not_exact(tmp_path, a5, exact):
    """x field components become a radial field with a note: 'NOT exact' naming the phase
    surface when it has a non-symmetric term (astigmatism A_5), 'exact' when only m = 0 terms."""
    body = ["PARM 0 1", "XDAT 1 9", "XDAT 2 4", "XDAT 6 0.3", f"XDAT 7 {a5!r}"]
    text = phase_file(body).replace("FTYP 0 0 1 1 0 0 0", "FTYP 0 0 2 1 0 0 0")
    text = text.replace("XFLN 0\n", "XFLN 0 0.5\n").replace("YFLN 0\n", "YFLN 0 0.5\n")
    with pytest.warns(UserWarning) as rec:
        read_zmx(write(tmp_path, text))
    notes = [str(w.message) for w in rec if "x field components" in str(w.message)]
    assert len(notes) == 1
    assert ("NOT exact" in notes[0] and "ZernikeFringePhase" in notes[0]) == (not exact)
