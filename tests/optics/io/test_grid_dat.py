"""OpticStudio's grid sag data file (``.DAT``, :mod:`deeplens.optics.io.grid_dat`): the same grid
as a ``.DAT`` in centimetres and as ``.zmx`` records in mm gives the same surface; no-data
points, sag-only files, the user's decenter; malformed files refused with their line."""

from __future__ import annotations

import pytest
import torch
from test_zmx import write
from test_zmx_grid_sag import garr, grid_lens, inside, poly

from deeplens.optics.errors import LensFileError
from deeplens.optics.io.grid_dat import grid_sag_from_dat, read_grid_dat
from helpers import read_zmx_quiet


def dat_text(f, nx, ny, hx, hy, dec=(0.0, 0.0), unitflag=1, nodata=()):
    """``f`` (mm) as a DAT file in the unit ``unitflag`` (1: cm), from the top left."""
    s = {0: 1.0, 1: 10.0, 2: 25.4, 3: 1000.0}[unitflag]
    out = [f"{nx} {ny} {hx / s!r} {-hy / s!r} {unitflag} {dec[0] / s!r} {dec[1] / s!r}"]
    n = 0
    for r in range(ny):
        y = dec[1] + (0.5 * (ny - 1) - r) * hy
        for i in range(nx):
            x = dec[0] + (i - 0.5 * (nx - 1)) * hx
            z, zx, zy, zxy = (float(v) for v in f(x, y))
            out.append(f"{z / s!r} {zx!r} {zy!r} {zxy * s!r} {1 if n in nodata else 0}")
            n += 1
    return "\n".join(out) + "\n"


def test_dat_in_cm_is_the_zmx_grid_in_mm(tmp_path):
    """The DAT file in cm (a negative dely: only its size counts) and the .zmx records in mm of
    the same asymmetric bicubic: the same grids, the same surface."""
    zmx = read_zmx_quiet(write(tmp_path, grid_lens(garr(poly, 7, 5, 3.1, 4.6, dec=(0.9, -0.6))),
                               "g.zmx")).surfaces[0]
    p = write(tmp_path, dat_text(poly, 7, 5, 3.1, 4.6, dec=(0.9, -0.6)), "g.dat")
    s = grid_sag_from_dat(p, curvature=0.0, semi_diameter=10.0)
    for name in ("grid_z", "grid_dz_dx", "grid_dz_dy", "grid_d2z_dxdy", "grid_spacing",
                 "grid_decenter"):
        assert torch.allclose(getattr(s, name), getattr(zmx, name), rtol=1e-14, atol=1e-15), name
    x, y = inside(s)
    assert s.sag(torch.tensor(x), torch.tensor(y)).tolist() == pytest.approx(
        poly(x, y)[0].tolist(), abs=1e-12)
    moved = grid_sag_from_dat(p, 0.0, 10.0, decenter=(0.5, 0.25))
    assert moved.grid_decenter.tolist() == pytest.approx([1.4, -0.35], abs=1e-15)


def test_no_data_points_and_sag_only_files(tmp_path):
    g = read_grid_dat(write(tmp_path, dat_text(poly, 7, 5, 3.1, 4.6, unitflag=0, nodata=(0,)),
                            "n.dat"))
    assert float(g["z"][-1, 0]) == 0.0 and float(g["dz_dx"][-1, 0]) == 0.0   # top left
    assert float(g["z"][-1, 1]) != 0.0

    def quad(x, y):
        return 0.02 * x * x - 0.01 * x * y + 0.1 * y, 0.0, 0.0, 0.0
    g = read_grid_dat(write(tmp_path, dat_text(quad, 6, 5, 1.0, 1.5, unitflag=0), "q.dat"))
    X = (torch.arange(6, dtype=torch.float64) - 2.5).expand(5, 6)
    Y = ((torch.arange(5, dtype=torch.float64) - 2.0) * 1.5)[:, None].expand(5, 6)
    assert torch.allclose(g["dz_dx"], 0.04 * X - 0.01 * Y, atol=1e-12)
    assert torch.allclose(g["dz_dy"], -0.01 * X + 0.1, atol=1e-12)


@pytest.mark.parametrize("edit,line,match", [
    (lambda t: t.replace(" 1 0.0 0.0\n", " 5 0.0 0.0\n", 1), 1, r"unitflag must be 0 \(mm\)"),
    (lambda t: "7 5 0.31\n" + t.split("\n", 1)[1], 1, r"the header must be nx ny delx dely"),
    (lambda t: t.rsplit("\n", 2)[0] + "\n", 1,
     r"the header declares 7 x 5 = 35 points, the file has 34 data lines"),
    (lambda t: t.replace("\n", "\nx 0 0 0 0\n", 1), 2, r"data line: expected numbers"),
    (lambda t: t.replace("\n", "\n0 0 0\n", 1), 2, r"a data line is z dz/dx dz/dy d2z/dxdy"),
])
def test_malformed_files_are_refused_on_their_line(tmp_path, edit, line, match):
    text = edit(dat_text(poly, 7, 5, 3.1, 4.6))
    if "x 0 0 0 0" in text or "\n0 0 0\n" in text:   # a line put in: one data line too many
        text = text.rsplit("\n", 2)[0] + "\n"
    with pytest.raises(LensFileError, match=match) as e:
        read_grid_dat(write(tmp_path, text, "bad.dat"))
    assert e.value.line == line and str(e.value).startswith(str(tmp_path / "bad.dat"))
