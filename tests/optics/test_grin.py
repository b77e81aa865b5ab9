"""Gradient-index media (deeplens/optics/grin.py, grin_trace.py): real rays against closed forms,
the paraxial rod matrix against its closed form and pygrin, gradients against central
differences, rays lost through the rod's wall, and OpticStudio's ``GRINSUR1`` records.

The square-law rod ``n² = n0² (1 − g² r²)``, entered from air through a plane at ``z = 0``:
with ``T = n dr/ds`` and the optical-path parameter ``t`` (``ds = n dt``) the ray equation is
``dT/dt = ½ ∇n² = −n0² g² (x, y, 0)``, so ``T_z = β`` is constant and each transverse
coordinate is a harmonic oscillator of angular frequency ``Ω = n0 g`` in ``t``:

    x(t) = x0 cos Ωt + (T_x0 / Ω) sin Ωt,      T_x(t) = −x0 Ω sin Ωt + T_x0 cos Ωt

(and ``y`` alike; ``z = β t``: meridional rays are exact sinusoids in ``z``).  At a plane the
tangential part of ``n d`` is continuous (Snell), so from air ``T_x0`` is the incoming
direction's ``x`` component, ``β = sqrt(n(r0)² − |T_⊥0|²)``, and the direction in air after the
exit plane ``z = L`` has transverse components ``T_⊥(L / β)``.  The optical path inside is
``∫ n² dt = ∫ (β² + |T_⊥|²) dt``, integrated in closed form below.
"""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics import Lens, TraceOptions
from deeplens.optics.grin import RadialGradient, SquareLawGradient, radial_transfer
from deeplens.optics.io import read_zmx, write_zmx
from deeplens.optics.materials import Air
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Plane

N0, G, L = 1.5, 0.3, 4.0          # gL = 1.2 rad: about a fifth of a period
Z0 = -1.0                         # the rays start 1 mm before the rod


def rod(medium, length=L, radius=1.0, d_sensor=5.0):
    return Lens([Plane(radius), Plane(radius)], [Air(), medium, Air()], [0.0, length],
                d_sensor, 0)


def launch(starts, dirs, dtype=torch.float64):
    """Rays from ``(x, y)`` at ``z = Z0`` along unit directions ``dirs``."""
    o = torch.tensor([[x, y, Z0] for x, y in starts], dtype=dtype)
    d = torch.tensor(dirs, dtype=dtype)
    d = d / d.norm(dim=-1, keepdim=True)
    return Rays(o, d, torch.full((len(starts),), 550.0, dtype=dtype))


def exact(o, d, n0=N0, g=G, length=L):
    """The closed form (module docstring) for one ray from ``o`` along ``d`` (floats): the
    exit point's ``(x, y)``, the direction's ``(x, y)`` in air and the optical path from ``o``
    to the exit plane."""
    t_air = -o[2] / d[2]
    p = [o[0] + t_air * d[0], o[1] + t_air * d[1]]
    n_in = n0 * math.sqrt(1 - g * g * (p[0] ** 2 + p[1] ** 2))
    T = [d[0], d[1]]
    beta = math.sqrt(n_in ** 2 - T[0] ** 2 - T[1] ** 2)
    om, tau = n0 * g, length / beta
    c, s = math.cos(om * tau), math.sin(om * tau)
    x = [p[k] * c + T[k] / om * s for k in range(2)]
    tx = [-p[k] * om * s + T[k] * c for k in range(2)]
    opl = t_air + beta * beta * tau
    for k in range(2):   # ∫ (a sin Ωt + b cos Ωt)² dt over [0, τ]
        a, b = -p[k] * om, T[k]
        opl += (a * a * (tau / 2 - math.sin(2 * om * tau) / (4 * om))
                + b * b * (tau / 2 + math.sin(2 * om * tau) / (4 * om))
                + a * b * s * s / om)
    return x, tx, opl


STARTS = [(0.0, 0.0), (0.3, 0.0), (-0.5, 0.0), (0.2, -0.35), (0.6, 0.1)]
DIRS = [(0.2, 0.0, 1.0), (0.1, 0.0, 1.0), (0.0, 0.0, 1.0), (-0.15, 0.1, 1.0), (0.05, -0.2, 1.0)]


def errors(step):
    """Largest errors of the traced exit point, direction and optical path against the closed
    form, for the rays of STARTS/DIRS at integration step ``step`` (mm)."""
    lens = rod(SquareLawGradient(N0, G, step_mm=step))
    rays = launch(STARTS, DIRS)
    out = lens.trace(rays)
    assert bool(out.valid.all())
    ex = [0.0, 0.0, 0.0]
    for j in range(len(STARTS)):
        x, tx, opl = exact(rays.o[j].tolist(), rays.d[j].tolist())
        ex[0] = max(ex[0], *(abs(float(out.o[j, k]) - x[k]) for k in range(2)))
        ex[1] = max(ex[1], *(abs(float(out.d[j, k]) - tx[k]) for k in range(2)))
        ex[2] = max(ex[2], abs(float(out.opl[j]) - opl))
        assert float(out.o[j, 2]) == pytest.approx(L, abs=1e-12)   # on the exit plane
    return ex


def test_square_law_rod_matches_the_closed_form():
    """(a) Meridional and skew rays through the square-law rod: the exit point and direction
    to 1e-10 and the optical path to 1e-8 mm at a 0.02 mm step; the errors are the method's
    truncation, which falls at least 2³-fold (2⁴ for the position and direction, the scheme's
    order; Simpson's rule on the path is third order) when the step halves, and the error at
    0.02 mm lies within its Richardson estimate from 0.04 mm."""
    e04, e02 = errors(0.04), errors(0.02)
    assert e02[0] < 1e-10 and e02[1] < 1e-10 and e02[2] < 1e-8, e02
    coarse, fine = errors(0.4), errors(0.2)
    for k in range(3):
        assert coarse[k] / fine[k] > 7.0, (k, coarse, fine)
        assert e02[k] <= abs(e04[k] - e02[k]) + 1e-13, (k, e04, e02)


def test_reverse_trace_retraces_the_path():
    """Rays traced back from the exit return to their entry points through the same medium
    (the integration runs towards −z with the next surface behind)."""
    lens = rod(SquareLawGradient(N0, G, step_mm=0.02))
    rays = launch(STARTS, DIRS)
    fwd = lens.trace(rays)
    back = Rays(fwd.o, -fwd.d, fwd.wavelength)
    ret = lens.trace(back, reverse=True)
    assert bool(ret.valid.all())
    t_air = -rays.o[:, 2] / rays.d[:, 2]
    entry = rays.o + t_air.unsqueeze(-1) * rays.d
    torch.testing.assert_close(ret.o, entry, rtol=0, atol=1e-10)
    torch.testing.assert_close(ret.d, -rays.d, rtol=0, atol=1e-10)


def test_float32_trace_is_close_to_float64():
    """Float32 rays through a float32 lens: the exit point agrees with float64 to a few hundred
    float32 roundings (about 60 steps, each rounding at 6e-8 relative)."""
    lens = rod(SquareLawGradient(N0, G, step_mm=0.1))
    out64 = lens.trace(launch(STARTS, DIRS))
    out32 = lens.to(torch.float32).trace(launch(STARTS, DIRS, torch.float32))
    assert out32.o.dtype == torch.float32 and bool(out32.valid.all())
    torch.testing.assert_close(out32.o.double(), out64.o, rtol=0, atol=2e-5)


# ------------------------------------------------------------------ paraxial
def rod_efl_bfl(n0, nr2, length):
    """The closed form (deeplens/optics/grin.py): EFL = 1 / (n0 g sin gL), back focal distance
    from the exit face cos gL / (n0 g sin gL); g² < 0 with cosh, sinh."""
    g2 = -2 * nr2 / n0
    if g2 > 0:
        g = math.sqrt(g2)
        return 1 / (n0 * g * math.sin(g * length)), 1 / (n0 * g * math.tan(g * length))
    h = math.sqrt(-g2)
    return -1 / (n0 * h * math.sinh(h * length)), -1 / (n0 * h * math.tanh(h * length))


@pytest.mark.parametrize("nr2", [-0.083, -0.02, 0.03])
def test_paraxial_rod_matches_the_closed_form(nr2):
    """(b) The paraxial EFL and back focal distance of a Gradient 1 rod between planes, both
    signs of the gradient (a converging and a diverging rod), to 1e-13 relative."""
    p = paraxial(rod(RadialGradient(N0, nr2)))
    efl, bfl = rod_efl_bfl(N0, nr2, L)
    assert float(p.efl) == pytest.approx(efl, rel=1e-13)
    assert float(p.bfl) == pytest.approx(bfl, rel=1e-13)


def test_paraxial_rod_matches_pygrin():
    """(b) pygrin (an independent GRIN library: its parabolic profile n0 (1 − g² r² / 2), our
    nr2 = −n0 g² / 2) gives the same EFL and back focal length (pygrin's from the front face)."""
    pygrin = pytest.importorskip("pygrin")
    nr2 = -0.083
    g = math.sqrt(-2 * nr2 / N0)
    pitch = g * L / (2 * math.pi)
    assert pygrin.parabolic_profile_index(N0, pitch, L, 0.7) == pytest.approx(
        N0 + nr2 * 0.49, rel=1e-14)
    p = paraxial(rod(RadialGradient(N0, nr2)))
    assert float(p.efl) == pytest.approx(pygrin.EFL(N0, pitch, L), rel=1e-13)
    assert float(p.bfl) + L == pytest.approx(pygrin.BFL(N0, pitch, L), rel=1e-13)


def test_transfer_matrix_is_smooth_through_a_vanishing_gradient():
    """Near g = 0 the series branch joins the circular and hyperbolic ones (the Taylor series
    to q³ at |q| < 1e-3 is exact to 1e-13) and tends to the homogeneous slab; the derivative
    with respect to g² is finite at g² = 0 (−L² / 2 for the diagonal)."""
    n0, length = torch.tensor(1.5, dtype=torch.float64), torch.tensor(2.0, dtype=torch.float64)
    for q in (-1.01e-3, -0.99e-3, 0.99e-3, 1.01e-3):
        g2 = torch.tensor(q, dtype=torch.float64) / length ** 2
        A, B, C, D = radial_transfer(g2, length, n0)
        root = math.sqrt(abs(q))
        c = math.cos(root) if q > 0 else math.cosh(root)
        s = (math.sin(root) if q > 0 else math.sinh(root)) / root
        assert float(A) == pytest.approx(c, abs=1e-13)
        assert float(B) == pytest.approx(2.0 * s / 1.5, abs=1e-13)
        assert float(C) == pytest.approx(-1.5 * float(g2) * 2.0 * s, abs=1e-13)
    g2 = torch.zeros((), dtype=torch.float64, requires_grad=True)
    A, B, C, D = radial_transfer(g2, length, n0)
    A0, B0, C0 = (float(v.detach()) for v in (A, B, C))
    assert (A0, B0, C0) == (1.0, pytest.approx(2.0 / 1.5, abs=1e-15), 0.0)
    (dA,) = torch.autograd.grad(A, g2)
    assert float(dA) == pytest.approx(-2.0, abs=1e-12)


def focal_length_errors(lens, heights=(4e-3, 2e-3)):
    """``|f(h) − EFL| / EFL`` for a parallel ray at each height ``h`` (mm) from ``z = −1``:
    ``f(h) = −h / tan u'`` with ``u'`` its slope after the lens (every ray traced)."""
    efl = float(paraxial(lens).efl)
    diffs = []
    for h in heights:
        rays = Rays(torch.tensor([[0.0, h, -1.0]], dtype=torch.float64),
                    torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64),
                    torch.tensor([550.0], dtype=torch.float64))
        out = lens.trace(rays)
        assert bool(out.valid.all())
        diffs.append(abs(-h / float(out.d[0, 1] / out.d[0, 2]) - efl) / efl)
    return diffs


def test_real_ray_focal_length_tends_to_the_paraxial_one():
    """A parallel ray at height h through a Gradient 1 rod leaves at slope u': its focal length
    −h / tan u' tends to the paraxial EFL as h² (aberrations), so the differences at h and h/2
    fall fourfold (their ratio 4 to 5 %: the next term is h⁴; measured 3.99995) and the one at
    h = 2e-3 mm is below 1e-6 relative (measured 4.5e-7: the rod's spherical aberration, 0.11 h²
    per mm²)."""
    diffs = focal_length_errors(rod(RadialGradient(N0, -0.083, step_mm=0.02)))
    assert abs(diffs[0] / diffs[1] - 4.0) < 0.2
    assert diffs[1] < 1e-6
    assert diffs[0] / diffs[1] == pytest.approx(4.0, rel=0.05)


# ------------------------------------------------------------------ gradients
def image_height(nr2, length, step=0.02):
    med = RadialGradient(N0, 0.0, step_mm=step)
    lens = rod(med)
    with torch.no_grad():
        med.nr2.fill_(nr2)
        lens.distances[1].fill_(length)
    med.nr2.requires_grad_(True)
    lens.distances[1].requires_grad_(True)
    rays = launch([(0.1, 0.2), (-0.3, 0.05)], [(0.05, -0.1, 1.0), (0.1, 0.02, 1.0)])
    out = lens.trace_to_sensor(rays)
    assert bool(out.valid.all())
    return (out.o[:, 1] * torch.tensor([1.0, 0.7], dtype=torch.float64)).sum(), med, lens


def test_gradients_match_central_differences():
    """(c) d(image-plane height)/d(nr2) and /d(rod length) by autograd against central
    differences in float64 (step 1e-6: truncation ~ 1e-12 f''' and rounding 1e-16 / 1e-6;
    the integration error is a smooth function of both, 1e-11 at this step)."""
    nr2, length = -0.083, 4.0
    y, med, lens = image_height(nr2, length)
    g_nr2, g_len = torch.autograd.grad(y, [med.nr2, lens.distances[1]])
    eps = 1e-6
    with torch.no_grad():
        fd_nr2 = (image_height(nr2 + eps, length)[0]
                  - image_height(nr2 - eps, length)[0]) / (2 * eps)
        fd_len = (image_height(nr2, length + eps)[0]
                  - image_height(nr2, length - eps)[0]) / (2 * eps)
    assert abs(float(g_nr2)) > 1e-2 and abs(float(g_len)) > 1e-2
    assert float(g_nr2) == pytest.approx(float(fd_nr2), rel=1e-6)
    assert float(g_len) == pytest.approx(float(fd_len), rel=1e-6)


# ------------------------------------------------------------------ the rod's wall
def test_ray_leaving_through_the_side_is_vignetted_without_nan():
    """(d) A steep ray in a weak rod reaches the wall (r > 0.5 mm) before the exit face: it is
    invalid, its values finite, and the gradient through a batch holding it is finite."""
    med = RadialGradient(N0, -0.005, step_mm=0.05)
    lens = rod(med, radius=0.5)
    med.nr2.requires_grad_(True)
    rays = launch([(0.0, 0.0), (0.0, 0.3)], [(0.0, 0.02, 1.0), (0.0, 0.5, 1.0)])
    out = lens.trace_to_sensor(rays)
    assert out.valid.tolist() == [True, False]
    for v in (out.o, out.d, out.opl):
        assert bool(torch.isfinite(v).all())
    (g,) = torch.autograd.grad((out.o[..., 1] * out.valid).sum(), med.nr2)
    assert math.isfinite(float(g)) and float(g) != 0.0
    # and with clear apertures off the same ray reaches the exit face
    free = lens.trace(rays, options=TraceOptions(clip_aperture=False))
    assert bool(free.valid[1])


def test_an_unbounded_stop_on_the_rod_traces():
    """Regression: the spot diagram lifts the stop's semi-diameter to infinity while it traces
    rays aimed at the paraxial pupil (analysis/spot.py); with the stop on the GRIN surface the
    wall was infinite and the step limit overflowed (OverflowError).  The rays now trace, the
    same as with the finite wall they stay inside."""
    lens = rod(RadialGradient(N0, -0.083, step_mm=0.05))
    rays = launch(STARTS, DIRS)
    ref = lens.trace(rays)
    with torch.no_grad():
        lens.surfaces[0].semi_diameter.fill_(math.inf)
    out = lens.trace(rays)
    assert bool(out.valid.all()) and torch.equal(out.o, ref.o)


# ------------------------------------------------------------------ .zmx
def grin_zmx(parm4="0", glas=""):
    """A GRINSUR1 rod between planes, imaging a point 2.5406992524 mm before it at NA 0.2,
    the prescription of OpticStudio's "GRIN interconnect" sample (Δt 0.1, n0 1.5, nr2 −0.083,
    4 mm; its numbers, written here)."""
    return "\n".join([
        "VERS 130724 121 23203", "MODE SEQ", "NAME GRIN rod", "UNIT MM X W X CM MR CPMM",
        "OBNA 2.0E-1 0", "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0", "WAVM 1 5.5E-1 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  CURV 0.0 0 0 0 0 \"\"", "  DISZ 2.5406992524",
        "SURF 1", "  STOP", "  TYPE GRINSUR1", "  CURV 0.0 0 0 0 0 \"\"", "  PARM 1 1.0E-1",
        "  PARM 2 1.5", "  PARM 3 -8.3E-2", f"  PARM 4 {parm4}", "  DISZ 4.0",
        *([f"  {glas}"] if glas else []), "  DIAM 1 1 1 0 1 \"\"",
        "SURF 2", "  TYPE STANDARD", "  CURV 0.0 0 0 0 0 \"\"", "  DISZ 2.5406992524",
        "  DIAM 1 1 1 0 1 \"\"",
        "SURF 3", "  TYPE STANDARD", "  CURV 0.0 0 0 0 0 \"\"", "  DISZ 0", ""])


def test_grinsur1_file_loads_with_the_closed_form_efl(tmp_path):
    """(e) GRINSUR1 is read as a GradientSurface with its Gradient 1 medium (n0, nr2, Δt from
    PARM 1-3) and the paraxial EFL is the closed form's; written and read again bit for bit
    (also as UTF-16, as OpticStudio writes)."""
    p = tmp_path / "rod.zmx"
    p.write_text(grin_zmx())
    lens = read_zmx(p)
    med = lens.materials[1]
    assert med.graded and (float(med.n0), float(med.nr2), med.step_mm) == (1.5, -0.083, 0.1)
    assert lens.surfaces[0].medium is med and lens.stop_index == 0
    efl, _ = rod_efl_bfl(1.5, -0.083, 4.0)
    assert float(paraxial(lens).efl) == pytest.approx(efl, rel=1e-13)
    for enc in ("utf-8", "utf-16"):
        q = tmp_path / f"back-{enc}.zmx"
        write_zmx(lens, q, encoding=enc)
        back = read_zmx(q)
        m2 = back.materials[1]
        assert (float(m2.n0), float(m2.nr2), m2.step_mm) == (1.5, -0.083, 0.1)
        assert [float(d) for d in back.distances] == [float(d) for d in lens.distances]
        assert float(back.d_sensor) == float(lens.d_sensor)
        assert float(paraxial(back).efl) == float(paraxial(lens).efl)


def test_grinsur1_marginal_ray_meets_opticstudios_image_size(tmp_path):
    """OpticStudio's own number: in its "GRIN interconnect" sample (the prescription of
    grin_zmx) the image surface's automatic semi-diameter is 2.491944691397E-2 mm, the largest
    ray height there (one on-axis field: the marginal ray at NA 0.2).  deeplens' marginal ray
    lands at 0.02491945 mm: the same to 5e-9 mm (2e-7 relative), at the file's Δt = 0.1 mm as
    at 0.01 mm (OpticStudio's own integration is not documented)."""
    p = tmp_path / "rod.zmx"
    p.write_text(grin_zmx())
    lens = read_zmx(p)
    s = float(lens.spec.object_distance_mm)
    th = math.asin(0.2)
    rays = Rays(torch.tensor([[0.0, 0.0, -s]], dtype=torch.float64),
                torch.tensor([[0.0, math.sin(th), math.cos(th)]], dtype=torch.float64),
                torch.tensor([550.0], dtype=torch.float64))
    for step in (0.1, 0.01):
        lens.materials[1].step_mm = step
        out = lens.trace_to_sensor(rays)
        assert bool(out.valid.all())
        assert abs(float(out.o[0, 1])) == pytest.approx(2.491944691397e-2, abs=5e-9)


@pytest.mark.parametrize("edit,needle", [
    (dict(parm4="0.01"), "PARM 4"),
    (dict(glas="GLAS N-BK7 0 0 1.5 40 0 0 0 0 0 0"), "GLAS"),
])
def test_grinsur1_refuses_what_it_does_not_read(tmp_path, edit, needle):
    """A fourth Gradient 1 coefficient and a GLAS on the surface are refused at their line."""
    from deeplens.optics.errors import ZemaxFileError

    text = grin_zmx(**edit)
    p = tmp_path / "rod.zmx"
    p.write_text(text)
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(p)
    line = next(k for k, t in enumerate(text.splitlines(), 1) if t.strip().startswith(needle))
    assert e.value.line == line


def test_grinsur9_is_refused_naming_the_missing_data(tmp_path):
    """Gradient 9 (SELFOC) needs the glass's dispersion coefficients that only OpticStudio's
    GRADIENT_9.DAT holds: refused on its TYPE line, saying so."""
    from deeplens.optics.errors import ZemaxFileError

    text = grin_zmx().replace("TYPE GRINSUR1", "TYPE GRINSUR9")
    p = tmp_path / "selfoc.zmx"
    p.write_text(text)
    with pytest.raises(ZemaxFileError, match="GRADIENT_9.DAT") as e:
        read_zmx(p)
    assert e.value.line == text.splitlines().index("  TYPE GRINSUR9") + 1


def test_cardinal_points_match_pygrin():
    """The system matrix of deeplens.analysis.cardinal carries the rod's transfer: focal and
    principal points of a Gradient 1 rod (front face at z = 0) equal pygrin's
    ``cardinal_points`` (FF, FPP, SPP, BF: front focus, front and rear principal planes, back
    focus) to 1e-12 mm."""
    pygrin = pytest.importorskip("pygrin")
    from deeplens.analysis.cardinal import cardinal_points

    nr2 = -0.083
    g = math.sqrt(-2 * nr2 / N0)
    pitch = g * L / (2 * math.pi)
    ff, _, fpp, spp, _, bf = pygrin.cardinal_points(N0, pitch, L)
    c = cardinal_points(rod(RadialGradient(N0, nr2)))
    for ours, theirs in ((c.front_focal_z, ff), (c.front_principal_z, fpp),
                         (c.rear_principal_z, spp), (c.rear_focal_z, bf)):
        assert float(ours) == pytest.approx(theirs, abs=1e-12)


def test_compiled_and_checkpointed_schedules_trace_the_same():
    """Surfaces beside a graded medium run eager under ``compile=...`` (a rod between planes:
    no compiled kernel at all, the same rays bit for bit), and ``checkpoint=True`` recomputes
    the whole propagation in the backward pass: the same gradients to rounding."""
    def run(**opt):
        med = RadialGradient(N0, -0.083, step_mm=0.1)
        lens = rod(med)
        med.nr2.requires_grad_(True)
        out = lens.trace(launch(STARTS, DIRS), options=TraceOptions(**opt))
        (g,) = torch.autograd.grad((out.o[:, :2] * out.valid.unsqueeze(-1)).sum(), med.nr2)
        return out, g

    eager, g_eager = run()
    comp, _ = run(compile="surface")
    assert torch.equal(comp.o, eager.o) and torch.equal(comp.d, eager.d)
    ckpt, g_ckpt = run(checkpoint=True)
    assert torch.equal(ckpt.o, eager.o)
    assert float(g_ckpt) == pytest.approx(float(g_eager), rel=1e-12)


def test_curved_faces_real_rays_tend_to_the_paraxial_efl():
    """A Gradient 1 rod with a convex front and a concave back face (the next surface a sphere:
    the approach steps intersect it by the closed form, backwards where they overshoot): the
    real-ray focal length of parallel rays tends to the paraxial EFL (the faces' powers and
    the rod's matrix) as h², and lies within 1e-6 relative of it at h = 2e-3 mm."""
    from deeplens.optics.surfaces import Sphere

    med = RadialGradient(N0, -0.05, step_mm=0.02)
    lens = Lens([Sphere(0.1, 1.0), Sphere(-0.05, 1.0)], [Air(), med, Air()], [0.0, L], 5.0, 0)
    efl = float(paraxial(lens).efl)
    h2 = 1 / (N0 * math.sqrt(0.1 / N0) * math.sin(math.sqrt(0.1 / N0) * L))   # faces off
    assert abs(efl - h2) / h2 > 0.05          # the faces' powers count
    diffs = focal_length_errors(lens)
    assert abs(diffs[0] / diffs[1] - 4.0) < 0.2
    assert diffs[1] < 1e-6
    assert diffs[0] / diffs[1] == pytest.approx(4.0, rel=0.05)


def test_a_decentred_and_tilted_rod_carries_its_medium():
    """The medium moves with its element (the frame of its first surface): rays through a rod
    decentred by (dx, dy) and tilted about its front vertex are the aligned rod's rays in the
    moved frame, to 1e-12 mm (the same rays, expressed there)."""
    dx, dy, tx = 0.07, -0.04, 0.02
    aligned = rod(RadialGradient(N0, -0.083, step_mm=0.05))
    moved = rod(RadialGradient(N0, -0.083, step_mm=0.05))
    m = moved.misalignments[0]
    with torch.no_grad():
        m.dx.fill_(dx)
        m.dy.fill_(dy)
        m.tilt_x.fill_(tx)
    rays = launch(STARTS, DIRS)
    pivot = torch.zeros(3, dtype=torch.float64)   # the element's first vertex (z = 0)
    o_g, d_g = m.to_global(rays.o, rays.d, pivot)   # the same rays, carried with the rod
    out_m = moved.trace(Rays(o_g, d_g, rays.wavelength))
    out_a = aligned.trace(rays)
    assert bool(out_m.valid.all()) and bool(out_a.valid.all())
    o_back, d_back = m.to_element(out_m.o, out_m.d, pivot)
    torch.testing.assert_close(o_back, out_a.o, rtol=0, atol=1e-12)
    torch.testing.assert_close(d_back, out_a.d, rtol=0, atol=1e-12)


def test_lens_file_refuses_a_graded_medium_saying_where_it_can_go(tmp_path):
    """deeplens' JSON lens file has no gradient-index record: refused, naming .zmx."""
    from deeplens.optics.io import lens_to_dict

    p = tmp_path / "rod.zmx"
    p.write_text(grin_zmx())
    with pytest.raises(ValueError, match="write_zmx"):
        lens_to_dict(read_zmx(p))


@pytest.mark.parametrize("old,new,needle,match", [
    ("PARM 1 1.0E-1", "PARM 1 0", "PARM 1", "the step"),
    ("PARM 2 1.5", "PARM 2 0", "PARM 2", "n0 must be >= 0.001"),
])
def test_grinsur1_bad_step_or_index_refused_at_its_line(tmp_path, old, new, needle, match):
    """A step that is not a positive length is refused at PARM 1's line, an axial index below
    the medium's floor at PARM 2's (a number that is not finite is the parser's error)."""
    from deeplens.optics.errors import ZemaxFileError

    text = grin_zmx().replace(old, new)
    p = tmp_path / "rod.zmx"
    p.write_text(text)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(p)
    line = next(k for k, t in enumerate(text.splitlines(), 1) if t.strip().startswith(needle))
    assert e.value.line == line
