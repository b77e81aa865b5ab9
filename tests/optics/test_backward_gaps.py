"""Gaps crossed backwards (``Lens(backward_gaps=...)``, issue 22): where two surfaces cross (a
negative edge thickness), OpticStudio's sequential trace meets the next surface along the ray's
line whatever the sign of the distance, so rays beyond the crossing travel back through the gap
and their optical path decreases by ``n |t|``.  Opted in per gap; off by default (a hit behind
the ray invalidates it, and crossing surfaces are an error).

The real files that need it (``optiland_lens_floa.zmx``, ``patent2zemax_EP0770895A2-1.zmx``) are
checked against optiland in ``tests/optics/io/test_zmx_corpus.py``."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.errors import LensError, SurfacesCrossError, ZemaxWarning
from deeplens.optics.intersect import intersect
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.io.zmx import read_zmx, write_zmx
from deeplens.optics.lens import Lens, LensSpec
from deeplens.optics.materials import get_material
from deeplens.optics.options import TraceOptions
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture, Sphere
from deeplens.optics.tracer import fused_kind

R = 20.0      # both radii (mm): R1 = +20, R2 = -20
GAP = 5.0     # centre thickness (mm): the spheres cross at r = sqrt(R^2 - (R - GAP/2)^2)
N_GLASS = 1.2
R_CROSS = math.sqrt(R**2 - (R - GAP / 2) ** 2)   # 9.682 mm

EAGER = TraceOptions(compile=False)
NEWTON = TraceOptions(compile=False, closed_form=False)


def _lens(backward=(2,), stop_sd=12.0):
    """A stop in front of a biconvex singlet whose spheres cross at ``R_CROSS`` (surfaces 1
    and 2, semi-diameters 15 mm beyond it), float64."""
    air, glass = get_material("AIR"), get_material(f"{N_GLASS}/inf")
    return Lens([Aperture(stop_sd), Sphere(1.0 / R, 15.0), Sphere(-1.0 / R, 15.0)],
                [air, air, glass, air], [0.0, 2.0, GAP], 30.0, 0,
                spec=LensSpec(wavelengths_nm=[587.5618]), backward_gaps=backward,
                name="crossing singlet").double()


def _line_sphere(o, d, centre_z, radius, branch_sign):
    """The roots ``t`` of ``|o + t d - C|^2 = radius^2`` (``C = (0, 0, centre_z)``) and the one
    whose point lies on the vertex's side of the centre (``branch_sign (z - centre_z) > 0``)."""
    oc = o - torch.tensor([0.0, 0.0, centre_z], dtype=o.dtype)
    b = float(oc @ d)
    c = float(oc @ oc) - radius**2
    disc = math.sqrt(b * b - c)
    roots = [-b - disc, -b + disc]
    on_branch = [t for t in roots if branch_sign * float(oc[2] + t * d[2]) > 0]
    assert len(on_branch) == 1
    return on_branch[0], roots


def _snell(d, n, eta):
    """Vector Snell's law (unit ``d``, unit normal ``n`` against the ray, ``eta = n1/n2``)."""
    cos_i = -float(d @ n)
    k = 1.0 - eta**2 * (1.0 - cos_i**2)
    return eta * d + (eta * cos_i - math.sqrt(k)) * n


@pytest.mark.parametrize("options", [EAGER, NEWTON], ids=["closed_form", "newton"])
def test_a_backward_hit_is_the_line_sphere_root_on_the_vertex_branch(options):
    """Sphere c = -1/20 (centre 20 mm before the vertex).  A ray past it whose vertex-branch
    crossing lies *behind* it: with ``backward`` the hit is that closed-form root (t < 0), not
    the far side of the sphere; without it the ray is invalid.  A ray inside the sphere near
    its far side: the hit is still the vertex branch ahead (t = +26), not the nearer far-side
    root behind it (t = -6)."""
    s = Sphere(-1.0 / R, 15.0).double()
    d = torch.tensor([0.0, 0.1, 1.0], dtype=torch.float64)
    d = d / torch.linalg.vector_norm(d)
    o = torch.tensor([0.3, 11.0, 5.0], dtype=torch.float64)
    t_ref, roots = _line_sphere(o, d, -R, R, +1.0)
    assert t_ref < 0 and all(r < 0 for r in roots)
    valid = torch.ones(1, dtype=torch.bool)
    t, x, ok = intersect(s, o[None], d[None], valid, options, backward=True)
    assert bool(ok[0])
    assert float(t[0]) == pytest.approx(t_ref, rel=0, abs=1e-11)
    assert torch.allclose(x[0], o + t_ref * d, rtol=0, atol=1e-11)
    _, _, ok = intersect(s, o[None], d[None], valid, options)
    assert not bool(ok[0])   # forwards only (the default): a hit behind the ray is no hit
    # the far-side root nearer the ray, behind it: not taken
    o2 = torch.tensor([0.0, 12.0, -30.0], dtype=torch.float64)
    d2 = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    t_ref2, roots2 = _line_sphere(o2, d2, -R, R, +1.0)
    assert t_ref2 == pytest.approx(26.0) and min(roots2, key=abs) == pytest.approx(-6.0)
    t, x, ok = intersect(s, o2[None], d2[None], valid, options, backward=True)
    assert bool(ok[0]) and float(t[0]) == pytest.approx(t_ref2, rel=0, abs=1e-11)


@pytest.mark.parametrize("options", [EAGER, NEWTON], ids=["closed_form", "newton"])
def test_a_ray_beyond_the_crossing_goes_back_through_the_gap(options):
    """A ray parallel to the axis at h = 11 mm (beyond the crossing at 9.68 mm) meets the first
    sphere, refracts, and meets the second sphere *behind* that point: the recorded hit is the
    closed-form line-sphere root from the first hit along the refracted direction, and the
    optical path after the second surface is the one after the first *minus* n_glass |t|."""
    lens = _lens()
    h = 11.0
    o = torch.tensor([[0.0, h, -5.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    rays = Rays(o, d, 587.5618)
    out, hits = lens.trace(rays, options=options, record=True)
    assert bool(out.valid[0])
    # independent: the first hit, Snell's law there, the line to the second sphere
    z1 = 2.0 + R - math.sqrt(R**2 - h**2)
    p1 = torch.tensor([0.0, h, z1], dtype=torch.float64)
    n1 = torch.tensor([0.0, h, z1 - (2.0 + R)], dtype=torch.float64) / R   # towards the ray
    d1 = _snell(d[0], n1, 1.0 / N_GLASS)
    t2, _ = _line_sphere(p1, d1, 2.0 + GAP - R, R, +1.0)
    assert t2 < 0   # behind the first hit: back through the gap
    assert torch.allclose(hits[1][0], p1, rtol=0, atol=1e-12)
    assert torch.allclose(hits[2][0], p1 + t2 * d1, rtol=0, atol=1e-11)
    opl1 = z1 - (-5.0)
    assert float(out.opl[0]) == pytest.approx(opl1 + N_GLASS * t2, rel=0, abs=1e-11)
    assert float(out.opl[0]) < opl1   # the optical path decreased by n |t|
    # the flag matters: forwards only, the same ray is lost at the second surface
    lens.backward_gaps = ()
    assert not bool(lens.trace(rays, options=options).valid[0])


def test_the_default_refuses_crossing_surfaces_and_the_set_is_validated():
    with pytest.raises(SurfacesCrossError) as e:
        _lens(backward=())
    assert e.value.surfaces == (1, 2)
    assert e.value.radius == pytest.approx(R_CROSS, rel=1e-9)
    assert _lens().backward_gaps == frozenset({2})
    for bad in ([1], [0], [3], [True], ["2"]):   # 1: its previous surface is the stop
        with pytest.raises(LensError, match="backward gap"):
            _lens(backward=bad)


def test_compiled_traces_fall_back_to_eager_for_the_gap_surfaces():
    """Both surfaces of the gap run eager under ``compile=...`` (the kernels accept hits ahead
    of the ray only); the same spheres with a thicker gap (no crossing, no flag) are fused.
    A lens with nothing else (the stop on the first sphere) then compiles nothing, and its
    ``compile="surface"`` trace is the eager one bit for bit, rays beyond the crossing
    included."""
    assert [fused_kind(_lens(), i) for i in range(3)] == ["stop", None, None]
    air, glass = get_material("AIR"), get_material(f"{N_GLASS}/inf")

    def singlet(gap, backward):
        return Lens([Sphere(1.0 / R, 15.0), Sphere(-1.0 / R, 15.0)], [air, glass, air],
                    [0.0, gap], 30.0, 0, backward_gaps=backward).double()

    assert [fused_kind(singlet(20.0, ()), i) for i in range(2)] == ["quadric", "quadric"]
    lens = singlet(GAP, (1,))
    assert [fused_kind(lens, i) for i in range(2)] == [None, None]
    h = torch.linspace(-11.5, 11.5, 9, dtype=torch.float64)
    o = torch.stack([torch.zeros_like(h), h, torch.full_like(h, -5.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(9, 3)
    rays = Rays(o, d, 587.5618)
    a = lens.trace(rays, options=EAGER)
    b = lens.trace(rays, options=TraceOptions(compile="surface"))
    assert torch.equal(a.o, b.o) and torch.equal(a.opl, b.opl) and torch.equal(a.valid, b.valid)
    assert bool((a.valid & (h.abs() > R_CROSS)).any())


def test_gradients_through_a_backward_gap_match_central_differences():
    """d(loss)/d(gap thickness, curvatures) through rays that cross the gap backwards, float64,
    against central finite differences (closed form and Newton)."""
    h = torch.tensor([10.0, 10.5, 11.0, -10.8], dtype=torch.float64)
    o = torch.stack([torch.full_like(h, 0.2), h, torch.full_like(h, -5.0)], -1)
    d = torch.tensor([0.0, 0.01, 1.0], dtype=torch.float64).expand(4, 3)
    rays = Rays(o, d, 587.5618)

    def loss(lens, options):
        out = lens.trace_to_sensor(rays, options=options)
        assert bool(out.valid.all())
        return (out.o[:, 1] * torch.arange(1, 5, dtype=torch.float64)).sum() + out.opl.sum()

    for options in (EAGER, NEWTON):
        lens = _lens()
        params = [lens.distances[2], lens.surfaces[1].c, lens.surfaces[2].c]
        for p in params:
            p.requires_grad_(True)
        grads = torch.autograd.grad(loss(lens, options), params)
        for p, g in zip(params, grads):
            eps = 1e-6 * max(1.0, abs(float(p.detach())))
            with torch.no_grad():
                p0 = float(p)
                p.fill_(p0 + eps)
                up = float(loss(lens, options))
                p.fill_(p0 - eps)
                down = float(loss(lens, options))
                p.fill_(p0)
            fd = (up - down) / (2 * eps)
            assert abs(float(g)) > 1e-3
            assert float(g) == pytest.approx(fd, rel=1e-6, abs=1e-7)


def test_the_gaps_round_trip_through_json_and_zmx(tmp_path):
    """The JSON lens file keeps the set; a written ``.zmx`` has no such record: the reader
    opts the gap in again because the on-axis beam of the stop (radius 12 mm) reaches past the
    crossing (9.68 mm), and keeps the written semi-diameters (15 mm, beyond it)."""
    lens = _lens()
    d = lens_to_dict(lens)
    assert d["backward_gaps"] == [2]
    assert lens_from_dict(d).backward_gaps == frozenset({2})
    write_zmx(lens, tmp_path / "x.zmx")
    with pytest.warns(ZemaxWarning, match="backwards through the gap"):
        back = read_zmx(tmp_path / "x.zmx")
    assert back.backward_gaps == frozenset({2})
    a, b = lens_to_dict(lens), lens_to_dict(back)
    a.pop("name"), b.pop("name")
    assert a == b


@pytest.mark.parametrize("options", [EAGER, NEWTON], ids=["closed_form", "newton"])
def test_a_reverse_trace_crosses_the_gap_backwards_too(options):
    """Traced in reverse (sensor to object), the gap is crossed at surface 1 (the previous
    surface of gap 2): the reversed rays retrace their forward hits on both spheres, the ones
    beyond the crossing included (lost without the flag)."""
    lens = _lens()
    h = torch.tensor([3.0, 10.0, 11.0, -11.2], dtype=torch.float64)
    o = torch.stack([torch.zeros_like(h), h, torch.full_like(h, -5.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(4, 3)
    fwd, hits = lens.trace(Rays(o, d, 587.5618), options=options, record=True)
    assert bool(fwd.valid.all())
    back = Rays(fwd.o + 3.0 * fwd.d, -fwd.d, 587.5618)
    rev, rhits = lens.trace(back, reverse=True, options=options, record=True)
    assert bool(rev.valid.all())
    # reverse order: rhits[0] is surface 2, rhits[1] surface 1
    assert torch.allclose(rhits[0], hits[2], rtol=0, atol=1e-9)
    assert torch.allclose(rhits[1], hits[1], rtol=0, atol=1e-9)
    assert torch.allclose(rev.d, -d, rtol=0, atol=1e-9)
    lens.backward_gaps = ()
    lost = lens.trace(back, reverse=True, options=options).valid
    assert lost.tolist() == [True, False, False, False]
