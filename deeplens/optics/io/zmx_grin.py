"""``TYPE GRINSUR1`` (OpticStudio's Gradient 1) in ``.zmx`` files <->
:class:`~deeplens.optics.surfaces.gradient.GradientSurface` with its
:class:`~deeplens.optics.grin.RadialGradient` medium.

OpticStudio User Guide, "Gradient 1": the Standard surface's shape (``CURV``, ``CONI``), the
medium after it ``n = n0 + nr2 r²`` with ``PARM 1`` the maximum step ``Δt`` (lens units),
``PARM 2`` ``n0``, ``PARM 3`` ``nr2`` (per lens unit squared).  The index is the same at every
wavelength.  Read: ``PARM 4`` must be 0 (files written by OpticStudio 13 carry it; an early
PyZDDE's lens-scaling routine scales it per lens unit as a "radial linear index", but no stored
source defines the term), and the block must have no ``GLAS`` (the medium
is the parameters'); both are refused at their line otherwise.  Written: the same records,
numbers with ``repr`` (a round trip is bit for bit), no ``GLAS`` line.
"""

from __future__ import annotations

from ..grin import RadialGradient
from ..surfaces.gradient import GradientSurface
from .surface_formats import (SurfaceFormat, refuse_unread, register_format, zmx_diam,
                              zmx_number as _f)

__all__ = ["Gradient1Format"]


@register_format
class Gradient1Format(SurfaceFormat):
    """:class:`GradientSurface` with a :class:`RadialGradient`: Zemax ``GRINSUR1`` (the module
    docstring)."""

    classes = (GradientSurface,)
    zmx_types = ("GRINSUR1",)
    shape_only = False

    def read_zmx(self, s, ctx):
        p, k, s_mm = ctx.p, ctx.k, ctx.s_mm
        refuse_unread(p, s.parm, f"SURF {k}: GRINSUR1", "PARM 1 the step Delta T, 2 n0, 3 nr2: "
                      "n = n0 + nr2 r^2; no source defines further terms", range(4))
        if s.glass is not None:
            p.fail(s.glass_line or s.line,
                   f"SURF {k}: a GLAS on a GRINSUR1 surface is not read (the gradient's n0 and "
                   f"nr2, PARM 2 and 3, define the medium)")

        def parm(i, what):
            if i not in s.parm:
                p.fail(s.type_line or s.line, f"SURF {k}: GRINSUR1 needs PARM {i} ({what})")
            return s.parm[i][0]

        step = parm(1, "the step Delta T") * s_mm
        n0 = parm(2, "n0")
        nr2 = parm(3, "nr2") / (s_mm * s_mm)
        try:
            medium = RadialGradient(n0, nr2, step_mm=step)
        except ValueError as e:
            p.fail(s.parm[1][1] if not step > 0 else s.parm[2][1], f"SURF {k}: {e}")
        return GradientSurface(ctx.c, ctx.sd_build, medium, conic=s.coni)

    def write_zmx(self, s, i):
        m = s.medium
        return ["TYPE GRINSUR1", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}",
                f"PARM 1 {_f(m.step_mm)}", f"PARM 2 {_f(m.n0)}", f"PARM 3 {_f(m.nr2)}",
                zmx_diam(s.semi_diameter)]
