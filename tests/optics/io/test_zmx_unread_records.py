"""A non-zero ``PARM`` or ``XDAT`` record that a surface type does not read is refused at its
line with one message form naming the surface, the record, its value and what the type reads
(``surface_formats.refuse_unread``, shared by every Zemax surface reader)."""

from __future__ import annotations

import pytest
from test_zmx import singlet, write

from deeplens.optics.errors import ZemaxFileError
from deeplens.optics.io.surface_formats import refuse_unread
from deeplens.optics.io.zmx import read_zmx
from deeplens.optics.io.zmx_parse import Locator


def test_the_first_unread_record_by_number_is_refused_with_its_value_and_why():
    p = Locator("f.zmx")
    records = {9: (0.0, 40), 11: (-2e-7, 44), 10: (3.5, 42), 1: (1.0, 30)}
    with pytest.raises(ZemaxFileError) as e:
        refuse_unread(p, records, "SURF 2: EVENASPH", "PARM 1-8 are read", range(1, 9))
    assert e.value.line == 42   # PARM 9 is 0 (nothing to read); PARM 10 comes before 11
    assert str(e.value) == "f.zmx:42: SURF 2: EVENASPH PARM 10 = 3.5 is not read (PARM 1-8 are read)"
    with pytest.raises(ZemaxFileError, match=r":44: SURF 2: X XDAT 11 = -2e-07 is not read \(no"):
        refuse_unread(p, {11: (-2e-7, 44)}, "SURF 2: X", "none", kind="XDAT")
    refuse_unread(p, {1: (1.0, 30), 9: (0.0, 40)}, "SURF 2: EVENASPH", "why", range(1, 9))


def test_a_negative_unread_value_is_refused_at_its_line(tmp_path):
    """A negative coefficient is as unread as a positive one: ``PARM 9 -0.001`` on an even
    asphere (which has PARM 1-8) is refused at its line, not silently dropped."""
    text = singlet().replace("PARM 1 0", "PARM 9 -0.001")
    p = write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=r"SURF 2: EVENASPH PARM 9 = -0.001 is not read "
                                             r"\(Zemax's even asphere has PARM 1-8\)") as e:
        read_zmx(p)
    assert e.value.line == text.splitlines().index("  PARM 9 -0.001") + 1
