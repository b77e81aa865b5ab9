"""``TraceOptions(checkpoint=True)``: each surface is recomputed in backward from its incoming
ray state (``torch.utils.checkpoint``).  Values and the gradients w.r.t. every parameter kind
(curvature, conic, asphere coefficient, thickness, sensor distance, misalignment, the wavelength)
must equal the recorded trace's exactly (float64), forward and reverse, and the graph kept between
forward and backward must be smaller."""

import helpers as H
import pytest
import torch

from deeplens.optics.options import TraceOptions
from deeplens.optics.io import load_lens
from deeplens.optics.rays import Rays
from deeplens.optics.sampling import field_rays

F64 = torch.float64


def _lens():
    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    with torch.no_grad():
        lens.misalignments[3].dx.fill_(0.02)
        lens.misalignments[1].tilt_y.fill_(0.005)
    params = [lens.surfaces[0].c, lens.surfaces[0].k, lens.surfaces[0].a[0], lens.surfaces[4].c,
              lens.distances[3], lens.d_sensor, lens.misalignments[3].dx,
              lens.misalignments[1].tilt_y]
    for p in params:
        p.requires_grad_(True)
    return lens, params


@pytest.mark.parametrize("reverse", [False, True], ids=["forward", "reverse"])
def test_checkpointed_trace_equals_recorded_trace(reverse):
    lens, params = _lens()
    wl = torch.tensor(550.0, dtype=F64, requires_grad=True)
    if reverse:
        xy = H.disk_points(200, 1.5, seed=2)
        z0 = float(lens.z_sensor().detach())
        o = torch.cat([xy, torch.full((200, 1), z0, dtype=F64)], -1)
        d = torch.tensor([0.02, -0.01, -1.0], dtype=F64).expand(200, 3)
        rays = Rays(o, d, wl.expand(200))
    else:
        rays = field_rays(lens, 6.0, 550.0, H.disk_points(200, 2.2, seed=2), 6.0)
        rays = rays.replace(wavelength=wl.expand(200))
    w = torch.randn(200, 3, generator=torch.Generator().manual_seed(4), dtype=F64)
    results = []
    for ck in (False, True):
        opt = TraceOptions(checkpoint=ck)
        out = (lens.trace(rays, reverse=True, options=opt) if reverse
               else lens.trace_to_sensor(rays, options=opt))
        v = out.valid
        loss = (torch.where(v[:, None], out.o, 0 * out.o) * w).sum() + out.opl[v].sum() \
            + (out.d[v] * w[v]).sum()
        results.append((out, torch.autograd.grad(loss, params + [wl], allow_unused=reverse)))
    (a, ga), (b, gb) = results
    assert int(a.valid.sum()) > 150 and torch.equal(a.valid, b.valid)
    assert torch.equal(a.o, b.o) and torch.equal(a.d, b.d) and torch.equal(a.opl, b.opl)
    assert sum(x is None for x in ga) == (1 if reverse else 0)  # d_sensor: rays start there
    for x, y in zip(ga, gb):
        if x is None:
            assert y is None
            continue
        assert float(x.abs()) > 0
        assert H.rel_err(x, y) < 1e-12


def test_checkpoint_keeps_a_smaller_graph():
    """Tensors saved for backward (counted through saved-tensor hooks): the checkpointed trace
    keeps less than half of the recorded one's bytes."""
    lens, _ = _lens()
    rays = field_rays(lens, 0.0, 587.5618, H.disk_points(5000, 2.2, seed=1).float(), 6.0)
    saved = {}

    def count(ck):
        total = [0]

        def pack(t):
            total[0] += t.numel() * t.element_size()
            return t

        with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
            out = lens.trace_to_sensor(rays, options=TraceOptions(checkpoint=ck))
        saved[ck] = total[0]
        return out

    count(False)
    count(True)
    assert saved[True] < 0.5 * saved[False], saved
