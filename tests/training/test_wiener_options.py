"""One trace setting for a training step (issue 24): the renderer's ``TraceOptions``
(``render.compile``, ``render.newton_tol``, ``render.max_iter``) reach the Wiener filter's PSF
traces too (before, the filter's PSFs ran at the default settings whatever the renderer's)."""

from __future__ import annotations

import pytest
import torch

from deeplens.optics.camera import Camera
from deeplens.optics.io import load_lens
from deeplens.optics.options import TraceOptions
from deeplens.render import Sensor
from deeplens.render.psf_conv import PSFConvRenderer
from deeplens.training import wiener
from deeplens.training.lens_setup import cubic_phase_plate
from deeplens.training.module import EndToEndModule
from deeplens.training.wiener import DepthWienerFilter


def _camera():
    lens = load_lens("data/lenses/edof_achromat.json").to(torch.float64)
    cubic_phase_plate(lens, 4, 0.005)
    return lens, Sensor((24, 24), 0.0069, channels=[[587.6]])


def _spy(monkeypatch):
    seen = []
    real = wiener.psf_many

    def psf_many(*args, **kw):
        seen.append(kw.get("options"))
        return real(*args, **kw)

    monkeypatch.setattr(wiener, "psf_many", psf_many)
    return seen


def test_the_filter_traces_its_psfs_with_the_options_it_is_given(monkeypatch):
    lens, sensor = _camera()
    seen = _spy(monkeypatch)
    opts = TraceOptions(tol=1e-9, max_iter=17)
    wf = DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=1024, options=opts)
    k_opts = wf.psfs((24, 24))
    assert seen and all(o is opts for o in seen)
    default = DepthWienerFilter(lens, sensor, [6000.0], depths=1, rays=1024).psfs((24, 24))
    # no options: the defaults (a default TraceOptions, traced as None was before)
    assert repr(seen[-1]) == repr(TraceOptions())
    assert torch.allclose(k_opts, default, rtol=0, atol=1e-12)  # same physics either way


def test_the_filter_reads_its_cameras_options_at_every_trace(monkeypatch):
    """With a camera, the filter holds no copy: options set on the camera later are the
    ones its next PSF trace runs with; options beside a camera are refused."""
    lens, sensor = _camera()
    seen = _spy(monkeypatch)
    cam = Camera(lens, sensor)
    wf = DepthWienerFilter(cam, None, [6000.0], depths=1, rays=1024)
    later = TraceOptions(tol=1e-9, max_iter=17)
    cam.options = later
    wf.psfs((24, 24))
    assert seen and all(o is later for o in seen) and wf.options is later
    with pytest.raises(ValueError, match="options given beside a Camera"):
        DepthWienerFilter(cam, None, [6000.0], depths=1, rays=1024, options=TraceOptions())


def test_the_module_hands_the_renderers_options_to_the_filter(monkeypatch):
    lens, sensor = _camera()
    opts = TraceOptions(tol=1e-9, max_iter=17)
    renderer = PSFConvRenderer(lens, sensor, n_rays=256, options=opts)
    module = EndToEndModule(lens, sensor, renderer, torch.nn.Identity(), [6000.0], [6000.0],
                            deconvolution={"depths": 1, "rays": 1024})
    assert module.deconv.options is opts
    # one camera: the renderer's, held by the module and the filter
    assert module.camera is renderer.camera is module.deconv.camera
