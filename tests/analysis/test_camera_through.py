"""Every analysis function that traces takes a :class:`~deeplens.optics.camera.Camera` in place
of the lens (issue 24): the chief ray and pupil search, ray fans, field curvature, distortion,
colour, vignetting, the reports, the polychromatic MTFs, the figures and ``render_image``.

For each: (a) ``f(Camera(lens, options=o))`` is bit for bit ``f(lens, options=o)``; (b) every
trace inside it, the aiming traces included, runs at the camera's options (or their copy
without clear apertures), and the options change the result (so they are not ignored);
(c) a camera with ``options`` beside it is refused."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from camera_checks import assert_traced_at, same, spy_surface_options

from deeplens.analysis import aberrations as A
from deeplens.analysis import mtf_poly as MP
from deeplens.analysis import plot as P
from deeplens.analysis.report import analysis_report, lens_report
from deeplens.analysis.spot import find_pupil, spot_diagram
from deeplens.optics.camera import Camera
from deeplens.optics.chief import chief_ray
from deeplens.optics.io import load_lens
from deeplens.optics.options import TraceOptions
from deeplens.render.image import render_image

LENSES = Path(__file__).resolve().parents[2] / "data" / "lenses"

# Newton from the vertex plane on spheres too, to a coarse tolerance: different low bits
# wherever a ray is traced, so the options are observable
NEWTON = TraceOptions(tol=1e-3, max_iter=25, closed_form=False)
# clear apertures ignored: observable in counts of rays (vignetting, pupil search, images)
FREE = TraceOptions(tol=1e-3, max_iter=25, clip_aperture=False)


@pytest.fixture(scope="module")
def lens():
    return load_lens(LENSES / "double_gauss.json")


F = 10.0
W = 587.6
IMG = torch.rand(3, 6, 8, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

# name -> (call(lens_or_camera, **kw), the options that make a difference)
CASES = {
    "chief_ray": (lambda L, **kw: chief_ray(L, F, W, **kw), NEWTON),
    "find_pupil": (lambda L, **kw: find_pupil(L, F, W, grid=33, bisections=12, **kw), FREE),
    "spot_diagram": (lambda L, **kw: spot_diagram(L, F, W, "hexapolar:4", **kw), FREE),
    "real_chief_ray": (lambda L, **kw: A.real_chief_ray(L, F, W, **kw), NEWTON),
    "ray_fan": (lambda L, **kw: A.ray_fan(L, F, [W, 486.1], n=9, **kw), NEWTON),
    "field_curvature": (lambda L, **kw: A.field_curvature(L, [0.0, F], W, **kw), NEWTON),
    "distortion": (lambda L, **kw: A.distortion(L, [0.0, F], W, **kw), NEWTON),
    "distortion_paraxial_aim": (lambda L, **kw: A.distortion(L, [F], W, aim="paraxial", **kw),
                                NEWTON),
    "chief_heights": (lambda L, **kw: A.chief_heights(L, [5.0, F], W, **kw), NEWTON),
    "lateral_color": (lambda L, **kw: A.lateral_color(L, [F], [486.1, 656.3], **kw), NEWTON),
    "vignetting": (lambda L, **kw: A.vignetting(L, [0.0, 14.0], W, n=11, **kw), FREE),
    "lens_report": (lambda L, **kw: lens_report(L, [F], [W], "hexapolar:3", **kw), NEWTON),
    "analysis_report": (lambda L, **kw: analysis_report(
        L, ["distortion", "field", "color", "vignetting"], [F], [W, 656.3], **kw), NEWTON),
    "polychromatic_mtf": (lambda L, **kw: MP.polychromatic_mtf(L, 0.0, [10.0, 40.0], [W], n=32,
                                                               **kw), NEWTON),
    "through_focus_mtf": (lambda L, **kw: MP.through_focus_mtf(L, 0.0, [20.0], [0.0, 0.01], [W],
                                                               n=32, **kw), NEWTON),
    "mtf_vs_field": (lambda L, **kw: MP.mtf_vs_field(L, [0.0], [20.0], [W], n=32, **kw), NEWTON),
    "layout_figure": (lambda L, **kw: P.layout_figure(L, [0.0, F], n_rays=3, **kw), NEWTON),
    "spot_figure": (lambda L, **kw: P.spot_figure(L, [F], [W], "hexapolar:3", **kw), NEWTON),
    "fan_figure": (lambda L, **kw: P.fan_figure(L, [F], [W], n=9, **kw), NEWTON),
    "distortion_figure": (lambda L, **kw: P.distortion_figure(L, [F], [W], **kw), NEWTON),
    "render_image": (lambda L, **kw: render_image(L, IMG, 5000.0, pixel_size_mm=0.004, spp=2,
                                                  **kw), FREE),
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_camera_traces_every_ray_at_its_options(name, lens, monkeypatch):
    call, opts = CASES[name]
    ref = call(lens, options=opts)
    seen = spy_surface_options(monkeypatch)
    got = call(Camera(lens, options=opts))
    assert_traced_at(seen, opts)
    monkeypatch.undo()
    assert same(got, ref)                        # (a) the lens call with the same options
    assert same(call(Camera(lens)), call(lens))  # the default camera is the plain lens call
    assert not same(got, call(lens))             # (b) the options change the result


@pytest.mark.parametrize("name", list(CASES))
def test_options_beside_a_camera_are_refused(name, lens):
    call, _ = CASES[name]
    with pytest.raises(ValueError, match="options given beside a Camera"):
        call(Camera(lens, options=NEWTON), options=TraceOptions())


def test_longitudinal_colour_is_paraxial_and_takes_a_camera(lens, monkeypatch):
    seen = spy_surface_options(monkeypatch)
    got = A.longitudinal_color(Camera(lens, options=NEWTON), [486.1, 656.3])
    assert not seen  # paraxial: no ray is traced
    assert same(got, A.longitudinal_color(lens, [486.1, 656.3]))


def test_the_paraxial_functions_take_a_camera_and_the_primary_wavelength(lens):
    """One calling form (issue 39, item 6): the cardinal-point functions take a camera like the
    tracing ones, and the functions whose wavelength was required (the pupil search, the spot,
    the real chief ray) default to the lens's primary wavelength like the rest."""
    from deeplens.analysis import cardinal as C

    cam = Camera(lens, options=NEWTON)
    for f in (C.system_matrix, C.cardinal_points, C.pupils):
        assert same(f(cam), f(lens))
    assert same(C.magnification(cam, object_distance_mm=500.0),
                C.magnification(lens, object_distance_mm=500.0))
    w = float(lens.spec.primary_wavelength_nm)
    assert same(find_pupil(lens, F, grid=33, bisections=12),
                find_pupil(lens, F, w, grid=33, bisections=12))
    assert same(spot_diagram(lens, F, sampling="hexapolar:4"),
                spot_diagram(lens, F, w, "hexapolar:4"))
    assert same(A.real_chief_ray(lens, F), A.real_chief_ray(lens, F, w))
