"""The camera (issue 24): lens + sensor + trace options, and the one rule of lens ownership."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch import nn

from deeplens.optics.camera import Camera, as_camera, set_trainable, unpack
from deeplens.optics.io import load_lens
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.sampling import field_rays

LENSES = Path(__file__).resolve().parents[2] / "data" / "lenses"


@pytest.fixture
def lens():
    return load_lens(LENSES / "double_gauss.json")


def _rays(lens, scale=1.6):
    """Rays of the 10 deg field over a square ``scale`` times the entrance pupil: the outer
    ones pass only when clear apertures are ignored."""
    p = paraxial(lens)
    r = 0.5 * float(p.entrance_pupil_diameter) * scale
    g = torch.linspace(-r, r, 15, dtype=lens.dtype)
    xy = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    return field_rays(lens, 10.0, 587.6, xy, float(p.entrance_pupil_z))


def test_default_options_and_their_checks(lens):
    cam = Camera(lens)
    assert repr(cam.options) == repr(TraceOptions())
    mine = TraceOptions(max_iter=7)
    cam.options = mine
    assert cam.options is mine
    cam.options = None
    assert repr(cam.options) == repr(TraceOptions())
    with pytest.raises(TypeError, match="Camera.options: expected a TraceOptions"):
        cam.options = {"max_iter": 7}
    with pytest.raises(TypeError, match="Camera: lens must be a Lens"):
        Camera(nn.Linear(1, 1))
    assert cam.dtype == lens.dtype and cam.device == lens.device


def test_the_camera_traces_with_its_options_read_when_it_traces(lens):
    cam = Camera(lens)
    rays = _rays(lens)
    clipped = cam.trace_to_sensor(rays)
    assert torch.equal(clipped.o, lens.trace_to_sensor(rays).o)
    cam.options = TraceOptions(clip_aperture=False)  # set after construction: read now
    free = cam.trace_to_sensor(rays)
    ref = lens.trace_to_sensor(rays, options=TraceOptions(clip_aperture=False))
    assert torch.equal(free.o, ref.o) and torch.equal(free.valid, ref.valid)
    # the setting is observable: rays outside the clear apertures pass only without clipping
    assert int(free.valid.sum()) > int(clipped.valid.sum())
    back = cam.trace(rays, reverse=False)
    assert torch.equal(back.valid, lens.trace(rays, options=cam.options).valid)


def test_the_camera_owns_which_lens_parameters_train(lens):
    cam = Camera(lens)
    assert cam.trainable_parameters() == []
    names = cam.set_trainable(["surfaces.1.c", "surfaces.2.*"])
    got = [n for n, _ in cam.trainable_parameters()]
    assert got[0] == "surfaces.1.c" and set(got) == set(names)
    assert all(n == "surfaces.1.c" or n.startswith("surfaces.2.") for n in got)
    with pytest.raises(ValueError, match=r"lens.trainable: 'surfaces.99.\*' matches no"):
        cam.set_trainable(["surfaces.99.*"])
    # the same rule as the module-level function (training's lens.trainable)
    assert set_trainable(lens, ["surfaces.1.c"]) == ["surfaces.1.c"]
    assert [n for n, _ in cam.trainable_parameters()] == ["surfaces.1.c"]
    cam.freeze_lens()
    assert cam.trainable_parameters() == []


def test_lens_fixed_freezes_for_a_while_and_restores_even_on_error(lens):
    cam = Camera(lens)
    cam.set_trainable(["surfaces.1.c", "surfaces.4.c"])
    before = [n for n, _ in cam.trainable_parameters()]
    with cam.lens_fixed():
        assert cam.trainable_parameters() == []
    assert [n for n, _ in cam.trainable_parameters()] == before
    with pytest.raises(RuntimeError), cam.lens_fixed():
        raise RuntimeError("boom")
    assert [n for n, _ in cam.trainable_parameters()] == before
    with cam.lens_fixed(False):
        assert [n for n, _ in cam.trainable_parameters()] == before


def test_a_camera_registers_its_lens_and_sensor(lens):
    sensor = nn.Module()
    sensor.register_buffer("gain", torch.ones(1))
    cam = Camera(lens, sensor)
    keys = set(cam.state_dict())
    assert {f"lens.{k}" for k in lens.state_dict()} | {"sensor.gain"} == keys


def test_as_camera_and_unpack(lens):
    sensor = nn.Module()
    cam = Camera(lens, sensor, TraceOptions(max_iter=9))
    assert as_camera(cam) is cam and as_camera(cam, sensor, cam.options) is cam
    with pytest.raises(ValueError, match="f: options given beside a Camera"):
        as_camera(cam, options=TraceOptions(), where="f")
    with pytest.raises(ValueError, match="another sensor"):
        as_camera(cam, nn.Module())
    built = as_camera(lens, sensor, cam.options)
    assert built.lens is lens and built.sensor is sensor and built.options is cam.options
    assert unpack(cam) == (lens, sensor, cam.options)
    # a lens passes through as given: None stays None (the traces' defaults, as before)
    assert unpack(lens, sensor, None) == (lens, sensor, None)
