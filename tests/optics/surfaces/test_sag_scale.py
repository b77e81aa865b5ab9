"""Every registered surface type's parameter scale (:meth:`Surface.sag_scale
<deeplens.optics.surfaces.base.Surface.sag_scale>`, read by
:func:`deeplens.optics.parameters.parameter_scale`) against the sag change per unit of each
parameter, measured by central differences at the rim.

The rule (the module docstring of :mod:`deeplens.optics.parameters`): a parameter's scale is
``max |∂ sag / ∂p|`` over the rim ``r = R`` (the semi-diameter; for the XY polynomial, written
in ``x`` and ``y``, over the square ``|x|, |y| <= R`` about it: its ``x^i y^j`` scales by
``R^(i+j)``, the term at the corner); 1 for a parameter that does not move the sag (a phase, a
focal length, a frame change); and 1 by convention for the few families documented as mm
(Zernike and B-spline heights, the XY ``b``).  A curvature's rule, ``R^2/2``, is the derivative
at ``c = 0``; at the examples' curvatures (``|c| R <= 0.05``) the derivative is
``R^2/2 (1 + 3/4 (1+k) c^2 R^2 + ...)``, within 0.3 % of it, hence the 1 % tolerance (every
other rule is the derivative itself; the differences' error is ~1e-9 relative).

The test iterates over the registry (:data:`~deeplens.optics.surfaces.SURFACE_TYPES`): a new
surface type without an example here fails it.  Planting the defect this test was written for
back (``Cylinder``, ``Toroid`` or ``QType`` returning 1 for a curvature, issue 39) fails it.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from deeplens.optics.parameters import parameter_scale
from deeplens.optics.surfaces import (SURFACE_TYPES, Aperture, Asphere, Biconic, Binary1,
                                      Binary2, BSpline,
                                      CoordinateBreak, Cylinder, ExtendedOddAsphere,
                                      ExtendedPolynomial, Fresnel,
                                      Grating, GridSag,
                                      Hologram,
                                      IdealLens,
                                      IdealLensXY,
                                      Irregular, LensletArray, OddAsphere,
                                      Plane, QType, Toroid, XYPolynomial, ZernikeFringePhase,
                                      ZernikeFringeSag, ZernikeSag)

F64 = torch.float64
R = 5.0   # mm, every example's semi-diameter

EXAMPLES = {
    Asphere: lambda: Asphere(0.01, R, conic=-0.5, coefficients=[1e-4, -2e-6]),
    Aperture: lambda: Aperture(R),
    Plane: lambda: Plane(R),
    Binary2: lambda: Binary2(0.01, R, R, [-10.0, 1.0], 1, conic=-0.5, coefficients=[1e-4]),
    ZernikeFringePhase: lambda: ZernikeFringePhase(0.01, R, R, [0.0, 0.1, 0.0, -1.0], 1,
                                                   conic=-0.5),
    Binary1: lambda: Binary1(0.01, R, R, [1.0, 0.0, -10.0, 0.0, -10.0], 1, conic=-0.5),
    Biconic: lambda: Biconic(0.01, R, -0.008, conic=-0.5, conic_x=0.3),
    BSpline: lambda: BSpline(R, torch.linspace(0.0, 0.1, 25).reshape(5, 5)),
    CoordinateBreak: lambda: CoordinateBreak(0.1, 0.0, 0.01, semi_diameter=R),
    Cylinder: lambda: Cylinder(0.01, R, conic=-0.5, coefficients=[1e-3, 1e-5]),
    Grating: lambda: Grating(0.01, R, 0.5, 1, conic=-0.5),
    IdealLens: lambda: IdealLens(50.0, R),
    IdealLensXY: lambda: IdealLensXY(0.0, 0.02, R),
    OddAsphere: lambda: OddAsphere(0.01, R, conic=-0.5, coefficients=[1e-3, 1e-4, 1e-5]),
    QType: lambda: QType(0.01, R, R, [1e-3, 2e-4], "qbfs", conic=-0.5),
    Toroid: lambda: Toroid(0.01, R, 100.0, conic=-0.5, coefficients=[1e-3]),
    XYPolynomial: lambda: XYPolynomial(R, [0.0, 1e-3, 2e-3, 1e-3, 5e-4, -1e-3], b=1e-3),
    ZernikeSag: lambda: ZernikeSag(0.01, R, R, [0.0, 1e-3, 2e-3, 1e-3], conic=-0.5,
                                   coefficients=[1e-4]),
    ZernikeFringeSag: lambda: ZernikeFringeSag(-0.01, R, R, [0.0, 1e-3, 2e-3, 1e-3], conic=0.3,
                                               coefficients=[1e-4, 1e-6]),
    GridSag: lambda: GridSag(0.01, R, (2.5, 2.5), torch.zeros(5, 5), conic=-0.5,
                             coefficients=[1e-4, -2e-6]),
    Fresnel: lambda: Fresnel(0.01, R, conic=-0.5, coefficients=[1e-3, 1e-5]),   # flat: scale 1
    Irregular: lambda: Irregular(0.01, R, 1.2 * R, conic=-0.5, decenter=(0.3, -0.2),
                                 tilt=(0.002, -0.001), z_spherical=1e-3, z_astigmatism=-2e-3,
                                 z_coma=1e-3, angle=0.3),
    ExtendedPolynomial: lambda: ExtendedPolynomial(0.01, R, 0.8 * R, [1e-3, -2e-3, 1e-3,
                                                                5e-4, -1e-3, 2e-4, 0.0, 3e-4],
                                                   conic=-0.5),
    ExtendedOddAsphere: lambda: ExtendedOddAsphere(0.01, R, 0.8 * R, [1e-3, 2e-3, -1e-3, 5e-4],
                                                   conic=-0.5),
    Hologram: lambda: Hologram(0.01, R, (1.0, -2.0, -150.0), (0.5, 3.0, 90.0), 550.0, 1, 2,
                               conic=-0.5),
    # lenslets of width w = R / (1.5 sqrt 2): a corner of four lenslets on the rim at 45°, where
    # the sag's derivative is largest (the farthest point from a lenslet's centre: its
    # half-diagonal, the scale's rule; c = 0.05 puts the conic's derivative there above
    # conic_scale's 1e-6 floor, |c| ρ = 0.08 keeps the curvature's within 0.3 % of ρ²/2)
    LensletArray: lambda: LensletArray(0.05, R, (5, 5), (R / (1.5 * math.sqrt(2)),) * 2,
                                       conic=-0.5),
}
#: grids of node values (one tensor, one scale per node value): checked per node in
#: tests/optics/surfaces/test_grid_sag.py (the largest sag change per unit of one node's value)
PER_NODE = {(GridSag, "grid_z"), (GridSag, "grid_dz_dx"), (GridSag, "grid_dz_dy"),
            (GridSag, "grid_d2z_dxdy")}
#: documented as mm (or 1/mm) with scale 1 by convention, not the rim derivative
CONVENTION = {(ZernikeSag, "zernike"), (ZernikeFringeSag, "zernike"), (BSpline, "coefficients"), (XYPolynomial, "b")}


def _rim(surface):
    """Rim points ``(x, y)`` (mm, float64): the circle ``r = R`` (72 azimuths), or the boundary
    of the square ``|x|, |y| <= R`` for the XY polynomial."""
    if isinstance(surface, XYPolynomial):
        t = torch.linspace(-R, R, 41, dtype=F64)
        one = torch.full_like(t, R)
        return torch.cat([t, t, one, -one]), torch.cat([one, -one, t, t])
    phi = torch.arange(72, dtype=F64) * (2 * math.pi / 72)
    return R * torch.cos(phi), R * torch.sin(phi)


def _rim_derivative(surface, param) -> float:
    """``max |∂ sag / ∂p|`` over the rim by central differences (float64; ``param`` 0-d)."""
    x, y = _rim(surface)
    h = 1e-6 * max(1.0, abs(float(param)))
    p0 = float(param)
    with torch.no_grad():
        param.fill_(p0 + h)
        up = surface.sag(x, y)
        param.fill_(p0 - h)
        down = surface.sag(x, y)
        param.fill_(p0)
    return float(((up - down) / (2 * h)).abs().max())


def test_every_registered_type_has_an_example():
    assert set(SURFACE_TYPES.values()) == set(EXAMPLES)


@pytest.mark.parametrize("cls", list(EXAMPLES), ids=lambda c: c.__name__)
def test_scale_is_the_rim_sag_derivative(cls):
    surface = EXAMPLES[cls]()
    lens = SimpleNamespace(surfaces=[Plane(R), surface])   # what parameter_scale reads
    checked = 0
    for name, p in surface.named_parameters():
        scale = parameter_scale(lens, f"surfaces.1.{name}")
        if (cls, name.split(".")[0]) in CONVENTION:
            assert scale == 1.0, name
            continue
        if (cls, name) in PER_NODE:
            continue
        ref = _rim_derivative(surface, p)
        if ref < 1e-9:   # the parameter does not move the sag
            assert scale == 1.0, f"{cls.__name__}.{name}: {scale} (no sag change)"
        else:
            assert scale == pytest.approx(ref, rel=1e-2), f"{cls.__name__}.{name}"
        checked += 1
    assert checked == sum(1 for n, _ in surface.named_parameters()
                          if (cls, n.split(".")[0]) not in CONVENTION and (cls, n) not in PER_NODE)
