"""Field angles of 90 deg or more (``FTYP 0``) are left out with a note at their line.

OpticStudio defines field angles "fully in the range of -180 to 180 degrees", the chief ray's
axial direction cosine ``n`` negative beyond 90 deg (User Guide, *Field Angles and Heights*):
set 12's 220 deg fisheye (``ob_Samy_Gao-1_220deg_``, fields 0, 30, 60, 90, 109 deg) and
OpticStudio's 200 and 210 deg wide-angle samples (set 5: 100 deg, 105 deg) have rays arriving
sideways and from behind.  deeplens launches rays towards ``+z`` (fields within (-90, 90)
deg), so those fields are not read; the lens and its other fields are.  Before, 90 deg was
refused by the lens's generic range check, and 100, 105 or 109 deg were read as 80, 75 or
71 deg without a word (the radial combination ``atan(hypot(tan x, tan y))`` of
``tan v < 0``).
"""

from __future__ import annotations

import pytest
from test_zmx import singlet, write

from deeplens.optics.io import ZemaxWarning, read_zmx


@pytest.mark.parametrize("yfln,which,kept", [
    ("YFLN 0 30 109", r"field 3 \(109 deg\)", [0.0, 30.0]),
    ("YFLN 0 30 90", r"field 3 \(90 deg\)", [0.0, 30.0]),
    ("YFLN 0 -100 20", r"field 2 \(-100 deg\)", [0.0, 20.0]),
    ("YFLN 0 100 -180", r"field 2 \(100 deg\), field 3 \(-180 deg\)", [0.0]),
])
def test_a_field_at_or_beyond_90_deg_is_left_out_with_a_note_at_its_line(tmp_path, yfln, which,
                                                                         kept):
    text = singlet(ftyp="FTYP 0 0 3 2 0 0 0", yfln=yfln)
    with pytest.warns(ZemaxWarning, match=rf"t\.zmx:9: YFLN: {which} not read: .*at or beyond "
                                          r"90 deg.*within \(-90, 90\) deg only"):
        lens = read_zmx(write(tmp_path, text))
    assert lens.spec.fields_deg == pytest.approx(kept, abs=1e-12)


def test_an_x_field_beyond_90_deg_is_left_out_at_the_xfln_line(tmp_path):
    text = singlet(ftyp="FTYP 0 0 3 2 0 0 0", yfln="YFLN 0 0 10").replace("XFLN 0 0",
                                                                          "XFLN 0 95 0")
    with pytest.warns(ZemaxWarning, match=r"t\.zmx:8: XFLN: field 2 \(95 deg\) not read"):
        lens = read_zmx(write(tmp_path, text))
    assert lens.spec.fields_deg == pytest.approx([0.0, 10.0], abs=1e-12)


def test_fields_below_90_deg_are_read_as_before(tmp_path):
    lens = read_zmx(write(tmp_path, singlet(ftyp="FTYP 0 0 3 2 0 0 0", yfln="YFLN 0 30 89.5")))
    assert lens.spec.fields_deg == pytest.approx([0.0, 30.0, 89.5], abs=1e-12)


def test_a_file_whose_every_field_lies_at_or_beyond_90_deg_is_refused_at_its_yfln_line(
        tmp_path):
    """No field left to read: refused at the ``YFLN`` line, naming the angles, rather than read
    with an on-axis field the file does not have."""
    from deeplens.optics.io import ZemaxFileError

    text = singlet(ftyp="FTYP 0 0 2 2 0 0 0", yfln="YFLN 95 100").replace("XFLN 0 0", "XFLN 0 0")
    with pytest.raises(ZemaxFileError, match=r"t\.zmx:9: every field lies at or beyond 90 deg "
                                             r"\(YFLN 95, 100"):
        read_zmx(write(tmp_path, text))
