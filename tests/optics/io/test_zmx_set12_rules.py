"""Readings met by the twelfth unseen set of real files (docs/guide/zemax.md), each on a small
hand-written file checked by a closed form or an independent reading:

* an image-space F-number (``FNUM f 0``) on a system whose focal length is negative (a relay
  with one intermediate image, or a diverging lens) sizes the pupil as ``EPD = |EFL| / F#``, as
  OpticStudio does (its own stored semi-diameters on such telescopes reproduce that pupil to
  12 digits) and as optiland's ``imageFNO`` does; before, it was refused as needing a positive
  focal length.
"""

from __future__ import annotations

import math
import warnings

import pytest
from test_zmx import write

from deeplens.optics.io import read_zmx
from deeplens.optics.paraxial import paraxial

_HEAD = """VERS 80915 20 20100
MODE SEQ
UNIT MM X W X CM MR CPMM
{aperture}
FTYP 0 0 1 1 0 0 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
"""


def _surf(k, *lines):
    return f"SURF {k}\n" + "".join(f"  {ln}\n" for ln in lines)


def _quiet(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path)


# --------------------------------------------------- an F-number on a negative focal length
_N, _C, _T, _GAP = 1.5, 0.02, 4.0, 250.0     # two plano-convex singlets (f = 100 mm each)
_GLASS = "GLAS ___BLANK 1 0 1.5 1e9 0 0 0 0 0 0"
_RELAY = "".join([_surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
                  _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 10"),
                  _surf(2, "TYPE STANDARD", f"CURV {_C}", f"DISZ {_T}", _GLASS),
                  _surf(3, "TYPE STANDARD", "CURV 0", f"DISZ {_GAP}"),
                  _surf(4, "TYPE STANDARD", f"CURV {_C}", f"DISZ {_T}", _GLASS),
                  _surf(5, "TYPE STANDARD", "CURV 0", "DISZ 290"),
                  _surf(6, "TYPE STANDARD", "CURV 0", "DISZ 0")])


def _relay_efl_by_hand():
    """The relay's EFL by a y-nu trace written out here: refraction ``nu' = nu - y φ``, transfer
    ``y' = y + (t / n) nu``; ``EFL = -1 / nu'`` in air (negative: one intermediate image, the
    singlets 254 mm apart, more than the sum of their focal lengths)."""
    y, nu = 1.0, 0.0
    for phi, t, n in ((_C * (_N - 1), _T, _N), (0.0, _GAP, 1.0),
                      (_C * (_N - 1), _T, _N), (0.0, 0.0, 1.0)):
        nu = nu - y * phi
        y = y + t / n * nu
    return -1.0 / nu


@pytest.mark.parametrize("fno", [10.0, 6.5])
def test_fnum_on_a_negative_focal_length_takes_its_magnitude(tmp_path, fno):
    """OpticStudio's *Image Space F/#* is the ratio of the paraxial infinite-conjugate EFL to
    the paraxial entrance-pupil diameter; a negative EFL has the pupil of its magnitude,
    ``EPD = |EFL| / F#`` (OpticStudio's stored semi-diameters on such files, Zemax guide), and
    the F-number deeplens reports is that positive ratio again.  The stop is the first surface,
    so its semi-diameter is ``EPD / 2``.  Before, such a file was refused."""
    path = write(tmp_path, _HEAD.format(aperture=f"FNUM {fno} 0") + _RELAY)
    lens = _quiet(path)
    p = paraxial(lens)
    efl = _relay_efl_by_hand()
    assert efl < 0
    assert float(p.efl) == pytest.approx(efl, rel=1e-13)
    assert float(p.entrance_pupil_diameter) == pytest.approx(abs(efl) / fno, rel=1e-13)
    assert float(lens.stop.semi_diameter) == pytest.approx(abs(efl) / fno / 2, rel=1e-13)
    assert float(p.fno) == pytest.approx(fno, rel=1e-13)


def test_fnum_on_a_negative_focal_length_as_optiland_reads_it(tmp_path):
    """The independent reading: optiland reads the same file (``FNUM`` as its ``imageFNO``,
    whose pupil is ``|f2| / FNO``) and gets the same EFL, sign included, and pupil."""
    pytest.importorskip("optiland")
    import numpy as np
    from optiland.fileio import load_zemax_file

    path = write(tmp_path, _HEAD.format(aperture="FNUM 10 0") + _RELAY)
    lens = _quiet(path)
    p = paraxial(lens)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = load_zemax_file(str(path))
    f2 = float(np.ravel(op.paraxial.f2())[0])
    epd = float(np.ravel(op.paraxial.EPD())[0])
    assert f2 < 0 and math.isfinite(f2)
    assert float(p.efl) == pytest.approx(f2, rel=1e-12)
    assert float(p.entrance_pupil_diameter) == pytest.approx(epd, rel=1e-12)
