"""The lenslet array (:class:`~deeplens.optics.surfaces.LensletArray`, OpticStudio's sample
``US_ARRAY.DLL``): the sag at points in several lenslets against the conic about each
lenslet's centre worked out by hand (odd counts: a lenslet on the vertex; even: a corner),
continuous across the cells' edges; its slopes against central differences; a ray through an
off-axis lenslet against Snell's law written out by hand; a ray whose vertex-plane crossing lies
in one cell and whose hit lies in the next; rays outside the array miss; trace gradients in
``c`` and ``k`` against central differences (float64); paraxial use refused where the axis falls
on an edge; the lens file round-trips."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.errors import LensFileError
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import LensletArray, Plane
from deeplens.optics.tracer import fused_kind

F64 = torch.float64


def conic(rho2, c, k):
    """The conic's sag at ``rho2 = ρ²`` (plain python: the hand reference)."""
    return c * rho2 / (1.0 + math.sqrt(1.0 - (1.0 + k) * c * c * rho2))


#: (point, the centre of its lenslet) in a 5 x 3 array of 2 x 3 mm lenslets (odd: a lenslet on
#: the vertex, centres at whole widths) and a 4 x 2 one (even: a corner on the vertex, centres at
#: half widths), worked out by hand from the cells' edges
ODD = [((0.3, -0.4), (0.0, 0.0)), ((1.2, 0.0), (2.0, 0.0)), ((-2.9, 1.6), (-2.0, 3.0)),
       ((4.7, -4.2), (4.0, -3.0)), ((-3.05, 2.0), (-4.0, 3.0))]
EVEN = [((0.3, 0.4), (1.0, 1.5)), ((-0.3, -0.4), (-1.0, -1.5)), ((3.5, 2.9), (3.0, 1.5)),
        ((-2.2, 0.1), (-3.0, 1.5))]


@pytest.mark.parametrize("counts,cases", [((5, 3), ODD), ((4, 2), EVEN)])
@pytest.mark.parametrize("c,k", [(0.1, 0.0), (-0.08, -0.6)])
def test_sag_is_the_conic_about_each_lenslets_centre(counts, cases, c, k):
    s = LensletArray(c, 10.0, counts, (2.0, 3.0), conic=k)
    x = torch.tensor([p[0] for p, _ in cases], dtype=F64)
    y = torch.tensor([p[1] for p, _ in cases], dtype=F64)
    want = [conic((px - cx) ** 2 + (py - cy) ** 2, c, k) for (px, py), (cx, cy) in cases]
    assert s.sag(x, y).tolist() == pytest.approx(want, rel=1e-14, abs=1e-16)
    assert bool(s.in_domain(x, y).all())


@pytest.mark.parametrize("counts", [(5, 3), (4, 2)])
def test_sag_is_continuous_across_the_edges_and_slopes_jump(counts):
    """On an edge between two lenslets both meet at the same height (1e-15 mm either side of
    it); the x slope changes sign there (each lenslet rises away from its own centre)."""
    s = LensletArray(0.1, 10.0, counts, (2.0, 3.0))
    edge = 1.0 if counts[0] % 2 else 2.0   # an x edge in each layout
    y = torch.tensor([0.37], dtype=F64)
    a, b = torch.tensor([edge - 1e-12], dtype=F64), torch.tensor([edge + 1e-12], dtype=F64)
    assert float(s.sag(a, y)) == pytest.approx(float(s.sag(b, y)), abs=1e-14)
    sa, sb = s.sag_grad(a, y)[0], s.sag_grad(b, y)[0]
    assert float(sa) > 0 > float(sb) and float(sa) == pytest.approx(-float(sb), rel=1e-9)


def test_slopes_match_central_differences():
    """∂z/∂x, ∂z/∂y inside several lenslets against central differences of the sag (float64,
    h = 1e-6 mm: truncation ~h² z''' and rounding ~eps z / h, both below 1e-8)."""
    s = LensletArray(0.12, 10.0, (5, 5), (2.0, 2.0), conic=-0.3)
    x = torch.tensor([0.31, 1.7, -2.45, 3.9, -0.6], dtype=F64)
    y = torch.tensor([-0.2, 2.6, 0.9, -3.3, -4.1], dtype=F64)
    h = 1e-6
    gx, gy = s.sag_grad(x, y)
    fx = (s.sag(x + h, y) - s.sag(x - h, y)) / (2 * h)
    fy = (s.sag(x, y + h) - s.sag(x, y - h)) / (2 * h)
    assert torch.allclose(gx, fx, rtol=0, atol=1e-8)
    assert torch.allclose(gy, fy, rtol=0, atol=1e-8)


def _array_lens(c=0.1, k=0.0, counts=(5, 5), w=2.0):
    """A lenslet array in glass (index 1.5, non-dispersive) then a plane 3 mm on, the sensor
    20 mm behind; the array is the stop."""
    mats = [Air(), ModelGlass(1.5, math.inf), Air()]
    return Lens([LensletArray(c, 7.0, counts, (w, w), conic=k), Plane(7.0)], mats, [0.0, 3.0],
                20.0, 0)


def _snell(d, n, n1, n2):
    """Snell's law written out: the refracted unit direction (lists of 3 floats), ``n`` the unit
    normal on the side the ray comes from."""
    cos_i = -sum(a * b for a, b in zip(d, n))
    mu = n1 / n2
    cos_t = math.sqrt(1.0 - mu * mu * (1.0 - cos_i * cos_i))
    return [mu * a + (mu * cos_i - cos_t) * b for a, b in zip(d, n)]


def test_a_ray_through_an_off_axis_lenslet_follows_snells_law_by_hand():
    """A ray parallel to the axis at (3.4, -1.7) meets the lenslet centred at (4, -2) where that
    sphere's sag is (ρ² = 0.36 + 0.09), turns by Snell's law at its normal about that centre, and
    reaches the plane 3 mm on where the hand computation puts it (1e-12 mm)."""
    lens = _array_lens().double()
    c, x0, y0, cx, cy = 0.1, 3.4, -1.7, 4.0, -2.0
    u, v = x0 - cx, y0 - cy
    rho2 = u * u + v * v
    z = conic(rho2, c, 0.0)
    q = math.sqrt(1.0 - c * c * rho2)
    nrm = [c * u / q, c * v / q, -1.0]                       # ∇(sag − z), towards the ray
    ln = math.sqrt(sum(a * a for a in nrm))
    nrm = [a / ln for a in nrm]
    d1 = _snell([0.0, 0.0, 1.0], nrm, 1.0, 1.5)
    t = (3.0 - z) / d1[2]
    want = [x0 + t * d1[0], y0 + t * d1[1]]
    o = torch.tensor([[x0, y0, -1.0]], dtype=F64)
    out, hits = lens.trace(Rays(o, torch.tensor([[0.0, 0.0, 1.0]], dtype=F64), 550.0),
                           record=True)
    assert out.valid.all()
    assert hits[0][0].tolist() == pytest.approx([x0, y0, z], abs=1e-12)
    assert hits[1][0, :2].tolist() == pytest.approx(want, abs=1e-12)


def test_a_ray_crossing_into_the_next_lenslet_lands_on_it():
    """Steep lenslets (R 1.5 mm, 2 mm wide) and a ray at 30° that crosses the vertex plane in
    the lenslet at x = 0 but meets the surface in the one at x = -2: Newton, started on the first
    lenslet's sphere, ends on the second one's (the hit on its sag to 1e-12 mm, in its cell)."""
    lens = Lens([LensletArray(1 / 1.5, 7.0, (5, 5), (2.0, 2.0)), Plane(7.0)],
                [Air(), ModelGlass(1.5, math.inf), Air()], [0.0, 3.0], 20.0, 0).double()
    s = lens.surfaces[0]
    a = math.radians(30.0)
    d = torch.tensor([[-math.sin(a), 0.0, math.cos(a)]], dtype=F64)
    o = torch.tensor([[-0.95 + math.tan(a) * 1.0, 0.2, -1.0]], dtype=F64)   # crosses z = 0 at
    out, hits = lens.trace(Rays(o, d, 550.0), record=True)                    # x = -0.95
    assert out.valid.all()
    h = hits[0][0]
    assert float(h[0]) < -1.0                                 # in the cell of x = -2
    assert float(h[2]) == pytest.approx(conic((float(h[0]) + 2.0) ** 2 + 0.04, 1 / 1.5, 0.0),
                                        abs=1e-12)
    assert float(s.sag(h[:1], h[1:2])) == pytest.approx(float(h[2]), abs=1e-12)


def test_rays_outside_the_array_miss():
    """A 5 x 5 array of 2 mm lenslets spans |x|, |y| <= 5 mm: rays parallel to the axis at 4.99
    mm pass, at 5.01 mm (inside the 7 mm semi-diameter) miss; the array's outer edge itself
    belongs to the outermost lenslets."""
    lens = _array_lens().double()
    o = torch.tensor([[4.99, 0.0, -1.0], [0.0, -4.99, -1.0], [5.01, 0.0, -1.0],
                      [0.0, -5.01, -1.0], [4.9, 4.9, -1.0], [5.0, 0.0, -1.0]], dtype=F64)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(6, 3)
    out = lens.trace(Rays(o, d, 550.0))
    assert out.valid.tolist() == [True, True, False, False, True, True]


@pytest.mark.parametrize("name,h", [("c", 1e-6), ("k", 1e-5)])
def test_trace_gradients_match_central_differences(name, h):
    """d/dθ of (Σ x_image² + Σ y_image² + Σ opl) over rays through several lenslets (and the one
    on the axis), θ the lenslets' curvature or conic, against central differences in float64
    (truncation ~h² and rounding ~eps/h both below 1e-6 relative)."""
    xs = torch.tensor([0.3, 1.7, -2.6, 3.1, -0.8, 4.2], dtype=F64)
    ys = torch.tensor([-0.4, 0.9, 2.2, -3.7, -4.4, 0.0], dtype=F64)
    o = torch.stack([xs, ys, torch.full_like(xs, -1.0)], -1)
    dd = torch.tensor([0.01, -0.02, 1.0], dtype=F64)
    rays = Rays(o, (dd / dd.norm()).expand(6, 3), 550.0)

    def q(delta):
        lens = _array_lens(c=0.1 + (delta if name == "c" else 0.0),
                           k=-0.4 + (delta if name == "k" else 0.0)).double()
        p = getattr(lens.surfaces[0], name)
        p.requires_grad_(True)
        out = lens.trace_to_sensor(rays)
        assert out.valid.all()
        return (out.o[:, :2] ** 2).sum() + out.opl.sum(), p

    v, p = q(0.0)
    ad, = torch.autograd.grad(v, p)
    fd = float((q(h)[0] - q(-h)[0]).detach()) / (2 * h)
    assert abs(fd) > 1e-3
    assert float(ad) == pytest.approx(fd, rel=1e-6)


def test_paraxial_data_are_the_on_axis_lenslets_and_refused_on_an_edge():
    """An odd array's paraxial data are its on-axis lenslet's: the EFL of a plano-convex lens of
    R = 10 mm, n = 1.5, is 20 mm (the plane after it in the same glass is flat); an even count
    puts an edge on the axis: refused, saying so."""
    lens = _array_lens().double()
    assert float(paraxial(lens).efl) == pytest.approx(20.0, rel=1e-12)
    assert fused_kind(lens, 0) is None   # traced eagerly between fused runs
    even = LensletArray(0.1, 7.0, (5, 4), (2.0, 2.0))
    with pytest.raises(ValueError, match=r"the axis falls on an edge between lenslets \(an even "
                                         r"count along y \(4 lenslets\)\)"):
        even.paraxial_curvature()


def test_corners_beyond_the_conic_and_bad_arguments_are_refused():
    with pytest.raises(ValueError, match=r"lenslets' corners \(1.41421 mm from each lenslet's "
                                         r"centre\) lie beyond the domain of their conic"):
        LensletArray(1 / 1.4, 7.0, (3, 3), (2.0, 2.0)).check()
    with pytest.raises(ValueError, match="counts must be two whole numbers >= 1"):
        LensletArray(0.1, 7.0, (0, 3), (2.0, 2.0))
    with pytest.raises(ValueError, match="widths must be two numbers of mm > 0"):
        LensletArray(0.1, 7.0, (3, 3), (2.0, -1.0))


@pytest.mark.parametrize("field,value,match", [
    ("lenslet_widths_mm", [0.0, 1.5], "widths must be two numbers of mm > 0"),
    ("lenslet_counts", [7, 2.5], "counts must be two whole numbers >= 1"),
])
def test_a_bad_lens_file_field_is_named(field, value, match):
    """A bad width is refused naming ``lenslet_widths_mm``, a bad count ``lenslet_counts``
    (before, both named ``lenslet_counts``)."""
    d = lens_to_dict(_array_lens(c=0.11, k=-0.25, counts=(7, 3), w=1.5))
    d["surfaces"][0][field] = value
    with pytest.raises(LensFileError, match=rf"surfaces\[0\]\.{field}: LensletArray: {match}"):
        lens_from_dict(d)


def test_lens_file_round_trip():
    lens = _array_lens(c=0.11, k=-0.25, counts=(7, 3), w=1.5)
    d = lens_to_dict(lens)
    assert d["surfaces"][0]["type"] == "lenslet_array"
    assert d["surfaces"][0]["lenslet_counts"] == [7, 3]
    assert d["surfaces"][0]["lenslet_widths_mm"] == [1.5, 1.5]
    back = lens_from_dict(d)
    assert lens_to_dict(back) == d
    s = back.surfaces[0]
    assert isinstance(s, LensletArray) and s.counts == (7, 3) and float(s.k) == -0.25
