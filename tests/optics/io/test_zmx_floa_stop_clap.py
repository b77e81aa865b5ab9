"""``FLOA`` (the pupil floats on the stop's size) with a stop whose ``CLAP`` radius and ``DIAM``
differ (two files of the first unseen set: an automatic ``DIAM 75`` beside ``CLAP 0 72.5``):
deeplens takes a ``CLAP`` as the surface's semi-diameter, so the pupil floats on its radius, and
the reader says so in one located note naming both sizes; no note where they agree."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from deeplens.optics.io.zmx import ZemaxWarning, read_zmx
from deeplens.optics.paraxial import paraxial

SINGLET = Path(__file__).resolve().parents[2] / "data" / "zmx_opticstudio" / "zernike_sag_singlet.zmx"


def _read(tmp_path, clap):
    """The singlet with ``FLOA`` for its ``ENPD`` and, on its stop (``SURF 1``, a plane in air
    with ``DIAM 4``), the line ``clap`` after the ``DIAM`` (line 21 of the file)."""
    text = SINGLET.read_text().replace("ENPD 8", "FLOA").replace(
        '  DIAM 4 1 0 0 1 ""', '  DIAM 4 1 0 0 1 ""' + clap, 1)
    f = tmp_path / "floa.zmx"
    f.write_text(text)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(f)
    notes = [x.message for x in w if isinstance(x.message, ZemaxWarning) and "FLOA" in str(x.message)]
    return lens, notes, f


def test_floating_pupil_on_a_narrower_clap_is_noted(tmp_path):
    lens, notes, f = _read(tmp_path, "\n  CLAP 0 3.5 0")
    # the stop is the first surface, in air: the entrance pupil is the stop itself
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(7.0, rel=1e-12)
    assert len(notes) == 1
    n = notes[0]
    assert n.source == str(f) and n.line == 22
    assert "CLAP radius 3.5" in str(n) and "DIAM 4 (fixed)" in str(n) and "x 0.875" in str(n)


def test_no_note_where_clap_and_diam_agree(tmp_path):
    lens, notes, _ = _read(tmp_path, "\n  CLAP 0 4 0")
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(8.0, rel=1e-12)
    assert notes == []
    lens, notes, _ = _read(tmp_path, "")
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(8.0, rel=1e-12)
    assert notes == []
