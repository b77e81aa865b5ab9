"""Renderers, PSFs and analysis take a :class:`~deeplens.optics.camera.Camera` (issue 24): the
same values as the older lens + sensor + options calls, bit for bit, with the camera's options
read when they trace (watched at the tracer's entry point)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from helpers import spy_trace_options

from deeplens.analysis.spot import spot_diagram
from deeplens.optics.camera import Camera
from deeplens.optics.io import load_lens
from deeplens.optics.options import TraceOptions
from deeplens.render import MonteCarloRenderer, Scene, Sensor
from deeplens.render.psf import psf, psf_grids, psf_many
from deeplens.render.psf_conv import PSFConvRenderer

LENSES = Path(__file__).resolve().parents[2] / "data" / "lenses"


@pytest.fixture
def parts():
    lens = load_lens(LENSES / "wide_doublet.json")
    return lens, Sensor((8, 8), 0.05, channels=[[587.6]])


def _spy(monkeypatch):
    return spy_trace_options(monkeypatch)


def test_psfs_through_a_camera_equal_the_lens_calls_and_use_its_options(parts, monkeypatch):
    lens, sensor = parts
    cam = Camera(lens, sensor, TraceOptions(tol=1e-11, max_iter=12))
    jobs = [((0.0, 0.0), 3000.0, 587.6), ((0.0, 200.0), 3000.0, 587.6)]
    ref = psf_many(lens, sensor, jobs, n_rays=512, options=cam.options)
    seen = _spy(monkeypatch)
    got = psf_many(cam, None, jobs, n_rays=512)
    assert seen and all(o is cam.options for o in seen)
    assert all(torch.equal(a, b) for a, b in zip(ref, got))
    one = psf(cam, None, (0.0, 0.0), 3000.0, 587.6, n_rays=512)
    assert torch.equal(one, ref[0])
    (k_ref, c_ref), = psf_grids(lens, sensor, [(3000.0, 587.6)], (2, 2), 256,
                                options=cam.options)
    (k, c), = psf_grids(cam, None, [(3000.0, 587.6)], (2, 2), 256)
    assert torch.equal(k, k_ref) and torch.equal(c, c_ref)
    with pytest.raises(ValueError, match="psf_many: options given beside a Camera"):
        psf_many(cam, None, jobs, options=TraceOptions())


@pytest.mark.parametrize("kind", ["mc", "psf"])
def test_renderers_through_a_camera(kind, parts, monkeypatch):
    lens, sensor = parts
    opts = TraceOptions(tol=1e-11, max_iter=12)

    def make(*args, **kw):
        if kind == "mc":
            return MonteCarloRenderer(*args, spp=2, adjoint=False, **kw)
        return PSFConvRenderer(*args, n_rays=256, **kw)

    old = make(lens, sensor, options=opts)
    cam = Camera(lens, sensor, opts)
    new = make(cam)
    assert new.camera is cam and new.lens is lens and new.sensor is sensor
    assert set(new.state_dict()) == set(old.state_dict())  # checkpoints load as before
    scene = Scene(torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0),
                             dtype=lens.dtype), 3000.0)
    assert torch.equal(old(scene, seed=5), new(scene, seed=5))
    later = TraceOptions(tol=1e-11, max_iter=13)
    new.options = later  # the renderer's options are the camera's
    assert cam.options is later
    seen = _spy(monkeypatch)
    new(scene, seed=5)
    assert seen and all(o is later for o in seen)
    with pytest.raises(ValueError, match="options given beside a Camera"):
        make(cam, options=opts)
    with pytest.raises(ValueError, match="the camera has no sensor"):
        make(Camera(lens))


def test_spot_diagram_through_a_camera(parts, monkeypatch):
    lens, _ = parts
    # Newton from the vertex plane also on spheres (whether that differs from the closed form
    # in the last bit depends on the CPU's vector unit, so the spy, not the value, shows that
    # the camera's options were used)
    cam = Camera(lens, options=TraceOptions(closed_form=False))
    ref = spot_diagram(lens, 10.0, 587.6, options=cam.options)
    seen = _spy(monkeypatch)
    got = spot_diagram(cam, 10.0, 587.6)
    assert seen and all(o is cam.options for o in seen)
    assert torch.equal(got.rms_radius, ref.rms_radius) and got.n_rays == ref.n_rays


def test_diffraction_psfs_through_a_camera(monkeypatch):
    from deeplens.render.psf_model import PSFModel

    lens = load_lens(LENSES / "edof_achromat.json")
    sensor = Sensor((16, 16), 0.0069, channels=[[587.6]])
    cam = Camera(lens, sensor, TraceOptions(tol=1e-11, max_iter=12))
    jobs = [((0.0, 0.0), 6000.0, 587.6)]
    ref = PSFModel("diffraction").diffraction(lens, sensor, jobs, cam.options, max_kernel=15)
    seen = _spy(monkeypatch)
    got = PSFModel("diffraction").diffraction(cam, None, jobs, max_kernel=15)
    assert seen and all(o is cam.options for o in seen)
    assert len(got) == 1 and torch.equal(got[0], ref[0])
