"""Malformed or hostile ``.zmx`` files (issue 38): each is refused or warned about with the
file, the line and what was expected, never read silently or with a traceback."""

from __future__ import annotations

import json
import re

import pytest
from test_zmx import JSON, REPO, ZMX, line_of, singlet, write

from deeplens.optics.io import (
    LensFileError,
    ZemaxFileError,
    ZemaxWarning,
    lens_to_dict,
    load_lens,
    read_agf,
    read_zmx,
)
from deeplens.optics.io.agf import AgfError
from deeplens.optics.io.zmx_parse import parse


def test_a_second_stop_is_refused_naming_the_first(tmp_path):
    text = singlet().replace("SURF 3\n", "SURF 3\n  STOP\n")
    first = line_of(text, "STOP")
    second = line_of(text.replace("  STOP", "  XXXX", 1), "STOP")
    with pytest.raises(ZemaxFileError, match=rf"t.zmx:{second}: a second STOP \(SURF 3\): the "
                                             rf"stop is already SURF 1 \(STOP on line {first}\)"):
        read_zmx(write(tmp_path, text))
    assert read_zmx(write(tmp_path, singlet(), "one.zmx")).stop_index == 0


@pytest.mark.parametrize("old,new,field,match", [
    ("  DISZ 5.0\n", "  DISZ 1e308\n", "DISZ", r"DISZ \(SURF 2 thickness\) 1e\+308 MM: expected a "
                                           r"length of at most 1e\+12 mm in magnitude"),
    ("  DISZ 5.0\n", "  DISZ 1e29\n", "DISZ", r"DISZ \(SURF 2 thickness\) 1e\+29 MM: expected"),
    # (a positive one, 1e10 lens units or more, is an object at infinity:
    # test_zmx_object_at_infinity.py; a virtual object that far is refused)
    ("  DISZ INFINITY\n", "  DISZ -1e300\n", "DISZ",
     r"DISZ \(SURF 0 thickness\) -1e\+300 MM: .*an object at infinity is DISZ INFINITY"),
    ("  CURV 0.02\n", "  CURV 1e308\n", "CURV", r"CURV 1e\+308 per MM \(SURF 2\): expected a "
                                              r"curvature of at most 1e\+12 per mm"),
    ("  DIAM 8.0 1", "  DIAM 1e300 1", "DIAM", r"DIAM \(SURF 2 semi-diameter\) 1e\+300 MM"),
    ("ENPD 10", "ENPD 3e12", "ENPD", r"ENPD entrance-pupil diameter 3e\+12 MM"),
])
def test_overflowing_numbers_are_refused_at_their_line(tmp_path, old, new, field, match):
    text = singlet()
    assert old in text
    text = text.replace(old, new, 1)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, new.strip()) and e.value.feature == field


def test_the_length_limit_is_in_millimetres(tmp_path):
    """1e12 mm is the limit whatever the file's unit: 5e11 in inches is 1.27e13 mm."""
    text = singlet().replace("  DISZ 5.0\n", "  DISZ 5e11\n").replace("UNIT MM", "UNIT IN")
    with pytest.raises(ZemaxFileError, match=r"DISZ \(SURF 2 thickness\) 5e\+11 IN: expected"):
        read_zmx(write(tmp_path, text))


@pytest.mark.parametrize("key,value,match", [
    ("curvature_per_mm", 1e308, r"surfaces\[1\].curvature_per_mm: expected a curvature of at "
                                r"most 1e\+12 per mm"),
    ("roc_mm", 1e-300, r"surfaces\[1\].roc_mm: expected a radius of at least 1e-12 mm"),
])
def test_json_curvatures_have_the_same_limit(tmp_path, key, value, match):
    d = json.loads(JSON.read_text())
    d["surfaces"][1].pop("curvature_per_mm")
    d["surfaces"][1][key] = value
    p = tmp_path / "c.json"
    p.write_text(json.dumps(d))
    with pytest.raises(LensFileError, match=match):
        load_lens(p)


# --------------------------------------------------------------------------- .agf glasses
def _agf(tmp_path, nm_line, cd):
    p = tmp_path / "ACME.agf"
    p.write_text(f"CC test catalogue\n{nm_line}\nCD {cd}\nLD 0.3 2.5\n")
    return p


@pytest.mark.parametrize("formula", ["inf", "nan", "1e400"])
def test_a_non_finite_formula_number_is_a_located_error(tmp_path, formula):
    p = _agf(tmp_path, f"NM BAD {formula} 0 0 0", "1.0 0.01 0 0 0 0")
    with pytest.raises(AgfError, match=rf"ACME.agf:2: glass 'BAD': unknown dispersion formula "
                                       rf"'{formula}'"):
        read_agf(p)


@pytest.mark.parametrize("cd,match", [
    # Sellmeier 1: n² = 1 - 2 λ²/(λ² - 0.01) < 0 at 550 nm
    ("-2 0.01 0 0 0 0", r"no real index at 550 nm \(n² < 0 or an overflow\)"),
    # n² = 1 - 0.5 λ²/(λ² - 0.01): n = 0.69 at 550 nm
    ("-0.5 0.01 0 0 0 0", r"n = 0.69\d* at 550 nm"),
    # n² = 1 + 1e300 λ²/(λ² - 1e-300) ~ 1e300: n = 1e150, a coefficient typed wrong
    ("1e300 1e-300 0 0 0 0", r"n = 1e\+150 at 550 nm"),
])
def test_a_glass_without_a_real_index_at_the_design_wavelengths_is_refused(tmp_path, cd, match):
    agf = _agf(tmp_path, "NM BADGLASS 2 0 0 0", cd)
    text = singlet(gcat="GCAT ACME", glass="GLAS BADGLASS 0 0 1.5 60 0 0 0 0 0 0")
    with pytest.raises(ZemaxFileError, match=rf"t.zmx:{line_of(text, 'GLAS BADGLASS')}: glass "
                                             rf"'BADGLASS' \({re.escape(str(agf))}:2\) of SURF 2: its dispersion "
                                             rf"formula gives {match}; expected a finite index "
                                             rf">= 1 \(and <= 10 for a catalogue glass\)") as e:
        read_zmx(write(tmp_path, text), glass_catalogs=[agf])
    assert e.value.feature == "GLAS"
    # the same catalogue with a sound glass reads
    _agf(tmp_path, "NM BADGLASS 2 0 0 0", "1.03961212 0.00600069867 0.231792344 0.0200179144 "
                                          "1.01046945 103.560653")
    read_zmx(write(tmp_path, text), glass_catalogs=[agf])


# --------------------------------------------------------------------------- encodings
@pytest.mark.parametrize("codec", ["utf-16-le", "utf-16-be"])
def test_utf16_without_a_byte_order_mark_is_decoded(tmp_path, codec):
    """The shipped file (UTF-16 LE with a mark) without its mark, and byte-swapped."""
    raw = ZMX.read_bytes()
    assert raw[:2] == b"\xff\xfe"
    text = raw[2:].decode("utf-16-le")
    p = tmp_path / ZMX.name   # the lens is named after the file
    p.write_bytes(text.encode(codec))
    assert lens_to_dict(read_zmx(p)) == lens_to_dict(read_zmx(ZMX))
    agf = tmp_path / "ACME.agf"
    agf.write_bytes("NM G1 2 0 0 0\nCD 1.0 0.01 0 0 0 0\n".encode(codec))
    assert read_agf(agf).get("G1") is not None


# --------------------------------------------------------------------------- cut-off files
def test_a_file_cut_after_a_lens_surface_is_warned_about(tmp_path):
    text = ZMX.read_bytes().decode("utf-16")
    lines = text.splitlines()
    last = line_of(text, "SURF 13") - 1        # the file up to the end of SURF 12's block
    p = tmp_path / "cut.zmx"
    p.write_text("\n".join(lines[:last]) + "\n")
    with pytest.warns(ZemaxWarning) as rec:
        read_zmx(p)
    cut = [w for w in rec if "may be cut off" in str(w.message)]
    assert len(cut) == 1
    assert str(cut[0].message) == (
        f"{p}:{line_of(text, 'SURF 12')}: the file ends with SURF 12, which has DISZ 17.4277: "
        f"OpticStudio ends every file with its image surface (a block with DISZ 0), so the file "
        f"may be cut off; it was read as a lens whose image surface is SURF 12")
    # cut inside the image surface's block, before its DISZ line
    p.write_text("\n".join(lines[:last + 3]) + "\n")
    with pytest.warns(ZemaxWarning, match=r"cut.zmx:\d+: the file ends with SURF 13, which has "
                                          r"no DISZ line"):
        read_zmx(p)


def test_no_shipped_or_corpus_file_looks_cut_off():
    files = sorted((REPO / "tests" / "data").rglob("*.zmx")) + sorted(
        (REPO / "data").rglob("*.zmx"))
    assert len(files) >= 30
    for f in files:
        _, _, p = parse(f)
        assert not [m for _, m in p.notes if "may be cut off" in m], f.name
