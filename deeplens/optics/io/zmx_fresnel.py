"""``TYPE FRESNELS`` (OpticStudio's sequential "Fresnel" surface) in ``.zmx`` files <->
:class:`~deeplens.optics.surfaces.Fresnel`.

A plane substrate with the refractive (or reflective) power of a curved surface (OpticStudio User
Guide, *Extended Fresnel*: "The Fresnel surface described in "Fresnel" models a plane surface
which has the refractive (or reflective) power of a curved surface"; *Generalized Fresnel*: "the
overall shape of the surface substrate is independent of the local slope"; Zemax knowledge base,
*How to model a Fresnel lens in OpticStudio*: the rays are traced to the substrate, "ignoring the
presence of the grooves, and then refract[ed] ... as though the grooves truly exist").  The
records are the Even Asphere's: ``CURV`` and ``CONI`` the facet profile's curvature and conic,
``PARM 1..8`` its ``r², r⁴, ..., r¹⁶`` terms (lens units^(1−2i)), as the Extended Fresnel's
"Fresnel sag ... virtually identical to the even asphere sag expression" (and OpticStudio's own
short-course sample ``sc_fresnel1``: ``CURV``, ``PARM 1..8`` all 0).  Another ``PARM`` is refused
with its line.
"""

from __future__ import annotations

from ..errors import ZemaxFileError
from ..surfaces import Fresnel
from .surface_formats import (SurfaceFormat, refuse_unread, register_format, zmx_diam,
                              zmx_number as _f)

__all__ = ["FresnelFormat"]


def _fresnel(s, ctx) -> Fresnel:
    p, k, s_mm = ctx.p, ctx.k, ctx.s_mm
    refuse_unread(p, s.parm, f"SURF {k}: FRESNELS", "PARM 1-8: the facet profile's r², r⁴, ..., "
                  "r¹⁶ terms, as the Even Asphere's", range(1, 9))
    alpha = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i) for i in range(1, 9)]
    while alpha and alpha[-1] == 0.0:
        alpha.pop()
    return Fresnel(ctx.c, ctx.sd_build, conic=s.coni, coefficients=alpha)


@register_format
class FresnelFormat(SurfaceFormat):
    """:class:`Fresnel`: Zemax ``FRESNELS`` (``CURV``, ``CONI``, ``PARM 1..8`` the facet profile,
    an even asphere with its ``r²`` term; the substrate a plane)."""

    classes = (Fresnel,)
    zmx_types = ("FRESNELS",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _fresnel(s, ctx)

    def write_zmx(self, s, i):
        alpha = s.even_coefficients
        if len(alpha) > 8:
            raise ZemaxFileError(f"surface {i}: {len(alpha)} Fresnel terms; Zemax's FRESNELS "
                                 f"holds r²..r¹⁶ (8 terms)", surfaces=(i,))
        lines = ["TYPE FRESNELS", f"CURV {_f(s.facet.c)}", f"CONI {_f(s.facet.k)}"]
        lines += [f"PARM {j} {_f(v)}" for j, v in enumerate(alpha, start=1)]
        return lines + [zmx_diam(s.semi_diameter)]
