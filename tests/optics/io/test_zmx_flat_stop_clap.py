"""A ``CLAP`` on a flat stop in air narrower than the stop that the system aperture (``ENPD``,
``OBNA``) defines: as in OpticStudio the pupil keeps the size the system aperture gives it and
the surface aperture vignettes its rim.  deeplens reads such a stop as a flat ``Asphere``
(``c = 0`` in air) whose semi-diameter is the paraxial stop radius and whose ``clear_radius`` is
the ``CLAP`` (as it reads a narrower ``CLAP`` on a lens-surface stop).

Checked: paraxial data equal the same file's without the ``CLAP``; the stop is the first
surface, in object space, so a ray's height on it is a straight line's (closed form), and
exactly the rays meeting it within the ``CLAP`` radius pass (both trace paths); the share of a
uniform square pupil grid that passes is ``(a / r_stop)^2`` within the lattice-count bound;
``.zmx`` and JSON round trips; a stop the rays cannot land on (inside the next lens's sag) is
refused at the ``CLAP`` line."""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.optics.io import ZemaxFileError, lens_from_dict, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture, Asphere

STOP_LINES = '  DISZ 2\n  DIAM 5 1 0 0 1 ""\n'
A = 3.5   # the CLAP's radius, mm (the ENPD 10 stop's radius is 5)
#: the system apertures: ENPD 10 (object at infinity), OBNA 0.1 (an object 50 mm before the
#: stop, which is the first surface)
APERTURES = {"enpd": dict(aperture="ENPD 10"), "obna": dict(aperture="OBNA 0.1 0", obj="50")}


def _file(kind, clap=f"CLAP 0 {A} 0", stop_gap="2"):
    text = singlet(**APERTURES[kind])
    lines = STOP_LINES.replace("DISZ 2", f"DISZ {stop_gap}")
    return text.replace(STOP_LINES, lines + (f"  {clap}\n" if clap else ""), 1)


def _first_order(lens):
    p = paraxial(lens)
    return [float(v) for v in (p.efl, p.entrance_pupil_diameter, p.entrance_pupil_z,
                               lens.stop.semi_diameter)]


def _rays_through_stop(lens, kind, xy, field_deg=0.0):
    """Rays of one object point meeting the stop plane at ``xy`` ``(M, 2)`` (mm): for
    ``enpd`` parallel rays at ``field_deg`` (in y), for ``obna`` rays from the on-axis object
    point 50 mm before the stop; each starts on its straight line 1 mm before the stop plane
    (object space: the stop is the first surface), so its height on the stop is ``xy``."""
    z_stop = float(lens.z_vertices()[lens.stop_index])
    x, y = xy[:, 0], xy[:, 1]
    if kind == "enpd":
        t = math.tan(math.radians(field_deg))
        d = torch.stack([torch.zeros_like(x), torch.full_like(x, t), torch.ones_like(x)], -1)
    else:
        d = torch.stack([x, y, torch.full_like(x, 50.0)], -1)   # from (0, 0, z_stop - 50)
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    o = torch.stack([x, y, torch.full_like(x, z_stop)], -1) - d / d[:, 2:3]   # 1 mm before
    return Rays(o, d, torch.full(x.shape, 650.0, dtype=torch.float64))


@pytest.mark.parametrize("kind", sorted(APERTURES))
def test_flat_stop_clap_keeps_the_pupil_and_vignettes_its_rim(tmp_path, kind):
    """The stop keeps the system aperture's radius (paraxial EFL, EPD, pupil position and stop
    radius equal the file's without the CLAP; ENPD 10: EPD 10) and is a flat ``Asphere`` with
    clear radius 3.5; rays meeting the stop 1e-6 relative inside the CLAP's circle pass, just
    outside it are blocked, at 16 azimuths and on a grid (an ``Aperture`` of the stop's radius
    would pass all of them), on both trace paths."""
    lens = read_zmx(write(tmp_path, _file(kind))).double()
    bare = read_zmx(write(tmp_path, _file(kind, clap=None), "bare.zmx")).double()
    stop = lens.stop
    assert type(stop) is Asphere and float(stop.c) == 0.0 and float(stop.k) == 0.0
    assert float(stop.clear_radius) == A
    assert isinstance(bare.stop, Aperture)
    assert _first_order(lens) == pytest.approx(_first_order(bare), rel=1e-12)
    r_stop = float(stop.semi_diameter)
    assert r_stop > A * 1.2
    if kind == "enpd":
        assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(10.0, rel=1e-12)
    phi = torch.arange(16, dtype=torch.float64) * (2 * math.pi / 16)
    ring = torch.stack([torch.cos(phi), torch.sin(phi)], -1)
    g = torch.linspace(-0.98 * r_stop, 0.98 * r_stop, 23, dtype=torch.float64)
    gx, gy = torch.meshgrid(g, g, indexing="ij")
    grid = torch.stack([gx.reshape(-1), gy.reshape(-1)], -1)
    grid = grid[torch.linalg.vector_norm(grid, dim=-1) <= 0.98 * r_stop]
    grid = grid[(torch.linalg.vector_norm(grid, dim=-1) - A).abs() > 1e-6]   # off the rim
    xy = torch.cat([A * (1 - 1e-6) * ring, A * (1 + 1e-6) * ring, grid])
    want = torch.linalg.vector_norm(xy, dim=-1) <= A
    assert 0 < int(want.sum()) < xy.shape[0]
    fields = (0.0, 3.0) if kind == "enpd" else (0.0,)
    with torch.no_grad():
        for f in fields:
            rays = _rays_through_stop(lens, kind, xy, f)
            assert bool(bare.trace(rays).valid.all())   # nothing else clips these rays
            for opt in (None, TraceOptions(closed_form=False)):
                assert torch.equal(lens.trace(rays, options=opt).valid, want)


def test_share_of_a_uniform_pupil_grid_is_the_area_ratio(tmp_path):
    """ENPD 10 (stop radius 5 in object space, the entrance pupil itself): of the on-axis
    ``grid:N`` pattern over the paraxial pupil, exactly the points within 3.5 mm pass, and
    their share is ``(3.5 / 5)^2`` within the lattice-count bound: a disc of radius ``R`` holds
    between ``pi (R - h/sqrt 2)^2 / h^2`` and ``pi (R + h/sqrt 2)^2 / h^2`` points of a square
    lattice of spacing ``h`` (each point's cell lies within the disc grown by half a cell's
    diagonal, and covers the disc shrunk by it)."""
    from deeplens.analysis.spot import spot_diagram
    from deeplens.optics.sampling import pupil_pattern

    lens = read_zmx(write(tmp_path, _file("enpd"))).double()
    n = 81
    with torch.no_grad():
        s = spot_diagram(lens, 0.0, 650.0, f"grid:{n}", pupil="paraxial")
    r = 5.0 * torch.linalg.vector_norm(pupil_pattern(f"grid:{n}"), dim=-1)
    assert s.n_launched == r.numel()
    assert s.n_rays == int((r <= A).sum())
    h, d = 10.0 / (n - 1), 10.0 / (n - 1) / math.sqrt(2)
    lo = (A - d) ** 2 / (5.0 + d) ** 2
    hi = (A + d) ** 2 / (5.0 - d) ** 2
    assert h < 0.2 and lo < s.n_rays / s.n_launched < hi
    assert s.n_rays / s.n_launched == pytest.approx((A / 5.0) ** 2, abs=hi - lo)


@pytest.mark.parametrize("clap,obsc", [(f"CLAP 0 {A} 0", 0.0), (f"CLAP 1.5 {A} 0", 1.5)])
def test_flat_stop_clap_round_trips(tmp_path, clap, obsc):
    """Written back by ``write_zmx`` as the same ``CLAP`` on the stop (an annular one as
    ``CLAP`` + ``OBSC``), read back equal; the JSON lens file keeps it too.  With an annular
    ``CLAP`` the pattern points between the two radii pass (rings at 5k/9 mm: none on a rim)."""
    from deeplens.analysis.spot import spot_diagram
    from deeplens.optics.sampling import pupil_pattern

    lens = read_zmx(write(tmp_path, _file("enpd", clap=clap)))
    assert float(lens.stop.obscuration) == obsc and float(lens.stop.clear_radius) == A
    write_zmx(lens, tmp_path / "back.zmx")
    text = (tmp_path / "back.zmx").read_text()
    block = text[text.index("STOP"):]
    block = block[:block.index("SURF")]
    assert f"CLAP 0 {A} 0" in block and ("OBSC 0 1.5 0" in block) == (obsc > 0)
    back = read_zmx(tmp_path / "back.zmx")
    assert lens_to_dict(back) == lens_to_dict(lens)
    d = lens_to_dict(lens)
    assert lens_to_dict(lens_from_dict(d)) == d
    r = 5.0 * torch.linalg.vector_norm(pupil_pattern("hexapolar:9"), dim=-1)
    with torch.no_grad():
        s = spot_diagram(back, 0.0, 650.0, "hexapolar:9", pupil="paraxial")
    assert s.n_rays == int(((r <= A) & (r >= obsc)).sum())


def test_a_flat_stop_clap_the_rays_cannot_land_on_is_refused(tmp_path):
    """A stop 0.3 mm inside the next lens's sag (``DISZ -0.3``): an ``Aperture`` is crossed,
    not landed on, so it loads without a CLAP; with a narrower CLAP the flat surface that
    carries it would have to be landed on behind the lens's vertex: refused at the CLAP line."""
    text = _file("enpd", stop_gap="-0.3")
    with pytest.raises(ZemaxFileError, match=f"t.zmx:{line_of(text, 'CLAP')}: CLAP on the stop "
                                             f"surface: its clear radius 3.5 mm is smaller "
                                             f"than the stop radius 5 mm"):
        read_zmx(write(tmp_path, text))
    assert isinstance(read_zmx(write(tmp_path, _file("enpd", None, "-0.3"), "b.zmx")).stop,
                      Aperture)


def test_layout_draws_the_flat_stop_as_bars_at_its_opening(tmp_path):
    """The layout figure draws the flat stop that holds the CLAP as an ``Aperture`` stop is
    drawn, two bars from the opening's rim (3.5 mm) outwards, not as a profile line across
    the pupil."""
    pytest.importorskip("matplotlib")
    from deeplens.analysis.plot import layout_figure

    lens = read_zmx(write(tmp_path, _file("enpd")))
    z = float(lens.z_vertices()[lens.stop_index])
    fig = layout_figure(lens, [0.0], n_rays=3)
    at_stop = [sorted(map(float, ln.get_ydata())) for ln in fig.axes[0].lines
               if len(ln.get_xdata()) == 2 and all(abs(float(v) - z) < 1e-12
                                                    for v in ln.get_xdata())]
    assert [v for bar in sorted(at_stop) for v in bar] == pytest.approx(
        [-1.3 * A, -A, A, 1.3 * A])
    assert not any(len(ln.get_xdata()) == 101 and min(map(float, ln.get_xdata())) == z ==
                   max(map(float, ln.get_xdata())) for ln in fig.axes[0].lines)
