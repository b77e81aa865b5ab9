r"""CODE V decenters and tilts (``XDE`` ... ``CDE``, ``DAR``, ``BEN``, ``REV``, ``RET``) read as
:class:`~deeplens.optics.surfaces.CoordinateBreak` surfaces, the model the ``.zmx`` reader builds
for ``COORDBRK`` surfaces (:mod:`.zmx_coordbrk`).

A surface's decenter is given by commands in its block: ``XDE x``, ``YDE y``, ``ZDE z`` (lens
units) and ``ADE α``, ``BDE β``, ``CDE γ`` (degrees), and at most one type: none (a *basic*
decenter), ``DAR`` (decenter and return), ``BEN`` (decenter and bend), ``REV`` (reverse
decenter) or ``RET Sk`` (return to the coordinate system of surface ``k``).  Conventions, each
with its source:

* **Order and frames.**  The decentred system is reached by translating the current one by
  ``(x, y, z)`` and then rotating it by ``α`` about x, ``β`` about the new y and ``γ`` about the
  newest z.  A point of the decentred frame ``p'`` is ``t + R p'`` in the frame before, with
  ``R = R_x(-α) R_y(-β) R_z(γ)`` in deeplens' right-handed rotation matrices
  (:meth:`CoordinateBreak.rotation <deeplens.optics.surfaces.CoordinateBreak.rotation>`, order
  0): CODE V's ``α`` and ``β`` are left-handed, ``γ`` right-handed.  Sources: rayoptics' CODE V
  reader (``rayoptics.elem.surface.DecenterData``, ``rayoptics.util.misc_math.euler2opt``:
  "optical design convention, i.e. alpha and beta are left-handed", intrinsic x, y, z
  rotations after the translation), and Zemax's own CODE V -> OpticStudio conversion macro
  (version 2.06.4, 2019), which writes ``ADE`` and ``BDE`` into a ``COORDBRK`` negated ("reverse
  tilt orientation") and ``XDE``, ``YDE``, ``CDE`` unchanged, with OpticStudio's order flag 0
  (decenter, then tilt x, y, z).  The CODE V documentation found (CODE V Introductory User's
  Guide, ch. 8 "Decentered Systems", <https://www.scribd.com/document/597545753/CODEV-Ch9>;
  J. Loomis' CODE V notes, "Coordinates in CODE V",
  <https://johnloomis.org/eop601/codev/ldm/cv_ldm4.html>) names the types and the right-handed
  local frames but its excerpts do not state the signs; the two readers agree on them.
  ``ZDE`` translates along the axis *before* the tilt (rayoptics; Zemax's macro puts it on the
  break's thickness, after the tilt, which differs only when ``ZDE`` and a tilt come together).
* **Basic** (no type): the surface and every following one lie in the decentred frame; the
  thickness after the surface is measured there.  -> a break (order 0) before the surface.
* **DAR**: the surface lies in the decentred frame; after it the frame returns to the one
  before the decenter, and the thickness is measured from the undecentred vertex position
  along the undecentred axis (rayoptics' ``tform_after_surf``: the inverse transform; Zemax's
  macro: the negated values with order flag 1).  -> a break, the surface, the inverse break.
* **BEN** (for fold mirrors): as basic, and after the surface the frame is rotated by ``R``
  once more, so that a flat mirror tilted by ``α`` turns the axis by ``2α`` onto the reflected
  beam (the Introductory User's Guide: "decenter and bend for creating a fold mirror with a
  single surface (normally this would require an additional dummy surface)"; rayoptics: the
  same rotation after the surface; Zemax's macro: a second break picking up the same tilts).
  -> a break, the surface, a break of the same tilts.  For a compound tilt (``ADE`` and ``BDE``
  both non-zero) the sources differ (rayoptics rotates by ``R`` again; Zemax's macro adds a
  rotation about z "to keep the meridional ray in plane"): refused.
* **REV**: the surface is not decentred; after it the frame is decentred by the inverse of the
  transform (the reverse order, the values negated: undoes a basic decenter with the same
  values; rayoptics' ``'reverse'``).  -> the surface, the inverse break.
* **RET Sk**: the surface lies in the frame surface ``k`` lies in (after ``k``'s own decenter),
  at ``k``'s vertex; the thickness before the surface is not used (Zemax's macro: the surface
  becomes a ``COORDBRK`` with a coordinate return, "Orientation, XYZ", to surface ``k``).  No
  other decenter value may be given with it.  rayoptics does not read ``RET``.
  -> a break that maps the current frame onto surface ``k``'s.

A decenter on ``SO`` (the object) is refused; on ``SI`` the image plane lies in the decentred
frame (``DAR``, ``BEN`` and ``REV`` have nothing after the image to act on: ``DAR`` and ``BEN``
decentre it as basic, ``REV`` leaves it).  Surface numbers are CODE V's: ``SO`` is 0, the first
``S`` 1.  Values are in lens units (``DIM``); tilts in degrees.
"""

from __future__ import annotations

import math

import torch

from ..surfaces import CoordinateBreak

__all__ = ["DECENTER_COMMANDS", "decenter_command", "expand_decenters", "write_break"]

_VALUES = ("XDE", "YDE", "ZDE", "ADE", "BDE", "CDE")
_TYPES = ("DAR", "BEN", "REV", "RET")
#: the commands this module reads (a surface's decenter values and its decenter type)
DECENTER_COMMANDS = frozenset(_VALUES + _TYPES)


def decenter_command(s: dict, cmd: str, args: list[str], line: int, nums, fail) -> None:
    """Record one decenter command of the ``.seq`` reader on the surface record ``s``.

    Args:
        s: the current surface record (``kind`` ``SO``, ``S`` or ``SI``); gains ``s["dec"]``.
        cmd: one of :data:`DECENTER_COMMANDS` (upper case).
        args: its arguments (one number for ``XDE`` ... ``CDE``; ``Sk`` for ``RET``; none for
            the other types).
        line: the file line (1-based).
        nums: the reader's ``nums(args, line, what, n)`` (numbers, or a located error).
        fail: the reader's ``fail(line, message)`` (raises a located ``LensFileError``).
    """
    if s["kind"] == "SO":
        fail(line, f"{cmd}: a decentred or tilted object is not supported (deeplens' object "
                   f"lies on the axis); expected decenters on S or SI surfaces")
    d = s.setdefault("dec", {"v": [0.0] * 6, "type": None, "type_line": None, "ret": None,
                             "line": line})
    if cmd in _VALUES:
        if len(args) > 1 and args[0].upper()[:1] == "S":
            fail(line, f"{cmd} {args[0]}: surface qualifiers are not supported; expected the "
                       f"command in the surface's own block")
        d["v"][_VALUES.index(cmd)] = nums(args, line, cmd, 1)[0]
        return
    if cmd == "RET":
        tok = args[0].upper() if len(args) == 1 else ""
        if not (len(tok) > 1 and tok[0] == "S" and tok[1:].isdigit()):
            fail(line, f"RET: expected 'RET Sk' (return to the coordinate system of surface "
                       f"k), got {' '.join(args)!r}")
        d["ret"] = int(tok[1:])
    elif args:
        fail(line, f"{cmd}: expected no value (a decenter type), got {' '.join(args)!r}")
    if d["type"] is not None and d["type"] != cmd:
        fail(line, f"{cmd}: this surface already has the decenter type {d['type']} (line "
                   f"{d['type_line']}); expected one of DAR, BEN, REV, RET per surface")
    d["type"], d["type_line"] = cmd, line


# --------------------------------------------------------------------------- frames
def _break(dx, dy, tx, ty, tz, order=0) -> CoordinateBreak:
    """A :class:`CoordinateBreak` (mm, radians), float64 values."""
    return CoordinateBreak(dx, dy, tx, ty, tz, order=order).double()


def _forward(v, u: float) -> CoordinateBreak:
    """The break into the decentred frame of CODE V values ``v`` (XDE..CDE, lens units and
    degrees; ``u`` mm per lens unit): order 0, ``α`` and ``β`` negated."""
    return _break(v[0] * u, v[1] * u, -math.radians(v[3]), -math.radians(v[4]),
                  math.radians(v[5]))


def _inverse(v, u: float) -> CoordinateBreak:
    """The break back from the decentred frame of ``v``: the same values negated, order 1
    (tilt z, y, x, then decenter: exactly undoes :func:`_forward`; ``ZDE`` is left to the
    thickness after it)."""
    return _break(-v[0] * u, -v[1] * u, math.radians(v[3]), math.radians(v[4]),
                  -math.radians(v[5]), order=1)


def _bend(v) -> CoordinateBreak:
    """The break after a ``BEN`` surface: the same rotation again, no decenter."""
    return _break(0.0, 0.0, -math.radians(v[3]), -math.radians(v[4]), math.radians(v[5]))


def _euler(R: torch.Tensor) -> tuple[float, float, float]:
    """``(tilt_x, tilt_y, tilt_z)`` (rad) with ``R = R_x R_y R_z`` (deeplens' matrices)."""
    r = R.tolist()
    ty = math.asin(max(-1.0, min(1.0, r[0][2])))
    if math.hypot(r[0][0], r[0][1]) < 1e-12:   # gimbal lock: put the whole x-z turn in tilt_z
        return 0.0, ty, math.atan2(r[1][0], r[1][1])
    return math.atan2(-r[1][2], r[2][2]), ty, math.atan2(-r[0][1], r[0][0])


#: how far before a decentred image plane that lies on its break the break is moved (mm): the
#: sensor must lie a positive distance after the last surface along the direction of travel
IMAGE_BREAK_MM = 1e-9


def _before_image(cb: CoordinateBreak, sign: float,
                  shift: float = 0.0) -> tuple[float, CoordinateBreak, float]:
    """The same frame as ``cb`` (order 0), moved ``shift`` (mm) along its own axis (an image
    plane's focus shift), reached from a point ``IMAGE_BREAK_MM`` before that origin along the
    axis (``sign``: the direction of travel): ``(dz, break, gap)``, ``dz`` (mm) to add to the
    distance before the break, ``gap`` (mm) from the break to the image plane.  Exact: the axes
    of the frame after the break are unchanged, its origin moved by ``shift`` along them."""
    like = torch.zeros((), dtype=torch.float64)
    R = cb.rotation(like).detach()
    gap = sign * IMAGE_BREAK_MM
    P = cb.offset(like).detach() + R[:, 2] * (shift - gap)
    out = _break(float(P[0]), float(P[1]), float(cb.tilt_x), float(cb.tilt_y),
                 float(cb.tilt_z))
    return float(P[2]), out, gap


class _Frame:
    """The running frame ``(A, b)``: a point ``p`` of the current frame, relative to the current
    vertex, is ``A p + b`` in object-space coordinates (mm, float64)."""

    def __init__(self):
        self.A = torch.eye(3, dtype=torch.float64)
        self.b = torch.zeros(3, dtype=torch.float64)

    def advance(self, t_mm: float) -> None:
        self.b = self.b + self.A[:, 2] * t_mm

    def cross(self, cb: CoordinateBreak) -> None:
        like = self.b
        self.b = self.b + self.A @ cb.offset(like).detach()
        self.A = self.A @ cb.rotation(like).detach()

    def copy(self):
        f = _Frame()
        f.A, f.b = self.A.clone(), self.b.clone()
        return f


# --------------------------------------------------------------------------- the sequence
def _cb_item(cb: CoordinateBreak, t: float, line: int) -> dict:
    """A break in the reader's surface sequence: ``t`` the thickness after it (lens units)."""
    return {"kind": "CB", "cb": cb, "t": t, "line": line, "stop": False, "cir": None,
            "glass": None}


def expand_decenters(obj: dict, body: list[dict], img: dict, u: float, fail):
    """The reader's sequence with every decenter turned into coordinate breaks.

    Args:
        obj, body, img: the object record, the records of the ``S`` surfaces, the image
            record (the reader's dicts; ``t`` the thickness after, lens units; ``dec`` from
            :func:`decenter_command`).  Not modified.
        u: mm per lens unit.
        fail: the reader's ``fail(line, message)``.

    Returns:
        ``(obj, body, img)``: copies, ``body`` with break records (``kind`` ``"CB"``, ``cb`` a
        float64 :class:`CoordinateBreak` in mm, ``t`` the thickness after it) where the
        decenters are (see the module docstring); thicknesses changed by ``ZDE`` and ``RET``.
        Unchanged when no surface is decentred.
    """
    if not any("dec" in s for s in body + [img]):
        return obj, body, img
    obj = dict(obj)
    out: list[dict] = []
    prev = obj                      # the record whose thickness leads to the current vertex
    frame = _Frame()                # the frame at the current vertex (object: the origin)
    frames = {}                     # CODE V surface number -> frame its surface lies in
    finite = abs(obj["t"]) < 1e10

    def lead(dz: float) -> None:
        """Add ``dz`` (lens units) to the thickness before the current vertex."""
        if prev is obj and not finite:
            return   # an object at infinity: a shift along the axis changes nothing
        prev["t"] += dz
        frame.advance(dz * u)

    def emit(item: dict) -> None:
        nonlocal prev
        out.append(item)
        if item["kind"] == "CB":
            frame.cross(item["cb"])
        prev = item

    def place(cb: CoordinateBreak, on_image: bool, where: int, shift: float = 0.0) -> None:
        """Emit the break ``cb`` of the current vertex; one whose image plane lies on it
        (``on_image``) moved :data:`IMAGE_BREAK_MM` back along its axis (same frame), after
        moving it ``shift`` (lens units: the image's focus shift) along that axis."""
        if not on_image:
            emit(_cb_item(cb, 0.0, where))
            return
        sign = next((math.copysign(1.0, r["t"]) for r in reversed(out + [prev])
                     if r["t"] != 0 and r is not obj), 1.0)
        dz, cb, gap = _before_image(cb, sign, shift * u)
        lead(dz / u)
        emit(_cb_item(cb, gap / u, where))

    for n, s in enumerate(body + [img], start=1):
        s = dict(s)
        if prev is not obj or finite:
            frame.advance(prev["t"] * u)
        d = s.pop("dec", None)
        image = s["kind"] == "SI"
        if d is None or (not any(d["v"]) and d["type"] != "RET"):
            frames[n] = frame.copy()
            if image:
                img = s
            else:
                out.append(s)
            prev = s
            continue
        v, typ, where = d["v"], d["type"], d["line"]
        t_after = s["t"]
        if typ == "RET":
            if any(v):
                fail(where, "RET with XDE ... CDE on the same surface: expected RET Sk alone "
                            "(the surface takes surface k's coordinate system)")
            k = d["ret"]
            if not 1 <= k < n:
                fail(d["type_line"], f"RET S{k}: expected a surface before this one (S1 .. "
                                     f"S{n - 1})")
            target = frames[k]
            # the current frame (at this vertex) onto surface k's: p_cur = A^T (A_k p_k + b_k - b)
            R = frame.A.T @ target.A
            p = frame.A.T @ (target.b - frame.b)
            lead(float(p[2]) / u)
            p = frame.A.T @ (target.b - frame.b)
            place(_break(float(p[0]), float(p[1]), *_euler(R)), image and s["t"] == 0, where)
            frames[n] = frame.copy()
            s["t"] = t_after
            if image:
                img = s
            else:
                emit(s)
            continue
        if typ == "BEN" and v[3] != 0 and v[4] != 0:
            fail(d["type_line"], "BEN with both ADE and BDE: the bend of a compound tilt is not "
                                 "defined the same way by the sources deeplens follows; expected "
                                 "a bend about one axis (ADE or BDE, with CDE)")
        if typ == "REV":
            frames[n] = frame.copy()
            if image:      # nothing after the image for the reverse decenter to act on
                img = s
                continue
            s["t"] = 0.0
            emit(s)
            emit(_cb_item(_inverse(v, u), t_after - v[2], where))
            continue
        lead(v[2])
        # a decentred image: SI's thickness is its focus shift along the image's own axis (the
        # z displacement from the nominal image surface: rayoptics' FocusRange.focus_shift, the
        # SI thickness its reader keeps); the image plane is put on a break at that place
        place(_forward(v, u), image, where, s["t"] if image else 0.0)
        frames[n] = frame.copy()
        if image:
            s["t"] = 0.0
            img = s
            continue
        if typ == "DAR":
            s["t"] = 0.0
            emit(s)
            emit(_cb_item(_inverse(v, u), t_after - v[2], where))
        elif typ == "BEN":
            s["t"] = 0.0
            emit(s)
            emit(_cb_item(_bend(v), t_after, where))
        else:
            emit(s)
    return obj, out, img


# --------------------------------------------------------------------------- writing
def write_break(cb: CoordinateBreak, i: int, after_mm: float, medium) -> list[str]:
    """The ``.seq`` lines of surface ``i``, a :class:`CoordinateBreak` with ``after_mm`` to the
    next vertex: a dummy ``S 0 t`` whose decenter :func:`expand_decenters` reads back as the
    same break (order 0 as a basic decenter, order 1 as a reverse decenter ``REV`` of the
    negated values).  Tilts are written with the degrees that the reader's ``radians`` turns
    back into the same radians when there is one, so the break reads back bit for bit.

    Raises:
        LensFileError: the break lies inside a glass (``medium`` not air): the dummy would read
            back as a glass-glass interface.
    """
    from ..errors import LensFileError
    from ..materials import Air
    from .zmx_coordbrk import degrees_read_back_exactly

    def deg(rad: float) -> float:   # the shortest degrees that read back as ``rad``
        short = float(f"{math.degrees(rad):.12g}")
        return short if math.radians(short) == rad else degrees_read_back_exactly(rad)

    if not isinstance(medium, Air):
        raise LensFileError(f"surface {i}: a coordinate break inside {medium.name!r}: CODE V's "
                            f"decenters are written on a dummy surface in air",
                            surfaces=(i,))
    dx, dy = float(cb.dx), float(cb.dy)
    tx, ty, tz = (float(t) for t in (cb.tilt_x, cb.tilt_y, cb.tilt_z))
    if cb.order == 0:
        vals, head = (dx, dy, deg(-tx), deg(-ty), deg(tz)), []
    else:
        vals, head = (-dx, -dy, deg(tx), deg(ty), deg(-tz)), ["REV"]
    mods = head + [f"{c} {v!r}" for c, v in zip(("XDE", "YDE", "ADE", "BDE", "CDE"), vals)
                   if v != 0]
    return [f"S 0.0 {after_mm!r}"] + ["  " + m for m in mods]
