"""``write_zmx_configs``: several configurations of one lens written as one multi-configuration
``.zmx`` file (``MNUM`` and operand rows), read back by ``read_zmx_configs`` as the same lenses.

The zoom sketch ``tests/data/zmx_opticstudio/zoom_two_group_3conf.zmx`` (its configurations are
checked against a thick-lens formula in test_zmx_multiconfig.py) round-trips with every
configuration's lens equal (``lens_to_dict``: every surface, gap, glass, field and aperture) and
its first-order numbers equal to the last bit (the values are written at full precision); a
hand-written file with every operand the writer emits (curvature, conic, catalogue glass,
aperture, wavelength, primary wavelength, object distance) does too; configurations that differ
in a record no operand carries are refused, naming the configuration and the record.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import pytest

from deeplens.optics.io import ZemaxWarning, lens_to_dict
from deeplens.optics.io.zmx import read_zmx, read_zmx_configs, write_zmx_configs
from deeplens.optics.paraxial import paraxial

REPO = Path(__file__).resolve().parents[3]
ZOOM = REPO / "tests" / "data" / "zmx_opticstudio" / "zoom_two_group_3conf.zmx"


def _configs(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        return read_zmx_configs(path)


def _first_order(lens):
    p = paraxial(lens)
    return [float(v) for v in (p.efl, p.bfl, p.entrance_pupil_diameter,
                               p.entrance_pupil_position)]


def _same_lenses(a, b):
    assert len(a) == len(b)
    for k, (x, y) in enumerate(zip(a, b), start=1):
        dx, dy = lens_to_dict(x), lens_to_dict(y)
        dx.pop("name", None), dy.pop("name", None)
        assert dy == dx, f"configuration {k}"
        assert _first_order(y) == _first_order(x), f"configuration {k}"


def test_zoom_round_trips_every_configuration(tmp_path):
    lenses = _configs(ZOOM)
    assert len(lenses) == 3
    write_zmx_configs(lenses, tmp_path / "zoom.zmx")
    text = (tmp_path / "zoom.zmx").read_text()
    assert re.search(r"^MNUM 3 1$", text, re.M)
    # the operands of the source file, and nothing else (the rest is common to the three)
    assert sorted({ln.split()[0] for ln in text[text.index("MNUM"):].splitlines()[1:]}) == \
        ["THIC", "YFIE"]
    back = _configs(tmp_path / "zoom.zmx")
    _same_lenses(lenses, back)
    efl = [_first_order(L)[0] for L in back]
    assert len(set(efl)) == 3   # three different zoom positions
    # read_zmx(config=N) reads configuration N of the written file too
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        assert _first_order(read_zmx(tmp_path / "zoom.zmx", config=2)) == _first_order(lenses[1])
    # and shared surfaces stay shared (the unchanged ones, by object)
    assert back[0].surfaces[0] is back[1].surfaces[0] is back[2].surfaces[0]


EVERY_OPERAND = """VERS 190513 80 123457
MODE SEQ
NAME every operand the writer emits
UNIT MM X W X CM MR CPMM
ENPD 8
FTYP 0 0 2 2 0 0 0
XFLN 0 0
YFLN 0 5
WAVM 1 0.4861327 1
WAVM 2 0.5875618 1
PWAV 2
GCAT SCHOTT
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ 1000
SURF 1
  STOP
  TYPE STANDARD
  CURV 0.02
  CONI 0
  DISZ 5
  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0
  DIAM 6 1
SURF 2
  TYPE STANDARD
  CURV -0.01
  DISZ 95
  DIAM 6 1
SURF 3
  TYPE STANDARD
  CURV 0.0
  DISZ 0
MNUM 2 1
CRVT   2   1 -0.01 0 0 0 1 1 1 0 0 "" 0
CRVT   2   2 -0.005 0 0 0 1 1 1 0 0 "" 0
CONN   1   1 0 0 0 0 1 1 1 0 0 "" 0
CONN   1   2 -0.5 0 0 0 1 1 1 0 0 "" 0
GLSS   1   1 N-BK7 0 0 0 1 1 1 0 0 "" 0
GLSS   1   2 N-SF5 0 0 0 1 1 1 0 0 "" 0
APER   0   1 8 0 0 0 1 1 1 0 0 "" 0
APER   0   2 6 0 0 0 1 1 1 0 0 "" 0
WAVE   1   1 0.4861327 0 0 0 1 1 1 0 0 "" 0
WAVE   1   2 0.45 0 0 0 1 1 1 0 0 "" 0
PRWV   0   1 2 0 0 0 1 1 1 0 0 "" 0
PRWV   0   2 1 0 0 0 1 1 1 0 0 "" 0
THIC   0   1 1000 0 0 0 1 1 1 0 0 "" 0
THIC   0   2 2000 0 0 0 1 1 1 0 0 "" 0
"""


def test_every_operand_round_trips(tmp_path):
    src = tmp_path / "src.zmx"
    src.write_text(EVERY_OPERAND)
    lenses = _configs(src)
    a, b = (lens_to_dict(L) for L in lenses)
    assert a != b
    write_zmx_configs(lenses, tmp_path / "out.zmx")
    text = (tmp_path / "out.zmx").read_text()
    ops = {ln.split()[0] for ln in text[text.index("MNUM"):].splitlines()[1:]}
    # SDIA: the stop's semi-diameter, each configuration's own pupil (APER changes it)
    assert ops == {"CRVT", "CONN", "GLSS", "APER", "WAVE", "PRWV", "THIC", "SDIA"}
    _same_lenses(lenses, _configs(tmp_path / "out.zmx"))


def test_one_lens_writes_a_plain_file(tmp_path):
    lens = _configs(ZOOM)[1]
    write_zmx_configs([lens], tmp_path / "one.zmx")
    assert "MNUM" not in (tmp_path / "one.zmx").read_text()
    _same_lenses([lens], _configs(tmp_path / "one.zmx"))


def test_a_difference_no_operand_carries_is_refused(tmp_path):
    zoom = _configs(ZOOM)
    src = tmp_path / "src.zmx"
    src.write_text(EVERY_OPERAND[:EVERY_OPERAND.index("MNUM")])
    other = _configs(src)[0]   # another design: other surfaces, fields, wavelengths
    with pytest.raises(ValueError, match=r"configuration 2 differs from configuration 1"):
        write_zmx_configs([zoom[0], other], tmp_path / "bad.zmx")
    # a model glass changed (an n_d / V_d pair is no GLSS name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        a = read_zmx(ZOOM, config=1)
        b = read_zmx(ZOOM, config=1)
    from deeplens.optics.materials import ModelGlass

    b.materials[1] = ModelGlass(1.6, 50.0)
    with pytest.raises(ValueError, match=r"configuration 2 .* SURF 1, record 'GLAS ___BLANK"):
        write_zmx_configs([a, b], tmp_path / "bad.zmx")
    with pytest.raises(ValueError, match="no configuration"):
        write_zmx_configs([], tmp_path / "none.zmx")


def test_surface_parameters_apertures_and_semi_diameters_round_trip(tmp_path):
    """PARM / XDAT / CLAP-OBSC radii / DIAM that differ between configurations are written as
    PRAM / EDVA / APMN-APMX / SDIA rows (the parameter or extra-data number in the row's sixth
    field) and read back as the same lenses."""
    text = ZOOM.read_text()
    base = text[:text.index("MNUM")]
    base = base.replace("SURF 2\n  TYPE STANDARD\n",
                        "SURF 2\n  TYPE EVENASPH\n  PARM 1 0\n  PARM 2 0\n  PARM 3 0\n", 1)
    base = base.replace("SURF 3\n  TYPE STANDARD\n  CURV -0.015\n",
                        "SURF 3\n  TYPE STANDARD\n  CURV -0.015\n  CLAP 1 6.5 0\n", 1)
    rows = ("PRAM 2 2 2e-06 0 2 0\nPRAM 2 3 -1e-06 0 2 0\nPRAM 2 3 1e-09 0 3 0\n"
            "APMN 3 2 2 0\nSDIA 4 3 6 0\n")
    src = tmp_path / "src.zmx"
    src.write_text(base + "MNUM 3 1\n" + rows)
    lenses = _configs(src)
    assert len({str(lens_to_dict(L)) for L in lenses}) == 3
    write_zmx_configs(lenses, tmp_path / "out.zmx")
    out = (tmp_path / "out.zmx").read_text()
    mce = out[out.index("MNUM"):].splitlines()[1:]
    # the annular CLAP's inner circle is written as a central OBSC: its radius is an APMX row
    assert {ln.split()[0] for ln in mce} >= {"PRAM", "APMX"}
    assert {ln.split()[5] for ln in mce if ln.startswith("PRAM")} == {"2", "3"}
    _same_lenses(lenses, _configs(tmp_path / "out.zmx"))
