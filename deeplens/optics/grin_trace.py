r"""Rays through a gradient-index medium (:mod:`.grin`): the ray equation, integrated.

Between the surface that starts a graded medium and the next one, a ray follows

    d/ds (n dr/ds) = ∇n,

written in the optical-path parameter ``t`` (``ds = n dt``) as the first-order pair

    dr/dt = T,      dT/dt = D(r) = n ∇n = ½ ∇(n²),        T = n dr/ds  (|T| = n),

and integrated with the fixed-step Runge-Kutta(-Nyström) scheme of A. Sharma, D. V. Kumar and
A. K. Ghatak, "Tracing rays through graded-index media: a new method", Appl. Opt. 21, 984
(1982)::

    A = h D(r_k),   B = h D(r_k + h T_k / 2 + h A / 8),   C = h D(r_k + h T_k + h B / 2)
    r_k+1 = r_k + h (T_k + (A + 2B) / 6),        T_k+1 = T_k + (A + 4B + C) / 6

(fourth order: the position's global error falls ``2⁴``-fold when ``h`` halves,
``tests/optics/test_grin.py``).  The optical path ``∫ n ds = ∫ n² dt`` is integrated with
Simpson's rule on ``n²`` at ``r_k``, the scheme's mid-step point and ``r_k+1`` (third order
globally).  The step is ``h = Δs / n0`` with ``Δs`` the medium's ``step_mm`` (OpticStudio's
``Δt``, read from the file): about ``Δs`` mm of path per step.

Reaching the next surface.  Every ray takes full steps while its next point stays before the
surface (the surface function ``f = sag − z`` keeps its sign); it then lies less than one step
from it.  Three *approach* steps follow: each takes the straight-line distance ``s`` from the
ray's point along ``T / |T|`` to the surface (:func:`~.intersect.intersect`, either sign) and
one integration step of that length (``h = s / n``).  The straight line misses the curved path
by at most about ``κ s² / 2`` (``κ = |∇n⊥| / n``, the path's curvature), so each approach squares
the remaining distance in units of ``1/κ`` (a bound: from ``Δs = 0.1`` mm and ``κ = 0.1``/mm it
gives 5e-4, 1e-8 and 5e-18 mm after the three); measured on the marginal ray of OpticStudio's
``GRINSUR1`` interconnect sample: 0.097 mm before the approaches, 6.4e-13 mm after the first and
0 (below float64's resolution) after the second.  The last,
straight segment is then the surface's own intersection (:meth:`Lens.trace_surface
<deeplens.optics.lens.Lens.trace_surface>`), and the ray refracts there with the local index
``n(r)`` of the graded side(s) at the hit (the entry surface likewise).

Rays that leave the medium through its side (``r`` beyond the larger semi-diameter of the two
surfaces that bound it: the rod's wall, when clear apertures clip), that reach an index below
0.01, that do not reach the surface within ``8 (thickness + wall radius) / Δs + 16`` steps (the
thickness in place of an unbounded wall's radius), or
whose approach finds no surface, become invalid (their state stays finite).

Autograd records every step (the positions of the whole path and three per-step evaluations
of ``n ∇n``): memory grows with the number of steps, unlike the paper's constant-memory adjoint
of a homogeneous lens (``benchmarks/bench_grin_memory.py``); ``TraceOptions(checkpoint=True)``
recomputes each surface's trace, this propagation included, in the backward pass.  The number of steps is decided
without autograd; the last approach step, whose length depends on the surface's position,
carries the derivative with respect to the thickness.  Device-agnostic; float32 and float64.
"""

from __future__ import annotations

import math

import torch

from .errors import LensError
from .intersect import intersect
from .options import TraceOptions
from .rays import Rays, compact_broadcast as _compact

__all__ = ["APPROACH_STEPS", "MIN_INDEX", "check_graded", "graded_surface", "propagate",
           "rk_step"]

#: the approach steps onto the next surface (module docstring)
APPROACH_STEPS = 3
#: rays reaching a lower index are lost (a profile such as ``n0 + nr2 r²`` with ``nr2 < 0``
#: reaches 0 far off axis)
MIN_INDEX = 0.01


def rk_step(medium, r, T, h):
    """One step of Sharma, Kumar and Ghatak's scheme (module docstring) in ``medium`` (a
    :class:`~.grin.GradedMedium`): ``r`` ``(*B, 3)`` (mm, the medium's frame), ``T``
    ``(*B, 3)`` (``n dr/ds``, dimensionless), ``h`` a float or ``(*B,)`` tensor (the step in
    the optical-path parameter ``t``, mm).  Returns ``(r, T, dopl, n_end)``: the
    new point and optical direction, the optical path of the step (mm) and the index at the
    new point."""
    hv = h.unsqueeze(-1) if isinstance(h, torch.Tensor) else h

    def D(p):
        n, dx, dy, dz = medium.local(*p.unbind(-1))
        return n, torch.stack([dx, dy, dz], -1)

    n_a, Da = D(r)
    A = hv * Da
    n_b, Db = D(r + hv * 0.5 * T + hv * 0.125 * A)
    B = hv * Db
    _, Dc = D(r + hv * T + hv * 0.5 * B)
    C = hv * Dc
    r1 = r + hv * (T + (A + 2.0 * B) / 6.0)
    T1 = T + (A + 4.0 * B + C) / 6.0
    n_end = medium.local(*r1.unbind(-1))[0]
    dopl = h / 6.0 * (n_a * n_a + 4.0 * n_b * n_b + n_end * n_end)
    return r1, T1, dopl, n_end


def check_graded(lens) -> None:
    """Refuse a graded medium the tracer cannot follow: in object or image space, bounded by a
    surface that is not landed on (a stop, a coordinate break) or by a mirror, or between
    surfaces of two elements (:class:`~.errors.LensError` naming the surfaces)."""
    n = len(lens.surfaces)
    for k, m in enumerate(lens.materials):
        if not getattr(m, "graded", False):
            continue
        if k == 0 or k == n:
            raise LensError(f"the graded medium {m.name!r} is in {'object' if k == 0 else 'image'}"
                            f" space: a graded medium must lie between two surfaces",
                            surfaces=() if k == 0 else (n - 1,))
        a, b = k - 1, k
        for i in (a, b):
            law = lens.surfaces[i].interaction
            if not law.lands or law.changes_frame or i in lens.mirrors:
                raise LensError(f"surface {i} bounds the graded medium {m.name!r} but is a "
                                f"{lens.surfaces[i].law} surface: a graded medium lies between "
                                f"two refracting surfaces", surfaces=(i,))
        if lens._element_of[a] != lens._element_of[b]:
            raise LensError(f"surfaces {a} and {b} bound the graded medium {m.name!r} but belong "
                            f"to different elements: they must move together", surfaces=(a, b))


def _to_medium(lens, a: int, z, x):
    """``(to, back)``: closures taking global points and directions ``(p, q)`` (``(*B, 3)``)
    into the frame of surface ``a`` (the medium's: its element frame, origin at its vertex) and
    back; ``z`` the vertices' positions (mm), ``x`` gives the dtype and device."""
    m, pivot, vertex = lens._frame(a, z, x)
    if m is None:
        shift = pivot + vertex
        return (lambda p, q: (p - shift, q)), (lambda p, q: (p + shift, q))

    def to(p, q):
        pe, qe = m.to_element(p, q, pivot)
        return pe - vertex, qe

    return to, (lambda p, q: m.to_global(p + vertex, q, pivot))


def _wall_radius(lens, a: int) -> float:
    return max(float(lens.surfaces[k].semi_diameter.detach()) for k in (a, a + 1))


def propagate(lens, a: int, rays: Rays, z, options: TraceOptions | None = None,
              reverse: bool = False) -> Rays:
    """Move ``rays`` (on surface ``a``'s side of the medium after surface ``a``, travelling
    towards ``+z``; from surface ``a + 1`` towards ``-z`` when ``reverse``) through the graded
    medium ``lens.materials[a + 1]`` to just before the surface they reach (``a + 1``, or ``a``
    when ``reverse``): the module docstring's full and approach steps.  ``rays.opl`` grows by
    the optical path; the returned direction is the ray's tangent ``T / |T|``."""
    medium = lens.materials[a + 1]
    opt = options or TraceOptions()
    target = a if reverse else a + 1
    surf = lens.surfaces[target]
    to, back = _to_medium(lens, a, z, rays.o)
    r, d = to(rays.o, rays.d)
    zero = torch.zeros((), dtype=r.dtype, device=r.device)
    # the target surface's vertex in the medium's frame (same element, check_graded)
    off = torch.stack([zero, zero, (z[target] - z[a]).to(r)])
    valid = rays.valid
    n, *_ = medium.local(*r.unbind(-1))
    valid = valid & (n > MIN_INDEX)
    T = torch.where(valid, n, torch.ones_like(n)).unsqueeze(-1) * d
    opl = rays.opl
    step = medium.step_mm
    n0 = float(medium.n0.detach())
    h = step / n0
    wall2 = _wall_radius(lens, a) ** 2
    sign = -1.0 if reverse else 1.0       # f = sag - z > 0 before the surface (forward)
    thickness = abs(float((z[a + 1] - z[a]).detach()))
    wall = math.sqrt(wall2) if math.isfinite(wall2) else thickness   # (an unbounded wall)
    max_steps = int(math.ceil(8.0 * (thickness + wall) / step)) + 16
    active = valid.clone()
    for k in range(max_steps):
        r1, T1, dopl, n1 = rk_step(medium, r, T, h)
        with torch.no_grad():
            q = r1.detach() - off
            fv = surf.f(*q.unbind(-1))
            crossed = ~(sign * fv > 0)             # NaN (outside the surface's domain): stop
            lost = n1.detach() <= MIN_INDEX
            if opt.clip_aperture:
                lost = lost | ((q[..., 0] ** 2 + q[..., 1] ** 2) > wall2)
            lost = active & lost & ~crossed
            go = active & ~crossed & ~lost
        r = torch.where(go.unsqueeze(-1), r1, r)
        T = torch.where(go.unsqueeze(-1), T1, T)
        opl = opl + torch.where(go, dopl, torch.zeros_like(dopl))
        valid = valid & ~lost
        active = go
        if not bool(active.any()):
            break
    valid = valid & ~active                        # ran out of steps
    for _ in range(APPROACH_STEPS):
        tn = T.norm(dim=-1, keepdim=True)
        d = T / torch.where(valid.unsqueeze(-1), tn, torch.ones_like(tn))
        s, _, valid = intersect(surf, r - off, d, valid, opt, backward=True)
        n_here = medium.local(*r.unbind(-1))[0]
        hh = s / torch.where(valid, n_here, torch.ones_like(n_here))
        hh = torch.where(valid, hh, torch.zeros_like(hh))
        r1, T1, dopl, _ = rk_step(medium, r, T, hh)
        r = torch.where(valid.unsqueeze(-1), r1, r)
        T = torch.where(valid.unsqueeze(-1), T1, T)
        opl = opl + torch.where(valid, dopl, torch.zeros_like(dopl))
    tn = T.norm(dim=-1, keepdim=True)
    d = T / torch.where(valid.unsqueeze(-1), tn, torch.ones_like(tn))
    d = torch.where(valid.unsqueeze(-1), d, rays.d)
    x, d = back(r, d)
    return Rays(x, d, rays.wavelength, valid, opl, normalize=False)


def local_index(lens, a: int, x, z):
    """The index of the graded medium after surface ``a`` at global points ``x`` ``(*B, 3)``."""
    to, _ = _to_medium(lens, a, z, x)
    r, _ = to(x, x)
    return lens.materials[a + 1].local(*r.unbind(-1))[0]


def graded_surface(lens, i: int, rays: Rays, n1, n2, z, options=None, refract_: bool = True,
                   reverse: bool = False) -> Rays:
    """Surface ``i`` of ``lens`` when a graded medium lies on either side of it (what
    :meth:`Lens.trace_surface <deeplens.optics.lens.Lens.trace_surface>` runs there): the rays
    are first propagated through the graded medium they are in (:func:`propagate`), then land
    on the surface and refract with the local index at the hit on the graded side(s) in place
    of ``n1`` / ``n2`` (the media's axial indices)."""
    before, after = (i + 1, i) if reverse else (i, i + 1)   # media indices in travel order
    if lens.materials[before].graded:
        rays = propagate(lens, before - 1, rays, z, options, reverse)
    if not refract_:
        return lens._trace_surface(i, rays, n1, n2, z, options, refract_=False, reverse=reverse)
    hit = lens._trace_surface(i, rays, n1, n2, z, options, refract_=False, reverse=reverse)
    x = hit.o
    n1, n2 = _compact(n1), _compact(n2)
    if lens.materials[before].graded:
        n1 = torch.where(hit.valid, local_index(lens, before - 1, x, z), n1.to(x))
        n1 = torch.where(n1 > MIN_INDEX, n1, torch.ones_like(n1))
    if lens.materials[after].graded:
        n2 = torch.where(hit.valid, local_index(lens, after - 1, x, z), n2.to(x))
        n2 = torch.where(n2 > MIN_INDEX, n2, torch.ones_like(n2))
    return lens._trace_surface(i, rays, n1, n2, z, options, reverse=reverse)
