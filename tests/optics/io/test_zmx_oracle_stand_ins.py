"""The corpus oracles (optiland, rayoptics; test_zmx_corpus.py, test_zmx_corpus_rayoptics.py)
on two kinds of file they could not read: a ``GRID_SAG`` surface (rayoptics reads a plane,
optiland refuses it), given deeplens' stated paraxial rule worked out from the file's own grid
numbers (test_zmx_corpus.grid_sag_vertex_curvatures), and an OpTaliX export (every line indented
by one space, an old-style ``WAVL`` line), given the file as test_zmx_corpus.oracle_text lays it
out.  Synthetic files only (the real ones are not redistributable)."""

from __future__ import annotations

import math
import warnings

import pytest

import test_zmx_corpus as tc
import test_zmx_corpus_rayoptics as tr
from test_zmx_grid_sag import garr, grid_lens, poly, A
from deeplens.optics.io.zmx import read_zmx

pytest.importorskip("optiland")
pytest.importorskip("rayoptics")

#: the x⁵, y⁵ coefficients of the grid below (mm⁻⁴): odd and beyond cubic, so the bicubic
#: interpolant's curvature across the grid lines through the vertex jumps (right cell −4 E h³,
#: left +4 E h³ per mm² from the x⁵ term: their mean is the true 0)
E5, F5 = 1e-5, -2e-5


def _quintic(x, y):
    """``(x² + y²)/200 + E5 x⁵ + F5 y⁵`` (mm) and its ``(z, z_x, z_y, z_xy)``."""
    return ((x * x + y * y) / 200.0 + E5 * x ** 5 + F5 * y ** 5, x / 100.0 + 5 * E5 * x ** 4,
            y / 100.0 + 5 * F5 * y ** 4, 0.0 * x)


def _at(tmp_path, monkeypatch, name, text):
    """``text`` as ``tmp_path / name``, the oracle modules pointed at ``tmp_path``."""
    (tmp_path / name).write_text(text)
    monkeypatch.setattr(tc, "CORPUS", tmp_path)
    monkeypatch.setattr(tr, "CORPUS", tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(tmp_path / name)


def _both_oracles(name, lens, monkeypatch, tmp_path):
    """``{oracle: {quantity: (deeplens, oracle)}}`` (file units), as the corpus tests compare."""
    optic, s_mm = tc._oracle(name, lens)
    scratch = tmp_path / "ro"
    scratch.mkdir(exist_ok=True)
    opm = tr._rayoptics(name, lens, monkeypatch, scratch)
    return {"optiland": tc._first_order(lens, optic, s_mm, name),
            "rayoptics": tr._numbers(name, lens, opm)}, opm


def _assert_agree(numbers):
    for oracle, got in numbers.items():
        for what, (dl, ol) in got.items():
            assert dl == pytest.approx(ol, rel=1e-9 if oracle == "rayoptics" else 1e-6,
                                       abs=1e-9 * max(1.0, abs(dl))), (oracle, what)


@pytest.mark.parametrize("dec", [(0.3, -0.45), (0.0, 0.0)])
def test_grid_sag_oracle_curvature_is_the_closed_form_of_a_bicubic(dec, tmp_path, monkeypatch):
    """The oracle's own curvature (numpy, Hermite basis) of a bicubic polynomial grid, which the
    interpolant reproduces exactly: ``CURV + 2 PARM 1 + A_20 + A_02`` (``G_xx = 2 A_20``), with
    the vertex inside a cell (a decentred grid) and on a node (both cells), rows from +y."""
    text = grid_lens(garr(poly, 7, 5, 1.5, 2.0, dec=dec), parm=("PARM 0 0", "PARM 1 0.002"),
                     curv=0.01)
    (tmp_path / "g.zmx").write_text(text)
    monkeypatch.setattr(tc, "CORPUS", tmp_path)
    want = 0.01 + 2 * 0.002 + A[2, 0] + A[0, 2]
    assert tc.grid_sag_vertex_curvatures("g.zmx") == {1: pytest.approx(want, rel=1e-12)}


def test_grid_sag_paraxial_rule_through_both_oracles(tmp_path, monkeypatch):
    """A GRID_SAG singlet whose grid is a paraboloid of R = 100 mm plus x⁵ and y⁵ terms, the
    vertex on a node: both oracles, given the vertex curvature of deeplens' stated rule worked out
    from the GARR numbers (here the true ``0.005 + 2·0.0005 + 0.01``: the two cells' jump
    averages out), give deeplens' EFL, EPD, pupil position and back focus; rayoptics' own
    reading (a plane) is > 1 % apart in EFL."""
    grid = garr(_quintic, 11, 11, 2.2, 2.2)
    lens = _at(tmp_path, monkeypatch, "g.zmx",
               grid_lens(grid, parm=("PARM 0 0", "PARM 1 0.0005"), curv=0.005))
    cv = tc.grid_sag_vertex_curvatures("g.zmx")
    assert cv == {1: pytest.approx(0.016, rel=1e-12)}
    numbers, opm = _both_oracles("g.zmx", lens, monkeypatch, tmp_path)
    _assert_agree(numbers)
    opm["seq_model"].ifcs[1].profile.cv = 0.005   # CURV alone (rayoptics reads a plane grid)
    tr._update(opm)
    dl, ro = tr._numbers("g.zmx", lens, opm)["EFL"]
    assert abs(dl - ro) > 0.01 * abs(dl)


def _optalix(text):
    """An OpticStudio file written as OpTaliX's exporter writes one: every line indented by one
    space, the wavelengths as one ``WAVL`` line with ``WWGT``, the infinite object at 1e20."""
    text = text.replace("WAVM 1 0.55 1", "WAVL 0.55\nWWGT 1").replace(
        "  DISZ INFINITY", "  DISZ 0.1000000000E+21")
    return "".join(f" {ln}\n" for ln in text.splitlines())


def test_optalix_layout_through_both_oracles(tmp_path, monkeypatch):
    """The plano-convex singlet (R 50 mm, N-BK7) in OpTaliX's layout: deeplens reads it as the
    OpticStudio file (the same EFL); the oracles, given oracle_text's copy (dedented, WAVM
    lines; the numbers and DISZ 1e20 unchanged), confirm all four numbers; without it optiland
    0.6 fails on the WAVL line and the helpers find no SURF block."""
    plain = grid_lens([], grid_type=False, curv=0.02)
    text = _optalix(plain)
    assert text != plain and "WAVL 0.55" in text
    (tmp_path / "raw").mkdir()
    lens = _at(tmp_path / "raw", monkeypatch, "o.zmx", text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (tmp_path / "p.zmx").write_text(plain)
        efl_plain = float(tc.paraxial(read_zmx(tmp_path / "p.zmx")).efl)
    assert float(tc.paraxial(lens).efl) == pytest.approx(efl_plain, rel=1e-12)
    with pytest.raises(IndexError):
        tc._oracle("o.zmx", lens)   # optiland's WAVL reading
    (tmp_path / "scratch").mkdir()
    with pytest.raises(AssertionError, match="gaps are not the file's"):
        tr._rayoptics("o.zmx", lens, monkeypatch, tmp_path / "scratch")
    fixed = tc.oracle_folder(tmp_path / "raw", tmp_path)
    monkeypatch.setattr(tc, "CORPUS", fixed)
    monkeypatch.setattr(tr, "CORPUS", fixed)
    assert "WAVM 1 0.55 1\nPWAV" in (fixed / "o.zmx").read_text()
    numbers, _ = _both_oracles("o.zmx", lens, monkeypatch, tmp_path)
    _assert_agree(numbers)
    assert math.isfinite(numbers["rayoptics"]["EFL"][1])


def test_oracle_text_keeps_a_current_file(tmp_path):
    """oracle_text leaves an OpticStudio file with WAVM lines and no common indent unchanged,
    and gives each WAVL wavelength its WWGT weight (1 where WWGT has none)."""
    plain = grid_lens([], grid_type=False, curv=0.02)
    assert tc.oracle_text(plain) == plain
    three = plain.replace("WAVM 1 0.55 1", "WAVL 0.486 0.55 0.656\nWWGT 1 2")
    got = tc.oracle_text(three)
    assert "WAVM 1 0.486 1\nWAVM 2 0.55 2\nWAVM 3 0.656 1\nPWAV 1" in got
    assert "WWGT" not in got and "WAVL" not in got
