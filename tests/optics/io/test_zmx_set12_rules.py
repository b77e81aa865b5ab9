"""Readings met by the twelfth unseen set of real files (docs/guide/zemax.md), each on a small
hand-written file checked by a closed form or an independent reading:

* an image-space F-number (``FNUM f 0``) on a system whose focal length is negative (a relay
  with one intermediate image, or a diverging lens) sizes the pupil as ``EPD = |EFL| / F#``, as
  OpticStudio does (its own stored semi-diameters on such telescopes reproduce that pupil to
  12 digits) and as optiland's ``imageFNO`` does; before, it was refused as needing a positive
  focal length;
* a wavelength beyond the range of a glass from a visible-only previous catalogue (``UBK7``, in
  no full-range source deeplens ships) stays refused, in one line naming that catalogue and
  the file to pass;
* an image plane before the last vertex after a curved mirror stays refused, saying whether the
  beam reaches it forwards (an off-axis section met far from its vertex at grazing incidence);
* a curved image surface whose vertex plane the last surface crosses stays refused, saying by
  how much and whether the curved surface clears it (deeplens' sensor is flat).
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import line_of, singlet, write
from test_zmx_glass_rules import agf

from deeplens.optics.io import ZemaxFileError, read_zmx
from deeplens.optics.paraxial import paraxial

_HEAD = """VERS 80915 20 20100
MODE SEQ
UNIT MM X W X CM MR CPMM
{aperture}
FTYP 0 0 1 1 0 0 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
"""


def _surf(k, *lines):
    return f"SURF {k}\n" + "".join(f"  {ln}\n" for ln in lines)


def _quiet(path):
    return _quiet_with(path)


def _quiet_with(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path, **options)


# --------------------------------------------------- an F-number on a negative focal length
_N, _C, _T, _GAP = 1.5, 0.02, 4.0, 250.0     # two plano-convex singlets (f = 100 mm each)
_GLASS = "GLAS ___BLANK 1 0 1.5 1e9 0 0 0 0 0 0"
_RELAY = "".join([_surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
                  _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 10"),
                  _surf(2, "TYPE STANDARD", f"CURV {_C}", f"DISZ {_T}", _GLASS),
                  _surf(3, "TYPE STANDARD", "CURV 0", f"DISZ {_GAP}"),
                  _surf(4, "TYPE STANDARD", f"CURV {_C}", f"DISZ {_T}", _GLASS),
                  _surf(5, "TYPE STANDARD", "CURV 0", "DISZ 290"),
                  _surf(6, "TYPE STANDARD", "CURV 0", "DISZ 0")])


def _relay_efl_by_hand():
    """The relay's EFL by a y-nu trace written out here: refraction ``nu' = nu - y φ``, transfer
    ``y' = y + (t / n) nu``; ``EFL = -1 / nu'`` in air (negative: one intermediate image, the
    singlets 254 mm apart, more than the sum of their focal lengths)."""
    y, nu = 1.0, 0.0
    for phi, t, n in ((_C * (_N - 1), _T, _N), (0.0, _GAP, 1.0),
                      (_C * (_N - 1), _T, _N), (0.0, 0.0, 1.0)):
        nu = nu - y * phi
        y = y + t / n * nu
    return -1.0 / nu


@pytest.mark.parametrize("fno", [10.0, 6.5])
def test_fnum_on_a_negative_focal_length_takes_its_magnitude(tmp_path, fno):
    """OpticStudio's *Image Space F/#* is the ratio of the paraxial infinite-conjugate EFL to
    the paraxial entrance-pupil diameter; a negative EFL has the pupil of its magnitude,
    ``EPD = |EFL| / F#`` (OpticStudio's stored semi-diameters on such files, Zemax guide), and
    the F-number deeplens reports is that positive ratio again.  The stop is the first surface,
    so its semi-diameter is ``EPD / 2``.  Before, such a file was refused."""
    path = write(tmp_path, _HEAD.format(aperture=f"FNUM {fno} 0") + _RELAY)
    lens = _quiet(path)
    p = paraxial(lens)
    efl = _relay_efl_by_hand()
    assert efl < 0
    assert float(p.efl) == pytest.approx(efl, rel=1e-13)
    assert float(p.entrance_pupil_diameter) == pytest.approx(abs(efl) / fno, rel=1e-13)
    assert float(lens.stop.semi_diameter) == pytest.approx(abs(efl) / fno / 2, rel=1e-13)
    assert float(p.fno) == pytest.approx(fno, rel=1e-13)


def test_fnum_on_a_negative_focal_length_as_optiland_reads_it(tmp_path):
    """The independent reading: optiland reads the same file (``FNUM`` as its ``imageFNO``,
    whose pupil is ``|f2| / FNO``) and gets the same EFL, sign included, and pupil."""
    pytest.importorskip("optiland")
    import numpy as np
    from optiland.fileio import load_zemax_file

    path = write(tmp_path, _HEAD.format(aperture="FNUM 10 0") + _RELAY)
    lens = _quiet(path)
    p = paraxial(lens)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = load_zemax_file(str(path))
    f2 = float(np.ravel(op.paraxial.f2())[0])
    epd = float(np.ravel(op.paraxial.EPD())[0])
    assert f2 < 0 and math.isfinite(f2)
    assert float(p.efl) == pytest.approx(f2, rel=1e-12)
    assert float(p.entrance_pupil_diameter) == pytest.approx(epd, rel=1e-12)


# ------------------------------------------- a visible-only previous glass beyond its range
def test_a_previous_glass_beyond_its_range_names_its_catalogue_and_the_flag(tmp_path):
    """``UBK7`` (SCHOTT, withdrawn) is in no shipped full-range source (not in the current or
    archived SCHOTT catalogues nor the withdrawn entries); only Robb & Mercado's 1983
    visible-only fit (400-700 nm) has it, so 800 nm is refused at the ``GLAS`` line, in one
    line that names that catalogue (why the range is visible-only) and the file to pass: the
    user's ``SCHOTT.agf``, which is looked up before every shipped SCHOTT source."""
    p = write(tmp_path, singlet(glass="GLAS UBK7 0 0 1.5 40 0 0 0 0 0 0", wav=(0.55, 0.8),
                                pwav=1))
    ln = line_of(p.read_text(), "GLAS UBK7")
    with pytest.raises(ZemaxFileError) as e:
        _quiet(p)
    msg = str(e.value)
    assert e.value.line == ln and "\n" not in msg and len(msg) < 260 + len(str(p)), msg
    assert "wavelength 800 nm is outside the valid range 400–700 nm of material 'UBK7'" in msg
    assert "previous SCHOTT catalogue, Robb & Mercado 1983, a visible-only fit" in msg
    assert msg.endswith("; pass SCHOTT.agf with --glass-catalog"), msg
    # the advice works: the user's SCHOTT.agf (a constant n 1.52 over 0.3-2.5 µm) is used
    cat = agf(tmp_path / "SCHOTT.agf", {"UBK7": 1.52})
    lens = _quiet_with(p, glass_catalogs=[cat])
    w = torch.tensor([550.0, 800.0], dtype=torch.float64)
    assert torch.equal(lens.materials[2].n(w), torch.full_like(w, 1.52))


def test_a_current_catalogue_glass_beyond_its_range_names_its_catalogue(tmp_path):
    """The same refusal on a current catalogue glass names that catalogue (SCHOTT's N-BK7,
    300-2500 nm, at 3 µm) and the same file to pass; a model glass (no catalogue) keeps the
    bare message."""
    p = write(tmp_path, singlet(wav=(0.55, 3.0), pwav=1))
    with pytest.raises(ZemaxFileError) as e:
        _quiet(p)
    msg = str(e.value)
    assert "of material 'N-BK7' (glass of SURF 2, catalogue SCHOTT); pass SCHOTT.agf with " \
           "--glass-catalog" in msg, msg


# ------------------------------- an image plane before the last vertex after an off-axis mirror
_FOLD_OAP = "".join([
    _surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
    _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 10"),
    _surf(2, "TYPE COORDBRK", "PARM 1 0", "PARM 2 0", "PARM 3 45", "PARM 4 0", "PARM 5 0",
          "PARM 6 0", "DISZ 0"),
    _surf(3, "TYPE STANDARD", "CURV 0", "DISZ 0", "GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0"),
    _surf(4, "TYPE COORDBRK", "PARM 1 0", "PARM 2 0", "PARM 3 45", "PARM 4 0", "PARM 5 0",
          "PARM 6 0", "DISZ -600"),
    # a paraboloid (R 10 mm) decentred 100 mm: the beam meets it at local y = -100, z = 500,
    # at grazing incidence (slope 10), and goes on towards its focus (y 100, z 5) along -z
    _surf(5, "TYPE COORDBRK", "PARM 1 0", "PARM 2 100", "PARM 3 0", "PARM 4 0", "PARM 5 0",
          "PARM 6 0", "DISZ 0"),
    _surf(6, "TYPE STANDARD", "CURV 0.1", "CONI -1", "DISZ 0",
          "GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0"),
    _surf(7, "TYPE COORDBRK", "PARM 1 0", "PARM 2 -100", "PARM 3 0", "PARM 4 0", "PARM 5 0",
          "PARM 6 1", "DISZ 0"),
    _surf(8, "TYPE COORDBRK", "PARM 1 0", "PARM 2 0", "PARM 3 {tilt}", "PARM 4 0", "PARM 5 0",
          "PARM 6 0", "DISZ {d}"),
    _surf(9, "TYPE STANDARD", "CURV 0", "DISZ 0")])


def test_image_before_the_vertex_after_a_grazing_off_axis_mirror_says_the_beam_reaches_it(
        tmp_path):
    """Set 12's grazing-incidence ellipsoid: after two mirrors (a fold, then an off-axis
    section met far from its vertex) the file's tilted image plane lies before the last vertex
    (DISZ < 0), against the mirror parity that OpticStudio's *Thicknesses* page states and
    deeplens' paraxial data use, yet the beam, sent on towards the focus the way it came, meets
    it forwards.  Still refused (deeplens' direction of travel flips at every mirror), but the
    one line now says so with the distance the chief ray travels to the plane: by hand, from the
    hit (0, 500) in the frame after the return break towards the focus (100, 5), to the plane
    through ``d ẑ'`` with normal ``ẑ' = (0, -sin θ, cos θ)`` (θ = 10°, right-handed)."""
    tilt, d = 10.0, -12.0
    text = _HEAD.format(aperture="ENPD 1e-5") + _FOLD_OAP.format(tilt=tilt, d=d)
    path = write(tmp_path, text)
    with pytest.raises(ZemaxFileError) as e:
        _quiet(path)
    msg = str(e.value)
    assert e.value.line == line_of(text, "SURF 9") and "\n" not in msg, msg
    assert ("the image plane lies 12 mm before the last surface's vertex (light travels "
            "towards +z there, after 2 mirrors), yet the beam reaches it forwards (") in msg, msg
    assert msg.endswith("keeps the beam's direction, which deeplens' mirror parity cannot "
                        "express: not supported"), msg
    th = math.radians(tilt)
    zn = (0.0, -math.sin(th), math.cos(th))
    hit, focus = (0.0, 500.0), (100.0, 5.0)
    u = (focus[0] - hit[0], focus[1] - hit[1])
    nu = math.hypot(*u)
    u = (u[0] / nu, u[1] / nu)
    t = ((d * zn[1] - hit[0]) * zn[1] + (d * zn[2] - hit[1]) * zn[2]) / (u[0] * zn[1]
                                                                         + u[1] * zn[2])
    assert f"({t:.6g} to {t:.6g} mm on)" in msg, (t, msg)


def test_image_before_the_vertex_after_a_concave_mirror_slip_of_sign_is_refused(tmp_path):
    """A concave mirror met at its vertex (no decenter) with the image written on the wrong
    side (``DISZ +5`` for its focus at ``-5``): the beam leaves away from that plane, so the
    refusal keeps its message: a slip of sign, not an off-axis section."""
    text = _HEAD.format(aperture="ENPD 1") + "".join([
        _surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
        _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 10"),
        _surf(2, "TYPE STANDARD", "CURV -0.1", "DISZ 5", "GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0"),
        _surf(3, "TYPE STANDARD", "CURV 0", "DISZ 0")])
    with pytest.raises(ZemaxFileError) as e:
        _quiet(write(tmp_path, text))
    msg = str(e.value)
    assert e.value.line == line_of(text, "SURF 3") and "reaches it forwards" not in msg, msg
    assert "the image plane lies 5 mm before the last surface's vertex (light travels towards " \
           "-z there, after 1 mirror): a virtual image plane after mirrors is read only" in msg


# ----------------------------------------- a curved image surface whose vertex plane is cut
def _meniscus(img_curv):
    """A meniscus (both faces R 20 mm, 4 mm thick, DIAM 8 fixed) with the image surface 1 mm
    after it: the last face's rim lies ``20 - sqrt(20² - 8²)`` = 1.6697 mm beyond its vertex
    plane, so 0.6697 mm beyond the plane of the image's vertex."""
    return _HEAD.format(aperture="ENPD 4") + "".join([
        _surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
        _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 5"),
        _surf(2, "TYPE STANDARD", "CURV 0.05", "DISZ 4", "GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0",
              'DIAM 8 1 0 0 1 ""'),
        _surf(3, "TYPE STANDARD", "CURV 0.05", "DISZ 1", 'DIAM 8 1 0 0 1 ""'),
        _surf(4, "TYPE STANDARD", f"CURV {img_curv}", "DISZ 0")])


@pytest.mark.parametrize("img_curv, clears", [(0.05, True), (0.02, False)])
def test_a_curved_image_surface_cut_by_the_last_surface_says_so(tmp_path, img_curv, clears):
    """Set 12's catadioptric camera (``ob_HoO-V2C18Ex36``): OpticStudio images onto a curved
    image surface; deeplens reads it as a flat sensor at its vertex, which the last face's rim
    crosses.  Refused at the image line in one line naming the curvature, the crossing surface,
    how far it reaches beyond the plane (the closed-form sag at the semi-diameter less the 1 mm
    gap) and whether the file's curved surface clears it (concentric with the face at R 20: it
    does; at R 50 the face reaches 1.6697 − (1 + 50 − sqrt(50² − 8²)) beyond it: it does not);
    before, the message was "the last surface crosses the sensor plane (sensor distance 1 mm)"."""
    text = _meniscus(img_curv)
    with pytest.raises(ZemaxFileError) as e:
        _quiet(write(tmp_path, text))
    msg = str(e.value)
    reach = 20.0 - math.sqrt(20.0 ** 2 - 8.0 ** 2) - 1.0
    assert e.value.line == line_of(text, "SURF 4") and "\n" not in msg, msg
    assert (f"the image surface is curved (R {1 / img_curv:g} mm) and deeplens' sensor is the "
            f"plane at its vertex, which SURF 3 crosses: it reaches {reach:.4g} mm beyond that "
            f"plane within its semi-diameter 8 mm") in msg, msg
    assert ("where the curved image surface clears it" in msg) == clears, msg
    assert msg.endswith("; a curved sensor is not supported"), msg


def test_a_flat_image_cut_by_the_last_surface_keeps_the_lens_message(tmp_path):
    """With a flat image surface the plane is the file's own: the Lens check's message stays."""
    with pytest.raises(ZemaxFileError) as e:
        _quiet(write(tmp_path, _meniscus(0)))
    assert "the last surface crosses the sensor plane (sensor distance 1 mm)" in str(e.value)


def test_fnum_on_a_negative_focal_length_round_trips(tmp_path):
    """Written back as ``FNUM 10 0`` and read again: the same pupil (``.zmx`` and JSON)."""
    from deeplens.optics.io import lens_from_dict, lens_to_dict, write_zmx

    lens = _quiet(write(tmp_path, _HEAD.format(aperture="FNUM 10 0") + _RELAY))
    out = tmp_path / "back.zmx"
    write_zmx(lens, out)
    assert "FNUM 10.0 0" in out.read_text()
    for again in (_quiet(out), lens_from_dict(lens_to_dict(lens))):
        assert float(paraxial(again).entrance_pupil_diameter) == pytest.approx(
            float(paraxial(lens).entrance_pupil_diameter), rel=1e-12)
