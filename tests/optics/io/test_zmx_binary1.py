"""``TYPE BINARY_1`` (OpticStudio's Binary 1) in ``.zmx`` files: read into
:class:`~deeplens.optics.surfaces.Binary1` (``XDAT 1`` the maximum term number, ``XDAT 2`` the
normalisation radius, ``XDAT 3..`` the x-y polynomial phase terms in radians), checked against
the number OpticStudio itself stored in its short-course sample "diffract3" (the automatic
semi-diameter at the image: the +y marginal ray's height, to the 12 digits printed), written
back, and odd records refused on their line."""

from __future__ import annotations

import pytest
import torch
from test_zmx import assert_refused_on_line, assert_written_back, write

from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Binary1
from helpers import read_zmx_quiet

F64 = torch.float64

#: OpticStudio's short-course sample "diffract3": a flat Binary 1 stop (PARM 0 1, 18 terms,
#: R_n 10 mm; XDAT 3.. below, radians), EPD 20 mm, 0.55 µm, on axis, the image plane 80 mm
#: behind; and the automatic semi-diameter OpticStudio stored at the image (DIAM ... 0: solved)
DIFFRACT3_XDAT = (7.112255105933e3, 7.112255102509e3, -7.084507848802e3, 5.512737188901e1,
                  -7.084496933368e3, -5.487259430759e1, -5.464993165213e1, -5.379627317568e1,
                  -5.427566005697e1, 2.656917293157e1, -1.243494818118, 5.314654614184e1,
                  -1.240248904741, 2.655885130194e1, 6.184546727486e-1, 9.455739118475e-1,
                  9.546274208762e-1, 1.373300627383)
OS_IMAGE_SD = 7.07057849426


def binary1_file(body=None, unit="MM", s=1.0):
    """The diffract3 layout written afresh (``body`` replaces the BINARY_1 records); ``s`` mm
    per ``unit``."""
    if body is None:
        body = ["PARM 0 1", "PARM 1 0", "PARM 9 0", "XDAT 1 18", f"XDAT 2 {10 / s!r}"]
        body += [f"XDAT {j + 3} {v!r}" for j, v in enumerate(DIFFRACT3_XDAT)]
    lines = ["VERS 80915 20 20100", "MODE SEQ", "NAME diffract3",
             f"UNIT {unit} X W X CM MR CPMM", f"ENPD {20 / s!r}", "FTYP 0 0 1 1 0 0 0",
             "XFLN 0", "YFLN 0", "WAVM 1 0.55 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE BINARY_1", "  CURV 0.0", *[f"  {b}" for b in body],
             f"  DISZ {80 / s!r}", f"  DIAM {10 / s!r} 0 0 0 1",
             "SURF 2", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0",
             f"  DIAM {OS_IMAGE_SD / s!r} 0 0 0 1"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_marginal_ray_meets_opticstudios_own_number(tmp_path, unit, s):
    """The records read (R_n a length, the A_t unscaled radians, the Extended Polynomial's term
    order); the +y marginal ray (y = 10 mm, parallel) meets the image where OpticStudio put it,
    1e-11 mm from its 12 printed digits (the terms in the other order within a degree give
    7.07128, the phase's sign flipped 27.07; waves or order 2 trace far off)."""
    lens = read_zmx_quiet(write(tmp_path, binary1_file(s=s, unit=unit)))
    b = lens.surfaces[0]
    assert isinstance(b, Binary1) and b.order == 1
    assert float(b.norm_radius) == pytest.approx(10.0, rel=1e-14)
    assert [float(a) for a in b.poly] == list(DIFFRACT3_XDAT)
    y0 = float(lens.spec.aperture_value) / 2
    assert y0 == pytest.approx(10.0, rel=1e-15)
    o = torch.tensor([[0.0, y0, -1.0]], dtype=F64)
    out = lens.trace(Rays(o, torch.tensor([[0.0, 0.0, 1.0]], dtype=F64), 550.0))
    assert out.valid.all()
    z = float(lens.z_sensor())
    assert z == pytest.approx(80.0, rel=1e-14)
    img = out.o + out.d * (z - out.o[:, 2:3]) / out.d[:, 2:3]
    assert float(torch.hypot(img[0, 0], img[0, 1])) == pytest.approx(OS_IMAGE_SD, abs=1e-11)


def test_write_and_read_back(tmp_path):
    assert_written_back(tmp_path, read_zmx_quiet(write(tmp_path, binary1_file())),
                        ["TYPE BINARY_1", "PARM 0 1", "XDAT 1 18", "XDAT 2 10.0",
                         f"XDAT 20 {DIFFRACT3_XDAT[-1]!r}"])


def test_an_order_other_than_one_is_not_written(tmp_path):
    lens = read_zmx_quiet(write(tmp_path, binary1_file()))
    lens.surfaces[0].order = 2
    with pytest.raises(ZemaxFileError, match="order 2 is not written"):
        write_zmx(lens, tmp_path / "out.zmx")


@pytest.mark.parametrize("body,needle,match", [
    (["PARM 0 2", "XDAT 1 5", "XDAT 2 4", "XDAT 7 100"], "PARM 0 2",
     r"BINARY_1 PARM 0 = 2.0 is refused: only 1 \(diffraction order 1\) is read"),
    (["XDAT 1 5", "XDAT 2 4", "XDAT 7 100"], "TYPE BINARY_1",
     r"BINARY_1 PARM 0 = None is refused"),
    (["PARM 0 1", "PARM 3 0.5", "XDAT 1 5", "XDAT 2 4"], "PARM 3",
     r"BINARY_1 PARM 3 = 0.5 is not read \(no stored OpticStudio source gives its meaning"),
    (["PARM 0 1", "XDAT 1 231", "XDAT 2 4"], "XDAT 1",
     r"BINARY_1 XDAT 1 \(the maximum term number\) must be an integer 0..230"),
    (["PARM 0 1", "XDAT 1 5", "XDAT 2 0", "XDAT 7 100"], "XDAT 2",
     r"BINARY_1 XDAT 2 \(the normalisation radius\) must be > 0"),
    (["PARM 0 1", "XDAT 1 2", "XDAT 2 4", "XDAT 7 100"], "XDAT 7",
     r"XDAT 7 lies beyond the 2 phase terms"),
])
def test_odd_records_are_refused_on_their_line(tmp_path, body, needle, match):
    assert_refused_on_line(tmp_path, binary1_file(body), needle, match)


@pytest.mark.parametrize("symmetric", [False, True])
def test_x_fields_on_a_non_symmetric_phase_are_named_not_exact(tmp_path, symmetric):
    """x field components become a radial field with a note: 'NOT exact' naming the Binary 1
    surface when its phase has a non-symmetric term (diffract3's tilts), 'exact' when it is a
    function of x² + y² only (A_3 = A_5)."""
    body = None if not symmetric else ["PARM 0 1", "XDAT 1 5", "XDAT 2 10", "XDAT 5 -7000",
                                       "XDAT 7 -7000"]
    text = binary1_file(body).replace("FTYP 0 0 1 1 0 0 0", "FTYP 0 0 2 1 0 0 0")
    text = text.replace("XFLN 0\n", "XFLN 0 0.5\n").replace("YFLN 0\n", "YFLN 0 0.5\n")
    with pytest.warns(UserWarning) as rec:
        read_zmx(write(tmp_path, text))
    notes = [str(w.message) for w in rec if "x field components" in str(w.message)]
    assert len(notes) == 1
    assert ("NOT exact" in notes[0] and "Binary1" in notes[0]) == (not symmetric)


def test_not_written_to_code_v(tmp_path):
    """CODE V has no equivalent deeplens writes: refused by name, not written as another
    diffractive surface."""
    from deeplens.optics.errors import LensFileError
    from deeplens.optics.io.codev import write_seq

    lens = read_zmx_quiet(write(tmp_path, binary1_file()))
    with pytest.raises(LensFileError, match="Binary1 has no CODE V equivalent"):
        write_seq(lens, tmp_path / "out.seq")
