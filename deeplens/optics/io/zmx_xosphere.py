"""``TYPE XOSPHERE`` (OpticStudio's sequential "Extended Odd Asphere") in ``.zmx`` files <->
:class:`~deeplens.optics.surfaces.ExtendedOddAsphere`.

The sag is the Standard surface's plus ``Σ_{i=1..N} A_i ρ^i``, ``ρ = r / R_n``, every power of
the normalised radius from ``ρ¹`` on, the coefficients ``A_i`` in lens units (OpticStudio User
Guide, *Extended Odd Asphere*,
<https://ansyshelp.ansys.com/public/Views/Secured/Zemax/v251/en/OpticStudio_User_Guide/OpticStudio_Help/topics/Extended_Odd_Asphere.html>:
the Odd Asphere's series, *Odd Asphere*: "both even and odd powers of r are used", in the
Extended Asphere's normalised coordinate, *Extended Asphere*: "The normalized radial coordinate ρ
is used because then the coefficients αi all have units of lens units").  The records are the
Extended Asphere's extra data (*Extended Asphere*'s table: parameter 13 "Maximum term number",
14 "Normalization radius", 15.. the coefficients; parameter ``12 + j`` is ``XDAT j``): ``XDAT 1``
the maximum term number ``N``, ``XDAT 2`` ``R_n``, ``XDAT i + 2`` ``A_i`` on ``ρ^i``.  That
``XDAT 3`` is the ``ρ¹`` term, not the Extended Asphere's ``ρ²``, is how rayoptics 0.9's reader
reads ``XOSPHERE`` (``XDAT 3..`` its ``RadialPolynomial``'s coefficients from the linear term
on) and how the users' files of ``ThibautA/optical_black_box`` lay out patents' ``A3, A4, ...``
(``XDAT 3``, ``XDAT 4`` zero, ``XDAT 5`` the printed ``A3``): 46 files, 170 surfaces, none with a
``ρ¹`` or ``ρ²`` term.

Refused, each on its line: a non-zero ``PARM`` (the surface's data are all extra data), an
``XDAT 1`` that is not an integer ``0..240`` (240: the Extended Asphere's stated maximum; the
odd one's page is not at hand), a non-zero ``XDAT`` beyond the ``N + 2`` it declares (as
``XASPHERE``), ``XDAT 2`` <= 0 with a term, and a non-zero ``ρ¹`` term (``XDAT 3``): a cone tip
on the axis, whose place in OpticStudio's paraxial data no source at hand states.  A surface
with no non-zero term is the Standard surface (read as ``STANDARD``).  Written back as
``XOSPHERE`` with its ``R_n`` and terms (a lens read and written is the same bit for bit).
"""

from __future__ import annotations

import dataclasses

from ..surfaces import ExtendedOddAsphere
from ..surfaces.extended_odd_asphere import MAX_XOSPHERE_TERMS
from .surface_formats import (FORMATS, SurfaceFormat, refuse_unread, register_format,
                              xdat_term_count, zmx_diam, zmx_number as _f)

__all__ = ["ExtendedOddAsphereFormat", "xosphere_terms"]


def xosphere_terms(s, k: int, p) -> tuple[list[tuple[float, int]], float, int]:
    """The records of ``XOSPHERE`` block ``s`` (file surface ``k``) in lens units:
    ``(terms, rn, rn_line)``, ``terms`` ``[(A_1, line), ...]`` up to the last non-zero one,
    ``rn`` ``XDAT 2``.  What is refused (module docstring) fails through ``p.fail`` at its
    line."""
    refuse_unread(p, s.parm, f"SURF {k}: XOSPHERE",
                  "the Extended Odd Asphere's data are XDAT 1 the maximum term number, XDAT 2 "
                  "the normalisation radius, XDAT 3.. the coefficients on ρ¹, ρ², ...")
    n = xdat_term_count(p, s, k, "XOSPHERE", "the maximum term number", MAX_XOSPHERE_TERMS,
                         "terms")
    rn, rn_ln = s.xdat.get(2, (0.0, s.type_line))
    terms = [s.xdat.get(i + 2, (0.0, s.type_line)) for i in range(1, n + 1)]
    while terms and terms[-1][0] == 0.0:
        terms.pop()
    if terms and terms[0][0] != 0.0:
        p.fail(terms[0][1], f"SURF {k}: XOSPHERE XDAT 3 (the ρ¹ term, a cone tip on the axis) = "
                            f"{terms[0][0]!r} is refused: no source at hand says how "
                            f"OpticStudio's paraxial data treat it")
    if terms and not rn > 0:
        p.fail(rn_ln, f"SURF {k}: XOSPHERE XDAT 2 (the normalisation radius) must be > 0, got "
                      f"{rn!r}")
    return terms, rn, rn_ln


@register_format
class ExtendedOddAsphereFormat(SurfaceFormat):
    """:class:`ExtendedOddAsphere`: Zemax ``XOSPHERE`` (OpticStudio's Extended Odd Asphere;
    ``CURV``, ``CONI``, ``XDAT 1`` ``N``, ``XDAT 2`` ``R_n``, ``XDAT 3..`` ``A_1, A_2, ...`` on
    ``ρ¹, ρ², ...``); one with no non-zero term is read as ``STANDARD``."""

    classes = (ExtendedOddAsphere,)
    zmx_types = ("XOSPHERE",)
    shape_only = True

    @staticmethod
    def _as_standard(s):
        return dataclasses.replace(s, type="STANDARD", parm={}, xdat={})

    def zmx_flat(self, s, ctx):
        terms, _, _ = xosphere_terms(s, ctx.k, ctx.p)
        return not terms and FORMATS.for_zmx_type("STANDARD").zmx_flat(self._as_standard(s), ctx)

    def read_zmx(self, s, ctx):
        terms, rn, _ = xosphere_terms(s, ctx.k, ctx.p)
        if not terms:
            return FORMATS.for_zmx_type("STANDARD").read_zmx(self._as_standard(s), ctx)
        return ExtendedOddAsphere(ctx.c, ctx.sd_build, rn * ctx.s_mm,
                                  [v * ctx.s_mm for v, _ in terms], conic=s.coni)

    def write_zmx(self, s, i):
        a = [float(v) for v in s.a]
        lines = ["TYPE XOSPHERE", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}", f"XDAT 1 {len(a)}",
                 f"XDAT 2 {_f(s.norm_radius)}"]
        lines += [f"XDAT {j + 3} {_f(v)}" for j, v in enumerate(a)]
        return lines + [zmx_diam(s.semi_diameter)]   # (SQAP, ELAP, ELOB: the writer's)
