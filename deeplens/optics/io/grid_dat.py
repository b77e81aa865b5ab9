"""OpticStudio's grid sag data file (``.DAT``) -> the grids of a :class:`GridSag`.

A ``.zmx`` keeps an imported grid in its own ``GDAT``/``GARR`` records (:mod:`.zmx_grid_sag`);
this reads the file a user imports into OpticStudio, so that the same grid can be put on a
deeplens surface::

    from deeplens.optics.io.grid_dat import grid_sag_from_dat
    surface = grid_sag_from_dat("mirror_figure.dat", curvature=1 / 500, semi_diameter=25.0)

The format (OpticStudio User Guide, *Grid Sag*, ansyshelp.ansys.com, v242; Zemax knowledge base,
*How to use the Grid Sag surface type*): a first line ``nx ny delx dely unitflag xdec ydec``
(``unitflag`` 0 mm, 1 cm, 2 in, 3 m; only the absolute values of the spacings count; the
decenters may be omitted), then ``nx·ny`` lines ``z dz/dx dz/dy d2z/dxdy [nodata]`` from the top
left (−x, +y), row after row down; a non-zero ``nodata`` makes the point's values 0; sag and
cross derivative scale with the unit, the slopes have none; a file with every derivative 0 gets
finite-difference slopes (:func:`~..surfaces.grid_sag.grid_slopes`), as OpticStudio computes
them.  Blank lines are skipped.  Errors name the file and line.
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..errors import LensFileError
from ..surfaces import GridSag
from ..surfaces.grid_sag import grid_slopes
from .agf import decode_zemax_text

__all__ = ["read_grid_dat", "grid_sag_from_dat", "DAT_UNITS_MM"]

#: ``unitflag`` -> millimetres per unit
DAT_UNITS_MM = {0: 1.0, 1: 10.0, 2: 25.4, 3: 1000.0}
#: the most grid points read (a damaged header must not allocate without bound)
MAX_DAT_POINTS = 4_000_000


def read_grid_dat(path) -> dict:
    """The grids of an OpticStudio grid sag ``.DAT`` file, in mm (module docstring).

    Returns:
        ``{"spacing_mm": (h_x, h_y), "decenter_mm": (x_d, y_d), "z": (n_y, n_x), "dz_dx",
        "dz_dy", "d2z_dxdy"}`` (float64 tensors, rows of rising ``y``: :class:`GridSag`'s
        layout; ``d2z_dxdy`` per mm).

    Raises:
        LensFileError: the file cannot be read, or a line is not what the format expects
            (named with its line).
    """
    path = Path(path)
    text = decode_zemax_text(path, "grid sag data file")
    lines = [(i, ln.split()) for i, ln in enumerate(text.splitlines(), 1) if ln.strip()]

    def fail(line, msg):
        raise LensFileError(msg, source=path, line=line)

    def numbers(line, toks, what):
        try:
            vals = [float(t) for t in toks]
        except ValueError:
            fail(line, f"{what}: expected numbers, got {' '.join(toks)!r}")
        if not all(v == v and abs(v) != float("inf") for v in vals):
            fail(line, f"{what}: expected finite numbers, got {' '.join(toks)!r}")
        return vals

    if not lines:
        fail(None, "empty grid sag data file: expected the header nx ny delx dely unitflag "
                   "[xdec ydec]")
    hl, head = lines[0]
    if not 5 <= len(head) <= 7:
        fail(hl, f"the header must be nx ny delx dely unitflag [xdec ydec], got {len(head)} "
                 f"values")
    nx, ny, dx, dy, unit, *dec = numbers(hl, head, "header")
    if nx != int(nx) or ny != int(ny) or nx < 2 or ny < 2 or nx * ny > MAX_DAT_POINTS:
        fail(hl, f"the numbers of points nx, ny must be integers >= 2 (at most {MAX_DAT_POINTS} "
                 f"points), got {nx:g}, {ny:g}")
    if unit not in DAT_UNITS_MM:
        fail(hl, f"unitflag must be 0 (mm), 1 (cm), 2 (in) or 3 (m), got {unit:g}")
    if dx == 0 or dy == 0:
        fail(hl, f"the spacings delx, dely must be non-zero, got {dx:g}, {dy:g}")
    nx, ny, s = int(nx), int(ny), DAT_UNITS_MM[int(unit)]
    dec = dec + [0.0] * (2 - len(dec))
    rows = lines[1:]
    if len(rows) != nx * ny:
        fail(rows[-1][0] if len(rows) > nx * ny else hl,
             f"the header declares {nx} x {ny} = {nx * ny} points, the file has {len(rows)} "
             f"data lines")
    data = []
    for line, toks in rows:
        if not 4 <= len(toks) <= 5:
            fail(line, f"a data line is z dz/dx dz/dy d2z/dxdy [nodata], got {len(toks)} values")
        vals = numbers(line, toks, "data line")
        data.append(vals[:4] if len(vals) == 4 or vals[4] == 0 else [0.0] * 4)
    grid = torch.tensor(data, dtype=torch.float64).reshape(ny, nx, 4).flip(0)
    z, zx, zy, zxy = grid[..., 0] * s, grid[..., 1], grid[..., 2], grid[..., 3] / s
    hx, hy = abs(dx) * s, abs(dy) * s
    if not bool(grid[..., 1:].any()) and bool(z.any()):
        if min(nx, ny) < 3:
            fail(hl, f"the points carry sag values only and the grid is {nx} x {ny}: finite "
                     f"differences need 3 points in x and in y")
        zx, zy, zxy = grid_slopes(z, hx, hy)
    return {"spacing_mm": (hx, hy), "decenter_mm": (dec[0] * s, dec[1] * s), "z": z,
            "dz_dx": zx, "dz_dy": zy, "d2z_dxdy": zxy}


def grid_sag_from_dat(path, curvature: float, semi_diameter: float, conic: float = 0.0,
                      coefficients=(), decenter=(0.0, 0.0)) -> GridSag:
    """A :class:`GridSag` with the grid of the ``.DAT`` file ``path`` on the even asphere base
    (``curvature`` 1/mm, ``conic``, ``coefficients`` on ``r², r⁴, ...``); ``decenter`` (mm) is
    added to the file's (as OpticStudio's Grid Sag objects add theirs to their file's)."""
    g = read_grid_dat(path)
    dec = (g["decenter_mm"][0] + float(decenter[0]), g["decenter_mm"][1] + float(decenter[1]))
    return GridSag(curvature, semi_diameter, g["spacing_mm"], g["z"], g["dz_dx"], g["dz_dy"],
                   g["d2z_dxdy"], decenter=dec, conic=conic, coefficients=coefficients)
