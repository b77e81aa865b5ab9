"""``TYPE HOLOGRM1`` and ``TYPE HOLOGRM2`` (OpticStudio's "Hologram 1", "Hologram 2") in
``.zmx`` files <-> :class:`~deeplens.optics.surfaces.Hologram`.

The records (OpticStudio User Guide 2024 R2, *Hologram 1*: "described by the x, y, and z
coordinates of two different construction points, a construction wavelength, and the
diffraction order"; the order of the parameters as OpticStudio's own samples
``Transmission hologram.zmx`` and ``Reflection hologram.zmx`` write them, and as a public
CODE V to OpticStudio converter macro (ZPL) maps CODE V's ``HX1 HY1 HZ1 HX2 HY2 HZ2 HWL HOR``
onto ``PARM 1..8``):

* ``CURV``, ``CONI``: the substrate (plane, sphere or conic);
* ``PARM 1``, ``2``, ``3``: construction point 1 ``x, y, z`` (lens units, the surface's local
  frame); ``PARM 4``, ``5``, ``6``: construction point 2;
* ``PARM 7``: the construction wavelength (µm, as every Zemax wavelength; > 0: a negative one,
  OpticStudio's hologram recorded in transmission and used aluminised, is refused);
* ``PARM 8``: the diffraction order (an integer);
* ``GLAS MIRROR``: recorded and used in reflection.

Any other non-zero ``PARM`` or ``XDAT`` (OpticStudio's volume-hologram settings) is refused at
its line.  A ``HOLOGRM1`` loads with one located warning: the sense of its construction beams is
deeplens' choice by analogy with ``HOLOGRM2`` (the Zemax guide, *Holograms*), and negating
``PARM 8`` in the file flips it.
"""

from __future__ import annotations

import math

from ..errors import ZemaxFileError
from ..surfaces import Hologram
from ..surfaces.base import clear_ellipse_of, clear_rect_of, obscuration_ellipse_of
from .surface_formats import (SurfaceFormat, refuse_unread, register_format, zmx_diam,
                              zmx_number as _f)
from .zmx_notes import Cause

__all__ = ["HologramFormat"]


_SENSE = ("read as converging towards their points (order +1 at the construction wavelength "
          "sends a ray from point 1 as if from point 2), by analogy with HOLOGRM2's sample files; "
          "OpticStudio's sense for HOLOGRM1 is not documented in the sources found (Zemax guide, "
          "Holograms): negate PARM 8 to read the other sense")
#: HOLOGRM1 surfaces, whose construction beams' sense is a choice: one warning per file
_HOLOGRM1_SENSE = Cause(one="{item}: HOLOGRM1: both construction beams are " + _SENSE,
                        many="{n} HOLOGRM1 surfaces ({items}): both construction beams of each "
                             "are " + _SENSE)


def _opening_lines(s, i: int) -> list[str]:
    """``CLAP`` (a clear circle narrower than the semi-diameter) and ``OBSC`` of a hologram; a
    rectangular, elliptical or decentred opening or obscuration on one is refused (the reader
    does not take them there; no file at hand has one)."""
    if clear_rect_of(s) is not None or clear_ellipse_of(s) is not None \
            or obscuration_ellipse_of(s) is not None:
        raise ZemaxFileError(f"surface {i}: a rectangular or elliptical opening on a hologram is "
                             f"not written (a circular CLAP and OBSC are)", surfaces=(i,))
    if bool(s.clear_decenter.any()):
        raise ZemaxFileError(f"surface {i}: a decentred opening on a hologram is not written (the "
                             f"reader takes OBDC on flat, STANDARD and EVENASPH surfaces only)",
                             surfaces=(i,))
    out = []
    if math.isfinite(float(s.clear_radius)):
        out.append(f"CLAP 0 {_f(s.clear_radius)} 0")
    if float(s.obscuration) > 0:
        out.append(f"OBSC 0 {_f(s.obscuration)} 0")
    return out


def _hologram(s, ctx) -> Hologram:
    p, k, s_mm = ctx.p, ctx.k, ctx.s_mm
    name = s.type
    refuse_unread(p, s.parm, f"SURF {k}: {name}", "PARM 1-3 construction point 1, 4-6 "
                  "construction point 2, 7 the construction wavelength in µm, 8 the order; "
                  "volume-hologram settings are not supported", range(1, 9))
    refuse_unread(p, s.xdat, f"SURF {k}: {name}", "a surface hologram has no extra data; "
                  "volume-hologram settings are not supported", kind="XDAT")

    def parm(i):
        return s.parm.get(i, (0.0, s.type_line or s.line))

    wl, wl_ln = parm(7)
    if not wl > 0:
        p.fail(wl_ln, f"SURF {k}: {name} PARM 7 (the construction wavelength, µm) must be > 0, got "
                      f"{wl!r}" + (" (a negative one, a hologram recorded in transmission and "
                                   "used in reflection, is not supported)" if wl < 0 else ""))
    order, o_ln = parm(8)
    if order != int(order):
        p.fail(o_ln, f"SURF {k}: the diffraction order ({name} PARM 8) must be an integer, got "
                     f"{order!r}")
    pts = []
    for first, which in ((1, 1), (4, 2)):
        pt = [parm(first + j)[0] * s_mm for j in range(3)]
        if math.hypot(*pt) == 0.0:
            p.fail(parm(first)[1], f"SURF {k}: {name} construction point {which} (PARM "
                                   f"{first}-{first + 2}) is at the surface's vertex: the "
                                   f"construction beam's curvature is infinite there")
        pts.append(pt)
    kind = 1 if name == "HOLOGRM1" else 2
    if kind == 1:
        p.note_each(s.type_line or s.line, _HOLOGRM1_SENSE, f"SURF {k}")
    return Hologram(ctx.c, ctx.sd_build, pts[0], pts[1], wl * 1000.0, int(order), kind,
                    conic=s.coni)


@register_format
class HologramFormat(SurfaceFormat):
    """:class:`Hologram`: Zemax ``HOLOGRM1`` / ``HOLOGRM2`` (the module docstring)."""

    classes = (Hologram,)
    zmx_types = ("HOLOGRM1", "HOLOGRM2")
    shape_only = False

    def read_zmx(self, s, ctx):
        return _hologram(s, ctx)

    def write_zmx(self, s, i):
        values = [float(v) for v in s.p1] + [float(v) for v in s.p2]
        lines = [f"TYPE HOLOGRM{s.kind}", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}"]
        lines += [f"PARM {j + 1} {_f(v)}" for j, v in enumerate(values)]
        lines += [f"PARM 7 {_f(float(s.wl_c) / 1000.0)}", f"PARM 8 {s.order}",
                  zmx_diam(s.semi_diameter)]
        return lines + _opening_lines(s, i)
