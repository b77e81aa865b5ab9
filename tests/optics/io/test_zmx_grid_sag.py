"""``TYPE GRID_SAG`` (OpticStudio's Grid Sag) in ``.zmx`` files: ``GDAT``/``GARR`` read into a
:class:`~deeplens.optics.surfaces.GridSag` with the rows from the top left (−x, +y), the units
and the derivative columns right (an asymmetric bicubic polynomial on a decentred, non-square
grid comes back exactly, also from a file in inches); no-data points and sag-only files as
OpticStudio takes them; written and read again bit for bit; a lens shaped as OpticStudio's own
sample (``Grid sag surface.zmx``: a flat base plus the grid of a sphere of R 100 mm) against the
same lens with the grid replaced by the sphere, read by optiland; refusals on their line.

The files are generated here (OpticStudio's sample itself is not redistributable); what it gives
is in docs/guide/zemax.md ("Grid sag")."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from test_zmx import line_of, write

from deeplens.optics.io import lens_to_dict
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import GridSag
from helpers import read_zmx_quiet

F64 = torch.float64
RNG = np.random.default_rng(11)
A = RNG.normal(size=(4, 4)) * np.outer([1, 0.1, 0.01, 0.001], [1, 0.1, 0.01, 0.001]) * 0.05


def poly(x, y):
    """An asymmetric bicubic polynomial (mm) and its ``(z, z_x, z_y, z_xy)``."""
    P, Q = [x ** p for p in range(4)], [y ** q for q in range(4)]
    dP = [0 * x, 1 + 0 * x, 2 * x, 3 * x * x]
    dQ = [0 * y, 1 + 0 * y, 2 * y, 3 * y * y]
    terms = [(p, q) for p in range(4) for q in range(4)]
    return (sum(A[p, q] * P[p] * Q[q] for p, q in terms),
            sum(A[p, q] * dP[p] * Q[q] for p, q in terms),
            sum(A[p, q] * P[p] * dQ[q] for p, q in terms),
            sum(A[p, q] * dP[p] * dQ[q] for p, q in terms))


def sphere(c):
    def f(x, y):
        q = np.sqrt(1 - c * c * (x * x + y * y))
        return c * (x * x + y * y) / (1 + q), c * x / q, c * y / q, c ** 3 * x * y / q ** 3
    return f


def garr(f, nx, ny, hx, hy, dec=(0.0, 0.0), s=1.0, nodata=()):
    """The ``GDAT`` and ``GARR`` lines of ``f`` (mm) sampled as OpticStudio lists a grid: point
    0 at the top left (−x, +y), rows from +y down, each from −x; values in file units (``s``
    mm per unit)."""
    lines = [f"  GDAT {nx} {ny} {hx / s!r} {hy / s!r} {dec[0] / s!r} {dec[1] / s!r}"]
    n = 0
    for r in range(ny):
        y = dec[1] + (0.5 * (ny - 1) - r) * hy
        for i in range(nx):
            x = dec[0] + (i - 0.5 * (nx - 1)) * hx
            z, zx, zy, zxy = (float(v) for v in f(x, y))
            flag = 1 if n in nodata else 0
            lines.append(f"  GARR {n} {z / s!r} {zx!r} {zy!r} {zxy * s!r} {flag}")
            n += 1
    return lines


def grid_lens(grid_lines, *, unit="MM", s=1.0, parm=("PARM 0 0",), curv=0.0, grid_type=True):
    """A plano-convex singlet as OpticStudio's sample: ENPD 19 mm, 0.55 µm, the stop a GRID_SAG
    (or, ``grid_type=False``, a STANDARD of curvature ``curv``) 5 mm of N-BK7, a plane, the
    image 189.22 mm behind it; lengths in file units (``s`` mm per unit)."""
    head = ["VERS 130724 34 23203", "MODE SEQ", "NAME grid sag test",
            f"UNIT {unit} X W X CM MR CPMM", f"ENPD {19.0 / s!r}", "GCAT SCHOTT",
            "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0", "WAVM 1 0.55 1", "PWAV 1",
            "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
            "SURF 1", "  STOP", f"  TYPE {'GRID_SAG' if grid_type else 'STANDARD'}",
            f"  CURV {curv * s!r}"]
    surf1 = ([f"  {p}" for p in parm] + list(grid_lines)) if grid_type else []
    tail = [f"  DISZ {5.0 / s!r}", "  GLAS N-BK7 0 0 1.5 4.0E+1 0 0 0 0 0 0",
            f"  DIAM {10.0 / s!r} 1 0 0 1 \"\"",
            "SURF 2", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {189.2236760135 / s!r}",
            f"  DIAM {10.0 / s!r} 1 0 0 1 \"\"",
            "SURF 3", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", f"  DIAM {1.0 / s!r} 0 0 0 1 \"\""]
    return "\n".join(head + surf1 + tail) + "\n"


def inside(s, n=300, seed=0):
    (x0, x1), (y0, y1) = s.grid_extent()
    g = np.random.default_rng(seed)
    x, y = g.uniform(x0, x1, n), g.uniform(y0, y1, n)
    keep = x * x + y * y < float(s.semi_diameter) ** 2
    return x[keep], y[keep]


def test_grid_rows_are_read_from_the_top_left(tmp_path):
    """A bicubic polynomial with every term (no symmetry) on a 7 x 5 grid of unequal spacings,
    decentred: the surface read back is the polynomial (1e-12 mm), so the rows run from +y,
    the columns from −x, the decenter moves the grid by +(x_d, y_d) and the derivative columns
    are per mm."""
    lines = garr(poly, 7, 5, 3.1, 4.6, dec=(0.9, -0.6))
    lens = read_zmx_quiet(write(tmp_path, grid_lens(lines)))
    s = lens.surfaces[0]
    assert isinstance(s, GridSag) and s.grid_shape == (7, 5)
    assert s.grid_spacing.tolist() == [3.1, 4.6] and s.grid_decenter.tolist() == [0.9, -0.6]
    x, y = inside(s)
    z = s.sag(torch.tensor(x), torch.tensor(y))
    assert z.tolist() == pytest.approx(poly(x, y)[0].tolist(), abs=1e-12)
    # the top-left GARR is the node at (x_d − 3 h_x, y_d + 2 h_y)
    top_left = poly(0.9 - 3 * 3.1, -0.6 + 2 * 4.6)[0]
    assert float(s.grid_z[-1, 0]) == top_left


def test_the_file_in_inches_is_the_same_surface(tmp_path):
    """The same grid written in inches (sag, spacings and decenter / 25.4, slopes as they are,
    cross derivative × 25.4): the same surface in mm."""
    mm = read_zmx_quiet(write(tmp_path, grid_lens(garr(poly, 7, 5, 3.1, 4.6, dec=(0.9, -0.6))),
                              "mm.zmx")).surfaces[0]
    inch = read_zmx_quiet(write(tmp_path, grid_lens(
        garr(poly, 7, 5, 3.1, 4.6, dec=(0.9, -0.6), s=25.4), unit="IN", s=25.4),
        "in.zmx")).surfaces[0]
    for name in ("grid_z", "grid_dz_dx", "grid_dz_dy", "grid_d2z_dxdy", "grid_spacing",
                 "grid_decenter"):
        assert torch.allclose(getattr(inch, name), getattr(mm, name), rtol=1e-14, atol=1e-15), name
    x, y = inside(mm)
    assert inch.sag(torch.tensor(x), torch.tensor(y)).tolist() == pytest.approx(
        mm.sag(torch.tensor(x), torch.tensor(y)).tolist(), abs=1e-13)


def test_written_and_read_again_bit_for_bit(tmp_path):
    """``.zmx -> Lens -> .zmx -> Lens`` is the same lens (every grid value, the base), and the
    written ``GARR`` lines list the grid from the top left as OpticStudio does."""
    text = grid_lens(garr(poly, 7, 5, 3.1, 4.6, dec=(0.9, -0.6)),
                     parm=("PARM 0 0", "PARM 1 0.001", "PARM 2 -2e-05"), curv=0.004)
    lens = read_zmx_quiet(write(tmp_path, text))
    assert [float(v) for v in lens.surfaces[0].a] == [0.001, -2e-05]
    out = tmp_path / "back.zmx"
    write_zmx(lens, out)
    back = read_zmx_quiet(out)
    assert lens_to_dict(back) == lens_to_dict(lens)
    written = [ln.split() for ln in out.read_text().splitlines() if ln.strip().startswith("GARR")]
    given = [ln.split() for ln in text.splitlines() if ln.strip().startswith("GARR")]
    assert [float(t[2]) for t in written] == [float(t[2]) for t in given]


def test_no_data_points_are_zero_with_a_note(tmp_path):
    """A point flagged no-data (``nodata`` != 0) has sag and derivatives 0 (the base alone
    there), with a located note."""
    lines = garr(poly, 7, 5, 3.1, 4.6, nodata=(8,))
    text = grid_lens(lines)
    with pytest.warns(Warning, match=r"SURF 1: 1 GRID_SAG points are marked no-data") as rec:
        lens = read_zmx(write(tmp_path, text))
    assert any(getattr(w.message, "line", None) == line_of(text, "GDAT") for w in rec)
    s = lens.surfaces[0]
    # point 8: file row 1 (from the top), column 1 -> deeplens row 5 - 1 - 1 = 3
    assert float(s.grid_z[3, 1]) == 0.0 and float(s.grid_dz_dx[3, 1]) == 0.0
    assert float(s.grid_z[3, 2]) != 0.0


def test_sag_values_only_take_finite_difference_slopes(tmp_path):
    """Every derivative 0 (a file with sag values only): the slopes come from finite
    differences, exact for a quadratic, so the surface between the points is the quadratic;
    a located note says so."""
    def quad(x, y):
        return 0.02 * x * x - 0.01 * x * y + 0.015 * y * y + 0.1 * x, 0.0, 0.0, 0.0
    text = grid_lens(garr(quad, 9, 7, 2.5, 3.2))
    with pytest.warns(Warning, match=r"carry sag values only .* finite differences"):
        lens = read_zmx(write(tmp_path, text))
    s = lens.surfaces[0]
    x, y = inside(s, seed=3)
    assert s.sag(torch.tensor(x), torch.tensor(y)).tolist() == pytest.approx(
        quad(x, y)[0].tolist(), abs=1e-12)


def test_opticstudio_sample_shape_against_the_sphere_read_by_optiland(tmp_path):
    """OpticStudio's sample lens (a flat base plus the 25 x 25 grid, 0.875 mm, of a sphere of
    R 100 mm, N-BK7, ENPD 19, 0.55 µm) against the same file with the grid replaced by a
    STANDARD sphere, read by optiland (the independent reading; it reads no GRID_SAG): the
    sphere file reads alike in both (EFL to 1e-12); the grid lens's EFL is the sphere's times
    ``c / c_eff``, ``c_eff = c − c³h²/4 − 3c⁵h⁴/8`` (the interpolant's vertex curvature), with
    a located note; real rays land where optiland lands them through the sphere within the
    grid's slope error (measured) times the path (2 x 190 mm)."""
    pytest.importorskip("optiland")
    from optiland.fileio import load_zemax_file

    c, h = 0.01, 0.875
    text = grid_lens(garr(sphere(c), 25, 25, h, h))
    with pytest.warns(Warning, match=r"SURF 1: the grid adds 0.00999981 /mm to the vertex "
                                     r"curvature \(0 /mm from CURV and PARM 1\)"):
        lens = read_zmx(write(tmp_path, text, "grid.zmx"))
    sph = write(tmp_path, grid_lens([], curv=c, grid_type=False), "sphere.zmx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = load_zemax_file(str(sph))
        ours_sph = read_zmx(sph)
    efl_op = float(np.ravel(op.paraxial.f2())[0])
    assert float(paraxial(ours_sph).efl) == pytest.approx(efl_op, rel=1e-12)
    c_eff = c - c ** 3 * h * h / 4 - 3 * c ** 5 * h ** 4 / 8
    assert float(paraxial(lens).efl) == pytest.approx(efl_op * c / c_eff, rel=1e-10)
    px = np.array([0.0, 0.3, -0.5, 0.7, 0.0, 0.95, 0.6])
    py = np.array([0.2, 0.0, 0.5, -0.6, 0.99, 0.0, 0.7])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = op.trace_generic(Hx=0.0, Hy=0.0, Px=px, Py=py, wavelength=0.55)
    ol = np.stack([np.ravel(r.x), np.ravel(r.y)], -1)
    o = torch.tensor(np.stack([9.5 * px, 9.5 * py, -np.ones_like(px)], -1), dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0]] * len(px), dtype=F64)
    with torch.no_grad():
        out = lens.trace_to_sensor(Rays(o, d, 550.0), options=TraceOptions(clip_aperture=False))
    assert out.valid.all()
    s = lens.surfaces[0]
    xe, ye = (t.ravel() for t in np.meshgrid(np.linspace(-9.5, 9.5, 97), np.linspace(-9.5, 9.5, 97)))
    gx, gy = s.sag_grad(torch.tensor(xe), torch.tensor(ye))
    ex, ey = sphere(c)(xe, ye)[1:3]
    slope_err = max(np.abs(gx.numpy() - ex).max(), np.abs(gy.numpy() - ey).max())
    assert slope_err < 1e-7
    assert np.abs(out.o[:, :2].numpy() - ol).max() < 2 * 190.0 * slope_err + 1e-9


REFUSALS = [
    (lambda t: t.replace("PARM 0 0", "PARM 0 1"), "PARM 0 1",
     r"SURF 1: GRID_SAG PARM 0 = 1 \(linear interpolation of the grid\) is not supported"),
    (lambda t: t.replace("PARM 0 0", "PARM 0 0\n  XDAT 1 4\n  XDAT 2 10\n  XDAT 6 0.01"),
     "XDAT 6", r"SURF 1: GRID_SAG XDAT 6 is a Zernike coefficient; Zernike terms on a grid sag "
               r"surface are not supported"),
    (lambda t: "\n".join(ln for ln in t.splitlines() if "GDAT" not in ln and "GARR" not in ln)
     + "\n", "TYPE GRID_SAG", r"SURF 1: GRID_SAG without its grid data \(GDAT and GARR lines\)"),
    (lambda t: t.replace("  GARR 7 ", "  XGARR 7 "), "GDAT",
     r"SURF 1: GDAT declares 7 x 5 = 35 grid points, the file has 34 GARR lines \(point 7 is "
     r"missing\)"),
    (lambda t: t.replace("  GARR 7 ", "  GARR 35 "), "GARR 35",
     r"SURF 1: GARR 35 lies beyond the 7 x 5 = 35 grid points"),
    (lambda t: t.replace("  GARR 7 ", "  GARR 6  "), "GARR 6  ",   # the second point 6
     r"SURF 1: grid point 6 is given twice \(first on line \d+\)"),
    (lambda t: t.replace("  GDAT 7 5", "  GDAT 7.5 5"), "GDAT",
     r"SURF 1: GDAT: the numbers of grid points must be integers >= 2"),
    (lambda t: t.replace("  GARR 0 ", "  GARR 0 abc "), "GARR 0 ",
     r"GARR sag: expected a number, got 'abc'"),
]


@pytest.mark.parametrize("edit,needle,match", REFUSALS)
def test_refused_on_their_line(tmp_path, edit, needle, match):
    text = edit(grid_lens(garr(poly, 7, 5, 3.1, 4.6)))
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx_quiet(write(tmp_path, text))
    assert e.value.line == line_of(text, needle)


def test_garr_before_gdat_is_refused_on_its_line(tmp_path):
    lines = garr(poly, 7, 5, 3.1, 4.6)
    text = grid_lens(lines[1:] + lines[:1])
    with pytest.raises(ZemaxFileError, match=r"GARR on SURF 1 before its GDAT line") as e:
        read_zmx_quiet(write(tmp_path, text))
    assert e.value.line == line_of(text, "GARR 0 ")
    assert math.isfinite(e.value.line)


def test_an_aperture_beyond_the_grid_is_noted(tmp_path):
    """A semi-diameter (DIAM 10 mm) that reaches beyond the grid (x ±4.65, y ±4.6 mm): a located
    note says that rays landing outside it are blocked; and so they are."""
    text = grid_lens(garr(poly, 7, 5, 1.55, 2.3))
    with pytest.warns(Warning, match=r"SURF 1: the semi-diameter \(10 mm\) reaches beyond the "
                                     r"grid \(x -4.65..4.65 mm, y -4.6..4.6 mm\)") as rec:
        lens = read_zmx(write(tmp_path, text))
    assert any(getattr(w.message, "line", None) == line_of(text, "GDAT") for w in rec)
    o = torch.tensor([[0.0, 4.0, -1.0], [0.0, 4.8, -1.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=F64)
    with torch.no_grad():
        out = lens.trace_to_sensor(Rays(o, d, 550.0), options=TraceOptions(clip_aperture=False))
    assert out.valid.tolist() == [True, False]


def test_x_fields_on_a_grid_sag_lens_are_noted_as_not_exact(tmp_path):
    """An x field component on a lens with a grid sag (not rotationally symmetric in general):
    the note that combines x and y into a radial field says it is NOT exact, naming the
    surface."""
    text = grid_lens(garr(poly, 7, 5, 3.1, 4.6)).replace("XFLN 0", "XFLN 1")
    text = text.replace("YFLN 0", "YFLN 1")
    with pytest.warns(Warning, match=r"XFLN: x field components are combined with y into a "
                                     r"radial field, which is NOT exact for this lens \(surface "
                                     r"0, a GridSag"):
        read_zmx(write(tmp_path, text))

