"""The design engine through a :class:`~deeplens.optics.camera.Camera` (issue 24): the merit
terms, ``optimize_lens``, the sensitivity and Monte Carlo functions, quick focus and the
centring probe take a camera in place of the lens.

For each: a default camera gives bit for bit the plain lens call (and, where the function takes
``options``, a camera with options the lens call with the same options); every surface step
inside it (pupil search, chief-ray aiming, the merit's rays, each optimiser evaluation) runs at
the camera's options (or their copy without clear apertures); and those options change the
result, so they are not ignored."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch

from camera_checks import assert_traced_at, same, spy_surface_options

from deeplens.design.caustic import caustic_lens, collimated_square_rays, irradiance
from deeplens.design.constraints import ConstraintSet, parse_constraint
from deeplens.design.depth_invariance import DepthInvarianceMerit
from deeplens.design.focus import quick_focus_shift
from deeplens.design.lensopt import optimize_lens
from deeplens.design.merit import DistortionMerit, Merit, SpotMerit, TargetMerit
from deeplens.design.sensitivity import (finite_difference_matrix, rss_estimate,
                                         sensitivity_matrix)
from deeplens.design.tolerance import monte_carlo
from deeplens.optics.tolerance_model import ToleranceModel, axis_image
from deeplens.design.variables import Variables, on_camera
from deeplens.optics.camera import Camera
from deeplens.optics.io import load_lens
from deeplens.optics.options import TraceOptions

LENSES = Path(__file__).resolve().parents[2] / "data" / "lenses"
W = 587.6
NAMES = ["distances.2", "surfaces.1.c"]
# Newton from the vertex plane on spheres too, to a coarse tolerance: observable low bits
NEWTON = TraceOptions(tol=1e-3, max_iter=25, closed_form=False)


@pytest.fixture(scope="module")
def lens():
    return load_lens(LENSES / "double_gauss.json")


def _spot(L):
    return SpotMerit([0.0, 10.0], [W], sampling="hexapolar:3", reference="chief").prepare(L)


def _own(L):
    """A copy of the lens (or camera: a camera of the copy with the same options object), for
    calls that move the lens."""
    if isinstance(L, Camera):
        return Camera(copy.deepcopy(L.lens), options=L.options)
    return copy.deepcopy(L)


def _optimise(L):
    L = _own(L)
    target = L.lens if isinstance(L, Camera) else L
    cons = parse_constraint(target, "max_track=200")
    res = optimize_lens(L, Variables(L, "d_sensor"), Merit(_spot(L)), steps=2,
                        constraints=cons)
    return res.merit_before, res.merit_after, res.variables_after


def _monte_carlo(L):
    m = _spot(L)
    r = monte_carlo(L, m, NAMES, [0.01, 1e-5], n=2, seed=3)
    return r["nominal_um"], r["samples_um"]


def _monte_carlo_drawn(L):
    """Draws of a tolerance group with the centring compensator (its traces run at the
    camera's options too)."""
    model = ToleranceModel({"decenter": {"shape": "normal", "std": 0.01, "truncate": 2},
                            "compensator": "center"})
    r = monte_carlo(L, _spot(L), [], [], n=2, seed=3, model=model)
    return r["nominal_um"], r["samples_um"]


CASES = {
    "SpotMerit": lambda L: (lambda m: (m.residuals(L), m.rms(L)))(_spot(L)),
    "DistortionMerit": lambda L: DistortionMerit([10.0]).prepare(L).residuals(L),
    "Merit": lambda L: Merit(DistortionMerit([10.0]), TargetMerit("efl", 100.0),
                             ConstraintSet(parse_constraint(unwrap(L), "max_track=200"))
                             ).prepare(L)(L),
    "DepthInvarianceMerit": lambda L: DepthInvarianceMerit(
        [3000.0, 8000.0], [W], 0.0069, sampling="grid:8", n_freq=2).prepare(L).residuals(L),
    "optimize_lens": _optimise,
    "sensitivity_matrix": lambda L: sensitivity_matrix(L, _spot(L), NAMES),
    "finite_difference_matrix": lambda L: finite_difference_matrix(L, _spot(L), NAMES),
    "rss_estimate": lambda L: rss_estimate(L, _spot(L), NAMES, [0.01, 1e-5]),
    "monte_carlo": _monte_carlo,
    "monte_carlo_drawn": _monte_carlo_drawn,
    "quick_focus_shift": lambda L, **kw: quick_focus_shift(L, [0.0, 10.0], [W], **kw),
    "axis_image": lambda L, **kw: axis_image(L, **kw),
}
WITH_OPTIONS = ("quick_focus_shift", "axis_image")


def unwrap(L):
    return L.lens if isinstance(L, Camera) else L


@pytest.mark.parametrize("name", list(CASES))
def test_the_design_engine_traces_at_the_cameras_options(name, lens, monkeypatch):
    call = CASES[name]
    opts = NEWTON
    seen = spy_surface_options(monkeypatch)
    got = call(Camera(lens, options=opts))
    assert_traced_at(seen, opts)
    monkeypatch.undo()
    plain = call(lens)
    assert same(call(Camera(lens)), plain)  # a default camera is the plain lens call
    assert not same(got, plain)             # the camera's options change the result
    if name in WITH_OPTIONS:
        assert same(got, call(lens, options=opts))
        with pytest.raises(ValueError, match="options given beside a Camera"):
            call(Camera(lens, options=opts), options=TraceOptions())


def test_on_camera_keeps_the_camera_of_its_own_lens(lens):
    cam = Camera(lens, options=NEWTON)
    assert on_camera(None, lens) is lens and on_camera(cam, lens) is cam
    other = copy.deepcopy(lens)
    view = on_camera(cam, other)
    assert view.lens is other and view.options is cam.options


def test_optimize_lens_refuses_variables_of_another_lens(lens):
    cam = Camera(copy.deepcopy(lens))
    with pytest.raises(ValueError, match="variables belong to another lens"):
        optimize_lens(cam, Variables(copy.deepcopy(lens), "d_sensor"),
                      Merit(TargetMerit("efl", 100.0)), steps=1)


def test_variables_of_a_camera_are_its_lens_parameters(lens):
    cam = Camera(lens)
    v = Variables(cam, "d_sensor")
    assert v.lens is lens and torch.equal(v.x0(), Variables(lens, "d_sensor").x0())


def test_caustic_irradiance_through_a_camera(monkeypatch):
    # a beam wider than the plate's clear aperture: its corners pass only when apertures are
    # ignored, so the camera's options show in the irradiance
    L = caustic_lens(5.0, 6, 50.0).to(torch.float64)
    rays = collimated_square_rays(7.0, 24)
    free = TraceOptions(clip_aperture=False)
    ref = irradiance(L, rays, 16, 7.0, options=free)
    seen = spy_surface_options(monkeypatch)
    got = irradiance(Camera(L, options=free), rays, 16, 7.0)
    assert seen and all(o is free for o in seen)
    monkeypatch.undo()
    assert torch.equal(got, ref)
    plain = irradiance(L, rays, 16, 7.0)
    assert torch.equal(irradiance(Camera(L), rays, 16, 7.0), plain)
    assert float(got.sum()) > float(plain.sum())
    with pytest.raises(ValueError, match="options given beside a Camera"):
        irradiance(Camera(L, options=free), rays, 16, 7.0, options=TraceOptions())
