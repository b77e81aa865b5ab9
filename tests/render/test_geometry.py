"""The renderer's lens geometry (exit pupil, image circle, reference weight, cache key)."""

from __future__ import annotations

import warnings

import pytest
import torch

from deeplens.optics.lens import Lens
from deeplens.optics.materials import get_material
from deeplens.optics.surfaces import Aperture, Asphere
from deeplens.render import MonteCarloRenderer, Scene, Sensor


def asphere_singlet():
    """A stop 2 mm before a biconvex N-BK7 even asphere, f ~ 50 mm."""
    return Lens([Aperture(4.0), Asphere(1 / 50.0, 8.0, coefficients=[1e-6]),
                 Asphere(-1 / 50.0, 8.0)],
                [get_material(m) for m in ("AIR", "AIR", "N-BK7", "AIR")], [0.0, 2.0, 5.0],
                48.0, 0)


def test_trainable_lens_renders_and_analyses_without_tensor_to_scalar_warnings():
    """Regression (issue 12, defect 7): every render with a trainable asphere printed
    "Converting a tensor with requires_grad=True to a scalar" (the geometry cache key called
    ``repr(lens)``, whose ``extra_repr`` read trainable tensors as floats).  Rendering (plain
    and adjoint), printing the lens, PSFs and the analysis functions must not warn."""
    from deeplens.optics.paraxial import paraxial
    from deeplens.analysis.report import lens_report
    from deeplens.analysis.spot import chief_ray, spot_diagram
    from deeplens.render.psf import psf

    lens = asphere_singlet()
    for p in lens.parameters():
        p.requires_grad_(True)
    sensor = Sensor((8, 8), 0.05)
    scene = Scene(torch.ones(1, 3, 8, 8, dtype=torch.float64), 1000.0)
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*requires_grad=True to a scalar")
        for adjoint in (False, True):
            img = MonteCarloRenderer(lens, sensor, spp=2, adjoint=adjoint)(scene, seed=1)
            img.sum().backward()
        repr(lens)
        paraxial(lens)
        spot_diagram(lens, 0.0, 587.5618, "hexapolar:2", pupil="paraxial")
        chief_ray(lens, 1.0, 587.5618)
        psf(lens, sensor, (0.0, 0.0), 1000.0, 587.5618, n_rays=64)
        lens_report(lens, fields_deg=[1.0], wavelengths_nm=[587.5618], sampling="hexapolar:2",
                    pupil="paraxial")


def _ideal(f=50.0, stop_sd=5.0):
    from deeplens.optics.surfaces import IdealLens

    return Lens([Aperture(stop_sd), IdealLens(f, 3 * stop_sd)],
                [get_material("AIR") for _ in range(3)], [0.0, 1.0], f, 0)


def test_reference_weight_matches_the_closed_form_for_an_ideal_lens():
    """``w̄_0 = mean |d_z|^4`` over a disk of radius R at distance L from the sensor centre is
    ``L^2 / (L^2 + R^2)`` (integrate 2ρ L^4 / (L^2 + ρ^2)^2 over the disk); inside the exit pupil
    of an ideal lens no ray is vignetted."""
    from deeplens.render.geometry import exit_pupil, reference_weight

    lens = _ideal()
    z_xp, r_xp = (float(v) for v in exit_pupil(lens))
    R = 0.9 * r_xp
    L = float(lens.z_sensor()) - z_xp
    w = reference_weight(lens, z_xp, R, 587.5618)
    assert w == pytest.approx(L * L / (L * L + R * R), rel=5e-4)


def test_geometry_is_a_frozen_record_that_the_renderer_caches_and_plans_share():
    import dataclasses

    from deeplens.render.geometry import LensGeometry, measure_geometry

    lens = _ideal()
    sensor = Sensor((8, 8), 0.05)
    r = MonteCarloRenderer(lens, sensor, spp=2)
    scene = Scene(torch.ones(1, 3, 8, 8, dtype=torch.float64), 1000.0)
    plan = r.plan(scene, seed=3)
    geo = plan.geometry
    assert isinstance(geo, LensGeometry) and r.plan(scene, seed=4).geometry is geo  # cached
    with pytest.raises(dataclasses.FrozenInstanceError):
        geo.z_xp = 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.seed = 5
    other = plan.with_seed(9)
    assert other.seed == 9 and other.geometry is geo and plan.seed == 3
    fresh = measure_geometry(lens, sensor, plan.jobs, options=r.options,
                             pupil_margin=r.pupil_margin, vignetting=True)
    assert (fresh.z_xp, fresh.r_xp, fresh.w_ref, fresh.image_circle_mm) == \
        (geo.z_xp, geo.r_xp, geo.w_ref, geo.image_circle_mm)
    assert torch.equal(fresh.pixels, geo.pixels) and len(geo.w_ref) == 3


def test_a_large_pupil_margin_does_not_lose_the_image_circle():
    """Regression (issue 25, item 12): with ``pupil_margin=10`` 99 % of the aiming disk is dark
    and all 64 probe rays per radius missed the light: every pixel was culled (a black image)
    and the warning blamed the sensor size.  Half the probes now aim inside the paraxial exit
    pupil; the image circle and the image do not depend on the margin."""
    lens = asphere_singlet()
    sensor = Sensor((8, 8), 0.05)
    scene = Scene(torch.ones(1, 1, 8, 8, dtype=torch.float64), 1000.0)
    means = {}
    for margin in (1.05, 10.0):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            r = MonteCarloRenderer(lens, sensor, spp=512, pupil_margin=margin, adjoint=False)
            img = r(scene, seed=1)
        assert r.image_circle_mm == pytest.approx(sensor.half_diagonal_mm)
        means[margin] = float(img.mean())
    assert means[10.0] == pytest.approx(means[1.05], rel=0.15)
