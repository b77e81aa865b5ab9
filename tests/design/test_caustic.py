"""Caustic design (Eq. 11): the irradiance forward model's gradients against central finite
differences (float64), its geometry against Snell's law for a wedge written in closed form, a
short optimisation, and clear errors for bad input."""

import argparse
import json
import math

import numpy as np
import pytest
import torch

import helpers
from deeplens.design.apps import caustic as app
from deeplens.design.caustic import (caustic_lens, collimated_square_rays, irradiance,
                                     load_target, optimize_caustic, sag_map)
from deeplens.optics.io import load_lens
from deeplens.render.sensor import Sensor
from deeplens.render.splat import splat_bilinear

A, D = 2.0, 20.0  # beam half-width and screen distance of the small cases, mm


def test_irradiance_gradient_matches_central_differences():
    """d/dC of a randomly weighted sum of the irradiance, for coefficients under the beam,
    autograd (implicit intersection + Snell + bilinear splat) vs a fourth-order central
    difference.  h = 1e-7 mm moves a ray on the screen by ~1e-6 mm (D x (n - 1) x slope change
    1e-7 / knot spacing 0.7 mm x 20 mm), 1e-5 of a pixel, so no ray crosses a pixel centre
    (where the bilinear weight has a kink) within the stencil."""
    lens = caustic_lens(A, 8, D)
    c = lens.surfaces[1].coefficients
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        c.copy_(0.02 * torch.randn(c.shape, generator=g, dtype=torch.float64))
    rays = collimated_square_rays(A, 24)
    W = torch.rand(12, 12, generator=g, dtype=torch.float64)
    c.requires_grad_(True)
    (irradiance(lens, rays, 12, A) * W).sum().backward()
    grad = c.grad.clone()
    c.requires_grad_(False)
    for idx in [(3, 3), (4, 2), (2, 5), (5, 4)]:
        fd = helpers.central_fd(lambda: (irradiance(lens, rays, 12, A) * W).sum(), c, 1e-7,
                                index=idx)
        assert abs(fd) > 1e-2
        assert helpers.rel_err(grad[idx], fd) < 1e-4, (idx, float(grad[idx]), fd)


def test_wedge_irradiance_matches_snell_closed_form():
    """B-spline coefficients ``C_p = s x_p`` at the basis centres ``x_p = -L + (p - 1) h``
    reproduce the plane ``z = s x`` exactly; the plate is then a prism.  Each ray leaves it at
    ``z = t + s x0`` deviated by ``delta = asin(n sin(atan s)) - atan s`` towards the thick
    side (+x) and lands at ``x0 + (D - s x0) tan(delta)``.  The traced irradiance must equal
    these closed-form landing points splatted on the same grid."""
    s, n_idx, res = 0.09, 1.5, 16
    lens = caustic_lens(A, 10, D)
    bs = lens.surfaces[1]
    L = float(bs.semi_diameter)
    n = bs.coefficients.shape[0]
    h = 2 * L / (n - 3)
    xp = -L + (torch.arange(n, dtype=torch.float64) - 1) * h
    with torch.no_grad():
        bs.coefficients.copy_((s * xp)[:, None].expand(n, n))
    xs = torch.linspace(-A, A, 7, dtype=torch.float64)
    assert torch.allclose(bs.sag(xs, 0.3 * xs), s * xs, atol=1e-12)
    rays = collimated_square_rays(A, res * 3)
    E = irradiance(lens, rays, res, A)
    alpha = math.atan(s)
    delta = math.asin(n_idx * math.sin(alpha)) - alpha
    x0, y0 = rays.o[:, 0], rays.o[:, 1]
    x1 = x0 + (D - s * x0) * math.tan(delta)
    sensor = Sensor((res, res), 2 * A / res, channels=[[532.8]])
    i, j = sensor.xy_to_pixel(x1, y0)
    E_ref = splat_bilinear(i, j, torch.full_like(i, res * res / len(i)), (res, res))
    assert (E - E_ref).abs().max() < 1e-9
    # and the deflection is visible: the light moved by about 3.6 pixels towards -j
    shift_px = D * math.tan(delta) / (2 * A / res)
    assert 3 < shift_px < 4
    assert float(E[:, -3:].sum()) < 1e-9 * res


def test_flat_plate_gives_uniform_irradiance():
    """An undeflected beam reads exactly 1 in every pixel not touching the screen's edge (the
    normalisation of the irradiance)."""
    lens = caustic_lens(A, 6, D)
    E = irradiance(lens, collimated_square_rays(A, 32), 16, A)
    assert torch.allclose(E[1:-1, 1:-1], torch.ones(14, 14, dtype=torch.float64), atol=1e-12)


def test_short_optimisation_reproduces_a_blob():
    """30 Adam steps turn the flat plate's uniform irradiance towards a bright disk."""
    res = 16
    yy, xx = torch.meshgrid(torch.arange(res) + 0.5, torch.arange(res) + 0.5, indexing="ij")
    T = 0.2 + ((yy - 6) ** 2 + (xx - 9) ** 2 < 16).double()
    T = T / T.mean()
    r = optimize_caustic(T, half_width_mm=A, distance_mm=D, n_ctrl=12, rays_per_pixel=2,
                         steps=30, lr_px=1.0, sigma0=2.0, sigma1=0.5, snapshots=(0,))
    E0, E = r["snapshots"][0].double(), r["irradiance"].double()
    err0, err = float(((E0 - T) ** 2).mean()), float(((E - T) ** 2).mean())
    assert err < 0.4 * err0, (err0, err)
    assert r["loss"][-1] < r["loss"][0]
    assert float(sag_map(r["lens"], A, 8).abs().max()) > 1e-4  # the surface did change


def test_target_errors():
    with pytest.raises(ValueError, match=r"--target: 'no_such_image' is not an image bundled"):
        load_target("no_such_image", 16)
    with pytest.raises(ValueError, match=r"--target: 'astronaut' is not a grey image"):
        load_target("astronaut", 16)
    T = load_target("camera", 16, floor=0.1)
    assert T.shape == (16, 16) and float(T.mean()) == pytest.approx(1.0)
    assert float(T.min() / T.max()) == pytest.approx(0.1)


def _args(tmp_path, *argv):
    p = argparse.ArgumentParser()
    p.add_argument("--out")  # added by the ``deeplens design`` command itself
    app.add_arguments(p)
    return p.parse_args([*argv, "--out", str(tmp_path / "out")])


@pytest.mark.parametrize("argv,match", [
    (["--distances", "50,-1"], r"--distances: expected positive distances"),
    (["--distances", "abc"], r"--distances: expected comma-separated numbers"),
    (["--resolution", "4"], r"--resolution must be >= 8"),
    (["--floor", "1.5"], r"--floor must lie in \[0, 1\)"),
    (["--target", "astronaut"], r"--target: 'astronaut' is not a grey image"),
])
def test_app_bad_options(tmp_path, argv, match):
    with pytest.raises(ValueError, match=match):
        app.run(_args(tmp_path, *argv))
    assert not (tmp_path / "out").exists()  # nothing written half-way


def test_app_short_run(tmp_path):
    r = app.run(_args(tmp_path, "--resolution", "12", "--control-points", "10", "--steps", "4",
                      "--distances", "30,60", "--half-width", "2"))
    json.dumps(r)
    assert set(r["ssim"]) == {"30 mm", "60 mm"}
    assert all(-1 <= v <= 1 for v in r["ssim"].values())
    for name in ("caustic_states.png", "caustic_loss.png", "caustic_D30mm.json"):
        assert (tmp_path / "out" / name).stat().st_size > 500
    states = np.load(tmp_path / "out" / "caustic_states.npz")
    assert states["irradiance_D60"].shape == (len(states["steps"]), 12, 12)
    lens = load_lens(tmp_path / "out" / "caustic_D30mm.json")  # a valid lens file
    assert lens.surfaces[1].coefficients.shape == (10, 10)


@pytest.mark.slow
def test_app_default_run(tmp_path):
    r = app.run(_args(tmp_path))
    assert min(r["ssim"].values()) > 0.6, r
