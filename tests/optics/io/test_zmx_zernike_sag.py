"""``TYPE SZERNSAG`` (OpticStudio's Zernike Standard Sag) in ``.zmx`` files: the hand-written
singlet ``tests/data/zmx_opticstudio/zernike_sag_singlet.zmx`` is read into a
:class:`~deeplens.optics.surfaces.ZernikeSag` whose sag at chosen points is the one worked out
here from OpticStudio's written-out terms; the same file in inches gives the same lens; written
and read again it is the same lens bit for bit; unsupported data are refused with their line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from test_zmx import line_of, write

from deeplens.optics.io import lens_to_dict
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.surfaces import ZernikeFringeSag, ZernikeSag
from helpers import read_zmx_quiet

FILE = Path(__file__).resolve().parents[2] / "data" / "zmx_opticstudio" / "zernike_sag_singlet.zmx"
F64 = torch.float64


def sag_by_hand(x, y):
    """The file's SURF 2, worked out from OpticStudio's formula and its Zernike Standard table:
    CURV 0.025, CONI −0.5, r² term 1e-3, r⁴ term 2e-5, R_n = 5, Z4 = 0.01, Z6 = 0.003, Z8 = 0.001,
    Z11 = −0.002."""
    r2 = x * x + y * y
    p, a = math.sqrt(r2) / 5.0, math.atan2(y, x)
    base = 0.025 * r2 / (1 + math.sqrt(1 - 0.5 * 0.025 ** 2 * r2)) + 1e-3 * r2 + 2e-5 * r2 ** 2
    return (base + 0.01 * math.sqrt(3) * (2 * p * p - 1)
            + 0.003 * math.sqrt(6) * p * p * math.cos(2 * a)
            + 0.001 * math.sqrt(8) * (3 * p ** 3 - 2 * p) * math.cos(a)
            - 0.002 * math.sqrt(5) * (6 * p ** 4 - 6 * p * p + 1))


POINTS = [(0.0, 0.0), (1.5, -2.0), (-3.0, 0.5), (0.0, 4.4), (2.5, 2.5)]


def test_hand_written_file_has_the_known_sag():
    lens = read_zmx_quiet(FILE)
    s = lens.surfaces[1]
    assert isinstance(s, ZernikeSag) and s.extrapolate
    assert float(s.norm_radius) == 5.0 and [float(v) for v in s.a] == [1e-3, 2e-5]
    assert [float(v) for v in s.zernike] == [0, 0, 0, 0.01, 0, 0.003, 0, 0.001, 0, 0, -0.002]
    x = torch.tensor([p[0] for p in POINTS], dtype=F64)
    y = torch.tensor([p[1] for p in POINTS], dtype=F64)
    z = s.sag(x, y)
    ref = [sag_by_hand(*p) for p in POINTS]
    assert z.tolist() == pytest.approx(ref, abs=1e-15)
    # the vertex sits at Z4(0) + Z11(0) = −√3·0.01 − √5·0.002, not at 0
    assert float(z[0]) == pytest.approx(-math.sqrt(3) * 0.01 - math.sqrt(5) * 0.002, abs=1e-16)


def _in_inches(text):
    """The file with every length in inches (``s`` = 25.4 mm per unit): PARM i (r^(2i)) scales
    by s^(2i−1), the normalisation radius and the Zernike coefficients by 1/s."""
    s = 25.4
    out = []
    for ln in text.splitlines():
        t = ln.split()
        if t[:1] == ["UNIT"]:
            ln = ln.replace("UNIT MM", "UNIT IN")
        elif t[:1] == ["ENPD"]:
            ln = f"ENPD {8 / s!r}"
        elif t[:1] == ["CURV"]:
            ln = f"  CURV {float(t[1]) * s!r}"
        elif t[:1] in (["DISZ"], ["DIAM"]) and t[1] != "INFINITY":
            ln = "  " + " ".join([t[0], repr(float(t[1]) / s)] + t[2:])
        elif t[:1] == ["PARM"] and 1 <= int(t[1]) <= 8:
            ln = f"  PARM {t[1]} {float(t[2]) * s ** (2 * int(t[1]) - 1)!r}"
        elif t[:1] == ["XDAT"] and int(t[1]) >= 2:
            ln = f"  XDAT {t[1]} {float(t[2]) / s!r}"
        out.append(ln)
    return "\n".join(out) + "\n"


def test_the_file_in_inches_is_the_same_lens(tmp_path):
    mm = read_zmx_quiet(FILE)
    inch = read_zmx_quiet(write(tmp_path, _in_inches(FILE.read_text())))
    a, b = mm.surfaces[1], inch.surfaces[1]
    assert float(b.norm_radius) == pytest.approx(5.0, rel=1e-15)
    x = torch.tensor([p[0] for p in POINTS], dtype=F64)
    y = torch.tensor([p[1] for p in POINTS], dtype=F64)
    assert b.sag(x, y).tolist() == pytest.approx(a.sag(x, y).tolist(), rel=1e-13, abs=1e-16)


def test_round_trip_zmx_lens_zmx_lens(tmp_path):
    """.zmx -> Lens -> .zmx -> Lens: the same prescription bit for bit and the same rays."""
    from deeplens.optics.sampling import field_rays

    lens = read_zmx_quiet(FILE)
    p = tmp_path / "back.zmx"
    write_zmx(lens, p)
    text = p.read_text()
    assert "TYPE SZERNSAG" in text and "XDAT 13 -0.002" in text and "PARM 0 1" in text
    back = read_zmx_quiet(p)
    assert lens_to_dict(back) == lens_to_dict(lens)
    pupil = torch.tensor([[0.0, 0.0], [0.0, 0.9], [0.6, -0.5], [-0.8, 0.1]], dtype=F64)
    with torch.no_grad():
        a = lens.trace_to_sensor(field_rays(lens, 3.0, 587.5618, pupil, 4.0))
        b = back.trace_to_sensor(field_rays(back, 3.0, 587.5618, pupil, 4.0))
    assert a.valid.all() and torch.equal(a.o, b.o)
    # and once more: the written file is a fixed point
    p2 = tmp_path / "again.zmx"
    write_zmx(back, p2)
    assert p2.read_text() == text


def test_no_extrapolation_round_trips(tmp_path):
    text = FILE.read_text().replace("PARM 0 1", "PARM 0 0")
    lens = read_zmx_quiet(write(tmp_path, text))
    assert not lens.surfaces[1].extrapolate
    p = tmp_path / "back.zmx"
    write_zmx(lens, p)
    assert "PARM 0 0" in p.read_text() and not read_zmx_quiet(p).surfaces[1].extrapolate


@pytest.mark.parametrize("old,new,needle,match", [
    ("PARM 9 0", "PARM 9 0.5", "PARM 9", r"SZERNSAG PARM 9 \(the Zernike decenter in x\) is not "
                                         r"supported"),
    ("PARM 0 1", "PARM 0 2", "PARM 0", r"PARM 0 \(the extrapolate flag\) must be 0 or 1"),
    ("XDAT 1 11", "XDAT 1 232", "XDAT 1", r"XDAT 1 \(the number of Zernike terms\) must be an "
                                          r"integer 0..231"),
    ("XDAT 1 11", "XDAT 1 10", "XDAT 13", r"SZERNSAG XDAT 13 lies beyond the 10 Zernike terms"),
    ("XDAT 2 5", "XDAT 2 0", "XDAT 2 0", r"XDAT 2 \(the normalisation radius\) must be > 0"),
    ("PARM 8 0", "PARM 11 0.1", "PARM 11", r"SZERNSAG PARM 11 = 0.1 is not read"),
])
def test_unsupported_data_are_refused_with_their_line(tmp_path, old, new, needle, match):
    text = FILE.read_text()
    assert old in text
    text = text.replace(old, new)
    ln = line_of(text, needle)
    with pytest.raises(ZemaxFileError, match=f":{ln}: .*{match}"):
        read_zmx(write(tmp_path, text))


def test_paraxial_focus_uses_the_vertex_curvature():
    """The file's paraxial EFL against a y-nu trace by hand with the vertex curvature ``c + 2 α_1
    + 2 (2√3 A_4 − 6√5 A_11) / R_n²`` (the m = 0 terms' r² parts)."""
    from deeplens.optics.paraxial import paraxial

    lens = read_zmx_quiet(FILE)
    c = 0.025 + 2e-3 + 2 * (2 * math.sqrt(3) * 0.01 - 6 * math.sqrt(5) * -0.002) / 25.0
    n = float(lens.materials[2].n(torch.tensor(587.5618, dtype=F64)))
    efl = 1.0 / (c * (n - 1.0))    # a plano-convex lens: the flat back adds no power
    assert float(paraxial(lens).efl) == pytest.approx(efl, rel=1e-12)
    assert np.isfinite(efl)


def test_x_fields_on_a_non_symmetric_zernike_sag_are_reported_as_not_exact(tmp_path):
    """XFLN combined radially is exact only for a rotationally symmetric lens: the file's Z6 and
    Z8 (astigmatism, coma) make it not, and the note says so; with only m = 0 terms it is."""
    from deeplens.optics.io.zmx import ZemaxWarning

    text = FILE.read_text().replace("XFLN 0 0", "XFLN 0 1")
    with pytest.warns(ZemaxWarning, match=r"NOT exact for this lens \(surface 1, a ZernikeSag"):
        read_zmx(write(tmp_path, text))
    sym = text.replace("XDAT 8 0.003", "XDAT 8 0").replace("XDAT 10 0.001", "XDAT 10 0")
    lens = read_zmx_quiet(write(tmp_path, sym, "sym.zmx"))
    assert lens.surfaces[1].rotationally_symmetric()
    with pytest.warns(ZemaxWarning, match=r"exact for a rotationally symmetric lens"):
        read_zmx(write(tmp_path, sym, "sym2.zmx"))


def _fringe_text():
    """The singlet with its SURF 2 a Zernike Fringe sag (``FZERNSAG``) of the same records."""
    return FILE.read_text().replace("TYPE SZERNSAG", "TYPE FZERNSAG").replace(
        "Zernike standard sag singlet", "Zernike fringe sag singlet")


def fringe_sag_by_hand(x, y):
    """SURF 2 as FZERNSAG, worked out from the Fringe table (no normalisation): Z4 = 2ρ² − 1,
    Z6 = ρ² sin 2φ, Z8 = (3ρ³ − 2ρ) sin φ, Z11 = ρ³ sin 3φ."""
    r2 = x * x + y * y
    p, a = math.sqrt(r2) / 5.0, math.atan2(y, x)
    base = 0.025 * r2 / (1 + math.sqrt(1 - 0.5 * 0.025 ** 2 * r2)) + 1e-3 * r2 + 2e-5 * r2 ** 2
    return (base + 0.01 * (2 * p * p - 1) + 0.003 * p * p * math.sin(2 * a)
            + 0.001 * (3 * p ** 3 - 2 * p) * math.sin(a) - 0.002 * p ** 3 * math.sin(3 * a))


def test_fringe_file_has_the_known_sag_and_round_trips(tmp_path):
    """``FZERNSAG`` is read into a :class:`ZernikeFringeSag` whose sag is the one worked out by
    hand from the Fringe terms (not the Standard ones of the same numbers), its paraxial EFL
    uses the Fringe defocus (``c + 2 α_1 + 2 · 2 A_4 / R_n²``); written back it is ``FZERNSAG``
    with the same records, and read again the same lens bit for bit."""
    from deeplens.optics.paraxial import paraxial

    lens = read_zmx_quiet(write(tmp_path, _fringe_text()))
    s = lens.surfaces[1]
    assert type(s) is ZernikeFringeSag
    x = torch.tensor([p[0] for p in POINTS], dtype=F64)
    y = torch.tensor([p[1] for p in POINTS], dtype=F64)
    assert s.sag(x, y).tolist() == pytest.approx([fringe_sag_by_hand(*p) for p in POINTS],
                                                 abs=1e-15)
    assert abs(float(s.sag(x, y)[1]) - sag_by_hand(*POINTS[1])) > 1e-3
    c = 0.025 + 2e-3 + 2 * 2 * 0.01 / 25.0
    n = float(lens.materials[2].n(torch.tensor(587.5618, dtype=F64)))
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / (c * (n - 1.0)), rel=1e-12)
    p = tmp_path / "back.zmx"
    write_zmx(lens, p)
    text = p.read_text()
    assert "TYPE FZERNSAG" in text and "SZERNSAG" not in text and "XDAT 13 -0.002" in text
    back = read_zmx_quiet(p)
    assert lens_to_dict(back) == lens_to_dict(lens)
    assert lens_to_dict(back)["surfaces"][1]["type"] == "zernike_fringe_sag"


@pytest.mark.parametrize("old,new,needle,match", [
    ("XDAT 1 11", "XDAT 1 38", "XDAT 1", r"FZERNSAG XDAT 1 \(the number of Zernike terms\) must "
                                         r"be an integer 0..37"),
    ("PARM 9 0", "PARM 9 0.5", "PARM 9", r"FZERNSAG PARM 9 \(the Zernike decenter in x\)"),
    ("XDAT 1 11", "XDAT 1 10", "XDAT 13", r"FZERNSAG XDAT 13 lies beyond the 10 Zernike terms"),
    ("  XDAT 13 -0.002\n", "  XDAT 13 -0.002\n  OBSC 1 2 0\n", "OBSC 1 2",
     r"SURF 2: OBSC 1 2, a ring obscuration \(a baffle; minimum radius > 0\), on a lens "
     r"surface \(ZernikeFringeSag\) is not supported"),
])
def test_fringe_data_refused_with_their_line(tmp_path, old, new, needle, match):
    text = _fringe_text().replace(old, new)
    ln = line_of(text, needle)
    with pytest.raises(ZemaxFileError, match=f":{ln}: .*{match}"):
        read_zmx(write(tmp_path, text))


@pytest.mark.parametrize("record", ["CLAP 1 4.5 0", "OBSC 0 1 0"])
def test_a_central_obscuration_on_a_zernike_sag_blocks_the_centre_and_round_trips(tmp_path,
                                                                                  record):
    """An annular CLAP (1-4.5 mm) or an OBSC of 1 mm on the FZERNSAG face (a telescope
    primary's hole): the surface's opening passes exactly the points at 1 <= r <= 4.5; written
    back as OBSC, read again, and through the lens file, the same lens."""
    from deeplens.optics.io import lens_from_dict

    text = _fringe_text().replace("  XDAT 13 -0.002\n", f"  XDAT 13 -0.002\n  {record}\n")
    lens = read_zmx_quiet(write(tmp_path, text))
    s = lens.surfaces[1]
    assert type(s) is ZernikeFringeSag and float(s.obscuration) == 1.0
    r = torch.tensor([0.0, 0.5, 0.999, 1.0, 3.0, 4.5, 4.6], dtype=F64)
    assert s.opening.contains(r, torch.zeros_like(r)).tolist() == [
        False, False, False, True, True, True, False]
    p = tmp_path / "back.zmx"
    write_zmx(lens, p)
    assert "OBSC 0 1.0 0" in p.read_text()
    d = lens_to_dict(lens)
    assert d["surfaces"][1]["obscuration_mm"] == 1.0
    assert lens_to_dict(read_zmx_quiet(p)) == d and lens_to_dict(lens_from_dict(d)) == d
    keys = list(lens.state_dict())
    assert "surfaces.1.c" in keys and "surfaces.1.obscuration" not in keys
