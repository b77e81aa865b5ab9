"""Spider obscurations: the :class:`~deeplens.optics.openings.Spider` opening, an
:class:`Aperture` with one, Zemax's ``SPID width n`` read, traced and written back.

Hand geometry: arm ``j`` runs from the centre along ``u_j = (cos t_j, sin t_j)``, ``t_j =
angle + 2 pi j / n``; a point ``q`` is on it when ``q . u_j > 0`` and its distance from the
arm's centre line ``|q x u_j|`` is below ``w / 2``.  Test points sit ``EPS`` = 1e-6 mm inside
or outside an arm's edge, at radii where no other arm is near: the verdicts are far from
float64's rounding of a hit point (~1e-15 relative), whatever the CPU's instruction set.
"""

from __future__ import annotations

import math

import pytest
import torch
from test_elliptical_apertures import _dummy_before_stop, _line, _mirror, _passes
from test_zmx import singlet, write

from deeplens.optics.errors import LensFileError, ZemaxFileError
from deeplens.optics.io import lens_to_dict, read_zmx, write_zmx
from deeplens.optics.io.codev import write_seq
from deeplens.optics.io.lensfile import lens_from_dict
from deeplens.optics.openings import Circle, Spider
from deeplens.optics.options import TraceOptions
from deeplens.optics.surfaces import Aperture, Asphere
from deeplens.optics.surfaces.base import obscuration_spider_of

EPS = 1e-6


def _edge_points(w, n, angle, radii, eps):
    """Points at distance ``radii`` along each arm, ``w / 2 + eps`` from its centre line on
    both sides (``eps < 0``: inside the arm)."""
    out = []
    for j in range(n):
        t = angle + 2.0 * math.pi * j / n
        u, v = (math.cos(t), math.sin(t)), (-math.sin(t), math.cos(t))
        for r in radii:
            for side in (1.0, -1.0):
                off = side * (w / 2 + eps)
                out.append((r * u[0] + off * v[0], r * u[1] + off * v[1]))
    return out


def _on_arm(q, w, n, angle):
    """Hand geometry: whether point ``q`` lies strictly inside one of the arms."""
    for j in range(n):
        t = angle + 2.0 * math.pi * j / n
        along = q[0] * math.cos(t) + q[1] * math.sin(t)
        across = q[1] * math.cos(t) - q[0] * math.sin(t)
        if along > 0 and abs(across) < w / 2:
            return True
    return False


def _xy(points):
    return (torch.tensor([p[0] for p in points], dtype=torch.float64),
            torch.tensor([p[1] for p in points], dtype=torch.float64))


# --------------------------------------------------------------------------- the opening
@pytest.mark.parametrize("n, angle", [(1, 0.0), (2, 0.3), (3, 0.0), (3, math.pi / 6),
                                      (4, 0.0), (6, -1.0)])
def test_spider_arms_by_hand_geometry(n, angle):
    """Points 1e-6 mm inside either edge of every arm at radii 1.5, 3 and 9 mm are in the
    spider, 1e-6 mm outside are not; a point opposite an arm (on the far side of the centre,
    where no arm runs for odd n) is not; and a 50 x 50 grid agrees with the hand geometry."""
    w = 0.8
    radii = (1.5, 3.0, 9.0)
    sp = Spider(w, n, angle)
    inside = _edge_points(w, n, angle, radii, -EPS)
    outside = _edge_points(w, n, angle, radii, EPS)
    assert sp.contains(*_xy(inside)).all() and not sp.contains(*_xy(outside)).any()
    assert (~sp.outside(*_xy(inside))).all() and sp.outside(*_xy(outside)).all()
    if n % 2:   # opposite each arm: no arm there
        back = [(-3.0 * math.cos(angle + 2 * math.pi * j / n),
                 -3.0 * math.sin(angle + 2 * math.pi * j / n)) for j in range(n)]
        assert not sp.contains(*_xy(back)).any()
    g = torch.linspace(-7.3, 7.1, 50, dtype=torch.float64)
    gx, gy = torch.meshgrid(g, g, indexing="ij")
    got = sp.contains(gx.flatten(), gy.flatten()).tolist()
    want = [_on_arm((float(a), float(b)), w, n, angle) for a, b in zip(gx.flatten(), gy.flatten())]
    assert got == want and 0 < sum(want) < len(want)


def test_spider_blocked_fraction_of_an_annulus_is_the_closed_form():
    """Uniform points (fixed seed, N = 2e6) in an annulus ``r_o < ρ < R`` less a 3-arm spider
    of width ``w``: the blocked fraction is ``n (A(R) - A(r_o)) / (π (R² - r_o²))``, ``A(ρ) =
    h sqrt(ρ² - h²) + ρ² asin(h / ρ)`` (one half-strip of half-width ``h = w / 2`` within a
    disc of radius ρ), exact when the arms do not meet in the annulus (``r_o >= h / sin(π/n)``).
    Tolerance: 5 binomial standard deviations."""
    R, r_o, w, n = 10.0, 2.0, 1.2, 3
    h = w / 2
    assert r_o >= h / math.sin(math.pi / n)

    def A(rho):
        return h * math.sqrt(rho * rho - h * h) + rho * rho * math.asin(h / rho)

    want = n * (A(R) - A(r_o)) / (math.pi * (R * R - r_o * r_o))
    g = torch.Generator().manual_seed(7)
    N = 2_000_000
    rho = torch.sqrt(r_o ** 2 + (R ** 2 - r_o ** 2) * torch.rand(N, generator=g,
                                                                 dtype=torch.float64))
    phi = 2 * math.pi * torch.rand(N, generator=g, dtype=torch.float64)
    x, y = rho * torch.cos(phi), rho * torch.sin(phi)
    opening = Circle(R) - Circle(r_o) - Spider(w, n)
    got = 1.0 - float(opening.contains(x, y).double().mean())
    sigma = math.sqrt(want * (1 - want) / N)
    assert abs(got - want) < 5 * sigma, (got, want, sigma)


def test_spider_refuses_bad_values():
    for args, match in (((0.0, 3), "width"), ((1.0, 0), "integer >= 1"),
                        ((1.0, 2.5), "integer >= 1"), ((math.inf, 3), "width")):
        with pytest.raises(ValueError, match=match):
            Spider(*args)
    with pytest.raises(ValueError, match="without another obscuration"):
        Aperture(5.0, obscuration=1.0, spider=(0.5, 3, 0.0))


# --------------------------------------------------------------------------- .zmx
def test_spid_on_a_flat_surface_in_air_blocks_the_arms(tmp_path):
    """``SPID 0.8 3`` on a flat surface in air 1 mm before the stop: an :class:`Aperture`
    whose opening is its circle less a 3-arm spider of width 0.8 mm, the first arm along +x.
    Rays parallel to the axis 1e-6 mm inside either edge of each arm at radii 1.5, 3 and 4.5
    mm are blocked, 1e-6 mm outside pass; the JSON round trip is exact and the .zmx one writes
    SPID alone (no CLAP: one aperture type per surface) and keeps every verdict."""
    w, n, radii = 0.8, 3, (1.5, 3.0, 4.5)
    lens = read_zmx(_dummy_before_stop(tmp_path, [f"SPID {w} {n} 0"]))
    ap = lens.surfaces[0]
    assert isinstance(ap, Aperture) and ap.spider_of() == (w, n, 0.0)

    def check(lens):
        inside = _edge_points(w, n, 0.0, radii, -EPS)
        outside = _edge_points(w, n, 0.0, radii, EPS)
        got = _passes(lens, inside + outside, z0=-0.5)
        assert got == [False] * len(inside) + [True] * len(outside)

    check(lens)
    d = lens_to_dict(lens)
    assert d["surfaces"][0]["spider_width_mm"] == w and d["surfaces"][0]["spider_arms"] == n
    assert lens_to_dict(lens_from_dict(d)) == d
    check(lens_from_dict(d))
    write_zmx(lens, tmp_path / "out.zmx")
    text = (tmp_path / "out.zmx").read_text()
    block = text[text.index("SURF 1"):text.index("SURF 2")]
    assert "SPID 0.8 3 0" in block and "CLAP" not in block
    with pytest.warns(UserWarning, match="beside a SPID"):   # its DIAM: drawn, not clipping
        again = read_zmx(tmp_path / "out.zmx")
    assert again.surfaces[0].spider_of() == (w, n, 0.0)
    check(again)
    with pytest.raises(LensFileError, match="spider obscuration has no CODE V record"):
        write_seq(lens, tmp_path / "out.seq")


def test_spider_rays_on_a_grid_match_hand_geometry(tmp_path):
    """A 40 x 40 grid of rays parallel to the axis through the 4-arm ``SPID 0.6 4`` and the
    stop (radius 5): each ray passes exactly when hand geometry puts it inside the stop's
    circle and off every arm (points within 1e-6 mm of an edge are left out)."""
    w, n = 0.6, 4
    lens = read_zmx(_dummy_before_stop(tmp_path, [f"SPID {w} {n} 0"]))
    g = torch.linspace(-4.9, 4.83, 40, dtype=torch.float64)
    pts = [(float(a), float(b)) for a in g for b in g]

    def near_edge(q):
        for j in range(n):
            t = 2.0 * math.pi * j / n
            across = q[1] * math.cos(t) - q[0] * math.sin(t)
            if abs(abs(across) - w / 2) < 1e-6:
                return True
        return abs(math.hypot(*q) - 5.0) < 1e-6
    pts = [q for q in pts if not near_edge(q)]
    got = _passes(lens, pts, z0=-0.5)
    want = [math.hypot(*q) < 5.0 and not _on_arm(q, w, n, 0.0) for q in pts]
    assert got == want and sum(want) > 100 and sum(not v for v in want) > 100


@pytest.mark.parametrize("closing_order", [1, 0])
def test_spider_inside_a_z_turn_pair_turns_its_arms(tmp_path, closing_order):
    """A ``COORDBRK`` turning 30° about z (``PARM 5``) before the spider's surface and one
    turning back after it (OpticStudio's sample Schmidt-Cassegrain turns its spider so).  The
    closing break with order flag 1 makes the pair one element's misalignment (zero thickness
    inside): the reader turns the spider, whose first arm then lies at +30° in the lens's frame
    (``x_before = R_z(t) x_after``), and writing it back is refused (SPID's first arm is along
    +x).  With order 0 the breaks are kept as :class:`CoordinateBreak` surfaces and the spider,
    first arm along its own +x, turns with the frame; that lens writes back and reads back.
    Either way rays on the turned arms are blocked and rays on the unturned ones pass."""
    w, n = 0.8, 3

    def brk(tz, disz, order):
        return ("  TYPE COORDBRK\n  CURV 0.0\n  PARM 1 0\n  PARM 2 0\n  PARM 3 0\n  PARM 4 0\n"
                f"  PARM 5 {tz}\n  PARM 6 {order}\n  DISZ {disz}\n")
    text = singlet(aperture="FLOA").replace(
        "SURF 1\n  STOP", "SURF 1\n" + brk(30, 0, 0) + "SURF 2\n  TYPE STANDARD\n  CURV 0.0\n"
        f"  DISZ 0\n  SPID {w} {n} 0\nSURF 3\n" + brk(-30, 1, closing_order)
        + "SURF 4\n  STOP", 1)
    out, k = [], 0
    for ln in text.splitlines():
        if ln.startswith("SURF "):
            ln, k = f"SURF {k}", k + 1
        out.append(ln)
    path = write(tmp_path, "\n".join(out) + "\n", "turned.zmx")
    lens = read_zmx(path)
    aps = [s for s in lens.surfaces if isinstance(s, Aperture) and s.spider_of() is not None]
    breaks = [s for s in lens.surfaces if type(s).__name__ == "CoordinateBreak"]
    assert len(aps) == 1
    if closing_order == 1:
        assert math.isclose(aps[0].spider_of()[2], math.radians(30.0)) and not breaks
    else:
        assert aps[0].spider_of()[2] == 0.0 and len(breaks) == 2
    a = math.radians(30.0)
    on_turned = _edge_points(w, n, a, (2.0, 4.0), -EPS)
    on_plain = _edge_points(w, n, 0.0, (2.0, 4.0), -EPS)
    z0 = float(lens.z_vertices()[0]) - 0.5
    want = [False] * 12 + [True] * 12
    assert _passes(lens, on_turned + on_plain, z0=z0) == want
    if closing_order == 1:
        with pytest.raises(ZemaxFileError, match="first arm"):
            write_zmx(lens, tmp_path / "out.zmx")
    else:
        write_zmx(lens, tmp_path / "out.zmx")
        with pytest.warns(UserWarning, match="beside a SPID"):
            again = read_zmx(tmp_path / "out.zmx")
        assert _passes(again, on_turned + on_plain, z0=z0) == want


@pytest.mark.parametrize("extra, needle, match", [
    (("SPID 0.5 3 0", "CLAP 0 4 0"), "SPID", "SPID on SURF 2: a spider together with CLAP"),
    (("OBSC 0 1 0", "SPID 0.5 3 0"), "SPID", "together with OBSC"),
    (("SPID 0.5 3 0", "OBDC 0 1"), "OBDC", "a decentred spider"),
    (("SPID 0 3 0",), "SPID", "expected the arms' width > 0"),
    (("SPID 0.5 2.5 0",), "SPID", "an integer >= 1"),
])
def test_spid_refusals_name_the_line(tmp_path, extra, needle, match):
    """A spider beside another surface aperture, decentred, or with a bad width or arm count:
    refused with the file and line."""
    text = singlet(s1_extra=("PARM 1 0", "PARM 2 1e-05", *extra))
    path = write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(path)
    assert f"{path}:{_line(text, needle)}:" in str(e.value)


def test_lens_file_spider_fields_are_checked(tmp_path):
    lens = read_zmx(_dummy_before_stop(tmp_path, ["SPID 0.8 3 0"]))
    d = lens_to_dict(lens)
    d["surfaces"][0]["spider_arms"] = 2.5
    with pytest.raises(LensFileError, match="spider_arms"):
        lens_from_dict(d)
    del d["surfaces"][0]["spider_width_mm"]
    with pytest.raises(LensFileError, match="spider_width_mm"):
        lens_from_dict(d)


def test_spid_on_a_mirror_blocks_the_arms(tmp_path):
    """``SPID 0.7 4`` on a concave mirror (the shadow of a secondary's vanes): rays parallel to
    the axis 1e-6 mm inside either edge of each arm at radii 2, 5 and 8 mm are blocked, 1e-6 mm
    outside pass (both trace paths); the control mirror without it passes all; .zmx and JSON
    round trips keep it; the CODE V writer refuses it."""
    w, n, radii = 0.7, 4, (2.0, 5.0, 8.0)
    lens = read_zmx(_mirror(tmp_path, [f"SPID {w} {n} 0"]))
    m = lens.surfaces[1]
    assert isinstance(m, Asphere) and obscuration_spider_of(m) == (w, n, 0.0)
    inside = _edge_points(w, n, 0.0, radii, -EPS)
    outside = _edge_points(w, n, 0.0, radii, EPS)
    want = [False] * len(inside) + [True] * len(outside)
    for options in (None, TraceOptions(closed_form=False)):
        assert _passes(lens, inside + outside, options, z0=-1.0) == want
    plain = read_zmx(_mirror(tmp_path, name="plain.zmx"))
    assert _passes(plain, inside, z0=-1.0) == [True] * len(inside)
    write_zmx(lens, tmp_path / "out.zmx")
    assert f"SPID {w} {n} 0" in (tmp_path / "out.zmx").read_text()
    again = read_zmx(tmp_path / "out.zmx")
    assert lens_to_dict(again) == lens_to_dict(lens)
    assert _passes(again, inside + outside, z0=-1.0) == want
    d = lens_to_dict(lens)
    assert d["surfaces"][1]["spider_width_mm"] == w and d["surfaces"][1]["spider_arms"] == n
    back = lens_from_dict(d)
    assert lens_to_dict(back) == d and _passes(back, inside + outside, z0=-1.0) == want
    with pytest.raises(LensFileError, match="spider obscuration has no CODE V record"):
        write_seq(lens, tmp_path / "out.seq")


def test_spid_on_a_lens_surface_and_its_refusals(tmp_path):
    """``SPID 0.5 3`` on the singlet's first (refracting, aspheric) surface is that surface's
    obscuration; beside a CLAP there it is refused at its line, and a spider beside a circular
    obscuration on one lens surface is refused when written (one aperture type per surface)."""
    lens = read_zmx(write(tmp_path, singlet(s1_extra=("PARM 1 0", "PARM 2 1e-05",
                                                      "SPID 0.5 3 0"))))
    assert obscuration_spider_of(lens.surfaces[1]) == (0.5, 3, 0.0)
    lens.surfaces[1].obscuration.fill_(0.3)
    with pytest.raises(ZemaxFileError, match="spider obscuration beside OBSC"):
        write_zmx(lens, tmp_path / "out.zmx")
