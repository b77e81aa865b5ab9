"""OpticStudio's surface tilt/decenter (``SCBD`` records): a surface's own coordinate breaks,
read as :class:`~deeplens.optics.surfaces.CoordinateBreak` surfaces around it.

OpticStudio's User Guide (*Tilt/Decenter*, the surface properties' section): "A surface
tilt/decenter can be thought of as a coordinate break, followed by the surface, followed by
another coordinate break"; before the surface the frame is "decentered in X, decentered in Y,
and then tilted around X, tilted around Y, tilted around Z" (decenters in lens units, tilts in
degrees, right-handed), or in the other order ("tilted around Z, tilted around Y, tilted around
X", then decentered), exactly a ``COORDBRK``'s ``PARM 1``-``5`` with order flag ``PARM 6`` 0 or
1; the tilts/decenters "may not be placed on a coordinate break surface", where the tab holds
the coordinate return solve instead.

No OpticStudio text at hand gives the record's field layout; it is decoded from the files (the
project's corpora: a 30° prism, a spectrometer, fold mirrors, a double-pass tolerancing
sample), which show it unambiguously:

* ``SCBD 1 order 0 dx dy tx ty tz``: before the surface (``order`` 0 decenter then tilt, 1 tilt
  then decenter);
* ``SCBD 2 order status dx dy tx ty tz``: after the surface, ``status`` 0 explicit (its own
  values and order), 1 pickup (the before values and order again: 8° before and after a fold
  mirror), 2 reverse (the exact inverse of the before break: the values negated, the order
  flipped; the files write exactly that, ``SCBD 2 1 2 -a -b -c -d -e`` after ``SCBD 1 0 0 a b
  c d e``);
* ``SCBD 3 mode N`` on a ``COORDBRK`` only, commented "lock to surface N": the coordinate
  return solve (*How to restore coordinate systems using the Coordinate Return*: orientation
  only, XY or XYZ), whose result OpticStudio saves as the break's ``PARM`` and ``DISZ``
  values.

The thickness (``DISZ``) of the surface follows the after break (the thickness of the last of
the three surfaces).  Anything else (another field count, kind or status, a value that is not a
finite number, tilt/decenter on a break, on the object or a non-zero one on the image surface,
which deeplens keeps normal to its axis) is refused or noted at its line.
"""

from __future__ import annotations

import math

from ..surfaces import CoordinateBreak
from .zmx_notes import Cause

__all__ = ["parse_scbd", "scbd_breaks", "check_scbd_on_break", "scbd_identity",
           "image_scbd_note", "refuse_object_scbd"]

_WHAT = "dx dy tilt_x tilt_y tilt_z"


def parse_scbd(p, toks, ln: int, k: int, have: dict):
    """``(kind, entry)`` of the ``SCBD`` record ``toks`` (line ``ln``, ``SURF k``): kind 1 or 2
    ``(order, status, (dx, dy, tx, ty, tz), ln)`` (file units, degrees), kind 3
    ``(mode, N, ln)``; a located refusal of any other layout.  ``have``: the kinds already read
    on this surface (a second record of one kind is refused)."""
    where = f"SCBD on SURF {k}"

    def num(t, what):
        try:
            v = float(t)
        except ValueError:
            p.fail(ln, f"{where}: {what} must be a number, got {t!r}")
        if not math.isfinite(v):
            p.fail(ln, f"{where}: {what} must be finite, got {t!r}")
        return v

    def flag(t, what, allowed):
        v = num(t, what)
        if v not in allowed:
            p.fail(ln, f"{where}: {what} must be one of {', '.join(str(a) for a in allowed)} "
                       f"(the values the files show), got {t!r}")
        return int(v)

    if len(toks) < 2:
        p.fail(ln, f"{where}: no fields (expected SCBD 1|2 order status {_WHAT}, or SCBD 3 "
                   f"mode N)")
    kind = flag(toks[1], "the first field (1 before the surface, 2 after it, 3 a coordinate "
                         "return)", (1, 2, 3))
    if kind in have:
        p.fail(ln, f"{where}: a second SCBD {kind} record on this surface (first on line "
                   f"{have[kind][-1]})")
    if kind == 3:
        if len(toks) != 4:
            p.fail(ln, f"{where}: a coordinate return is 'SCBD 3 mode N' (4 fields), got "
                       f"{len(toks)} fields; this layout is not decoded")
        mode = flag(toks[2], "the coordinate return's mode", (1, 2, 3))
        n = num(toks[3], "the coordinate return's surface")
        if n != int(n) or n < 0 or n >= k:
            p.fail(ln, f"{where}: the coordinate return's surface must be an earlier surface "
                       f"number (0 to {k - 1}), got {toks[3]!r}")
        return kind, (mode, int(n), ln)
    if len(toks) != 9:
        p.fail(ln, f"{where}: a surface tilt/decenter is 'SCBD {kind} order status {_WHAT}' "
                   f"(9 fields), got {len(toks)}; this layout is not decoded")
    order = flag(toks[2], "the order (0 decenter then tilt, 1 tilt then decenter)", (0, 1))
    status = flag(toks[3], "the status (before the surface: 0)" if kind == 1 else
                  "the after-surface status (0 explicit, 1 pickup, 2 reverse)",
                  (0,) if kind == 1 else (0, 1, 2))
    vals = tuple(num(t, w) for t, w in zip(toks[4:9], _WHAT.split()))
    return kind, (order, status, vals, ln)


def _before(s):
    b = s.scbd.get(1)
    return ((0.0,) * 5, 0) if b is None else (b[2], b[0])


def _after(s):
    """``(values, order, how)`` of the break after surface ``s``."""
    a = s.scbd.get(2)
    vals, order = _before(s)
    if a is None:
        return (0.0,) * 5, 0, "none"
    a_order, status, a_vals, _ = a
    if status == 0:
        return a_vals, a_order, "explicit"
    if status == 1:
        return vals, order, "pickup"
    return tuple(-v for v in vals), 1 - order, "reverse"


def scbd_identity(s) -> bool:
    """Whether surface ``s``'s tilt/decenter before and after it are all zero (or absent)."""
    return (all(v == 0 for v in _before(s)[0]) and all(v == 0 for v in _after(s)[0]))


def _cb(vals, order, s_mm):
    return CoordinateBreak.from_zemax({1: vals[0], 2: vals[1], 3: vals[2], 4: vals[3],
                                       5: vals[4], 6: order}, s_mm)


def _fmt(vals):
    return " ".join(f"{v:g}" for v in vals)


def scbd_breaks(s, k: int, s_mm: float, p):
    """``(before, after)``: the :class:`CoordinateBreak` s (or ``None`` where all zero) that
    surface ``s`` (``SURF k``, a surface that is no ``COORDBRK``, the object or the image)
    stands between, with one located note per surface saying what was read (values in file
    units, degrees; lengths times ``s_mm``)."""
    if not s.scbd:
        return None, None
    _no_return_here(s, k, p)
    vals, order = _before(s)
    a_vals, a_order, how = _after(s)
    ln = (s.scbd.get(1) or s.scbd.get(2))[-1]
    if scbd_identity(s):
        p.note_each(ln, _ZERO, f"SURF {k}")
        return None, None
    a = s.scbd.get(2)
    stale = ""
    if how == "reverse" and tuple(a[2]) != a_vals:
        stale = (f" (the record's own numbers, {_fmt(a[2])}, are not the inverse: the "
                 f"inverse is used, as the reverse status says)")
    read = (f"dx dy tx ty tz = {_fmt(vals)}, order {order}) and one after it ({how}: "
            f"{_fmt(a_vals)}, order {a_order}){stale}")
    if stale:   # a fact of its own: said in full
        p.note(ln, _READ.one.format(item=f"SURF {k}", detail=read))
    else:
        p.note_each(ln, _READ, f"SURF {k}", read)
    before = None if all(v == 0 for v in vals) else _cb(vals, order, s_mm)
    after = None if all(v == 0 for v in a_vals) else _cb(a_vals, a_order, s_mm)
    return before, after


#: one warning per file for each kind of note (``{item}``: ``"SURF k"``)
_ZERO = Cause(one="SCBD on {item}: surface tilt/decenter data, all 0: nothing to apply",
              many="SCBD on {n} surfaces ({items}): surface tilt/decenter data, all 0: nothing "
                   "to apply")
_LAYOUT = ("the surface's thickness after both (OpticStudio's Tilt/Decenter: a coordinate break, "
           "the surface, another coordinate break); the record's field layout is decoded from "
           "files, no OpticStudio text gives it")
_READ = Cause(one="SCBD on {item}: surface tilt/decenter read as a coordinate break before the "
                  "surface ({detail}, " + _LAYOUT,
              many="SCBD on {n} surfaces ({items}): each surface tilt/decenter read as a "
                   "coordinate break before the surface and one after it, " + _LAYOUT)
_RETURN = Cause(one="SCBD on {item}: a coordinate return to {detail}: OpticStudio saves the "
                    "solve's result as the break's PARM values (mode 3: and DISZ), which "
                    "deeplens reads as written (they are not solved again)",
                many="SCBD on {n} surfaces ({items}): coordinate returns: OpticStudio saves each "
                     "solve's result as the break's PARM values (mode 3: and DISZ), which "
                     "deeplens reads as written (they are not solved again)")


def check_scbd_on_break(s, k: int, p) -> None:
    """A ``COORDBRK`` ``SURF k``: a coordinate return (``SCBD 3``) is noted (its result is the
    break's saved ``PARM``/``DISZ`` values, read as written); a tilt/decenter, which OpticStudio
    does not allow on a break, is refused."""
    for kind in (1, 2):
        e = s.scbd.get(kind)
        if e is not None:
            p.fail(e[-1], f"SCBD on SURF {k}: a surface tilt/decenter on a COORDBRK, which "
                          f"OpticStudio does not allow (User Guide, Tilt/Decenter); this file's "
                          f"meaning is not known")
    r = s.scbd.get(3)
    if r is not None:
        mode, n, ln = r
        p.note_each(ln, _RETURN, f"SURF {k}", f"SURF {n} (mode {mode})")


def _no_return_here(s, k: int, p) -> None:
    r = s.scbd.get(3)
    if r is not None:
        p.fail(r[-1], f"SCBD on SURF {k}: a coordinate return (SCBD 3) on a surface that is "
                      f"not a COORDBRK; OpticStudio has the solve on breaks only, and this "
                      f"record's meaning here is not known")


def image_scbd_note(s, k: int, p) -> None:
    """The image surface ``SURF k``: deeplens' sensor is normal to the axis at its vertex; a
    non-zero tilt/decenter before it is noted as not modelled (the after break moves nothing
    deeplens traces)."""
    if not s.scbd:
        return
    _no_return_here(s, k, p)
    vals, order = _before(s)
    ln = (s.scbd.get(1) or s.scbd.get(2))[-1]
    if all(v == 0 for v in vals):
        p.note(ln, f"SCBD on SURF {k}: the image surface's tilt/decenter before it is all 0: "
                   f"nothing to apply")
        return
    p.note(ln, f"SCBD on SURF {k}: the image surface is tilted/decentred (dx dy tx ty tz = "
               f"{_fmt(vals)}, order {order}): NOT applied, deeplens' sensor is flat and normal "
               f"to the axis at its vertex, so off-axis spots are those of that plane")


def refuse_object_scbd(s, p) -> None:
    """The object surface: a non-zero tilt/decenter is refused (deeplens' object plane is
    normal to the axis or a ``TILTSURF``); all zero is nothing."""
    if s.scbd:
        _no_return_here(s, 0, p)
    if s.scbd and not scbd_identity(s):
        ln = (s.scbd.get(1) or s.scbd.get(2))[-1]
        p.fail(ln, "SCBD on SURF 0: a tilt/decenter of the object surface is not supported "
                   "(tilt the object with a TILTSURF object, or put a COORDBRK after it)")
