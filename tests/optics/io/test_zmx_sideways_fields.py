"""Field angles of 90 deg or more (``FTYP 0``) are refused at their ``YFLN``/``XFLN`` line.

OpticStudio defines field angles "fully in the range of -180 to 180 degrees", the chief ray's
axial direction cosine ``n`` negative beyond 90 deg (User Guide, *Field Angles and Heights*):
set 12's 220 deg fisheye (``ob_Samy_Gao-1_220deg_``, fields 0, 30, 60, 90, 109 deg) has rays
arriving sideways and from behind.  deeplens launches rays towards ``+z`` (fields within
(-90, 90) deg).  Before, 90 deg was refused by the lens's generic range check, but 109 deg was
read as 71 deg without a word (the radial combination ``atan(hypot(tan x, tan y))`` of
``tan 109 deg < 0``).
"""

from __future__ import annotations

import pytest
from test_zmx import singlet, write

from deeplens.optics.io import ZemaxFileError, read_zmx


@pytest.mark.parametrize("yfln,which", [("YFLN 0 30 109", "field 3 is 109 deg"),
                                        ("YFLN 0 30 90", "field 3 is 90 deg"),
                                        ("YFLN 0 -100 90", "field 2 is -100 deg, field 3 is 90")])
def test_a_field_at_or_beyond_90_deg_is_refused_at_its_line(tmp_path, yfln, which):
    text = singlet(ftyp="FTYP 0 0 3 2 0 0 0", yfln=yfln)
    with pytest.raises(ZemaxFileError, match=rf"t\.zmx:9: YFLN: {which}.*at or beyond 90 deg.*"
                                             r"within \(-90, 90\) deg only"):
        read_zmx(write(tmp_path, text))


def test_an_x_field_beyond_90_deg_is_refused_at_the_xfln_line(tmp_path):
    text = singlet(ftyp="FTYP 0 0 2 2 0 0 0", yfln="YFLN 0 0").replace("XFLN 0 0", "XFLN 0 95")
    with pytest.raises(ZemaxFileError, match=r"t\.zmx:8: XFLN: field 2 is 95 deg"):
        read_zmx(write(tmp_path, text))


def test_fields_beyond_the_count_and_below_90_deg_load(tmp_path):
    """The count in FTYP (here 2) drops the 109 deg field, as the message advises."""
    lens = read_zmx(write(tmp_path, singlet(ftyp="FTYP 0 0 2 2 0 0 0", yfln="YFLN 0 30 109")))
    assert lens.spec.fields_deg == pytest.approx([0.0, 30.0], abs=1e-12)
