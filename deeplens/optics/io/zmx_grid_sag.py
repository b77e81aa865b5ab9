"""``TYPE GRID_SAG`` (OpticStudio's "Grid Sag") in ``.zmx`` files <-> :class:`GridSag`.

The records (OpticStudio User Guide, *Grid Sag*, ansyshelp.ansys.com, v242; the ZEMAX manual's
file-format list, "GDAT ix iy dx dy" and "GARR i sag dx dy dxdy ... i is the array index,
starting at 0 ... Must follow after the GDAT command"; and OpticStudio's own sample ``Grid sag
surface.zmx``):

* ``CURV``, ``CONI``, ``PARM 1..8``: the even asphere base (``r², r⁴, ..., r¹⁶``, lens
  units^(1−2i)), as OpticStudio's Even Asphere;
* ``PARM 0``: the interpolation, 0 bicubic (read), 1 linear (refused: its slopes jump at every
  grid line); ``PARM 9``/``10`` the decenter of the Zernike terms, ``XDAT 1`` their number,
  ``XDAT 2`` their normalisation radius, ``XDAT 3..`` their coefficients (terms refused);
* ``GDAT nx ny delx dely xdec ydec``: the points in x and y, their spacings (only the absolute
  values count) and the grid's decenter, in lens units.  The DAT file OpticStudio imports has
  the header ``nx ny delx dely unitflag xdec ydec`` (``unitflag`` 0 mm, 1 cm, 2 in, 3 m); once
  imported the values are the lens's and the ``.zmx`` keeps six (its sample: ``GDAT 25 25
  0.875 0.875 0 0``), read here as the header less ``unitflag``;
* ``GARR i z dz/dx dz/dy d2z/dxdy nodata``: point ``i`` (0 .. nx·ny − 1) of the grid, listed
  as the DAT file's rows: "the first data point is at the upper left corner (−x, +y) ... next
  the point to its right (+x) ... after a row the next row down, until the last point at +x,
  −y" (Zemax knowledge base, *How to use the Grid Sag surface type*, and its translations); a
  non-zero ``nodata`` makes the point's four values 0 ("only the base sag counts there").
  ``z`` is a length, ``dz/dx`` and ``dz/dy`` have no unit, ``d2z/dxdy`` is per length.  When
  every derivative is 0 OpticStudio takes the derivatives from the sag values by finite
  differences (same article); deeplens does too (:func:`~..surfaces.grid_sag.grid_slopes`) with
  a located note, the stencil OpticStudio uses not being documented.

The grid's data are in the ``.zmx`` itself (OpticStudio copies an imported DAT file's values
into ``GDAT``/``GARR``); a ``GRID_SAG`` without them is refused on its ``TYPE`` line.
"""

from __future__ import annotations

import math

import torch

from ..surfaces import GridSag
from ..surfaces.grid_sag import MAX_GRID_EVEN_TERMS, grid_slopes
from .surface_formats import (SurfaceFormat, refuse_unread, register_format, zmx_diam,
                              zmx_number as _f)
from .zmx_notes import Cause

__all__ = ["GridSagFormat"]

#: the most grid points read (OpticStudio's own limit is not documented; a damaged GDAT line
#: must not allocate without bound)
MAX_GRID_POINTS = 4_000_000



#: one warning per file for each kind of note on GRID_SAG surfaces (``{item}``: ``"SURF k"``)
_NODATA = Cause(one="{item}: {detail} GRID_SAG points are marked no-data: their sag and "
                    "derivatives are 0 (the base alone), as OpticStudio takes them",
                many="{n} GRID_SAG surfaces ({items}) have points marked no-data: their sag and "
                     "derivatives are 0 (the base alone), as OpticStudio takes them")
_SAG_ONLY_WHY = ("the slopes and cross derivatives are taken from them by finite differences "
                 "(central, one-sided at the edges), as OpticStudio does with a stencil it does "
                 "not document; between the points the surface may differ from OpticStudio's by "
                 "the differences' error")
_SAG_ONLY = Cause(one="{item}: the GRID_SAG points carry sag values only (every derivative 0): "
                      + _SAG_ONLY_WHY,
                  many="{n} GRID_SAG surfaces ({items}) carry sag values only (every derivative "
                       "0): " + _SAG_ONLY_WHY)
_BEYOND = Cause(one="{item}: the semi-diameter {detail}: rays that land outside the grid are "
                    "blocked (deeplens does not extrapolate the grid)",
                many="{n} GRID_SAG surfaces ({items}): the semi-diameter reaches beyond the grid: "
                     "rays that land outside it are blocked (deeplens does not extrapolate the "
                     "grid)")
_VERTEX_WHY = ("deeplens' paraxial data (EFL, pupils, back focus) include it, as OpticStudio's do "
               "(it computes the paraxial curvature from the vertex radius, the asphere terms "
               "and the grid), taking the interpolated grid's mean curvature at the vertex")
_VERTEX = Cause(one="{item}: the grid adds {detail}: " + _VERTEX_WHY,
                many="{n} GRID_SAG surfaces' grids add to the vertex curvature ({items}): "
                     + _VERTEX_WHY)


def _grid_sag(s, ctx) -> GridSag:
    p, k, s_mm = ctx.p, ctx.k, ctx.s_mm
    v, ln = s.parm.get(0, (0.0, 0))
    if v == 1:
        p.fail(ln, f"SURF {k}: GRID_SAG PARM 0 = 1 (linear interpolation of the grid) is not "
                   f"supported: its slopes jump at every grid line; deeplens traces the bicubic "
                   f"interpolation (PARM 0 = 0)")
    if v != 0:
        p.fail(ln, f"SURF {k}: GRID_SAG PARM 0 (the interpolation) must be 0 (bicubic) or 1 "
                   f"(linear), got {v!r}")
    refuse_unread(p, s.parm, f"SURF {k}: GRID_SAG", "PARM 0 the interpolation, PARM 1-8 the even "
                  "terms on r², ..., r¹⁶, PARM 9-10 the Zernike decenter", range(11))
    for j, (v, ln) in sorted(s.xdat.items()):
        if j >= 3 and v != 0:
            p.fail(ln, f"SURF {k}: GRID_SAG XDAT {j} is a Zernike coefficient; Zernike terms on a "
                       f"grid sag surface are not supported (deeplens reads its even asphere "
                       f"base and its grid)")
    if s.grid is None:
        p.fail(s.type_line, f"SURF {k}: GRID_SAG without its grid data (GDAT and GARR lines): "
                            f"OpticStudio keeps the values of an imported DAT file in the .zmx; "
                            f"re-save the file from OpticStudio with the grid imported")
    nx, ny, dx, dy, xd, yd, g_ln = s.grid
    if nx != int(nx) or ny != int(ny) or nx < 2 or ny < 2 or nx * ny > MAX_GRID_POINTS:
        p.fail(g_ln, f"SURF {k}: GDAT: the numbers of grid points must be integers >= 2 (at most "
                     f"{MAX_GRID_POINTS} points), got {nx:g} x {ny:g}")
    nx, ny = int(nx), int(ny)
    if dx == 0 or dy == 0:
        p.fail(g_ln, f"SURF {k}: GDAT: the grid spacings must be non-zero, got {dx:g}, {dy:g}")
    rows = s.grid_rows
    for i, row in rows.items():
        if i >= nx * ny:
            p.fail(row[-1], f"SURF {k}: GARR {i} lies beyond the {nx} x {ny} = {nx * ny} grid "
                            f"points the GDAT line ({g_ln}) declares (indices 0..{nx * ny - 1})")
    if len(rows) != nx * ny:
        missing = next(i for i in range(nx * ny) if i not in rows)
        p.fail(g_ln, f"SURF {k}: GDAT declares {nx} x {ny} = {nx * ny} grid points, the file "
                     f"has {len(rows)} GARR lines (point {missing} is missing)")
    a = torch.tensor([rows[i][:5] for i in range(nx * ny)], dtype=torch.float64)
    nodata = a[:, 4] != 0
    a[nodata, :4] = 0.0
    if bool(nodata.any()):
        p.note_each(g_ln, _NODATA, f"SURF {k}", f"{int(nodata.sum())}",
                    f"SURF {k}: {int(nodata.sum())} points")
    # file rows run from +y down, columns from -x: row j of deeplens' grid (rising y) is file
    # row ny - 1 - j
    grid = a[:, :4].reshape(ny, nx, 4).flip(0)
    z = grid[..., 0] * s_mm
    zx, zy = grid[..., 1], grid[..., 2]
    zxy = grid[..., 3] / s_mm
    hx, hy = abs(dx) * s_mm, abs(dy) * s_mm
    if not bool(grid[..., 1:].any()) and bool(z.any()):
        if min(nx, ny) < 3:
            p.fail(g_ln, f"SURF {k}: the GRID_SAG points carry sag values only (every derivative "
                         f"0) and the grid is {nx} x {ny}: finite differences need 3 points in x "
                         f"and in y")
        zx, zy, zxy = grid_slopes(z, hx, hy)
        p.note_each(g_ln, _SAG_ONLY, f"SURF {k}")
    top = max([i for i in range(1, MAX_GRID_EVEN_TERMS + 1)
               if s.parm.get(i, (0.0, 0))[0] != 0] + [0])
    coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i) for i in range(1, top + 1)]
    surf = GridSag(ctx.c, ctx.sd_build, (hx, hy), z, zx, zy, zxy, decenter=(xd * s_mm, yd * s_mm),
                   conic=s.coni, coefficients=coeffs)
    (x0, x1), (y0, y1) = surf.grid_extent()
    if ctx.sd > 0 and min(-x0, x1, -y0, y1) < ctx.sd:
        p.note_each(g_ln, _BEYOND, f"SURF {k}",
                    f"({ctx.sd:g} mm) reaches beyond the grid (x {x0:g}..{x1:g} mm, y "
                    f"{y0:g}..{y1:g} mm)", f"SURF {k}: {ctx.sd:g} mm")
    with torch.no_grad():
        dc = float(surf.paraxial_curvature()) - (ctx.c + 2.0 * (coeffs[0] if coeffs else 0.0))
    if dc != 0.0 and math.isfinite(dc):
        p.note_each(g_ln, _VERTEX, f"SURF {k}",
                    f"{dc:.6g} /mm to the vertex curvature ({ctx.c:.6g} /mm from CURV and PARM 1)",
                    f"SURF {k}: {dc:.6g} /mm")
    return surf


@register_format
class GridSagFormat(SurfaceFormat):
    """:class:`GridSag`: Zemax ``GRID_SAG`` (``PARM 0`` the interpolation, ``PARM 1..8``
    ``r² ... r¹⁶``, ``GDAT``/``GARR`` the grid; the module docstring)."""

    classes = (GridSag,)
    zmx_types = ("GRID_SAG",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _grid_sag(s, ctx)

    def write_zmx(self, s, i):
        nx, ny = s.grid_shape
        hx, hy = (float(v) for v in s.grid_spacing)
        xd, yd = (float(v) for v in s.grid_decenter)
        lines = ["TYPE GRID_SAG", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}", "PARM 0 0"]
        lines += [f"PARM {j + 1} {_f(v)}" for j, v in enumerate(s.a)]
        lines += ["PARM 9 0", "PARM 10 0", "XDAT 1 0", "XDAT 2 1",
                  f"GDAT {nx} {ny} {_f(hx)} {_f(hy)} {_f(xd)} {_f(yd)}"]
        # file order: rows from +y down, each from -x
        data = torch.stack([s.grid_z, s.grid_dz_dx, s.grid_dz_dy, s.grid_d2z_dxdy],
                           -1).detach().cpu().flip(0).reshape(nx * ny, 4).tolist()
        lines += [f"GARR {n} {_f(z)} {_f(zx)} {_f(zy)} {_f(zxy)} 0"
                  for n, (z, zx, zy, zxy) in enumerate(data)]
        lines.append(zmx_diam(s.semi_diameter))
        return lines
