"""``TYPE IRREGULA`` (OpticStudio's "Irregular") in ``.zmx`` files <-> :class:`Irregular`.

The records (OpticStudio User Guide, *Irregular*, ansyshelp.ansys.com, v242, "Parameter
definitions for irregular surfaces"; OpticStudio's own sample ``Irregular surface.zmx``):

* ``CURV``, ``CONI``: the Standard surface's curvature and conic;
* ``PARM 1``, ``PARM 2``: decenter x, y (lens units); ``PARM 3``, ``PARM 4``: tilt about x, about
  y (degrees); ``PARM 5``, ``6``, ``7``: ``Zs``, ``Za``, ``Zc`` (lens units at the maximum radial
  aperture); ``PARM 8``: θ (degrees), the orientation of the astigmatism and coma;
* ``DIAM``: the semi-diameter, which is also ``r_max`` ("the maximum radial aperture of the lens,
  defined by the clear semi-diameter or semi-diameter value for the surface"): deeplens keeps the
  written value as :class:`Irregular`'s ``r_max`` (an automatic ``DIAM`` is OpticStudio's value
  when the file was saved).  Z terms with no positive ``DIAM`` are refused.

Written back with ``DIAM`` the surface's semi-diameter and the Z terms scaled to it (``Zs (sd /
r_max)⁴``, ``Za (sd / r_max)²``, ``Zc (sd / r_max)³``: the same surface).
"""

from __future__ import annotations

import math

from ..surfaces import Irregular
from .surface_formats import (SurfaceFormat, refuse_unread, register_format, zmx_diam,
                              zmx_number as _f)

__all__ = ["IrregularFormat"]

#: PARM i -> what it is (the User Guide's table)
_PARMS = {1: "decenter x", 2: "decenter y", 3: "tilt about x", 4: "tilt about y", 5: "Zs",
          6: "Za", 7: "Zc", 8: "angle"}


def _irregular(s, ctx) -> Irregular:
    p, k, s_mm = ctx.p, ctx.k, ctx.s_mm
    refuse_unread(p, s.parm, f"SURF {k}: IRREGULA", "PARM 1-2 the decenter, 3-4 the tilts, 5-7 "
                  "Zs, Za, Zc, 8 the angle", _PARMS)
    refuse_unread(p, s.xdat, f"SURF {k}: IRREGULA", "an irregular surface has no extra data",
                  kind="XDAT")

    def parm(i):
        return s.parm.get(i, (0.0, 0))[0]

    z_terms = [parm(5) * s_mm, parm(6) * s_mm, parm(7) * s_mm]
    r_max = (s.diam or 0.0) * s_mm
    if not r_max > 0:
        if any(z_terms):
            ln = next(s.parm[i][1] for i in (5, 6, 7) if parm(i) != 0)
            p.fail(ln, f"SURF {k}: IRREGULA Z terms need the surface's semi-diameter (DIAM), "
                       f"which normalises them (OpticStudio's maximum radial aperture); the "
                       f"file gives none")
        r_max = ctx.sd_build
    return Irregular(ctx.c, ctx.sd_build, r_max, conic=s.coni,
                     decenter=(parm(1) * s_mm, parm(2) * s_mm),
                     tilt=(math.radians(parm(3)), math.radians(parm(4))),
                     z_spherical=z_terms[0], z_astigmatism=z_terms[1], z_coma=z_terms[2],
                     angle=math.radians(parm(8)))


@register_format
class IrregularFormat(SurfaceFormat):
    """:class:`Irregular`: Zemax ``IRREGULA`` (the module docstring)."""

    classes = (Irregular,)
    zmx_types = ("IRREGULA",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _irregular(s, ctx)

    def write_zmx(self, s, i):
        sd, rm = float(s.semi_diameter), float(s.r_max)
        q = sd / rm
        values = [float(s.dx), float(s.dy), math.degrees(float(s.tilt_x)),
                  math.degrees(float(s.tilt_y)), float(s.zs) * q ** 4, float(s.za) * q ** 2,
                  float(s.zc) * q ** 3, math.degrees(float(s.angle))]
        lines = ["TYPE IRREGULA", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}"]
        lines += [f"PARM {j} {_f(v)}" for j, v in enumerate(values, start=1)]
        lines.append(zmx_diam(sd))
        return lines
