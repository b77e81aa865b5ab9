"""Openings as objects (:mod:`deeplens.optics.openings`): the primitives and their compositions
against their closed forms written here, each surface type's opening against the clear-aperture
rule of its lens-file fields (written here in numpy), an opening assigned to a surface (also a
new kind of opening, defined in this file) clipping the eager trace, and the fused kernels'
clip (``kernel_clip``) used only for a centred circle or rectangle."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.openings import (Circle, Difference, Everywhere, Intersection, Opening,
                                      Rectangle, annulus)
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture, Asphere, CoordinateBreak, Cylinder, Plane
from deeplens.optics.tracer import fused_kind

F64 = torch.float64


def _grid(n=81, half=6.0):
    t = torch.linspace(-half, half, n, dtype=F64)
    X, Y = torch.meshgrid(t, t, indexing="ij")
    return X.reshape(-1), Y.reshape(-1)


def test_primitives_and_compositions_against_closed_forms():
    X, Y = _grid()
    x, y = X.numpy(), Y.numpy()
    circ = Circle(torch.tensor(4.0), (1.0, -0.5))
    assert torch.equal(circ.contains(X, Y),
                       torch.from_numpy((x - 1.0) ** 2 + (y + 0.5) ** 2 <= 16.0))
    rect = Rectangle((2.0, 3.0), (0.5, 0.0))
    assert torch.equal(rect.contains(X, Y),
                       torch.from_numpy((np.abs(x - 0.5) <= 2.0) & (np.abs(y) <= 3.0)))
    ring = Circle(4.0) - Circle(1.5)   # an annulus: the inner boundary passes
    r2 = x * x + y * y
    assert torch.equal(ring.contains(X, Y), torch.from_numpy((r2 <= 16.0) & (r2 >= 2.25)))
    assert torch.equal(annulus(4.0, 1.5).contains(X, Y), ring.contains(X, Y))
    both = Circle(4.0) & Rectangle((5.0, 2.0))
    assert isinstance(both, Intersection)
    assert torch.equal(both.contains(X, Y),
                       torch.from_numpy((r2 <= 16.0) & (np.abs(x) <= 5.0) & (np.abs(y) <= 2.0)))
    assert bool(Everywhere().contains(X, Y).all())
    # a difference of a difference: a ring with a square hole cut from its right side
    cut = ring - Rectangle((0.5, 0.5), (3.0, 0.0))
    expect = (r2 <= 16.0) & (r2 >= 2.25) & ~((np.abs(x - 3.0) < 0.5) & (np.abs(y) < 0.5))
    assert torch.equal(cut.contains(X, Y), torch.from_numpy(expect))


def test_kernel_clip_only_for_one_centred_circle_or_rectangle():
    r = torch.tensor(3.0, dtype=F64)
    assert Circle(r).kernel_clip == ("circle", r)
    assert Rectangle((1.0, 2.0)).kernel_clip[0] == "rect"
    assert Circle(r, (0.0, 0.0)).kernel_clip is not None   # a zero decenter is none
    for opening in (Circle(r, (0.1, 0.0)), Rectangle((1.0, 2.0), (0.0, 1.0)),
                    Circle(r) - Circle(1.0), Circle(r) & Rectangle((1.0, 1.0)), Everywhere()):
        assert opening.kernel_clip is None
    assert (Circle(r) - Circle(1.0)).outer.kind == "circle"
    assert Intersection(Circle(5.0), Circle(2.0, (1.0, 1.0))).bounds() == ((1.0, 1.0), 2.0)


@pytest.mark.parametrize("bad, match", [
    (lambda: Circle(-1.0), "radius must be > 0"),
    (lambda: Rectangle((1.0, 0.0)), "half-widths must be > 0"),
    (lambda: Circle(1.0, (math.nan, 0.0)), "decenter must be two finite"),
    (lambda: Rectangle((1.0, 2.0, 3.0)), "shape"),
])
def test_bad_openings_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        bad()


def test_each_surface_type_opening_is_its_lens_file_rule():
    """The openings built from the lens-file fields: an asphere's semi-diameter, obscuration,
    decentred clear circle and rectangle; an aperture's decentred annulus and rectangle; a
    cylinder's rectangle; a coordinate break lets everything through."""
    X, Y = _grid(121, 7.0)
    x, y = X.numpy(), Y.numpy()
    r2 = x * x + y * y
    oap = Asphere(0.0, 6.0, obscuration=0.5, clear_radius=2.5, clear_decenter=(2.0, 1.0),
                  clear_rect=(1.5, 2.0))
    u, v = x - 2.0, y - 1.0
    expect = (r2 <= 36.0) & (r2 >= 0.25) & (u * u + v * v <= 6.25) & (np.abs(u) <= 1.5) \
        & (np.abs(v) <= 2.0)
    assert torch.equal(oap.in_aperture(X, Y), torch.from_numpy(expect))
    ap = Aperture(4.0, obscuration=1.0, decenter=(0.5, -1.0))
    u, v = x - 0.5, y + 1.0
    assert torch.equal(ap.in_aperture(X, Y),
                       torch.from_numpy((u * u + v * v <= 16.0) & (u * u + v * v >= 1.0)))
    rect = Aperture(shape="rect", half_width_x=3.0, half_width_y=1.0)
    assert torch.equal(rect.in_aperture(X, Y),
                       torch.from_numpy((np.abs(x) <= 3.0) & (np.abs(y) <= 1.0)))
    cyl = Cylinder(0.01, 5.0, half_widths=(4.0, 3.0))
    assert torch.equal(cyl.in_aperture(X, Y),
                       torch.from_numpy((np.abs(x) <= 4.0) & (np.abs(y) <= 3.0)))
    assert bool(CoordinateBreak(tilt_x=0.1).in_aperture(X, Y).all())
    # the lens-file fields stay buffers under their names (state_dict, checkpoints)
    assert {"obscuration", "semi_diameter"} <= set(oap.state_dict())
    assert {"obscuration", "decenter", "half_widths"} <= set(ap.state_dict())


class Ellipse(Opening):
    """A new kind of opening in one class: ``(x/a)^2 + (y/b)^2 <= 1``."""

    kind = "ellipse"

    def __init__(self, a, b):
        self.a, self.b = a, b

    def contains(self, x, y):
        return (x / self.a) ** 2 + (y / self.b) ** 2 <= 1.0

    def outside(self, x, y):
        return (x / self.a) ** 2 + (y / self.b) ** 2 >= 1.0

    def bounds(self):
        return (0.0, 0.0), max(self.a, self.b)


def _singlet():
    glass = ModelGlass(1.5168, 64.17)
    air = Air()
    return Lens([Aperture(5.0), Asphere(1 / 30, 6.0), Plane(6.0)], [air, air, glass, air],
                [0.0, 1.0, 4.0], 50.0, 0)


def _parallel_rays(n=41, half=5.5):
    t = torch.linspace(-half, half, n, dtype=F64)
    X, Y = torch.meshgrid(t, t, indexing="ij")
    o = torch.stack([X.reshape(-1), Y.reshape(-1), torch.full((n * n,), -1.0, dtype=F64)], -1)
    d = torch.zeros_like(o)
    d[:, 2] = 1.0
    return Rays(o, d, torch.full((n * n,), 587.56, dtype=F64))


def test_an_assigned_opening_clips_the_trace_and_runs_eager():
    lens = _singlet()
    assert [fused_kind(lens, i) for i in range(3)] == ["stop", "quadric", "plane"]
    lens.surfaces[1].opening = Ellipse(3.0, 1.5)
    assert fused_kind(lens, 1) is None and not lens.surfaces[1].closed_form
    rays = _parallel_rays()
    out = lens.trace(rays)
    x, y = rays.o[:, 0], rays.o[:, 1]
    # parallel rays hit the front surface at their own (x, y): the ellipse decides
    assert torch.equal(out.valid, (x / 3.0) ** 2 + (y / 1.5) ** 2 <= 1.0)
    with pytest.raises(TypeError, match="expected an Opening"):
        lens.surfaces[1].opening = 3.0


def test_an_assigned_centred_circle_is_the_fused_clip():
    """A centred circle narrower than the semi-diameter: the surface stays fused, and the
    kernels clip by the opening's radius (the closed-form quadric step on the eager path too)."""
    lens = _singlet()
    lens.surfaces[1].opening = Circle(torch.tensor(2.0, dtype=F64))
    assert fused_kind(lens, 1) == "quadric" and lens.surfaces[1].closed_form
    assert float(lens.surfaces[1].fused_values(torch.zeros((), dtype=F64))[2]) == 2.0
    rays = _parallel_rays()
    out = lens.trace(rays)
    r2 = rays.o[:, 0] ** 2 + rays.o[:, 1] ** 2
    assert torch.equal(out.valid, r2 <= 4.0)


def test_difference_is_a_difference_class():
    assert isinstance(Circle(2.0) - Circle(1.0), Difference)
