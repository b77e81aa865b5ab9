"""Zemax glass catalogues (.agf): every dispersion formula checked against an independent form.

The catalogue is synthetic (written here; deeplens ships no vendor file).  Its glasses carry
N-BK7's published Sellmeier coefficients (SCHOTT catalogue, as in deeplens' own table) in the
three Sellmeier forms, B270's SCHOTT power series in the three "extended" forms (the extra terms
zero, or reordered for Extended 3), and one- and two-term Sellmeier glasses in the forms that can
express them exactly (Sellmeier 2 and 4, Handbook 2; Handbook 1 through the identity
``B λ²/(λ² − C) = B + B C/(λ² − C)``).  They are compared with deeplens' existing
``SellmeierGlass`` / ``SchottFormulaGlass`` code.  Herzberger and Conrady have no such
equivalent; they are checked against the closed forms evaluated with ``math`` at one wavelength.
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch

from deeplens.optics.io.agf import AgfError, read_agf
from deeplens.optics.materials import GLASS_TABLE, SellmeierGlass, get_material

W = torch.tensor([365.0, 486.1327, 587.5618, 656.2725, 1014.0, 2300.0], dtype=torch.float64)

BK7 = GLASS_TABLE["N-BK7"].coefficients           # B1 C1 B2 C2 B3 C3
B270 = GLASS_TABLE["B270"].coefficients           # a0..a5
B1, C1, B2, C2 = BK7[0], BK7[1], BK7[2], BK7[3]


def _nums(v):
    return " ".join(repr(float(x)) for x in v)


def agf_text() -> str:
    a = B270
    glasses = [
        ("BK7_S1", 2, BK7, 1.5168, 64.17),
        # the extra resonances split one of N-BK7's terms in two halves at the same C
        ("BK7_S3", 6, BK7[:4] + (BK7[4] / 2, BK7[5], BK7[4] / 2, BK7[5]), 1.5168, 64.17),
        ("BK7_S5", 11, (BK7[0] / 2, BK7[1], BK7[0] / 2, BK7[1]) + BK7[2:4]
         + (BK7[4] / 2, BK7[5], BK7[4] / 2, BK7[5]), 1.5168, 64.17),
        ("B270_SCHOTT", 1, a, 1.52308, 58.57),
        ("B270_EXT", 10, a + (0.0, 0.0), 1.52308, 58.57),
        ("B270_EXT2", 12, a + (0.0, 0.0), 1.52308, 58.57),
        ("B270_EXT3", 13, (a[0], a[1], 0.0, a[2], a[3], a[4], a[5], 0.0, 0.0), 1.52308, 58.57),
        ("TWO_S2", 4, (0.0, B1, C1, B2, C2), 0, 0),
        ("TWO_S4", 9, (1.0, B1, C1, B2, C2), 0, 0),
        ("ONE_HB2", 8, (1.0, B1, C1, 0.0), 0, 0),
        ("ONE_HB1", 7, (1.0 + B1, B1 * C1, C1, 0.0), 0, 0),
        ("HB1_C3", 7, (2.0, 0.01, 0.02, 0.003), 0, 0),
        ("HB2_C3", 8, (2.0, 0.01, 0.02, 0.003), 0, 0),
        ("EXT_HI", 10, a + (1e-6, -2e-7), 0, 0),
        ("EXT2_HI", 12, a + (1e-4, -2e-5), 0, 0),
        ("EXT3_HI", 13, (a[0], a[1], 3e-4, a[2], a[3], a[4], a[5], 1e-6, -2e-7), 0, 0),
        ("HERZ", 3, (1.5, 0.004, -0.0002, -0.003, 1e-4, -2e-6), 0, 0),
        ("CONR", 5, (1.5, 0.006, 0.0002), 0, 0),
    ]
    lines = ["CC synthetic catalogue for deeplens tests (no vendor data)"]
    for name, f, cd, nd, vd in glasses:
        lines += [f"NM {name} {f} 0 {nd} {vd} 0 0 0", "ED 7.1 8.3 2.51 -0.0009 0",
                  f"CD {_nums(cd)}", "TD 1.86e-06 1.31e-08 -1.37e-11 4.34e-07 6.27e-10 0.17 20",
                  "OD -1 -1 -1 -1 -1 -1", "LD 0.3 2.5", "IT 0.31 0.01 10"]
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def cat(tmp_path_factory):
    p = tmp_path_factory.mktemp("agf") / "acme.agf"
    p.write_text(agf_text())
    return read_agf(p)


def n_of(cat, name, w=W):
    return cat.get(name).n(w)


@pytest.mark.parametrize("name", ["BK7_S1", "BK7_S3", "BK7_S5"])
def test_sellmeier_forms_match_n_bk7(cat, name):
    ref = get_material("N-BK7").n(W)
    torch.testing.assert_close(n_of(cat, name), ref, rtol=0, atol=1e-13)
    g = cat.get(name)
    assert g.nd == pytest.approx(1.5168, abs=2e-5) and g.vd == pytest.approx(64.17, abs=0.02)


@pytest.mark.parametrize("name", ["B270_SCHOTT", "B270_EXT", "B270_EXT2", "B270_EXT3"])
def test_power_series_forms_match_b270(cat, name):
    ref = get_material("B270").n(W)
    torch.testing.assert_close(n_of(cat, name), ref, rtol=0, atol=1e-13)


@pytest.mark.parametrize("name,terms", [("TWO_S2", 2), ("TWO_S4", 2), ("ONE_HB2", 1),
                                        ("ONE_HB1", 1)])
def test_short_sellmeier_forms(cat, name, terms):
    ref = SellmeierGlass("ref", [B1, B2][:terms], [C1, C2][:terms]).n(W)
    torch.testing.assert_close(n_of(cat, name), ref, rtol=0, atol=1e-13)


def test_closed_forms_herzberger_conrady_handbook(cat):
    lam = 0.55  # µm
    w = torch.tensor([550.0], dtype=torch.float64)
    A, B, C, D, E, F = 1.5, 0.004, -0.0002, -0.003, 1e-4, -2e-6
    L = 1.0 / (lam ** 2 - 0.028)
    herz = A + B * L + C * L ** 2 + D * lam ** 2 + E * lam ** 4 + F * lam ** 6
    assert float(n_of(cat, "HERZ", w)) == pytest.approx(herz, abs=1e-14)
    conr = 1.5 + 0.006 / lam + 0.0002 / lam ** 3.5
    assert float(n_of(cat, "CONR", w)) == pytest.approx(conr, abs=1e-14)
    hb1 = math.sqrt(2.0 + 0.01 / (lam ** 2 - 0.02) - 0.003 * lam ** 2)
    assert float(n_of(cat, "HB1_C3", w)) == pytest.approx(hb1, abs=1e-14)
    hb2 = math.sqrt(2.0 + 0.01 * lam ** 2 / (lam ** 2 - 0.02) - 0.003 * lam ** 2)
    assert float(n_of(cat, "HB2_C3", w)) == pytest.approx(hb2, abs=1e-14)


def test_extended_forms_high_terms(cat):
    """The terms the SCHOTT series lacks, on top of B270 (deeplens' SchottFormulaGlass)."""
    lam = 0.55
    w = torch.tensor([550.0], dtype=torch.float64)
    n2 = float(get_material("B270").n(w)) ** 2
    ext = math.sqrt(n2 + 1e-6 * lam ** -10 - 2e-7 * lam ** -12)
    ext2 = math.sqrt(n2 + 1e-4 * lam ** 4 - 2e-5 * lam ** 6)
    ext3 = math.sqrt(n2 + 3e-4 * lam ** 4 + 1e-6 * lam ** -10 - 2e-7 * lam ** -12)
    assert float(n_of(cat, "EXT_HI", w)) == pytest.approx(ext, abs=1e-13)
    assert float(n_of(cat, "EXT2_HI", w)) == pytest.approx(ext2, abs=1e-13)
    assert float(n_of(cat, "EXT3_HI", w)) == pytest.approx(ext3, abs=1e-13)


def test_index_is_differentiable_in_wavelength(cat):
    w = torch.tensor([587.5618], dtype=torch.float64, requires_grad=True)
    g = cat.get("BK7_S3")
    torch.autograd.gradcheck(lambda x: g.n(x), (w,))


def test_exact_names_only(cat):
    assert cat.get("bk7_s1") is not None          # case-insensitive, as Zemax
    assert cat.get("BK7_S") is None and cat.get("BK7") is None  # never a close match
    assert len(cat) == 18 and cat.name == "ACME"


def test_range_from_ld_enforced(cat):
    g = cat.get("BK7_S1")
    assert g.wavelength_range_nm == pytest.approx((300.0, 2500.0))
    with pytest.raises(ValueError, match=r"outside the valid range 300.2500 nm of material 'BK7_S1'"):
        g.n(torch.tensor([250.0], dtype=torch.float64))


def test_td_is_noted(cat):
    assert any("TD" in n and "ignored" in n for n in cat.notes)


def test_utf16_catalogue(tmp_path):
    p = tmp_path / "U16.agf"
    p.write_bytes(agf_text().encode("utf-16"))
    assert read_agf(p).get("BK7_S1") is not None


def test_nd_mismatch_warns(tmp_path):
    p = tmp_path / "bad.agf"
    p.write_text(f"NM WRONG 2 0 1.6 50\nCD {_nums(BK7)}\nLD 0.3 2.5\n")
    with pytest.warns(UserWarning, match=r"bad.agf:1: glass 'WRONG'.*n_d = 1.51680.*1.600000"):
        read_agf(p)
    # three such glasses: one warning naming their NM lines and names, not one per glass
    p.write_text("".join(f"NM WRONG{i} 2 0 1.6 50\nCD {_nums(BK7)}\nLD 0.3 2.5\n"
                         for i in range(3)))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        read_agf(p)
    assert [str(x.message) for x in w] == [
        f"{p}:1,4,7: 3 glasses ('WRONG0', 'WRONG1', 'WRONG2'): the formula gives another n_d "
        f"than the NM record says (check the formula number and the CD record)"]


@pytest.mark.parametrize("text,match", [
    ("NM A 2 0 1.5 60\nCD 1.0 x 0.2 0.02 1.0 100\n", r":2: CD record: expected numbers, got 'x'"),
    ("NM A 2 0 1.5 60\nLD 0.3 2.5\nNM B 2 0 1.5 60\nCD 1 0.006 0.2 0.02 1 100\n",
     r":1: glass 'A' has no CD .*truncated"),
    ("NM A 2 0 1.5 60\nCD 1.0 0.006\n", r":2: glass 'A': formula 2 \(Sellmeier 1\) needs 6"),
    ("NM A 14 0 1.5 60\nCD 1 2 3\n", r":1: glass 'A': unknown dispersion formula '14'"),
    ("CD 1 2 3\n", r":1: a CD record before the first NM"),
    ("NM A\n", r":1: an NM record needs"),
    ("CC only a comment\n", r"no glass \(NM record\)"),
    ("NM A 2 0 1.5 60\nCD 1 0.006 0.2 0.02 1 100\nLD 2.5 0.3\n", r":3: glass 'A': LD needs"),
])
def test_malformed_catalogue_names_line(tmp_path, text, match):
    p = tmp_path / "m.agf"
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(AgfError, match=match):
            read_agf(p)


def test_melt_records_silent_and_unknown_records_warned_once(tmp_path):
    """Newer catalogues carry MD/BD records on every glass: no warning; an unknown record kind
    is reported once with its first line and count, not once per glass."""
    bk7 = GLASS_TABLE["N-BK7"].coefficients
    glass = ("NM G{i} 2 0 1.5168 64.17 0\nCD " + " ".join(map(repr, bk7)) +
             "\nMD 1 2 3\nBD 4 5\nXX 1\n")
    p = tmp_path / "NEW.agf"
    p.write_text("".join(glass.format(i=i) for i in range(50)))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        cat = read_agf(p)
    assert len(cat) == 50
    assert len(w) == 1 and "NEW.agf:5: unknown record 'XX' ignored (50 line(s)" in str(w[0].message)
