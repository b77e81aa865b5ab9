"""The anamorphic ideal lens (:class:`~deeplens.optics.surfaces.IdealLensXY`, OpticStudio's
``PARAX_XY``): with equal powers it is :class:`IdealLens`; each section images a point at the
thin-lens distance of its own power (the closed form ``1/v = φ − 1/s``, real rays to 1e-12 mm);
a trace gradient in the y power against central differences (float64); the lens file
round-trips."""

from __future__ import annotations

import pytest
import torch

from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import IdealLens, IdealLensXY

F64 = torch.float64
S = 0.5362          # object distance (mm), as OpticStudio's diode sample
PX, PY = 2.5, 7.971  # powers (1/mm)


def _lens(surface, sensor=1.0):
    return Lens([surface], [Air(), Air()], [S], sensor, 0)


def _from_point(n, axis):
    """``n`` rays from the axial object point (``z = 0``, the lens at ``z = S``) in the x-z
    (``axis`` 0) or y-z (1) plane, within the lens's 0.09 mm semi-diameter."""
    t = torch.linspace(-0.15, 0.15, n, dtype=F64)
    d = torch.zeros(n, 3, dtype=F64)
    d[:, axis] = t
    d[:, 2] = 1.0
    return Rays(torch.zeros(n, 3, dtype=F64), d / d.norm(dim=-1, keepdim=True), 550.0)


def test_equal_powers_are_the_ideal_lens():
    rays = _from_point(7, 1)
    d = torch.tensor([0.05, -0.1, 1.0], dtype=F64)
    rays.d = torch.cat([rays.d[:4], (d / d.norm()).expand(3, 3)])
    a = _lens(IdealLensXY(4.0, 4.0, 0.2))
    b = _lens(IdealLens(0.25, 0.2))
    with torch.no_grad():
        ra, rb = a.trace_to_sensor(rays), b.trace_to_sensor(rays)
    assert ra.valid.all() and torch.allclose(ra.o, rb.o, rtol=0, atol=1e-15)
    assert torch.allclose(ra.d, rb.d, rtol=0, atol=1e-15)


@pytest.mark.parametrize("axis, power", [(0, PX), (1, PY)])
def test_each_section_images_the_point_at_its_own_thin_lens_distance(axis, power):
    v = 1.0 / (power - 1.0 / S)
    lens = _lens(IdealLensXY(PX, PY, 0.2), sensor=v)
    with torch.no_grad():
        out = lens.trace_to_sensor(_from_point(9, axis))
    assert out.valid.all()
    assert float(out.o[:, :2].abs().max()) < 1e-12


def test_paraxial_data_take_the_y_section():
    lens = Lens([IdealLensXY(PX, PY, 0.2)], [Air(), Air()], [1.0], 1.0, 0)
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / PY, rel=1e-14)


def test_trace_gradient_in_the_y_power_matches_central_differences():
    h = 1e-6

    def q(delta):
        s = IdealLensXY(PX, PY + delta, 0.2)
        s.power_y.requires_grad_(True)
        out = _lens(s, 0.2).trace_to_sensor(_from_point(9, 1))
        assert out.valid.all()
        return (out.o[:, 1] ** 2).sum(), s.power_y

    val, p = q(0.0)
    ad, = torch.autograd.grad(val, p)
    fd = float((q(h)[0] - q(-h)[0]).detach()) / (2 * h)
    assert abs(fd) > 1e-6
    assert float(ad) == pytest.approx(fd, rel=1e-6)


def test_both_powers_zero_is_refused_and_the_lens_file_round_trips():
    with pytest.raises(ValueError, match="at least one of power_x, power_y"):
        IdealLensXY(0.0, 0.0, 1.0)
    lens = _lens(IdealLensXY(0.0, PY, 0.2))
    d = lens_to_dict(lens)
    assert d["surfaces"][0]["type"] == "ideal_lens_xy"
    assert d["surfaces"][0]["power_x_per_mm"] == 0.0 and d["surfaces"][0]["power_y_per_mm"] == PY
    assert lens_to_dict(lens_from_dict(d)) == d
