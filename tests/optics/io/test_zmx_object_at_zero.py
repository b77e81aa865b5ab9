"""An object at ``DISZ 0`` (on ``SURF 1``): when dummy gaps follow it, the object lies that far
before the first surface deeplens traces, and the file is the same lens as one with the object
distance written on ``SURF 0``: the object distance is the sum (100 mm), the object-height
field of 5 mm is the chief-ray angle ``-atan(5 / 100)`` (the stop on the first vertex, the
entrance pupil there).  Where the sum is 0 (the object on a traced surface) the file is refused
at ``SURF 0``'s ``DISZ`` line with what to change: deeplens puts a finite object at a distance
!= 0 from the first vertex.
"""

from __future__ import annotations

import math

import pytest
from test_zmx import write

from deeplens.optics.errors import ZemaxFileError
from deeplens.optics.io import read_zmx
from deeplens.optics.paraxial import paraxial


def lens_text(d0, gap):
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "NAME object at 0", "UNIT MM X W X CM MR CPMM",
        "ENPD 10", "FTYP 1 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 5", "WAVM 1 0.55 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", f"  DISZ {d0}",
        "SURF 1", "  TYPE STANDARD", f"  DISZ {gap}",
        "SURF 2", "  STOP", "  TYPE STANDARD", "  CURV 0.02", "  DISZ 5",
        "  GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0", "  DIAM 8 1 0 0 1 \"\"",
        "SURF 3", "  TYPE STANDARD", "  CURV -0.01", "  DISZ 120", "  DIAM 8 1 0 0 1 \"\"",
        "SURF 4", "  TYPE STANDARD", "  DISZ 0", "  DIAM 30 1 0 0 1 \"\""]) + "\n"


@pytest.mark.parametrize("d0, gap", [(0, 100), (40, 60), (100, 0)])
def test_object_at_zero_before_a_dummy_gap(tmp_path, d0, gap):
    lens = read_zmx(write(tmp_path, lens_text(d0, gap)))
    assert lens.spec.object_distance_mm == 100.0
    # the object point (0, +5): a negative field angle (OpticStudio's convention)
    assert lens.spec.fields_deg == pytest.approx([0.0, -math.degrees(math.atan(5 / 100))],
                                                 rel=1e-12)
    # the thick lens's focal length, 1/f = (n-1)(c1 - c2 + (n-1) t c1 c2 / n)
    n, c1, c2, t = 1.5, 0.02, -0.01, 5.0
    assert float(paraxial(lens).efl) == pytest.approx(
        1 / ((n - 1) * (c1 - c2 + (n - 1) * t * c1 * c2 / n)), rel=1e-12)


def test_object_on_the_first_traced_surface_is_refused_at_its_line(tmp_path):
    text = lens_text(0, 0)
    line = text.splitlines().index("  DISZ 0") + 1
    with pytest.raises(ZemaxFileError, match=rf"t.zmx:{line}: the object lies on the first "
                                             rf"surface deeplens traces \(SURF 2\): .* add up to "
                                             rf"0; deeplens puts a finite object at a distance "
                                             rf"!= 0 from the first vertex"):
        read_zmx(write(tmp_path, text))
