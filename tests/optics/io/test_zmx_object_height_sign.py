"""Object-height fields (``FTYP 1``; ``FTYP 2`` at a finite object, through the object heights
``h' / m``) put each object point where the file puts it, ``(0, +h)``: OpticStudio's
convention, "Positive field angles imply positive slope for the ray in that direction, and thus
refer to negative coordinates on distant objects", object heights being the object's own
coordinates (OpticStudio User Guide, *Field Angles and Heights*,
https://ansyshelp.ansys.com/public/Views/Secured/Zemax/v251/en/OpticStudio_User_Guide/OpticStudio_Help/topics/Field_Angles_and_Heights.html).
So a height ``+h`` is the field angle ``-atan(h / (s + z_EP))``.  Until branch ``objsign`` an
untilted object read it mirrored (``y = -h``), which is the same system only where the lens is
symmetric under ``y -> -y``: on a decentred or tilted lens it traced another field point.

Checked on synthetic files written here (a singlet decentred, or tilted, between a coordinate
break pair, the stop before it so that both readers' paraxial entrance pupils are the stop):

* against optiland's global ray trace of the same file with its own object-height fields
  (``object_height``: the object point at ``(0, h)``): chief and pupil-rim rays of ``+h`` and
  ``-h`` land at the same global points.  Both traces are float64 through four surfaces; they
  agree to ~1e-14 mm, the mirrored reading misses by ~6 mm, so 1e-9 mm separates the two by
  far more than any rounding (angle fields, ``FTYP 0``, the control, agree to the same 1e-9);
* in closed form: an ideal thin lens (f 50 mm, object 150 mm, m = -1/2) decentred by ``δ``
  images the object point ``h`` at ``m h + (1 - m) δ`` (the point ``h - δ`` about its own axis,
  imaged to ``m (h - δ)``); every ray of the field meets there, the chief ray to 1e-9 mm;
* an erect relay (two ideal lenses, m = +1) given paraxial image heights (``FTYP 2``) lands
  the chief ray at ``+h'`` on its paraxial image (the mirrored reading: ``-h'``);
* ``.zmx``, JSON and CODE V ``YOB`` readings of the same object point agree, and a
  telecentric lens's heights round-trip through ``write_zmx``;
* the untilted reading is the limit of the tilted one (``TILTSURF``, tan 1e-9);
* real image heights (``FTYP 3``) on the decentred singlet land at their own signed heights,
  0 included, and where optiland's real-image-height fields land.

Planted bugs (tests/mutation/run_mutations.py): ``object_height_mirrored`` (the old sign put
back), ``codev_yob_mirrored``, ``ftyp3_axis_images_at_zero``.
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch

from deeplens.optics.frames import local_frames, to_global
from deeplens.optics.io import lens_from_dict, lens_to_dict, read_zmx
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.sampling import field_rays, object_point

W = 587.5618
N = 1.5
PUPIL = [(0.0, 0.0), (0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0)]
GLASS = f"___BLANK 1 0 {N} 0 0 0 0 0 0 0"


def _surf(typ="STANDARD", curv=0.0, disz=0.0, glas=None, parms=None, stop=False, diam=None):
    out = (["  STOP"] if stop else []) + [f"  TYPE {typ}", f"  CURV {curv!r}"]
    out += [f"  PARM {i} {v!r}" for i, v in enumerate(parms or (), start=1)]
    out.append(f"  DISZ {disz if isinstance(disz, str) else repr(disz)}")
    out += [f"  GLAS {glas}"] if glas else []
    out += [f'  DIAM {diam!r} 1 0 0 1 ""'] if diam is not None else []
    return out


def _file(blocks, ftyp, yfln, aperture="ENPD 8.0"):
    head = ["VERS 170912 299 123456", "MODE SEQ", "NAME sign", "UNIT MM X W X CM MR CPMM",
            aperture, f"FTYP {ftyp} 0 {len(yfln)} 1 0 0 0",
            "XFLN " + " ".join("0" for _ in yfln), "YFLN " + " ".join(repr(v) for v in yfln),
            "WAVM 1 0.5875618 1", "PWAV 1"]
    lines = []
    for k, b in enumerate(blocks):
        lines += [f"SURF {k}"] + b
    return "\n".join(head + lines) + "\n"


def singlet_file(ftyp=1, yfln=(0.0, 5.0, -5.0), decenter=2.0, tilt=0.0):
    """Object 100 mm before a flat stop; 10 mm on, a singlet (n 1.5, R ±50, 5 mm) decentred in
    y by ``decenter`` or tilted about x by ``tilt`` (deg) between a break pair (the second,
    order flag 1, returns the frame); the image plane 60 mm after it."""
    return _file([_surf(disz=100.0), _surf(disz=10.0, stop=True),
                  _surf("COORDBRK", parms=[0.0, decenter, tilt, 0.0, 0.0, 0]),
                  _surf(curv=1 / 50, disz=5.0, glas=GLASS, diam=15.0),
                  _surf(curv=-1 / 50, disz=0.0, diam=15.0),
                  _surf("COORDBRK", disz=60.0, parms=[0.0, -decenter, -tilt, 0.0, 0.0, 1]),
                  _surf(diam=40.0)], ftyp, list(yfln))


def _read(tmp_path, text, name="t.zmx"):
    p = tmp_path / name
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return p, read_zmx(p).double()


def _landings(lens, fields=None):
    """Global landing points ``[(len(PUPIL), 3)]`` per field of the chief ray and the rim rays
    of the paraxial entrance pupil (apertures ignored)."""
    par = paraxial(lens)
    xy = torch.tensor(PUPIL, dtype=torch.float64) * 0.5 * float(par.entrance_pupil_diameter)
    out = []
    with torch.no_grad():
        for f in lens.spec.fields_deg if fields is None else fields:
            r = lens.trace_to_sensor(field_rays(lens, f, W, xy, float(par.entrance_pupil_z)),
                                     options=TraceOptions(clip_aperture=False))
            assert bool(r.valid.all())
            out.append(to_global(local_frames(lens)[-1], r.o))
    return out


def _optiland_landings(path, fields):
    """optiland's global landing points of the same rays, each field ``(0, v)`` in the file's
    own field type (normalised by the largest), z from the first surface after the object."""
    pytest.importorskip("optiland")
    from optiland.fileio import load_zemax_file
    from optiland.materials import AbbeMaterial, IdealMaterial

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        optic = load_zemax_file(str(path))
        for s in optic.surface_group.surfaces:
            if isinstance(s.material_post, AbbeMaterial):   # V_d = 0: NaN in optiland
                s.material_post = IdealMaterial(n=N)
        sg = optic.surface_group
        z1 = float(torch.as_tensor(sg.surfaces[1].geometry.cs.z))
        top = max(abs(v) for v in fields)
        out = []
        for v in fields:
            pts = []
            for px, py in PUPIL:
                optic.trace_generic(0.0, v / top, px, py, W / 1000.0)
                sg = optic.surface_group
                x, y, z = (float(torch.as_tensor(c)[-1].reshape(-1)[0]) for c in (sg.x, sg.y, sg.z))
                pts.append([x, y, z - z1])
            out.append(torch.tensor(pts, dtype=torch.float64))
    return out


# ------------------------------------------------------------------ against optiland's trace
@pytest.mark.parametrize("decenter,tilt", [(2.0, 0.0), (0.0, 5.0)], ids=["decentred", "tilted"])
@pytest.mark.parametrize("ftyp,yfln", [(1, (0.0, 5.0, -5.0)), (0, (0.0, 2.5, -2.5))],
                         ids=["object-height", "angle"])
def test_fields_land_where_optilands_do_on_an_asymmetric_lens(tmp_path, decenter, tilt, ftyp,
                                                              yfln):
    path, lens = _read(tmp_path, singlet_file(ftyp, yfln, decenter, tilt))
    ours, theirs = _landings(lens), _optiland_landings(path, yfln)
    for v, a, b in zip(yfln, ours, theirs):
        assert a.reshape(-1).tolist() == pytest.approx(b.reshape(-1).tolist(), abs=1e-9), (
            ftyp, v)
    if ftyp == 1:
        # +5 mm is the object point (0, +5): its chief ray falls towards the axis
        d = 100.0 + float(paraxial(lens).entrance_pupil_position)
        assert lens.spec.fields_deg[1] == pytest.approx(-math.degrees(math.atan(5.0 / d)),
                                                        rel=1e-12)
        # the lens is not symmetric under y -> -y: the axial object point images off the axis
        assert abs(float(ours[0][0, 1])) > 0.3
        # and the mirrored reading (+h at y = -h) lands the +h chief ray millimetres away
        assert abs(float(ours[1][0, 1]) - float(ours[2][0, 1])) > 5.0


# ------------------------------------------------------------------------ closed forms
def _ideal(f, disz, decenter=0.0):
    """An ideal thin lens of focal length ``f`` (``PARAXIAL``), decentred in y by a break pair."""
    lens = [_surf("PARAXIAL", parms=[f, 1], disz=0.0, diam=30.0)]
    if not decenter:
        return [lens[0][:-2] + [f"  DISZ {disz!r}", lens[0][-1]]]
    return [_surf("COORDBRK", parms=[0.0, decenter, 0.0, 0.0, 0.0, 0]), *lens,
            _surf("COORDBRK", disz=disz, parms=[0.0, -decenter, 0.0, 0.0, 0.0, 1])]


@pytest.mark.parametrize("h", [5.0, -5.0, 3.0])
def test_a_decentred_ideal_lens_images_the_object_point_where_the_closed_form_puts_it(tmp_path,
                                                                                      h):
    """f 50 mm, the object 150 mm before it (100 to the stop, 50 on), m = -1/2, the image 75 mm
    after it; decentred by 2 mm: the object point ``(0, h)`` images to ``m h + (1 - m) δ``."""
    f, s, delta = 50.0, 150.0, 2.0
    m, s_img = -f / (s - f), s * f / (s - f)
    text = _file([_surf(disz=100.0), _surf(disz=50.0, stop=True), *_ideal(f, s_img, delta),
                  _surf(diam=40.0)], 1, [0.0, h])
    _, lens = _read(tmp_path, text)
    want = m * h + (1 - m) * delta
    pts = _landings(lens)[1]
    # every ray of the field meets at the image point (an ideal lens), the chief ray first
    assert pts[:, 1].tolist() == pytest.approx([want] * len(PUPIL), abs=1e-9)
    assert pts[:, 0].tolist() == pytest.approx([0.0] * len(PUPIL), abs=1e-9)
    # the mirrored reading would land at the image of (0, -h): 2 |m h| away
    assert abs(want - (-m * h + (1 - m) * delta)) == pytest.approx(abs(h), rel=1e-12)


def test_paraxial_image_heights_of_an_erect_relay_land_at_the_files_heights(tmp_path):
    """Two ideal lenses (f 50 mm, then f 25 mm 150 mm later), the object 100 mm before the first
    (the stop on it): the intermediate image 100 mm after it (m1 = -1), 50 mm before the second,
    which images it again 50 mm behind itself (m2 = -f2 / (s2 - f2) = -1): the whole is erect,
    m = m1 m2 = +1.  ``FTYP 2`` heights ``h'`` are the object heights ``h' / m``: the chief ray
    lands at ``+h'`` on the paraxial image (the mirrored reading lands at ``-h'``)."""
    f1, f2, gap = 50.0, 25.0, 150.0
    s2 = gap - 100.0                      # the intermediate image 100 mm after lens 1
    s2_img = s2 * f2 / (s2 - f2)
    m = (-1.0) * (-f2 / (s2 - f2))
    assert m == 1.0
    text = _file([_surf(disz=100.0), [*_ideal(f1, gap)[0][:-2], "  STOP", f"  DISZ {gap!r}",
                                      '  DIAM 30.0 1 0 0 1 ""'],
                  *_ideal(f2, s2_img), _surf(diam=40.0)], 2, [0.0, 3.0, -2.0])
    _, lens = _read(tmp_path, text)
    for v, pts in zip([0.0, 3.0, -2.0], _landings(lens)):
        assert pts[:, 1].tolist() == pytest.approx([v] * len(PUPIL), abs=1e-9)


# ------------------------------------------------------------ the other readers and writers
def test_json_and_codev_readings_place_the_same_object_point(tmp_path):
    """The object point of a 5 mm object height is ``(0, +5)`` however the lens was read: the
    ``.zmx`` file, its JSON round trip, and CODE V's ``YOB`` of the same singlet."""
    from deeplens.optics.io.codev import read_seq

    _, lens = _read(tmp_path, singlet_file(1, (0.0, 5.0), decenter=0.0))
    back = lens_from_dict(lens_to_dict(lens))
    for ln in (lens, back):
        z_ep = float(paraxial(ln).entrance_pupil_z)
        q = object_point(ln, math.radians(ln.spec.fields_deg[1]), z_ep, 100.0)
        assert q[:2].tolist() == pytest.approx([0.0, 5.0], abs=1e-12)
    seq = tmp_path / "s.seq"
    seq.write_text("RDM\nLEN\nTIT 'sign'\nDIM M\nWL 587.5618\nEPD 8\nYOB 0 5\nSO 0 100\n"
                   "S 0 10\n  STO\nS 50 5 NBK7_SCHOTT\nS -50 60\nSI 0 0\nGO\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cv = read_seq(seq)
    z_ep = float(paraxial(cv).entrance_pupil_z)
    q = object_point(cv, math.radians(cv.spec.fields_deg[1]), z_ep, 100.0)
    assert q[:2].tolist() == pytest.approx([0.0, 5.0], abs=1e-12)


def test_telecentric_object_heights_round_trip_through_write_zmx(tmp_path):
    """An object-space telecentric file (``FTYP 1 1``) with heights 0, 4, -6: the object points
    are ``(0, h)`` (``y = -s tan θ``), and ``write_zmx`` writes the same heights back."""
    from deeplens.optics.io import write_zmx

    text = _file([_surf(disz=100.0), _surf(curv=1 / 50, disz=5.0, glas=GLASS, diam=15.0),
                  _surf(disz=50.0, stop=True, diam=15.0), _surf(diam=40.0)], 1,
                 [0.0, 4.0, -6.0], aperture="OBNA 0.05 0").replace("FTYP 1 0 ", "FTYP 1 1 ")
    _, lens = _read(tmp_path, text)
    assert lens.object_telecentric
    s = float(lens.spec.object_distance_mm)
    ys = [-s * math.tan(math.radians(f)) for f in lens.spec.fields_deg]
    assert ys == pytest.approx([0.0, 4.0, -6.0], abs=1e-12)
    write_zmx(lens, tmp_path / "back.zmx")
    yfln = [ln for ln in (tmp_path / "back.zmx").read_text().splitlines()
            if ln.startswith("YFLN")][0]
    assert [float(v) for v in yfln.split()[1:]] == pytest.approx([0.0, 4.0, -6.0], abs=1e-12)
    _, again = _read(tmp_path, (tmp_path / "back.zmx").read_text(), "again.zmx")
    assert again.spec.fields_deg == pytest.approx(lens.spec.fields_deg, abs=1e-12)


# ------------------------------------------------------------------ real image heights
def test_real_image_heights_on_a_decentred_lens_land_at_the_files_heights(tmp_path):
    """``FTYP 3`` (real image height: "the real ray coordinates of the primary wavelength chief
    ray on the image surface") on the decentred singlet, whose axial field images 2.4 mm off the
    axis: each field's chief ray lands at its own signed height, 0 included (before branch
    ``objsign``: the angle of ``|v|`` with the sign of ``v``, 0 for 0: -3 landed at +1.87, 0 at
    +2.43), and where optiland's real-image-height field lands it (its image frame is the global
    one here: the break pair returns the frame at the last vertex, 1e-9 mm)."""
    from deeplens.optics.io.zmx_system import chief_height

    heights = (0.0, 3.0, -3.0, 1.0)
    path, lens = _read(tmp_path, singlet_file(3, heights, decenter=2.0))
    assert abs(chief_height(lens, 0.0)) > 2.0        # not symmetric under y -> -y
    for v, a in zip(heights, lens.spec.fields_deg):
        assert chief_height(lens, a) == pytest.approx(v, abs=1e-9)
    ours, theirs = _landings(lens), _optiland_landings(path, heights)
    for v, a, b in zip(heights, ours, theirs):
        assert a[0].tolist() == pytest.approx(b[0].tolist(), abs=1e-9), v


def test_real_image_heights_of_a_symmetric_lens_are_the_signed_angles_of_their_sizes(tmp_path):
    """On the centred singlet the solved angles are odd in the height, bit for bit (the old
    ``copysign(angle(|v|), v)``): a symmetric lens's numbers do not change."""
    _, lens = _read(tmp_path, singlet_file(3, (0.0, 3.0, -3.0), decenter=0.0))
    a = lens.spec.fields_deg
    assert a[0] == 0.0 and a[1] > 0 and a[2] == -a[1]


def test_the_untilted_reading_is_the_limit_of_the_tilted_one(tmp_path):
    """An object plane tilted about x by tan 1e-9 (``TILTSURF``) and the untilted one give the
    same field angles to ~1e-9 relative: the rule is continuous at zero tilt (before branch
    ``objsign`` the sign flipped there)."""
    def text(tilt):
        obj = (_surf("TILTSURF", parms=[0.0, tilt], disz=100.0) if tilt else _surf(disz=100.0))
        return _file([obj, _surf(disz=10.0, stop=True),
                      _surf(curv=1 / 50, disz=5.0, glas=GLASS, diam=15.0),
                      _surf(curv=-1 / 50, disz=60.0, diam=15.0), _surf(diam=40.0)],
                     1, [0.0, 5.0, -5.0])

    _, flat = _read(tmp_path, text(0.0), "flat.zmx")
    _, tilted = _read(tmp_path, text(1e-9), "tilted.zmx")
    assert tilted.object_tilt == (0.0, 1e-9)
    assert flat.spec.fields_deg[1] < 0 < flat.spec.fields_deg[2]
    assert tilted.spec.fields_deg == pytest.approx(flat.spec.fields_deg, rel=1e-8, abs=1e-12)
