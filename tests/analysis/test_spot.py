"""Spot diagrams (``deeplens.analysis.spot``): the RMS radius and its gradient.

The RMS radius is the centroid-referenced ``sqrt(mean |p - p̄|^2)``; its gradient is compared with
a float64 central finite difference, and a spot of a single ray (radius 0) must have a finite
(zero) gradient.
"""

import torch

from deeplens.analysis.spot import spot_diagram
from deeplens.optics.surfaces import Sphere

from helpers import WAVELENGTH_D, central_fd, rel_err, singlet


def _lens():
    lens = singlet(Sphere(1 / 30.0, 6.0), Sphere(-1 / 40.0, 6.0), d_sensor=30.0)
    lens.d_sensor.requires_grad_(True)
    return lens


def test_rms_radius_of_a_single_ray_has_a_zero_gradient():
    """Regression (issue 12, defect 4): one surviving ray (or coincident rays) gives a spot of
    radius 0, and ``sqrt`` at 0 made the documented-differentiable ``rms_radius`` gradient NaN.
    The RMS radius is a norm; at 0 its gradient is the subgradient 0."""
    lens = _lens()
    spot = spot_diagram(lens, 0.0, WAVELENGTH_D, "hexapolar:0", pupil="paraxial")
    assert spot.n_rays == 1 and float(spot.rms_radius.detach()) == 0.0
    (g,) = torch.autograd.grad(spot.rms_radius, lens.d_sensor)
    assert float(g) == 0.0


def test_rms_radius_gradient_matches_finite_differences():
    lens = _lens()

    def rms():
        return spot_diagram(lens, 5.0, WAVELENGTH_D, "hexapolar:4", pupil="paraxial").rms_radius

    r = rms()
    assert float(r.detach()) > 1e-3
    (g,) = torch.autograd.grad(r, lens.d_sensor)
    fd = central_fd(rms, lens.d_sensor, 1e-3)
    assert rel_err(g, fd) < 1e-7, (float(g), fd)
