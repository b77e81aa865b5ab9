"""Mirrors in the sequential tracer: the reflection law, Zemax's sign convention (negative
distances after a mirror), paraxial data with ``n' = -n``, folds through coordinate breaks,
gradients through a mirror, and the JSON / Zemax round trips.

Closed forms used: a paraboloid ``z = c r^2 / 2`` (conic -1) brings every ray parallel to its
axis to its focus ``R / 2`` exactly (any aperture, also an off-axis section); a sphere's paraxial
focal length is ``|R| / 2``; a plane mirror at 45 degrees turns the axis by 90 degrees.
"""

from __future__ import annotations

import math

import pytest
import torch
from helpers import fd_with_error

from deeplens.optics.errors import LensError
from deeplens.optics.frames import local_frames, to_global
from deeplens.optics.io import lens_from_dict, lens_to_dict, load_lens, save_lens
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, get_material
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.reflect import reflect
from deeplens.optics.surfaces import Aperture, Asphere, CoordinateBreak, Plane

F64 = torch.float64
W = 587.5618


def parallel_rays(y, x=None, z0=-5.0, direction=(0.0, 0.0, 1.0)):
    """Rays at heights ``y`` (and ``x``) in the plane ``z0``, all along ``direction``."""
    y = torch.as_tensor(y, dtype=F64)
    x = torch.zeros_like(y) if x is None else torch.as_tensor(x, dtype=F64)
    o = torch.stack([x, y, torch.full_like(y, z0)], -1)
    d = torch.tensor(direction, dtype=F64)
    d = (d / d.norm()).expand_as(o)
    return Rays(o, d, torch.full(y.shape, W, dtype=F64))


def grid(r_max, n=9, cy=0.0):
    """A square grid of ray heights within a disk of radius ``r_max`` centred at ``(0, cy)``."""
    t = torch.linspace(-r_max, r_max, n, dtype=F64)
    X, Y = torch.meshgrid(t, t, indexing="ij")
    keep = X * X + Y * Y <= r_max * r_max
    return X[keep], Y[keep] + cy


def telescope(R=-1000.0, conic=-1.0, sd=60.0, d_sensor=None):
    """A stop 10 mm before one concave mirror (radius ``R`` < 0, at z = 10), sensor at its
    paraxial focus ``R / 2`` (negative: the light returns towards -z)."""
    air = Air()
    return Lens([Aperture(sd), Asphere(1.0 / R, sd, conic=conic)], [air, air, air],
                [0.0, 10.0], R / 2 if d_sensor is None else d_sensor, 0, mirrors=[1])


def newtonian(f=500.0, a=100.0, tilt_deg=45.0):
    """Paraboloid of focal length ``f`` at z = 10, a flat 45-degree fold ``f - a`` before its
    focus (between two coordinate breaks, Zemax's layout), the image ``a`` from the fold."""
    air = Air()
    t = math.radians(tilt_deg)
    surfaces = [Aperture(60.0), Asphere(-1.0 / (2 * f), 60.0, conic=-1.0),
                CoordinateBreak(tilt_x=t), Plane(30.0), CoordinateBreak(tilt_x=t)]
    return Lens(surfaces, [air] * 6, [0.0, 10.0, -(f - a), 0.0, 0.0], a, 0, mirrors=[1, 3],
                name="Newtonian")


# ---------------------------------------------------------------------------- the law
def test_reflection_law_closed_form():
    th = torch.linspace(-1.4, 1.4, 15, dtype=F64)
    d = torch.stack([torch.sin(th), torch.zeros_like(th), torch.cos(th)], -1)
    ok = torch.ones_like(th, dtype=torch.bool)
    for n in ((0.0, 0.0, -1.0), (0.0, 0.0, 1.0)):  # either orientation of the normal
        dr, v = reflect(d, torch.tensor(n, dtype=F64).expand_as(d), ok)
        want = torch.stack([torch.sin(th), torch.zeros_like(th), -torch.cos(th)], -1)
        assert torch.allclose(dr, want, atol=1e-15, rtol=0)
        assert bool(v.all())
    # a general normal: equal angles, coplanar, unit length
    g = torch.Generator().manual_seed(0)
    d = torch.nn.functional.normalize(torch.randn(64, 3, generator=g, dtype=F64), dim=-1)
    n = torch.nn.functional.normalize(torch.randn(64, 3, generator=g, dtype=F64), dim=-1)
    dr, _ = reflect(d, n, torch.ones(64, dtype=torch.bool))
    assert torch.allclose((dr * n).sum(-1), -(d * n).sum(-1), atol=1e-15)
    assert torch.allclose(dr.norm(dim=-1), torch.ones(64, dtype=F64), atol=1e-15)
    assert torch.allclose((torch.linalg.cross(d, n) * dr).sum(-1), torch.zeros(64, dtype=F64),
                          atol=1e-15)
    # invalid rays keep their direction
    dr, v = reflect(d, n, torch.zeros(64, dtype=torch.bool))
    assert torch.equal(dr, d) and not bool(v.any())


# ---------------------------------------------------------------------------- one mirror
@pytest.mark.parametrize("R", [-1000.0, -250.0, 400.0])
def test_spherical_mirror_paraxial_focal_length(R):
    """EFL = |R|/2 for a concave mirror (-|R|/2, diverging, for a convex one); the paraxial
    image lies R/2 along z from the vertex (before it: light returns towards -z)."""
    lens = telescope(R=R, conic=0.0, sd=10.0, d_sensor=-1.0)
    p = paraxial(lens)
    assert float(p.efl) == pytest.approx(-R / 2 if R < 0 else -R / 2, rel=1e-14)
    assert float(p.bfl) == pytest.approx(R / 2, rel=1e-14)
    assert float(p.image_z) == pytest.approx(10.0 + R / 2, rel=1e-14)
    assert float(p.efl) * R < 0  # concave (R < 0 facing +z light) converges
    if R < 0:  # real near-axis rays focus there too (spherical aberration ~ h^2 / R)
        lens = telescope(R=R, conic=0.0)
        out = lens.trace_to_sensor(parallel_rays([1e-3, -2e-3]))
        assert bool(out.valid.all())
        assert out.o[:, 1].abs().max() < 1e-9
        assert torch.all(out.d[:, 2] < 0)  # travelling towards -z after the mirror


def test_paraboloid_focuses_every_ray_to_one_point():
    lens = telescope(R=-1000.0, conic=-1.0)
    x, y = grid(58.0, 15)
    out = lens.trace_to_sensor(parallel_rays(y, x))
    assert bool(out.valid.all()) and out.o.shape[0] > 100
    assert out.o[:, :2].abs().max() < 1e-12  # f = R/2 exactly, any aperture
    assert torch.allclose(out.o[:, 2], torch.full_like(out.o[:, 2], 10.0 - 500.0), atol=1e-12)
    # the optical path to the focus is the same for every ray (a perfect point)
    assert (out.opl.max() - out.opl.min()) < 1e-10
    # the same aperture on a sphere does not focus (the test can tell them apart)
    sph = telescope(R=-1000.0, conic=0.0)
    assert sph.trace_to_sensor(parallel_rays(y, x)).o[:, :2].abs().max() > 1e-2


def test_off_axis_parabola():
    """An off-axis section (beam centred 100 mm off the parent's axis, as an OAP is cut) still
    focuses perfectly on the parent's focus, off the beam's axis."""
    air = Air()
    R, off = -800.0, 100.0
    lens = Lens([Aperture(130.0), Asphere(1.0 / R, 130.0, conic=-1.0)], [air] * 3,
                [0.0, 20.0], R / 2, 0, mirrors=[1])
    x, y = grid(25.0, 11, cy=off)
    out = lens.trace_to_sensor(parallel_rays(y, x))
    assert bool(out.valid.all())
    assert out.o[:, :2].abs().max() < 1e-12
    # the reflected beam's centre ray leaves at the angle 2 atan(off / (2 f)) to the axis
    centre = lens.trace_to_sensor(parallel_rays([off]))
    f = -R / 2
    assert float(torch.atan2(-centre.d[0, 1], -centre.d[0, 2])) == pytest.approx(
        2 * math.atan(off / (2 * f)), rel=1e-12)
    # the same section described the Zemax way: the beam on its own axis, a coordinate break
    # decentring the parent parabola by -100 mm; the focus is then 100 mm below the beam axis
    lens2 = Lens([Aperture(30.0), CoordinateBreak(dy=-off, semi_diameter=30.0),
                  Asphere(1.0 / R, 130.0, conic=-1.0)], [air] * 4, [0.0, 10.0, 0.0], R / 2, 0,
                 mirrors=[2])
    x, y = grid(25.0, 11)
    out2 = lens2.trace_to_sensor(parallel_rays(y, x))
    assert bool(out2.valid.all()) and out2.o[:, :2].abs().max() < 1e-12
    g = to_global(local_frames(lens2)[-1], out2.o)
    want = torch.tensor([0.0, -off, 10.0 + R / 2], dtype=F64)  # the parent's focus
    assert torch.allclose(g, want.expand_as(g), atol=1e-11)


# ---------------------------------------------------------------------------- a fold
def test_newtonian_image_position_closed_form():
    f, a = 500.0, 100.0
    lens = newtonian(f, a)
    assert lens.directions() == [1, 1, -1, -1, 1, 1]
    p = paraxial(lens)
    assert float(p.efl) == pytest.approx(f, rel=1e-14)
    assert float(p.image_z) == pytest.approx(float(lens.z_sensor()), abs=1e-12)
    x, y = grid(55.0, 11)
    out = lens.trace_to_sensor(parallel_rays(y, x))
    assert bool(out.valid.all())
    assert out.o[:, :2].abs().max() < 1e-12  # the fold keeps the perfect focus
    assert torch.all(out.d[:, 2] > 0)  # after two mirrors the light travels +z again
    # in space: the fold mirror sits f - a before the primary on the axis; its normal is
    # R_x(45 deg) e_z = (0, -1/sqrt 2, 1/sqrt 2), which turns the -z beam to -y
    g = to_global(local_frames(lens)[-1], out.o)
    want = torch.tensor([0.0, -a, 10.0 - (f - a)], dtype=F64)
    assert torch.allclose(g, want.expand_as(g), atol=1e-11)
    # the global direction of the axial ray is -y
    axial = lens.trace_to_sensor(parallel_rays([0.0]))
    gd = to_global((local_frames(lens)[-1][0], torch.zeros(3, dtype=F64)), axial.d)
    assert torch.allclose(gd[0], torch.tensor([0.0, -1.0, 0.0], dtype=F64), atol=1e-12)
    # a small field angle: image height f tan(theta) in the image plane (paraxial limit)
    th = 1e-4
    ch = lens.trace_to_sensor(parallel_rays([0.0], direction=(0.0, math.sin(th),
                                                              math.cos(th))))
    assert float(ch.o[0, 1].abs()) == pytest.approx(f * math.tan(th), rel=1e-6)


def test_fold_reverse_trace_returns_the_rays():
    """Backward tracing through the breaks and mirrors undoes the forward trace."""
    lens = newtonian()
    x, y = grid(40.0, 5)
    rays = parallel_rays(y, x, direction=(0.0, 0.002, 1.0))
    out = lens.trace(rays)
    back = Rays(out.o, -out.d, out.wavelength, out.valid, out.opl, normalize=False)
    ret = lens.trace(back, reverse=True)
    start = lens.propagate_to_z(ret, torch.tensor(-5.0, dtype=F64))
    assert bool(start.valid.all())
    assert torch.allclose(start.o, rays.o, atol=1e-10)
    assert torch.allclose(-start.d, rays.d, atol=1e-12)


def test_sign_convention_is_checked():
    air = Air()
    with pytest.raises(LensError, match=r"sensor distance must be < 0 mm \(after 1 mirror\)"):
        telescope(d_sensor=500.0)
    with pytest.raises(LensError, match=r"distance before surface 2 is positive \(5 mm\).*-z"):
        Lens([Aperture(10.0), Asphere(-1e-3, 10.0), Plane(10.0)], [air] * 4, [0.0, 1.0, 5.0],
             -1.0, 0, mirrors=[1])
    with pytest.raises(LensError, match="medium after it must be the medium before"):
        Lens([Asphere(-1e-3, 10.0)], [air, get_material("N-BK7")], [0.0], -1.0, 0, mirrors=[0])
    with pytest.raises(LensError, match="cannot be a mirror"):
        Lens([Aperture(10.0)], [air, air], [0.0], -1.0, 0, mirrors=[0])


# ---------------------------------------------------------------------------- gradients
def _check_grad(lens, p, fn, h):
    """The autograd gradient against a fourth-order central difference, within the difference's
    own error estimate (:func:`helpers.fd_with_error`), which must be small enough (1e-5 of the
    derivative) for the comparison to mean something."""
    p.requires_grad_(True)
    (g,) = torch.autograd.grad(fn(), p)
    p.requires_grad_(False)
    fd, err = fd_with_error(fn, p, h)
    assert abs(fd) > 1e-6, "a constant loss checks nothing"
    assert err < 1e-5 * abs(fd), "the finite difference is too noisy to check anything"
    assert abs(float(g) - fd) <= err + 1e-12 * abs(fd)


@pytest.mark.parametrize("which", ["c", "k", "distance", "fold"])
def test_gradients_through_a_mirror_match_finite_differences(which):
    lens = newtonian()
    mirror = lens.surfaces[1]
    with torch.no_grad():
        mirror.k.fill_(-1.3)  # a hyperboloid: every derivative non-trivial
    x, y = grid(45.0, 5)
    rays = parallel_rays(y, x, direction=(0.001, 0.003, 1.0))
    wgt = torch.linspace(0.5, 1.5, x.numel(), dtype=F64)

    def loss():
        out = lens.trace_to_sensor(rays)
        assert bool(out.valid.all())
        return (wgt * (out.o[:, 0] ** 2 + out.o[:, 1] ** 2 + 0.3 * out.o[:, 1])).sum()

    p, h = {"c": (mirror.c, 1e-8), "k": (mirror.k, 1e-4), "distance": (lens.distances[2], 1e-3),
            "fold": (lens.surfaces[2].tilt_x, 1e-5)}[which]
    _check_grad(lens, p, loss, h)


def test_paraxial_gradient_through_a_mirror():
    lens = telescope(R=-600.0, conic=0.0, sd=10.0, d_sensor=-1.0)
    c = lens.surfaces[1].c
    _check_grad(lens, c, lambda: paraxial(lens).efl, 1e-9)


# ---------------------------------------------------------------------------- files
def test_json_round_trip_of_a_fold(tmp_path):
    lens = newtonian()
    d = lens_to_dict(lens)
    assert [s["material"] for s in d["surfaces"]][1:4] == ["MIRROR", "AIR", "MIRROR"]
    assert d["surfaces"][2]["type"] == "coordinate_break"
    save_lens(lens, tmp_path / "newt.json")
    back = load_lens(tmp_path / "newt.json")
    assert lens_to_dict(back) == d
    assert back.mirrors == lens.mirrors
    rays = parallel_rays(*reversed(grid(40.0, 5)))
    assert torch.equal(back.trace_to_sensor(rays).o, lens.trace_to_sensor(rays).o)
    d["sensor"]["distance_mm"] = -100.0
    with pytest.raises(ValueError, match=r"sensor\.distance_mm.*must be > 0 mm after 2 mirrors"):
        lens_from_dict(d)


def cassegrain():
    """A classical Cassegrain (paraboloid primary, hyperboloid secondary), no breaks."""
    air = Air()
    R1, R2, sep, back = -2000.0, -800.0, -700.0, 1200.0  # EFL 4000 mm, image 500 behind
    return Lens([Asphere(1 / R1, 100.0, conic=-1.0), Asphere(1 / R2, 30.0, conic=-2.7)],
                [air] * 3, [0.0, sep], back, 0, mirrors=[0, 1], name="Cassegrain")


def test_zemax_round_trip_of_mirrors(tmp_path):
    lens = cassegrain()
    write_zmx(lens, tmp_path / "cass.zmx")
    text = (tmp_path / "cass.zmx").read_text()
    assert text.count("GLAS MIRROR") == 2
    back = read_zmx(tmp_path / "cass.zmx")
    assert back.mirrors == lens.mirrors == frozenset({0, 1})
    assert [float(v) for v in back.distances] == [float(v) for v in lens.distances]
    assert float(back.d_sensor) == float(lens.d_sensor)
    # two thin mirrors: 1/F = 1/f1 + 1/f2 - d/(f1 f2), f1 = 1000 (concave), f2 = -400 (convex),
    # d = 700: F = 4000 mm
    assert float(paraxial(lens).efl) == pytest.approx(4000.0, rel=1e-14)
    assert float(paraxial(back).efl) == pytest.approx(float(paraxial(lens).efl), rel=1e-14)
    rays = parallel_rays(torch.linspace(30.0, 90.0, 7))
    assert torch.allclose(back.trace_to_sensor(rays).o, lens.trace_to_sensor(rays).o,
                          atol=1e-12)

def test_zemax_round_trip_of_a_fold(tmp_path):
    """A Newtonian (paraboloid, 45-degree fold between coordinate breaks) written as COORDBRK
    surfaces and read back: the same prescription (bit for bit, tilts included) and the same
    image in space."""
    lens = newtonian(tilt_deg=44.0)
    write_zmx(lens, tmp_path / "newt.zmx")
    text = (tmp_path / "newt.zmx").read_text()
    assert text.count("TYPE COORDBRK") == 2 and text.count("GLAS MIRROR") == 2
    back = read_zmx(tmp_path / "newt.zmx")
    a, b = lens_to_dict(lens), lens_to_dict(back)
    a.pop("name"), b.pop("name")
    assert b == a
    rays = parallel_rays(*reversed(grid(40.0, 5)))
    ga = to_global(local_frames(lens)[-1], lens.trace_to_sensor(rays).o)
    gb = to_global(local_frames(back)[-1], back.trace_to_sensor(rays).o)
    assert torch.equal(ga, gb)


# Zemax's own layout of a single-mirror telescope as OpticStudio writes it (GLAS MIRROR with
# its placeholder numbers, the negative thickness after the mirror to the image)
_ZMX_PARABOLA = """VERS 190513 80 123457 L123457
MODE SEQ
NAME F/5 PARABOLA
UNIT MM X W X CM MR CPMM
ENPD 200
GCAT SCHOTT
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.55 1
PWAV 1
SURF 0
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ 100
  DIAM 100 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV -0.0005 0 0 0 0 ""
  CONI -1
  GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0
  DISZ -1000
  DIAM 100 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ 0
  DIAM 1 0 0 0 1 ""
"""


def test_zemax_mirror_file_loads(tmp_path):
    p = tmp_path / "parabola.zmx"
    p.write_text(_ZMX_PARABOLA)
    lens = read_zmx(p)
    assert lens.mirrors == frozenset({1})
    assert float(lens.d_sensor) == -1000.0
    pd = paraxial(lens)
    assert float(pd.efl) == pytest.approx(1000.0, rel=1e-14)
    assert float(pd.entrance_pupil_diameter) == pytest.approx(200.0, rel=1e-12)
    assert float(pd.fno) == pytest.approx(5.0, rel=1e-12)
    x, y = grid(99.0, 9)
    out = lens.trace_to_sensor(parallel_rays(y, x))
    assert bool(out.valid.all()) and out.o[:, :2].abs().max() < 1e-12


def test_compiled_options_run_a_folded_lens_eagerly():
    """The compiled kernels refract only: a lens with mirrors or breaks runs the eager path
    under ``compile=...`` and gives the eager result bit for bit."""
    from deeplens.optics.options import TraceOptions

    lens = newtonian()
    assert lens.folded()
    rays = parallel_rays(*reversed(grid(40.0, 5)))
    eager = lens.trace_to_sensor(rays)
    comp = lens.trace_to_sensor(rays, options=TraceOptions(compile=True))
    assert torch.equal(comp.o, eager.o) and torch.equal(comp.valid, eager.valid)


def test_newton_path_for_rays_travelling_minus_z():
    """Intersections after a mirror (rays towards -z): the Newton path (``closed_form=False``,
    paper Eq. 7) agrees with the closed form, and an aspheric mirror (always Newton) gets the
    finite-difference gradient of its a4 term."""
    from deeplens.optics.options import TraceOptions

    lens = cassegrain()
    x, y = grid(90.0, 7)
    rays = parallel_rays(y, x, direction=(0.0, 0.002, 1.0))
    a = lens.trace_to_sensor(rays)
    b = lens.trace_to_sensor(rays, options=TraceOptions(closed_form=False))
    assert bool(a.valid.all()) and torch.equal(a.valid, b.valid)
    assert torch.allclose(a.o, b.o, atol=1e-10, rtol=0)
    air = Air()
    asph = Lens([Asphere(-1 / 2000.0, 100.0, conic=-1.0),
                 Asphere(-1 / 800.0, 30.0, conic=-2.7, coefficients=[2e-10])],
                [air] * 3, [0.0, -700.0], 1200.0, 0, mirrors=[0, 1])
    a4 = asph.surfaces[1].a[0]
    wgt = torch.linspace(0.5, 1.5, x.numel(), dtype=F64)

    def loss():
        out = asph.trace_to_sensor(rays)
        assert bool(out.valid.all())
        return (wgt * out.o[:, 1]).sum()

    _check_grad(asph, a4, lambda: loss(), 1e-13)


def test_coordinate_break_order_flags_undo_each_other():
    """Zemax's convention: a break with order flag 1 and the negated values undoes an order-0
    break (tilts about x, y and z together), for rays and for the global frames."""
    v = {1: 1.5, 2: -2.5, 3: 7.0, 4: -11.0, 5: 23.0}
    a = CoordinateBreak.from_zemax({**v, 6: 0})
    b = CoordinateBreak.from_zemax({k: -x for k, x in v.items()} | {6: 1})
    assert (a.order, b.order) == (0, 1)
    g = torch.Generator().manual_seed(1)
    x = torch.randn(16, 3, generator=g, dtype=F64) * 10
    d = torch.nn.functional.normalize(torch.randn(16, 3, generator=g, dtype=F64), dim=-1)
    z = torch.tensor(3.0, dtype=F64)
    x1, d1 = a.to_next(x, d, z)
    assert not torch.allclose(x1, x)
    x2, d2 = b.to_next(x1, d1, z)
    assert torch.allclose(x2, x, atol=1e-12) and torch.allclose(d2, d, atol=1e-15)
    xb, db = a.to_previous(x1, d1, z)
    assert torch.allclose(xb, x, atol=1e-12) and torch.allclose(db, d, atol=1e-15)
    # the same pair inside a lens: the frames after it are the frame before it
    air = Air()
    b.semi_diameter.fill_(1.0)
    lens = Lens([Aperture(5.0), a, b, Plane(5.0)], [air] * 5, [0.0, 3.0, 0.0, 2.0], 10.0, 0)
    A, bb = local_frames(lens)[-1]
    assert torch.allclose(A, torch.eye(3, dtype=F64), atol=1e-15)
    assert torch.allclose(bb, torch.zeros(3, dtype=F64), atol=1e-12)
    # and a JSON round trip keeps the order flag
    back = lens_from_dict(lens_to_dict(lens))
    assert [s.order for s in back.surfaces[1:3]] == [0, 1]


def test_zemax_mirror_inside_glass(tmp_path):
    """A mirror on the back of a glass plate (as a Mangin mirror is written): the medium after
    the mirror is the glass again (Zemax takes it from the surface before), a normal ray's
    optical path is 2 n t in the glass, and a tilted ray leaves at its incidence angle."""
    head = _ZMX_PARABOLA[:_ZMX_PARABOLA.index("SURF 1\n")].replace("ENPD 200", "FLOA")
    tail = _ZMX_PARABOLA[_ZMX_PARABOLA.index("SURF 3\n") + len("SURF 3"):]
    text = head + """SURF 1
  STOP
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0
  DISZ 5
  DIAM 10 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0
  DISZ -5
  DIAM 10 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ -10
  DIAM 10 1 0 0 1 ""
SURF 4""" + tail
    p = tmp_path / "mangin.zmx"
    p.write_text(text)
    lens = read_zmx(p)
    assert lens.mirrors == frozenset({1})
    assert lens.materials[2] is lens.materials[1] and lens.materials[1].to_spec() == "N-BK7"
    n = float(lens.materials[1].n(torch.tensor(W, dtype=F64)))  # the rays' wavelength
    rays = parallel_rays([0.0, 3.0], z0=0.0, direction=(0.0, 0.1, 1.0))
    out = lens.trace(rays)
    assert bool(out.valid.all())
    d_in = rays.d[0]
    assert torch.allclose(out.d, torch.stack([d_in[0], d_in[1], -d_in[2]]).expand(2, 3),
                          atol=1e-15)
    normal = lens.trace(parallel_rays([0.0], z0=0.0))
    assert float(normal.opl[0]) == pytest.approx(2 * n * 5.0, rel=1e-14)


def test_zemax_image_plane_side_follows_the_direction_of_travel(tmp_path):
    """After one mirror light travels towards -z: a positive thickness to the image puts the
    image plane *before* the mirror's vertex (refused with the line and the mirror count); a
    flat mirror with the image on its vertex gets the sensor 1e-9 mm behind it, along -z."""
    p = tmp_path / "wrong_side.zmx"
    p.write_text(_ZMX_PARABOLA.replace("DISZ -1000", "DISZ 1000"))
    with pytest.raises(ZemaxFileError, match=r"wrong_side\.zmx:\d+: the image plane lies 1000 mm "
                                             r"before .*towards -z.*after 1 mirror"):
        read_zmx(p)
    p = tmp_path / "on_vertex.zmx"   # a window after the mirror, the image on its flat back
    p.write_text(_ZMX_PARABOLA.replace("DISZ -1000", "DISZ -990").replace("SURF 3\n", """SURF 3
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0
  DISZ -2
  DIAM 30 1 0 0 1 ""
SURF 4
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ 0
  DIAM 30 1 0 0 1 ""
SURF 5
"""))
    with pytest.warns(UserWarning, match="on the last"):
        lens = read_zmx(p)
    assert float(lens.d_sensor) == -1e-9


def test_afocal_periscope(tmp_path):
    """Two parallel 45-degree flat mirrors (a periscope, as optiland's fold files): no paraxial
    power, so EFL, BFL and F/# are infinite while the entrance pupil is the stop; the light
    leaves parallel to where it came from, displaced by the mirrors' separation (closed form).
    Read from Zemax it loads; with fields given as paraxial image heights (which need a finite
    focal length) it is refused at the FTYP line."""
    air, t = Air(), math.radians(45.0)
    lens = Lens([Aperture(5.0), CoordinateBreak(tilt_x=t), Plane(8.0), CoordinateBreak(tilt_x=t),
                 CoordinateBreak(tilt_x=-t), Plane(8.0), CoordinateBreak(tilt_x=-t)],
                [air] * 8, [0.0, 10.0, 0.0, 0.0, -30.0, 0.0, 0.0], 20.0, 0, mirrors=[2, 5],
                spec=None)
    p = paraxial(lens)
    assert math.isinf(float(p.efl)) and math.isinf(float(p.bfl)) and math.isinf(float(p.fno))
    assert float(p.entrance_pupil_diameter) == pytest.approx(10.0, rel=1e-15)
    rays = parallel_rays(torch.linspace(-4.0, 4.0, 5))
    out = lens.trace_to_sensor(rays)
    A, b = local_frames(lens)[-1]
    g = to_global(local_frames(lens)[-1], out.o)
    d = out.d @ A.T
    assert bool(out.valid.all())
    assert torch.allclose(d, rays.d, atol=1e-15)                  # parallel to the input
    # up by 30 mm at the fold, then 20 mm on past the second mirror (at z = 10)
    want = torch.stack([rays.o[:, 0], rays.o[:, 1] + 30.0, torch.full_like(rays.o[:, 0], 30.0)], -1)
    assert torch.allclose(g, want, atol=1e-12)
    write_zmx(lens, tmp_path / "periscope.zmx")
    back = read_zmx(tmp_path / "periscope.zmx")
    assert math.isinf(float(paraxial(back).efl))
    text = (tmp_path / "periscope.zmx").read_text().replace("FTYP 0 0", "FTYP 2 0")
    (tmp_path / "ftyp2.zmx").write_text(text)
    with pytest.raises(ZemaxFileError, match=r"ftyp2\.zmx:\d+: the system is afocal"):
        read_zmx(tmp_path / "ftyp2.zmx")


def test_central_obscuration_on_a_mirror(tmp_path):
    """A Cassegrain whose primary carries the secondary's shadow (Zemax's OBSC on the mirror
    surface): exactly the rays that meet the primary within the obscuration radius are blocked
    (closed form: the primary is the first surface, a ray parallel to the axis meets it at its
    own height) and the others land where they do without it, the same with the closed-form, Newton and compiled options; the obscuration
    survives the JSON and .zmx round trips (OBSC line)."""
    from deeplens.optics.options import TraceOptions

    lens = cassegrain()
    with torch.no_grad():
        lens.surfaces[0].obscuration.fill_(30.0)
    x, y = grid(95.0, 19)
    r = torch.sqrt(x * x + y * y)
    assert bool(((r - 30.0).abs() > 1e-6).all()) and bool((r < 30).any())
    rays = parallel_rays(y, x)
    want = r >= 30.0
    clear = cassegrain().trace_to_sensor(rays)
    assert bool(clear.valid.all())
    for opt in (None, TraceOptions(closed_form=False), TraceOptions(compile=True)):
        out = lens.trace_to_sensor(rays, options=opt)
        assert torch.equal(out.valid, want), opt
        assert torch.allclose(out.o[want], clear.o[want], atol=1e-12)   # the rest unchanged
    d = lens_to_dict(lens)
    assert d["surfaces"][0]["obscuration_mm"] == 30.0
    assert lens_to_dict(lens_from_dict(d)) == d
    write_zmx(lens, tmp_path / "obsc.zmx")
    assert "OBSC 0 30.0 0" in (tmp_path / "obsc.zmx").read_text()
    back = read_zmx(tmp_path / "obsc.zmx")
    assert float(back.surfaces[0].obscuration) == 30.0
    assert torch.equal(back.trace_to_sensor(rays).valid, want)
    with pytest.raises(LensError, match="obscuration .* must be smaller than the semi-diameter"):
        lens.surfaces[0].obscuration.fill_(150.0)
        lens.check()


def _obscured_singlet():
    air, glass = Air(), get_material("N-BK7")
    lens = Lens([Aperture(12.0), Asphere(1 / 60.0, 12.0, obscuration=4.0), Asphere(-1 / 80.0, 12.0)],
                [air, air, glass, air], [0.0, 5.0, 4.0], 50.0, 0)
    x, y = grid(11.0, 15)
    r = torch.sqrt(x * x + y * y)
    assert bool(((r - 4.0).abs() > 1e-6).all())
    return lens, parallel_rays(y, x), r >= 4.0   # rays meet the front surface at their height


@pytest.mark.slow
def test_central_obscuration_on_a_lens_surface_compiled():
    """The fused compiled kernels clip by the semi-diameter only: an obscured surface runs
    eagerly under ``compile=True`` (torch.compile: slow on a loaded CPU)."""
    from deeplens.optics.options import TraceOptions

    lens, rays, want = _obscured_singlet()
    assert torch.equal(lens.trace_to_sensor(rays, options=TraceOptions(compile=True)).valid,
                       want)


def test_central_obscuration_on_a_lens_surface_in_every_tracer_path():
    """An obscured refracting sphere (as US05331467's front lens carries the secondary's
    shadow): the closed-form kernel clips by the semi-diameter only, so an obscured surface
    must take the generic path; every option blocks the same rays."""
    from deeplens.optics.options import TraceOptions

    lens, rays, want = _obscured_singlet()
    assert not bool(want.all())
    for opt in (None, TraceOptions(closed_form=False)):
        assert torch.equal(lens.trace_to_sensor(rays, options=opt).valid, want), opt
