r"""CODE V rectangular and elliptical apertures (``REX``, ``REY`` or ``ELX``, ``ELY``, with
``ADX``/``ADY``) read onto deeplens' openings; rotated ones (``ARO``) refused with the line.

In a surface's block::

    REX 24.79; REY 24.79; ADY -6.21      ! a 49.6 x 49.6 rectangle centred 6.21 below the vertex

* ``REX h_x``, ``REY h_y`` (lens units): the surface's rectangular clear aperture, of
  *half*-widths ``h_x``, ``h_y``: rays that meet the surface at local ``|x - d_x| > h_x`` or
  ``|y - d_y| > h_y`` are blocked.  ``ADX d_x``, ``ADY d_y`` (lens units): the aperture's centre
  in the surface's local x-y plane.  Both are needed (a rectangle with one half-width has no
  reading).  Sources: rayoptics' CODE V reader (``rayoptics/codev/cmdproc.py``,
  ``aperture_data``: ``REX`` -> ``Rectangular.x_half_width``, ``REY`` -> ``y_half_width``,
  ``ELX``/``ELY`` -> ``Elliptical``; ``aperture_offset``: ``ADX``/``ADY`` -> the last
  aperture's ``x_offset``/``y_offset``, ``ARO`` -> its ``rotation``; ``Rectangular.point_inside``
  tests ``|x - x_offset| <= x_half_width`` after ``Aperture.tform`` subtracts the offset: the
  offset is the centre), and a real file: rayoptics' ``threemir.seq`` gives its primary
  ``REX 75.7; REY 78.5; ADY 99.6``; the beam that its stop passes (95 mm tall for the ±2° fields)
  passes that rectangle read so, is cut by one of full width 78.5 and misses one centred at
  ``-99.6`` entirely (``tests/optics/io/test_codev_apertures.py``).
* ``ELX a``, ``ELY b`` (lens units): an elliptical clear aperture of half-axes ``a`` along the
  local x axis and ``b`` along y, centred at ``(d_x, d_y)`` as the rectangle: rays that meet the
  surface at ``((x - d_x) / a)^2 + ((y - d_y) / b)^2 > 1`` are blocked.  Source: the same
  reader (``aperture_data``: the command's first letter picks the class, ``E`` ->
  ``Elliptical``, and its third the field, ``X`` -> ``x_half_width``, ``Y`` -> ``y_half_width``;
  ``rayoptics/codev/tla_mapping.csv`` routes ``ELX``/``ELY`` there with the qualifiers ``CLR``,
  ``EDG``, ``OBS``, ``HOL``; ``Elliptical.dimension`` is ``(x_half_width, y_half_width)``); its
  ``Elliptical`` has no ``point_inside`` of its own, so rayoptics does not clip by it and the
  inside test is the ellipse's definition.  On a lens or mirror surface it is the surface's
  clear ellipse (:func:`~deeplens.optics.surfaces.base.set_clear_ellipse`, the model of Zemax's
  ``ELAP``), on a flat surface in air an :class:`~deeplens.optics.surfaces.Aperture` of shape
  ``"ellipse"``; everything refused for a rectangle is refused for an ellipse, and a rectangle
  and an ellipse on one surface too.
* On a lens or mirror surface (an :class:`~deeplens.optics.surfaces.Asphere`) the rectangle is
  the surface's ``clear_rect`` (:func:`~deeplens.optics.surfaces.base.set_clear_rect`, the model
  of Zemax's ``SQAP``) and ``ADX``/``ADY`` its ``clear_decenter`` (Zemax's ``OBDC``): the
  semi-diameter, the disc about the vertex the surface is defined on, encloses the decentred
  rectangle (``|d| +`` its half-diagonal).  On a flat surface in air it is an
  :class:`~deeplens.optics.surfaces.Aperture` of shape ``"rect"`` (decentred: not on the stop,
  whose entrance pupil deeplens centres on the axis).
* ``EDG`` (a mechanical edge) is read and not used, as for ``CIR EDG``; ``CLR`` is the clear
  aperture.  Refused, each with its line: ``OBS``/``HOL`` rectangles and ellipses (deeplens'
  obscurations read from CODE V are circles), ``ARO`` other
  than 0 (deeplens' rectangles are aligned with the local axes, and rayoptics stores ``ARO``
  without applying it, so no source gives its sign), a rectangle together with a ``CIR`` clear
  aperture on one surface, ``ADX``/``ADY`` without a rectangle, a rectangle on ``SO`` or ``SI``,
  and a decentred one on a surface type other than an asphere.
"""

from __future__ import annotations

import math

import torch

__all__ = ["APERTURE_COMMANDS", "aperture_command", "apply_aperture", "write_aperture"]

_SIZES = ("REX", "REY", "ELX", "ELY")
_OFFSETS = ("ADX", "ADY", "ARO")
#: the commands this module reads
APERTURE_COMMANDS = frozenset(_SIZES + _OFFSETS)


def aperture_command(s: dict, cmd: str, args: list[str], line: int, nums, fail) -> None:
    """Record one aperture command of the ``.seq`` reader on the surface record ``s``.

    Args:
        s: the current surface record; gains ``s["rect"]`` (``{"REX": (v, line), ...}``; the
            ``ELX``/``ELY`` of an ellipse are kept there too).
        cmd: one of :data:`APERTURE_COMMANDS` (upper case).
        args: its arguments: qualifiers (``CLR``, ``EDG``, ``OBS``, ``HOL``, an aperture label
            ``L'name'``), then one number (lens units; ``ARO`` degrees).
        line: the file line (1-based).
        nums: the reader's ``nums(args, line, what, n)``.
        fail: the reader's ``fail(line, message)``.
    """
    quals = [a.upper() for a in args[:-1] if not a.upper().startswith("L")]   # labels: not used
    v = nums(args[-1:], line, cmd, 1)[0]
    bad = [q for q in quals if q not in ("CLR", "EDG", "OBS", "HOL")]
    if bad or len(quals) > 1:
        fail(line, f"{cmd} {' '.join(args)}: expected at most one of CLR, EDG, OBS, HOL before "
                   f"the value (surface qualifiers such as S3 are not supported)")
    if quals == ["EDG"]:
        return   # a mechanical edge: read and not used (as CIR EDG)
    if quals and quals[0] in ("OBS", "HOL"):
        fail(line, f"{cmd} {quals[0]}: a rectangular or elliptical obscuration or hole is not "
                   f"supported (deeplens' obscurations are central circles: CIR OBS)")
    if s["kind"] != "S":
        what = "an elliptical" if cmd in ("ELX", "ELY") else "a rectangular"
        fail(line, f"{cmd}: {what} aperture on {s['kind']} is not supported; expected it "
                   f"on an S surface")
    if cmd == "ARO":
        if v != 0:
            fail(line, f"ARO {v!r}: a rotated aperture is not supported (deeplens' rectangles "
                       f"are aligned with the surface's local x and y; rayoptics stores ARO "
                       f"without applying it, so no source gives its sign); expected ARO 0")
        return
    if cmd in ("REX", "REY", "ELX", "ELY") and not v > 0:
        fail(line, f"{cmd}: expected a half-width > 0, got {args[-1]}")
    s.setdefault("rect", {})[cmd] = (v, line)


def apply_aperture(rec: dict, surf, u: float, flat_air: bool, fail):
    """The surface ``surf`` built from the record ``rec`` with its rectangle or ellipse, if it
    has one (module docstring): the same surface (a lens or mirror surface) or a rectangular
    or elliptical :class:`Aperture` (a flat surface in air).  Lengths: ``u`` mm per lens
    unit."""
    from ..surfaces import Aperture, Asphere
    from ..surfaces.base import set_clear_ellipse, set_clear_rect, takes_clear_rect

    r = rec.get("rect")
    if not r:
        return surf
    first = min(ln for _, ln in r.values())
    ellipse = "ELX" in r or "ELY" in r
    if ellipse and ("REX" in r or "REY" in r):
        ln = max(r[k][1] for k in ("REX", "REY", "ELX", "ELY") if k in r)
        fail(ln, "REX/REY and ELX/ELY on one surface: expected one clear aperture (a "
                 "rectangle or an ellipse)")
    sizes, shape = (("ELX", "ELY"), "elliptical") if ellipse else (("REX", "REY"),
                                                                   "rectangular")
    for k in ("ADX", "ADY"):
        if k in r and not any(c in r for c in ("REX", "REY", "ELX", "ELY")):
            fail(r[k][1], f"{k}: an aperture decenter with no rectangle (REX, REY) or ellipse "
                          f"(ELX, ELY) on this surface; a decentred circular aperture is not "
                          f"supported")
    article = "an" if ellipse else "a"
    for k in sizes:
        if k not in r:
            fail(first, f"{article} {shape} aperture needs both {sizes[0]} and {sizes[1]} "
                        f"(half-widths); {k} is missing")
    if rec["cir"] is not None:
        fail(rec["cir"][1], f"CIR and {sizes[0]}/{sizes[1]} on one surface: expected one clear "
                            f"aperture (a circle, a rectangle or an ellipse)")
    hx, hy = r[sizes[0]][0] * u, r[sizes[1]][0] * u
    dec = (r["ADX"][0] * u if "ADX" in r else 0.0, r["ADY"][0] * u if "ADY" in r else 0.0)
    where = r["ADX"][1] if "ADX" in r else (r["ADY"][1] if "ADY" in r else first)
    if flat_air:
        if rec["stop"] and any(dec):
            fail(where, "ADX/ADY on the stop: a decentred aperture stop is not supported "
                        "(deeplens' entrance pupil is centred on the axis)")
        return Aperture(shape="ellipse" if ellipse else "rect", half_width_x=hx,
                        half_width_y=hy, decenter=dec)
    if not takes_clear_rect(surf) or (any(dec) and type(surf) is not Asphere):
        fail(where, f"a {'decentred ' if any(dec) else ''}{shape} aperture on a "
                    f"{type(surf).__name__} surface is not supported (deeplens has them on "
                    f"flat surfaces in air and on lens and mirror surfaces, decentred on "
                    f"spheres, conics and aspheres)")
    try:
        (set_clear_ellipse if ellipse else set_clear_rect)(surf, (hx, hy))
    except ValueError as e:
        fail(first, f"{sizes[0]}/{sizes[1]}: {e}")
    if any(dec):
        outer = max(hx, hy) if ellipse else math.hypot(hx, hy)
        with torch.no_grad():
            surf.clear_decenter.copy_(torch.tensor(dec, dtype=torch.float64))
            surf.semi_diameter.fill_(math.hypot(*dec) + outer)
    return surf


def write_aperture(s, i: int | None = None) -> list[str] | None:
    """The ``REX``/``REY`` or ``ELX``/``ELY`` (and ``ADX``/``ADY``) lines of surface ``s``'s
    rectangular or elliptical opening, or ``None`` when it has none (a rectangular or
    elliptical :class:`Aperture`, or a clear rectangle or ellipse whose clear circle is its
    circumscribed one, as :func:`apply_aperture` builds them).  An elliptical obscuration has
    no CODE V record here (the reader refuses ``ELX OBS``), nor a spider: ``LensFileError``."""
    from ..errors import LensFileError
    from ..surfaces import Aperture
    from ..surfaces.base import (clear_ellipse_of, clear_rect_of, obscuration_ellipse_of,
                                 obscuration_spider_of)

    if obscuration_ellipse_of(s) is not None:
        raise LensFileError(f"surface {i}: an elliptical obscuration has no CODE V record here "
                            f"(deeplens reads CIR OBS circles only)",
                            surfaces=() if i is None else (i,))
    if (isinstance(s, Aperture) and s.spider_of() is not None) or obscuration_spider_of(s):
        raise LensFileError(f"surface {i}: a spider obscuration has no CODE V record here "
                            f"(deeplens reads CIR OBS circles only)",
                            surfaces=() if i is None else (i,))
    names = ("REX", "REY")
    if isinstance(s, Aperture):
        if s.shape == "circle":
            return None
        names = ("ELX", "ELY") if s.shape == "ellipse" else names
        (hx, hy), dec = (float(v) for v in s.half_widths), [float(v) for v in s.decenter]
    else:
        rect, ell = clear_rect_of(s), clear_ellipse_of(s)
        if rect is None and ell is None:
            return None
        hx, hy = rect if ell is None else ell
        names = names if ell is None else ("ELX", "ELY")
        dec = [float(v) for v in getattr(s, "clear_decenter", torch.zeros(2))]
    out = [f"{names[0]} {hx!r}", f"{names[1]} {hy!r}"]
    out += [f"{c} {v!r}" for c, v in zip(("ADX", "ADY"), dec) if v != 0]
    return out
