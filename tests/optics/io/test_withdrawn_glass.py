"""SCHOTT's withdrawn BK7 with its published Sellmeier coefficients (issue 37): the formula
evaluated here independently, n_d against SCHOTT's published 1.51680, a ``.zmx`` singlet at
1000 nm (beyond Robb & Mercado's 400-700 nm fit) against the thick-lens lensmaker's equation."""

from __future__ import annotations

import math
import warnings

import pytest

from deeplens.optics.io import read_zmx
from deeplens.optics.io.vendor_glass import find_in_vendor_catalogues, previous_glass
from deeplens.optics.io.withdrawn_glass import withdrawn_glass
from deeplens.optics.paraxial import paraxial

# RefractiveIndex.INFO, "Refractive index and related constants - BK7", after SCHOTT's data
# sheets (the module docstring of deeplens.optics.io.withdrawn_glass): B_i, C_i (µm²)
B = (1.03961212, 0.231792344, 1.01046945)
C = (0.00600069867, 0.0200179144, 103.560653)


def n_formula(lam_um: float) -> float:
    """The Sellmeier formula, written out here (not the AGF code)."""
    l2 = lam_um * lam_um
    return math.sqrt(1.0 + sum(b * l2 / (l2 - c) for b, c in zip(B, C)))


@pytest.mark.parametrize("lam_nm", [400.0, 1000.0, 2300.0])
def test_bk7_index_is_the_published_formula(lam_nm):
    g = withdrawn_glass("bk7", "schott")
    # float64 evaluation of a 3-term sum: rounding ~1e-15
    assert float(g.n(lam_nm)) == pytest.approx(n_formula(lam_nm / 1000.0), abs=1e-12)


def test_bk7_nd_is_schotts_published_value():
    g = withdrawn_glass("BK7", "SCHOTT")
    assert float(g.n(587.5618)) == pytest.approx(1.51680, abs=1e-5)
    with pytest.raises(ValueError, match="BK7"):
        g.n(2600.0)   # beyond the source's 0.3-2.5 µm
    assert withdrawn_glass("N-BK7", "SCHOTT") is None and withdrawn_glass("BK7", "OHARA") is None


def test_withdrawn_comes_before_the_previous_catalogue():
    hits = find_in_vendor_catalogues("BK7")
    assert "SCHOTT (withdrawn)" in hits and "SCHOTT (previous)" in hits
    assert hits.index("SCHOTT (withdrawn)") < hits.index("SCHOTT (previous)")
    assert previous_glass("BK7", "SCHOTT") is not None   # still there, just not first


def _zmx(tmp_path, c1, c2, t, lam_um):
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME bk7 singlet", "UNIT MM X W X CM MR CPMM",
             "ENPD 4", "GCAT SCHOTT", "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0",
             f"WAVM 1 {lam_um} 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 1", "  DIAM 2 1 0 0 1 \"\"",
             "SURF 2", "  TYPE STANDARD", f"  CURV {c1!r}", f"  DISZ {t!r}",
             "  GLAS BK7 0 0 1.5168 64.17 0 0 0 0 0 0", "  DIAM 5 1 0 0 1 \"\"",
             "SURF 3", "  TYPE STANDARD", f"  CURV {c2!r}", "  DISZ 40", "  DIAM 5 1 0 0 1 \"\"",
             "SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 5 1 0 0 1 \"\""]
    p = tmp_path / "bk7.zmx"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_zmx_bk7_singlet_at_1000nm_efl_is_the_lensmakers(tmp_path):
    c1, c2, t = 0.025, -0.01, 4.0
    p = _zmx(tmp_path, c1, c2, t, 1.0)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(p)
    notes = [str(x.message) for x in w]
    assert any("glass 'BK7': from the withdrawn SCHOTT catalogue" in m
               and "RefractiveIndex.INFO" in m for m in notes), notes
    n = n_formula(1.0)
    phi = (n - 1.0) * (c1 - c2 + (n - 1.0) * t * c1 * c2 / n)
    # paraxial EFL in float64: relative rounding ~1e-14 on a well-conditioned 2-surface system
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / phi, rel=1e-10)
