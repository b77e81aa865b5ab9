"""Millimetre waves from a ``.zmx``: ``WAVM`` states micrometres, so a wave beyond 100 µm is
meant, not a unit slip.  It loads where every medium of the lens is defined there (a constant
index, ``GLAS ___BLANK 1 0 n 0``: a model glass with ``V_d`` 0; air), and is refused, at the
glass's line, where one is not (a catalogue glass fitted for 310-2500 nm).  The bare-number guard
of the API (above 100 µm looks like ångström or picometres) is unchanged.

The loaded lens's focal length is the thick-lens closed form
``1/f = (n-1) (c1 - c2 + (n-1) t c1 c2 / n)``, and, the index being constant, the same lens at
0.55 µm has the same focal length to rounding.
"""

from __future__ import annotations

import math

import pytest
from test_zmx import write

from deeplens.optics.errors import LensError, ZemaxFileError
from deeplens.optics.io import read_zmx
from deeplens.optics.lens import LensSpec
from deeplens.optics.materials import ModelGlass, check_wavelength_nm, get_material
from deeplens.optics.paraxial import paraxial

C1, C2, T, N = 1 / 300.0, -1 / 500.0, 40.0, 1.52


def mm_wave_singlet(wavm="3000", glass=f"GLAS ___BLANK 1 0 {N} 0 0 0 0 0 0 0"):
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "NAME mm-wave singlet",
        "UNIT MM X W X CM MR CPMM", "ENPD 200", "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0",
        f"WAVM 1 {wavm} 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  DISZ INFINITY",
        "SURF 1", "  STOP", "  TYPE STANDARD", f"  CURV {C1!r}", f"  DISZ {T}", f"  {glass}",
        "  DIAM 110 1 0 0 1 \"\"",
        "SURF 2", "  TYPE STANDARD", f"  CURV {C2!r}", "  DISZ 350", "  DIAM 110 1 0 0 1 \"\"",
        "SURF 3", "  TYPE STANDARD", "  DISZ 0", "  DIAM 20 1 0 0 1 \"\""]) + "\n"


def test_a_millimetre_wave_lens_of_constant_index_loads(tmp_path):
    lens = read_zmx(write(tmp_path, mm_wave_singlet()))
    assert lens.spec.wavelengths_nm == [3e6] and lens.spec.wavelength_unit_stated
    phi = (N - 1) * (C1 - C2 + (N - 1) * T * C1 * C2 / N)
    efl = float(paraxial(lens).efl)
    assert efl == pytest.approx(1 / phi, rel=1e-12)
    visible = read_zmx(write(tmp_path, mm_wave_singlet("0.55"), "vis.zmx"))
    assert efl == pytest.approx(float(paraxial(visible).efl), rel=1e-14)


def test_a_dispersive_glass_at_3_mm_is_refused_at_its_line(tmp_path):
    text = mm_wave_singlet(glass="GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0")
    line = text.splitlines().index("  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0") + 1
    with pytest.raises(ZemaxFileError, match=rf"t.zmx:{line}: wavelength 3e\+06 nm is outside "
                                             rf"the valid range 310–2500 nm of material 'N-BK7'"
                                             rf".*WAVM 3000 µm \(3 mm"):
        read_zmx(write(tmp_path, text))
    # a model glass with an Abbe number is a Cauchy fit for 310-2500 nm: refused too
    with pytest.raises(ZemaxFileError, match=r"outside the valid range 310–2500 nm"):
        read_zmx(write(tmp_path, mm_wave_singlet(glass="GLAS ___BLANK 1 0 1.52 50 0 0 0 0 0 0"),
                       "model.zmx"))


def test_the_bare_number_guard_is_unchanged():
    """Without a stated unit or a medium defined there, 3e6 nm is a likely unit slip."""
    with pytest.raises(ValueError, match="ångström"):
        check_wavelength_nm(3e6)
    with pytest.raises(LensError, match="ångström"):
        LensSpec(wavelengths_nm=[3e6])
    with pytest.raises(ValueError, match="ångström"):   # beyond N-BK7's range: the hint stays
        check_wavelength_nm(5875.6e2, get_material("N-BK7"))
    # a medium defined there says the value is meant; so does a stated unit
    check_wavelength_nm(3e6, ModelGlass(1.52, math.inf))
    assert float(ModelGlass(1.52, math.inf).n(3e6)) == 1.52
    check_wavelength_nm(3e6, stated_unit=True)
    assert LensSpec(wavelengths_nm=[3e6], wavelength_unit_stated=True).wavelengths_nm == [3e6]
    # the other checks still apply with a stated unit
    with pytest.raises(ValueError, match="below 10 nm"):
        check_wavelength_nm(5.0, stated_unit=True)
    with pytest.raises(ValueError, match="finite and > 0"):
        check_wavelength_nm(-3e6, stated_unit=True)
