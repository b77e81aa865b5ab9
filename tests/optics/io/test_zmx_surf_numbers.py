"""``SURF`` numbers that skip one (``SURF 39`` after ``SURF 37``, as in a patent prescription
written by jfotoptix): the blocks are read in file order with one located note, unless a line
of the file names a surface by number (a pickup, a solve, a tolerance or multi-configuration
operand, the global reference surface), which the gap makes ambiguous: then refused at that
line.  Numbers that go back or repeat stay refused."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from deeplens.optics.errors import ZemaxFileError
from deeplens.optics.io.zmx import ZemaxWarning, read_zmx
from deeplens.optics.paraxial import paraxial

SINGLET = Path(__file__).resolve().parents[2] / "data" / "zmx_opticstudio" / "zernike_sag_singlet.zmx"


def _skipped(tmp_path, extra=""):
    """The singlet with its last two blocks numbered 4 and 5 instead of 3 and 4 (the image block
    gets ``extra`` lines), and the file."""
    text = SINGLET.read_text().replace("SURF 4", "SURF 5").replace("SURF 3", "SURF 4") + extra
    f = tmp_path / "skip.zmx"
    f.write_text(text)
    return f, text


def _line(text, needle):
    return next(i for i, t in enumerate(text.splitlines(), 1) if t.strip().startswith(needle))


def test_a_gap_in_surf_numbers_reads_in_file_order_with_a_note(tmp_path):
    f, text = _skipped(tmp_path)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(f)
    notes = [x.message for x in w if isinstance(x.message, ZemaxWarning)
             and "follows SURF" in str(x.message)]
    assert len(notes) == 1 and notes[0].line == _line(text, "SURF 4")
    assert "SURF 4 follows SURF 2 (no SURF 3)" in str(notes[0])
    # the same lens as the file numbered without the gap
    ref = read_zmx(SINGLET)
    assert float(paraxial(lens).efl) == float(paraxial(ref).efl)
    assert float(lens.d_sensor) == float(ref.d_sensor)
    assert [float(d) for d in lens.distances] == [float(d) for d in ref.distances]


def test_tolerances_off_name_no_surface(tmp_path):
    f, _ = _skipped(tmp_path, "TOL TOFF   0   0              0              0   0 0 0 0\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        read_zmx(f)


@pytest.mark.parametrize("extra,key", [
    ("  PZUP 2 1 0 0\n", "PZUP"),                    # a thickness pickup from a surface
    ("TOL TTHI 2 3 -0.1 0.1 0 0 0 0 0\n", "TOL"),   # a thickness tolerance between surfaces
    ("GLRS 4 0\n", "GLRS"),                          # the global coordinate reference surface
    ("MNUM 2 1\nTHIC 4 0 0\n", "MNUM"),              # multi-configuration operands
])
def test_a_gap_with_a_line_that_names_a_surface_is_refused(tmp_path, extra, key):
    f, text = _skipped(tmp_path, extra)
    with pytest.raises(ZemaxFileError, match=rf"skip\.zmx:{_line(text, extra.strip()[:4])}: "
                                             rf"{key} names a surface by number, and the SURF "
                                             rf"numbers skip from 2 to 4"):
        read_zmx(f)


def test_numbers_that_repeat_are_refused(tmp_path):
    text = SINGLET.read_text().replace("SURF 2", "SURF 1")
    f = tmp_path / "dup.zmx"
    f.write_text(text)
    second = [i for i, t in enumerate(text.splitlines(), 1) if t == "SURF 1"][1]
    with pytest.raises(ZemaxFileError, match=rf"dup\.zmx:{second}: SURF 1 out of order: "
                                             rf"expected SURF 2"):
        read_zmx(f)
