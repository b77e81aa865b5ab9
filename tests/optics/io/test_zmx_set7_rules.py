"""Readings met by the seventh unseen set of real files (docs/guide/zemax.md, "A seventh unseen
set"), each on a synthetic file checked by a closed form and by an independent reading:

* an ideal lens (``PARAXIAL``) met while the light travels towards ``-z`` (after a mirror)
  converges along the light's way for a positive focal length, in deeplens' paraxial data as in
  its real trace (``IdealLens.deflect``) and rayoptics' reading, and as a file's own thickness
  to the focus after it says (OpticStudio's short-course null test: ``PARM 1 100`` then
  ``DISZ -100``).  The paraxial data had taken ``1/f`` times the signed index there, a lens of
  the opposite power (EFL -399.08 mm against rayoptics' -38.47 on the null test);
* a file with both the old ``WAVL`` list and ``WAVM`` records (OpticStudio writes both in files
  of its 2008-2010 versions): the oracles read the ``WAVM`` records, as deeplens does
  (``test_zmx_corpus.oracle_text``), where optiland 0.6 took the ``WAVL`` line for
  ``WAVL slot value`` and failed with an IndexError.
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import write
from zmx_blocks import surf as _surf, zmx_file

import test_zmx_corpus as tc
from deeplens.optics.io import read_zmx
from deeplens.optics.paraxial import paraxial

#: focal lengths of the two ideal lenses and the light's path between them (mm): the first on
#: the stop, a flat mirror A further on, the second B back from the mirror
F1, F2, A, B = 200.0, 100.0, 50.0, 10.0


def _file(blocks, waves="WAVM 1 0.5875618 1\n"):
    return zmx_file(blocks, name="set7", waves=waves)


def _two_lenses_about_a_mirror():
    """Ideal lens ``F1`` on the stop, a flat mirror ``A`` behind it, ideal lens ``F2`` ``B``
    back from the mirror (light travelling towards -z), the image plane at the paraxial focus
    (thin-lens pair, separation ``d = A + B``: ``φ = 1/F1 + 1/F2 - d/(F1 F2)``, back focal
    distance ``(1 - d/F1)/φ``)."""
    d = A + B
    phi = 1.0 / F1 + 1.0 / F2 - d / (F1 * F2)
    bfl = (1.0 - d / F1) / phi
    return _file([_surf(disz="INFINITY"),
                  _surf("PARAXIAL", parms=[F1, 0], disz=A, stop=True, diam=6.0),
                  _surf(disz=-B, glas="MIRROR", diam=10.0),
                  _surf("PARAXIAL", parms=[F2, 0], disz=-bfl, diam=10.0), _surf()]), phi, bfl


def _read(p):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lens = read_zmx(p).double()
    return lens, [w.message for w in caught]


def test_paraxial_lens_after_a_mirror_converges_along_the_light(monkeypatch, tmp_path):
    """EFL = 1/φ = 83.33 mm and the focus (1 - d/F1)/φ = 58.33 mm on from the second lens, as
    two converging thin lenses 60 mm apart (with the second lens's power of the opposite sign,
    φ = -0.002: EFL -500 mm, the paraxial data before); real rays across the pupil meet the
    axis on the file's image plane at that distance (ideal lenses: exactly), and rayoptics' own
    reading confirms EFL, EPD, pupil and back focus."""
    import test_zmx_corpus_rayoptics as tr

    text, phi, bfl = _two_lenses_about_a_mirror()
    write(tmp_path, text)
    lens, msgs = _read(tmp_path / "t.zmx")
    par = paraxial(lens)
    assert float(par.efl) == pytest.approx(1.0 / phi, rel=1e-12)
    assert abs(float(par.bfl)) == pytest.approx(bfl, rel=1e-12)
    assert abs(float(par.image_distance)) == pytest.approx(bfl, rel=1e-12)
    lines = text.splitlines()
    second = lines.index("  TYPE PARAXIAL", lines.index("SURF 3")) + 1   # its TYPE line
    notes = [m for m in msgs if getattr(m, "line", None) == second]
    assert len(notes) == 1 and "direction of travel" in str(notes[0])
    assert not [m for m in msgs if "direction of travel" in str(m) and m not in notes]

    from test_zmx_apertures import _on_axis_rays

    rays = _on_axis_rays(lens)
    with torch.no_grad():
        out = lens.trace_to_sensor(rays)
    hit = out.o[out.valid]
    assert hit.shape[0] > 10 and float(rays.o[..., :2].abs().max()) > 4.0
    assert float(hit[..., :2].abs().max()) < 1e-9

    monkeypatch.setattr(tc, "CORPUS", tmp_path)
    monkeypatch.setattr(tr, "CORPUS", tmp_path)
    (tmp_path / "ro").mkdir()
    opm = tr._rayoptics("t.zmx", lens, monkeypatch, tmp_path / "ro")
    for what, (dl, ro) in tr._numbers("t.zmx", lens, opm).items():
        assert tr._agrees(dl, ro), f"rayoptics {what}: deeplens {dl!r} vs {ro!r}"
    # optiland 0.6 makes the second lens diverge (why the reader notes the choice)
    optic, _ = tc._oracle("t.zmx", lens)
    d = A + B
    assert abs(float(optic.paraxial.f2())) == pytest.approx(
        1.0 / abs(1.0 / F1 - 1.0 / F2 + d / (F1 * F2)), rel=1e-9)


def _singlet(waves):
    glass = "___BLANK 1 0 1.5 0 0 0 0 0 0 0"
    return _file([_surf(disz="INFINITY"), _surf(disz=5.0, stop=True),
                  _surf(curv=0.01, disz=4.0, glas=glass, diam=6.0),
                  _surf(disz=190.0, diam=6.0), _surf()], waves=waves)


#: OpticStudio 2008-2010's wavelength records: the old WAVL list and the WAVM slots, 24 of them
_BOTH = ("WAVL 0.6328\nWAVN 0.6328 0.55 0.55\nWWGT 1\nWWGN 1 1 1\n"
         + "".join(f"WAVM {k} {0.6328 if k == 1 else 0.55} 1\n" for k in range(1, 25)))


def test_old_wavl_beside_wavm_records_reach_the_oracles(monkeypatch, tmp_path):
    """A plano-convex singlet (n = 1.5, R = 100 mm: EFL 200 mm) written with both the old WAVL
    list and WAVM records: deeplens reads WAVM (primary 632.8 nm); optiland 0.6 fails on the
    raw text (IndexError: WAVL read as ``WAVL slot value``) and agrees with deeplens on the
    oracle's copy, whose only change is the old records dropped."""
    write(tmp_path, _singlet(_BOTH))
    lens, _ = _read(tmp_path / "t.zmx")
    assert float(lens.spec.primary_wavelength_nm) == pytest.approx(632.8)
    assert float(paraxial(lens).efl) == pytest.approx(200.0, rel=1e-12)
    text = (tmp_path / "t.zmx").read_text()
    copy = tc.oracle_text(text)
    assert not [ln for ln in copy.splitlines() if ln.split()[:1] in (["WAVL"], ["WWGT"])]
    assert [ln for ln in copy.splitlines() if ln.startswith("WAVM")] == \
        [ln for ln in text.splitlines() if ln.startswith("WAVM")]
    from optiland.fileio import load_zemax_file

    with pytest.raises(IndexError):
        load_zemax_file(str(tmp_path / "t.zmx"))
    monkeypatch.setattr(tc, "CORPUS", tmp_path)
    tc.oracle_folder(tmp_path, tmp_path)     # the oracle reads its copy (in place here)
    optic, s_mm = tc._oracle("t.zmx", lens)
    for what, (dl, ol) in tc._first_order(lens, optic, s_mm, "t.zmx").items():
        assert dl == pytest.approx(ol, rel=1e-9, abs=1e-9), f"optiland {what}"
    assert math.isclose(float(optic.paraxial.f2()), 200.0, rel_tol=1e-9)
