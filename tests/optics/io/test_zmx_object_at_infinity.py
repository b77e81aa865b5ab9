"""An object thickness (``DISZ`` of ``SURF 0``) of 1e10 lens units or more is an object at
infinity (docs/guide/zemax.md, "What is read"): OpTaliX's exporter writes its infinite object as
``DISZ 0.1000000000E+21`` (the fifth unseen set's ``AFL12-15``), refused before as a length
beyond the 1e12 mm limit of lens files.  The reading is the file with ``DISZ INFINITY``, with
one located note at the line; below the threshold the object stays finite."""

from __future__ import annotations

import math
import warnings

import pytest
from test_zmx import line_of, singlet, write

from deeplens.optics.io import lens_to_dict, read_zmx
from deeplens.optics.io.zmx import ZemaxWarning
from deeplens.optics.io.zmx_parse import OBJECT_AT_INFINITY


def _quiet(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path)


@pytest.mark.parametrize("obj, unit", [("0.1000000000E+21", "MM"), ("1e10", "MM"),
                                       ("1E+10", "IN"), ("5e11", "CM")])
def test_a_huge_object_thickness_is_an_object_at_infinity(tmp_path, obj, unit):
    text = singlet(obj=obj, unit=unit)
    p = write(tmp_path, text)
    with pytest.warns(ZemaxWarning, match=r"object distance DISZ .* \(SURF 0\) is 1e\+10 lens "
                                          r"units or more: read as an object at infinity") as rec:
        read_zmx(p)
    w = next(r.message for r in rec if "object at infinity" in str(r.message))
    assert w.line == line_of(text, f"DISZ {obj}") and w.feature == "DISZ"
    got = lens_to_dict(_quiet(p))
    want = lens_to_dict(_quiet(write(tmp_path, singlet(obj="INFINITY", unit=unit), "inf.zmx")))
    assert got == want
    assert math.isinf(_quiet(p).spec.object_distance_mm)


def test_just_below_the_threshold_the_object_stays_finite(tmp_path):
    below = OBJECT_AT_INFINITY * (1 - 1e-6)
    p = write(tmp_path, singlet(obj=repr(below)))
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        lens = read_zmx(p)
    assert not any("object at infinity" in str(r.message) for r in rec)
    assert lens.spec.object_distance_mm == below      # the file's number, not infinity
