"""Zemax ``COORDBRK`` surfaces: which become an element's misalignment, which a
:class:`~deeplens.optics.surfaces.CoordinateBreak` (a fold, an off-axis section).

A ``COORDBRK`` changes the frame of every following surface (OpticStudio's definition, which
:class:`~deeplens.optics.surfaces.CoordinateBreak` implements with both order flags).  Reading
every break as a ``CoordinateBreak`` is therefore always exact; the reader still maps the
tolerancing idiom -- a break, one whole element in air, a return to its first vertex and the
break that undoes the first -- onto that element's
:class:`~deeplens.optics.misalignment.Misalignment` (what deeplens' tolerancing and design
tools perturb), when the misalignment can express it:

* the opening break has order flag 0 and thickness 0; the next non-identity break has the
  negated values with order flag 1 (or both are pure decenters);
* with a tilt, the surfaces between return to the first vertex (thicknesses summing to 0);
* air before the opening and after the element (a whole element);
* tilts about one axis, or an element whose surfaces are all rotationally symmetric
  (``STANDARD`` / ``EVENASPH`` without a rectangular aperture).

Any other break (folds, off-axis mirrors, a decenter never undone, a pair around part of a
cemented group) becomes a ``CoordinateBreak`` surface.  A break with every value zero is a
dummy: only its thickness counts.
"""

from __future__ import annotations

import dataclasses
import math

from ..surfaces import CoordinateBreak
from .zmx_scbd import scbd_identity

__all__ = ["is_identity", "misalignment_brackets", "coordinate_break", "coordbrk_lines",
           "stop_plane_of_break"]

_PARMS = (1, 2, 3, 4, 5)   # dx, dy, tilt x, tilt y, tilt z


def _values(s) -> tuple:
    return tuple(s.parm.get(i, (0.0, 0))[0] for i in _PARMS)


def _order(s) -> float:
    return s.parm.get(6, (0.0, 0))[0]


def is_identity(s) -> bool:
    """A ``COORDBRK`` that decenters and tilts by zero: a dummy surface (its thickness only)."""
    return s.type == "COORDBRK" and all(v == 0 for v in _values(s))


def _air_before(surfs, k: int) -> bool:
    """Whether the medium in front of ``SURF k`` is air (a mirror or a break keeps the medium
    of the surface before it)."""
    for j in range(k - 1, -1, -1):
        s = surfs[j]
        if s.type == "COORDBRK" or s.mirror:
            continue
        return s.glass is None and s.glass_model is None
    return True


def _symmetric(s) -> bool:
    return s.type in ("STANDARD", "EVENASPH") and s.sqap is None


def misalignment_brackets(surfs) -> dict[int, int]:
    """``{opening k: closing k}`` of the ``COORDBRK`` pairs (indices into ``surfs``, the file's
    ``SURF`` blocks) that the reader maps onto one element's misalignment (see the module
    docstring); every other non-identity break is read as a ``CoordinateBreak``."""
    cbs = [k for k in range(1, len(surfs) - 1)
           if surfs[k].type == "COORDBRK" and not is_identity(surfs[k])]
    out = {}
    i = 0
    while i < len(cbs) - 1:
        a, b = cbs[i], cbs[i + 1]
        sa, sb = surfs[a], surfs[b]
        va, vb = _values(sa), _values(sb)
        tilted = any(v != 0 for v in va[2:])
        inside = surfs[a + 1:b]
        ok = (_order(sa) == 0 and sa.disz == 0 and b > a + 1
              and all(math.isclose(-x, y, rel_tol=1e-9, abs_tol=1e-12) for x, y in zip(va, vb))
              and (_order(sb) != 0 or not tilted)
              and (not tilted or abs(sum(s.disz for s in inside)) <= 1e-9)
              and _air_before(surfs, a) and _air_before(surfs, b)
              and not any(s.type == "COORDBRK" or s.scbd and not scbd_identity(s)
                          for s in inside)
              and ((va[2] == 0 or va[3] == 0) and va[4] == 0
                   or all(_symmetric(s) for s in inside if not is_identity(s))))
        if ok:
            out[a] = b
            i += 2
        else:
            i += 1
    return out


def stop_plane_of_break(s, k: int, p):
    """The flat stop at the vertex of ``COORDBRK`` block ``s`` (``SURF k``) that carries the
    ``STOP``: a copy of the block as a plain ``STANDARD`` plane of thickness 0, placed before the
    break (in the frame the light arrives in), or a located refusal.

    A break with no decenter (``PARM 1``, ``PARM 2``) and no tilt about x or y (``PARM 3``,
    ``PARM 4``) turns the frame about the z axis through its vertex only: the vertex plane is the
    same before and after it, and a circle centred on the vertex is the same circle in both
    frames, so a circular stop there is unambiguous (OpticStudio's toroid sample: a 45° turn
    about z).  A break that decentres or tilts out of that plane moves it: before or after the
    break are two different stops, and the reader refuses.  A non-circular aperture on the
    break (``SQAP``, ``ELAP``, ``ELOB``, ``OBSC``, ``OBDC``, ``SPID``) would turn with the frame: refused
    too.  ``p``: the :class:`~.zmx_parse.Locator`."""
    dx, dy, tx, ty, tz = _values(s)
    if any(v != 0 for v in (dx, dy, tx, ty)):
        p.fail(s.line, f"SURF {k}: the STOP is on a COORDBRK that decentres (PARM 1, 2: {dx:g}, "
                       f"{dy:g}) or tilts about x or y (PARM 3, 4: {tx:g}, {ty:g} degrees): its "
                       f"vertex plane differs before and after the break, so where the stop "
                       f"lies is ambiguous; deeplens reads a stop on a break only when the break "
                       f"turns about z alone (put the stop on a plain surface before or after "
                       f"the break)")
    shaped = [(name, v) for name, v in (("SQAP", s.sqap), ("ELAP", s.elap), ("ELOB", s.elob),
                                        ("OBSC", s.obsc), ("OBDC", s.obdc),
                                        ("SPID", s.spid)) if v is not None]
    if shaped:
        name, v = shaped[0]
        p.fail(v[-1], f"SURF {k}: {name} on a STOP that is a COORDBRK turning the frame "
                      f"{tz:g} degrees about z: the aperture's shape or place differs before "
                      f"and after the turn; deeplens reads only a circular stop (DIAM, CLAP) "
                      f"on a break (put the stop on a plain surface before or after it)")
    return dataclasses.replace(s, type="STANDARD", curv=0.0, coni=0.0, parm={}, xdat={},
                               disz=0.0, glass=None, glass_model=None, glass_model_name=None,
                               mirror=False)


def coordinate_break(s, s_mm: float) -> CoordinateBreak:
    """The :class:`CoordinateBreak` of ``COORDBRK`` block ``s`` (lengths in file units times
    ``s_mm``)."""
    return CoordinateBreak.from_zemax({i: v for i, (v, _) in s.parm.items()}, s_mm)


def degrees_read_back_exactly(rad: float) -> float:
    """The degrees (a float within a few ulps of ``degrees(rad)``) that the reader's
    ``radians`` turns back into ``rad`` exactly when there is one (always for a tilt read from
    a file, ``radians`` of its degrees), so that a written break reads back bit for bit
    (``radians(degrees(x))`` is not always ``x``); otherwise ``degrees(rad)`` (one ulp off)."""
    d = math.degrees(rad)
    for cand in (d, *(math.nextafter(d, s * math.inf) for s in (1, -1))):
        if math.radians(cand) == rad:
            return cand
    lo = hi = d
    for _ in range(8):
        lo, hi = math.nextafter(lo, -math.inf), math.nextafter(hi, math.inf)
        for cand in (lo, hi):
            if math.radians(cand) == rad:
                return cand
    return d


def coordbrk_lines(cb: CoordinateBreak, fmt) -> list[str]:
    """The ``SURF`` body lines (without ``DISZ``) of a :class:`CoordinateBreak`; ``fmt`` formats
    a number."""
    vals = (float(cb.dx), float(cb.dy), *(degrees_read_back_exactly(float(t))
                                          for t in (cb.tilt_x, cb.tilt_y, cb.tilt_z)))
    return (["TYPE COORDBRK", "CURV 0.0"] + [f"PARM {k} {fmt(v)}" for k, v in zip(_PARMS, vals)]
            + [f"PARM 6 {cb.order}"])


def y_fields_only(sysd: dict, n_fields, p):
    """``(sysd, n_fields)`` keeping only the fields with no x component, for a lens with a fold
    or an off-axis section: deeplens' fields are angles in the y-z plane, and there an x field
    is not a y field turned about the axis (the reader otherwise combines x and y radially,
    exact only for a rotationally symmetric lens).  The dropped fields are reported."""
    if not sysd["xfln"] or not any(sysd["xfln"][0]):
        return sysd, n_fields
    ys, yline = sysd["yfln"] if sysd["yfln"] else ([0.0], 0)
    xs, xline = sysd["xfln"]
    n = len(ys) if n_fields is None else min(n_fields, len(ys))
    xs = (xs + [0.0] * n)[:n]
    keep = [i for i in range(n) if xs[i] == 0]
    if not keep:
        p.fail(xline, "XFLN: every field has an x component, and this lens has a fold or an "
                      "off-axis section (not rotationally symmetric): deeplens' fields lie in "
                      "the y-z plane")
    if len(keep) < n:
        p.note(xline, f"XFLN: field(s) {', '.join(str(i + 1) for i in range(n) if i not in keep)}"
                      f" have an x component and are not used: this lens has a fold or an "
                      f"off-axis section, and deeplens' fields lie in the y-z plane")
    out = dict(sysd)
    out["yfln"] = ([ys[i] for i in keep], yline)
    out["xfln"] = ([0.0] * len(keep), xline)
    return out, len(keep)
