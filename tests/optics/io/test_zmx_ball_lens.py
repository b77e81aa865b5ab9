"""Ball lenses: two full hemispheres (``DIAM`` = ``|R|``) back to back, ``2R`` apart.

Two real files of the unseen sets (``px_2_Ball_lens_interconnect``, ``px_Ball_coupling``) were
refused because a semi-diameter equal to the radius was taken as beyond the sphere's domain.  A
semi-diameter on the rim of a conic's domain is a valid full hemisphere (within 8 float64
rounding units of ``1 - (1+k) c^2 r^2 = 0``: ``check_conic_domain``); beyond it stays refused.
Checked here against closed forms and independent code:

* the paraxial focal length of a ball, ``f = n D / (4 (n - 1))``;
* real rays through a ball against a ray-sphere intersection and Snell's law written here in
  numpy (float64), up to ``r = R (1 - 1e-9)`` (grazing incidence); a ray that reaches exactly
  the rim is a clean miss (invalid, every number finite, finite gradients);
* the autograd derivative of an exit direction w.r.t. a face's curvature against a central
  difference near the rim (``r = 0.99 R``);
* zero edge thickness (faces meeting at the rim) accepted; a ball ``1e-6 mm`` thinner (faces
  crossing at the rim) refused;
* a hand-written ``.zmx`` ball loads with the closed-form EFL; a ``DIAM`` beyond the radius is
  refused at its block, naming the block as the file numbers it (``SURF 1``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from deeplens.optics.errors import SurfacesCrossError, ZemaxWarning
from deeplens.optics.intersect import TraceOptions
from deeplens.optics.io.zmx import read_zmx
from deeplens.optics.lens import Lens, LensSpec
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture, Asphere, Sphere
from deeplens.optics.surfaces.base import check_conic_domain

F64 = torch.float64
EPS = 2.0 ** -52


def ball(R: float, n: float, thickness: float | None = None, sd: float | None = None) -> Lens:
    """A ball of radius ``R`` (mm) and constant index ``n`` in air, the stop (radius ``R``, no
    ray inside the ball misses it) at its centre."""
    t = 2 * R if thickness is None else thickness
    sd = R if sd is None else sd
    glass = ModelGlass(n, math.inf)
    return Lens([Sphere(1 / R, sd), Aperture(R), Sphere(-1 / R, sd)],
                [Air(), glass, glass, Air()], [0.0, t / 2, t / 2], 2 * R, 1,
                spec=LensSpec(aperture_type="stop"))


# ------------------------------------------------------------------- the rim of the domain
def test_semi_diameter_on_the_rim_is_a_hemisphere_beyond_is_refused():
    for R, k in [(1.0, 0.0), (3.7, 0.0), (-25.4 / 3, 0.0), (2.0, 0.5)]:
        c = 1 / R
        rim = 1 / (abs(c) * math.sqrt(1 + k))
        check_conic_domain(rim, c, k, "conic")                  # on the rim
        check_conic_domain(rim * (1 + 2 * EPS), c, k, "conic")  # within its rounding
        with pytest.raises(ValueError, match="beyond the domain of the conic"):
            check_conic_domain(rim * (1 + 1e-12), c, k, "conic")


@pytest.mark.parametrize("R,n", [(1.0, 1.5), (2.5, 1.8), (0.75, 1.45)])
def test_ball_focal_length_is_the_closed_form(R, n):
    # a thick lens R1 = R, R2 = -R, t = 2R: 1/f = (n-1)(2/R) - (n-1)^2 2R/(n R^2) = 2(n-1)/(nR)
    f = n * (2 * R) / (4 * (n - 1))
    assert float(paraxial(ball(R, n)).efl) == pytest.approx(f, rel=1e-12)


# ------------------------------------------------------------------- real rays
def _snell(d, nrm, eta):
    """Refracted unit direction (vector Snell's law); ``nrm`` faces the incoming ray."""
    cos_i = -float(d @ nrm)
    k = 1 - eta * eta * (1 - cos_i * cos_i)
    return eta * d + (eta * cos_i - math.sqrt(k)) * nrm


def _ball_by_hand(R: float, n: float, h: float):
    """A ray parallel to the axis at height ``h`` through the ball (centre ``(0, 0, R)``):
    entry point, exit point, exit direction (numpy, float64)."""
    C = np.array([0.0, 0.0, R])
    o, d = np.array([0.0, h, -1.0]), np.array([0.0, 0.0, 1.0])
    # |o + t d - C|^2 = R^2: t^2 + 2 b t + c = 0
    b, cc = float((o - C) @ d), float((o - C) @ (o - C)) - R * R
    p1 = o + (-b - math.sqrt(b * b - cc)) * d           # the near root: entry
    d1 = _snell(d, (p1 - C) / R, 1 / n)
    b, cc = float((p1 - C) @ d1), float((p1 - C) @ (p1 - C)) - R * R
    p2 = p1 + (-b + math.sqrt(b * b - cc)) * d1         # the far root: exit, from inside
    d2 = _snell(d1, -(p2 - C) / R, n)
    return p1, p2, d2


def _trace(lens, heights, options=None):
    h = torch.tensor(heights, dtype=F64)
    o = torch.stack([torch.zeros_like(h), h, torch.full_like(h, -1.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand_as(o)
    return lens.trace(Rays(o, d, 587.5618), record=True, options=options)


@pytest.mark.parametrize("R,n", [(1.0, 1.5), (2.5, 1.8)])
def test_real_rays_through_a_ball_match_a_sphere_by_hand(R, n):
    lens = ball(R, n)
    heights = [0.0, 0.3 * R, 0.9 * R, 0.999 * R, R * (1 - 1e-9)]
    out, hits = _trace(lens, heights)
    assert bool(out.valid.all())
    for j, h in enumerate(heights):
        p1, p2, d2 = _ball_by_hand(R, n, h)
        # a few roundings of R, amplified by the slope 1 / cos(i) at grazing incidence (cos(i)
        # = 4.5e-5 at r = R (1 - 1e-9): 3e-10 R; measured 2.5e-12 R for the points and 4e-11
        # for the directions, which the refraction's normal carries over)
        cos_i = math.sqrt(1 - (h / R) ** 2)
        tol_p, tol_d = 64 * EPS * R / cos_i, 64 * EPS / cos_i
        assert np.abs(hits[0][j].numpy() - p1).max() < tol_p, (h, hits[0][j], p1)
        assert np.abs(hits[2][j].numpy() - p2).max() < tol_p, (h, hits[2][j], p2)
        assert np.abs(out.d[j].numpy() - d2).max() < tol_d, (h, out.d[j], d2)


@pytest.mark.parametrize("options", [None, TraceOptions(closed_form=False),
                                     TraceOptions(mode="unrolled"), "asphere"],
                         ids=["closed_form", "newton", "unrolled", "asphere_newton"])
def test_a_ray_at_the_rim_is_a_clean_miss_with_finite_gradients(options):
    lens = ball(1.0, 1.5)
    if options == "asphere":   # Newton from the conic's root: faces 2e-3 mm apart at the rim
        glass = ModelGlass(1.5, math.inf)
        lens = Lens([Asphere(1.0, 1.0, coefficients=[-1e-3]), Aperture(1.0),
                     Asphere(-1.0, 1.0, coefficients=[1e-3])],
                    [Air(), glass, glass, Air()], [0.0, 1.0, 1.0], 2.0, 1)
        options = None
    front = lens.surfaces[0]
    front.c.requires_grad_(True)
    heights = [0.5, 1 - 1e-9, 1.0, 1.0 + 1e-9]
    out, hits = _trace(lens, heights, options)
    assert out.valid.tolist() == [True, True, False, False]
    assert all(bool(torch.isfinite(x).all()) for x in (out.o, out.d, out.opl, *hits))
    loss = torch.where(out.valid, out.o[:, 1] + out.d[:, 1] + out.opl, 0.0).sum()
    (g,) = torch.autograd.grad(loss, front.c)
    assert math.isfinite(float(g))
    # the sag, its slope and the implicit function stay finite up to and beyond the rim
    r = torch.tensor([0.0, 0.5, 1 - 1e-9, 1.0, 1.0 + 1e-9], dtype=F64)
    z = torch.zeros_like(r)
    for v in (front.sag(z, r), *front.sag_grad(z, r), *front.f_grad(z, r, z)):
        assert bool(torch.isfinite(v).all())
    # on the rim the sag is the hemisphere's depth R (plus a4 R^4), where a ball's faces meet
    rim = 1.0 + (float(front.a[0]) if len(front.a) else 0.0)
    assert float(front.sag(z[3:4], r[3:4]).detach()) == pytest.approx(rim, rel=1e-15)


def test_exit_direction_gradient_near_the_rim_is_a_central_difference():
    def exit_slope(c: float, grad: bool = False):
        lens = ball(1.0, 1.5)
        with torch.no_grad():
            lens.surfaces[0].c.fill_(c)
        lens.surfaces[0].c.requires_grad_(grad)
        out, _ = _trace(lens, [0.99])
        assert bool(out.valid.all())
        return out.d[0, 1], lens.surfaces[0].c

    y, c = exit_slope(1.0, grad=True)
    (g,) = torch.autograd.grad(y, c)
    step = 1e-6   # truncation ~ y''' step^2 / 6, rounding ~ eps / step: both < 1e-8 relative
    fd = (float(exit_slope(1.0 + step)[0]) - float(exit_slope(1.0 - step)[0])) / (2 * step)
    assert float(g) == pytest.approx(fd, rel=1e-6)


# ------------------------------------------------------------------- edge thickness
def test_zero_edge_thickness_is_accepted_crossing_faces_are_refused():
    ball(1.0, 1.5, thickness=2.0)
    ball(1.0, 1.5, thickness=2.0 - 1e-10)      # within the crossing check's 1e-9 mm
    with pytest.raises(SurfacesCrossError, match=r"surfaces 0 and 2 cross: at r = 1 mm"):
        ball(1.0, 1.5, thickness=2.0 - 1e-6)
    with pytest.raises(ValueError, match="beyond the domain of the conic"):
        ball(1.0, 1.5, sd=1.0 + 1e-9)


# ------------------------------------------------------------------- a .zmx ball
BALL_ZMX = """VERS 130724 109 23203
MODE SEQ
NAME ball
UNIT MM X W X CM MR CPMM
ENPD 0.4
GCAT SCHOTT
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
SURF 0
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ INFINITY
SURF 1
  TYPE STANDARD
  CURV 1.0 0 0 0 0 ""
  DISZ 1
  GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0
  DIAM {diam} 1 0 0 1 ""
SURF 2
  STOP
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ 1
  GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0
  DIAM 1 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV -1.0 0 0 0 0 ""
  DISZ 0.5
  DIAM 1 1 0 0 1 ""
SURF 4
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ 0
"""


def test_zmx_ball_loads_and_a_fixed_diam_beyond_the_radius_is_read_at_the_rim(tmp_path):
    """DIAM 1 on R 1 mm (the rim) loads; DIAM 1.001 (fixed, a surface with power: OpticStudio's
    floating aperture, which clips nothing the sphere keeps) is read at the rim with one note at
    its line (before branch setups13: refused at the block as beyond the conic's domain)."""
    f = tmp_path / "ball.zmx"
    f.write_text(BALL_ZMX.format(diam="1"))
    lens = read_zmx(f)
    assert float(paraxial(lens).efl) == pytest.approx(1.5 * 2 / (4 * 0.5), rel=1e-12)
    f.write_text(BALL_ZMX.format(diam="1.001"))
    line = BALL_ZMX.splitlines().index('  DIAM {diam} 1 0 0 1 ""') + 1
    with pytest.warns(ZemaxWarning, match=rf"ball.zmx:{line}: SURF 1: the fixed DIAM 1.001 "
                                          rf"\(read as 1\) lies beyond the edge of its conic"):
        lens = read_zmx(f)
    assert float(lens.surfaces[0].semi_diameter) == pytest.approx(1.0, rel=4 * 2.0 ** -52)
    assert float(paraxial(lens).efl) == pytest.approx(1.5 * 2 / (4 * 0.5), rel=1e-12)
