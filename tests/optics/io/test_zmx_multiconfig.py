"""Multi-configuration ``.zmx`` files (``MNUM`` and the operand rows after it).

``tests/data/zmx_opticstudio/zoom_two_group_3conf.zmx`` is a hand-written two-group zoom sketch:
a positive singlet (model glass n_d 1.5168) and a negative one (n_d 1.6) whose air gap is 10, 20
and 30 mm in configurations 1-3 (``THIC 2``), with the back distance refocused (``THIC 4``) and
the outer field 6, 7 and 8 degrees (``YFIE 2``).  Each configuration is checked against

* the same file written as a single-configuration file with that configuration's values typed
  into its ``DISZ``/``YFLN`` lines (read without any operand: an independent path), and
* the paraxial thick-lens formula (the 2x2 ray-transfer matrices of the file's curvatures,
  thicknesses and indices, worked out here).
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import helpers as H
import pytest
import torch

from deeplens.optics.paraxial import paraxial
from deeplens.optics.io import ZemaxFileError, ZemaxWarning, lens_to_dict, load_lens, read_zmx
from deeplens.optics.io.zmx import read_zmx_configs

REPO = Path(__file__).resolve().parents[3]
ZOOM = REPO / "tests" / "data" / "zmx_opticstudio" / "zoom_two_group_3conf.zmx"
GAPS = {1: 10.0, 2: 20.0, 3: 30.0}
BACK = {1: 100.15, 2: 68.94, 3: 45.73}
FIELD = {1: 6.0, 2: 7.0, 3: 8.0}


def _text() -> str:
    return ZOOM.read_text()


def _single(k: int) -> str:
    """The zoom file as a single-configuration file holding configuration ``k``'s values."""
    text = _text()
    text = text[:text.index("MNUM")]
    text = text.replace("  DISZ 10\n", f"  DISZ {GAPS[k]:g}\n", 1)
    text = text.replace("  DISZ 100.15\n", f"  DISZ {BACK[k]:g}\n", 1)
    return text.replace("YFLN 0 6\n", f"YFLN 0 {FIELD[k]:g}\n", 1)


def _write(tmp_path, text: str, name: str = "lens.zmx") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _read(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        return read_zmx(path, **kw)


def _efl(lens) -> float:
    return float(paraxial(lens.to(torch.float64)).efl)


def _thick_lens_efl(gap: float) -> float:
    """EFL (mm) of the two singlets in air from their ray-transfer matrices: refraction by
    ``[[1, 0], [-(n' - n) c, 1]]`` on (height, n u), transfer by ``[[1, t / n], [0, 1]]``."""
    def refr(n0, n1, c):
        return [[1.0, 0.0], [-(n1 - n0) * c, 1.0]]

    def move(t, n):
        return [[1.0, t / n], [0.0, 1.0]]

    def mul(a, b):
        return [[sum(a[i][k] * b[k][j] for k in range(2)) for j in range(2)] for i in range(2)]

    n1, n2 = 1.5168, 1.6
    m = refr(1.0, n1, 0.02)
    for step in (move(5.0, n1), refr(n1, 1.0, -0.01), move(gap, 1.0), refr(1.0, n2, -0.015),
                 move(2.0, n2), refr(n2, 1.0, 0.0)):
        m = mul(step, m)
    return -1.0 / m[1][0]


@pytest.mark.parametrize("k", [1, 2, 3])
def test_each_configuration_matches_its_single_configuration_file_and_the_formula(tmp_path, k):
    lens = _read(ZOOM, config=k)
    alone = _read(_write(tmp_path, _single(k)))
    assert lens_to_dict(lens) == lens_to_dict(alone)
    assert lens.spec.fields_deg == pytest.approx([0.0, FIELD[k]], rel=1e-12)
    efl = _efl(lens)
    assert efl == _efl(alone)
    # the model glasses are exact at n_d, and the primary wavelength is the d line
    n = [float(m.n(torch.tensor(587.5618, dtype=torch.float64))) for m in lens.materials[1:4:2]]
    assert n == pytest.approx([1.5168, 1.6], abs=1e-9)
    # float64 matrices: agreement to ~1e-13 relative; 1e-10 leaves room for the tracer's
    # paraxial rays (float64 as well)
    assert efl == pytest.approx(_thick_lens_efl(GAPS[k]), rel=1e-10)


def test_configurations_differ_and_zoom_as_the_gap_grows():
    efl = [_efl(_read(ZOOM, config=k)) for k in (1, 2, 3)]
    assert efl[0] > efl[1] > efl[2]          # the negative group moving away shortens the EFL
    assert efl[0] / efl[2] > 1.3


def test_default_is_the_active_configuration_with_a_warning(tmp_path):
    with pytest.warns(ZemaxWarning, match=r"zoom_two_group_3conf\.zmx:\d+: multi-configuration "
                                          r"file \(3 configurations\).*configuration 1"):
        lens = read_zmx(ZOOM)
    assert lens_to_dict(lens) == lens_to_dict(_read(ZOOM, config=1))
    # MNUM 3 2: configuration 2 is the saved one
    p = _write(tmp_path, _text().replace("MNUM 3 1", "MNUM 3 2"))
    assert lens_to_dict(_read(p)) == lens_to_dict(_read(ZOOM, config=2))
    # an explicit configuration: no warning about the others
    with warnings.catch_warnings():
        warnings.simplefilter("error", ZemaxWarning)
        read_zmx(ZOOM, config=3)


def test_load_lens_passes_the_configuration():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        lens = load_lens(ZOOM, config=3)
    assert _efl(lens) == pytest.approx(_thick_lens_efl(30.0), rel=1e-10)


def test_read_zmx_configs_shares_unchanged_surfaces_by_object():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        lenses = read_zmx_configs(ZOOM)
    assert len(lenses) == 3
    for k, lens in enumerate(lenses, start=1):
        assert _efl(lens) == pytest.approx(_thick_lens_efl(GAPS[k]), rel=1e-10)
    first = lenses[0]
    for other in lenses[1:]:
        assert all(a is b for a, b in zip(first.surfaces, other.surfaces))
        assert other.surfaces is not first.surfaces      # the gaps stay each lens's own
    # one parameter, every configuration: a change to a shared surface reaches all three
    with torch.no_grad():
        first.surfaces[0].c.mul_(1.01)
    efl = [_efl(L) for L in lenses]
    assert efl[1] != pytest.approx(_thick_lens_efl(20.0), rel=1e-6)
    assert float(lenses[2].surfaces[0].c) == pytest.approx(0.0202, rel=1e-6)


def test_shared_automatic_semi_diameter_is_the_largest(tmp_path):
    """Without DIAM each configuration's automatic semi-diameters are its own beam's footprint;
    the shared surface keeps the largest (one physical surface passes every beam)."""
    text = re.sub(r"\n  DIAM 7 1", "", _text())
    p = _write(tmp_path, text)
    alone = [_read(p, config=k) for k in (1, 2, 3)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        lenses = read_zmx_configs(p)
    for i in (1, 2, 3):     # the surfaces after the stop
        own = [float(L.surfaces[i].semi_diameter) for L in alone]
        assert max(own) > min(own) * 1.001          # the configurations' beams differ
        assert all(L.surfaces[i] is lenses[0].surfaces[i] for L in lenses)
        assert float(lenses[0].surfaces[i].semi_diameter) == max(own)


def _operand_file(tmp_path, rows: str, mnum: str = "MNUM 2 1") -> Path:
    text = _text()
    return _write(tmp_path, text[:text.index("MNUM")] + mnum + "\n" + rows)


@pytest.mark.parametrize("rows, edit", [
    ('CRVT 3 1 -0.015 0 0 0 1 1 1 0 0 "" 0\nCRVT 3 2 -0.012 0 0 0 1 1 1 0 0 "" 0\n',
     ("  CURV -0.015\n", "  CURV -0.012\n")),
    ("CONN 1 2 -0.5\n", ("  CURV 0.02\n", "  CURV 0.02\n  CONI -0.5\n")),
    ('GLSS 3 2 N-BK7 0 0 0 1 1 1 0 0 "" 0\n',
     ("  GLAS ___BLANK 1 0 1.6 40 0 0 0 0 0 0\n", "  GLAS N-BK7 0 0 1.5168 64.17\n")),
    ('GLSS 3 2 "" 0 0 0 1 1 1 0 0 "" 0\n', ("  GLAS ___BLANK 1 0 1.6 40 0 0 0 0 0 0\n", "")),
    ('GLSS 1 2 "N-BK7" 0\n', ("  GLAS ___BLANK 1 0 1.5168 64.17 0 0 0 0 0 0\n",
                              "  GLAS N-BK7 0 0 1.5168 64.17\n")),
    ("APER 0 1 10 0\nAPER 0 2 8 0\n", ("ENPD 10\n", "ENPD 8\n")),
    ("XFIE 2 2 3\n", ("XFLN 0 0\n", "XFLN 0 3\n")),
    ("WAVE 3 2 0.7\n", ("WAVM 3 0.6562725 1\n", "WAVM 3 0.7 1\n")),
    ("PRWV 0 2 3\n", ("PWAV 2\n", "PWAV 3\n")),
    ("THIC 0 2 500\n", ("  DISZ INFINITY\n", "  DISZ 500\n")),
])
def test_each_applied_operand_matches_the_file_with_that_value(tmp_path, rows, edit):
    text = _text()
    if "GLSS" in rows:
        text = text.replace("FTYP", "GCAT SCHOTT\nFTYP", 1)
    base = text[:text.index("MNUM")]
    p = _write(tmp_path, base + "MNUM 2 1\n" + rows)
    alone = _write(tmp_path, base.replace(*edit, 1), "alone.zmx")
    assert base.replace(*edit, 1) != base
    assert lens_to_dict(_read(p, config=2)) == lens_to_dict(_read(alone))
    assert lens_to_dict(_read(p, config=1)) == lens_to_dict(_read(_write(tmp_path, base, "b.zmx")))


def test_changed_surface_is_not_shared(tmp_path):
    p = _operand_file(tmp_path, "CRVT 3 2 -0.012\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        a, b = read_zmx_configs(p)
    same = [x is y for x, y in zip(a.surfaces, b.surfaces)]
    assert same == [True, True, False, True]


def test_object_thickness_of_1e10_is_infinity(tmp_path):
    p = _operand_file(tmp_path, "THIC 0 1 1e10\nTHIC 0 2 250\n")
    assert math.isinf(_read(p, config=1).spec.object_distance_mm)
    assert _read(p, config=2).spec.object_distance_mm == pytest.approx(250.0)


@pytest.mark.parametrize("rows, operand", [
    ("IGNR 2 1 0 0\nIGNR 2 2 1 0\n", "IGNR"),
    ("MIND 3 1 1.6 0\nMIND 3 2 1.7 0\n", "MIND"),
    ("APDX 2 2 0.5 0\n", "APDX"),
    ("ZQXW 2 2 9 0\n", "ZQXW"),     # not an operand deeplens knows: refused all the same
])
def test_unsupported_operand_that_changes_the_lens_is_refused(tmp_path, rows, operand):
    p = _operand_file(tmp_path, rows)
    lines = p.read_text().splitlines()
    ln = next(i for i, t in enumerate(lines, start=1)
              if t.split()[:1] == [operand] and t.split()[2] == "2")
    with pytest.raises(ZemaxFileError) as err:
        _read(p, config=2)
    e = err.value
    assert e.feature == operand
    assert re.search(rf"lens\.zmx:{e.line}: .*multi-configuration operand {operand} .*"
                     rf"configuration 2", str(e))
    assert e.line == ln
    # configuration 1 is the saved one: that operand changes nothing there
    _read(p, config=1)
    with pytest.raises(ZemaxFileError, match=operand):
        read_zmx_configs(p)


def test_unsupported_operand_with_the_saved_value_is_read(tmp_path):
    p = _operand_file(tmp_path, "IGNR 1 1 0 0\nIGNR 1 2 0 0\n")
    assert lens_to_dict(_read(p, config=2)) == lens_to_dict(_read(p, config=1))


@pytest.mark.parametrize("rows, config, match", [
    ("", 3, r"configuration 3 requested: the file has 2 configurations"),
    ("", 0, r"configuration 0 requested"),
    ("THIC 2 3 12\n", 1, r"THIC 2 3: expected a number >= 0 and a configuration from 1 to 2"),
    ("THIC 9 2 12\n", 2, r"THIC 9: no SURF 9"),
    ("YFIE 5 2 1\n", 2, r"YFIE 5: no field 5"),
    ("THIC 2 2 abc\n", 2, r"THIC value: expected a number, got 'abc'"),
    ("THIC 2\n", 2, r"truncated"),
])
def test_malformed_rows_and_configurations_are_located(tmp_path, rows, config, match):
    p = _operand_file(tmp_path, rows)
    with pytest.raises(ZemaxFileError, match=match) as err:
        _read(p, config=config)
    assert err.value.line > 0
    assert re.search(r"lens\.zmx:\d+:", str(err.value))


def test_cli_report_config(tmp_path, capsys):
    import json

    for k in (1, 3):
        code, out, err = H.run_cli(["report", str(ZOOM), "--config", str(k), "--json",
                                    "--sampling", "hexapolar:2"], capsys)
        assert code == 0, err
        rep = json.loads(out)
        assert rep["efl_mm"] == pytest.approx(_thick_lens_efl(GAPS[k]), rel=1e-10)
        assert sorted({f["field_deg"] for f in rep["fields"]}) == pytest.approx([0, FIELD[k]])
    code, out, err = H.run_cli(["report", str(ZOOM), "--config", "4"], capsys)
    assert code == 2 and "configuration 4 requested: the file has 3 configurations" in err
    json_lens = REPO / "data" / "lenses" / "double_gauss.json"
    code, out, err = H.run_cli(["report", str(json_lens), "--config", "2"], capsys)
    assert code == 2 and "--config applies to Zemax files (.zmx) and CODE V zoom lenses" in err


def test_optiland_reading_of_each_single_configuration_file(tmp_path):
    """optiland (the test-only oracle) reads only the saved configuration of a multi-
    configuration file (its reader has no MNUM/THIC rows: 124.78 mm for all three), so it reads
    the single-configuration files; its EFL agrees with deeplens' configuration to float64
    rounding of two paraxial traces."""
    pytest.importorskip("optiland")
    from optiland.fileio import load_zemax_file

    for k in (1, 2, 3):
        path = _write(tmp_path, _single(k), f"single{k}.zmx")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            optic = load_zemax_file(str(path))
        assert float(optic.paraxial.f2()) == pytest.approx(_efl(_read(ZOOM, config=k)),
                                                           rel=1e-9)


@pytest.mark.parametrize("mnum", ["MNUM 0 1", "MNUM 3 4", "MNUM 2.5 1", "MNUM 1e308 1"])
def test_bad_mnum_is_located(tmp_path, mnum):
    p = _operand_file(tmp_path, "", mnum=mnum)
    with pytest.raises(ZemaxFileError, match=r"lens\.zmx:\d+: MNUM .*expected a whole number of "
                                             r"configurations from 1 to 10000") as err:
        _read(p)
    assert err.value.feature == "MNUM"


def test_a_file_without_mnum_has_one_configuration(tmp_path):
    p = _write(tmp_path, _single(2))
    assert lens_to_dict(_read(p, config=1)) == lens_to_dict(_read(p))
    with pytest.raises(ZemaxFileError, match=r"configuration 2 requested: the file has 1 "
                                             r"configuration"):
        _read(p, config=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        (only,) = read_zmx_configs(p)
    assert lens_to_dict(only) == lens_to_dict(_read(p))


def test_a_line_after_mnum_that_is_not_an_operand_row_is_reported_not_refused(tmp_path):
    p = _operand_file(tmp_path, "THIC 2 2 20\nGLCZ 1\n")
    ln = p.read_text().splitlines().index("GLCZ 1") + 1
    with pytest.warns(ZemaxWarning, match=rf"lens\.zmx:{ln}: GLCZ line not used"):
        lens = read_zmx(p, config=2)
    assert float(lens.distances[2]) == 20.0
