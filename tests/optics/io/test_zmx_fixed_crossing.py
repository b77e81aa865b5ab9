"""Fixed semi-diameters (``DIAM`` flag 1) of two surfaces that cross within them.

OpticStudio's semi-diameters, fixed or automatic, do not vignette: it traces every ray, those
beyond the radius where two surfaces meet backwards through the gap.  deeplens takes a
semi-diameter as the clear aperture, so, as for automatic ones, both are limited to that radius
with a located warning where the on-axis beam fits within it, and the gap is traced backwards
where the beam reaches past it.  Checked against the closed-form crossing radius of a
symmetric biconvex lens, ``sqrt(R² − (R − t/2)²)``, and the thick-lens focal length.
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch

from deeplens.optics.errors import ZemaxWarning
from deeplens.optics.io.zmx import read_zmx
from deeplens.optics.paraxial import paraxial

R, T, SD = 20.0, 5.0, 15.0   # radius, centre thickness, the file's fixed semi-diameter (mm)
N_D = 1.5                     # a model glass (GLAS ___BLANK 1 0 n_d V_d): the index is exact
CROSS = math.sqrt(R**2 - (R - T / 2) ** 2)    # 9.68246 mm: where the faces meet


def _file(tmp_path, epd: float, flag1: int = 1, flag2: int = 1):
    text = f"""VERS 190513 80 123457 L123457
MODE SEQ
UNIT MM X W X CM MR CPMM
ENPD {epd}
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV {1 / R!r}
  DISZ {T}
  GLAS ___BLANK 1 0 {N_D} 60.0
  DIAM {SD} {flag1} 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV {-1 / R!r}
  DISZ 19.0
  DIAM {SD} {flag2} 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0.0
  DISZ 0
"""
    path = tmp_path / "crossing.zmx"
    path.write_text(text)
    return path


def _read(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(path)
    return lens, [x.message for x in w if isinstance(x.message, ZemaxWarning)]


def _thick_lens_efl() -> float:
    c1, c2 = 1 / R, -1 / R
    phi = (N_D - 1) * (c1 - c2 + (N_D - 1) * T * c1 * c2 / N_D)
    return 1 / phi


def _stop_behind(path):
    """The same lens with the stop on a flat dummy 1 mm behind it (the stop is never limited)."""
    text = path.read_text().replace("SURF 1\n  STOP\n", "SURF 1\n")
    head, tail = text.split("SURF 3\n")
    head = head.replace("  DISZ 19.0\n", "  DISZ 1.0\n")
    text = (head + "SURF 3\n  STOP\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 18.0\nSURF 4\n"
            + tail)
    path.write_text(text)
    return path


def test_fixed_semi_diameters_that_cross_are_limited_where_the_beam_fits(tmp_path):
    """Both faces' DIAMs fixed (flag 1) beyond where the faces meet, the beam well within:
    both are limited to the crossing radius (the edge thickness there is 0), one located
    warning names them as fixed, the first-order numbers are the thick lens's."""
    path = _stop_behind(_file(tmp_path, epd=10.0))
    lens, notes = _read(path)
    a, b = lens.surfaces[0], lens.surfaces[1]
    assert float(a.semi_diameter) == pytest.approx(CROSS, abs=1e-9)
    assert float(b.semi_diameter) == pytest.approx(CROSS, abs=1e-9)
    z = lens.z_vertices()
    r = torch.tensor([CROSS], dtype=torch.float64)
    zero = torch.zeros_like(r)
    edge = float(z[1] + b.sag(zero, r) - z[0] - a.sag(zero, r))
    assert abs(edge) < 1e-9
    limited = [n for n in notes if "overlap where the surfaces cross" in n.message]
    assert limited[0].line == path.read_text().splitlines().index("SURF 2") + 1
    assert len(limited) == 1 and limited[0].message.startswith(
        "the fixed (DIAM flag 1) semi-diameters")
    assert float(paraxial(lens).efl) == pytest.approx(_thick_lens_efl(), rel=1e-12)


def test_a_beam_past_fixed_crossing_is_traced_backwards(tmp_path):
    """An entrance pupil wider than the crossing: the gap is traced backwards (as OpticStudio
    does) and the file's fixed semi-diameter is kept."""
    lens, notes = _read(_stop_behind(_file(tmp_path, epd=2 * 9.9)))
    assert lens.backward_gaps == {1}
    assert float(lens.surfaces[1].semi_diameter) == SD
    assert float(lens.surfaces[0].semi_diameter) == SD
    gap = [n for n in notes if "backwards through the gap" in n.message]
    assert len(gap) == 1 and gap[0].line == 20
    assert f"cross at r = {CROSS:.6g} mm" in gap[0].message


def test_a_fixed_clear_aperture_is_never_limited(tmp_path):
    """A CLAP is a surface aperture (it vignettes in OpticStudio too): crossing within it is
    still refused at the file's line."""
    from deeplens.optics.io.zmx import ZemaxFileError

    path = _stop_behind(_file(tmp_path, epd=10.0))
    path.write_text(path.read_text().replace('  DIAM 15.0 1 0 0 1 ""\nSURF 3',
                                             '  DIAM 15.0 1 0 0 1 ""\n  CLAP 0 15.0 0\nSURF 3'))
    with pytest.raises(ZemaxFileError, match=r"crossing\.zmx:\d+: surfaces 0 and 1 cross"):
        _read(path)


def test_a_floating_stop_is_sized_by_the_files_own_semi_diameters(tmp_path):
    """FLOA with a stop that has no DIAM (sized by the limiting aperture, zmx_stop_size): the
    beam is sized by the file's fixed semi-diameters, not by the limits the reader put where
    the faces cross.  The front face (15 mm) limits a beam from infinity: EPD = 30 mm; that
    beam reaches past the crossing, so the gap is traced backwards and 15 mm kept."""
    path = _stop_behind(_file(tmp_path, epd=10.0))
    path.write_text(path.read_text().replace("ENPD 10.0\n", "FLOA\n"))
    lens, notes = _read(path)
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(2 * SD, rel=1e-12)
    assert lens.backward_gaps == {1}
    assert [float(s.semi_diameter) for s in lens.surfaces[:2]] == [SD, SD]
    sized = [n for n in notes if "has no semi-diameter under FLOA" in n.message]
    assert len(sized) == 1 and f"semi-diameter {SD:.6g} mm" in sized[0].message
