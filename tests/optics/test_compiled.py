"""``TraceOptions(compile=...)``: runs of aligned spheres, conics, planes and stops, and even
aspheres' Newton iterations, through fused ``torch.compile`` kernels (:mod:`deeplens.optics.compiled`).

Two layers, so that the default suite pays little compilation:

* the fused path's *logic* (run grouping, the component-major state, the Newton chunks with their
  host checks, the pure kernels ``flat_step_xyz`` / ``asphere_*``) runs with the plain Python
  functions in place of the compiled ones (``uncompiled`` fixture, no compiler): values and
  gradients must equal the eager tracer's in float64 for the double Gauss forward and reverse,
  with a misaligned element (eager in between compiled runs), a rectangular stop, vignetted
  rays, ``checkpoint=True``, and a lens with total internal reflection;
* the compiled kernels themselves (C++ through inductor on CPU, Triton on CUDA), kept to two
  small forward traces in the default suite (compiling costs 10-30 s of CPU per test on a
  clean machine): float64 ``compile="surface"`` against eager and the generic Newton path
  ``closed_form=False``, forward and reverse, and float32 ``compile="lens"`` with two ray
  counts.  The compiled *backward* (inductor's derivative of the same graphs; compiling it
  costs about a minute more) is checked against eager and central finite differences in
  float64 by a ``slow`` test.
"""

import helpers as H
import pytest
import torch

from deeplens.optics.options import TraceOptions
from deeplens.optics.io import load_lens
from deeplens.optics.rays import Rays
from deeplens.optics.sampling import field_rays
from deeplens.optics.surfaces import Aperture, Asphere, Sphere

F64 = torch.float64
EAGER = TraceOptions(compile=False)
GENERIC = TraceOptions(tol=1e-13, closed_form=False)


def _lens(misalign=False, rect_stop=False):
    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    if misalign:
        with torch.no_grad():
            lens.misalignments[3].dx.fill_(0.02)
    if rect_stop:
        stop = lens.surfaces[lens.stop_index]
        lens.surfaces[lens.stop_index] = Aperture(None, "rect", float(stop.semi_diameter),
                                                  0.6 * float(stop.semi_diameter))
    s0, s4 = lens.surfaces[0], lens.surfaces[4]
    params = [s0.c, s0.k, s0.a[0], s4.c, lens.distances[3], lens.d_sensor]
    if misalign:
        params.append(lens.misalignments[3].dx)
    for p in params:
        p.requires_grad_(True)
    return lens, params


def _rays(lens, n=200, reverse=False, dtype=F64):
    if reverse:
        xy = H.disk_points(n, 4.0, seed=2)
        z0 = float(lens.z_sensor().detach())
        o = torch.cat([xy, torch.full((n, 1), z0, dtype=F64)], -1)
        d = torch.tensor([0.1, -0.05, -1.0], dtype=F64).expand(n, 3)
        rays = Rays(o, d, H.WAVELENGTH_D)
    else:  # a pupil 20 % larger than the lens passes: vignetted rays too
        rays = field_rays(lens, 10.0, H.WAVELENGTH_D, H.disk_points(n, 2.6, seed=2), 6.0)
    return rays.to(dtype)


def _trace(lens, rays, opt, reverse):
    out = lens.trace(rays, reverse=True, options=opt) if reverse else \
        lens.trace_to_sensor(rays, options=opt)
    w = torch.randn(len(rays), 3, generator=torch.Generator().manual_seed(4), dtype=rays.dtype)
    v = out.valid
    loss = (torch.where(v[:, None], out.o, 0 * out.o) * w).sum() + out.opl[v].sum() \
        + (out.d[v] * w[v]).sum()
    return out, loss


def _assert_same(lens, params, rays, opt, reverse, ref_opt=EAGER, tol=1e-12, gtol=1e-10):
    a, la = _trace(lens, rays, ref_opt, reverse)
    b, lb = _trace(lens, rays, opt, reverse)
    assert torch.equal(a.valid, b.valid)
    assert 0.3 * len(a.valid) < int(a.valid.sum()) < len(a.valid)  # vignetted rays as well
    v = a.valid
    for x, y in ((a.o, b.o), (a.d, b.d), (a.opl, b.opl)):
        assert float((x - y)[v].detach().abs().max()) < tol
        assert bool(torch.isfinite(y).all())
    ga = torch.autograd.grad(la, params, allow_unused=True)
    gb = torch.autograd.grad(lb, params, allow_unused=True)
    for p, x, y in zip(params, ga, gb):
        assert (x is None) == (y is None)
        if x is not None:
            assert H.rel_err(x, y) < gtol, (p.shape, x, y)
    return a, b


# ----------------------------------------------------------------- the fused logic, no compiler
@pytest.mark.parametrize("mode", ["surface", "lens", "auto"])
@pytest.mark.parametrize("reverse", [False, True], ids=["forward", "reverse"])
@pytest.mark.parametrize("misalign", [False, True], ids=["aligned", "misaligned"])
def test_fused_path_equals_eager(uncompiled, mode, reverse, misalign):
    lens, params = _lens(misalign=misalign)
    _assert_same(lens, params, _rays(lens, reverse=reverse), TraceOptions(compile=mode),
                 reverse)


@pytest.mark.parametrize("mode", ["surface", "lens"])
def test_fused_path_last_element_eager(uncompiled, mode):
    """The last element misaligned: its surfaces run eager, so the move to the sensor (fused into
    the last compiled kernel otherwise) runs eager too; values and gradients (``d_sensor``
    included) as the eager tracer's."""
    lens, params = _lens()
    last = lens.misalignments[-1]
    with torch.no_grad():
        last.dy.fill_(-0.03)
    last.dy.requires_grad_(True)
    _assert_same(lens, params + [last.dy], _rays(lens), TraceOptions(compile=mode), False)


def test_fused_path_rect_stop_and_checkpoint(uncompiled):
    lens, params = _lens(rect_stop=True)
    rays = _rays(lens)
    _assert_same(lens, params, rays, TraceOptions(compile="lens", checkpoint=True), False)
    # the rectangle clips: fewer rays pass than through the circular stop
    n_rect = int(lens.trace_to_sensor(rays, options=TraceOptions(compile=True)).valid.sum())
    lens_c, _ = _lens()
    assert n_rect < int(lens_c.trace_to_sensor(rays).valid.sum())


def test_from_soa_copy_is_from_soa():
    """The compiled trace's last layout change (``tracer.from_soa_copy``: per-component copies
    without autograd on the CPU) gives ``rays.from_soa``'s tensor bitwise, contiguous, for one
    and two batch dimensions; with autograd it is ``from_soa`` itself (same gradient)."""
    from deeplens.optics.rays import from_soa
    from deeplens.optics.tracer import from_soa_copy

    g = torch.Generator().manual_seed(0)
    for shape in ((3, 37), (3, 5, 7)):
        v = torch.randn(shape, generator=g)
        a, b = from_soa_copy(v), from_soa(v)
        assert a.shape == b.shape == (*shape[1:], 3) and a.is_contiguous()
        assert torch.equal(a, b)
        w = v.clone().requires_grad_(True)
        out = from_soa_copy(w)
        assert out.grad_fn is not None and torch.equal(out.detach(), b)
        (out * torch.arange(3.0)).sum().backward()
        assert torch.equal(w.grad, torch.arange(3.0)[:, None, None].expand(shape).reshape(shape)
                           if len(shape) == 3 else torch.arange(3.0)[:, None].expand(shape))


def test_fused_path_forward_without_grad_equals_eager(uncompiled):
    """Without autograd (where ``from_soa_copy`` copies per component) the fused path's spot
    points, directions and valid rays equal the eager tracer's (float64, as the gradient tests;
    the plain functions in place of the compiled ones)."""
    lens, _ = _lens()
    rays = _rays(lens)
    with torch.no_grad():
        a = lens.trace_to_sensor(rays, options=EAGER)
        for mode in ("surface", "lens"):
            b = lens.trace_to_sensor(rays, options=TraceOptions(compile=mode))
            assert torch.equal(a.valid, b.valid) and a.o.is_contiguous() == b.o.is_contiguous()
            torch.testing.assert_close(b.o, a.o, rtol=0, atol=1e-12)
            torch.testing.assert_close(b.d, a.d, rtol=0, atol=1e-12)


@pytest.mark.filterwarnings("ignore:intersect.*did not converge:RuntimeWarning")  # max_iter=2
def test_fused_path_total_internal_reflection_and_newton_chunks(uncompiled):
    """A strong conic and an asphere into air (some rays totally internally reflected), and a
    Newton iteration cut at ``max_iter`` at the end of a chunk (2: rays that meet the tolerance
    only after the last update count as converged) and in the middle of one (3)."""
    from deeplens.optics.lens import Lens
    from deeplens.optics.materials import get_material

    back = Asphere(-1 / 6.0, 5.0, conic=-0.4)
    asph = Asphere(-1 / 7.0, 5.0, conic=-0.3, coefficients=[2e-4, -1e-6])
    air, glass = get_material("AIR"), get_material("N-SF5")
    for surf in (back, asph):
        lens = Lens([Sphere(1 / 20.0, 9.0), surf], [air, glass, air], [0.0, 3.0], 10.0, 0)
        params = [surf.c, surf.k, lens.distances[1]] + list(getattr(surf, "a", []))
        for p in params:
            p.requires_grad_(True)
        rays = H.collimated(H.disk_points(300, 5.5, seed=5), [0.1, 0.05, 1.0], -2.0)
        for opt in (TraceOptions(compile="lens"),
                    TraceOptions(compile="surface", max_iter=2, tol=1e-12),
                    TraceOptions(compile="surface", max_iter=3, tol=1e-12)):
            ref = TraceOptions(max_iter=opt.max_iter, tol=opt.tol)
            a, _ = _assert_same(lens, params, rays, opt, False, ref_opt=ref)
            tir = a.valid.logical_not() & (a.o[:, :2].norm(dim=-1) < 4.5)
            assert int(tir.sum()) > 10  # TIR, not only aperture misses


@pytest.mark.parametrize("b", [0.0, 0.004])
@pytest.mark.parametrize("reverse", [False, True], ids=["forward", "reverse"])
def test_fused_path_xy_polynomial_equals_eager(uncompiled, reverse, b):
    """The EDOF lens (achromat and an XY-polynomial plate, Newton from the vertex plane) with
    a cubic plate, with and without the ``z^2`` term ``b`` (its domain check)."""
    lens = load_lens(H.LENS_DIR / "edof_achromat.json")
    plate = lens.surfaces[4]
    with torch.no_grad():
        plate.a[9].fill_(2e-4)  # x^3
        plate.a[6].fill_(-1.5e-4)  # y^3
        plate.a[4].fill_(3e-4)  # xy
        plate.b.fill_(b)
    params = [plate.a[9], plate.a[4], plate.b, lens.surfaces[0].c, lens.d_sensor]
    for p in params:
        p.requires_grad_(True)
    if reverse:
        xy = H.disk_points(200, 0.8, seed=6)
        o = torch.cat([xy, torch.full((200, 1), float(lens.z_sensor().detach()), dtype=F64)], -1)
        d = H.disk_points(200, 0.06, seed=7)
        rays = Rays(o, torch.cat([d, -torch.ones(200, 1, dtype=F64)], -1), H.WAVELENGTH_D)
    else:
        rays = field_rays(lens, 0.5, H.WAVELENGTH_D, H.disk_points(200, 7.0, seed=2), 0.0)
    _assert_same(lens, params, rays, TraceOptions(compile="lens"), reverse)


def test_compile_option_is_checked():
    assert TraceOptions(compile=True).compile == "auto"
    assert TraceOptions().compile == "default"
    assert TraceOptions(compile=None).compile is False
    assert TraceOptions(compile=False).compile is False
    with pytest.raises(ValueError, match="compile must be"):
        TraceOptions(compile="fast")


# ----------------------------------------------------------------- the compiled kernels
def test_compiled_surface_kernels_float64():
    """float64 without gradients, ``compile="surface"`` (each kind of surface one kernel, forward
    and reverse share them): the compiled trace equals the eager one and the generic Newton
    path's, vignetted rays included."""
    lens, _ = _lens()
    opt = TraceOptions(compile="surface")
    for reverse in (False, True):
        rays = _rays(lens, reverse=reverse)
        with torch.no_grad():
            a, _ = _trace(lens, rays, EAGER, reverse)
            g, _ = _trace(lens, rays, GENERIC, reverse)
            b, _ = _trace(lens, rays, opt, reverse)
        assert torch.equal(a.valid, b.valid) and torch.equal(g.valid, b.valid)
        assert 0.3 * len(a.valid) < int(a.valid.sum()) < len(a.valid)
        v = a.valid
        for x, y, z in ((a.o, b.o, g.o), (a.d, b.d, g.d), (a.opl, b.opl, g.opl)):
            assert float((x - y)[v].abs().max()) < 1e-12
            assert float((z - y)[v].abs().max()) < 1e-11


@pytest.mark.slow
def test_compiled_surface_kernels_float64_gradients():
    """float64, ``compile="surface"``: the compiled trace equals the eager one (values to
    1e-12 mm, gradients to 1e-10), forward and reverse (the same kernels), equals the generic
    Newton path, and its gradient equals a central finite difference of the compiled trace.
    Every curvature and distance is trainable, so that each kernel compiles once."""
    lens, params = _lens()
    params = params + [s.c for s in lens.surfaces[1:] if hasattr(s, "c")] + list(lens.distances)
    params = list({id(p): p for p in params}.values())
    for p in params:
        p.requires_grad_(True)
    opt = TraceOptions(compile="surface")
    rays = _rays(lens)
    _assert_same(lens, params, rays, opt, False)
    _assert_same(lens, params, rays, opt, False, ref_opt=GENERIC, tol=1e-11, gtol=1e-8)
    _assert_same(lens, params, _rays(lens, reverse=True), opt, True)

    rays = field_rays(lens, 0.0, H.WAVELENGTH_D, H.disk_points(100, 2.2, seed=3), 6.0)

    def rms():  # with autograd on, as the gradient (no extra inference kernels to compile)
        out = lens.trace_to_sensor(rays, options=opt)
        assert bool(out.valid.all())
        pts = out.o[..., :2]
        return torch.sqrt(((pts - pts.mean(0)) ** 2).sum(-1).mean())

    asph, sph = lens.surfaces[0].a[0], lens.surfaces[4].c
    g = torch.autograd.grad(rms(), [asph, sph])
    for p, gp, h in ((asph, g[0], 1e-9), (sph, g[1], 1e-6)):
        f = {}
        p0 = p.detach().clone()
        for k in (-2, -1, 1, 2):
            with torch.no_grad():
                p.copy_(p0 + k * h)
            f[k] = float(rms())
        with torch.no_grad():
            p.copy_(p0)
        fd = (8.0 * (f[1] - f[-1]) - (f[2] - f[-2])) / (12.0 * h)
        assert abs(float(gp)) * h > 1e-12
        assert H.rel_err(gp, fd) < 1e-6, (float(gp), fd)


def test_compiled_lens_run_float32_forward():
    """float32 without gradients, ``compile="lens"``: a singlet with a stop (one kernel for the
    three surfaces), 2000 rays and then 3000 (the ray count is dynamic): the same valid rays as
    eager, and the spot points within float32 rounding of the eager trace."""
    from deeplens.optics.lens import Lens
    from deeplens.optics.materials import get_material

    air = get_material("AIR")
    lens = Lens([Aperture(6.0), Sphere(1 / 30.0, 12.0), Sphere(-1 / 40.0, 12.0)],
                [air, air, get_material("N-BK7"), air], [0.0, 2.0, 6.0], 40.0, 0)
    for n in (2000, 3000):
        rays = H.collimated(H.disk_points(n, 8.0, seed=n, dtype=torch.float32),
                            [0.05, 0.0, 1.0], -5.0)
        with torch.no_grad():
            a = lens.trace_to_sensor(rays)
            b = lens.trace_to_sensor(rays, options=TraceOptions(compile=True))
        assert torch.equal(a.valid, b.valid) and 0.3 * n < int(a.valid.sum()) < n
        eps = torch.finfo(torch.float32).eps
        assert float((a.o - b.o)[a.valid].abs().max()) < 4 * 8 * eps * 50  # 4 steps, |x| < 50
        assert float((a.d - b.d)[a.valid].abs().max()) < 4 * 8 * eps
