"""Analysis through a :class:`~deeplens.optics.camera.Camera` (issue 24): the wavefront, the
diffraction PSF and MTF, the Strehl ratio, the geometric MTF and the encircled energy take a
camera in place of the lens; every trace they make runs at the camera's tolerance and
iterations (aiming traces without clear apertures, as before), bit for bit what the lens calls
with the same ``options`` give."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from helpers import spy_trace_options

from deeplens.analysis import diffraction as D
from deeplens.analysis.wavefront import wavefront
from deeplens.optics.camera import Camera
from deeplens.optics.io import load_lens
from deeplens.optics.options import TraceOptions

LENSES = Path(__file__).resolve().parents[2] / "data" / "lenses"


@pytest.fixture
def lens():
    return load_lens(LENSES / "double_gauss.json")


def _spy(monkeypatch):
    return spy_trace_options(monkeypatch)


def test_replace_keeps_every_other_setting():
    o = TraceOptions(tol=1e-9, max_iter=12, closed_form=False, checkpoint=True, compile="lens")
    r = o.replace(clip_aperture=False)
    assert repr(r) == repr(TraceOptions(tol=1e-9, max_iter=12, clip_aperture=False,
                                        closed_form=False, checkpoint=True, compile="lens"))
    assert o.clip_aperture is True  # a new object
    with pytest.raises(TypeError, match="unknown settings"):
        o.replace(tolerance=1)


@pytest.mark.parametrize("what", ["wavefront", "mtf", "strehl", "geometric_mtf",
                                  "encircled_energy"])
def test_analysis_through_a_camera(what, lens, monkeypatch):
    # Newton from the vertex plane on spheres too (whether that changes the last bit depends on
    # the CPU's vector unit and the refraction formula's rounding, so the spy, not the value,
    # shows that the camera's options were used)
    opts = TraceOptions(tol=1e-11, max_iter=25, closed_form=False)
    cam = Camera(lens, options=opts)
    call = {
        "wavefront": lambda L, **kw: wavefront(L, 5.0, 587.6, n=32, **kw).opd,
        "mtf": lambda L, **kw: D.mtf(L, 5.0, 587.6, n=32, **kw).mtf_t,
        "strehl": lambda L, **kw: D.strehl(L, 0.0, 587.6, n=32, **kw),
        "geometric_mtf": lambda L, **kw: D.geometric_mtf(L, 5.0, [5.0, 20.0], 587.6, n=32,
                                                         **kw).mtf_t,
        "encircled_energy": lambda L, **kw: D.encircled_energy(L, 5.0, [0.01, 0.03], 587.6,
                                                               n=32, **kw),
    }[what]
    ref = call(lens, options=opts)
    seen = _spy(monkeypatch)
    got = call(cam)
    assert seen
    for o in seen:  # the camera's, or its aiming copy (no clear apertures)
        assert o is opts or repr(o) == repr(opts.replace(clip_aperture=False)), o
    assert torch.equal(got, ref)
