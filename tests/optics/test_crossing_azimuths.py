"""Issue 38: :meth:`Lens.check` looks for crossing surfaces along several azimuths, not along y
only.  A biconic whose x section reaches its neighbour while its y section does not was
accepted, and the rays beyond the crossing were lost silently; so was a surface crossing only
along a diagonal (an ``xy`` term)."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.errors import SurfacesCrossError
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.surfaces import Biconic, Plane, XYPolynomial

GAP = 1.0  # mm between the vertex of the first surface and the plane


def _lens(first):
    return Lens([first, Plane(5.0)], [Air(), ModelGlass(1.5, 60.0), Air()], [0.0, GAP], 20.0, 0)


def test_biconic_crossing_along_x_is_refused():
    """c_y = 1/50 (sag 0.25 mm at the 5 mm rim, clear of the plane 1 mm behind), c_x = 1/6
    (sag 2.68 mm): the x section meets the plane where 6 - sqrt(36 - r^2) = 1, r = sqrt(11)."""
    with pytest.raises(SurfacesCrossError,
                       match=r"surfaces 0 and 1 cross: at r = .* mm along x surface 1 lies .* mm "
                             r"before surface 0 \(distance between them 1 mm\); increase the "
                             r"thickness or reduce the semi-diameters") as e:
        _lens(Biconic(1 / 50.0, 5.0, 1 / 6.0))
    assert e.value.surfaces == (0, 1)
    assert e.value.radius == pytest.approx(math.sqrt(11.0), rel=1e-9)
    # the same surface turned by 90 degrees crosses along y, with the message as before
    with pytest.raises(SurfacesCrossError,
                       match=r"surfaces 0 and 1 cross: at r = .* mm surface 1 lies") as e:
        _lens(Biconic(1 / 6.0, 5.0, 1 / 50.0))
    assert e.value.radius == pytest.approx(math.sqrt(11.0), rel=1e-9)


def test_biconic_control_and_closed_form_rim():
    """x sag at the rim 15 - sqrt(225 - 25) = 0.858 mm < 1 mm: accepted; 12 - sqrt(119) =
    1.091 mm > 1 mm: refused at r = sqrt(12^2 - 11^2) = sqrt(23)."""
    _lens(Biconic(1 / 50.0, 5.0, 1 / 15.0))
    with pytest.raises(SurfacesCrossError, match="along x") as e:
        _lens(Biconic(1 / 50.0, 5.0, 1 / 12.0))
    assert e.value.radius == pytest.approx(math.sqrt(23.0), rel=1e-9)


def test_crossing_along_a_diagonal_only_is_refused():
    """z = 0.1 x y is 0 on both axes and 0.05 r^2 at 45 degrees: it meets the plane 1 mm behind
    at r = sqrt(20) = 4.47 mm < 5 mm along the diagonal, and nowhere along x or y."""
    coeffs = (0.0, 0.0, 0.0, 0.0, 0.1, 0.0)   # 1, y, x, y^2, xy, x^2
    with pytest.raises(SurfacesCrossError, match=r"at azimuth 45 deg from \+x") as e:
        _lens(XYPolynomial(5.0, coeffs))
    assert e.value.radius == pytest.approx(math.sqrt(20.0), rel=1e-9)
    _lens(XYPolynomial(5.0, (0.0, 0.0, 0.0, 0.0, 0.07, 0.0)))   # 0.035 * 25 = 0.875 < 1


def test_last_surface_crossing_the_sensor_along_x_is_refused():
    """The sensor-plane check samples the same azimuths: a biconic whose x section reaches past
    the sensor plane (sag 2.68 mm at the rim, sensor 2 mm behind) is refused."""
    with pytest.raises(Exception, match="the last surface crosses the sensor plane"):
        Lens([Plane(5.0), Biconic(1 / 50.0, 5.0, 1 / 6.0)],
             [Air(), ModelGlass(1.5, 60.0), Air()], [0.0, 4.0], 2.0, 0)
    # with the sensor 3 mm behind it is accepted
    lens = Lens([Plane(5.0), Biconic(1 / 50.0, 5.0, 1 / 6.0)],
                [Air(), ModelGlass(1.5, 60.0), Air()], [0.0, 4.0], 3.0, 0)
    assert isinstance(lens, Lens) and torch.is_tensor(lens.d_sensor)
