"""Normalised field/pupil coordinates (:mod:`deeplens.optics.normalized`): with ray aiming,
``P`` on the unit circle lands on the stop rim, ``P = 0`` is the real chief ray (checked
against :func:`deeplens.analysis.spot.chief_ray`, an independent secant search), ``H`` scales
the largest field angle in x and y."""

import math

import helpers as H
import pytest
import torch

from deeplens.analysis.spot import chief_ray
from deeplens.optics.options import TraceOptions
from deeplens.optics.io import load_lens
from deeplens.optics.normalized import normalized_rays, pupil_to_stop
from deeplens.optics.paraxial import paraxial

W = H.WAVELENGTH_D


@pytest.fixture(scope="module")
def cooke():
    return load_lens(H.LENS_DIR / "cooke_triplet.json").to(torch.float64)


def stop_hits(lens, rays):
    """Where the rays cross the stop, by a full trace that records every surface's hits."""
    _, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
    return hits[lens.stop_index][:, :2]


def test_unit_pupil_lands_on_the_stop_rim_off_axis(cooke):
    P = torch.tensor([(0.0, 1.0), (1.0, 0.0), (-1.0, 0.0), (0.6, -0.8), (0.0, 0.5)],
                     dtype=torch.float64)
    r_stop = float(cooke.stop.semi_diameter)
    for Hxy, n in [((0.0, 1.0), 3), ((0.0, 0.5), 5), ((0.7, 0.0), 5)]:
        rays = normalized_rays(cooke, Hxy, P[:n], W)
        assert bool(rays.valid.all())
        xy = stop_hits(cooke, rays)
        assert torch.allclose(xy, P[:n] * r_stop, atol=1e-8 * r_stop), (Hxy, xy)
    # the lower rim ray of the full field would need glass beyond the first element's edge
    # (its surfaces cross there): reported as not aimed, never a wrong ray
    rays = normalized_rays(cooke, (0, 1), (0, -1), W)
    assert not bool(rays.valid[0])


def test_centre_of_the_pupil_is_the_real_chief_ray(cooke):
    theta = max(cooke.spec.fields_deg)
    for hy in (0.5, 1.0):
        u, z_ep, _, ok = pupil_to_stop(cooke, (0, hy), (0, 0), W)
        y_img, y_pupil = chief_ray(cooke, hy * theta, W)
        assert bool(ok[0])
        assert float(u[0, 1]) == pytest.approx(y_pupil, abs=1e-7)
        assert z_ep == pytest.approx(float(paraxial(cooke).entrance_pupil_z))
        out = cooke.trace_to_sensor(normalized_rays(cooke, (0, hy), (0, 0), W))
        assert float(out.o[0, 1]) == pytest.approx(float(y_img), abs=1e-7)


def test_field_angles_in_x_and_y(cooke):
    theta = max(cooke.spec.fields_deg)
    rays = normalized_rays(cooke, [(0.0, 1.0), (0.5, 0.0), (-0.3, 0.4)], (0, 0), W)
    d = rays.d
    assert float(d[0, 1] / d[0, 2]) == pytest.approx(math.tan(math.radians(theta)), rel=1e-12)
    assert float(d[0, 0]) == 0.0
    assert float(d[1, 0] / d[1, 2]) == pytest.approx(math.tan(math.radians(0.5 * theta)))
    assert float(d[2, 0] / d[2, 2]) == pytest.approx(math.tan(math.radians(-0.3 * theta)))
    assert float(d[2, 1] / d[2, 2]) == pytest.approx(math.tan(math.radians(0.4 * theta)))
    # rotational symmetry: field and pupil turned by 90 deg turn the aimed point with them
    u1 = pupil_to_stop(cooke, (0, 0.8), (1, 0), W)[0][0]
    u2 = pupil_to_stop(cooke, (-0.8, 0), (0, 1), W)[0][0]
    assert torch.allclose(u2, torch.stack([-u1[1], u1[0]]), atol=1e-8)


def test_paraxial_aim_is_the_paraxial_entrance_pupil(cooke):
    p = paraxial(cooke)
    r_ep = 0.5 * float(p.entrance_pupil_diameter)
    P = torch.tensor([(0.0, 1.0), (0.3, -0.4)], dtype=torch.float64)
    rays = normalized_rays(cooke, (0, 0), P, W, aim="paraxial")
    t = (float(p.entrance_pupil_z) - rays.o[:, 2]) / rays.d[:, 2]
    at_ep = rays.o[:, :2] + t[:, None] * rays.d[:, :2]
    assert torch.allclose(at_ep, P * r_ep, atol=1e-10)
    # on axis the aimed rim ray differs from the paraxial one by the pupil's aberration only
    u = pupil_to_stop(cooke, (0, 0), (0, 1), W)[0]
    assert float(u[0, 1]) == pytest.approx(r_ep, rel=0.02)


def test_bad_input(cooke):
    with pytest.raises(ValueError, match="pairs"):
        normalized_rays(cooke, (0, 1, 2), (0, 0))
    with pytest.raises(ValueError, match="aim"):
        normalized_rays(cooke, (0, 1), (0, 0), aim="chief")
    with pytest.raises(ValueError, match="float64"):
        normalized_rays(cooke.to(torch.float32), (0, 1), (0, 0))
