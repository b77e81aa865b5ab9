"""Lens tracing: invalid rays with finite gradients (float32 and float64), forward/backward
reversibility, no mutation, misalignment against closed forms, first-order data against the
lensmaker's equation and published focal lengths, and numerics at the extremes."""

import math

import pytest
import torch

import helpers as H
from deeplens.optics.paraxial import paraxial
from deeplens.optics.intersect import TraceOptions, intersect
from deeplens.optics.io import load_lens
from deeplens.optics.lens import Lens
from deeplens.optics.materials import get_material
from deeplens.optics.rays import Rays
from deeplens.optics.sampling import field_rays, hexapolar, random_disk
from deeplens.optics.surfaces import Aperture, Asphere, BSpline, Plane, Sphere, XYPolynomial

F64, F32 = torch.float64, torch.float32
M = get_material


def _fan(dtype, radius=9.0, n=150, angles=(0.0, 0.4, 0.8, 1.2), z0=-3.0):
    """Collimated bundles over a disk of ``radius`` mm at several field angles (rad)."""
    xy = H.disk_points(n, radius, seed=1, dtype=dtype)
    return H.cat_rays(*[H.collimated(xy, [math.sin(a), 0.3 * math.sin(a), math.cos(a)], z0)
                        for a in angles])


def _unfreeze_all(lens):
    params = list(lens.parameters())
    for p in params:
        p.requires_grad_(True)
    return params


def _aperture_lens():
    """Rays miss clear apertures (stop and lens rims)."""
    return Lens([Asphere(1 / 10, 6.0, conic=-0.5, coefficients=[1e-4, 1e-6]),
                 Sphere(-1 / 30, 6.0), Aperture(3.0),
                 XYPolynomial(5.0, [0, 0.001, 0, 0.01, 0, 0.012], b=0.01)],
                [M("AIR"), M("N-BK7"), M("AIR"), M("AIR"), M("AIR")], [0, 4, 2, 2], 15.0, 2)


def _tir_lens():
    """Object space is dense flint: rays steeper than the critical angle reflect totally."""
    return Lens([Sphere(-1 / 12, 9.0), Plane(9.0)], [M("N-SF11"), M("AIR"), M("N-BK7")],
                [0, 2], 10.0, 0)


def _domain_lens():
    """An oblate conic (k = 3, defined for r < 5 mm) traced without aperture clipping."""
    g = torch.Generator().manual_seed(2)
    return Lens([Asphere(1 / 10, 4.5, conic=3.0),
                 BSpline(6.0, 0.05 * torch.randn(6, 6, generator=g, dtype=F64))],
                [M("AIR"), M("N-BK7"), M("AIR")], [0, 6], 20.0, 0)


def _meets_conic_branch(rays, c, k):
    """Whether each ray's line meets the conic ``c r² + (1+k) c z² − 2 z = 0`` (vertex at the
    origin) ahead of it on the branch ``1 − (1+k) c z > 0``, where ``1 − (1+k) c² r² > 0``
    holds: the closed-form quadratic in float64, both roots tried (a ray whose vertex-plane
    point lies outside the domain may still meet the branch)."""
    o, d = rays.o.double(), rays.d.double()
    ck = (1 + k) * c
    a = c * (d[:, 0] ** 2 + d[:, 1] ** 2) + ck * d[:, 2] ** 2
    b = c * (o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]) + (ck * o[:, 2] - 1) * d[:, 2]
    cc = c * (o[:, 0] ** 2 + o[:, 1] ** 2) + (ck * o[:, 2] - 2) * o[:, 2]
    disc = b * b - a * cc
    sq = disc.clamp_min(0).sqrt()
    meets = torch.zeros_like(disc, dtype=torch.bool)
    for sign in (1.0, -1.0):
        t = (-b + sign * sq) / a
        meets |= (disc > 0) & (t > 0) & (1 - ck * (o[:, 2] + t * d[:, 2]) > 0)
    return meets


SCENARIOS = {
    "aperture": (_aperture_lens, TraceOptions),
    "tir": (_tir_lens, TraceOptions),
    "domain": (_domain_lens, lambda **kw: TraceOptions(clip_aperture=False, **kw)),
}


def _tir_count(lens, rays):
    """Rays that reach surface 0 inside its aperture but do not leave it (TIR)."""
    _, _, hit = intersect(lens.surfaces[0], rays.o, rays.d, rays.valid)
    w = rays.wavelength
    after = lens.trace_surface(0, rays, lens.materials[0].n(w), lens.materials[1].n(w),
                               lens.z_vertices())
    return int((hit & ~after.valid).sum()), int(after.valid.sum())


@pytest.mark.parametrize("dtype", [F64, F32], ids=["float64", "float32"])
@pytest.mark.parametrize("mode", ["implicit", "unrolled"])
@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_invalid_rays_give_finite_outputs_and_gradients(scenario, mode, dtype):
    make, options = SCENARIOS[scenario]
    lens = make().to(dtype)
    params = _unfreeze_all(lens)
    assert all(p.dtype == dtype for p in params)
    rays = _fan(dtype)
    out = lens.trace_to_sensor(rays, options=options(mode=mode))
    n = out.valid.numel()
    assert 0.05 * n < int(out.valid.sum()) < 0.6 * n
    for t in (out.o, out.d, out.opl):
        assert t.dtype == dtype and bool(torch.isfinite(t).all())
    # the invalidity actually comes from the scenario's cause
    if scenario == "tir":
        n_tir, _ = _tir_count(lens, rays)
        assert n_tir > 0.05 * n
    if scenario == "domain":
        # rays whose line never meets the conic's branch (its domain r < 5) ahead of them
        outside = ~_meets_conic_branch(rays, 1 / 10, 3.0)
        assert int(outside.sum()) > 0.05 * n and not bool(out.valid[outside].any())
    w = torch.randn(n, 2, generator=torch.Generator().manual_seed(0), dtype=F64).to(dtype)
    masked = H.weighted_image_sum(out, w) + torch.where(out.valid, out.opl, 0 * out.opl).sum()
    grads = torch.autograd.grad(masked, params, retain_graph=True, allow_unused=True)
    assert sum(g is not None and bool((g != 0).any()) for g in grads) >= 3
    for p, g in zip(params, grads):
        assert g is None or bool(torch.isfinite(g).all()), p
    # invalid rays carry finite values, so even a loss that forgets the mask stays finite
    unmasked = (out.o[:, :2] * w).sum() + out.opl.sum()
    for g in torch.autograd.grad(unmasked, params, allow_unused=True):
        assert g is None or bool(torch.isfinite(g).all())


def test_trace_float32_agrees_with_float64():
    lens = _aperture_lens()
    rays = _fan(F64, radius=2.0, angles=(0.0, 0.1))
    out64 = lens.trace_to_sensor(rays)
    out32 = lens.to(F32).trace_to_sensor(rays.to(F32))
    assert torch.equal(out64.valid, out32.valid) and bool(out64.valid.all())
    assert float((out32.o.double() - out64.o).abs().max()) < 1e-4



# ------------------------------------------------------------------------- devices
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


def _double_gauss_fan(n=2000):
    """The double Gauss (float64) and rays over 90 % of its entrance pupil at 0 and 10 deg."""
    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    with torch.no_grad():
        p = paraxial(lens)
        r_ep, z_ep = 0.5 * float(p.entrance_pupil_diameter), float(p.entrance_pupil_z)
    xy = 0.9 * r_ep * random_disk(n, seed=2)
    rays = H.cat_rays(*[field_rays(lens, f, H.WAVELENGTH_D, xy, z_ep) for f in (0.0, 10.0)])
    return lens, rays


def _trace_error_bound(lens, rays, eps: float) -> float:
    """First-order estimate (mm) of the rounding error of the sensor points traced at machine
    epsilon ``eps``.  Each of the ``S`` surfaces rounds a ray's position (coordinates up to
    ``L`` mm: the vertex positions and the sensor points) and its unit direction by ``eps``
    relative.  A direction error moves the sensor point by ``G_d = sum |dx_s/dd|`` (measured in
    float64 at the entrance: about the distance to the image, the largest lever arm), a
    position error by ``max(1, G_o)``, ``G_o = sum |dx_s/do|`` (at least a shift of the ray
    itself).  Maximum over rays, x and y; x 4 for the intersection and the refraction, each a
    few roundings: ``4 S eps (max(1, G_o) L + G_d)``."""
    o = rays.o.detach().clone().requires_grad_(True)
    d = rays.d.detach().clone().requires_grad_(True)
    g_o = g_d = 0.0
    for k in range(2):
        out = lens.trace_to_sensor(Rays(o, d, rays.wavelength, normalize=False))
        go, gd = torch.autograd.grad(out.o[:, k][out.valid].sum(), (o, d))
        g_o = max(g_o, float(go.abs().sum(-1).max()))
        g_d = max(g_d, float(gd.abs().sum(-1).max()))
    with torch.no_grad():
        L = max(float(lens.z_vertices().abs().max()), float(out.o.abs().max()))
    return 4 * len(lens.surfaces) * eps * (max(1.0, g_o) * L + g_d)


def test_float32_trace_lies_within_the_rounding_estimate_of_the_device_tests():
    """The estimate the CUDA tests use holds for the CPU's float32 trace, and it is tight
    enough to matter (under 0.1 % of the 10 deg field's image height)."""
    lens, rays = _double_gauss_fan(500)
    ref = lens.trace_to_sensor(rays)
    bound = _trace_error_bound(lens, rays, torch.finfo(F32).eps)
    out = lens.to(F32).trace_to_sensor(rays.to(F32))
    both = out.valid & ref.valid
    assert bool(ref.valid.all()) and bool(both.all())
    err = float((out.o[both, :2].double() - ref.o[both, :2]).abs().max())
    assert err <= bound < 1e-3 * float(ref.o[:, 1].abs().max())


@CUDA
@pytest.mark.parametrize("dtype", [F64, F32])
def test_cuda_trace_equals_the_cpu_trace(dtype):
    """Points, optical path lengths and validity on CUDA equal the CPU's within the rounding
    estimate at the dtype's epsilon (float64: ~1e-12 mm; a curvature changed by 1e-7 relative
    already moves the points by ~1e-6 mm)."""
    lens, rays = _double_gauss_fan()
    ref = lens.trace_to_sensor(rays)  # float64, CPU
    bound = _trace_error_bound(lens, rays, torch.finfo(dtype).eps)
    cpu = lens.to(dtype).trace_to_sensor(rays.to(dtype))
    lens_cuda = load_lens(H.LENS_DIR / "double_gauss.json").to(dtype).to("cuda")
    out = lens_cuda.trace_to_sensor(rays.to(dtype).to("cuda"))
    assert out.o.device.type == "cuda" and out.o.dtype == dtype
    valid = out.valid.cpu()
    assert torch.equal(valid, cpu.valid) and bool(ref.valid.all())
    for got in (out.o.cpu(), cpu.o):
        assert float((got[valid, :2].double() - ref.o[valid, :2]).abs().max()) <= bound
    # optical path lengths: each of the S segments (index <= 2) changes by at most twice the
    # position error, and the sum rounds at eps relative to the longest path
    S, eps = len(lens.surfaces), torch.finfo(dtype).eps
    tol = 2 * 2.0 * S * bound + 4 * S * eps * float(ref.opl.abs().max())
    for got in (out.opl.cpu(), cpu.opl):
        assert float((got[valid].double() - ref.opl[valid]).abs().max()) <= tol


@CUDA
def test_cuda_trace_gradients_equal_the_cpu_ones():
    """d(RMS spot)/d(curvatures) in float64 on CUDA equals the CPU's: a sum over 4000 rays
    in another order differs by ~n eps64 ~ 1e-12 relative; any difference of method by far
    more than the tolerance sqrt(eps64) ~ 1.5e-8."""
    grads = {}
    for device in ("cpu", "cuda"):
        lens, rays = _double_gauss_fan()
        lens = lens.to(device)
        curv = [s.c.requires_grad_(True) for s in lens.surfaces if hasattr(s, "c")]
        out = lens.trace_to_sensor(rays.to(device))
        pts = out.o[..., :2][out.valid]
        rms = torch.sqrt(((pts - pts.mean(0)) ** 2).sum(-1).mean())
        grads[device] = torch.stack(torch.autograd.grad(rms, curv)).cpu()
    g, ref = grads["cuda"], grads["cpu"]
    assert float(ref.abs().max()) > 0
    assert float((g - ref).abs().max()) <= math.sqrt(torch.finfo(F64).eps) * float(ref.abs().max())


# ------------------------------------------------------------------------- reversibility
def _misaligned_double_gauss():
    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    with torch.no_grad():
        m = lens.misalignments[3]
        m.dx.fill_(0.05)
        m.tilt_y.fill_(0.01)
        lens.misalignments[0].dy.fill_(-0.03)
    return lens


@pytest.mark.parametrize("mode", ["implicit", "unrolled"])
def test_forward_then_backward_returns_to_start(mode):
    lens = _misaligned_double_gauss()
    xy = H.disk_points(100, 3.0, seed=4)
    start = H.cat_rays(H.collimated(xy, [0.0, 0.0, 1.0], -5.0),
                       H.collimated(xy, [0.05, math.tan(math.radians(10)), 1.0], -5.0))
    opt = TraceOptions(mode=mode)
    fwd = lens.trace_to_sensor(start, options=opt)
    assert int(fwd.valid.sum()) > 150
    back = Rays(fwd.o, -fwd.d, fwd.wavelength, fwd.valid, normalize=False)
    back = lens.trace(back, reverse=True, options=opt)
    back = lens.propagate_to_z(back, -5.0, 1.0)
    ok = fwd.valid
    assert torch.equal(back.valid, ok)
    assert float((back.o - start.o)[ok].abs().max()) < 1e-9
    assert float((back.d + start.d)[ok].abs().max()) < 1e-12
    # the optical path is the same both ways
    assert float((back.opl - fwd.opl)[ok].abs().max()) < 1e-9


def test_tracing_does_not_mutate_rays_or_lens():
    lens = _misaligned_double_gauss()
    lens.surfaces[0].c.requires_grad_(True)
    lens.misalignments[3].tilt_y.requires_grad_(True)
    rays = _fan(F64, radius=3.0, n=50, angles=(0.0, 0.2))
    before_rays = {k: getattr(rays, k).clone() for k in Rays.__slots__}
    before_lens = {k: v.detach().clone() for k, v in lens.state_dict().items()}
    out = lens.trace_to_sensor(rays)
    back = lens.trace(Rays(out.o, -out.d, out.wavelength, out.valid), reverse=True)
    (H.weighted_image_sum(out, torch.ones(100, 2, dtype=F64)) + back.o.sum()).backward()
    for k, v in before_rays.items():
        assert torch.equal(getattr(rays, k), v), k
    for k, v in lens.state_dict().items():
        assert torch.equal(v, before_lens[k]), k
    assert out.o.data_ptr() != rays.o.data_ptr() and out.d.data_ptr() != rays.d.data_ptr()


def test_optical_path_length_through_a_plate():
    n_glass = float(M("N-BK7").n(H.WAVELENGTH_D))
    lens = Lens([Plane(5.0), Plane(5.0)], [M("AIR"), M("N-BK7"), M("AIR")], [2.0, 3.0], 4.0, 0)
    rays = H.collimated(H.disk_points(10, 3.0, seed=0), [0, 0, 1], 0.0)
    out = lens.trace_to_sensor(rays)
    assert float(out.o[:, 2].sub(9.0).abs().max()) < 1e-14
    assert float((out.opl - (2.0 + 3.0 * n_glass + 4.0)).abs().max()) < 1e-13


# ------------------------------------------------------------------------- misalignment
def test_decentered_singlet_moves_the_image_with_it():
    """A lens decentered by δ images an on-axis point at infinity to its own (shifted) focal
    point: the spot on the paraxial focal plane moves by δ, along δ."""
    lens = load_lens(H.LENS_DIR / "thorlabs_la1131.json")
    z_f = float(paraxial(lens, H.WAVELENGTH_D).image_z)
    rays = H.collimated(0.5 * hexapolar(6), [0, 0, 1], -2.0)  # symmetric about the axis

    def centroid():
        out = lens.trace_to_sensor(rays, z_image=z_f)
        assert bool(out.valid.all())
        return out.o[:, :2].mean(0)

    c0 = centroid()
    assert float(c0.abs().max()) < 1e-12
    for dx, dy in ((0.3, 0.0), (0.0, -0.2), (-0.25, 0.15)):
        with torch.no_grad():
            lens.misalignments[0].dx.fill_(dx)
            lens.misalignments[0].dy.fill_(dy)
        c = centroid()
        assert float(c[0]) == pytest.approx(dx, abs=2e-3 * abs(dx) + 1e-12)
        assert float(c[1]) == pytest.approx(dy, abs=2e-3 * abs(dy) + 1e-12)


@pytest.mark.parametrize("tilt_x,tilt_y", [(0.2, 0.0), (0.0, 0.2), (-0.15, 0.25)])
def test_tilted_plate_displaces_ray_by_closed_form(tilt_x, tilt_y):
    """A plate of thickness T and index n whose normal makes the angle θ with a ray shifts the
    ray sideways by T sin(θ - θ') / cos θ' (sin θ = n sin θ'), towards the normal's transverse
    part.  With R = R_y(tilt_y) R_x(tilt_x) (misalignment module) the plate normal is
    R e_z = (cos a sin b, -sin a, cos a cos b) for a = tilt_x, b = tilt_y."""
    T = 5.0
    n = float(M("N-BK7").n(H.WAVELENGTH_D))
    lens = Lens([Plane(10.0), Plane(10.0)], [M("AIR"), M("N-BK7"), M("AIR")], [3.0, T], 6.0, 0)
    with torch.no_grad():
        lens.misalignments[0].tilt_x.fill_(tilt_x)
        lens.misalignments[0].tilt_y.fill_(tilt_y)
    rays = H.collimated(torch.tensor([[0.0, 0.0], [1.0, -0.5]], dtype=F64), [0, 0, 1], 0.0)
    out = lens.trace_to_sensor(rays)
    a, b = tilt_x, tilt_y
    normal = torch.tensor([math.cos(a) * math.sin(b), -math.sin(a), math.cos(a) * math.cos(b)],
                          dtype=F64)
    theta = math.acos(float(normal[2]))
    th_t = math.asin(math.sin(theta) / n)
    shift = T * math.sin(theta - th_t) / math.cos(th_t)
    expect = shift * normal[:2] / normal[:2].norm()
    assert bool(out.valid.all())
    assert float((out.o[:, :2] - rays.o[:, :2] - expect).abs().max()) < 1e-12
    assert float((out.d - rays.d).abs().max()) < 1e-14  # leaves parallel to itself


def test_zero_misalignment_equals_none():
    """Trainable zeros run the frame transform; the result equals the skipped transform."""
    lens = _aperture_lens()
    rays = _fan(F64, radius=4.0, n=100, angles=(0.0, 0.1))
    ref = lens.trace_to_sensor(rays)
    for m in lens.misalignments:
        assert m.is_identity()
        for p in (m.dx, m.dy, m.tilt_x, m.tilt_y):
            p.requires_grad_(True)
        assert not m.is_identity()
    with torch.no_grad():
        out = lens.trace_to_sensor(rays)
    assert torch.equal(out.valid, ref.valid) and int(ref.valid.sum()) > 50
    assert float((out.o - ref.o)[ref.valid].abs().max()) < 1e-13
    assert float((out.d - ref.d)[ref.valid].abs().max()) < 1e-15


# ------------------------------------------------------------------------- first-order data
def traced_efl(lens, wavelength=H.WAVELENGTH_D, h=1e-3):
    """EFL from a real ray: a ray parallel to the axis at height h leaves with slope u',
    EFL = -h / u' (the paraxial limit; the error is O((h/f)^2))."""
    rays = H.collimated(torch.tensor([[0.0, h]], dtype=F64), [0, 0, 1], -20.0, wavelength)
    out = lens.trace(rays)
    assert bool(out.valid.all())
    return -h / float(out.d[0, 1] / out.d[0, 2])


def lensmaker(n, R1, R2, d):
    return 1.0 / ((n - 1) * (1 / R1 - 1 / R2 + (n - 1) * d / (n * R1 * R2)))


@pytest.mark.parametrize("R1,R2,d", [(40.0, -60.0, 5.0), (25.0, 80.0, 4.0), (-30.0, 45.0, 2.0),
                                     (15.0, -15.0, 8.0)])
def test_thick_singlet_efl_matches_lensmaker(R1, R2, d):
    n = float(M("N-BK7").n(H.WAVELENGTH_D))
    lens = H.singlet(Sphere(1 / R1, 6.0), Sphere(1 / R2, 6.0), thickness=d,
                     d_sensor=20.0)
    f = lensmaker(n, R1, R2, d)
    assert float(paraxial(lens, H.WAVELENGTH_D).efl) == pytest.approx(f, rel=1e-12)
    assert traced_efl(lens) == pytest.approx(f, rel=1e-6)


def test_la1131_efl():
    """Thorlabs LA1131 (N-BK7, R = 25.75 mm): f = 50.0 mm at 588 nm (catalogue, rounded); for a
    plano-convex lens the thick-lens EFL is exactly R / (n - 1)."""
    lens = load_lens(H.LENS_DIR / "thorlabs_la1131.json")
    n = float(M("N-BK7").n(H.WAVELENGTH_D))
    R = 1 / float(lens.surfaces[0].c)
    f = traced_efl(lens)
    assert f == pytest.approx(R / (n - 1), rel=1e-6)
    assert f == pytest.approx(50.0, rel=5e-3)


def test_acl5040u_efl():
    """Thorlabs ACL5040U (B270, R = 20.923 mm, k = -0.6405): f = 40 mm."""
    lens = load_lens(H.LENS_DIR / "thorlabs_acl5040u.json")
    n = float(M("B270").n(H.WAVELENGTH_D))
    f = traced_efl(lens)
    assert f == pytest.approx((1 / float(lens.surfaces[0].c)) / (n - 1), rel=1e-6)
    assert f == pytest.approx(40.0, rel=5e-3)


def test_double_gauss_efl():
    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    f = traced_efl(lens)
    assert abs(f - 27.44) / 27.44 < 1e-4
    assert f == pytest.approx(float(paraxial(lens, H.WAVELENGTH_D).efl), rel=1e-7)


def test_edof_achromat_efl():
    """Thorlabs AC254-100-A (N-BK7/SF5 cemented achromat): EFL 100.0 mm; the N-BK7 plate and the
    flat XY surface behind it change nothing."""
    lens = load_lens(H.LENS_DIR / "edof_achromat.json")
    radii = [1 / float(lens.surfaces[i].c) for i in range(3)]
    assert radii == pytest.approx([62.8, -45.7, -128.2], abs=0.05)  # published prescription
    assert [float(lens.distances[i]) for i in (1, 2)] == [4.0, 2.5]
    assert [m.name for m in lens.materials[1:3]] == ["N-BK7", "SF5"]
    f = traced_efl(lens)
    assert f == pytest.approx(100.0, rel=1e-2)
    assert f == pytest.approx(float(paraxial(lens, H.WAVELENGTH_D).efl), rel=1e-7)


# ------------------------------------------------------------------------- extremes
def _loss_and_grads(lens, rays, params, options=None):
    out = lens.trace_to_sensor(rays, options=options)
    w = torch.ones(out.valid.shape[0], 2, dtype=out.o.dtype)
    loss = H.weighted_image_sum(out, w)
    if not loss.requires_grad:  # every ray invalid: the masked loss is a constant zero
        return out, loss, [torch.zeros_like(p) for p in params]
    grads = torch.autograd.grad(loss, params, allow_unused=True, materialize_grads=True)
    return out, loss, grads


def _assert_finite(out, grads):
    for t in (out.o, out.d, out.opl):
        assert bool(torch.isfinite(t).all())
    for g in grads:
        assert bool(torch.isfinite(g).all())


def _grazing_bundle(R, cases, dtype):
    """Forward rays (d_z > 0) that hit the sphere of radius R (vertex at 0) at the point
    P = (-r0, 0, sag(r0)) with incidence angle ``inc`` (deg), starting 10 mm before P."""
    o, d, p = [], [], []
    for r0, inc in cases:
        P = torch.tensor([-r0, 0.0, R - math.sqrt(R * R - r0 * r0)], dtype=F64)
        n_in = (torch.tensor([0.0, 0.0, R], dtype=F64) - P) / R
        t = torch.tensor([n_in[2], 0.0, -n_in[0]], dtype=F64)
        t = t if t[2] > 0 else -t
        a = math.radians(inc)
        di = math.cos(a) * n_in + math.sin(a) * t
        o.append(P - 10.0 * di)
        d.append(di)
        p.append(P)
    return (torch.stack(o).to(dtype), torch.stack(d).to(dtype), torch.stack(p))


@pytest.mark.parametrize("dtype", [F64, F32], ids=["float64", "float32"])
def test_grazing_rays(dtype):
    """A sphere (R = 20 mm) in N-BK7: rays exactly parallel to the vertex plane (d_z = 0) and
    nearly so (d_z = 1e-9: the vertex plane is 3e10 mm away) are invalid; rays hitting the cap
    at 60 to 89.9 deg incidence find the *first* crossing P (not the exit point of the chord),
    refract by Snell's law, and everything, gradients included, stays finite."""
    R = 20.0
    lens = Lens([Sphere(1 / R, 9.0)], [M("AIR"), M("N-BK7")], [0.0], 10.0, 0).to(dtype)
    params = _unfreeze_all(lens)
    cases = [(r0, inc) for r0 in (2.0, 6.0, 8.5) for inc in (60.0, 85.0, 89.0, 89.9)]
    o, d, P = _grazing_bundle(R, cases, dtype)
    o = torch.cat([torch.tensor([[-30.0, 0.0, 0.5], [-30.0, 1.0, -0.2]], dtype=dtype), o])
    d = torch.cat([torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 1e-9]], dtype=dtype), d])
    rays = Rays(o, d, H.WAVELENGTH_D)
    out = lens.trace(rays)
    assert out.valid.tolist() == [False, False] + [True] * len(cases)
    for t in (out.o, out.d, out.opl):
        assert bool(torch.isfinite(t).all())
    tol = 1e-9 if dtype == F64 else 2e-3
    assert float((out.o[2:].detach().double() - P).abs().max()) < tol
    # Snell: sin(theta_t) = sin(theta_i) / n
    n = float(M("N-BK7").n(H.WAVELENGTH_D))
    normal = (torch.tensor([0.0, 0.0, R], dtype=F64) - P) / R
    sin_t = torch.linalg.cross(out.d[2:].detach().double(), normal).norm(dim=-1)
    expect = torch.sin(torch.deg2rad(torch.tensor([c[1] for c in cases], dtype=F64))) / n
    assert float((sin_t - expect).abs().max()) < (1e-12 if dtype == F64 else 1e-3)
    w = torch.randn(len(cases) + 2, 2, generator=torch.Generator().manual_seed(3),
                    dtype=F64).to(dtype)
    loss = H.weighted_image_sum(out, w) + torch.where(out.valid, out.d[:, 0], 0 * out.opl).sum()
    grads = torch.autograd.grad(loss, params, allow_unused=True, materialize_grads=True)
    g_c = grads[[p is lens.surfaces[0].c for p in params].index(True)]
    assert bool(g_c != 0)  # the curvature moves the grazing hits
    for g in grads:
        assert bool(torch.isfinite(g).all())


@pytest.mark.parametrize("dtype", [F64, F32], ids=["float64", "float32"])
def test_flat_asphere_c_zero_gradient(dtype):
    """c = 0 (flat) traced by Newton like any asphere: equal to a Plane, finite gradient in c
    equal to the finite difference (float64)."""
    flat = H.singlet(Asphere(0.0, 6.0), Sphere(-1 / 30, 6.0)).to(dtype)
    plane = H.singlet(Plane(6.0), Sphere(-1 / 30, 6.0)).to(dtype)
    rays = _fan(dtype, radius=4.0, n=60, angles=(0.0, 0.1))
    a, b = flat.trace_to_sensor(rays), plane.trace_to_sensor(rays)
    assert torch.equal(a.valid, b.valid) and bool(a.valid.all())
    tol = 1e-12 if dtype == F64 else 1e-4
    assert float((a.o - b.o).abs().max()) < tol
    c = flat.surfaces[0].c
    c.requires_grad_(True)
    out, loss, (g,) = _loss_and_grads(flat, rays, [c])
    _assert_finite(out, [g])
    assert abs(float(g)) > 1.0
    if dtype == F64:
        fd = H.central_fd(lambda: _loss_and_grads(flat, rays, [c])[1], c, 1e-5)
        assert H.rel_err(g, fd) < 1e-6


@pytest.mark.parametrize("dtype", [F64, F32], ids=["float64", "float32"])
def test_near_hemisphere(dtype):
    """A surface with c * semi-diameter = 0.999 (slope ~22 at the rim): rays across the whole
    aperture are traced, rays beyond the sphere are invalid, everything stays finite."""
    R = 5.0
    lens = H.singlet(Sphere(1 / R, 0.999 * R), Plane(0.999 * R), thickness=6.0,
                     d_sensor=10.0).to(dtype)
    params = _unfreeze_all(lens)
    xy = torch.cat([H.disk_points(300, 1.2 * R, seed=6, dtype=dtype),
                    torch.tensor([[0.998 * R, 0.0], [0.0, -0.9985 * R]], dtype=dtype)])
    rays = H.collimated(xy, [0, 0, 1], -1.0)
    out, _, grads = _loss_and_grads(lens, rays, params)
    _assert_finite(out, grads)
    with torch.no_grad():  # surface 0 has its vertex at the origin and no misalignment
        _, x, hit = intersect(lens.surfaces[0], rays.o, rays.d, rays.valid)
    r = xy.norm(dim=-1)
    assert not bool(hit[r > R].any())
    assert bool(hit[r < 0.99 * R].all())
    assert bool(hit[-2:].all())  # at the rim
    if dtype == F64:  # the rim rays hit the closed-form sphere
        z = R - torch.sqrt(R * R - r[-2:] ** 2)
        assert float((x[-2:, 2] - z).abs().max()) < 1e-9


@pytest.mark.parametrize("dtype", [F64, F32], ids=["float64", "float32"])
def test_all_rays_miss(dtype):
    """No ray reaches the sensor: every output is finite and the masked loss has an exactly
    zero gradient (a NaN on a masked ray would survive as 0 * NaN = NaN)."""
    lens = _aperture_lens().to(dtype)
    params = _unfreeze_all(lens)
    rays = H.collimated(torch.tensor([[20.0, 0.0], [0.0, -15.0]], dtype=dtype), [0, 0, 1], -3.0)
    out = lens.trace_to_sensor(rays)
    assert not bool(out.valid.any())
    _assert_finite(out, [])
    loss = H.weighted_image_sum(out, torch.ones(2, 2, dtype=dtype))
    assert loss.requires_grad  # the masked-out positions still depend on the lens
    for g in torch.autograd.grad(loss, params, allow_unused=True, materialize_grads=True):
        assert bool(torch.isfinite(g).all()) and not bool(g.any())


def test_optics_imports_nothing_above_it():
    """``deeplens.optics`` is the bottom layer: importing it (and its lens-file readers) loads
    no analysis, render or training module, nor Lightning or Hydra; the common names are
    importable from the package."""
    import subprocess
    import sys

    code = ("import sys; from deeplens.optics import Lens, load_lens, Rays; "
            "from deeplens.optics.paraxial import paraxial; "
            "import deeplens.optics.io.table; "
            "bad = [m for m in sys.modules if m.split('.')[0] in ('lightning', 'hydra', "
            "'pytorch_lightning') or m.startswith(('deeplens.analysis', 'deeplens.render', "
            "'deeplens.training'))]; print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_lens_dtype_and_device_follow_its_values():
    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    assert lens.dtype == torch.float64 and lens.device == torch.device("cpu")
    lens = lens.float()
    assert lens.dtype == torch.float32 == lens.surfaces[0].c.dtype

