"""Vendor glass catalogues (opticalglass data): every glass against the catalogue's own formula
as opticalglass evaluates it, a few against the vendors' published n_d / V_d, and the previous
(Robb & Mercado 1983) catalogue against published data for withdrawn glasses."""

from __future__ import annotations

import pytest

from deeplens.optics.io.vendor_glass import (VENDOR_CATALOGUES, _vendor_table,
                                             find_in_vendor_catalogues, previous_glass,
                                             vendor_glass)

og = pytest.importorskip("opticalglass")

WAVES = (435.8343, 587.5618, 706.5188)


@pytest.mark.parametrize("cat", list(VENDOR_CATALOGUES))
def test_every_glass_equals_the_catalogue_formula(cat):
    import importlib

    module, cls, _ = VENDOR_CATALOGUES[cat]
    mod = importlib.import_module(f"opticalglass.{module}")
    glass_cls = getattr(mod, cls.replace("Catalog", "Glass"))
    table = _vendor_table(cat)
    assert len(table) > 100
    for gname in getattr(mod, cls)().df.index:   # the catalogue's own (unstripped) names
        if "".join(str(gname).split()).upper() not in table:
            continue   # rows without coefficients
        ours = vendor_glass(str(gname), cat)
        ref, name = glass_cls(gname), gname
        for w in WAVES:
            assert float(ours.n(w)) == pytest.approx(float(ref.calc_rindex(w)), abs=1e-12), (
                cat, name, w)


@pytest.mark.parametrize("name,cat,nd,vd", [
    ("N-BK7", "SCHOTT", 1.51680, 64.17), ("N-SF6", "SCHOTT", 1.80518, 25.36),
    ("N-BAF10", "SCHOTT", 1.67003, 47.11), ("S-BSL7", "OHARA", 1.51633, 64.14),
    ("S-LAH64", "OHARA", 1.78800, 47.37), ("S-LAH66", "OHARA", 1.77250, 49.60),
])
def test_published_nd_vd(name, cat, nd, vd):
    g = vendor_glass(name, cat)
    assert g.nd == pytest.approx(nd, abs=3e-5)
    assert g.vd == pytest.approx(vd, abs=0.05)


@pytest.mark.parametrize("name,nd,vd", [
    ("BK7", 1.51680, 64.17), ("SK16", 1.62041, 60.32), ("SF1", 1.71736, 29.51),
])
def test_previous_catalogue_reproduces_published_data(name, nd, vd):
    """At Robb & Mercado's base wavelength 0.574 µm; at 587.6 nm BK7's n_d would be 1.51739."""
    g = previous_glass(name, "SCHOTT")
    assert g.nd == pytest.approx(nd, abs=5e-6)
    assert g.vd == pytest.approx(vd, abs=0.25)
    with pytest.raises(ValueError):   # a visible-range fit: refused outside 400-700 nm
        g.n(1064.0)


def test_exact_names_only():
    assert vendor_glass("N-BK7X", "SCHOTT") is None
    assert vendor_glass("n-bk7", "schott") is not None
    assert find_in_vendor_catalogues("S-LAH64") == ["OHARA"]


@pytest.mark.parametrize("name,rii", [("CAF2", "CaF2/Malitson.yml"), ("BAF2", "BaF2/Malitson.yml"),
                                      ("MGF2", "MgF2/Dodge-o.yml"),
                                      ("SAPPHIRE", "Al2O3/Malitson-o.yml"),
                                      ("ZNSE", "ZnSe/Connolly.yml")])
def test_infrared_crystals_equal_the_refractiveindex_database(name, rii):
    """The INFRARED names against the refractiveindex.info entries of the same measurements
    (optiland ships that database; test-only)."""
    pytest.importorskip("optiland")
    import numpy as np
    from optiland.materials import Material

    author = rii.split("/")[1].split("-")[0].removesuffix(".yml")
    ref = Material(rii.split("/")[0], reference=author)
    assert str(ref.filename).endswith(rii)
    g = vendor_glass(name, "INFRARED")
    lo, hi = g.wavelength_range_nm
    for w in np.linspace(max(lo, 400.0), min(hi, 5000.0), 7):
        want = float(np.ravel(np.asarray(ref.n(np.array([w / 1000.0]))))[0])
        assert float(g.n(float(w))) == pytest.approx(want, abs=1e-9), (name, w)
