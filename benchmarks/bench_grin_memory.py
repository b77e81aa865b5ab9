#!/usr/bin/env python
"""Memory of the gradient through a gradient-index rod: autograd through every step.

    OMP_NUM_THREADS=1 python benchmarks/bench_grin_memory.py [--rays N]

The graded medium is integrated with a fixed step (:mod:`deeplens.optics.grin_trace`) and autograd
records every step, so the graph grows with the number of steps, unlike a homogeneous lens, whose
intersections keep a handful of per-ray scalars (the paper's implicit Newton step) whatever the
glass thickness.  Workload: a 4 mm Gradient 1 rod between planes (``n0`` 1.5, ``nr2`` -0.083 /mm²,
``nr2`` and the rod length trainable), ``N`` rays from an on-axis point 2.54 mm before it filling
NA 0.2, traced to the sensor; the loss is the sum of the image heights.  ``graph MiB`` counts the
bytes of every tensor autograd saves for the backward pass (``torch.autograd.graph.
saved_tensors_hooks``; a tensor saved twice counts twice), which is exact and independent of the
allocator; ``steps`` is the number of full integration steps the rays take.  The same system with
a homogeneous glass of index 1.5 (``ModelGlass``) is the reference row.  ``TraceOptions(checkpoint=
True)`` wraps each surface's trace, the propagation through the medium before it included, in
``torch.utils.checkpoint`` (the backward pass recomputes it): the graph keeps the ray state per
surface only (the last rows; the recomputation's own graph lives during the backward pass of
that one surface).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # this checkout's deeplens

from deeplens.optics import Lens, TraceOptions  # noqa: E402
from deeplens.optics.grin import RadialGradient  # noqa: E402
from deeplens.optics.materials import Air, ModelGlass  # noqa: E402
from deeplens.optics.rays import Rays  # noqa: E402
from deeplens.optics.surfaces import Plane  # noqa: E402


def graph_bytes(medium, n_rays: int, checkpoint: bool = False):
    """``(saved bytes, loss)`` for one forward pass through the rod filled with ``medium``."""
    lens = Lens([Plane(1.0), Plane(1.0)], [Air(), medium, Air()], [0.0, 4.0], 2.54, 0)
    lens.distances[1].requires_grad_(True)
    for p in medium.parameters():
        p.requires_grad_(True)
    th = torch.linspace(-math.asin(0.2), math.asin(0.2), n_rays, dtype=torch.float64)
    d = torch.stack([torch.zeros_like(th), torch.sin(th), torch.cos(th)], -1)
    o = torch.zeros_like(d)
    o[:, 2] = -2.54
    rays = Rays(o, d, torch.full((n_rays,), 550.0, dtype=torch.float64))
    total = [0]

    def pack(t):
        total[0] += t.numel() * t.element_size()
        return t

    with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
        out = lens.trace_to_sensor(rays, options=TraceOptions(checkpoint=checkpoint))
        loss = (out.o[:, 1] * out.valid).sum()
    loss.backward()
    return total[0], loss


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rays", type=int, default=10000)
    a = ap.parse_args(argv)
    print(f"{a.rays} rays, float64, 4 mm rod\n")
    print("| medium | step (mm) | steps | graph MiB | bytes per ray per step |")
    print("|---|---|---|---|---|")
    b, _ = graph_bytes(ModelGlass(1.5, math.inf), a.rays)
    print(f"| homogeneous n = 1.5 | - | - | {b / 2**20:.2f} | - |")
    for step in (0.4, 0.2, 0.1, 0.05, 0.025):
        med = RadialGradient(1.5, -0.083, step_mm=step)
        b, _ = graph_bytes(med, a.rays)
        n = math.ceil(4.0 / step)
        print(f"| Gradient 1 | {step:g} | {n} | {b / 2**20:.2f} | {b / a.rays / n:.0f} |")
    for step in (0.1, 0.025):   # each surface's trace recomputed in the backward pass
        b, _ = graph_bytes(RadialGradient(1.5, -0.083, step_mm=step), a.rays, checkpoint=True)
        print(f"| Gradient 1, checkpoint=True | {step:g} | {math.ceil(4.0 / step)} | "
              f"{b / 2**20:.2f} | - |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
