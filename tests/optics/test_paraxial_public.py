"""The paraxial module's public ray helpers (`media_indices`, `trace_paraxial_ray`), which the
Zemax reader and writer use, against closed forms: a singlet's EFL by the lensmaker's equation
and a concave mirror's focus at R / 2, travelling back along -z."""
from __future__ import annotations

import pytest
import torch

from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, get_material
from deeplens.optics.paraxial import media_indices, paraxial, trace_paraxial_ray
from deeplens.optics.surfaces import Aperture, Asphere

F64 = torch.float64


def singlet(r1=50.0, r2=-80.0, t=5.0):
    glass = get_material("N-BK7")
    return Lens([Asphere(1.0 / r1, 10.0), Asphere(1.0 / r2, 10.0)], [Air(), glass, Air()],
                [0.0, t], 60.0, 0).to(F64), glass


def test_singlet_focal_length_is_the_lensmakers():
    lens, glass = singlet()
    n = media_indices(lens, 587.56)
    ng = float(glass.n(torch.tensor(587.56, dtype=F64)))
    assert n.dtype == F64 and n.shape == (3,)
    assert torch.allclose(n, torch.tensor([1.0, ng, 1.0], dtype=F64))
    one = torch.ones((), dtype=F64)
    y, u, heights = trace_paraxial_ray(lens, one, 0 * one, n)
    c1, c2, t = 1 / 50.0, -1 / 80.0, 5.0
    power = (ng - 1) * (c1 - c2 + (ng - 1) * t * c1 * c2 / ng)   # thick-lens lensmaker
    assert float(-1 / u) == pytest.approx(1 / power, rel=1e-12)
    assert float(heights[0]) == 1.0 and len(heights) == 2
    assert float(-1 / u) == pytest.approx(float(paraxial(lens, 587.56).efl), rel=1e-14)


def test_mirror_media_are_signed_and_focus_at_half_the_radius():
    R = -1000.0
    air = Air()
    lens = Lens([Aperture(60.0), Asphere(1.0 / R, 60.0, conic=-1.0)], [air, air, air],
                [0.0, 10.0], R / 2, 0, mirrors=[1]).to(F64)
    n = media_indices(lens)
    assert n.tolist() == [1.0, 1.0, -1.0]   # after the mirror the light travels along -z
    one = torch.ones((), dtype=F64)
    y, u, _ = trace_paraxial_ray(lens, one, 0 * one, n)
    assert float(-y / u) == pytest.approx(R / 2, rel=1e-12)   # the focus, R / 2 from the vertex
