"""Malformed or hostile ``.zmx`` files (issue 38): each is refused or warned about with the
file, the line and what was expected, never read silently or with a traceback."""

from __future__ import annotations

import pytest
from test_zmx import line_of, singlet, write

from deeplens.optics.io import ZemaxFileError, read_zmx


def test_a_second_stop_is_refused_naming_the_first(tmp_path):
    text = singlet().replace("SURF 3\n", "SURF 3\n  STOP\n")
    first = line_of(text, "STOP")
    second = line_of(text.replace("  STOP", "  XXXX", 1), "STOP")
    with pytest.raises(ZemaxFileError, match=rf"t.zmx:{second}: a second STOP \(SURF 3\): the "
                                             rf"stop is already SURF 1 \(STOP on line {first}\)"):
        read_zmx(write(tmp_path, text))
    assert read_zmx(write(tmp_path, singlet(), "one.zmx")).stop_index == 0
