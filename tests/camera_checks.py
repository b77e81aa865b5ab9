"""Checks of the calls that take a :class:`~deeplens.optics.camera.Camera` in place of a lens
(issue 24): a spy on every surface step's trace options, and bitwise comparison of results."""

from __future__ import annotations

import math
from dataclasses import fields, is_dataclass

import torch

from deeplens.optics.lens import Lens


def spy_surface_options(monkeypatch) -> list:
    """Record the ``options`` of every surface a ray crosses (each trace, and the aiming
    traces that step surface by surface, goes through ``Lens.trace_surface``)."""
    seen = []
    real = Lens.trace_surface

    def spy(self, i, rays, n1, n2, z, options=None, *args, **kw):
        seen.append(options)
        return real(self, i, rays, n1, n2, z, options, *args, **kw)

    monkeypatch.setattr(Lens, "trace_surface", spy)
    return seen


def flat(x) -> list:
    """The tensors and numbers of a result (tensor, tuple/list, dict, dataclass, figure)."""
    if isinstance(x, torch.Tensor):
        return [x.detach()]
    if isinstance(x, (int, float, str)) or x is None:
        return [x]
    if isinstance(x, dict):
        return [k for k in x] + [v for k in x for v in flat(x[k])]
    if isinstance(x, (list, tuple)):
        return [v for e in x for v in flat(e)]
    if is_dataclass(x):
        return [v for f in fields(x) for v in flat(getattr(x, f.name))]
    if hasattr(x, "axes"):  # a matplotlib figure: the data of every line drawn
        import matplotlib.pyplot as plt

        out = [torch.as_tensor(ln.get_xydata()) for a in x.axes for ln in a.get_lines()]
        out += flat(getattr(x, "deeplens_data", None))
        plt.close(x)
        return out
    raise TypeError(type(x))


def same(a, b) -> bool:
    fa, fb = flat(a), flat(b)
    if len(fa) != len(fb):
        return False
    for u, v in zip(fa, fb):
        if isinstance(u, torch.Tensor):
            if not (isinstance(v, torch.Tensor) and u.shape == v.shape
                    and torch.equal(torch.nan_to_num(u, nan=1e300), torch.nan_to_num(v, nan=1e300))):
                return False
        elif isinstance(u, float) and math.isnan(u):
            if not (isinstance(v, float) and math.isnan(v)):
                return False
        elif u != v:
            return False
    return True


def assert_traced_at(seen: list, opts) -> None:
    """Every surface step ``spy_surface_options`` saw ran at ``opts`` or at its aiming copy
    (``opts.replace(clip_aperture=False)``), and there was at least one."""
    aim = repr(opts.replace(clip_aperture=False))
    assert seen, "nothing was traced"
    bad = [o for o in seen if not (o is opts or repr(o) == aim)]
    assert not bad, f"{len(bad)} of {len(seen)} surface steps ran at other options: {bad[0]!r}"
