"""An entrance pupil at infinity that the file does not flag (issue 37, set 11).

A PARAXIAL lens of focal length f with the object at its front focal plane and the stop at its
back focal plane: the ray parallel to the axis meets the stop at height 0, so the entrance
pupil is at infinity and object space is telecentric whatever ``FTYP`` says.  With an ``OBNA``
aperture the reader sets ``Lens.object_telecentric`` with one note at the ``OBNA`` line; an
``ENPD`` (a diameter of a pupil at infinity) is refused there.  Checked by closed forms: each
field's chief ray leaves parallel to the axis and crosses the stop's centre, the axial rim ray
leaves at ``asin(NA)`` and meets the stop at ``f tan(asin NA)`` (a ray from the front focal
point leaves an ideal lens parallel at that height).
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch

from deeplens.optics.io import ZemaxFileError, read_zmx
from deeplens.optics.lens import Lens, LensSpec
from deeplens.optics.materials import get_material
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import PupilAtInfinityError, paraxial
from deeplens.optics.sampling import field_rays
from deeplens.optics.surfaces import Aperture, IdealLens

F, NA = 25.0, 0.13


def _file(aperture=f"OBNA {NA} 0", ftyp="FTYP 1 0 3 1 0 0 0"):
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "UNIT MM X W X CM MR CPMM", aperture,
        ftyp, "XFLN 0 0 0", "YFLN 0 1 2", "WAVM 1 0.55 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  CURV 0", f"  DISZ {F}",
        "SURF 1", "  TYPE PARAXIAL", "  CURV 0", f"  PARM 1 {F}", "  PARM 2 1",
        f"  DISZ {F}", "  DIAM 10 1 0 0 1 \"\"",
        "SURF 2", "  STOP", "  TYPE STANDARD", "  CURV 0", "  DISZ 40", "  DIAM 5 0 0 0 1 \"\"",
        "SURF 3", "  TYPE PARAXIAL", "  CURV 0", "  PARM 1 40", "  PARM 2 1",
        "  DISZ 40", "  DIAM 10 1 0 0 1 \"\"",
        "SURF 4", "  TYPE STANDARD", "  CURV 0", "  DISZ 0", "  DIAM 5 0 0 0 1 \"\""]) + "\n"


def _write(tmp_path, text):
    path = tmp_path / "t.zmx"
    path.write_text(text)
    return path


def test_unflagged_pupil_at_infinity_loads_telecentric_with_one_note(tmp_path):
    path = _write(tmp_path, _file())
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        lens = read_zmx(path)
    notes = [str(r.message) for r in rec if "entrance pupil is at infinity" in str(r.message)]
    assert len(notes) == 1 and notes[0].startswith(f"{path}:4: ")   # the OBNA line
    assert "object-space telecentric" in notes[0]
    assert lens.object_telecentric
    assert lens.spec.fields_deg[0] == 0.0 and len(lens.spec.fields_deg) == 3

    par = paraxial(lens)
    z_ep, w = float(par.entrance_pupil_z), 550.0
    k = lens.stop_index
    r_stop = F * math.tan(math.asin(NA))   # closed form: f tan θ from the front focal point
    assert float(lens.stop.semi_diameter) == pytest.approx(r_stop, rel=1e-12)
    # every field's chief ray: parallel to the axis in object space, through the stop centre
    for fd in lens.spec.fields_deg:
        rays = field_rays(lens, fd, w, torch.zeros(1, 2, dtype=lens.dtype), z_ep)
        assert float(rays.d[0, :2].abs().max()) < 1e-15
        _, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
        assert float(hits[k][0, :2].abs().max()) < 1e-12
    # the axial rim ray of the pupil: object-space angle asin(NA), meets the stop's rim
    r_ep = 0.5 * float(par.entrance_pupil_diameter)
    rim = field_rays(lens, 0.0, w, torch.tensor([[0.0, r_ep]], dtype=lens.dtype), z_ep)
    angle = math.atan2(math.hypot(float(rim.d[0, 0]), float(rim.d[0, 1])), float(rim.d[0, 2]))
    assert angle == pytest.approx(math.asin(NA), abs=1e-14)
    out, hits = lens.trace(rim, options=TraceOptions(clip_aperture=False), record=True)
    assert float(hits[k][0, 1].abs()) == pytest.approx(r_stop, rel=1e-12)


def test_unflagged_pupil_at_infinity_refuses_a_pupil_diameter(tmp_path):
    with pytest.raises(ZemaxFileError, match=r":4: ENPD: the entrance pupil is at infinity .*"
                                             r"give the aperture as an object-space NA"):
        read_zmx(_write(tmp_path, _file(aperture="ENPD 2")))


def test_paraxial_names_the_pupil_at_infinity_not_an_image_of_the_object():
    """A finite object at the front focal plane, the stop at the back one, not flagged: the
    message says the entrance pupil is at infinity (set Lens.object_telecentric); flagged, the
    lens builds and its stop is sized from the cone (NA 0.13 -> f tan(asin NA))."""
    air = get_material("AIR")

    def build(tele):
        surfaces = [IdealLens(F, 10.0), Aperture(5.0)]
        spec = LensSpec(object_distance_mm=F, aperture_type="epd",
                        aperture_value=2 * (F + F) * math.tan(math.asin(NA)), fields_deg=[0.0],
                        wavelengths_nm=[550.0])
        return Lens(surfaces, [air, air, air], [0.0, F], 40.0, 1, spec=spec,
                    object_telecentric=tele)

    with pytest.raises(PupilAtInfinityError) as e:
        build(False)
    assert "entrance pupil is at infinity" in str(e.value)
    assert "Lens.object_telecentric" in str(e.value)
    assert "image of the object" not in str(e.value)
    lens = build(True)
    assert float(lens.stop.semi_diameter) == pytest.approx(F * math.tan(math.asin(NA)),
                                                           rel=1e-12)


def test_telecentric_fields_with_the_object_on_a_coordinate_break_are_refused_at_ftyp(tmp_path):
    """A tilted COORDBRK at the object (object distance 0 to the first surface deeplens keeps):
    a telecentric field is named by its direction from that vertex, which does not exist; a
    located refusal at the FTYP line (before: an unlocated ZeroDivisionError)."""
    text = _file().replace(f"SURF 0\n  TYPE STANDARD\n  CURV 0\n  DISZ {F}\n",
                           "SURF 0\n  TYPE STANDARD\n  CURV 0\n  DISZ 0\n"
                           "SURF 1\n  TYPE COORDBRK\n  CURV 0\n  PARM 1 0\n  PARM 2 0\n"
                           f"  PARM 3 -5\n  PARM 4 0\n  PARM 5 0\n  PARM 6 0\n  DISZ {F}\n")
    for k in (4, 3, 2):   # renumber the blocks after the inserted one
        text = text.replace(f"SURF {k}\n", f"SURF {k + 1}\n")
    text = text.replace("SURF 1\n  TYPE PARAXIAL", "SURF 2\n  TYPE PARAXIAL")
    with pytest.raises(ZemaxFileError, match=r":5: object-space telecentric fields with the "
                                             r"object on the first surface"):
        read_zmx(_write(tmp_path, text))
