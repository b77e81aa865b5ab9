"""Global placement of a folded lens's local frames (coordinate breaks composed).

The tracer works in local frames: each :class:`~.surfaces.CoordinateBreak` re-expresses the
rays in the frame of the following surfaces (its module docstring gives the map).  Frame ``k``
maps to the global frame (the object-space frame) by ``x_global = A_k x + b_k``; a break at
vertex ``z_b`` with decenter ``δ`` and rotation ``R`` gives

    A_{k+1} = A_k R,        b_{k+1} = b_k + A_k (z_b e_z + δ - R z_b e_z)

A lens without breaks has one frame, ``A = I``, ``b = 0``.  Used by layouts through a fold and
to place a folded system's image in space.

:func:`travel_directions` gives the direction of travel along each medium's local axis (the
sign of the distances there, :meth:`Lens.directions <deeplens.optics.lens.Lens.directions>`)
from the traced axis: the beam's direction after each surface in that surface's frame.
"""

from __future__ import annotations

import math

import torch


__all__ = ["local_frames", "to_global", "travel_directions", "traced_axes",
           "mirrors_met_edge_on", "vertex_normal"]

#: an axis direction whose local z component is smaller than this (a beam travelling across
#: the frame, as between the two mirrors of a roof) keeps the sign of the medium before it
_ACROSS = 1e-9


def local_frames(lens) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """``[(A (3, 3), b (3,)), ...]``: the frame of each of the ``N`` surfaces and, last, of the
    sensor (``N + 1`` entries), in the lens's dtype; differentiable in the breaks' values and
    the distances.  A break's own vertex is in the frame before it."""
    z = lens.z_vertices()
    like = z   # the lens's dtype and device
    A = torch.eye(3, dtype=lens.dtype, device=lens.device)
    b = torch.zeros(3, dtype=lens.dtype, device=lens.device)
    out = []
    for i, s in enumerate(lens.surfaces):
        out.append((A, b))
        if s.interaction.changes_frame:   # a coordinate break
            R = s.rotation(like)
            zero = torch.zeros_like(z[i])
            zc = torch.stack([zero, zero, z[i]])
            b = b + A @ (zc + s.offset(like) - R @ zc)
            A = A @ R
    out.append((A, b))
    return out


def to_global(frame, x: torch.Tensor) -> torch.Tensor:
    """Points ``(*B, 3)`` of a local frame ``(A, b)`` in global coordinates (for directions,
    pass ``b = 0``)."""
    A, b = frame
    return x @ A.T.to(x) + b.to(x)


def travel_directions(surfaces, mirrors, indices=None, wavelength_nm=None) -> list[int]:
    """The direction of travel (``+1``: towards ``+z``, ``-1``: towards ``-z``) along the local
    axis of each of the ``N + 1`` media of a sequential system: object space first, then the
    medium after each surface, in the frame the distance after that surface is measured in.

    It is the sign of the local ``z`` component of the *traced axis*: a unit vector that starts
    along ``+z`` in object space, is re-expressed by every coordinate break (``d_after = R^T
    d_before``; decenters do not turn it), is reflected by every mirror about the mirror's
    vertex normal (:func:`vertex_normal`: the local ``z`` axis for every surface whose sag has no
    linear term; a tilted plane's own normal, OpticStudio's ``TILTSURF``) and refracted there by
    vector Snell's law
    (``indices``: the ``N + 1`` media indices at one wavelength; ``None`` or total internal
    reflection: left as it is; an ideal lens not at all).  A diffracting surface (a grating,
    OpticStudio's ``DGRATING``) sends it on in the order it traces, at ``wavelength_nm`` (the
    wavelength of ``indices``), by the surface's own ``diffract`` at its vertex: OpticStudio's
    sequential trace follows the order the surface states (a grating stretcher whose breaks
    turn the frame onto the first order, which leaves near the incoming beam, not along the
    mirror's zeroth order); without ``wavelength_nm``, or where the order is evanescent at the
    vertex, its zeroth order.  This is where OpticStudio's sequential trace takes the beam,
    and so the sign its thicknesses carry for real propagation.  Without coordinate breaks the
    axis meets every surface at normal incidence and the rule is the mirror count's parity
    (``-1`` after an odd number of mirrors, Zemax's convention); with a fold written as
    ``break, mirror, break`` it is the same; where mirrors tilted inside break pairs that return
    the frame turn the beam round (a roof: the beam leaves along ``-z`` of an unturned frame
    after two mirrors), the parity is wrong and this is right.  An axis that crosses the frame
    (``|d_z| < 1e-9``, between the two mirrors of a roof) keeps the sign before it; one that
    meets a mirror edge-on (normal to the mirror's vertex normal, never reaching its vertex: an
    off-axis parabola lit from its focus across its axis) leaves along the local axis with the
    sign flipped (the parity rule).

    Args:
        surfaces: the ``N`` surfaces (:class:`~.surfaces.CoordinateBreak` turns the frame).
        mirrors: indices of the reflecting surfaces.
        indices: ``N + 1`` refractive indices (floats) or ``None``.
        wavelength_nm: the vacuum wavelength of ``indices`` (nm), for diffracting surfaces.

    Returns:
        ``N + 1`` ints, each ``+1`` or ``-1``.
    """
    return _traced_axis(surfaces, mirrors, indices, wavelength_nm)[0]


def traced_axes(surfaces, mirrors, indices=None, wavelength_nm=None) -> list[list[float]]:
    """The traced axis itself (:func:`travel_directions`): ``N + 1`` unit vectors ``[a_x, a_y,
    a_z]``, object space first, then the beam's direction after each surface in that surface's
    frame (the frame the distance after it is measured in; a coordinate break's entry is in the
    frame after it)."""
    return _traced_axis(surfaces, mirrors, indices, wavelength_nm)[2]


def mirrors_met_edge_on(surfaces, mirrors, indices=None, wavelength_nm=None) -> list[int]:
    """The indices of the mirrors the traced axis (:func:`travel_directions`) meets edge-on:
    travelling across their frame, so that it never reaches their vertex (an off-axis parabola
    lit from its focus across its axis).  The beam's centre then runs parallel to the mirror's
    vertex plane, where deeplens' intersection (from that plane) cannot follow it."""
    return _traced_axis(surfaces, mirrors, indices, wavelength_nm)[1]


def _diffract_axis(surface, a, n_after: float, wavelength_nm: float):
    """Unit direction ``a`` (already reflected or refracted at ``surface``'s vertex) sent on in
    the surface's diffraction order by its own ``diffract`` at the vertex (``n_after``: the
    index the ray leaves into; the index before at a mirror); unchanged where the order is
    evanescent there.  The tensors are made in the surface's own dtype and on its device (a
    lens in float32 or on a GPU), as its ``diffract`` expects."""
    like = next((t for t in (*surface.parameters(), *surface.buffers())
                 if t.is_floating_point()), None)
    kw = ({"dtype": like.dtype, "device": like.device} if like is not None
          else {"dtype": torch.float64})
    with torch.no_grad():
        x = torch.zeros(1, 3, **kw)
        d = torch.tensor([a], **kw)
        w = torch.tensor([float(wavelength_nm)], **kw)
        n = torch.tensor([float(n_after)], **kw)
        ok = torch.ones(1, dtype=torch.bool, device=kw.get("device"))
        out, ok = surface.diffract(x, d, w, n, ok)
    return [float(v) for v in out[0]] if bool(ok[0]) else a


def _traced_axis(surfaces, mirrors, indices=None,
                 wavelength_nm=None) -> tuple[list[int], list[int], list[list[float]]]:
    """``(signs, edge_on, axes)``: :func:`travel_directions`, :func:`mirrors_met_edge_on` and
    :func:`traced_axes`."""
    mirrors = set(mirrors)
    edge_on = []
    if not any(s.interaction.changes_frame for s in surfaces):   # normal incidence everywhere
        out = [1]
        for i in range(len(surfaces)):
            out.append(-out[-1] if i in mirrors else out[-1])
        return out, edge_on, [[0.0, 0.0, float(v)] for v in out]
    like = torch.zeros((), dtype=torch.float64)
    a = [0.0, 0.0, 1.0]
    out = [1]
    axes = [list(a)]
    for i, s in enumerate(surfaces):
        if s.interaction.changes_frame:
            with torch.no_grad():
                R = s.rotation(like).tolist()
            a = [sum(R[j][k] * a[j] for j in range(3)) for k in range(3)]   # R^T a
        elif i in mirrors and _edge_on(a, s):
            # the axis meets the mirror edge-on (normal to its vertex normal: it crosses the
            # frame and never reaches the vertex, an off-axis parabola lit from its focus across
            # its axis): no reflection to trace; it leaves along the local axis, turned round by
            # the mirror (the parity rule), so the sign flips (OpticStudio's "90 degree
            # parabolas" sample)
            a = [0.0, 0.0, -float(out[-1])]
            edge_on.append(i)
        elif i in mirrors:
            nv = vertex_normal(s)
            an = sum(a[k] * nv[k] for k in range(3))
            a = [a[k] - 2.0 * an * nv[k] for k in range(3)]
            if s.law == "diffract" and indices is not None and wavelength_nm is not None:
                a = _diffract_axis(s, a, float(indices[i]), wavelength_nm)
        elif indices is not None and s.law in ("refract", "diffract"):
            a = _refract_axis(a, float(indices[i]), float(indices[i + 1]), vertex_normal(s))
            if s.law == "diffract" and wavelength_nm is not None:
                a = _diffract_axis(s, a, float(indices[i + 1]), wavelength_nm)
        n = math.sqrt(sum(c * c for c in a))
        a = [c / n for c in a]
        out.append(out[-1] if abs(a[2]) < _ACROSS else (1 if a[2] > 0 else -1))
        axes.append(list(a))
    return out, edge_on, axes


def _edge_on(a, surface) -> bool:
    """Whether the unit direction ``a`` runs normal to ``surface``'s vertex normal
    (:func:`vertex_normal`, within ``1e-9``): the axis meets the surface edge-on."""
    nv = vertex_normal(surface)
    return abs(sum(a[k] * nv[k] for k in range(3))) < _ACROSS


def vertex_normal(surface) -> list[float]:
    """The unit normal ``[n_x, n_y, n_z]`` of ``surface`` at its vertex (the origin of its
    frame), from its implicit function's gradient: ``±e_z`` for every surface whose sag has no
    linear term, a tilted plane's own normal (``z = x tan θ_x + y tan θ_y``: ``(tan θ_x, tan θ_y,
    -1)`` normalised).  The local ``z`` axis where the surface has no gradient there."""
    zero = torch.zeros((), dtype=torch.float64)
    try:
        with torch.no_grad():
            g = [float(v) for v in surface.f_grad(zero, zero, zero)]
    except (NotImplementedError, AttributeError, TypeError, RuntimeError):
        return [0.0, 0.0, 1.0]
    n = math.sqrt(sum(c * c for c in g))
    if not (n > 0 and math.isfinite(n)):
        return [0.0, 0.0, 1.0]
    return [c / n for c in g]


def _refract_axis(a, n1: float, n2: float, normal=(0.0, 0.0, 1.0)):
    """Unit direction ``a`` refracted from index ``n1`` into ``n2`` at a surface of unit normal
    ``normal`` (either orientation; the local ``z`` axis by default) by vector Snell's law;
    unchanged at total internal reflection or a non-positive index."""
    if not (n1 > 0 and n2 > 0) or n1 == n2:
        return a
    cos_i = sum(a[k] * normal[k] for k in range(3))
    nv = [c if cos_i >= 0 else -c for c in normal]   # oriented along the direction of travel
    cos_i = abs(cos_i)
    r = n1 / n2
    sin2 = r * r * (1.0 - cos_i * cos_i)
    if sin2 >= 1.0:
        return a
    cos_t = math.sqrt(1.0 - sin2)
    return [r * a[k] + (cos_t - r * cos_i) * nv[k] for k in range(3)]
