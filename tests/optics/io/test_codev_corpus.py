"""The real ``.seq`` corpus (tests/data/codev_real: files written by others, see its SOURCES.md):
every file loads, and rayoptics' own reading of the same file (a test-only oracle, given
deeplens' refractive indices: tests/optics/io/codev_oracle.py) gives the same EFL, entrance pupil
diameter and position and rear focal point, to float64 round-off of a paraxial trace (1e-9
relative: both sides trace the same numbers in float64, ~1e-13 apart on these files; a thickness
read off by one surface moves them by more than 1e-4)."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import pytest

from codev_oracle import agrees, numbers
from deeplens.optics.io.codev import CodeVWarning, read_seq
from deeplens.optics.paraxial import paraxial

CORPUS = Path(__file__).resolve().parents[2] / "data" / "codev_real"
FILES = sorted(p.name for p in CORPUS.glob("*.seq"))

#: how a file is read when not by default, and why.  landscape_lens.seq and singlet.seq have no
#: RDM line and curvatures as their first numbers (``S -0.2 0.22`` with EPD 1, ``s 0.1 1`` with
#: a 15 mm gap behind: radii of 0.2 and 0.1 mm could not hold the beam): their author's program,
#: rayoptics, reads a file without RDM in curvature mode.
READ_AS = {"landscape_lens.seq": {"radius_mode": False}, "singlet.seq": {"radius_mode": False}}


def _load(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CodeVWarning)
        return read_seq(CORPUS / name, **READ_AS.get(name, {}))


def test_the_corpus_is_listed_in_sources():
    listed = re.findall(r"^\| (\S+\.seq) \|", (CORPUS / "SOURCES.md").read_text(), re.M)
    assert sorted(listed) == FILES and len(FILES) == 17


@pytest.mark.parametrize("name", FILES)
def test_every_file_loads(name):
    lens = _load(name)
    p = paraxial(lens)
    assert float(p.entrance_pupil_diameter) > 0


@pytest.mark.parametrize("name", FILES)
def test_rayoptics_confirms_first_order_numbers(name):
    pytest.importorskip("rayoptics")
    lens = _load(name)
    for what, (dl, ro) in numbers(CORPUS / name, lens, **READ_AS.get(name, {})).items():
        assert agrees(dl, ro), f"{what}: deeplens {dl!r} vs rayoptics {ro!r}"


def test_a_file_without_rdm_warns_of_the_choice():
    """Read by default (radius mode), the file without RDM says so and names the flag."""
    with pytest.warns(CodeVWarning, match="no RDM line.*radius_mode=False"):
        read_seq(CORPUS / "landscape_lens.seq")


@pytest.mark.parametrize("name", FILES)
def test_write_seq_round_trip(name, tmp_path):
    """Each real file -> lens -> ``write_seq`` -> lens: the same prescription (curvatures, gaps,
    indices, semi-diameters bit for bit or to 1e-12), private glasses (``PRV``, written back as
    their tables) and obscurations (``CIR OBS``) included."""
    from test_codev import _same_prescription

    from deeplens.optics.io.codev import write_seq

    a = _load(name)
    write_seq(a, tmp_path / "a.seq")
    b = read_seq(tmp_path / "a.seq")
    _same_prescription(a, b)
    assert [float(getattr(s, "obscuration", 0.0)) for s in a.surfaces] == \
        [float(getattr(s, "obscuration", 0.0)) for s in b.surfaces]
    assert a.mirrors == b.mirrors
