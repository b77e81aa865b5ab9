"""``XASPHERE``, OpticStudio's Extended Asphere: ``z = STANDARD + Σ α_i (r / R_n)^{2i}``, the
coefficients in lens units on even powers of the normalised radius (OpticStudio User Guide,
"Extended Asphere": XDAT 1 the maximum term number, XDAT 2 the normalisation radius, XDAT 3..
the coefficients on ρ², ρ⁴, ...).

The sag of a hand-written file is worked out here from that formula at five points, in mm and
in inches; the file equals the EVENASPH of the same surface; a lens with a20 is written back as
XASPHERE and read back unchanged.
"""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.optics.io import ZemaxFileError, read_zmx, write_zmx

RN, C, K = 5.0, 0.02, -0.5
ALPHA = {1: 0.0, 2: 0.01, 3: -0.002, 10: 1e-4}   # on ρ², ρ⁴, ρ⁶, ρ²⁰ (lens units)


def xasphere(alpha=ALPHA, rn=RN, unit="MM"):
    n = max(alpha)
    extra = (f"XDAT 1 {n}", f"XDAT 2 {rn!r}",
             *[f"XDAT {i + 2} {v!r}" for i, v in sorted(alpha.items())])
    return singlet(s1_type="XASPHERE", s1_extra=extra, curv1=C, k=K, unit=unit)


def hand_sag(r, alpha=ALPHA, rn=RN, c=C, k=K, scale=1.0):
    """The Extended Asphere's sag (mm) at radius r (mm), lengths of the file times ``scale``."""
    c, rn = c / scale, rn * scale
    z = c * r * r / (1 + math.sqrt(1 - (1 + k) * c * c * r * r))
    return z + sum(v * scale * (r / rn) ** (2 * i) for i, v in alpha.items())


@pytest.mark.parametrize("unit,scale", [("MM", 1.0), ("IN", 25.4)])
def test_sag_is_the_extended_asphere_formula(tmp_path, unit, scale):
    lens = read_zmx(write(tmp_path, xasphere(unit=unit)))
    surf = lens.surfaces[1]
    for r in (0.0, 0.7, 1.9, 3.3, 4.1):   # in file units; the same points in mm
        x, y = r * 0.6 * scale, r * 0.8 * scale
        z = float(surf.sag(torch.tensor(x, dtype=torch.float64),
                           torch.tensor(y, dtype=torch.float64)))
        assert z == pytest.approx(hand_sag(r * scale, scale=scale), abs=1e-13 * scale)


def test_with_a_rho2_term_and_as_the_even_asphere(tmp_path):
    """A ρ² term makes it an odd asphere (odd powers zero); the same surface written as an
    EVENASPH (PARM i on r^{2i}, lens units) traces the same."""
    alpha = {1: 0.05, 2: 0.01, 4: -1e-3}
    x = read_zmx(write(tmp_path, xasphere(alpha), "x.zmx"))
    parms = tuple(f"PARM {i} {v / RN ** (2 * i)!r}" for i, v in alpha.items())
    e = read_zmx(write(tmp_path, singlet(s1_extra=parms, curv1=C, k=K), "e.zmx"))
    r = torch.linspace(0.0, 4.0, 9, dtype=torch.float64)
    zx, ze = x.surfaces[1].sag(r, 0 * r), e.surfaces[1].sag(r, 0 * r)
    assert torch.allclose(zx, ze, rtol=0, atol=1e-14)
    for rr, z in zip(r.tolist(), zx.tolist()):
        assert z == pytest.approx(hand_sag(rr, alpha), abs=1e-13)


def test_written_back_and_read_again(tmp_path):
    lens = read_zmx(write(tmp_path, xasphere()))
    write_zmx(lens, tmp_path / "out.zmx")
    assert "TYPE XASPHERE" in (tmp_path / "out.zmx").read_text()
    again = read_zmx(tmp_path / "out.zmx")
    r = torch.linspace(0.0, 4.0, 9, dtype=torch.float64)
    a, b = lens.surfaces[1].sag(r, 0 * r), again.surfaces[1].sag(r, 0 * r)
    assert torch.allclose(a, b, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("edit,needle,match", [
    (lambda t: t.replace("XDAT 12 0.0001", "XDAT 13 0.0001").replace("XDAT 1 10", "XDAT 1 11"),
     "XDAT 13", r"XASPHERE term 11 \(on ρ\^22\) is not supported"),
    (lambda t: t.replace("XDAT 12 0.0001", "XDAT 14 0.0001"), "XDAT 14",
     r"XASPHERE XDAT 14 lies beyond the 10 terms XDAT 1 declares"),
    (lambda t: t.replace("XDAT 2 5.0", "XDAT 2 0"), "XDAT 2 0",
     r"XASPHERE XDAT 2 \(the normalisation radius\) must be > 0"),
    (lambda t: t.replace("XDAT 1 10", "XDAT 1 10.5"), "XDAT 1 10.5",
     r"XASPHERE XDAT 1 \(the maximum term number\) must be an integer"),
])
def test_bad_extended_asphere_lines(tmp_path, edit, needle, match):
    text = edit(xasphere())
    with pytest.raises(ZemaxFileError, match=rf"t\.zmx:{line_of(text, needle)}: SURF 2: {match}"):
        read_zmx(write(tmp_path, text))
