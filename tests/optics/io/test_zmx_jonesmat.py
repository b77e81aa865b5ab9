"""Zemax ``JONESMAT`` (OpticStudio's Jones Matrix surface: an idealised polarizer/retarder on a
plane): read as the flat ``STANDARD`` surface with one located note that its matrix is not
applied (deeplens traces no polarization); a curvature or an unknown ``PARM`` refused."""

from __future__ import annotations

import warnings

import pytest
import torch

from deeplens.analysis.spot import spot_diagram
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.paraxial import paraxial

_FILE = """VERS 240000 3 0
MODE SEQ
UNIT MM X W X CM MR CPMM
ENPD 8
FTYP 0 0 2 1 0 0 0
WAVM 1 0.5875618 1
PWAV 1
YFLN 0 5
SURF 0
  TYPE STANDARD
  CURV 0
  DISZ INFINITY
SURF 1
  STOP
  TYPE {type}
  CURV {curv}
{parms}  DISZ 3
  GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0
SURF 2
  TYPE STANDARD
  CURV -0.04
  DISZ 48
SURF 3
  TYPE STANDARD
  CURV 0
  DISZ 0
"""
_POLARIZER = "".join(f"  PARM {i} {v}\n" for i, v in enumerate([1, 0, 0, 0, 0, 0, 0, 0], 1))


def _read(tmp_path, name, **kw):
    f = tmp_path / name
    f.write_text(_FILE.format(**{"type": "STANDARD", "curv": 0, "parms": "", **kw}))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(f)
    return lens, [x.message for x in w if isinstance(x.message, ZemaxWarning)], f


def test_a_jones_matrix_surface_is_the_plane_with_a_located_note(tmp_path):
    """A plano-convex lens whose plane face is an x polarizer (A = 1): the same lens as the
    file with ``STANDARD`` there (EFL, and real rays of two fields land at the same points);
    the EFL is the plano-convex lensmaker's 1 / ((n − 1) c) = 50 mm; one note on the TYPE line
    names the matrix and that it is not applied."""
    jones, notes, f = _read(tmp_path, "jones.zmx", type="JONESMAT", parms=_POLARIZER)
    plain, plain_notes, _ = _read(tmp_path, "plain.zmx")
    assert float(paraxial(jones).efl) == pytest.approx(1.0 / (0.5 * 0.04), rel=1e-12)
    assert float(paraxial(jones).efl) == float(paraxial(plain).efl)
    mine = [n for n in notes if "JONESMAT" in str(n)]
    assert len(mine) == 1 and not [n for n in plain_notes if "JONESMAT" in str(n)]
    assert mine[0].line == 15 and mine[0].source == str(f)
    assert "A = 1+0i" in str(mine[0]) and "not applied" in str(mine[0])
    assert [type(s).__name__ for s in jones.surfaces] == [type(s).__name__ for s in plain.surfaces]
    for field in (0.0, 5.0):
        a, b = (spot_diagram(lens.to(torch.float64), field, sampling="hexapolar:4").points
                for lens in (jones, plain))
        assert a.shape[0] > 30 and torch.equal(a, b)


@pytest.mark.parametrize("kw, line, what", [
    ({"curv": 0.01}, 16, "CURV 0.01"),
    ({"parms": _POLARIZER + "  PARM 9 1\n"}, 25, "PARM 9"),
])
def test_a_curved_or_unknown_jones_matrix_is_refused_at_its_line(tmp_path, kw, line, what):
    f = tmp_path / "bad.zmx"
    f.write_text(_FILE.format(**{"type": "JONESMAT", "curv": 0, "parms": _POLARIZER, **kw}))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f)
    assert e.value.line == line and what in str(e.value), str(e.value)


def test_the_optiland_oracle_reads_the_jones_plane_as_deeplens_does(tmp_path):
    """optiland 0.6 has no JONESMAT: the corpus oracle gives it the plane (``STANDARD``), and
    its EFL, pupil and back focus equal deeplens' (the third unseen set's
    ``zospy_ref_polarization``)."""
    pytest.importorskip("optiland")
    from test_zmx_corpus import _first_order, _oracle

    lens, _, f = _read(tmp_path, "jones.zmx", type="JONESMAT", parms=_POLARIZER)
    numbers = _first_order(lens, _oracle(f, lens)[0], 1.0, f)
    for what, (dl, ol) in numbers.items():
        assert dl == pytest.approx(ol, rel=1e-9), what
