"""A new surface type is one file (issue 39): a toy paraboloid written and registered here only,
traced (against the even asphere with ``k = -1``, the same sag), written to and read from a lens
file, scaled (:func:`~deeplens.optics.parameters.parameter_scale`); a second toy that declares the
compiled Newton kernels runs the fused path (plain Python kernels in the default suite, inductor's
in a ``slow`` test) and agrees with eager; and a new law (a beam dump) as one
:class:`~deeplens.optics.interactions.Interaction` subclass.  The registration is undone
after each test (the registry is read by other tests)."""

from __future__ import annotations

import pytest
import torch

from deeplens.optics.interactions import Interaction
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.options import TraceOptions
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


# ------------------------------------------------- a toy type that joins the compiled path
def _paraboloid_f(x, y, z, c):
    """``(f, f_x, f_y, f_z)`` of ``f = c r^2 / 2 - z``: the one function the toy's eager
    methods and its compiled kernel both call."""
    return 0.5 * c * (x * x + y * y) - z, c * x, c * y, -torch.ones_like(z)


@pytest.fixture
def fused_toy():
    """A toy paraboloid that declares the compiled Newton kernels (``fused_geometry =
    "newton"``, :meth:`~deeplens.optics.surfaces.Surface.kernel_values` and the static
    ``kernel_*``), registered as ``"toy_fused_paraboloid"`` for the test only."""
    before = dict(SURFACE_TYPES)

    @register_surface("toy_fused_paraboloid")
    class FusedParaboloid(SagSurface):
        """``z = c r^2 / 2`` (mm), ``c`` in 1/mm, with compiled Newton kernels."""

        fused_geometry = "newton"

        def __init__(self, curvature, semi_diameter):
            super().__init__(semi_diameter)
            self.c = make_param(curvature, "curvature")

        def sag(self, x, y):
            return _paraboloid_f(x, y, torch.zeros_like(x), self.c.to(x))[0]

        def sag_grad(self, x, y):
            return _paraboloid_f(x, y, torch.zeros_like(x), self.c.to(x))[1:3]

        def paraxial_curvature(self):
            return self.c

        def kernel_values(self, like):
            return (self.c.to(like),)

        @staticmethod
        def kernel_f(x, y, z, values):
            return _paraboloid_f(x, y, z, values[0])

        @staticmethod
        def kernel_in_domain(x, y, values):
            return torch.ones_like(x, dtype=torch.bool)

        @staticmethod
        def kernel_start(bx, by, bz, dx, dy, dz, ok, values, root_fn):
            return torch.zeros_like(bz)   # Newton from the vertex plane

    yield FusedParaboloid
    SURFACE_TYPES.clear()
    SURFACE_TYPES.update(before)


def _fused_vs_eager(lens, compile_mode, grads):
    """Trace ``lens`` eager and with ``compile=compile_mode``; return the two outputs and, with
    ``grads``, the gradients of a loss of positions, directions and path lengths w.r.t. the
    toy's ``c`` and the glass thickness."""
    params = [lens.surfaces[1].c, lens.distances[1]]
    for p in params:
        p.requires_grad_(grads)
    rays = _rays()
    out = []
    for opt in (TraceOptions(compile=False), TraceOptions(compile=compile_mode)):
        with torch.set_grad_enabled(grads):
            r = lens.trace_to_sensor(rays, options=opt)
        g = None
        if grads:
            v = r.valid
            loss = r.o[v].sum() + (r.d[v] * torch.tensor([1.0, 2.0, 3.0], dtype=F64)).sum() \
                + r.opl[v].sum()
            g = torch.autograd.grad(loss, params)
        out.append((r, g))
    return out


def _assert_agree(eager, fused, tol, gtol=None):
    (a, ga), (b, gb) = eager, fused
    assert torch.equal(a.valid, b.valid)
    assert 0 < int(a.valid.sum()) < len(a.valid)   # vignetted rays too
    v = a.valid
    for x, y in ((a.o, b.o), (a.d, b.d), (a.opl, b.opl)):
        assert float((x - y).detach()[v].abs().max()) < tol
    if ga is not None:
        for x, y in zip(ga, gb):
            assert float(x) != 0.0
            assert abs(float(x - y)) < gtol * max(1.0, abs(float(x)))


def test_a_toy_type_with_kernels_runs_fused(fused_toy, uncompiled, monkeypatch):
    """The toy declares the Newton kernels: it runs through :func:`~deeplens.optics.tracer.
    newton_compiled` (the plain Python kernels in place of the compiled ones, ``uncompiled``),
    and its values and gradients agree with the eager tracer's in float64 (the same Newton
    iterations and final differentiable step: equal to rounding, a few ulp of ~100 mm, as
    :mod:`tests.optics.test_compiled` asks of the built-in types)."""
    import deeplens.optics.compiled as C

    lens = _lens(fused_toy(1 / 40, 5.0))
    assert fused_kind(lens, 1) == "newton"
    calls = []
    plain = C.compiled_newton_refract
    monkeypatch.setattr(C, "compiled_newton_refract",
                        lambda kind, *a, **k: (calls.append(kind), plain(kind, *a, **k))[1])
    eager, fused = _fused_vs_eager(lens, "surface", grads=True)
    assert calls and all(k is fused_toy for k in calls)
    _assert_agree(eager, fused, 1e-12, 1e-10)


@pytest.mark.slow
def test_a_toy_type_with_kernels_compiles(fused_toy):
    """The same through the real inductor kernels (C++ on CPU), float64, forward and
    gradients."""
    lens = _lens(fused_toy(1 / 40, 5.0))
    eager, fused = _fused_vs_eager(lens, "surface", grads=True)
    _assert_agree(eager, fused, 1e-12, 1e-10)
