""":func:`deeplens.optics.compiled.call`: a compiled graph differentiates twice, and the
recompilation limit warns instead of falling back silently (issue 25, items 10 and 13)."""

from __future__ import annotations

import warnings

import helpers as H
import pytest
import torch

import deeplens.optics.compiled as C
from deeplens.optics.options import TraceOptions
from deeplens.optics.io import load_lens
from deeplens.optics.sampling import field_rays


def _kernel(x, k: int):
    y = torch.tanh(x[:, None] * x[None, :]) + k
    return (y @ y).sum()  # a product the backward needs saved (a donated buffer)


@pytest.fixture
def compiled_kernel():
    torch._dynamo.reset()
    yield torch.compile(_kernel, dynamic=True)
    torch._dynamo.reset()


def test_a_compiled_graph_differentiates_twice_as_eager_does(compiled_kernel):
    x = torch.linspace(0.1, 1.0, 17, dtype=torch.float64, requires_grad=True)
    ref = torch.autograd.grad(_kernel(x, 1), x)[0]
    loss = C.call(compiled_kernel, x, 1)
    g1 = torch.autograd.grad(loss, x, retain_graph=True)[0]
    g2 = torch.autograd.grad(loss, x)[0]
    assert torch.allclose(g1, ref, rtol=1e-12) and torch.allclose(g2, ref, rtol=1e-12)


def test_beyond_the_recompile_limit_the_call_warns_and_runs_eager(compiled_kernel, monkeypatch):
    monkeypatch.setenv("DEEPLENS_RECOMPILE_LIMIT", "1")
    x = torch.linspace(0.1, 1.0, 17, dtype=torch.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert float(C.call(compiled_kernel, x, 1)) == pytest.approx(float(_kernel(x, 1)))
    with pytest.warns(RuntimeWarning, match="_kernel reached its limit of 1 compiled variants"):
        out = C.call(compiled_kernel, x.float(), 2)  # a second variant (dtype)
    assert float(out) == pytest.approx(float(_kernel(x.float(), 2)), rel=1e-6)


@pytest.mark.parametrize("text", ["0", "many"])
def test_a_bad_recompile_limit_is_refused_by_name(monkeypatch, text):
    monkeypatch.setenv("DEEPLENS_RECOMPILE_LIMIT", text)
    with pytest.raises(ValueError, match="DEEPLENS_RECOMPILE_LIMIT"):
        C.recompile_limit()


@pytest.mark.slow
def test_two_gradients_from_one_compiled_lens_trace():
    """The compiled trace of the Cooke triplet differentiated twice (``retain_graph=True``)
    gives the eager gradient both times (raised "non-empty donated buffers" before)."""
    lens = load_lens(H.LENS_DIR / "cooke_triplet.json")
    c = lens.surfaces[0].c
    c.requires_grad_(True)
    grads = []
    for opt in (TraceOptions(), TraceOptions(compile=True)):
        rays = field_rays(lens, 5.0, H.WAVELENGTH_D, H.disk_points(100, 2.0, seed=3), 6.0)
        out = lens.trace_to_sensor(rays, options=opt)
        loss = (out.o[..., :2] ** 2).sum()
        grads.append(torch.autograd.grad(loss, c, retain_graph=True)[0])
        grads.append(torch.autograd.grad(loss, c)[0])
    assert all(H.rel_err(g, grads[0]) < 1e-10 for g in grads[1:])
