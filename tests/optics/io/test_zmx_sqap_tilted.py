"""``SQAP`` (a rectangular clear aperture) on a ``TILTSURF``, which deeplens reads as an implicit
:class:`~deeplens.optics.surfaces.XYPolynomial` (``z = y tan θ_y + x tan θ_x``), not a sag
surface: the rectangle is tested at the hit point's local ``x, y``, as on any other surface.

Which rays pass is known by hand: a ray from ``(x0, y0, z0)`` along ``(0, sin θ, cos θ)`` meets
the plane ``z - z_v = t y`` at ``y = (y0 + tan θ (z_v - z0)) / (1 - t tan θ)`` (and at ``x0``);
it passes when ``|x0| <= 3`` and ``|y| <= 1``.  A cube beam splitter's diagonal (a 45° tilted
plane whose rectangle's corners touch the cube's faces) loads: surfaces are checked for crossing
only inside both openings' outlines.
"""

from __future__ import annotations

import math

import helpers as H
import pytest
import torch
from test_zmx import singlet, write

from deeplens.optics.io import lens_to_dict, read_zmx, write_zmx
from deeplens.optics.io.lensfile import lens_from_dict
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import XYPolynomial
from deeplens.optics.surfaces.base import clear_rect_of, set_clear_rect

TAN_Y = 0.5
TILTED = dict(s1_type="TILTSURF", curv1=0.0, k=0.0,
              s1_extra=("PARM 1 0", f"PARM 2 {TAN_Y}", "SQAP 3 1 0"))
THETA = math.radians(5.0)


def launch(lens, points, theta=THETA):
    """Rays at ``(x0, y_hit)`` on the tilted plane (mm), along ``(0, sin θ, cos θ)``, started
    1 mm before its vertex: their start heights from the closed form above."""
    zv = float(lens.z_vertices()[1])
    z0, tt = zv - 1.0, math.tan(theta)
    o = [(x, yh * (1 - TAN_Y * tt) - tt * (zv - z0), z0) for x, yh in points]
    o = torch.tensor(o, dtype=torch.float64)
    d = torch.tensor([0.0, math.sin(theta), math.cos(theta)], dtype=torch.float64).expand_as(o)
    return Rays(o, d, float(lens.spec.primary_wavelength_nm))


# (x0, y on the plane): inside |x| <= 3, |y| <= 1, then just outside each edge
INSIDE = [(0.0, 0.0), (2.95, 0.0), (0.0, 0.97), (0.0, -0.97), (-2.95, 0.95)]
OUTSIDE = [(0.0, 1.03), (0.0, -1.03), (3.05, 0.0), (-3.05, 0.5), (2.0, 1.2)]


def passes(lens, points):
    return lens.trace_to_sensor(launch(lens, points)).valid.tolist()


def test_sqap_on_a_tilted_plane_clips_at_the_hit_point(tmp_path):
    lens = read_zmx(write(tmp_path, singlet(**TILTED)))
    surf = lens.surfaces[1]
    assert isinstance(surf, XYPolynomial) and clear_rect_of(surf) == (3.0, 1.0)
    assert float(surf.semi_diameter) == pytest.approx(10 ** 0.5, rel=1e-15)
    assert passes(lens, INSIDE) == [True] * len(INSIDE)
    assert passes(lens, OUTSIDE) == [False] * len(OUTSIDE)
    # both file formats keep it
    back = lens_from_dict(lens_to_dict(lens))
    assert clear_rect_of(back.surfaces[1]) == (3.0, 1.0)
    assert passes(back, INSIDE + OUTSIDE) == [True] * len(INSIDE) + [False] * len(OUTSIDE)
    write_zmx(lens, tmp_path / "out.zmx")
    again = read_zmx(tmp_path / "out.zmx")
    assert isinstance(again.surfaces[1], XYPolynomial)
    assert clear_rect_of(again.surfaces[1]) == (3.0, 1.0)
    assert passes(again, INSIDE + OUTSIDE) == [True] * len(INSIDE) + [False] * len(OUTSIDE)


def test_without_sqap_the_same_rays_pass(tmp_path):
    """The blocked rays are blocked by the rectangle, not by anything else in the lens."""
    plain = dict(TILTED, s1_extra=TILTED["s1_extra"][:2])
    lens = read_zmx(write(tmp_path, singlet(**plain)))
    assert clear_rect_of(lens.surfaces[1]) is None
    assert passes(lens, INSIDE + OUTSIDE) == [True] * (len(INSIDE) + len(OUTSIDE))


def test_the_tilt_moves_the_clipped_band(tmp_path):
    """A start height that passes the rectangle for one tilt is blocked by another: the test
    is at the hit, not at the ray's start or on the vertex plane."""
    lens = read_zmx(write(tmp_path, singlet(**TILTED)))
    zv = float(lens.z_vertices()[1])
    tt = math.tan(THETA)
    y0 = 0.97 - tt   # on the vertex plane z_v (1 mm on): y = 0.97, inside
    y_hit = (y0 + tt * 1.0) / (1 - TAN_Y * tt)   # 1.0146 mm on the tilted plane: outside
    assert y_hit > 1.0
    o = torch.tensor([[0.0, y0, zv - 1.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, math.sin(THETA), math.cos(THETA)]], dtype=torch.float64)
    rays = Rays(o, d, float(lens.spec.primary_wavelength_nm))
    assert lens.trace_to_sensor(rays).valid.tolist() == [False]


def test_set_clear_rect_refuses_a_frame_change():
    from deeplens.optics.surfaces import Aperture, CoordinateBreak
    with pytest.raises(TypeError, match="land on"):
        set_clear_rect(CoordinateBreak(), (1.0, 1.0))
    with pytest.raises(TypeError, match="land on"):
        set_clear_rect(Aperture(2.0), (1.0, 1.0))
    s = XYPolynomial(5.0, [0.0, 0.3, 0.0])
    set_clear_rect(s, (2.0, 1.0))
    assert clear_rect_of(s) == (2.0, 1.0)
    x = torch.tensor([0.0, 1.9, 2.1, 0.0], dtype=torch.float64)
    y = torch.tensor([0.0, 0.9, 0.0, 1.1], dtype=torch.float64)
    assert s.in_aperture(x, y).tolist() == [True, True, False, False]


CUBE = """VERS 170912 299 123456
MODE SEQ
NAME cube beam splitter
UNIT MM X W X CM MR CPMM
ENPD 10
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.55 1
PWAV 1
SURF 0
  TYPE STANDARD
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV 0.02
  DISZ 5
  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0
  DIAM 6 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV 0.0
  DISZ 10
  DIAM 6 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0.0
  DISZ 10
  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0
  SQAP 10 10 0
SURF 4
  TYPE TILTSURF
  PARM 1 0
  PARM 2 1
  DISZ 10
  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0
  SQAP 10 10 0
SURF 5
  TYPE STANDARD
  CURV 0.0
  DISZ 20
  SQAP 10 10 0
SURF 6
  TYPE STANDARD
  DISZ 0
  DIAM 8 1 0 0 1 ""
"""


def test_cube_diagonal_touching_its_faces_loads(tmp_path):
    """A 20 mm cube's 45° diagonal: its rectangle's edges (y = ±10) touch the faces 10 mm
    before and after it; beyond them, within the circumscribed circle (r = 14.1 mm), the
    plane would lie before the entrance face, where no ray meets it.  The lens loads, and the
    faces still may not cross inside the openings: with the entrance face 9.5 mm before the
    diagonal, it is refused."""
    lens = read_zmx(write(tmp_path, CUBE))
    diag = lens.surfaces[3]
    assert isinstance(diag, XYPolynomial) and clear_rect_of(diag) == (10.0, 10.0)
    assert float(diag.semi_diameter) == pytest.approx(200 ** 0.5, rel=1e-15)
    # an axial ray crosses the cube: 20 mm of glass in all, BK7 on both sides of the diagonal
    rays = H.collimated(torch.zeros(1, 2, dtype=torch.float64), (0.0, 0.0, 1.0), 0.0, 550.0)
    assert lens.trace_to_sensor(rays).valid.tolist() == [True]
    from deeplens.optics.errors import ZemaxFileError
    with pytest.raises(ZemaxFileError, match="cross"):
        read_zmx(write(tmp_path, CUBE.replace("  DISZ 10\n  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 "
                                              "0 0 0\n  SQAP 10 10 0\nSURF 4",
                                              "  DISZ 9.5\n  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 "
                                              "0 0 0\n  SQAP 10 10 0\nSURF 4"), "cross.zmx"))
