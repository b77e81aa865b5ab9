"""Fused kernels for runs of aligned spheres, conics, planes and stops (``torch.compile``).

A run of surfaces ``i .. j`` maps the ray state ``(o, d, valid, opl)`` to the state after
surface ``j`` by composing, per surface, the pure tensor functions
:func:`~.intersect.quadric_step` (sphere or conic: closed-form intersection, normal, Snell) and
:func:`~.intersect.flat_step` (plane) and :func:`~.intersect.stop_step_xyz` (a virtual stop).  :func:`surface_run` is that composition; eager
PyTorch runs its ~60 element-wise operators per surface one at a time, each reading and writing
whole ``(N,)`` tensors, while ``torch.compile`` (inductor: C++/OpenMP on CPU, Triton on CUDA)
fuses them into one loop that reads the incoming ray state once and writes the outgoing one
once (``TraceOptions(compile="surface")``: one kernel per surface; ``compile="lens"`` or
``True``: one kernel per run, the state between surfaces never reaches memory).  The arithmetic
is the same function as the eager path's, so results agree to float rounding (the compiler may
reorder or contract operations).  Even aspheres and XY polynomials run Newton's method in
compiled chunks (:func:`newton_start`, below); B-spline freeforms, misaligned elements, ideal
lenses and a ``record``ed trace stay eager.

Compilation happens at the first call for each lens structure (the ``kinds`` tuple), dtype,
device, gradient pattern and shape of the media indices; ``dynamic=True`` makes the ray count
symbolic, so other batch sizes reuse the kernel.  Compiled kernels are cached on disk by
inductor's FX graph cache (``TORCHINDUCTOR_CACHE_DIR``, default ``/tmp/torchinductor_$USER``),
so a later process loads them instead of compiling.  With gradients, AOTAutograd compiles the
backward too; its partitioner recomputes cheap element-wise values in backward instead of
saving them, so the graph kept per ray and surface is small without ``checkpoint=True``.
"""

from __future__ import annotations

import os
import warnings

import torch

from .intersect import (_quadric_root, _safe_div, accept_hits, flat_step_xyz, propagate_xyz,
                        quadric_step_xyz, rounding_tolerance, stop_step_xyz)
from .refract import snell_xyz

__all__ = ["KINDS", "compiled_surface_run", "surface_run"]

#: the surface kinds a run can hold and the tensors each takes (after ``z_shift``)
KINDS = {"quadric": ("c", "k", "semi_diameter"), "plane": ("semi_diameter",),
         "stop": ("semi_diameter",), "stop_rect": ("half_widths",), "propagate": ()}


def surface_run(o, d, valid, opl, kinds: tuple, params: tuple, tol: float, clip: bool = True):
    """Trace the ray state through a run of aligned surfaces.

    The ray coordinates are component-major, ``(3, *B)`` (``o.movedim(-1, 0).contiguous()``):
    each component is then a contiguous array, which the compiler vectorises (SIMD); the
    ``(*B, 3)`` layout's stride-3 loads keep inductor's C++ kernels scalar (about 2x slower).

    Args:
        o, d: ``(3, *B)`` origins (mm, global frame) and unit directions, component-major.
        valid, opl: ``(*B,)`` mask and optical path length (mm).
        kinds: one entry of :data:`KINDS` per surface (a static value: each distinct tuple is
            its own kernel).
        params: per surface, ``(z_shift, *values, n1, n2)``: the vertex position (0-d, mm), the
            values :data:`KINDS` names (0-d, or ``(2,)`` half-widths) and the media indices
            before and after the surface (broadcastable to ``B``); for ``"propagate"`` (the move
            to a plane, :func:`propagate_xyz`, e.g. the sensor after the last surface),
            ``(z_plane, n, n)``.
        tol, clip: as :func:`~.intersect.quadric_step`.

    Returns:
        ``(o, d, valid, opl)`` after the last surface, ``o`` and ``d`` ``(3, *B)``.
    """
    state = (*o.unbind(0), *d.unbind(0), valid, opl)  # components: no (N, 3) in between
    for kind, p in zip(kinds, params):
        if kind == "quadric":
            state = quadric_step_xyz(*state, *p, tol, clip)
        elif kind == "propagate":
            state = propagate_xyz(*state, p[0], p[1])
        elif kind == "plane":
            state = flat_step_xyz(*state, *p, tol, clip)
        else:  # a virtual stop: clips, the ray stays where it was
            state = stop_step_xyz(*state, *p, tol, clip, rect=kind == "stop_rect")
    x, y, z, dx, dy, dz, valid, opl = state
    return torch.stack([x, y, z]), torch.stack([dx, dy, dz]), valid, opl


#: compiled variants one function may hold (dynamo's default, 8, is soon reached: each lens
#: structure, dtype and pattern of trainable values is one); the environment variable
#: ``DEEPLENS_RECOMPILE_LIMIT`` changes it (each variant keeps its kernels in memory).  Beyond
#: it the call runs eager, with a warning (:func:`call`)
RECOMPILE_LIMIT = 64


def recompile_limit() -> int:
    """:data:`RECOMPILE_LIMIT`, or ``DEEPLENS_RECOMPILE_LIMIT`` when set (an integer >= 1)."""
    text = os.environ.get("DEEPLENS_RECOMPILE_LIMIT")
    if text is None:
        return RECOMPILE_LIMIT
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"DEEPLENS_RECOMPILE_LIMIT: expected an integer >= 1, got {text!r}")
    return value


def call(fn, *args):
    """``fn(*args)`` for one of this module's ``compiled_*`` functions, with dynamo's
    per-function recompilation limit raised to :func:`recompile_limit` for the call.

    Buffer donation is turned off (``torch._functorch.config.donated_buffer``, for the rest of
    the process: AOTAutograd reads it again when the backward runs), so that a compiled trace's
    graph can be differentiated twice (``retain_graph=True``) as an eager one can (issue 25,
    item 10; donation lets the backward reuse its saved inputs' memory and then refuses a second
    backward).  A call that would need
    a compiled variant beyond the limit runs eager and warns (dynamo would fall back silently;
    item 13): same values, slower."""
    limit = recompile_limit()
    torch._functorch.config.donated_buffer = False
    with torch._dynamo.config.patch(recompile_limit=limit, fail_on_recompile_limit_hit=True):
        try:
            return fn(*args)
        except torch._dynamo.exc.FailOnRecompileLimitHit:
            pass
    eager = getattr(fn, "_torchdynamo_orig_callable", fn)
    warnings.warn(f"deeplens.optics.compiled: {getattr(eager, '__name__', 'a kernel')} reached "
                  f"its limit of {limit} compiled variants in this process (one per lens "
                  f"structure, dtype, device and pattern of trainable values); this call and "
                  f"later new variants run eager (same values, slower).  Raise "
                  f"DEEPLENS_RECOMPILE_LIMIT or use fewer variants per process",
                  RuntimeWarning, stacklevel=3)
    return eager(*args)


#: inductor settings for every kernel here: ``max_fusion_size`` (default 64 nodes) cut a run of
#: ten surfaces into four loops that pass their state through memory; one loop is 1.25-1.35x
#: faster (``benchmarks/README.md``, "compiled kernels")
INDUCTOR_OPTIONS = {"max_fusion_size": 4096}


def _compile(fn):
    return torch.compile(fn, dynamic=True, options=INDUCTOR_OPTIONS)


#: the compiled wrapper (compiles lazily, at its first call for each input signature)
compiled_surface_run = _compile(surface_run)


# ============================================================================ Newton surfaces
# Newton's method as in :func:`~.intersect.intersect` (implicit mode), on component-major tensors,
# for even aspheres (started from the conic root) and XY polynomials (from the vertex plane): the
# iteration runs in compiled chunks of ``NEWTON_CHUNK`` updates without autograd, and the host
# checks after each chunk whether any ray is still active (the eager loop checks after iterations
# 1, 2, 4, 8, ...; an extra iteration changes nothing once every ray has converged or failed, so
# both give the same roots).  The final differentiable Newton step (Eq. 7), the checks, the normal
# and Snell's law are one more kernel.  ``kind`` (the surface's class: its static ``kernel_f``,
# ``kernel_in_domain`` and ``kernel_start``, written in the surface's own file from the maths
# its eager methods call) and ``sp``, its values (:func:`newton_surface_values`), select the
# implicit function.

#: Newton updates per compiled chunk (one host synchronisation per chunk)
NEWTON_CHUNK = 2


def _surface_f(kind, sp, x, y, z):
    return kind.kernel_f(x, y, z, sp)


def _in_domain(kind, sp, x, y):
    return kind.kernel_in_domain(x, y, sp)


def detached(sp):
    """The surface values ``sp`` (:func:`newton_surface_values`) without autograd history."""
    return tuple(tuple(a.detach() for a in v) if isinstance(v, tuple) and v
                 and isinstance(v[0], torch.Tensor)
                 else v.detach() if isinstance(v, torch.Tensor) else v for v in sp)


def newton_surface_values(surface, like):
    """``(kind, sp)``: the surface's class (its static ``kernel_*`` functions: a constant to the
    compiler) and :meth:`~.surfaces.Surface.kernel_values` in ``like``'s dtype, or ``None``
    when the surface has no Newton kernel."""
    sp = surface.kernel_values(like)
    return (None, None) if sp is None else (type(surface), sp)


def _residual_xyz(kind, sp, bx, by, bz, dx, dy, dz, s, at=None):
    x, y, z = bx + s * dx, by + s * dy, bz + s * dz
    if at is not None:
        x, y, z = (torch.where(at, v, torch.zeros_like(v)) for v in (x, y, z))
    fv, fx, fy, fz = _surface_f(kind, sp, x, y, z)
    return fv, fx * dx + fy * dy + fz * dz


def _newton_updates(kind, sp, bx, by, bz, dx, dy, dz, s, active, converged, tol_ray, n):
    fv = None
    for _ in range(n):
        fv, fp = _residual_xyz(kind, sp, bx, by, bz, dx, dy, dz, s)
        done = active & (fv.abs() < tol_ray)
        converged = converged | done
        active = active & ~done
        active = active & (fp.abs() > 1e-12) & torch.isfinite(fv)
        s = torch.where(active, s - _safe_div(fv, fp, active), s)
    return s, active, converged, fv


def newton_start(kind, sp, o, d, valid, z_shift, tol: float, n: int):
    """No autograd.  The vertex-plane point ``b = o + t0 d``, the start (an asphere's conic
    root, else the vertex plane) and ``n`` Newton updates.  ``o``, ``d``: ``(3, *B)``.  Returns
    ``(b (3, *B), s, ok, active, converged, tol_ray, fv)``: ``ok`` the rays that were tried,
    ``fv`` the residual before the last update."""
    ox, oy, oz = o.unbind(0)
    dx, dy, dz = d.unbind(0)
    oz = oz - z_shift
    ok = valid & (dz.abs() > 1e-12)
    t0 = _safe_div(-oz, dz, ok)
    bx, by, bz = ox + t0 * dx, oy + t0 * dy, oz + t0 * dz
    s = kind.kernel_start(bx, by, bz, dx, dy, dz, ok, sp, _quadric_root)
    tol_ray = rounding_tolerance(bx, by, bz, tol)
    s, active, converged, fv = _newton_updates(kind, sp, bx, by, bz, dx, dy, dz, s, ok,
                                               torch.zeros_like(ok), tol_ray, n)
    return torch.stack([bx, by, bz]), s, ok, active, converged, tol_ray, fv


def newton_more(kind, sp, b, d, s, active, converged, tol_ray, n: int):
    """No autograd: ``n`` more Newton updates; returns ``(s, active, converged, fv)``."""
    return _newton_updates(kind, sp, *b.unbind(0), *d.unbind(0), s, active, converged, tol_ray, n)


def newton_last_check(kind, sp, b, d, s, active, converged, tol_ray):
    """No autograd: after ``max_iter`` updates, the rays still active that now meet the
    tolerance count as converged; returns ``(converged, fv)``."""
    fv, _ = _residual_xyz(kind, sp, *b.unbind(0), *d.unbind(0), s)
    return converged | (active & (fv.abs() < tol_ray)), fv


def newton_refract(kind, sp, o, d, valid, opl, z_shift, semi_diameter, n1, n2, s_star, ok,
                   tol: float, clip: bool = True):
    """The differentiable part: one Newton step from the converged ``s_star`` (Eq. 7; rays with
    ``ok`` False are evaluated at the vertex), the domain, direction, aperture and finiteness
    checks of :func:`~.intersect.intersect`, the normal ``∇f / |∇f|`` and Snell's law, as
    :meth:`Lens.trace_surface <deeplens.optics.lens.Lens.trace_surface>` does on the Newton
    path.  ``o``, ``d``: ``(3, *B)``; returns ``(o, d, valid, opl)`` in that layout."""
    ox, oy, oz = o.unbind(0)
    dx, dy, dz = d.unbind(0)
    oz = oz - z_shift
    t0 = _safe_div(-oz, dz, valid & (dz.abs() > 1e-12)).detach()
    bx, by, bz = ox + t0 * dx, oy + t0 * dy, oz + t0 * dz
    fv, fp = _residual_xyz(kind, sp, bx, by, bz, dx, dy, dz, s_star, ok)
    ok = ok & (fp.detach().abs() > 1e-12)
    s = s_star - _safe_div(fv, fp, ok)
    t = t0 + s
    x, y, z = bx + s * dx, by + s * dy, bz + s * dz
    with torch.no_grad():
        ok = ok & _in_domain(kind, detached(sp), x.detach(), y.detach())
    t, x, y, z, ok = accept_hits(t, x, y, z, ox, oy, oz, ok, semi_diameter, tol, clip)
    _, gx, gy, gz = _surface_f(kind, sp, x, y, z)
    norm2 = gx * gx + gy * gy + gz * gz
    norm = torch.sqrt(torch.where(norm2 > 0, norm2, torch.ones_like(norm2)))
    nx, ny, nz = gx / norm, gy / norm, gz / norm  # as refract.unit_normal
    ex, ey, ez, ok = snell_xyz(dx, dy, dz, nx, ny, nz, n1, n2, ok)
    return (torch.stack([x, y, z + z_shift]), torch.stack([ex, ey, ez]), ok, opl + n1 * t)


compiled_newton_start = _compile(newton_start)
compiled_newton_more = _compile(newton_more)
compiled_newton_last_check = _compile(newton_last_check)
compiled_newton_refract = _compile(newton_refract)
