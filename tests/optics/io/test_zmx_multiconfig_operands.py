"""The multi-configuration operands that real OpticStudio files use beyond thickness, curvature,
glass, aperture, field and wavelength (found on the sample and short-course files of
OpticStudio: benchmarks/zmx_mconf_corpus.py, docs/guide/zemax.md "Real files"): ``PRAM`` and
``PAR1`` .. ``PAR8`` (surface parameters: coordinate-break tilts, aspheric terms), ``EDVA``
(extra data), ``SDIA`` (semi-diameter), ``APMN`` / ``APMX`` (aperture radii), ``STPS`` (stop
surface), ``TEMP`` / ``PRES`` (read as ``ENVD``), ``MCOM`` / ``CWGT`` (no optics) and the
editor's ``CSUM`` checksum line.

Each is checked against the same file with that configuration's value typed into its own
record by hand (read without any operand), and a synthetic zoom file written in OpticStudio's
own row format (tests/data/zmx_opticstudio/zoom_asphere_3conf_osformat.zmx: scientific
notation, solve and pick-up columns, ``MCOM`` comment rows, ``CONF``/``TOL`` lines before
``MNUM``, a ``CSUM`` line, CRLF endings) against the thick-lens formula, the aspheric sag's
closed form and test-only applier tests/optics/io/zmx_mconf_apply.py (which shares no code
with deeplens' reading of the operands).
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import pytest
import torch

from deeplens.optics.io import ZemaxFileError, ZemaxWarning, lens_to_dict, read_zmx
from deeplens.optics.io.zmx import read_zmx_configs
from deeplens.optics.paraxial import paraxial
from test_zmx_multiconfig import _thick_lens_efl
from zmx_mconf_apply import single_configuration

REPO = Path(__file__).resolve().parents[3]
ZOOM = REPO / "tests" / "data" / "zmx_opticstudio" / "zoom_two_group_3conf.zmx"
OSFORMAT = REPO / "tests" / "data" / "zmx_opticstudio" / "zoom_asphere_3conf_osformat.zmx"


def _read(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        return read_zmx(path, **kw)


def _base() -> str:
    """The zoom sketch without its MNUM block, with an even asphere (SURF 2, r^4 term 0), a
    annular circular aperture (SURF 3) to change."""
    text = ZOOM.read_text()
    text = text[:text.index("MNUM")]
    text = text.replace("SURF 2\n  TYPE STANDARD\n",
                        "SURF 2\n  TYPE EVENASPH\n  PARM 1 0\n  PARM 2 0\n  PARM 3 0\n", 1)
    text = text.replace("SURF 3\n  TYPE STANDARD\n  CURV -0.015\n",
                        "SURF 3\n  TYPE STANDARD\n  CURV -0.015\n  CLAP 1 6.5 0\n", 1)
    return text


def _write(tmp_path, text, name="lens.zmx") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# (operand rows, the edit that types configuration 2's value into the saved records)
CASES = {
    "PRAM": ('PRAM 2 1 0 0 2 0 1 1 1 0 0\nPRAM 2 2 2e-06 0 2 0 2 1 1 0 0\n',
             ("  PARM 2 0\n", "  PARM 2 2e-06\n")),
    "PAR2": ("PAR2 2 2 2e-06 0 0 0 2 1 1 0 0\n", ("  PARM 2 0\n", "  PARM 2 2e-06\n")),
    "SDIA": ("SDIA 4 2 6 0 0 0 2 1 1 0 0\n", None),
    "APMN": ("APMN 3 2 2 0 0 0 2 1 1 0 0\n", ("  CLAP 1 6.5 0\n", "  CLAP 2 6.5 0\n")),
    "APMX": ("APMX 3 2 6 0 0 0 2 1 1 0 0\n", ("  CLAP 1 6.5 0\n", "  CLAP 1 6 0\n")),
    "STPS": ("STPS 0 1 1 0\nSTPS 0 2 2 0\n",
             ("  STOP\n  TYPE STANDARD\n  CURV 0.02\n", "  TYPE STANDARD\n  CURV 0.02\n")),
}


@pytest.mark.parametrize("operand", list(CASES))
def test_each_operand_matches_the_file_with_that_value(tmp_path, operand):
    rows, edit = CASES[operand]
    base = _base()
    if operand == "SDIA":   # the DIAM of SURF 4
        i = base.index("SURF 4")
        alone = base[:i] + base[i:].replace("  DIAM 7 1\n", "  DIAM 6 1\n", 1)
    else:
        alone = base.replace(*edit, 1)
    if operand == "STPS":
        alone = alone.replace("SURF 2\n", "SURF 2\n  STOP\n", 1)
    assert alone != base
    p = _write(tmp_path, base + "MNUM 2 1\n" + rows)
    two = lens_to_dict(_read(p, config=2))
    assert two == lens_to_dict(_read(_write(tmp_path, alone, "alone.zmx")))
    assert two != lens_to_dict(_read(p, config=1))     # the operand changed the lens
    # the test-only applier (no deeplens operand code) writes the same single configuration
    assert two == lens_to_dict(_read(_write(tmp_path, single_configuration(p, 2), "ap.zmx")))


def test_edva_sets_the_extra_data_its_sixth_field_names(tmp_path):
    """``EDVA s ... n``: ``XDAT n`` of ``SURF s`` (a binary 2 surface's normalisation radius)."""
    base = _base().replace(
        "SURF 4\n  TYPE STANDARD\n  CURV 0.0\n",
        "SURF 4\n  TYPE BINARY_2\n  CURV 0.0\n  PARM 0 1\n  XDAT 1 2\n  XDAT 2 5\n"
        "  XDAT 3 -100\n  XDAT 4 3\n", 1)
    rows = "EDVA 4 1 5 0 2 0 1 1 1 0 0\nEDVA 4 2 4 0 2 0 2 1 1 0 0\n"
    p = _write(tmp_path, base + "MNUM 2 1\n" + rows)
    alone = _write(tmp_path, base.replace("  XDAT 2 5\n", "  XDAT 2 4\n", 1), "alone.zmx")
    two = lens_to_dict(_read(p, config=2))
    assert two == lens_to_dict(_read(alone))
    assert two != lens_to_dict(_read(p, config=1))


def test_temperature_is_read_as_envd_with_its_note(tmp_path):
    """``TEMP``/``PRES`` are the configuration's ``ENVD``: deeplens' indices are the catalogues'
    at their reference temperature, so a temperature other than 20 °C is ignored with a note
    at the operand's line, as ``ENVD``'s (the thermal pick-ups of the other rows are applied)."""
    rows = "TEMP 0 1 20 0\nTEMP 0 2 100 0\nPRES 0 1 1 0\nPRES 0 2 1 0\nTHIC 2 2 10.5 4\n"
    p = _write(tmp_path, _base() + "MNUM 2 1\n" + rows)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        two = read_zmx(p, config=2)
    ln = p.read_text().splitlines().index("TEMP 0 2 100 0") + 1
    msgs = [str(w.message) for w in got if issubclass(w.category, ZemaxWarning)]
    assert any(f"lens.zmx:{ln}: TEMP: temperature 100 °C ignored, as ENVD's" in m for m in msgs)
    alone = _write(tmp_path, _base().replace("PWAV 2\n", "PWAV 2\nENVD 100 1 0\n", 1)
                   .replace("  DISZ 10\n", "  DISZ 10.5\n", 1), "alone.zmx")
    assert lens_to_dict(two) == lens_to_dict(_read(alone))
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        read_zmx(p, config=1)
    assert not any("TEMP" in str(w.message) for w in got)


def test_comment_weight_and_checksum_rows_change_nothing(tmp_path):
    rows = ('MCOM 0 1 "wide" 0 0 0 1 1 0 0.0 ""\nMCOM 0 2 "tele" 0 0 0 1 1 0 0.0 ""\n'
            "CWGT 0 1 0 0\nCWGT 0 2 1 0\nCSUM 123456\n")
    p = _write(tmp_path, _base() + "MNUM 2 1\n" + rows)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        two = read_zmx(p, config=2)
    assert not [w for w in got if re.search(r"MCOM|CWGT|CSUM", str(w.message))]
    assert lens_to_dict(two) == lens_to_dict(_read(p, config=1))


@pytest.mark.parametrize("rows, match", [
    ("APMN 2 2 1 0\n", r"APMN 2: SURF 2 has no circular aperture \(CLAP\) or obscuration"),
    ("APMN 3 2 7 0\n", r"APMN 3: the circular aperture \(CLAP\) of SURF 3 would have minimum "
                       r"radius 7 and maximum 6.5"),
    ("STPS 0 2 5 0\n", r"STPS: expected a surface number from 1 to 4"),
    ("PRAM 2 2 1e-06 0\n", r"PRAM 2: expected the .*number as the row's sixth field"),
    ("SDIA 3 2 -1 0\n", r"SDIA 3: a semi-diameter must be >= 0"),
    ("PRAM 9 2 1 0 2 0\n", r"PRAM 9: no SURF 9"),
])
def test_bad_values_are_refused_at_their_row(tmp_path, rows, match):
    p = _write(tmp_path, _base() + "MNUM 2 1\n" + rows)
    with pytest.raises(ZemaxFileError, match=match) as err:
        _read(p, config=2)
    assert err.value.line == p.read_text().splitlines().index(rows.strip()) + 1


# --- the synthetic file in OpticStudio's row format -------------------------------------------
GAPS = {1: 10.0, 2: 20.0, 3: 30.0}
EPD = {1: 10.0, 2: 8.0, 3: 6.0}
A4 = {1: 0.0, 2: 2e-6, 3: -2e-6}      # PRAM 2 (parameter 2: the r^4 term of SURF 2)
SDIA = {1: 7.0, 2: 6.5, 3: 6.0}       # SURF 3's semi-diameter
FIELD = {1: 6.0, 2: 7.0, 3: 8.0}


def test_opticstudio_format_file_has_the_closed_form_numbers_in_every_configuration():
    text = OSFORMAT.read_bytes().decode()
    assert "\r\n" in text and "CSUM" in text and "MCOM" in text
    for k in (1, 2, 3):
        lens = _read(OSFORMAT, config=k).to(torch.float64)
        p = paraxial(lens)
        assert float(p.efl) == pytest.approx(_thick_lens_efl(GAPS[k]), rel=1e-10)
        assert float(p.entrance_pupil_diameter) == pytest.approx(EPD[k], rel=1e-12)
        # the asphere's r^4 term: its sag at r minus configuration 1's (the sphere) is a4 r^4
        s = lens.surfaces[1]
        r = torch.tensor(3.0, dtype=torch.float64)
        c = -0.01
        sphere = c * r * r / (1 + torch.sqrt(1 - c * c * r * r))
        assert float(s.sag(torch.zeros_like(r), r) - sphere) == pytest.approx(A4[k] * 81.0,
                                                                             abs=1e-15)
        assert float(lens.surfaces[2].semi_diameter) == SDIA[k]
        assert float(lens.spec.fields_deg[-1]) == pytest.approx(FIELD[k], rel=1e-12)


def test_opticstudio_format_file_matches_the_independent_applier(tmp_path):
    for k in (1, 2, 3):
        alone = _write(tmp_path, single_configuration(OSFORMAT, k), f"c{k}.zmx")
        assert "MNUM" not in alone.read_text()
        assert lens_to_dict(_read(OSFORMAT, config=k)) == lens_to_dict(_read(alone))


def test_opticstudio_format_file_shares_the_unchanged_surfaces():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        lenses = read_zmx_configs(OSFORMAT)
    a, b, c = lenses
    # SURF 2's asphere (PRAM) is each configuration's own; SURF 3 differs only by its SDIA:
    # shared, with the largest semi-diameter (one physical surface passes every beam)
    assert [x is y for x, y in zip(a.surfaces, b.surfaces)] == [False, False, True, True]
    assert float(c.surfaces[2].semi_diameter) == max(SDIA.values())


def test_the_active_configuration_is_the_saved_records_not_its_rounded_rows(tmp_path):
    """OpticStudio writes the active configuration's operand rows rounded to 13 significant
    digits (``CRVT 1 1 1.044274562912E-002`` beside ``CURV 1.044274562912348200E-002`` in its
    sc_temp3 sample): the active configuration is read from the saved records, bit for bit."""
    base = _base().replace("  CURV -0.015\n", "  CURV -1.500000000000123400E-002\n", 1)
    rows = "CRVT 3 1 -1.500000000000E-002 1 0\nCRVT 3 2 -1.200000000000E-002 1 0\n"
    p = _write(tmp_path, base + "MNUM 2 1\n" + rows)
    saved = lens_to_dict(_read(_write(tmp_path, base, "saved.zmx")))
    assert lens_to_dict(_read(p)) == saved
    assert lens_to_dict(_read(p, config=1)) == saved
    assert lens_to_dict(_read(p, config=2)) != saved


def test_mnum_without_an_active_number_says_which_configuration_is_read(tmp_path):
    """OpticStudio's older files write ``MNUM n`` alone (its sc_temp5 sample: the saved records
    hold configuration 2): configuration 1 is read, and the note says the MNUM line names no
    active configuration (not that configuration 1 is the data as saved)."""
    rows = "THIC 2 1 10\nTHIC 2 2 20\n"
    p = _write(tmp_path, _base().replace("  DISZ 10\n", "  DISZ 20\n", 1) + "MNUM 2\n" + rows)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        lens = read_zmx(p)
    msgs = " ".join(str(w.message) for w in got)
    assert "configuration 1 (the MNUM line names no active configuration" in msgs
    assert lens_to_dict(lens) == lens_to_dict(_read(p, config=1))
    assert lens_to_dict(lens) != lens_to_dict(_read(p, config=2))
