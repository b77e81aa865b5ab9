"""The renderer's lens geometry (exit pupil, image circle, reference weight, cache key)."""

from __future__ import annotations

import warnings

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
    from deeplens.analysis.paraxial import paraxial
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
