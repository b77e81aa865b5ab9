"""The tracer: how a lens is traced (scheduling), apart from what the lens is (:mod:`.lens`).

:class:`~.lens.Lens` describes the system (surfaces, media, spacings, misalignment) and the
physics of one surface (:meth:`~.lens.Lens.trace_surface`: its frame, intersection and
refraction).  This module decides how a whole trace runs, from one :class:`~.options.TraceOptions`:

* eager: surface after surface through :meth:`~.lens.Lens.trace_surface`;
* ``checkpoint=True``: each surface inside ``torch.utils.checkpoint`` (backward recomputes it
  from the incoming ray state, :func:`surface_checkpointed`);
* ``compile="default"`` (the default): eager until compiling has paid for the trace's kernel
  signature, then as ``compile="auto"`` (:func:`default_mode`, :mod:`.compile_policy`);
* ``compile=...``: runs of aligned spheres, conics, planes and stops as fused kernels and aligned
  even aspheres and XY polynomials as compiled Newton chunks (:mod:`.compiled`,
  :func:`trace_compiled`); :func:`fused_kind` says which surface runs how, and everything else
  (misaligned elements, B-splines, cylinders, ideal lenses, gratings, annular stops, surfaces
  beside a graded medium) runs eager in between.
  A folded lens (mirrors, coordinate breaks), a ``record``ed trace, ``closed_form=False`` and
  ``mode="unrolled"`` stay eager.

The kernels call the same component-wise surface functions and laws as the eager path
(:mod:`.surfaces.asphere`, :mod:`.surfaces.xy_polynomial`, :func:`.refract.snell_coefficient`,
:func:`.intersect.hit_mask`), so the schedule changes speed and memory, not the physics.
"""

from __future__ import annotations

import functools

import torch
import torch.utils.checkpoint

from .intersect import _warn_stalled, default_tolerance
from .options import TraceOptions
from .rays import Rays, compact_broadcast as _compact, from_soa, to_soa

__all__ = ["default_mode", "from_soa_copy", "fused_kind", "newton_compiled",
           "surface_checkpointed", "trace", "trace_compiled"]


def trace(lens, rays: Rays, *, reverse: bool = False, options: TraceOptions | None = None,
          record: bool = False, propagate_to=None):
    """Trace ``rays`` through every surface of ``lens``
    (:meth:`Lens.trace <deeplens.optics.lens.Lens.trace>` documents the arguments); the
    schedule follows ``options`` (module docstring)."""
    w = rays.wavelength
    n = lens.indices(w)
    z = lens.z_vertices()
    order = range(len(lens.surfaces) - 1, -1, -1) if reverse else range(len(lens.surfaces))
    hits = []
    step = lens.trace_surface
    if options is not None and options.checkpoint and torch.is_grad_enabled():
        step = functools.partial(surface_checkpointed, lens)
    if (options is not None and options.compile and options.closed_form
            and options.mode == "implicit" and not record and not lens.folded()):
        mode = options.compile
        if mode == "default":
            mode = default_mode(lens, rays, options, reverse)
        if mode:
            return trace_compiled(lens, rays, order, n, z, reverse, options, step, propagate_to,
                                  mode)
    for i in order:
        n1, n2 = (n[i + 1], n[i]) if reverse else (n[i], n[i + 1])
        law = lens.surfaces[i].interaction
        if law.changes_frame:  # a change of frame only
            rays = lens.trace_surface(i, rays, n1, n2, z, reverse=reverse)
        elif record and not law.lands:
            # a stop is crossed, not landed on: its recorded hit is where the line crosses it
            hits.append(lens.trace_surface(i, rays, n1, n2, z, options, refract_=False).o)
            rays = step(i, rays, n1, n2, z, options, reverse=reverse)
            continue
        else:
            rays = step(i, rays, n1, n2, z, options, reverse=reverse)
        if record:
            hits.append(rays.o)
    if propagate_to is not None:
        rays = lens.propagate_to_z(rays, *propagate_to)
    return (rays, hits) if record else rays


def surface_checkpointed(lens, i: int, rays: Rays, n1, n2, z, options,
                         reverse: bool = False) -> Rays:
    """:meth:`Lens.trace_surface <deeplens.optics.lens.Lens.trace_surface>` that autograd does
    not record: backward recomputes it from the incoming ray state (``torch.utils.checkpoint``),
    so only that state is kept per surface."""
    def surface_step(o, d, wavelength, opl, n1, n2, z):
        out = lens.trace_surface(i, Rays(o, d, wavelength, rays.valid, opl, normalize=False),
                                 n1, n2, z, options, reverse=reverse)
        return out.o, out.d, out.opl, out.valid

    o, d, opl, valid = torch.utils.checkpoint.checkpoint(
        surface_step, rays.o, rays.d, rays.wavelength, rays.opl, n1, n2, z,
        use_reentrant=False)
    return Rays(o, d, rays.wavelength, valid, opl, normalize=False)

def fused_kind(lens, i: int):
    """How surface ``i`` runs compiled: its declared :attr:`~.surfaces.Surface.fused` kind (a
    :data:`~.compiled.KINDS` entry, or ``"newton"`` for a type with Newton kernels, or
    ``None``: eager) when its element is aligned and it is not reached through a gap of
    :attr:`Lens.backward_gaps <deeplens.optics.lens.Lens.backward_gaps>` (the kernels accept
    hits ahead of the ray only); else ``None``."""
    if lens.hit_backwards(i) or lens.hit_backwards(i, reverse=True):
        return None
    if not lens.misalignments[lens._element_of[i]].is_identity():
        return None
    if lens.materials[i].graded or lens.materials[i + 1].graded:
        return None   # beside a graded medium: its curved paths first (.grin_trace)
    return lens.surfaces[i].fused

def newton_compiled(lens, i: int, soa, rays: Rays, n1, n2, z_shift, options, tol: float):
    """Surface ``i`` (an aligned even asphere or XY polynomial) through the compiled Newton
    kernels (:mod:`.compiled`); ``soa``: ``(o, d)`` component-major.  Returns
    ``(o, d, valid, opl)`` with ``o``, ``d`` component-major."""
    from . import compiled as C

    s = lens.surfaces[i]
    like = soa[0]
    kind, sp = C.newton_surface_values(s, like)
    with torch.no_grad():
        o, d = soa[0].detach(), soa[1].detach()
        spd = C.detached(sp)
        it = min(C.NEWTON_CHUNK, options.max_iter)
        b, s_star, tried, active, converged, tol_ray, fv = C.call(
            C.compiled_newton_start, kind, spd, o, d, rays.valid, z_shift.detach(), tol, it)
        while it < options.max_iter and bool(active.any()):
            m = min(C.NEWTON_CHUNK, options.max_iter - it)
            s_star, active, converged, fv = C.call(
                C.compiled_newton_more, kind, spd, b, d, s_star, active, converged, tol_ray,
                m)
            it += m
        if it >= options.max_iter:
            converged, fv = C.call(C.compiled_newton_last_check, kind, spd, b, d, s_star,
                                   active, converged, tol_ray)
        if bool((tried & ~converged).any()):
            _warn_stalled(s, b.movedim(0, -1), d.movedim(0, -1), s_star, tried, converged,
                          tol_ray, tol, fv)
        ok = tried & converged
        s_star = torch.where(ok, s_star, torch.zeros_like(s_star))
    args = (kind, sp, soa[0], soa[1], rays.valid, rays.opl, z_shift,
            s.opening.kernel_clip[1].to(like), _compact(n1).to(like), _compact(n2).to(like), s_star,
            ok, tol, options.clip_aperture)
    if options.checkpoint and torch.is_grad_enabled():
        return torch.utils.checkpoint.checkpoint(C.call, C.compiled_newton_refract, *args,
                                                 use_reentrant=False)
    return C.call(C.compiled_newton_refract, *args)


def from_soa_copy(v: torch.Tensor) -> torch.Tensor:
    """Component-major ``(3, *B)`` -> ``(*B, 3)``, contiguous: the values of
    :func:`~.rays.from_soa`.  Without autograd on the CPU, one strided copy per component
    into a new tensor: 1.1 ms instead of 5.3 ms for 1e6 float32 rays at one thread (the
    interleaving ``torch.stack(..., -1)`` is a slow path there), 10 % of a compiled double
    Gauss forward (``docs/benchmarks.md``, "Against the reference code").  With autograd, and
    on other devices, :func:`~.rays.from_soa` (the copies' backward would build full-size
    zero tensors per component)."""
    if v.device.type != "cpu" or (torch.is_grad_enabled() and v.requires_grad):
        return from_soa(v)
    out = v.new_empty((*v.shape[1:], v.shape[0]))
    for i in range(v.shape[0]):
        out[..., i] = v[i]
    return out


def _needs_grad(lens, rays: Rays) -> bool:
    """Whether the trace builds an autograd graph (rays or lens parameters require one)."""
    return torch.is_grad_enabled() and (
        rays.o.requires_grad or rays.d.requires_grad or rays.opl.requires_grad
        or any(p.requires_grad for p in lens.parameters()))


def default_mode(lens, rays: Rays, options: TraceOptions, reverse: bool):
    """``compile="default"``: ``"auto"`` when the ski-rental ledger of ``options`` says that
    compiling this trace's kernel signature has paid (:mod:`.compile_policy`), else ``False``
    (eager; the call is charged to the ledger)."""
    from .compile_policy import MIN_RAYS

    if rays.valid.numel() < MIN_RAYS:  # small calls stay eager (and cost nothing to decide)
        return False
    kinds = tuple(fused_kind(lens, i) for i in range(len(lens.surfaces)))
    grad = _needs_grad(lens, rays)
    key = (f"{kinds}|{str(rays.dtype)}|{rays.o.device.type}|grad={grad}|reverse={reverse}")
    run = options.ledger.charge(key, rays.valid.numel(), kinds, grad, rays.o.device)
    return "auto" if run else False


def trace_compiled(lens, rays: Rays, order, n, z, reverse: bool, options: TraceOptions,
                   step, propagate_to=None, mode=None) -> Rays:
    """:func:`trace` with runs of aligned spheres, conics, planes and stops, and aligned
    even aspheres and XY polynomials, in compiled kernels (:mod:`.compiled`); every other
    surface goes through ``step``.  While ``soa`` holds the ray state, ``rays`` carries only
    its valid mask and optical path (its ``o`` and ``d`` are stale: read for dtype and
    device only).  ``propagate_to``: ``(z_plane, medium_index)`` or ``None``, as
    :func:`trace`; the move joins the last compiled kernel."""
    from . import compiled as C

    tol = options.tol if options.tol is not None else default_tolerance(rays.dtype)
    clip = options.clip_aperture
    checkpoint = options.checkpoint and torch.is_grad_enabled()
    mode = options.compile if mode is None else mode
    per_surface = mode == "surface"
    if mode == "auto":
        per_surface = _needs_grad(lens, rays)
    order = list(order)
    soa = None  # (o, d) component-major (3, *B) while between compiled runs

    def propagate_params(like):  # the "propagate" step's (z_plane, n, n)
        m = _compact(propagate_to[1]).to(like)
        return propagate_to[0], m, m

    k = 0
    while k < len(order):
        i = order[k]
        kind = fused_kind(lens, i)
        n1, n2 = (n[i + 1], n[i]) if reverse else (n[i], n[i + 1])
        if kind is None:
            if soa is not None:
                rays = Rays(soa[0].movedim(0, -1), soa[1].movedim(0, -1), rays.wavelength,
                            rays.valid, rays.opl, normalize=False)
                soa = None
            rays = step(i, rays, n1, n2, z, options, reverse=reverse)
            k += 1
            continue
        if soa is None:
            soa = (to_soa(rays.o), to_soa(rays.d))
        if kind == "newton":
            _, pivot, vertex = lens._frame(i, z, soa[0])
            o, d, valid, opl = newton_compiled(lens, i, soa, rays, n1, n2,
                                                     (pivot + vertex)[2], options, tol)
            soa = (o, d)
            rays = Rays(rays.o, rays.d, rays.wavelength, valid, opl, normalize=False)
            k += 1
            continue
        kinds, params = [], []
        while k < len(order) and kind is not None:
            i = order[k]
            s = lens.surfaces[i]
            n1, n2 = (n[i + 1], n[i]) if reverse else (n[i], n[i + 1])
            _, pivot, vertex = lens._frame(i, z, rays.o)
            like = rays.o
            values = s.fused_values(like)
            params.append(((pivot + vertex)[2], *values, _compact(n1).to(like),
                           _compact(n2).to(like)))
            kinds.append(kind)
            k += 1
            if k == len(order) and propagate_to is not None:  # the move to the sensor
                kinds.append("propagate")
                params.append(propagate_params(like))
                propagate_to = None
            if per_surface or k == len(order):
                break
            kind = fused_kind(lens, order[k])
            if kind == "newton":
                break
        args = (*soa, rays.valid, rays.opl, tuple(kinds), tuple(params), tol, clip)
        if checkpoint:
            o, d, valid, opl = torch.utils.checkpoint.checkpoint(
                C.call, C.compiled_surface_run, *args, use_reentrant=False)
        else:
            o, d, valid, opl = C.call(C.compiled_surface_run, *args)
        soa = (o, d)
        rays = Rays(rays.o, rays.d, rays.wavelength, valid, opl, normalize=False)
    if soa is not None and propagate_to is not None:  # after a Newton surface
        args = (*soa, rays.valid, rays.opl, ("propagate",), (propagate_params(rays.o),),
                tol, clip)
        o, d, valid, opl = C.call(C.compiled_surface_run, *args)
        soa, propagate_to = (o, d), None
        rays = Rays(rays.o, rays.d, rays.wavelength, valid, opl, normalize=False)
    if soa is not None:  # back to (*B, 3), contiguous
        rays = Rays(from_soa_copy(soa[0]), from_soa_copy(soa[1]),
                    rays.wavelength, rays.valid, rays.opl, normalize=False)
    if propagate_to is not None:  # the last surface ran eager
        rays = lens.propagate_to_z(rays, *propagate_to)
    return rays
