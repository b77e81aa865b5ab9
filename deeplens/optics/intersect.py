"""Differentiable ray-surface intersection (paper Sec. II-C, Eq. 6-7).

Find ``t`` with ``f(o + t d; θ) = 0``.  Newton's method

    t <- t - f(o + t d) / (d · ∇f(o + t d))

starts from the vertex-plane hit ``t0 = -o_z / d_z`` and iterates **without autograd**, per ray,
until ``|f| < tol`` or ``max_iter``.  The iteration runs on ``s = t - t0`` from the re-based
origin ``o' = o + t0 d`` (``t0`` a constant): a ray that starts far from the surface (a backward
ray from the sensor, 100 mm away) would otherwise evaluate ``f`` at ``o + t d`` with a rounding
error of ``|o| eps`` (6e-6 mm at 100 mm in float32), and a tolerance below it could never be
met.  One more Newton step is then taken *with* autograd (Eq. 7).  At the root its value is unchanged, and its derivative is the implicit-function
derivative ``dt/dθ = -(∂f/∂θ) / (d · ∇f)``, so memory does not grow with the iteration count.
``mode="unrolled"`` keeps the whole iteration in the graph (for tests and the memory benchmark).

A ray becomes invalid (never NaN) when it does not converge, when ``d · ∇f`` vanishes (grazing),
when it lands outside the surface's domain or clear aperture, or when ``t`` is negative, unless
the gap is crossed backwards (``backward=True``: a gap of :attr:`Lens.backward_gaps
<deeplens.optics.lens.Lens.backward_gaps>`, where two surfaces cross and OpticStudio traces the
rays beyond the crossing back through the gap; the root is the same, only its sign is free).

Tolerance.  ``|f| < tol`` with ``tol = max(tol_user, 4 eps |x0|_inf)`` per ray, ``x0 = o + t0 d``
(the ray's vertex-plane point, whose size is the hit's): ``f`` evaluated at a point ``x`` carries
a rounding error of about ``eps |x|`` (the stalled Newton residual was at most 1.2 eps |x|_inf
over 97,000 float32 rays through the double Gauss at 1x, 100x and 1000x scale), so an absolute
tolerance alone (1e-5 mm in float32) cannot be met once coordinates reach hundreds of mm.
Rays that stall near the root without meeting it are still marked invalid, and a
``RuntimeWarning`` says so when they are more than 1 % of the rays.

Rays that fail are kept out of every evaluation that autograd records: their residual is taken
at the vertex (a point where every surface is finite) instead of at ``o + t0 d``, which for a
grazing stray ray (|d_z| ~ 1e-8) lies 1e8 mm away where a polynomial sag overflows; a masked
``inf`` there still turned the shared parameters' gradients into NaN (``0 * inf``).

A mirror lit across its frame (``across``, quadric mirrors only: ``Lens.trace_surface``): a ray
parallel to the vertex plane has no ``t0``, and one that meets a steep rim while travelling
against the axis crosses the surface in the sense a ray travelling along it would; both take
the first crossing ahead of the ray instead (rays the rule takes are unchanged).

Quadrics (spheres and conics, ``surface.is_quadric``) skip Newton: the ray meets the quadric
``F = 0`` where ``A s^2 + 2 B s + C = 0`` (:meth:`~.surfaces.Asphere.quadric`), and

    Q = -(B + sign(B) sqrt(B^2 - A C)),      s_1 = C / Q,      s_2 = Q / A

are its roots without cancellation (the textbook ``(-B ± sqrt(.)) / A`` loses all digits of the
near root when ``A C << B^2``, and divides by zero for a paraboloid hit along its axis).  Exactly one
root is where the ray crosses the surface in its direction of travel (``_quadric_root``); it is
the hit when it lies on the surface's branch (``h = 1 - (1+k) c z > 0``).  The coefficients are
taken at the ray's vertex-plane point, or, where that point lies outside the conic's domain
(``|r| > |R|`` on a sphere: a steep ray near a strongly curved surface), at the line's point
nearest the vertex (not the origin, which may lie 100 mm away: float32 cancellation): the
line can still meet the branch further on, as OpticStudio's exact sphere does (before, such
rays were invalid; ``tests/optics/test_quadric_beyond_domain.py``).
The expression is differentiable as it stands: its derivative is the exact implicit derivative
``-(∂F/∂θ) / (d · ∇F)`` of the root, the same as the Eq. 7 step gives at a converged root, and
autograd keeps only a handful of per-ray scalars.  Aspheres start Newton from their conic base's
root (usually one or two iterations) instead of the vertex plane.  ``closed_form=False`` runs
the generic Newton path on every surface (the reference the closed form is tested against for
rays whose vertex-plane point lies within the conic's domain; a ray crossing the vertex plane
outside it, which the closed form solves from its line's point nearest the vertex, may find no
root on the generic path, which starts Newton from that vertex-plane point: there the closed form,
checked against the textbook line-conic intersection, is the reference).

:func:`trace_quadric` is the closed-form path and Snell's law written on per-component tensors
(what :meth:`Lens.trace_surface <deeplens.optics.lens.Lens.trace_surface>` runs for an aligned
sphere or conic); ``tests/optics/test_quadric.py`` checks it against ``intersect`` + ``refract``.

The Newton loop synchronises with the host (``active.any()``) only after iterations 1, 2, 4,
8, ...: an extra iteration on rays that have all converged changes nothing, and each
synchronisation stalls an accelerator's queue.
"""

from __future__ import annotations

import warnings

import torch

from .options import TraceOptions
from .refract import snell_coefficient, snell_xyz
from .openings import in_circle, in_rect
from .surfaces.asphere import conic_arg, conic_normal, conic_quadric

__all__ = ["TraceOptions", "accept_hits", "default_tolerance", "flat_step",
           "flat_step_xyz", "hit_mask", "intersect", "rounding_tolerance", "snell_xyz",
           "quadric_step", "quadric_step_xyz", "trace_quadric"]


def default_tolerance(dtype: torch.dtype) -> float:
    """Residual tolerance |f| in mm: 1e-10 for float64, 1e-5 for float32/16 (a floor: the
    tolerance a ray uses also grows with its coordinates, see the module docstring)."""
    return 1e-10 if dtype == torch.float64 else 1e-5


def __getattr__(name: str):
    """``IntersectOptions``, the former name of :class:`~.options.TraceOptions` (the settings
    now cover the whole trace: Newton, the closed form, compiled kernels and checkpointing),
    still resolves for one release, with a ``DeprecationWarning``."""
    if name == "IntersectOptions":
        warnings.warn(DEPRECATED_OPTIONS, DeprecationWarning, stacklevel=2)
        return TraceOptions
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: the warning of the former name ``IntersectOptions``
DEPRECATED_OPTIONS = ("IntersectOptions is deprecated and will be removed: use TraceOptions "
                      "(from deeplens.optics import TraceOptions), the same class")


#: the tolerance never goes below this many float rounding units of the coordinates, ``eps |x|``
_ROUNDING_ULPS = 4.0
#: warn when more than this fraction of the incoming rays stalls short of the tolerance
_STALL_WARN_FRACTION = 0.01


def _tolerance(tol: float, x: torch.Tensor) -> torch.Tensor:
    """Per-ray tolerance ``max(tol, 4 eps |x|_inf)`` (mm) at evaluation points ``x`` (*B, 3)."""
    return rounding_tolerance(*x.detach().unbind(-1), tol)


def _residual(surface, o, d, t, at=None):
    """``f`` and ``d · ∇f`` at ``o + t d``; where ``at`` is False, at the vertex instead (finite
    for every surface, so a failed ray's far-away point never enters autograd)."""
    x = o + t.unsqueeze(-1) * d
    if at is not None:
        x = torch.where(at.unsqueeze(-1), x, torch.zeros_like(x))
    X, Y, Z = x.unbind(-1)
    fv = surface.f(X, Y, Z)
    fx, fy, fz = surface.f_grad(X, Y, Z)
    fp = fx * d[..., 0] + fy * d[..., 1] + fz * d[..., 2]
    return fv, fp


def _safe_div(a, b, ok):
    return torch.where(ok, a, torch.zeros_like(a)) / torch.where(ok, b, torch.ones_like(b))


def _warn_stalled(surface, o, d, s, tried, converged, tol_ray, tol, fv=None):
    """Warn when many rays ended within 1000 tolerances of the root without meeting the
    tolerance (rounding, not a miss: a ray that misses keeps a large residual).  ``fv``: the
    residual at ``s`` if known (else it is evaluated)."""
    with torch.no_grad():
        left = tried & ~converged
        if not bool(left.any()):
            return
        if fv is None:
            fv, _ = _residual(surface, o, d, s, left)
        stalled = left & torch.isfinite(fv) & (fv.abs() < 1e3 * tol_ray)
        n, total = int(stalled.sum()), int(tried.sum())
        if n > _STALL_WARN_FRACTION * total:
            x = o + s.unsqueeze(-1) * d
            scale = float(x[stalled].abs().amax()) if n else 0.0
            warnings.warn(
                f"intersect: {n} of {total} rays did not converge on a {type(surface).__name__} "
                f"(|f| stalled above the tolerance {tol:g} mm at coordinates up to {scale:.3g} "
                f"mm in {o.dtype}) and are marked invalid; use float64, a larger "
                f"TraceOptions(tol=...) or more max_iter", RuntimeWarning, stacklevel=3)


def _signbit(x):
    """``torch.signbit(x)``; while ``torch.compile`` traces, the same bit (``-0.0`` and NaNs
    with the sign bit set included) through ``copysign``, which inductor's C++ backend
    vectorises (its ``signbit`` is a scalar loop; eager, the two extra operators cost more)."""
    if torch.compiler.is_compiling():
        return torch.copysign(torch.ones_like(x), x) < 0
    return torch.signbit(x)


def _quadric_root(quadric, obz, dz, ok):
    """The root ``s`` (``(*B,)``, differentiable) of ``A s^2 + 2 B s + C = 0`` where the ray
    crosses the branch ``h > 0`` in its direction of travel, and whether it exists (``s = 0``
    elsewhere; whether it lies ahead of the ray is checked with the other surfaces').

    ``d · ∇F = 2 (A s + B)`` is ``+2 sign(B) sqrt(disc)`` at ``s_1 = C / Q`` and the opposite at
    ``s_2 = Q / A``; on the branch ``∇F = 2 h ∇f`` with ``h > 0``, and a ray travelling towards
    ``±z`` passes from ``f > 0`` to ``f < 0`` or back (``sign(d · ∇f) = -sign(d_z)``, as
    ``∂f/∂z = -1``).  So exactly one root is the crossing in the direction of travel: ``s_1`` when
    ``B`` and ``d_z`` have opposite signs.  (The other one is where a grazing ray leaves the
    surface again, before or after.)
    """
    A, B, C, ck = quadric[:4]
    disc = B * B - A * C
    hit = ok & (disc > 1e-24)  # a miss, or a tangent ray (d · ∇F = ±2 sqrt(disc) vanishes)
    sq = torch.sqrt(torch.where(hit, disc, torch.ones_like(disc)))
    Q = -(B + torch.copysign(sq, B))  # |Q| >= sqrt(disc): no cancellation
    with torch.no_grad():
        use1 = _signbit(B) ^ _signbit(dz)
        # s_1 = C / Q; s_2 = Q / A only while the far root lies within 1e10 mm
        hit = hit & torch.where(use1, Q.abs() > 1e-12,
                                (A.abs() > 1e-12) & (Q.abs() < 1e10 * A.abs()))
    den = torch.where(use1, Q, A)
    s = torch.where(use1, C, Q) / torch.where(hit, den, torch.ones_like(den))
    with torch.no_grad():
        hit = hit & (ck * (obz + s * dz) < 1.0)
    return torch.where(hit, s, torch.zeros_like(s)), hit


def trace_quadric(surface, o, d, valid, opl, z_shift, n1, n2, options=None,
                  backward: bool = False):
    """Intersect and refract at a quadric surface in one pass over per-component tensors.

    The same computation as :func:`intersect` on the closed-form path followed by
    :func:`~.refract.refract` at :meth:`~.surfaces.Asphere.normal`, for a surface whose frame is
    its vertex shifted by ``z_shift`` along the axis (no misalignment).  Written on the ``x``,
    ``y``, ``z`` components (``(*B,)`` each) instead of ``(*B, 3)`` tensors: the shift touches
    ``z`` only, and each step reads one component at a time, about 2x less memory traffic.
    The arithmetic is the pure tensor function :func:`quadric_step` (which
    ``TraceOptions(compile=...)`` runs compiled, :mod:`.compiled`).

    Args:
        surface: a surface with ``is_quadric`` (an :class:`~.surfaces.Asphere` without
            coefficients: sphere or conic).
        o, d: ``(*B, 3)`` origins (mm, global frame) and unit directions.
        valid, opl: ``(*B,)`` mask and optical path length (mm).
        z_shift: vertex position (0-d tensor, mm).
        n1, n2: media indices, broadcastable to ``B``.
        backward: accept a hit behind the ray (:func:`hit_mask`).

    Returns:
        ``(x, d_t, valid, opl)`` in the global frame, as :meth:`Lens.trace_surface` returns them.
    """
    opt = options or TraceOptions()
    tol = opt.tol if opt.tol is not None else default_tolerance(o.dtype)
    args = (o, d, valid, opl, z_shift, *surface.fused_values(o),   # c, k and the clip radius
            torch.as_tensor(n1, dtype=o.dtype, device=o.device),
            torch.as_tensor(n2, dtype=o.dtype, device=o.device))
    return quadric_step(*args, tol=tol, clip=opt.clip_aperture, backward=backward)


def quadric_step(o, d, valid, opl, z_shift, c, k, semi_diameter, n1, n2, tol: float,
                 clip: bool = True, backward: bool = False):
    """The arithmetic of :func:`trace_quadric` as a pure function of tensors (no modules, no
    host synchronisation, no data-dependent Python branch), so that ``torch.compile`` can fuse
    it into one kernel.

    Args:
        o, d: ``(*B, 3)`` origins (mm, global frame) and unit directions.
        valid, opl: ``(*B,)`` mask and optical path length (mm).
        z_shift: vertex position (0-d, mm).
        c, k, semi_diameter: curvature (1/mm), conic constant, clear semi-aperture (mm), 0-d,
            in the rays' dtype.
        n1, n2: media indices, broadcastable to ``B``.
        tol: residual tolerance floor (mm), see :func:`default_tolerance`.
        clip: mark rays outside the clear aperture invalid.
        backward: accept a hit behind the ray (:func:`hit_mask`).

    Returns:
        ``(x (*B, 3), d_t (*B, 3), valid (*B,), opl (*B,))``.
    """
    x, y, z, dx, dy, dz, ok, opl = quadric_step_xyz(*o.unbind(-1), *d.unbind(-1), valid, opl,
                                                    z_shift, c, k, semi_diameter, n1, n2, tol,
                                                    clip, backward)
    return torch.stack([x, y, z], -1), torch.stack([dx, dy, dz], -1), ok, opl


def quadric_step_xyz(ox, oy, oz, dx, dy, dz, valid, opl, z_shift, c, k, semi_diameter, n1, n2,
                     tol: float, clip: bool = True, backward: bool = False):
    """:func:`quadric_step` on the ``(*B,)`` components of ``o`` and ``d``; returns
    ``(x, y, z, d_x, d_y, d_z, valid, opl)``."""
    oz = oz - z_shift
    ok = valid & (dz.abs() > 1e-12)
    t0 = _safe_div(-oz, dz, ok).detach()
    with torch.no_grad():  # as in intersect(): beyond the conic's domain, from the line's
        bx, by = ox + t0 * dx, oy + t0 * dy          # point nearest the vertex
        tc = -(ox * dx + oy * dy + oz * dz)
        t0 = torch.where(conic_arg(bx * bx + by * by, c, k) > 0, t0, tc)
    bx, by, bz = ox + t0 * dx, oy + t0 * dy, oz + t0 * dz
    quadric = conic_quadric(bx, by, bz, dx, dy, dz, c, k)  # the conic base, as Asphere.quadric
    s, found = _quadric_root(quadric, bz, dz, ok)
    ok = ok & found
    t = t0 + s
    x, y, z = bx + s * dx, by + s * dy, bz + s * dz
    t, x, y, z, ok = accept_hits(t, x, y, z, ox, oy, oz, ok, semi_diameter, tol, clip,
                                 backward)
    nx, ny, nz = conic_normal(x, y, z, c, quadric[3])  # as Asphere.normal
    ex, ey, ez, ok = snell_xyz(dx, dy, dz, nx, ny, nz, n1, n2, ok)
    return x, y, z + z_shift, ex, ey, ez, ok, opl + n1 * t


def rounding_tolerance(X, Y, Z, tol: float):
    """``max(tol, 4 eps |x|_inf)`` (mm) per ray at points with components ``X, Y, Z``
    (detached): the residual and "ahead of the ray" allowance (module docstring)."""
    eps = torch.finfo(X.dtype).eps
    big = torch.maximum(torch.maximum(X.abs(), Y.abs()), Z.abs())
    return torch.clamp(_ROUNDING_ULPS * eps * big, min=tol)


def hit_mask(t, X, Y, Z, ok, tol: float, inside=None, backward: bool = False):
    """Hit acceptance, written once (no autograd): ``ok`` and the hit at distance ``t`` lies
    ahead of the ray (``t >= -``:func:`rounding_tolerance`; with ``backward``, at either sign:
    a gap of :attr:`Lens.backward_gaps <deeplens.optics.lens.Lens.backward_gaps>`), inside the
    clear aperture (``inside``, a mask, or ``None`` when not clipping) and is finite.
    ``X, Y, Z``: the hit's detached components.  :func:`intersect`, :func:`accept_hits` and
    the compiled plane step call it."""
    with torch.no_grad():
        if not backward:
            ok = ok & (t >= -rounding_tolerance(X, Y, Z, tol))
        if inside is not None:
            ok = ok & inside
        return ok & torch.isfinite(t)


def accept_hits(t, x, y, z, ox, oy, oz, ok, semi_diameter, tol: float, clip: bool,
                backward: bool = False):
    """:func:`hit_mask` on components with a circular aperture of radius ``semi_diameter``
    when ``clip`` (``backward``: a hit behind the ray too); a ray that fails keeps its origin
    ``o`` and ``t = 0``.  Returns ``(t, x, y, z, ok)``."""
    X, Y = x.detach(), y.detach()
    inside = in_circle(X, Y, semi_diameter) if clip else None
    ok = hit_mask(t, X, Y, z.detach(), ok, tol, inside, backward)
    t = torch.where(ok, t, torch.zeros_like(t))
    x, y, z = torch.where(ok, x, ox), torch.where(ok, y, oy), torch.where(ok, z, oz)
    return t, x, y, z, ok


def flat_step(o, d, valid, opl, z_shift, aperture, n1, n2, tol: float, clip: bool = True):
    """Intersect and refract at an aligned plane ``z = z_shift`` (a :class:`~.surfaces.Plane`;
    a stop is crossed, not landed on: :func:`stop_step_xyz`): the same computation as
    :func:`intersect`'s flat path followed by :func:`~.refract.refract` at the normal
    ``(0, 0, -1)``, as a pure function of tensors (see :func:`quadric_step`).

    Args:
        o, d, valid, opl, z_shift, n1, n2, tol, clip: as :func:`quadric_step`.
        aperture: the 0-d semi-diameter (mm).

    Returns:
        ``(x (*B, 3), d_t (*B, 3), valid (*B,), opl (*B,))``.
    """
    x, y, z, dx, dy, dz, ok, opl = flat_step_xyz(*o.unbind(-1), *d.unbind(-1), valid, opl,
                                                 z_shift, aperture, n1, n2, tol, clip)
    return torch.stack([x, y, z], -1), torch.stack([dx, dy, dz], -1), ok, opl


def flat_step_xyz(ox, oy, oz, dx, dy, dz, valid, opl, z_shift, aperture, n1, n2, tol: float,
                  clip: bool = True):
    """:func:`flat_step` on the ``(*B,)`` components of ``o`` and ``d``; returns
    ``(x, y, z, d_x, d_y, d_z, valid, opl)``."""
    oz = oz - z_shift
    ok = valid & (dz.abs() > 1e-12)
    t = _safe_div(-oz, dz, ok)
    x, y, z = ox + t * dx, oy + t * dy, oz + t * dz
    t, x, y, z, ok = accept_hits(t, x, y, z, ox, oy, oz, ok, aperture, tol, clip)
    # Snell's law (refract.snell_coefficient) at n = (0, 0, -1): cos_i = -d_z
    eta = n1 / n2
    coef, ok = snell_coefficient(-dz, eta, ok)
    ex = torch.where(ok, eta * dx, dx)
    ey = torch.where(ok, eta * dy, dy)
    ez = torch.where(ok, eta * dz - coef, dz)
    return x, y, z + z_shift, ex, ey, ez, ok, opl + n1 * t


def stop_crossing_xyz(ox, oy, oz, dx, dy, dz, valid):
    """Where each ray's *line* crosses the plane ``z = 0`` (a virtual stop): ``(X, Y, t, ok)``,
    ``t = -o_z / d_z`` of either sign (a stop plane inside a neighbouring lens's sag is crossed
    behind the ray's origin), ``ok``: ``valid``, ``d_z != 0`` and a finite crossing.  No
    autograd: only the mask is used when the rays are not moved; ``t`` is ``0`` where not ok."""
    with torch.no_grad():
        ok = valid & (dz.abs() > 1e-12)
        t = _safe_div(-oz, dz, ok)   # of either sign: no hit_mask
        X, Y = ox + t * dx, oy + t * dy
        ok = ok & torch.isfinite(X) & torch.isfinite(Y)
        return X, Y, torch.where(ok, t, torch.zeros_like(t)), ok


def stop_step_xyz(ox, oy, oz, dx, dy, dz, valid, opl, z_shift, aperture, n1, n2, tol: float,
                  clip: bool = True, rect: bool = False):
    """A virtual stop at ``z = z_shift`` on components (the compiled runs' ``"stop"`` and
    ``"stop_rect"`` steps; :meth:`Lens.trace_surface
    <deeplens.optics.lens.Lens.trace_surface>` does the same for any stop): rays whose line
    crosses the plane outside the opening (``aperture``: the semi-diameter, or ``(2,)``
    half-widths when ``rect``) go invalid when ``clip``; the ray state is otherwise unchanged
    (origin, direction, optical path), so the next surface is intersected from where the ray
    was.  ``n1``, ``n2``, ``tol``: unused (the :func:`flat_step_xyz` signature)."""
    X, Y, _, ok = stop_crossing_xyz(ox, oy, oz - z_shift, dx, dy, dz, valid)
    if clip:
        ok = ok & (in_rect(X, Y, aperture) if rect else in_circle(X, Y, aperture))
    return ox, oy, oz, dx, dy, dz, ok, opl


def propagate_xyz(ox, oy, oz, dx, dy, dz, valid, opl, z_plane, n):
    """Move rays to the plane ``z = z_plane`` (mm) in a medium of index ``n``, on the ``(*B,)``
    components (:meth:`Lens.propagate_to_z <deeplens.optics.lens.Lens.propagate_to_z>` and
    the compiled runs' ``"propagate"`` step): rays that cannot reach it (``d_z = 0`` or the
    plane behind them) go invalid and stay where they are.  Returns ``(x, y, z, d_x, d_y,
    d_z, valid, opl)``."""
    t, ok = propagate_distance(oz, dz, valid, z_plane)
    return ox + t * dx, oy + t * dy, oz + t * dz, dx, dy, dz, ok, opl + n * t


def propagate_distance(oz, dz, valid, z_plane, backwards: bool = False):
    """``(t, ok)``: the marching distance ``(*B,)`` (mm) to the plane ``z = z_plane`` and
    whether the ray reaches it (``d_z != 0``, ahead of it); ``t = 0`` where not.
    ``backwards``: a plane behind the ray is reached too, along the ray's line extended
    backwards (``t < 0``: a virtual image plane, :attr:`Lens.virtual_image
    <deeplens.optics.lens.Lens.virtual_image>`)."""
    ok = valid & (dz.abs() > 1e-12)
    num = torch.where(ok, z_plane - oz, torch.zeros_like(dz))
    t = num / torch.where(ok, dz, torch.ones_like(dz))
    if not backwards:
        ok = ok & (t.detach() >= 0)
    return torch.where(ok, t, torch.zeros_like(t)), ok


def _nearest_root_ahead(quadric, oz, dz, ok):
    """The smaller root ``s >= 0`` (``(*B,)``, differentiable) of ``A s^2 + 2 B s + C = 0`` on
    the branch ``h > 0``, whatever the crossing's sense, and whether there is one: the first
    point ahead of a ray at ``o`` (``s`` from ``o``) where it meets the quadric."""
    A, B, C, ck = quadric[:4]
    disc = B * B - A * C
    hit = ok & (disc > 1e-24)
    sq = torch.sqrt(torch.where(hit, disc, torch.ones_like(disc)))
    Q = -(B + torch.copysign(sq, B))
    with torch.no_grad():
        has1 = hit & (Q.abs() > 1e-12)
        has2 = hit & (A.abs() > 1e-12) & (Q.abs() < 1e10 * A.abs())
    s1 = C / torch.where(has1, Q, torch.ones_like(Q))
    s2 = Q / torch.where(has2, A, torch.ones_like(A))
    with torch.no_grad():
        has1 = has1 & (s1 >= 0) & (ck * (oz + s1 * dz) < 1.0)
        has2 = has2 & (s2 >= 0) & (ck * (oz + s2 * dz) < 1.0)
        use1 = has1 & ~(has2 & (s2 < s1))
    s = torch.where(use1, s1, torch.where(has2, s2, torch.zeros_like(s2)))
    return s, has1 | has2


def intersect(surface, o: torch.Tensor, d: torch.Tensor, valid: torch.Tensor,
              options: TraceOptions | None = None, backward: bool = False,
              across: bool = False):
    """Intersect rays with ``surface`` in its local frame.

    Args:
        surface: a :class:`~deeplens.optics.surfaces.Surface`.
        o, d: ``(*B, 3)`` ray origins (mm) and unit directions in the surface frame.
        valid: ``(*B,)`` incoming validity.
        options: :class:`~.options.TraceOptions`.
        backward: accept a hit behind the ray (``t < 0``, :func:`hit_mask`).
        across: on a quadric (a sphere or conic mirror, :meth:`Lens.trace_surface
            <deeplens.optics.lens.Lens.trace_surface>` passes it for mirrors), a ray the vertex
            plane cannot start (``|d_z| <= 1e-12``: it travels across the surface's frame) or
            whose crossing in its direction of travel lies behind it meets the surface at the
            first crossing ahead instead (:func:`_nearest_root_ahead`, from ``o``): an off-axis
            paraboloid lit from its focus across its axis, whose steep rim the rays meet while
            travelling against the axis.  Rays the rule takes are unchanged.

    Returns:
        ``(t, x, valid)``: marching distance ``(*B,)`` (mm), hit point ``(*B, 3)`` and the
        updated mask.  For invalid rays ``t`` and ``x`` are finite but meaningless.
    """
    opt = options or TraceOptions()
    tol = opt.tol if opt.tol is not None else default_tolerance(o.dtype)
    dz = d[..., 2]
    ok = valid & (dz.abs() > 1e-12)
    t0 = _safe_div(-o[..., 2], dz, ok).detach()

    quadric = opt.mode == "implicit" and opt.closed_form and surface.is_quadric
    if surface.is_flat:
        t = _safe_div(-o[..., 2], dz, ok)
        ob, s = o, t
    elif quadric:
        # the roots from the ray's vertex-plane point; where that point lies outside the
        # conic's domain (|r| > |R| on a sphere: a steep ray near a strongly curved surface,
        # the chief ray of a wide-angle lens's edge field), from another point of its line: the
        # ray can still meet the surface's branch there, as OpticStudio's exact intersection
        # finds it (before, such rays were invalid).  Not from the origin, which may lie far
        # away (a backward ray from the sensor: float32 lost digits to |o|^2 in C): from the
        # line's point nearest the vertex, as near the surface as the ray comes; the
        # vertex-plane point, where it is in the domain, keeps every other ray's digits
        with torch.no_grad():
            xy0 = (o[..., :2] + t0.unsqueeze(-1) * d[..., :2])
            t0 = torch.where(surface.in_domain(xy0[..., 0], xy0[..., 1]), t0,
                             -(o * d).sum(-1))
        ob = o + t0.unsqueeze(-1) * d
        s, found = _quadric_root(surface.quadric(ob, d), ob[..., 2], d[..., 2], ok)
        ok = ok & found
        t = t0 + s
        if across and not backward:
            with torch.no_grad():
                xh = (ob + s.unsqueeze(-1) * d).detach()
                behind = ok & (t.detach() < -rounding_tolerance(*xh.unbind(-1), tol))
                redo = valid & ((dz.abs() <= 1e-12) | behind)
            if bool(redo.any()):
                s2, hit2 = _nearest_root_ahead(surface.quadric(o, d), o[..., 2], d[..., 2], redo)
                ob = torch.where(redo.unsqueeze(-1), o, ob)
                s = torch.where(redo, s2, s)
                t = torch.where(redo, s2, t)
                ok = torch.where(redo, hit2, ok)
    elif opt.mode == "implicit":
        with torch.no_grad():
            dd = d.detach()
            obd = o.detach() + t0.unsqueeze(-1) * dd
            base = surface.quadric(obd, dd) if opt.closed_form else None
            if base is None:
                s_star = torch.zeros_like(t0)
            else:  # start from the root of the conic base (an asphere's first term)
                s_star, _ = _quadric_root(base, obd[..., 2], dd[..., 2], ok)
            tried = ok
            active = ok.clone()
            converged = torch.zeros_like(ok)
            tol_ray = _tolerance(tol, obd)
            for it in range(opt.max_iter):
                fv, fp = _residual(surface, obd, dd, s_star)  # no graph: inf is only masked
                done = active & (fv.abs() < tol_ray)
                converged = converged | done
                active = active & ~done
                good = active & (fp.abs() > 1e-12) & torch.isfinite(fv)
                active = good
                if (it & (it + 1)) == 0 and not bool(active.any()):  # after 1, 2, 4, 8, ...
                    break
                s_star = torch.where(active, s_star - _safe_div(fv, fp, active), s_star)
            else:
                fv, _ = _residual(surface, obd, dd, s_star)
                converged = converged | (active & (fv.abs() < tol_ray))
            # fv is the residual at every ray's final s_star (evaluated for all rays each step)
            _warn_stalled(surface, obd, dd, s_star, tried, converged, tol_ray, tol, fv)
            ok = ok & converged
            s_star = torch.where(ok, s_star, torch.zeros_like(s_star))
        # one differentiable Newton step (Eq. 7); t0 is a constant, so ds/dθ = dt/dθ.  Failed
        # rays are evaluated at the vertex (see the module docstring: 0 * inf = NaN otherwise).
        ob = o + t0.unsqueeze(-1) * d
        fv, fp = _residual(surface, ob, d, s_star, ok)
        ok = ok & (fp.detach().abs() > 1e-12)
        s = s_star - _safe_div(fv, fp, ok)
        t = t0 + s
    else:  # unrolled: every iteration is recorded by autograd
        # A ray stops one recorded step *after* its residual falls below ``tol``.  The derivative
        # of a Newton iterate lags its value by one step (d t_{k+1} = -f_θ/f' + O(f(t_k))), so
        # stopping as soon as |f(t_k)| < tol left a derivative error of O(f(t_{k-1})) (~1e-6
        # relative), and a ray already on the surface at t0 kept the detached t0 and lost its
        # whole derivative.  The last step here starts at |f| < tol, as Eq. 7 does, but the
        # gradient still flows through the entire chain (regression tests in test_gradients.py).
        ob = o + t0.unsqueeze(-1) * d
        s = torch.zeros_like(t0)
        tried = ok
        active = ok.clone()
        converged = torch.zeros_like(ok)
        tol_ray = _tolerance(tol, ob)
        for _ in range(opt.max_iter):
            fv, fp = _residual(surface, ob, d, s, active)
            bad = active & ~(torch.isfinite(fv.detach()) & torch.isfinite(fp.detach()))
            if bool(bad.any()):  # a diverged ray: drop it and re-record without its inf
                active = active & ~bad
                fv, fp = _residual(surface, ob, d, s, active)
            step = active & (fp.detach().abs() > 1e-12)
            small = step & (fv.detach().abs() < tol_ray)
            s = torch.where(step, s - _safe_div(fv, fp, step), s)
            converged = converged | small
            active = step & ~small
            if not bool(active.any()):
                break
        else:
            with torch.no_grad():
                fv, _ = _residual(surface, ob, d, s, active)
                converged = converged | (active & (fv.abs() < tol_ray))
        _warn_stalled(surface, ob.detach(), d.detach(), s.detach(), tried, converged, tol_ray, tol)
        ok = ok & converged
        t = t0 + s
        # no separate Eq. 7 step: the gradient is the one of the unrolled chain

    # the hit from the re-based origin (no cancellation in float32); invalid rays keep x = o
    x = ob + s.unsqueeze(-1) * d
    X, Y = x[..., 0].detach(), x[..., 1].detach()
    if not quadric:  # on a quadric's branch h > 0 the domain 1 - (1+k) c^2 r^2 = h^2 > 0 holds
        ok = ok & surface.in_domain(X, Y)
    ok = hit_mask(t.detach(), X, Y, x[..., 2].detach(), ok, tol,
                  surface.in_aperture(X, Y) if opt.clip_aperture else None, backward)
    t = torch.where(ok, t, torch.zeros_like(t))
    x = torch.where(ok.unsqueeze(-1), x, o)
    return t, x, ok
