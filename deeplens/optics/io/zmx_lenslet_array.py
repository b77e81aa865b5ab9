"""``TYPE USERSURF US_ARRAY.DLL`` (OpticStudio's sample lenslet-array surface) in ``.zmx`` files
<-> :class:`~deeplens.optics.surfaces.LensletArray`.

``US_ARRAY.DLL`` is one of the user-defined surfaces OpticStudio ships as compiled samples with
their C source (OpticStudio User Guide, *User Defined*, ansyshelp.ansys.com, v242: a user
defined surface is a DLL "compiled and linked into OpticStudio", the sample DLLs' source files
beside them).  No OpticStudio page or source file at hand gives its parameters; they are read
as follows, from two sources that agree:

* an independent reimplementation: jbroll/acorn (SAO's ray tracer for the Binospec wavefront
  sensor, whose Zemax model uses this DLL) reads ``us_array.dll`` as ``lens-array-rect`` with
  ``PARM 1`` = ``nx``, ``PARM 2`` = ``ny``, ``PARM 3`` = ``width``, ``PARM 4`` = ``height``
  (``zmx.tcl``'s ``ZMXParmMap``) and traces each lenslet as the surface's conic ``R``, ``K``
  about a centre at a whole multiple of the width (``surfaces/lens-array-rect.cc``,
  ``LensCenter``: a lenslet on the vertex);
* OpticStudio's own numbers: the automatic semi-diameters (``DIAM`` flag 0) it traced and saved
  in two sample files with odd counts.  Its short-course sample *sc_uds1* (a 5 x 5 array of 50
  mm lenslets, ``R`` 100 mm, BK7, the stop, ``ENPD`` 250 at 0.55 µm) stores 124.4027397083 mm
  10 mm behind it and 99.5236051065 mm on the image: the ±y marginal rays at the pupil's rim (y
  = ±125 mm, the array's edge) meet the lenslet centred at ±100 mm, and reproduce both to every
  printed digit; its *sc_array1* (two 9 x 9 arrays of 8.33 mm lenslets, ``R`` ∓25 mm, B270,
  behind a paraboloid mirror, three object heights and three wavelengths) stores ten automatic
  semi-diameters, all reproduced to every printed digit (within 4e-12 mm) by the ±y marginal
  and chief rays.  A corner on the vertex (the centres at half-integer widths) misses them by up
  to 9 mm.

What is read: ``CURV`` (every lenslet's curvature), ``PARM 1``/``PARM 2`` the lenslet counts along
x/y, ``PARM 3``/``PARM 4`` the lenslet widths (the pitch) along x/y in lens units.  Refused with
their line, as in no source at hand: an even count (whether OpticStudio puts a lenslet or a corner
on the vertex then is not decided by any stored number: every file seen with an even count is
refused for other reasons), a non-zero ``PARM 0`` or ``PARM 5..12`` (0 in every file seen) and a
non-zero ``CONI`` (the lenslets' conic: acorn applies it, no OpticStudio number confirms it).
``PARM 1``/``PARM 3`` along x and ``PARM 2``/``PARM 4`` along y is acorn's order; every file seen
has equal pairs, so unequal ones load with a located warning naming that choice.  Outside the
array the surface is not defined (rays there are blocked, :mod:`..surfaces.lenslet_array`); an
opening (``DIAM``, or a ``SQAP``) reaching beyond it gets a located warning.
"""

from __future__ import annotations

from ..errors import ZemaxFileError
from ..surfaces import LensletArray
from .surface_formats import (SurfaceFormat, refuse_unread, register_format, zmx_diam,
                              zmx_number as _f)

__all__ = ["LensletArrayFormat", "US_ARRAY"]

#: the registry's name of the sample DLL's surface (the parser's ``USERSURF <DLL>``)
US_ARRAY = "USERSURF US_ARRAY.DLL"

#: PARM 1..4: what each is, in the messages
_PARMS = {1: "the number of lenslets along x", 2: "the number of lenslets along y",
          3: "the lenslet width along x", 4: "the lenslet width along y"}


def _lenslet_array(s, ctx) -> LensletArray:
    p, k, s_mm = ctx.p, ctx.k, ctx.s_mm
    where = f"SURF {k}: US_ARRAY"
    refuse_unread(p, s.parm, where, "what it means is in no source at hand: 0 in every file "
                  "seen; PARM 1-4 are the lenslet counts and widths", tuple(_PARMS))
    vals = {}
    for i, what in _PARMS.items():
        if i not in s.parm:
            p.fail(s.type_line, f"{where} without PARM {i} ({what})")
        vals[i] = s.parm[i]
    for i in (1, 2):
        n, ln = vals[i]
        if not (n == int(n) and n >= 1):
            p.fail(ln, f"{where} PARM {i} = {n:g}: {_PARMS[i]} must be a whole number >= 1")
        if int(n) % 2 == 0:
            p.fail(ln, f"{where} PARM {i} = {n:g}: an even lenslet count is not read: whether "
                       f"OpticStudio's sample DLL puts a lenslet or a corner on the vertex then "
                       f"is in no source at hand (odd counts, a lenslet on the vertex, are "
                       f"confirmed by OpticStudio's stored semi-diameters)")
    for i in (3, 4):
        w, ln = vals[i]
        if not w > 0:
            p.fail(ln, f"{where} PARM {i} = {w:g}: {_PARMS[i]} must be > 0")
    if s.coni != 0:
        p.fail(s.type_line, f"{where} with CONI {s.coni:g}: a conic on the lenslets is not read "
                            f"(whether the sample DLL applies the surface's conic to each "
                            f"lenslet is in no source at hand; every file seen has none)")
    (nx, l1), (ny, _), (wx, _), (wy, _) = (vals[i] for i in (1, 2, 3, 4))
    if nx != ny or wx != wy:
        p.note(l1, f"{where}: {nx:g} x {ny:g} lenslets of {wx:g} x {wy:g} read with PARM 1 and "
                   f"PARM 3 along x, PARM 2 and PARM 4 along y (the order of acorn's reading of "
                   f"the DLL; every file whose numbers confirm the layout has equal pairs)")
    surf = LensletArray(ctx.c, ctx.sd_build, (int(nx), int(ny)), (wx * s_mm, wy * s_mm))
    hx, hy = (s.sqap[0], s.sqap[1]) if s.sqap is not None else (ctx.sd / s_mm, ctx.sd / s_mm)
    if ctx.sd > 0 and (hx > 0.5 * nx * wx or hy > 0.5 * ny * wy):
        ln = s.sqap[2] if s.sqap is not None else s.diam_line
        p.note(ln, f"{where}: the opening ({'SQAP' if s.sqap is not None else 'DIAM'} "
                   f"{hx:g} x {hy:g}) reaches beyond the {nx:g} x {ny:g} array ({0.5 * nx * wx:g} "
                   f"x {0.5 * ny * wy:g} from the vertex): rays landing outside it are blocked "
                   f"(what the sample DLL does there is in no source at hand)")
    return surf


@register_format
class LensletArrayFormat(SurfaceFormat):
    """:class:`LensletArray`: Zemax ``TYPE USERSURF US_ARRAY.DLL`` (``PARM 1``/``2`` the lenslet
    counts, ``PARM 3``/``4`` the widths; the module docstring)."""

    classes = (LensletArray,)
    zmx_types = (US_ARRAY,)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _lenslet_array(s, ctx)

    def write_zmx(self, s, i):
        nx, ny = s.counts
        if nx % 2 == 0 or ny % 2 == 0 or float(s.k) != 0:
            what = (f"an even lenslet count ({nx} x {ny})" if nx % 2 == 0 or ny % 2 == 0
                    else f"a conic on the lenslets (k = {float(s.k):g})")
            raise ZemaxFileError(f"surface {i}: a lenslet array with {what} is not written: the "
                                 f"reader reads US_ARRAY.DLL with odd counts and no conic only "
                                 f"(the layout OpticStudio's numbers confirm)", surfaces=(i,))
        wx, wy = (float(w) for w in s.lenslet_widths)
        lines = ["TYPE USERSURF US_ARRAY.DLL", f"CURV {_f(s.c)}", "PARM 0 0", f"PARM 1 {nx}",
                 f"PARM 2 {ny}", f"PARM 3 {_f(wx)}", f"PARM 4 {_f(wy)}"]
        lines += [f"PARM {j} 0" for j in range(5, 13)]
        lines.append(zmx_diam(s.semi_diameter))
        return lines
