"""A Zernike sag surface whose rotationally symmetric terms curve the vertex: deeplens' paraxial
data include them (the sag's vertex curvature), a reader taking ``CURV`` alone does not (rayoptics
0.9: two files of the first unseen set, EFL 1999.957 vs 1999.983), so the reader says so in one
located note per surface, with the curvature they add worked out here by hand."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import pytest

from deeplens.optics.io.zmx import ZemaxWarning, read_zmx

SINGLET = Path(__file__).resolve().parents[2] / "data" / "zmx_opticstudio" / "zernike_sag_singlet.zmx"


def _notes(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(path)
    return lens, [x.message for x in w if isinstance(x.message, ZemaxWarning)
                  and "rotationally symmetric Zernike" in str(x.message)]


def test_the_vertex_curvature_of_m0_terms_is_noted_with_its_value():
    """The singlet's Noll Z4 = √3 (2ρ² − 1) (A 0.01) and Z11 = √5 (6ρ⁴ − 6ρ² + 1) (A −0.002) on
    R_n = 5 mm add 2 (2√3 A4 − 6√5 A11) / R_n² to the vertex curvature; Z6 and Z8 (m ≠ 0) do
    not count; the note sits on Z4's XDAT line (XDAT 6, line 42 of the file)."""
    _, notes = _notes(SINGLET)
    assert len(notes) == 1
    n = notes[0]
    assert n.line == 42 and n.source == str(SINGLET)
    dc = 2.0 * (2.0 * math.sqrt(3) * 0.01 - 6.0 * math.sqrt(5) * -0.002) / 25.0
    text = str(n)
    assert "Z4, Z11 add" in text and "Z6" not in text and "Z8" not in text
    assert float(text.split(" add ")[1].split(" /mm")[0]) == pytest.approx(dc, rel=1e-3)


def test_no_note_without_rotationally_symmetric_terms(tmp_path):
    """Only Z6 and Z8 (astigmatism, coma): the vertex curvature is CURV's; no note."""
    text = SINGLET.read_text().replace("XDAT 6 0.01", "XDAT 6 0").replace("XDAT 13 -0.002",
                                                                          "XDAT 13 0")
    f = tmp_path / "no_m0.zmx"
    f.write_text(text)
    _, notes = _notes(f)
    assert notes == []
