"""One camera per training step (issue 24): the trace options set once on ``module.camera``
reach every trace of a training step, the renderer's (forward and the adjoint's re-trace) and
the Wiener front end's PSF traces, through one :class:`~deeplens.optics.camera.Camera`.

The options are watched at the tracer's entry point (:func:`deeplens.optics.tracer.trace`,
which every lens trace goes through) by identity, with the caller read from the stack.  Before
the camera, ``module.camera`` was the ideal reference camera and the renderer and the filter
held copies of the options taken at construction: the assignment below reached no trace.
"""

from __future__ import annotations

import copy
import traceback
import warnings

import pytest
import torch

from deeplens.optics import tracer
from deeplens.optics.camera import Camera
from deeplens.optics.options import TraceOptions
from deeplens.training.train import build_objects

RUNS = {
    # PSF-convolution renderer + Wiener front end, trainable plate, geometric PSFs
    "edof": ["experiment=edof", "render.psf_rays=256", "render.psf_model=geometric",
             "model.deconvolution.rays=256", "model.deconvolution.depths=2",
             "model.optics_warmup_steps=0", "render.max_iter=23"],
    # Monte Carlo renderer with adjoint gradients (re-traces in backward) + a Wiener front end
    "doublet": ["experiment=doublet", "render=fast", "render.spp=1",
                "render.psf_model=geometric", "render.max_iter=23",
                "+model.deconvolution={depths: 1, rays: 256}"],
}
CALLERS = {"renderer": ("render/psf_conv.py", "render/monte_carlo.py", "render/adjoint.py"),
           "wiener": ("training/wiener.py",)}


def _caller(stack) -> str | None:
    files = [f.filename.replace("\\", "/") for f in stack]
    for who, names in CALLERS.items():
        if any(f.endswith(n) for f in files for n in names):
            return who
    return None


@pytest.mark.parametrize("run", sorted(RUNS))
def test_one_setting_on_the_camera_reaches_every_trace_of_a_step(run, cfg_factory, monkeypatch):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        objs = build_objects(cfg_factory(*RUNS[run]))
    module = objs["module"]
    assert module.deconv is not None
    # one camera, built from the config (render.max_iter), shared by renderer and filter
    assert isinstance(module.camera, Camera)
    assert module.camera is objs["renderer"].camera is module.deconv.camera
    assert module.camera.options.max_iter == 23
    assert module.camera.lens is module.lens and module.camera.sensor is module.sensor

    mine = TraceOptions(tol=3e-9, max_iter=19)   # set once, after everything was built
    module.camera.options = mine
    seen = []
    real = tracer.trace

    def spy(lens, rays, **kw):
        seen.append((_caller(traceback.extract_stack()[:-1]), kw.get("options")))
        return real(lens, rays, **kw)

    monkeypatch.setattr(tracer, "trace", spy)
    images = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loss, *_ = module.step_loss(images, 0)
        loss.backward()
    callers = {c for c, _ in seen}
    assert {"renderer", "wiener"} <= callers, callers
    stray = [(c, o) for c, o in seen if o is not mine]
    assert not stray, f"traces that did not run with the camera's options: {stray}"
    # and the optics' gradient came through those traces
    grads = [p.grad for _, p in module.camera.trainable_parameters()]
    assert grads and all(g is not None and bool(torch.isfinite(g).all()) for g in grads)
    assert any(bool(g.abs().sum() > 0) for g in grads)
    # a copy of the module (checkpointing, tolerance draws) keeps one camera and one lens
    clone = copy.deepcopy(module)
    assert clone.camera is not module.camera and clone.camera.lens is clone.lens
    assert clone.renderer.camera is clone.camera is clone.deconv.camera
    assert clone.renderer.lens is clone.lens and clone.camera.options is not mine
