"""A new surface type is one file (issue 39): a toy paraboloid written and registered here only,
traced (against the even asphere with ``k = -1``, the same sag), written to and read from a lens
file, scaled (:func:`~deeplens.optics.parameters.parameter_scale`), and a new law (a beam dump)
as one :class:`~deeplens.optics.interactions.Interaction` subclass.  The registration is undone
after each test (the registry is read by other tests)."""

from __future__ import annotations

import pytest
import torch

from deeplens.optics.interactions import Interaction
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.parameters import parameter_scale
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import SURFACE_TYPES, Aperture, Asphere, Plane, SagSurface
from deeplens.optics.surfaces.base import make_param, register_surface
from deeplens.optics.tracer import fused_kind

F64 = torch.float64


@pytest.fixture
def toy():
    """The toy type, registered as ``"toy_paraboloid"`` for the test only."""
    before = dict(SURFACE_TYPES)

    @register_surface("toy_paraboloid")
    class Paraboloid(SagSurface):
        """``z = c r^2 / 2`` (mm), ``c`` in 1/mm."""

        file_fields = ("curvature_per_mm",)

        def __init__(self, curvature, semi_diameter):
            super().__init__(semi_diameter)
            self.c = make_param(curvature, "curvature")

        def sag(self, x, y):
            return 0.5 * self.c.to(x) * (x * x + y * y)

        def sag_grad(self, x, y):
            c = self.c.to(x)
            return c * x, c * y

        def paraxial_curvature(self):
            return self.c

        def sag_scale(self, name):
            return float(self.semi_diameter) ** 2 / 2 if name == "c" else 1.0

        @classmethod
        def from_dict(cls, entry, semi_diameter):
            return cls(entry.get("curvature_per_mm"), semi_diameter)

        def to_dict(self):
            return {**super().to_dict(), "curvature_per_mm": float(self.c)}

    yield Paraboloid
    SURFACE_TYPES.clear()
    SURFACE_TYPES.update(before)


def _lens(front):
    air, glass = Air(), ModelGlass(1.5168, 64.17)
    return Lens([Aperture(4.0), front, Plane(5.0)], [air, air, glass, air], [0.0, 1.0, 4.0],
                60.0, 0)


def _rays(n=15):
    t = torch.linspace(-3.5, 3.5, n, dtype=F64)
    X, Y = torch.meshgrid(t, t, indexing="ij")
    o = torch.stack([X.reshape(-1), Y.reshape(-1), torch.full((n * n,), -1.0, dtype=F64)], -1)
    d = torch.tensor([0.0, 0.05, 1.0], dtype=F64).expand_as(o)
    return Rays(o, d / torch.linalg.vector_norm(d, dim=-1, keepdim=True),
                torch.full((n * n,), 587.56, dtype=F64))


def test_a_toy_type_traces_reads_writes_and_scales(toy):
    lens = _lens(toy(1 / 40, 5.0))
    ref = _lens(Asphere(1 / 40, 5.0, conic=-1.0))   # the same sag: a paraboloid
    assert fused_kind(lens, 1) is None   # no compiled geometry declared: eager
    rays = _rays()
    out, want = lens.trace_to_sensor(rays), ref.trace_to_sensor(rays)
    assert torch.equal(out.valid, want.valid) and bool(out.valid.any())
    # Newton (tolerance 1e-10 mm in float64) against the closed-form conic
    assert float((out.o - want.o)[out.valid].abs().max()) < 1e-9
    d = lens_to_dict(lens)
    assert d["surfaces"][1]["type"] == "toy_paraboloid"
    back = lens_from_dict(d)
    assert type(back.surfaces[1]) is toy and float(back.surfaces[1].c) == 1 / 40
    assert parameter_scale(lens, "surfaces.1.c") == 12.5


class BeamDump(Interaction):
    """A new law in one class: every ray that lands on the surface stops."""

    name = "dump"
    reflects = False

    def __call__(self, surface, x, d, n1, n2, wavelength, valid, opl, mirror):
        return d, torch.zeros_like(valid), opl


def test_a_new_law_is_one_class():
    lens = _lens(Asphere(1 / 40, 5.0))
    assert bool(lens.trace(_rays()).valid.any())
    lens.surfaces[2].interaction = BeamDump()
    assert lens.surfaces[2].law == "dump" and fused_kind(lens, 2) is None
    assert not bool(lens.trace(_rays()).valid.any())
