"""Readings met by the thirteenth unseen set of real files (docs/guide/zemax.md), each on a
small hand-written file checked by a closed form:

* a fixed DIAM beyond the edge of a sphere (OpticStudio's floating aperture, which clips no ray
  the sphere keeps) is read at the edge, with one note; before, it was refused;
* an image-space FNUM on an unflagged entrance pupil at infinity stays refused, saying why
  (afocal, or the EFL it would divide);
* an FTYP 3 height that only a field beyond 90 deg reaches stays refused, saying so;

* an image plane written just before a last flat surface in one medium whose fixed DIAM never
  clips (a focal-plane dummy after mirrors): OpticStudio's rays reach that surface and go back
  along their lines to the image plane (virtual propagation), so the surface is dropped and its
  gap merged into the image's, with one note at its line; before, it was refused as an image
  plane before the last vertex after a curved mirror.
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import line_of, write

from deeplens.optics.io import ZemaxFileError, read_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.sampling import field_rays

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


def _loaded(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(path)
    return lens, [str(x.message) for x in w]


# ----------------------- an image plane just before a drawn-only focal-plane dummy (mirrors)
_F, _DELTA = 100.0, 0.001   # the paraboloid's focal length; the dummy's distance past focus
_PARABOLOID = "".join([
    _surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
    _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 10"),
    # a concave paraboloid (R = -200 mm, k = -1): every ray parallel to the axis meets the axis
    # at its focus, 100 mm before the vertex (along -z after the mirror)
    _surf(2, "TYPE STANDARD", f"CURV {-1 / (2 * _F)!r}", "CONI -1", "DISZ {d_mirror}",
          "GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0"),
    # a flat dummy in air with a fixed DIAM (drawn, never clips)
    _surf(3, "TYPE STANDARD", "CURV 0", "DISZ {d_dummy}", "DIAM 30 1 0 0 1 \"\""),
    _surf(4, "TYPE STANDARD", "CURV 0", "DISZ 0")])


def _rim_landings(lens):
    """Where 24 rays parallel to the axis at 9.9 mm from it land on the sensor: (N, 2) mm."""
    phi = torch.arange(24, dtype=lens.dtype) * (2 * math.pi / 24)
    pts = torch.stack([torch.cos(phi), torch.sin(phi)], -1) * 9.9
    rays = field_rays(lens, 0.0, float(lens.spec.primary_wavelength_nm), pts, 0.0)
    with torch.no_grad():
        out = lens.trace(rays)
        out = lens.propagate_to_z(out, lens.z_sensor().to(out.o), backwards=True)
    assert bool(out.valid.all())
    return out.o[..., :2]


def test_image_before_a_drawn_only_dummy_after_a_mirror_is_reached_backwards(tmp_path):
    """The dummy lies ``_DELTA`` past the paraboloid's focus and the image plane ``_DELTA`` back
    from it (``DISZ +_DELTA`` against the direction of travel after one mirror): the dummy bends
    and stops no ray, so the image plane is the focal plane, 100 mm before the vertex, and every
    ray parallel to the axis lands on the axis there (the paraboloid's closed form); the note
    names the dummy's line.  Reading the merged gap with the wrong sign would put the sensor
    ``2 _DELTA`` past focus, where rays at slope ~0.1 land 2e-4 mm off the axis."""
    text = _HEAD.format(aperture="ENPD 20") + _PARABOLOID.format(
        d_mirror=-(_F + _DELTA), d_dummy=_DELTA)
    path = write(tmp_path, text)
    lens, notes = _loaded(path)
    assert len(lens.surfaces) == 2   # the stop and the mirror: the dummy is dropped
    assert float(lens.z_sensor()) == pytest.approx(10.0 - _F, abs=1e-12)   # mirror at z 10
    hits = _rim_landings(lens)
    assert float(hits.abs().max()) < 1e-9, hits
    line = line_of(text, "SURF 3")
    mine = [n for n in notes if "whose fixed DIAM never clips" in n]
    assert len(mine) == 1 and f":{line}: the image plane lies 0.001 mm before this flat " \
                               f"surface in one medium" in mine[0], notes


def test_image_after_a_drawn_only_dummy_keeps_the_dummy(tmp_path):
    """The same dummy ``_DELTA`` before focus, the image plane ``_DELTA`` after it (forwards):
    nothing to merge, the dummy is kept and the rays land on the axis at the focus."""
    text = _HEAD.format(aperture="ENPD 20") + _PARABOLOID.format(
        d_mirror=-(_F - _DELTA), d_dummy=-_DELTA)
    lens, notes = _loaded(write(tmp_path, text))
    assert len(lens.surfaces) == 3
    assert not any("whose fixed DIAM never clips" in n for n in notes), notes
    assert float(lens.z_sensor()) == pytest.approx(10.0 - _F, abs=1e-12)   # mirror at z 10
    assert float(_rim_landings(lens).abs().max()) < 1e-9


def test_image_before_a_clipping_dummy_after_a_mirror_stays_refused(tmp_path):
    """A dummy with a surface aperture (CLAP: it does clip) is no drawn-only plane: the image
    plane before it stays refused as before."""
    text = _HEAD.format(aperture="ENPD 20") + _PARABOLOID.format(
        d_mirror=-(_F + _DELTA), d_dummy=_DELTA).replace(
        "  DIAM 30 1 0 0 1 \"\"\n", "  DIAM 30 1 0 0 1 \"\"\n  CLAP 0 30 0\n")
    with pytest.raises(ZemaxFileError) as e:
        _loaded(write(tmp_path, text))
    assert "the image plane lies 0.001 mm before the last surface's vertex" in str(e.value)


# -------------------------------------- an image-space F-number on an entrance pupil at infinity
def _telecentric_relay(d2, aperture="FNUM 10 0"):
    """Two PARAXIAL lenses (f 25 and 40 mm), the object at the first's front focal plane, the
    stop at its back focal plane (the entrance pupil at infinity, not flagged by FTYP), the
    second lens ``d2`` mm after the stop."""
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "UNIT MM X W X CM MR CPMM", aperture,
        "FTYP 1 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 1", "WAVM 1 0.55 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  CURV 0", "  DISZ 25",
        "SURF 1", "  TYPE PARAXIAL", "  CURV 0", "  PARM 1 25", "  PARM 2 1", "  DISZ 25",
        "SURF 2", "  STOP", "  TYPE STANDARD", "  CURV 0", f"  DISZ {d2}",
        "SURF 3", "  TYPE PARAXIAL", "  CURV 0", "  PARM 1 40", "  PARM 2 1", "  DISZ 40",
        "SURF 4", "  TYPE STANDARD", "  CURV 0", "  DISZ 0"]) + "\n"


@pytest.mark.parametrize("d2", [40.0, 30.0])
def test_image_space_fnumber_on_a_pupil_at_infinity_is_refused_saying_why(tmp_path, d2):
    """Refused at the FNUM line (line 4), in one located line (no second file prefix), saying
    why OpticStudio's image-space F/# (EFL over the entrance-pupil diameter) sets no cone: with
    the second lens at its focal distance from the stop the relay is afocal (set 13's Offner
    relay); 30 mm from it, the EFL is the thin-lens pair's ``f1 f2 / (f1 + f2 - d)`` with
    ``d = 25 + 30``: 25 * 40 / 10 = 100 mm."""
    path = write(tmp_path, _telecentric_relay(d2))
    with pytest.raises(ZemaxFileError) as e:
        _loaded(path)
    msg = str(e.value)
    assert e.value.line == 4 and msg.count(str(path)) == 1 and "\n" not in msg, msg
    assert msg.startswith(f"{path}:4: FNUM: the entrance pupil is at infinity"), msg
    if d2 == 40.0:
        assert "the lens is afocal (EFL infinite)" in msg, msg
    else:
        f1, f2, d = 25.0, 40.0, 25.0 + d2
        efl = f1 * f2 / (f1 + f2 - d)
        assert f"(EFL {efl:.6g} mm over the entrance-pupil diameter)" in msg, msg
    assert msg.endswith("give the aperture as an object-space NA (OBNA)"), msg


# ------------------------------- a real image height that only a field beyond 90 deg reaches
def _clipped_ideal_lens(h):
    """A stop, then 10 mm on a PARAXIAL lens (f 10 mm, a fixed DIAM 10 mm: the floating aperture
    of a surface with power, which clips the aimed chief ray), the image at its focal plane: the
    chief ray of θ lands at ``f tan θ`` and meets the lens at ``10 tan θ``, so it is stopped from
    45 deg on, where it lands at 10 mm with the slope ``f sec² θ`` = 20 mm/rad."""
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "UNIT MM X W X CM MR CPMM", "ENPD 1",
        "RAIM 0 2 1 1 0 0 0 0 0", "FTYP 3 0 2 1 0 0 0", "XFLN 0 0", f"YFLN 0 {h!r}",
        "WAVM 1 0.55 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  CURV 0", "  DISZ INFINITY",
        "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0", "  DISZ 10",
        "SURF 2", "  TYPE PARAXIAL", "  CURV 0", "  PARM 1 10", "  PARM 2 1", "  DISZ 10",
        "  DIAM 10 1 0 0 1 \"\"",
        "SURF 3", "  TYPE STANDARD", "  CURV 0", "  DISZ 0"]) + "\n"


@pytest.mark.parametrize("h", [25.0, 30.0, 60.0])
def test_a_real_image_height_reached_only_beyond_90_deg_is_refused_saying_so(tmp_path, h):
    """Set 13's Nikon 6 mm fisheye asks for a real image height (11.61 mm) its chief ray reaches
    only near 110 deg; deeplens traces fields below 90 deg.  Still refused, and the message now
    says where the chief ray's slope at the last angle found would put the height: by the closed
    form, ``45 + (h - 10) / (20 π / 180)`` deg: 88.0 deg for 25 mm (below 90: no such tail),
    102.3 deg for 30 mm ("near 102 deg"), 188 deg for 60 mm (beyond OpticStudio's 180 deg:
    no such tail)."""
    with pytest.raises(ZemaxFileError) as e:
        _loaded(write(tmp_path, _clipped_ideal_lens(h)))
    msg = str(e.value)
    assert e.value.line == 6 and "\n" not in msg, msg
    assert "falls outside the clear aperture of SURF 2 (line " in msg, msg
    slope = 20.0 * math.pi / 180.0            # mm/deg at 45 deg
    est = 45.0 + (h - 10.0) / slope
    if not 90.0 <= est <= 180.0:
        assert "deeplens traces" not in msg, msg
    else:
        assert msg.endswith(f"; at the chief ray's rate there ({slope:.3g} mm/deg) the height "
                            f"lies near {est:.0f} deg, beyond the 90 deg deeplens traces (a "
                            f"fisheye's field)"), msg


# ---------------------------------------- a fixed DIAM beyond the edge of a sphere (R < DIAM)
def _hemisphere_lens(diam):
    """A stop, then a plano-convex lens whose front sphere (R 5 mm, n 1.5, model glass with no
    dispersion) carries a fixed DIAM ``diam``; 6 mm thick, flat back face."""
    return _HEAD.format(aperture="ENPD 4") + "".join([
        _surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
        _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 1"),
        _surf(2, "TYPE STANDARD", "CURV 0.2", "DISZ 6", "GLAS ___BLANK 1 0 1.5 1e9 0 0 0 0 0 0",
              f"DIAM {diam} 1 0 0 1 \"\""),
        _surf(3, "TYPE STANDARD", "CURV 0", "DISZ 10", "DIAM 5.3 1 0 0 1 \"\""),
        _surf(4, "TYPE STANDARD", "CURV 0", "DISZ 0")])


def test_a_fixed_diam_beyond_a_spheres_edge_is_read_at_the_edge(tmp_path):
    """Set 13's microscope objective (``ob_US03711186-2``: ``DIAM 1.59`` fixed on ``R`` 1.56 mm)
    was refused as a semi-diameter beyond the conic's domain.  A fixed DIAM on a surface with
    power is OpticStudio's floating aperture, and no ray meets a sphere beyond ``r = |R|``, so
    the aperture clips nothing the sphere keeps: read at the edge (5 mm here, to the rim's
    rounding band), one note at the DIAM line; the EFL is the plano-convex closed form
    ``R / (n - 1)`` = 10 mm.  A DIAM inside the edge is kept as written, with no note."""
    text = _hemisphere_lens(5.2)
    lens, notes = _loaded(write(tmp_path, text))
    front = lens.surfaces[1]
    assert float(front.semi_diameter) == pytest.approx(5.0, rel=4 * 2.0 ** -52)
    assert float(paraxial(lens).efl) == pytest.approx(5.0 / 0.5, rel=1e-12)
    line = text.splitlines().index('  DIAM 5.2 1 0 0 1 ""') + 1
    mine = [n for n in notes if "lies beyond the edge of its conic" in n]
    assert len(mine) == 1 and f":{line}: SURF 2: the fixed DIAM 5.2 (read as 5) " in mine[0], \
        notes

    lens, notes = _loaded(write(tmp_path, _hemisphere_lens(4.5)))
    assert float(lens.surfaces[1].semi_diameter) == 4.5
    assert not any("edge of its conic" in n for n in notes), notes
