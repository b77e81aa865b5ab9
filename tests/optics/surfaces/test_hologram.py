"""The two-point hologram (:mod:`deeplens.optics.surfaces.hologram`, OpticStudio's ``HOLOGRM1``
and ``HOLOGRM2``): at the construction wavelength a point at construction point 1 is imaged
exactly on construction point 2 (every real ray, float64), in transmission and reflection, on a
plane and a sphere, with off-axis points; at another wavelength and other orders the directions
agree with rayoptics' ``HolographicElement`` (a test-only oracle; the mapping of conventions is
stated in ``_rayoptics_element``); the paraxial power against the closed form and real rays at
small heights; gradients against central differences; evanescent orders are killed cleanly."""

from __future__ import annotations

import pytest
import torch

from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Hologram

F64 = torch.float64
WLC = 550.0


def _single(surface, sensor, mirror=False):
    """One surface at z = 0 (the stop) in air, the sensor plane at z = ``sensor``."""
    return Lens([surface], [Air(), Air()], [0.0], sensor, 0, mirrors=(0,) if mirror else ())


def _from_point(p, n=48, spread=14.0, seed=0, wavelength=WLC, toward=0.0):
    """Rays from the point ``p`` (mm) aimed at random points of the plane z = ``toward`` within
    ``spread`` mm of the axis."""
    g = torch.Generator().manual_seed(seed)
    aim = torch.empty(n, 3, dtype=F64).uniform_(-spread, spread, generator=g)
    aim[:, 2] = toward
    o = torch.tensor(p, dtype=F64).expand(n, 3).clone()
    d = aim - o
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    return Rays(o, d, wavelength)


def _at_plane(o, d, z):
    """The points where the lines ``o + s d`` cross the plane ``z`` (``s`` of either sign)."""
    s = (z - o[:, 2]) / d[:, 2]
    return o + s.unsqueeze(-1) * d


# ------------------------------------------------------------------- stigmatic imaging at λ_c
@pytest.mark.parametrize("c", [0.0, 1 / 80.0, -1 / 120.0])
@pytest.mark.parametrize("p1,p2", [((0.0, 0.0, -200.0), (0.0, 0.0, 100.0)),
                                   ((5.0, -20.0, -180.0), (-3.0, 10.0, 120.0))])
def test_hologram2_images_point1_on_point2_exactly(c, p1, p2):
    """HOLOGRM2, order 1, λ = λ_c, in air: every ray from P1 passes through P2 (to 1e-11 mm over
    ~300 mm of path: float64 round-off), on a plane or a sphere, on or off the axis."""
    lens = _single(Hologram(c, 25.0, p1, p2, WLC, 1, 2), p2[2])
    out = lens.trace_to_sensor(_from_point(p1, toward=0.0))
    assert out.valid.all()
    err = (out.o[:, :2] - torch.tensor(p2[:2], dtype=F64)).abs().max()
    assert err <= 1e-11
    # the bare surface does not: the rays keep going outwards
    bare = _single(Hologram(c, 25.0, p1, p2, WLC, 0, 2), p2[2]).trace_to_sensor(
        _from_point(p1, toward=0.0))
    assert (bare.o[:, :2] - torch.tensor(p2[:2], dtype=F64)).abs().max() > 1.0


def test_hologram2_optical_path_is_one_from_point1_to_point2():
    """Malus: with the phase in the optical path, every ray from P1 reaches P2 with the same
    optical path (1e-11 mm), which fails without it (the spread is ~1 mm here)."""
    p1, p2 = (4.0, -6.0, -200.0), (0.0, 3.0, 100.0)
    lens = _single(Hologram(1 / 90.0, 25.0, p1, p2, WLC, 1, 2), p2[2])
    rays = _from_point(p1, toward=0.0)
    out = lens.trace_to_sensor(rays)
    assert out.valid.all()
    assert float(out.opl.max() - out.opl.min()) <= 1e-11
    hit = lens.trace(rays).o   # the geometric path P1 -> hit -> P2 alone is not one
    geo = torch.linalg.vector_norm(hit - rays.o, dim=-1) + torch.linalg.vector_norm(
        out.o - hit, dim=-1)
    assert float(geo.max() - geo.min()) > 0.5


def test_reflection_hologram2_images_each_point_on_the_other():
    """GLAS MIRROR (OpticStudio's reflection sample: P1 (0, 0, -100), P2 (0, 0, -200)): rays
    from P2 are reflected through P1 and rays from P1 through P2, exactly; the paraxial image
    of an object at P2 is at P1."""
    p1, p2 = (0.0, 0.0, -100.0), (0.0, 0.0, -200.0)
    h = Hologram(0.0, 25.0, p1, p2, WLC, 1, 2)
    out = _single(h, -100.0, mirror=True).trace_to_sensor(_from_point(p2))
    assert out.valid.all() and (out.d[:, 2] < 0).all()
    assert out.o[:, :2].abs().max() <= 1e-11
    out = _single(h, -200.0, mirror=True).trace_to_sensor(_from_point(p1))
    assert out.valid.all() and out.o[:, :2].abs().max() <= 1e-11
    # an off-axis pair on a curved mirror
    q1, q2 = (6.0, -4.0, -150.0), (-2.0, 8.0, -260.0)
    out = _single(Hologram(-1 / 200.0, 25.0, q1, q2, WLC, 1, 2), q1[2], mirror=True) \
        .trace_to_sensor(_from_point(q2))
    assert out.valid.all()
    assert (out.o[:, :2] - torch.tensor(q1[:2], dtype=F64)).abs().max() <= 1e-11


@pytest.mark.parametrize("c", [0.0, 1 / 60.0])
def test_hologram1_sends_point1_as_if_from_point2(c):
    """HOLOGRM1, order 1, λ = λ_c: rays from P1 leave as if from P2 (a virtual image: their
    lines, extended backwards, pass through P2 to 1e-11 mm)."""
    p1, p2 = (3.0, 2.0, -200.0), (-1.0, 5.0, -90.0)
    lens = _single(Hologram(c, 25.0, p1, p2, WLC, 1, 1), 50.0)
    out = lens.trace_to_sensor(_from_point(p1))
    assert out.valid.all()
    back = _at_plane(out.o, out.d, p2[2])
    assert (back[:, :2] - torch.tensor(p2[:2], dtype=F64)).abs().max() <= 1e-11


# ------------------------------------------------------------ rayoptics' HolographicElement
def _rayoptics_element(p1, p2, wlc, order, kind):
    """rayoptics' two-point HOE with deeplens' convention.  rayoptics bends a ray by
    ``μ (obj_dir - ref_dir)`` (``μ = λ / ref_wl``, one order), each ``*_dir`` the unit vector
    away from its point, negated when ``*_virtual``; deeplens' kick is ``m (λ/λ_c) g`` with
    ``g = -(u_1 + u_2)`` (kind 2) or ``u_2 - u_1`` (kind 1), ``u_i`` away from ``P_i``.  So
    kind 2: obj = P1 virtual, ref = P2 real (m > 0; swapped roles for m < 0); kind 1: obj = P2,
    ref = P1, both real (m > 0; swapped for m < 0); ``ref_wl = λ_c / |m|``."""
    import numpy as np
    pytest.importorskip("rayoptics")
    from rayoptics.oprops.doe import HolographicElement

    e = HolographicElement()
    if kind == 2:   # obj - ref = -(u_1 + u_2) for m > 0, u_2 + u_1 for m < 0
        (e.obj_pt, e.obj_virtual), (e.ref_pt, e.ref_virtual) = \
            ((p1, True), (p2, False)) if order > 0 else ((p2, False), (p1, True))
    else:           # obj - ref = u_2 - u_1 for m > 0, u_1 - u_2 for m < 0
        e.obj_pt, e.ref_pt = (p2, p1) if order > 0 else (p1, p2)
        e.obj_virtual = e.ref_virtual = False
    e.obj_pt, e.ref_pt = np.asarray(e.obj_pt, float), np.asarray(e.ref_pt, float)
    e.ref_wl = wlc / abs(order)
    return e


@pytest.mark.parametrize("kind", [1, 2])
@pytest.mark.parametrize("order", [1, -1, 2])
@pytest.mark.parametrize("c,mirror", [(0.0, False), (1 / 70.0, False), (-1 / 90.0, True)])
def test_directions_agree_with_rayoptics_at_another_wavelength(kind, order, c, mirror):
    """Skew rays at 640 nm (λ_c 550 nm) through off-axis construction points: deeplens'
    outgoing directions at its own hit points equal rayoptics' ``HolographicElement.phase``
    given the same hit point, incoming direction and +z-facing normal (1e-13)."""
    import numpy as np

    p1, p2 = (4.0, -7.0, -250.0), (-2.0, 5.0, 160.0 if not mirror else -140.0)
    wl = 640.0
    h = Hologram(c, 25.0, p1, p2, WLC, order, kind)
    g = torch.Generator().manual_seed(7)
    n = 20
    o = torch.empty(n, 3, dtype=F64).uniform_(-8, 8, generator=g)
    o[:, 2] = -30.0
    d = torch.empty(n, 3, dtype=F64).uniform_(-0.15, 0.15, generator=g)
    d[:, 2] = 1.0
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    rays = Rays(o, d, wl)
    out = _single(h, -50.0 if mirror else 50.0, mirror=mirror).trace(rays)
    assert out.valid.all()
    e = _rayoptics_element(p1, p2, WLC, order, kind)
    worst = 0.0
    for x, din, dout in zip(out.o.numpy(), d.numpy(), out.d.numpy()):
        nrm = np.array([-c * x[0], -c * x[1], 1.0 - c * x[2]])
        nrm /= np.linalg.norm(nrm)
        ctx = (-1 if mirror else 1, wl, 1.0, 1.0, "reflect" if mirror else "transmit")
        ro, _ = e.phase(x, din, nrm, ctx)
        worst = max(worst, float(np.abs(ro - dout).max()))
    assert worst <= 1e-13
    # the hologram's kick is not negligible (the comparison would pass at order 0 otherwise)
    bare = _single(Hologram(c, 25.0, p1, p2, WLC, 0, kind), -50.0 if mirror else 50.0,
                   mirror=mirror).trace(rays)
    assert (bare.d - out.d).abs().max() > 1e-2


# ------------------------------------------------------------------------- paraxial power
@pytest.mark.parametrize("kind,order,wl", [(2, 1, 550.0), (2, 1, 640.0), (1, 1, 480.0),
                                           (2, -2, 600.0)])
def test_flat_on_axis_power_is_the_thin_lens_closed_form(kind, order, wl):
    """Flat, both points on the axis: φ = m (λ/λ_c) (1/|z_1| ± 1/|z_2|) (+ for kind 2), the
    paraxial EFL is 1/φ (1e-13)."""
    z1, z2 = -200.0, 100.0 if kind == 2 else -90.0
    lens = _single(Hologram(0.0, 25.0, (0, 0, z1), (0, 0, z2), WLC, order, kind), 50.0)
    sign = 1.0 if kind == 2 else -1.0
    phi = order * wl / WLC * (1 / abs(z1) + sign / abs(z2))
    assert float(paraxial(lens, wl).efl) == pytest.approx(1 / phi, rel=1e-13)


@pytest.mark.parametrize("c,p1,p2,kind", [
    (1 / 70.0, (0.0, 0.0, -200.0), (0.0, 0.0, 100.0), 2),
    (-1 / 50.0, (0.0, 0.0, 150.0), (0.0, 0.0, -80.0), 1),
    (0.0, (3.0, -25.0, -180.0), (2.0, 15.0, 120.0), 2),
    (1 / 90.0, (0.0, 0.0, -300.0), (0.0, 0.0, -420.0), 2),
])
def test_paraxial_power_matches_real_rays_at_small_heights(c, p1, p2, kind):
    """The paraxial power is -d(n' d'_y)/dy of real rays parallel to the axis at the vertex
    (central differences at y = ±1e-3 mm: truncation ~1e-10 relative): curved substrates with
    the points on the axis, and off-axis points on a flat one (their linear term tilts the beam;
    on a curved substrate the tilted beam's bending by the turning normal is not in the
    paraxial power, as for a grating: the Zemax guide, Holograms)."""
    wl = 600.0
    h = Hologram(c, 25.0, p1, p2, WLC, 1, kind)
    lens = _single(h, 50.0)
    y = torch.tensor([-1e-3, 1e-3], dtype=F64)
    o = torch.stack([torch.zeros_like(y), y, torch.full_like(y, -5.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand_as(o)
    out = lens.trace(Rays(o, d, wl))
    real = -float(out.d[1, 1] - out.d[0, 1]) / float(out.o[1, 1] - out.o[0, 1])
    phi = float(h.paraxial_phase_power(wl))
    assert phi == pytest.approx(real, rel=1e-6)
    assert abs(phi) > 1e-3


# ------------------------------------------------------------------------------ gradients
def test_gradients_match_central_differences():
    """d(Σ y² at the sensor)/d z_1, d/d y_2 and d/d λ_c against central differences in float64
    (steps 1e-3 mm / 1e-3 nm: truncation ~1e-9 relative)."""
    def loss(h):
        lens = _single(h, 95.0)
        rays = _from_point((1.0, -2.0, -200.0), n=16, spread=10.0, seed=3, wavelength=600.0)
        out = lens.trace_to_sensor(rays)
        assert out.valid.all()
        return (out.o[:, 1] ** 2).sum()

    base = dict(curvature=1 / 80.0, semi_diameter=25.0, point1=(0.0, 0.0, -200.0),
                point2=(0.0, 1.0, 100.0), construction_wavelength_nm=WLC, order=1, kind=2)
    h = Hologram(**base)
    for p in (h.P1[2], h.P2[1], h.wl_c):
        p.requires_grad_(True)
    loss(h).backward()
    analytic = [float(h.P1[2].grad), float(h.P2[1].grad), float(h.wl_c.grad)]

    def moved(which, idx, step):
        kw = dict(base)
        if which == "wl":
            kw["construction_wavelength_nm"] = WLC + step
        else:
            key = "point1" if which == "p1" else "point2"
            pt = list(kw[key])
            pt[idx] += step
            kw[key] = tuple(pt)
        with torch.no_grad():
            return float(loss(Hologram(**kw)))

    eps = 1e-3
    fd = [(moved(w, i, eps) - moved(w, i, -eps)) / (2 * eps)
          for w, i in (("p1", 2), ("p2", 1), ("wl", None))]
    for a, f in zip(analytic, fd):
        assert a == pytest.approx(f, rel=1e-6, abs=1e-9)
        assert abs(a) > 1e-4


# -------------------------------------------------------------------------- edge cases
def test_evanescent_orders_are_invalid_and_finite():
    """A high order whose kick exceeds 1 at the rim: those rays are invalid, every direction
    and the gradient finite (no NaN), the centre rays still valid."""
    h = Hologram(0.0, 25.0, (0, 0, -20.0), (0, 0, 20.0), WLC, 3, 2)
    for p in h.P1:
        p.requires_grad_(True)
    y = torch.linspace(-20, 20, 41, dtype=F64)
    o = torch.stack([torch.zeros_like(y), y, torch.full_like(y, -1.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand_as(o)
    out = _single(h, 30.0).trace(Rays(o, d, WLC))
    assert out.valid[20] and not out.valid[0] and not out.valid[-1]
    assert torch.isfinite(out.d).all()
    out.d[out.valid][:, 1].sum().backward()
    assert all(torch.isfinite(p.grad) for p in h.P1)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="kind must be 1"):
        Hologram(0.0, 5.0, (0, 0, -1), (0, 0, 1), WLC, 1, 3)
    with pytest.raises(ValueError, match="at the surface's vertex"):
        Hologram(0.0, 5.0, (0, 0, 0), (0, 0, 1), WLC, 1, 2)
    with pytest.raises(ValueError, match="construction wavelength must be"):
        Hologram(0.0, 5.0, (0, 0, -1), (0, 0, 1), -550.0, 1, 2)
    with pytest.raises(ValueError, match="order must be an integer"):
        Hologram(0.0, 5.0, (0, 0, -1), (0, 0, 1), WLC, 1.5, 2)


def test_lens_file_round_trip():
    lens = Lens([Hologram(1 / 70.0, 12.0, (1.0, -2.0, -150.0), (0.5, 3.0, 90.0), 532.0, -1, 1,
                          conic=-0.4)], [Air(), Air()], [0.0], 80.0, 0)
    back = lens_from_dict(lens_to_dict(lens))
    assert lens_to_dict(back) == lens_to_dict(lens)
    s = back.surfaces[0]
    assert isinstance(s, Hologram) and s.kind == 1 and s.order == -1


@pytest.mark.parametrize("field,value,expected", [
    ("aspheric", [1e-6], r"surfaces\[0\]\.aspheric: a hologram's base is a sphere or conic"),
    ("order", 1.5, r"surfaces\[0\]\.order: the diffraction order must be an integer, got 1\.5"),
    ("kind", 3, r"surfaces\[0\]\.kind: must be 1 \(HOLOGRM1\) or 2 \(HOLOGRM2\), got 3"),
    ("point2_mm", [0.5, 3.0], r"surfaces\[0\]\.point2_mm: must be three numbers"),
    ("construction_wavelength_nm", 0.0,
     r"surfaces\[0\]\.construction_wavelength_nm: must be > 0 \(nm\), got 0\.0"),
])
def test_lens_file_fields_are_refused_by_name(field, value, expected):
    """A bad hologram entry in a lens file is refused naming its field (the base and order as a
    grating's, :func:`~deeplens.optics.surfaces.grating.conic_base_from_dict`)."""
    from deeplens.optics.errors import LensFileError

    d = lens_to_dict(Lens([Hologram(1 / 70.0, 12.0, (1.0, -2.0, -150.0), (0.5, 3.0, 90.0),
                                    532.0, -1, 1)], [Air(), Air()], [0.0], 80.0, 0))
    d["surfaces"][0][field] = value
    with pytest.raises(LensFileError, match=expected):
        lens_from_dict(d)
