"""A ``GLAS`` name that is a six-digit n_d/V_d code (``GLAS 847238 ...``): refused by default
(OpticStudio's catalogues hold no such name), read as that model glass under
``glass_codes="model"`` / ``--glass-codes model`` (deeplens/optics/io/zmx_glass_codes.py)."""

from __future__ import annotations

import math
import warnings

import pytest
import torch

from deeplens.optics.io import load_lens
from deeplens.optics.materials import GLASS_TABLE
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.io.zmx_glass_codes import glass_code
from deeplens.optics.paraxial import paraxial

C1, C2, T = 0.02, -0.01, 4.0

SINGLET = """VERS 190513 80 123457
MODE SEQ
NAME glass code singlet
UNIT MM X W X CM MR CPMM
ENPD 10
GCAT SCHOTT
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
  CURV {c1}
  DISZ {t}
  GLAS {glass} 0 0 1.5 4.0E+1 0 0 0 0 0 0
  DIAM 8 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV {c2}
  DISZ 90
  DIAM 8 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0.0
  DISZ 0
"""


def _file(tmp_path, glass="847238"):
    text = SINGLET.format(c1=C1, c2=C2, t=T, glass=glass)
    f = tmp_path / f"code_{glass}.zmx"
    f.write_text(text)
    return f, text.splitlines().index(f"  GLAS {glass} 0 0 1.5 4.0E+1 0 0 0 0 0 0") + 1


def _thick_lens_efl(n):
    """1/f = (n-1) (c1 - c2 + (n-1) t c1 c2 / n), a thick lens in air."""
    return 1.0 / ((n - 1.0) * (C1 - C2 + (n - 1.0) * T * C1 * C2 / n))


def test_code_parsing():
    m = glass_code("847238")
    assert (m.n_d, m.v_d, m.name) == (1.847, 23.8, "847238")
    m = glass_code("847238.2380")             # CODE V's NNNNNN.VVVV
    assert (m.n_d, m.v_d) == (1.847238, 23.8)
    for name in ("N-BK7", "84723", "8472381", "923209.603", "847000", "84a238"):
        assert glass_code(name) is None, name


def test_default_refuses_at_the_glas_line_with_the_hint(tmp_path):
    f, line = _file(tmp_path)
    for call in (lambda: read_zmx(f), lambda: load_lens(f)):
        with pytest.raises(ZemaxFileError) as e:
            call()
        assert e.value.line == line
        msg = str(e.value)
        assert "'847238' is not in the shipped SCHOTT catalogue" in msg
        assert "six-digit n_d/V_d glass code (n_d 1.847, V_d 23.8)" in msg
        assert "glass_codes='model' (--glass-codes model)" in msg
    with pytest.raises(ValueError, match="glass_codes must be one of"):
        read_zmx(f, glass_codes="auto")


def test_model_reads_the_code_as_a_model_glass(tmp_path):
    f, line = _file(tmp_path)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        lens = read_zmx(f, glass_codes="model")
    notes = [str(w.message) for w in rec if isinstance(w.message, ZemaxWarning)
             and "six-digit" in str(w.message)]
    assert len(notes) == 1 and f"{f}:{line}:" in notes[0]
    assert "model glass n_d 1.847, V_d 23.8" in notes[0]
    assert "OpticStudio's catalogues hold no such name" in notes[0]
    mat = lens.materials[1]
    assert mat.name == "847238" and (mat.n_d, mat.v_d) == (1.847, 23.8)
    efl = float(paraxial(lens).efl)
    assert math.isclose(efl, _thick_lens_efl(1.847), rel_tol=1e-12), efl
    # through load_lens as well
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again = load_lens(f, glass_codes="model")
    assert float(paraxial(again).efl) == efl


def test_model_still_refuses_a_name_that_is_no_code(tmp_path):
    f, line = _file(tmp_path, glass="NOGLASS9")
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f, glass_codes="model")
    assert e.value.line == line and "six-digit" not in str(e.value)


def test_a_catalogue_glass_of_that_name_wins(tmp_path):
    """A user catalogue the file names (GCAT) that holds the code's name is used, not the code."""
    f, _ = _file(tmp_path)
    f.write_text(f.read_text().replace("GCAT SCHOTT", "GCAT MYCAT"))
    agf = tmp_path / "MYCAT.agf"
    bk7 = " ".join(repr(float(x)) for x in GLASS_TABLE["N-BK7"].coefficients)
    agf.write_text(f"CC synthetic catalogue for deeplens tests\nNM 847238 2 0 1.5168 64.17\n"
                   f"CD {bk7}\nLD 0.3 2.5\n")   # N-BK7's Sellmeier terms under the code's name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = read_zmx(f, glass_codes="model")
    n = float(lens.materials[1].n(torch.tensor(587.5618, dtype=torch.float64)))
    assert n == pytest.approx(1.5168, abs=1e-4)   # the catalogue's glass, not the code's


def test_cli_flag_reaches_the_reader(tmp_path, capsys):
    from deeplens.cli import main

    f, line = _file(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["report", str(f), "--sampling", "hexapolar:3"])
    out, err = capsys.readouterr()
    assert rc == 2 and out == "" and f"{f}:{line}:" in err and "--glass-codes model" in err
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["report", str(f), "--glass-codes", "model", "--sampling", "hexapolar:3"])
    out = capsys.readouterr().out
    assert rc == 0 and f"{_thick_lens_efl(1.847):.4f}"[:6] in out
    rc = main(["report", "double_gauss", "--glass-codes", "model"])
    err = capsys.readouterr().err
    assert rc == 2 and "--glass-codes applies to Zemax files (.zmx) only; double_gauss" in err
