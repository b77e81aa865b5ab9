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


#: a Jones matrix plane at DISZ 0 in front of a stop on a biconvex lens's first vertex (the
#: layout of OpticStudio's coating-analysis sample: JONESMAT, then the lens, R = ±20, t = 5,
#: model glass n = 2)
_JONES_ON_THE_LENS = """VERS 240000 3 0
MODE SEQ
UNIT MM X W X CM MR CPMM
ENPD 8
FTYP 0 0 1 1 0 0 0
WAVM 1 0.5875618 1
PWAV 1
YFLN 0
SURF 0
  TYPE STANDARD
  CURV 0
  DISZ INFINITY
SURF 1
  TYPE JONESMAT
  CURV 0
""" + _POLARIZER + """  DISZ 0
SURF 2
  STOP
  TYPE STANDARD
  CURV 0.05
  DISZ 5
  GLAS ___BLANK 1 0 2 0 0 0 0 0 0 0
SURF 3
  TYPE STANDARD
  CURV -0.05
  DISZ 30
SURF 4
  TYPE STANDARD
  CURV 0
  DISZ 0
"""


def test_oracles_give_a_jones_plane_on_a_lens_vertex_the_air_before_it(monkeypatch, tmp_path):
    """A Jones matrix plane at ``DISZ 0`` in front of the lens's first face: deeplens drops it
    as a dummy (a plane in air), so both oracles, which keep it, must give it the air before
    the face and the face the glass.  Before, the oracles' plain-plane test knew ``STANDARD``
    only: the Jones plane took the glass, the first face did not refract, and optiland and
    rayoptics both gave EFL 20 (the rear face alone) against the thick lens's 10.6667 worked
    out here by hand (``φ = (n − 1)(c1 − c2) + (n − 1)² t c1 c2 / n``)."""
    pytest.importorskip("optiland")
    pytest.importorskip("rayoptics")
    from test_zmx_corpus import (_dl_path_coords, _file_path_coords, _first_order,
                                 _medium_after, _oracle, _plain_planes)
    from test_zmx_corpus_rayoptics import _corpus_of_one, _numbers, _rayoptics

    lens, scratch = _corpus_of_one("jl.zmx", _JONES_ON_THE_LENS, monkeypatch, tmp_path)
    f = tmp_path / "jl.zmx"
    assert _plain_planes(f) == [True, True, False, False, True]
    n = [float(m.n(587.5618)) for m in lens.materials]
    q = _file_path_coords(f)[2]
    media = [n[j] for j in _medium_after(lens, _dl_path_coords(lens), q, _plain_planes(f))]
    assert media == [1.0, 1.0, 2.0, 1.0]   # object space, after the Jones plane, lens, after
    phi = 0.05 + 0.05 + 5.0 * 0.05 * -0.05 / 2.0   # thick lens, n = 2
    assert 1.0 / phi == pytest.approx(10.6667, abs=1e-4)
    ol = _first_order(lens, _oracle(f, lens)[0], 1.0, f)["EFL"]
    ro = _numbers("jl.zmx", lens, _rayoptics("jl.zmx", lens, monkeypatch, scratch))["EFL"]
    for dl, other in (ol, ro):
        assert dl == pytest.approx(1.0 / phi, rel=1e-12)
        assert other == pytest.approx(1.0 / phi, rel=1e-9)
