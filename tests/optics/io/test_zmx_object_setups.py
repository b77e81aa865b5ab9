"""Object set-ups of real OpticStudio files: a tilted object plane (``SURF 0`` a ``TILTSURF``,
OpticStudio's *Tilted* surface ``z = x tan θ_x + y tan θ_y``, "useful for implementing tilted
object and image surfaces": OpticStudio User Guide, *Tilted*) and an object at ``DISZ 0`` before
a ``COORDBRK`` (the object at the break's pivot, in the object's frame: a break is a dummy
surface no ray meets).  Checked against closed forms (the object point on the plane; an ideal
thin lens imaging a tilted plane onto the Scheimpflug plane ``tan θ' = m tan θ``; one real ray
through a sphere by hand) and against each other (an object at a tilting break's pivot is the
same physical point as on the equivalent tilted object plane: the chief rays land together).
"""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import line_of, write

from deeplens.optics.errors import ZemaxFileError
from deeplens.optics.io import lens_from_dict, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.lens import Lens, LensSpec
from deeplens.optics.materials import Air
from deeplens.optics.paraxial import paraxial
from deeplens.optics.prescription import prescription
from deeplens.optics.rays import Rays
from deeplens.optics.sampling import field_rays, object_point
from deeplens.optics.surfaces import CoordinateBreak, IdealLens

F64 = torch.float64
SINGLET = ["SURF {k}", "  STOP", "  TYPE STANDARD", "  CURV 0.04", "  DISZ 6",
           "  GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0", "  DIAM 8 1 0 0 1 \"\"",
           "SURF {k1}", "  TYPE STANDARD", "  CURV -0.04", "  DISZ 46", "  DIAM 8 1 0 0 1 \"\"",
           "SURF {k2}", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 30 1 0 0 1 \"\""]


def _text(obj, *, ftyp="FTYP 1 0 2 1 0 0 0", xfln="XFLN 0 0", yfln="YFLN 0 10",
          aperture="ENPD 10"):
    """A singlet (n 1.5, R ±25 mm, the stop on its front vertex) after the ``obj`` blocks
    (``SURF 0`` and any breaks), as a ``.zmx`` text."""
    k = sum(1 for ln in obj if ln.startswith("SURF"))
    body = [ln.format(k=k, k1=k + 1, k2=k + 2) for ln in SINGLET]
    return "\n".join(["VERS 170912 299 123456", "MODE SEQ", "NAME object set-up",
                      "UNIT MM X W X CM MR CPMM", aperture, ftyp, xfln, yfln, "WAVM 1 0.55 1",
                      "PWAV 1", *obj, *body]) + "\n"


def _tilted(tan_y="-1", d0="50", extra=()):
    return ["SURF 0", "  TYPE TILTSURF", "  CURV 0.0", "  PARM 1 0", f"  PARM 2 {tan_y}",
            *extra, f"  DISZ {d0}"]


def _at_break(alpha_deg, d=100):
    return ["SURF 0", "  TYPE STANDARD", "  DISZ 0", "SURF 1", "  TYPE COORDBRK", "  CURV 0.0",
            "  PARM 1 0", "  PARM 2 0", f"  PARM 3 {alpha_deg!r}", "  PARM 4 0", "  PARM 5 0",
            "  PARM 6 0", f"  DISZ {d}"]


# ---------------------------------------------------------------- a tilted object plane
def test_tilted_object_puts_each_field_point_on_its_plane(tmp_path):
    """``TILTSURF`` object, ``tan θ_y = -1``, 50 mm before the stop (the entrance pupil on the
    first vertex): the 10 mm object height lies at ``(0, 10, -50 - 10)``, and its field angle is
    that point's chief ray through the pupil's centre, ``-atan(10 / 60)`` (a positive height is
    a negative angle: the tilted plane is not symmetric under ``y -> -y``)."""
    lens = read_zmx(write(tmp_path, _text(_tilted())))
    assert lens.object_tilt == (0.0, -1.0)
    assert lens.spec.fields_deg[0] == 0.0
    assert lens.spec.fields_deg[1] == pytest.approx(-math.degrees(math.atan(10 / 60)), rel=1e-12)
    z_ep = float(paraxial(lens).entrance_pupil_z)
    assert z_ep == pytest.approx(0.0, abs=1e-12)
    q = object_point(lens, math.radians(lens.spec.fields_deg[1]), z_ep, 50.0)
    assert q.tolist() == pytest.approx([0.0, 10.0, -60.0], abs=1e-12)
    # first-order data do not depend on the tilt: the same EFL and pupil as the untilted file
    flat = read_zmx(write(tmp_path, _text(_tilted("0")), "flat.zmx"))
    assert flat.object_tilt == (0.0, 0.0)
    for a, b in [(paraxial(lens).efl, paraxial(flat).efl),
                 (paraxial(lens).entrance_pupil_diameter, paraxial(flat).entrance_pupil_diameter)]:
        assert float(a) == float(b)


def test_a_real_ray_from_a_tilted_object_point_matches_the_hand_trace(tmp_path):
    """One ray from the tilted plane's field point through the pupil point ``(0.7, 2)``: the
    object point from the closed form, the sphere ``R = 25`` hit by the quadratic, then vector
    Snell's law into ``n = 1.5``; deeplens' trace of the first surface lands there."""
    lens = read_zmx(write(tmp_path, _text(_tilted("0.3", d0="40"), yfln="YFLN 0 -6"))).to(F64)
    s, ty, h, R, mu = 40.0, 0.3, -6.0, 25.0, 1.0 / 1.5
    q = torch.tensor([0.0, h, -s + ty * h], dtype=F64)          # on z = -s + tan_y y
    th = lens.spec.fields_deg[1]
    assert th == pytest.approx(-math.degrees(math.atan(h / (s - ty * h))), rel=1e-12)
    p = torch.tensor([0.7, 2.0, 0.0], dtype=F64)
    rays = field_rays(lens, th, 550.0, p[:2].reshape(1, 2), 0.0)
    d = (p - q) / torch.linalg.vector_norm(p - q)
    assert rays.d[0].tolist() == pytest.approx(d.tolist(), abs=1e-14)
    c = torch.tensor([0.0, 0.0, R], dtype=F64)                  # the sphere's centre
    oc = q - c
    b = float(oc @ d)
    t = -b - math.sqrt(b * b - float(oc @ oc - R * R))          # the near crossing
    x = q + t * d
    nrm = (x - c) / R                                           # against the ray
    cos_i = -float(nrm @ d)
    cos_t = math.sqrt(1 - mu * mu * (1 - cos_i * cos_i))
    d2 = mu * d + (mu * cos_i - cos_t) * nrm
    n = lens.indices(torch.tensor(550.0, dtype=F64))
    out = lens.trace_surface(0, rays, n[0], n[1], lens.z_vertices())
    assert bool(out.valid[0])
    assert out.o[0].tolist() == pytest.approx(x.tolist(), abs=1e-10)
    assert out.d[0].tolist() == pytest.approx(d2.tolist(), abs=1e-12)


@pytest.mark.parametrize("ty", [0.4, -0.7])
def test_an_ideal_lens_images_a_tilted_plane_onto_the_scheimpflug_plane(ty):
    """An ideal thin lens (f = 50 mm) and an object plane 150 mm before it with slope ``tan_y``:
    each field's rays (meridional and sagittal pupil points) meet in one image point, and the
    image points lie on the plane through the axial image (75 mm behind) of slope ``m tan_y``,
    ``m = -f / (s - f) = -1/2`` (Scheimpflug; exact for a thin lens, a collineation)."""
    f, s = 50.0, 150.0
    lens = Lens([IdealLens(f, 40.0)], [Air(), Air()], [0.0], 75.0, 0,
                spec=LensSpec(object_distance_mm=s, fields_deg=[0.0, 3.0, -5.0, 8.0])).to(F64)
    lens.object_tilt = (0.0, ty)
    m = -f / (s - f)
    pupil = torch.tensor([[0.0, -3.0], [0.0, 4.0], [-2.5, 0.0], [3.0, 0.0]], dtype=F64)
    for th in lens.spec.fields_deg:
        out = lens.trace(field_rays(lens, th, 550.0, pupil, 0.0))
        assert bool(out.valid.all())
        (o1, o2), (d1, d2) = out.o[:2], out.d[:2]   # the two meridional rays
        t = float((o2[1] - o1[1]) * d2[2] - (o2[2] - o1[2]) * d2[1]) / float(
            d1[1] * d2[2] - d1[2] * d2[1])
        img = o1 + t * d1
        for k in range(4):                          # every ray passes through it
            r = out.o[k] + (img[2] - out.o[k, 2]) / out.d[k, 2] * out.d[k]
            assert r.tolist() == pytest.approx(img.tolist(), abs=1e-9)
        assert float(img[2]) - 75.0 == pytest.approx(m * ty * float(img[1]), abs=1e-9)
    q = object_point(lens, math.radians(8.0), 0.0, s)
    assert float(q[2]) == pytest.approx(-s + ty * float(q[1]), abs=1e-12)


def test_a_tilted_image_plane_loads_flat_with_a_note_that_says_so(tmp_path):
    """OpticStudio's sample images its tilted object onto a tilted image plane (``TILTSURF``,
    the Scheimpflug plane); deeplens' sensor is flat: the file loads with a located note that
    names the tangents and says that off-axis spots are the flat plane's."""
    text = _text(_tilted()).replace(
        "SURF 3\n  TYPE STANDARD\n  CURV 0.0\n",
        "SURF 3\n  TYPE TILTSURF\n  CURV 0.0\n  PARM 1 0\n  PARM 2 1.27\n")
    with pytest.warns(UserWarning, match=rf"t\.zmx:{line_of(text, 'SURF 3')}: the image surface "
                                         rf"is a tilted plane \(TILTSURF, tangents 0, 1\.27\): "
                                         rf"deeplens' sensor is flat"):
        lens = read_zmx(write(tmp_path, text))
    assert float(lens.d_sensor) == 46.0


def test_tilted_object_round_trips_through_zmx_and_json(tmp_path):
    lens = read_zmx(write(tmp_path, _text(_tilted("0.3", d0="40"), yfln="YFLN 0 -6 4")))
    back = read_zmx(write_zmx(lens, tmp_path / "w.zmx") or tmp_path / "w.zmx")
    assert back.object_tilt == lens.object_tilt
    assert back.spec.fields_deg == pytest.approx(lens.spec.fields_deg, rel=1e-12)
    again = lens_from_dict(lens_to_dict(lens))
    assert again.object_tilt == lens.object_tilt == (0.0, 0.3)
    assert prescription(lens)[0]["extra"] == "tan_x=0, tan_y=0.3"


@pytest.mark.parametrize("obj,edit,needle,match", [
    (_tilted(d0="INFINITY"), None, "DISZ INFINITY", r"a tilted object plane \(TILTSURF\) at "
                                                   r"infinity"),
    (_tilted(extra=("PARM 3 1",)), None, "PARM 3", r"SURF 0: TILTSURF PARM 3 = 1 is not read \(PARM 1 and 2 are the x and y "
                                   r"tangents of the tilted object plane\)"),
    (_tilted(), ("XFLN 0 0", "XFLN 0 2"), "XFLN", r"XFLN: x field components with an object "
                                                  r"plane tilted about x"),
    (_tilted(), ("FTYP 1 0", "FTYP 3 0"), "FTYP", r"FTYP 3 \(real image height\) with an object "
                                                  r"plane tilted"),
    (["SURF 0", "  TYPE STANDARD", "  CURV 0.01", "  DISZ 50"], None, "SURF 0",
     r"must be a flat STANDARD surface or a tilted plane \(TILTSURF\)"),
])
def test_tilted_object_refusals_name_their_line(tmp_path, obj, edit, needle, match):
    text = _text(obj)
    if edit:
        text = text.replace(*edit)
    with pytest.raises(ZemaxFileError, match=rf"t\.zmx:{line_of(text, needle)}: .*{match}"):
        read_zmx(write(tmp_path, text))


# ---------------------------------------------------------------- an object at a break's pivot
@pytest.mark.parametrize("alpha", [20.0, -35.0])
def test_object_at_a_tilting_break_is_the_tilted_plane_seen_from_the_lens(tmp_path, alpha):
    """Object at ``DISZ 0`` before a ``COORDBRK`` tilting by ``α`` about x, 100 mm before the
    singlet: the object lies at the break's pivot in the object's frame, so its 3 mm height is
    the point ``(0, 3 cos α, -3 sin α)`` of the lens's frame (``x' = R_x(α)^T x``), on the
    plane of slope ``-tan α`` 100 mm before the lens: the file with that ``TILTSURF`` object (the
    height ``3 cos α``) puts its field point there, and the rays from the two points through the
    stop's centre (the chief ray's line, built by hand in each object frame) land together."""
    h = 3.0
    a = read_zmx(write(tmp_path, _text(_at_break(alpha), yfln=f"YFLN 0 {h!r}"))).to(F64)
    assert a.spec.object_distance_mm == 0.0 and isinstance(a.surfaces[0], CoordinateBreak)
    assert a.spec.fields_deg[1] == pytest.approx(-math.degrees(math.atan(h / 100)), rel=1e-12)
    qa = object_point(a, math.radians(a.spec.fields_deg[1]),
                      float(paraxial(a).entrance_pupil_z), 0.0)
    assert qa.tolist() == pytest.approx([0.0, h, 0.0], abs=1e-12)   # in the object's frame
    # a real object at the pivot: the wavefront's rays start on it, their paths from it 0
    from deeplens.analysis.wavefront import launch

    z_ep = paraxial(a).entrance_pupil_z
    w = launch(a, a.spec.fields_deg[1], 550.0, torch.tensor([[0.0, 1.0], [2.0, -1.0]], dtype=F64),
               z_ep)
    assert float((w.o - qa).abs().max()) < 1e-12
    assert w.opl.abs().max() < 1e-12
    al = math.radians(alpha)
    b = read_zmx(write(tmp_path, _text(_tilted(repr(-math.tan(al)), d0="100"),
                                       yfln=f"YFLN 0 {h * math.cos(al)!r}"), "b.zmx")).to(F64)
    qb = object_point(b, math.radians(b.spec.fields_deg[1]),
                      float(paraxial(b).entrance_pupil_z), 100.0)
    assert qb.tolist() == pytest.approx([0.0, h * math.cos(al), -100.0 - h * math.sin(al)],
                                        abs=1e-12)
    for x, y in [(paraxial(a).efl, paraxial(b).efl),
                 (paraxial(a).entrance_pupil_diameter, paraxial(b).entrance_pupil_diameter)]:
        assert float(x) == pytest.approx(float(y), rel=1e-12)
    # the stop's centre: 100 mm along the turned axis R_x(α) e_z (a's object frame), the origin
    # of b's frame; one ray from each field point through it, traced to each image plane
    stop_a = torch.tensor([0.0, -100.0 * math.sin(al), 100.0 * math.cos(al)], dtype=F64)
    land = []
    for lens, q, c in [(a, qa, stop_a), (b, qb, torch.zeros(3, dtype=F64))]:
        d = (c - q) / torch.linalg.vector_norm(c - q)
        out = lens.trace_to_sensor(Rays(q.reshape(1, 3), d.reshape(1, 3), 550.0))
        assert bool(out.valid[0])
        land.append(out.o[0, :2])     # (a's vertices lie 100 mm further along its z)
    assert abs(float(land[0][1])) > 0.1
    assert land[0].tolist() == pytest.approx(land[1].tolist(), abs=1e-9)


def test_object_at_a_break_round_trips_and_stays_refused_on_a_real_surface(tmp_path):
    lens = read_zmx(write(tmp_path, _text(_at_break(20.0), yfln="YFLN 0 3")))
    write_zmx(lens, tmp_path / "w.zmx")
    back = read_zmx(tmp_path / "w.zmx")
    assert back.spec.object_distance_mm == 0.0
    assert back.spec.fields_deg == pytest.approx(lens.spec.fields_deg, rel=1e-12)
    again = lens_from_dict(lens_to_dict(lens))
    assert again.spec.object_distance_mm == 0.0
    # without the break the object lies on the singlet's front vertex: refused as before
    text = _text(["SURF 0", "  TYPE STANDARD", "  DISZ 0"])
    with pytest.raises(ZemaxFileError, match=r"the object lies on the first surface deeplens "
                                             r"traces \(SURF 1\)"):
        read_zmx(write(tmp_path, text, "r.zmx"))
    with pytest.raises(ValueError, match=r"object distance 0 puts the object on surface 0 "
                                         r"\(a IdealLens\)"):
        Lens([IdealLens(50.0, 10.0)], [Air(), Air()], [0.0], 100.0, 0,
             spec=LensSpec(object_distance_mm=0.0))


def _parabola_at_90(tilt="-90"):
    """A point source at the focus of a paraboloid mirror (R = -200 mm, k = -1), the frame
    turned by ``tilt`` degrees about x between them (OpticStudio's "90 degree parabolas"
    sample): the beam leaves the source across the mirror's axis and meets it off axis."""
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "NAME parabola at 90", "UNIT MM X W X CM MR CPMM",
        "FLOA", "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0", "WAVM 1 0.55 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  DISZ 0",
        "SURF 1", "  TYPE COORDBRK", "  CURV 0.0", f"  PARM 3 {tilt}", "  DISZ 100",
        "SURF 2", "  TYPE STANDARD", "  CURV -0.005", "  CONI -1", "  DISZ -300",
        "  GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0", "  DIAM 320 1 0 0 1 \"\"",
        "SURF 3", "  STOP", "  TYPE STANDARD", "  DISZ -10", "  DIAM 300 1 0 0 1 \"\"",
        "SURF 4", "  TYPE STANDARD", "  DISZ 0", "  DIAM 300 1 0 0 1 \"\""]) + "\n"


def test_a_paraboloid_lit_across_its_axis_from_its_focus_collimates_along_it(tmp_path):
    """The traced axis crosses the mirror's frame (it never reaches the vertex): it leaves along
    the local axis turned round (the parity rule), so the -300 mm after the mirror is real
    propagation (before, refused as against the direction of travel), with a located warning;
    every ray from the focus, both halves of the pupil (the half heading away from the vertex
    plane, which meets the steep rim travelling against the axis) and the centre (parallel to
    the vertex plane, d_z ~ 6e-17), meets the paraboloid and leaves it along -z (its closed
    form, to 1e-12); the hits lie on the paraboloid ``z = -r² / 400``."""
    text = _parabola_at_90()
    with pytest.warns(UserWarning, match=rf"t\.zmx:{line_of(text, 'SURF 2')}: SURF 2: the "
                                         rf"beam's axis meets this mirror edge-on"):
        lens = read_zmx(write(tmp_path, text))
    lens = lens.to(F64)
    assert lens.directions() == [1, 1, -1, -1]
    p = paraxial(lens)
    # (the paraxial pupil, 300 mm wide 50 mm from the source, is a ±72° cone; these points
    # span ±17° about the beam's centre, every one meeting the mirror within its 320 mm)
    pupil = torch.tensor([[0.0, -0.05], [0.0, -0.02], [0.01, -0.04], [-0.02, -0.015],
                          [0.0, 0.0], [0.0, 0.05], [0.0, 0.02], [0.01, 0.04], [-0.02, 0.015]],
                         dtype=F64)
    rays = field_rays(lens, 0.0, 550.0, pupil * float(p.entrance_pupil_diameter),
                      float(p.entrance_pupil_z))
    n = lens.indices(torch.tensor(550.0, dtype=F64))
    z = lens.z_vertices()
    for i in range(2):
        rays = lens.trace_surface(i, rays, n[i], n[i + 1], z)
    assert bool(rays.valid.all())
    x, y, zz = (rays.o - torch.tensor([0.0, 0.0, float(z[1])], dtype=F64)).unbind(-1)
    assert float((zz + (x * x + y * y) / 400.0).abs().max()) < 1e-10
    assert float(y.max()) < -140.0   # the off-axis segment, below the axis
    # the centre ray, across the frame from the focus: (0, -200, -100) (|y| = 2 f, z = -f)
    assert [float(x[4]), float(y[4]), float(zz[4])] == pytest.approx([0.0, -200.0, -100.0],
                                                                     abs=1e-9)
    want = torch.tensor([0.0, 0.0, -1.0], dtype=F64).expand_as(rays.d)
    assert float((rays.d - want).abs().max()) < 1e-12


def _distance_to_lines(q, rays):
    """Distances ``(M,)`` from the point ``q`` to the lines of ``rays``."""
    v = q - rays.o
    along = (v * rays.d).sum(-1, keepdim=True) * rays.d
    return torch.linalg.vector_norm(v - along, dim=-1)


def test_every_launcher_starts_a_field_from_its_point_on_the_tilted_plane(tmp_path):
    """``field_rays``, ``normalized_rays`` (paraxial aiming; field and pupil in x and y) and the
    wavefront's ``launch`` draw each field's rays from its point on the tilted object plane
    (``object_points``: on the chief line through the pupil centre and on ``z = z_obj + tan_x x
    + tan_y y``), not from the untilted plane."""
    from deeplens.analysis.wavefront import launch
    from deeplens.optics.normalized import normalized_rays
    from deeplens.optics.sampling import object_points

    lens = read_zmx(write(tmp_path, _text(_tilted("0.3", d0="40"), yfln="YFLN 0 -6"))).to(F64)
    lens.object_tilt = (-0.2, 0.3)
    th = lens.spec.fields_deg[1]
    z_ep = float(paraxial(lens).entrance_pupil_z)
    r_ep = 0.5 * float(paraxial(lens).entrance_pupil_diameter)
    xy = torch.tensor([[0.0, 0.0], [1.5, -2.0], [-3.0, 1.0]], dtype=F64)
    q = object_point(lens, math.radians(th), z_ep, 40.0)
    assert float(q[2]) == pytest.approx(-40.0 + 0.3 * float(q[1]), abs=1e-12)
    assert _distance_to_lines(q, field_rays(lens, th, 550.0, xy, z_ep)).max() < 1e-9
    assert _distance_to_lines(q, launch(lens, th, 550.0, xy, torch.tensor(z_ep))).max() < 1e-9
    hx, hy = 0.4, -0.8                       # a field with both components, in units of |th|
    tan = torch.tan(torch.deg2rad(torch.tensor([[hx, hy]], dtype=F64) * abs(th)))
    qn = object_points(lens, tan, z_ep, 40.0)[0]
    assert float(qn[2]) == pytest.approx(-40.0 - 0.2 * float(qn[0]) + 0.3 * float(qn[1]),
                                         abs=1e-12)
    rays = normalized_rays(lens, (hx, hy), xy / r_ep, 550.0, aim="paraxial")
    assert _distance_to_lines(qn, rays).max() < 1e-9


def test_a_cone_beyond_90_degrees_is_refused_saying_why(tmp_path):
    """``OBNA 160 1`` (a 160° half-angle cone: a source inside a reflector): the rays beyond 90°
    leave the object backwards, which deeplens' object-space rays (forwards, at an entrance
    pupil) cannot carry: refused at the ``OBNA`` line in one line that says so."""
    text = _text(["SURF 0", "  TYPE STANDARD", "  DISZ 100"], aperture="OBNA 160 1",
                 ftyp="FTYP 0 0 1 1 0 0 0", yfln="YFLN 0")
    with pytest.raises(ZemaxFileError, match=rf"t\.zmx:{line_of(text, 'OBNA')}: OBNA 160 \(cone "
                                             rf"angle\): must be below 90 degrees; a wider cone "
                                             rf"sends rays backwards from the object"):
        read_zmx(write(tmp_path, text))


@pytest.mark.parametrize("obj", [_tilted("0.3", d0="40"), _at_break(20.0)])
def test_codev_seq_refuses_what_it_cannot_carry(tmp_path, obj):
    """A CODE V ``.seq`` file has no tilted object plane and no object thickness 0: the writer
    refuses both (before, the object at a break's pivot was written as ``SO`` thickness 0,
    which the reader refuses)."""
    from deeplens.optics.errors import LensFileError
    from deeplens.optics.io.codev import write_seq

    text = _text(obj).replace("GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0",
                              "GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0")
    lens = read_zmx(write(tmp_path, text))
    with pytest.raises(LensFileError, match=r"tilted object plane|coordinate break's pivot"):
        write_seq(lens, tmp_path / "o.seq")


@pytest.mark.parametrize("tan_y", [1.0, -1.0])
def test_a_tilted_plane_mirror_across_the_frame_reflects_about_its_own_normal(tan_y):
    """The edge-on rule is for an axis normal to the mirror's vertex normal only: a tilted plane
    mirror (``TILTSURF``, ``z = y tan_y``) that an axis crossing the frame meets at 45° reflects
    it about the plane's normal ``(0, tan_y, -1)/√2``, which sends it along ``tan_y z`` (the
    parity rule would say -z for both), as OpticStudio's Twyman-Green sample needs."""
    from deeplens.optics.frames import mirrors_met_edge_on, travel_directions
    from deeplens.optics.surfaces import XYPolynomial

    brk = CoordinateBreak(tilt_x=math.radians(90.0))
    mirror = XYPolynomial(10.0, [0.0, tan_y, 0.0])
    a = brk.rotation(torch.zeros((), dtype=F64)).T @ torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    assert abs(float(a[2])) < 1e-12                       # across the frame after the break
    nrm = torch.tensor([0.0, tan_y, -1.0], dtype=F64) / math.sqrt(2.0)
    out = a - 2.0 * (a @ nrm) * nrm
    signs = travel_directions([brk, mirror], [1])
    assert signs[-1] == (1 if float(out[2]) > 0 else -1) == int(tan_y)
    assert mirrors_met_edge_on([brk, mirror], [1]) == []
