"""FTYP 3 (real image height): the chief-ray solve steps back from a trial angle that fails.

The hand-written singlet below (stop 2 mm in front, a rear surface concave towards the image,
``CURV 0.1``) totally reflects its chief ray beyond about 29 deg, while its paraxial slope
(0.596 mm/deg) puts the first trial for a 20 mm image height at 33.6 deg: the old solver got a
NaN there and refused the field; the real chief ray reaches 20 mm at 24.6 deg.
"""

from __future__ import annotations

import math

import pytest
from test_zmx import singlet, write

from deeplens.optics.io import ZemaxFileError, read_zmx
from deeplens.optics.io.zmx_system import chief_height

TIR_SINGLET = dict(curv1=0.02, curv2=0.1, t=8, bfl=20, s1_extra=(), k=0, diam1=6)


def tir_singlet(h: float) -> str:
    return singlet(ftyp="FTYP 3 0 2 2 0 0 0", yfln=f"YFLN 0 {h!r}", **TIR_SINGLET)


@pytest.mark.parametrize("h", [20.0, 30.0])
def test_solve_steps_back_from_a_failing_first_trial(tmp_path, h):
    lens = read_zmx(write(tmp_path, tir_singlet(h)))
    theta = lens.spec.fields_deg[1]
    # the case the test is about: the paraxial first trial h / slope fails (TIR)
    slope = abs(chief_height(lens, 1e-3)) / 1e-3
    assert math.isnan(chief_height(lens, h / slope))
    assert 0.0 < theta < h / slope
    # the solved field's chief ray lands at the height (float64 trace: 1e-12 relative)
    assert abs(chief_height(lens, theta)) == pytest.approx(h, abs=1e-10 * h)
    # and it is the smallest such angle: heights grow monotonically on [0, theta]
    hs = [abs(chief_height(lens, theta * k / 8)) for k in range(1, 9)]
    assert all(b > a for a, b in zip(hs, hs[1:]))


def test_a_first_trial_that_works_needs_no_step_back(tmp_path):
    lens = read_zmx(write(tmp_path, tir_singlet(5.0)))
    theta = lens.spec.fields_deg[1]
    assert abs(chief_height(lens, theta)) == pytest.approx(5.0, abs=1e-10 * 5.0)


def test_an_unreachable_height_is_refused_with_the_last_chief_ray_found(tmp_path):
    """A singlet whose chief rays miss its rear surface (R = -10 mm) beyond about 65 deg and
    never land above 15 mm: the refusal names the last chief ray found and the failing angle."""
    text = singlet(ftyp="FTYP 3 0 2 2 0 0 0", yfln="YFLN 0 500", curv1=0.05, curv2=-0.1, t=8,
                   bfl=20, s1_extra=(), k=0, diam1=6)
    with pytest.raises(ZemaxFileError, match=r"t\.zmx:7: FTYP 3 \(real image height\): no chief "
                                             r"ray reaches image height 500 mm .*the chief ray "
                                             r"of 6[45]\.[0-9]+ deg lands at [0-9.]+ mm; from "
                                             r"6[45]\.[0-9]+ deg on it misses"):
        read_zmx(write(tmp_path, text))
