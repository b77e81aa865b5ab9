"""``TYPE BINARY_2`` in ``.zmx`` files: read into :class:`~deeplens.optics.surfaces.Binary2` with
the file's units (``PARM 0`` the order, ``PARM 2..8`` the base's ``r⁴ ... r¹⁶`` terms, ``XDAT 1``
the number of phase terms, ``XDAT 2`` the normalisation radius, a length, ``XDAT 3..`` the
``A_i`` in radians), the paraxial EFL against a hand-made y-nu trace with the diffractive power
``-M A_1 λ / (π R_n²)``, written back, reported; odd data refused with its line.  No public
``.zmx`` with ``BINARY_2`` was found to add to the corpus; optiland 0.6 reads no ``BINARY_2``."""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import line_of, report, write

from deeplens.optics.io import lens_to_dict
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.materials import ModelGlass
from deeplens.optics.paraxial import paraxial
from deeplens.optics.surfaces import Binary2
from helpers import read_zmx_quiet

#: the Binary 2 rear surface in mm: curvature, conic, a4, order, R_n, A_1, A_2
C2, K2, A4, M, RN, PH1, PH2 = -0.01, 0.5, 2e-6, 1, 5.0, -1500.0, 30.0
N_GLASS, WL = 1.5168, 587.5618


def binary2_file(unit="MM", s=1.0, body=None, extra=()):
    """A singlet in air: a flat stop (EPD 10 mm), a spherical front (R 50 mm), 5 mm of a model
    glass, a BINARY_2 back (CURV −0.01/mm, CONI 0.5, a4 2e-6, M 1, R_n 5 mm, A_1 −1500, A_2 30),
    in ``unit`` (``s`` mm per unit).  ``body`` replaces the BINARY_2 lines after TYPE."""
    if body is None:
        body = [f"PARM 0 {M}", "PARM 1 0", f"PARM 2 {A4 * s ** 3!r}", "PARM 3 0", "XDAT 1 2",
                f"XDAT 2 {RN / s!r}", f"XDAT 3 {PH1!r}", f"XDAT 4 {PH2!r}"]
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME hybrid", f"UNIT {unit} X W X CM MR CPMM",
             f"ENPD {10 / s!r}", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 3",
             "WAVM 1 0.5875618 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {2 / s!r}",
             f"  DIAM {5 / s!r} 1 0 0 1 \"\"",
             "SURF 2", "  TYPE STANDARD", f"  CURV {0.02 * s!r}", f"  DISZ {5 / s!r}",
             f"  GLAS ___BLANK 1 0 {N_GLASS} 64.17 0 0 0 0 0 0", f"  DIAM {6 / s!r} 1 0 0 1 \"\"",
             "SURF 3", "  TYPE BINARY_2", f"  CURV {C2 * s!r}", f"  CONI {K2}",
             *[f"  {x}" for x in body], *[f"  {x}" for x in extra],
             f"  DISZ {30 / s!r}", f"  DIAM {6 / s!r} 1 0 0 1 \"\"",
             "SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", f"  DIAM {6 / s!r} 1 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


_read = read_zmx_quiet


def _efl_by_hand():
    """y-nu trace of the singlet (thick lens + the phase's power at the primary wavelength)."""
    n = lens_n()
    phi1 = 0.02 * (n - 1.0)
    phi2 = C2 * (1.0 - n) - M * PH1 * WL * 1e-6 / (math.pi * RN ** 2)
    y, nu = 1.0, 0.0
    nu = nu - y * phi1
    y = y + 5.0 * nu / n
    nu = nu - y * phi2
    return -1.0 / nu


def lens_n():
    return float(ModelGlass(N_GLASS, 64.17).n(torch.tensor(WL, dtype=torch.float64)))


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_reads_the_surface_with_the_units(tmp_path, unit, s):
    """PARM 0 -> the order, PARM 2 -> a4 (a length^-3), XDAT 2 -> R_n (a length), XDAT 3.. ->
    A_i (radians, unscaled); the paraxial EFL is the hand trace's (1e-12)."""
    lens = _read(write(tmp_path, binary2_file(unit, s)))
    b = lens.surfaces[-1]
    assert isinstance(b, Binary2)
    assert b.order == M
    assert float(b.c) == pytest.approx(C2, rel=1e-14) and float(b.k) == K2
    assert float(b.norm_radius) == pytest.approx(RN, rel=1e-14)
    assert [float(a) for a in b.A] == pytest.approx([PH1, PH2], rel=1e-14)
    assert [float(a) for a in b.a] == pytest.approx([A4], rel=1e-12)
    efl = float(paraxial(lens).efl)
    assert efl == pytest.approx(_efl_by_hand(), rel=1e-12)
    # the diffractive power matters: without it the EFL is 65.2 mm instead of 38.2
    assert abs(efl - _efl_by_hand_without_phase()) > 5.0


def _efl_by_hand_without_phase():
    n = lens_n()
    phi1, phi2 = 0.02 * (n - 1.0), C2 * (1.0 - n)
    nu = -phi1
    y = 1.0 + 5.0 * nu / n
    nu = nu - y * phi2
    return -1.0 / nu


def test_write_and_read_back(tmp_path):
    lens = _read(write(tmp_path, binary2_file()))
    write_zmx(lens, tmp_path / "out.zmx")
    text = (tmp_path / "out.zmx").read_text()
    assert "TYPE BINARY_2" in text and "PARM 0 1" in text and "XDAT 1 2" in text
    back = _read(tmp_path / "out.zmx")
    a, b = lens_to_dict(lens), lens_to_dict(back)
    a.pop("name", None), b.pop("name", None)
    assert a == b


def test_report_prints_numbers(tmp_path):
    rep = report(write(tmp_path, binary2_file()), "--sampling", "hexapolar:3")
    assert rep["efl_mm"] == pytest.approx(_efl_by_hand(), rel=1e-10)


BASE = [f"PARM 0 {M}", "PARM 1 0", "XDAT 1 2", f"XDAT 2 {RN!r}", f"XDAT 3 {PH1!r}",
        f"XDAT 4 {PH2!r}"]


@pytest.mark.parametrize("body,needle,match", [
    (["PARM 0 1", "PARM 1 0.001", "XDAT 1 1", "XDAT 2 5", "XDAT 3 -100"], "PARM 1 0.001",
     r"BINARY_2 PARM 1 \(the r² term of the base asphere\) is not supported"),
    (["PARM 1 0", "XDAT 1 1", "XDAT 2 5", "XDAT 3 -100"], "TYPE BINARY_2",
     r"BINARY_2 without PARM 0 \(the diffraction order\)"),
    (["PARM 0 1.5", "XDAT 1 1", "XDAT 2 5", "XDAT 3 -100"], "PARM 0 1.5",
     r"diffraction order \(BINARY_2 PARM 0\) must be an integer"),
    (["PARM 0 1", "XDAT 1 2.5", "XDAT 2 5", "XDAT 3 -100"], "XDAT 1 2.5",
     r"BINARY_2 XDAT 1 \(the number of phase terms\) must be an integer"),
    (["PARM 0 1", "XDAT 1 1", "XDAT 2 5", "XDAT 3 -100", "XDAT 4 7"], "XDAT 4 7",
     r"BINARY_2 XDAT 4 lies beyond the 1 phase terms XDAT 1 declares"),
    (["PARM 0 1", "XDAT 1 1", "XDAT 2 0", "XDAT 3 -100"], "XDAT 2 0",
     r"BINARY_2 XDAT 2 \(the normalisation radius\) must be > 0"),
    (BASE + ["PARM 9 0.1"], "PARM 9", r"BINARY_2 PARM 9 = 0.1 is not read"),
])
def test_odd_data_is_refused_with_its_line(tmp_path, body, needle, match):
    text = binary2_file(body=body)
    p = write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(p)
    assert e.value.line == line_of(text, needle)
    assert str(p) in str(e.value)


def test_a_rectangular_aperture_on_a_binary2_is_its_clear_aperture(tmp_path):
    """SQAP on any lens surface (tests/optics/io/test_zmx_sqap_any_surface.py): on a BINARY_2
    too, kept by the .zmx writer."""
    from deeplens.optics.surfaces.base import clear_rect_of

    text = binary2_file(extra=("SQAP 3 2 0",))
    lens = read_zmx(write(tmp_path, text))
    i = next(j for j, s in enumerate(lens.surfaces) if clear_rect_of(s) is not None)
    assert clear_rect_of(lens.surfaces[i]) == (3.0, 2.0)
    write_zmx(lens, tmp_path / "out.zmx")
    assert clear_rect_of(read_zmx(tmp_path / "out.zmx").surfaces[i]) == (3.0, 2.0)


def test_report_on_a_refused_binary2_prints_one_located_line(tmp_path, capsys):
    from deeplens.cli import main

    text = binary2_file(body=BASE + ["PARM 9 0.1"])
    p = write(tmp_path, text)
    rc = main(["report", str(p), "--sampling", "hexapolar:3"])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1
    assert f"{p}:{line_of(text, 'PARM 9')}" in lines[0] and "BINARY_2 PARM 9" in lines[0]
