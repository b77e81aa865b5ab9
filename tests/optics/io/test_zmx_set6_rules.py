"""Two readings met by the sixth unseen set of real files (docs/guide/zemax.md, "A sixth set"),
each on a synthetic file checked by a closed form and by both independent readings:

* an even asphere's ``r²`` term (``EVENASPH`` with ``PARM 1`` != 0) is part of the surface's
  vertex curvature, ``c + 2 a_1``, in deeplens' first-order data (What is read); optiland 0.6's
  and rayoptics 0.9's paraxial traces take ``CURV`` alone, so the corpus oracles are given the
  folded curvature (``test_zmx_corpus._even_r2_terms``; OpticStudio's double-pass null test
  sample, both readings 0.33 % apart before);
* a floating pupil (``FLOA``) whose stop is a mirror met by the marginal ray below the axis:
  optiland's float-by-stop EPD comes out negative there (the null test's stop, a flat mirror
  behind a corrector plate), and the oracle takes its magnitude.
"""

from __future__ import annotations

import warnings

import pytest
from test_zmx import write
from zmx_blocks import surf as _surf, zmx_file

import test_zmx_corpus as tc
from deeplens.optics.io import read_zmx
from deeplens.optics.paraxial import paraxial

pytest.importorskip("optiland")
pytest.importorskip("rayoptics")

#: a model glass of index 1.5 (no dispersion) and the plano-convex singlet's numbers
N = 1.5
C, A1 = 0.01, 0.0025          # CURV (1/mm) and the r² coefficient PARM 1 (1/mm)

def _file(blocks, aperture="ENPD 10.0"):
    return zmx_file(blocks, name="set6", aperture=aperture)


def _even_r2_singlet():
    """A plano-convex singlet, its convex face first an even asphere with an r² term."""
    glass = f"___BLANK 1 0 {N} 0 0 0 0 0 0 0"
    return _file([_surf(disz="INFINITY"),
                  _surf("EVENASPH", curv=C, parms=[A1, 1e-7], disz=5.0, glas=glass,
                        stop=True, diam=6.0),
                  _surf(disz=100.0, diam=6.0), _surf()])


def _floa_stop_behind_a_mirror(stop_radius=5.0, d=75.0):
    """A concave mirror (R = -100 mm, f = 50 mm) and a floating stop of radius ``stop_radius``
    on a flat mirror a distance ``d`` in front of it, past its focus (the returning beam has
    crossed the axis there)."""
    return _file([_surf(disz="INFINITY"),
                  _surf(curv=-0.01, disz=-d, glas="MIRROR", diam=30.0),
                  _surf(disz=10.0, stop=True, glas="MIRROR", diam=stop_radius), _surf()],
                 aperture="FLOA")


def _read(p):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(p).double()


def _both_oracles_agree(monkeypatch, tmp_path, name, lens):
    import test_zmx_corpus_rayoptics as tr

    monkeypatch.setattr(tc, "CORPUS", tmp_path)
    monkeypatch.setattr(tr, "CORPUS", tmp_path)
    ref = tc._r2_in_curvature(name, tmp_path) if tc._even_r2_terms(name) else name
    optic, s_mm = tc._oracle(ref, lens)
    for what, (dl, ol) in tc._first_order(lens, optic, s_mm, ref).items():
        assert dl == pytest.approx(ol, rel=1e-9, abs=1e-9), f"optiland {what}"
    scratch = tmp_path / "ro"
    scratch.mkdir()
    opm = tr._rayoptics(name, lens, monkeypatch, scratch)
    for what, (dl, ro) in tr._numbers(name, lens, opm).items():
        assert tr._agrees(dl, ro), f"rayoptics {what}: deeplens {dl!r} vs {ro!r}"
    return optic


def test_even_asphere_r2_term_is_in_the_vertex_curvature(monkeypatch, tmp_path):
    """EFL of the plano-convex singlet = 1 / ((n - 1)(c + 2 a_1)) = 133.33 mm (a plane back
    face adds no power whatever the thickness), not 1 / ((n - 1) c) = 200 mm; both oracles,
    given the folded curvature, confirm EFL, EPD, pupil and back focus, and optiland's own
    paraxial reading of the unfolded file gives 200 mm (why the oracle folds it)."""
    write(tmp_path, _even_r2_singlet())
    lens = _read(tmp_path / "t.zmx")
    efl = 1.0 / ((N - 1.0) * (C + 2.0 * A1))
    assert float(paraxial(lens).efl) == pytest.approx(efl, rel=1e-12)
    assert _even_r2_terms_of(monkeypatch, tmp_path) == {1: A1}
    _both_oracles_agree(monkeypatch, tmp_path, "t.zmx", lens)
    raw, _ = tc._oracle("t.zmx", lens)
    assert float(raw.paraxial.f2()) == pytest.approx(1.0 / ((N - 1.0) * C), rel=1e-9)


def _even_r2_terms_of(monkeypatch, tmp_path):
    monkeypatch.setattr(tc, "CORPUS", tmp_path)
    return tc._even_r2_terms("t.zmx")


def test_floating_stop_behind_a_mirror(monkeypatch, tmp_path):
    """The stop (radius 5 mm) on a flat mirror 75 mm in front of a mirror of focal length 50 mm:
    the marginal ray meets it at minus half its height on the concave mirror, so EPD =
    2 r f / (d - f) = 20 mm; both oracles confirm the four numbers (optiland's float-by-stop EPD
    is -20 on such a stop; the oracle takes its magnitude)."""
    write(tmp_path, _floa_stop_behind_a_mirror())
    lens = _read(tmp_path / "t.zmx")
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(20.0, rel=1e-12)
    assert abs(float(paraxial(lens).efl)) == pytest.approx(50.0, rel=1e-12)
    optic = _both_oracles_agree(monkeypatch, tmp_path, "t.zmx", lens)
    optic.set_aperture(aperture_type="float_by_stop_size", value=10.0)
    assert float(optic.paraxial.EPD()[0]) == pytest.approx(-20.0, rel=1e-12)   # why abs()


def test_rectangular_stop_under_an_epd_keeps_its_rectangle(tmp_path):
    """A rectangular stop (``SQAP 2 4``) first in air under ``ENPD 10`` (refused before: an EPD
    sized the stop and a rectangle has no radius): the paraxial pupil is the file's, EPD 10 mm
    (the stop is its own entrance pupil), and the rectangle stays as it is and vignettes, as
    OpticStudio's surface apertures do: of an on-axis grid filling the pupil exactly the rays
    with |x| <= 2 and |y| <= 4 at the stop pass."""
    import torch
    from test_zmx_apertures import _on_axis_rays

    from deeplens.optics.options import TraceOptions

    glass = f"___BLANK 1 0 {N} 0 0 0 0 0 0 0"
    stop = _surf(disz=10.0, stop=True) + ["  SQAP 2 4 0"]
    write(tmp_path, _file([_surf(disz="INFINITY"), stop,
                           _surf(curv=0.02, disz=5.0, glas=glass, diam=8.0),
                           _surf(disz=90.0, diam=8.0), _surf()]))
    lens = _read(tmp_path / "t.zmx")
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(10.0, rel=1e-12)
    assert tuple(float(v) for v in lens.stop.half_widths) == (2.0, 4.0)
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        free = lens.trace(rays, options=TraceOptions(clip_aperture=False))
        clipped = lens.trace(rays)
    x, y = rays.o[..., 0], rays.o[..., 1]
    want = free.valid & (x.abs() <= 2.0) & (y.abs() <= 4.0)
    assert 0 < int(want.sum()) < int(free.valid.sum())   # the rectangle vignettes the pupil
    assert torch.equal(clipped.valid, want)
