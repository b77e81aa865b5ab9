#!/usr/bin/env python
"""A training step's render with and without ``TraceOptions(compile=True)``.

The render half of the ``render=balanced`` training step as ``bench_render_accuracy.py`` times
it (its lenses, sensors, textures and preset; a batch of 4 planes, 64 x 64 RGB, render +
``backward()`` of a mean-square loss through the adjoint), eager and with the compiled kernels
(:mod:`deeplens.optics.compiled`): the first step (including compilation, which inductor's disk
cache shortens in later processes), the median of 5 steps (wall and CPU time), and the largest
difference of the lens gradients between the two, relative to the largest component.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_compiled_step.py
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_render_accuracy as B  # noqa: E402

from deeplens.optics.options import TraceOptions  # noqa: E402
from deeplens.render import MonteCarloRenderer, Scene  # noqa: E402


def main() -> None:
    torch.set_num_threads(1)
    cfg = B.load_preset("balanced")
    print(f"render=balanced training batch (4 planes, 64x64 RGB, spp {cfg['spp']}), one thread, "
          f"load average {os.getloadavg()[0]:.1f}\n")
    print("| lens | mode | first step s (incl. compiling) | step s (median of 5) | CPU s | "
          "grad rel. diff to eager |")
    print("|---|---|---|---|---|---|")
    for key in ("edof", "doublet"):
        dtype = B.lens_dtype(key)
        lens, sensor = B.make_lens(key, dtype), B.make_sensor(key)
        depths = B.LENSES[key]["train_depths"]
        batch = Scene(B.make_textures(len(depths), seed=555).to(getattr(torch, dtype)), depths)
        grads = {}
        for comp in (False, True):
            opts = TraceOptions(tol=cfg["newton_tol"], max_iter=cfg["max_iter"], compile=comp)

            def step(seed):
                r = MonteCarloRenderer(lens, sensor, spp=cfg["spp"], vignetting=cfg["vignetting"],
                                       adjoint=cfg["adjoint"], chunk_rays=cfg["chunk_rays"],
                                       options=opts,
                                       decorrelate=cfg.get("decorrelate", False) and cfg["adjoint"])
                lens.zero_grad(set_to_none=True)
                (r(batch, seed=seed) ** 2).mean().backward()

            t0 = time.perf_counter()
            step(30)
            first = time.perf_counter() - t0
            ts, cs = [], []
            for k in range(5):
                t0, c0 = time.perf_counter(), time.process_time()
                step(31 + k)
                ts.append(time.perf_counter() - t0)
                cs.append(time.process_time() - c0)
            grads[comp] = torch.cat([p.grad.reshape(-1).double() for p in lens.parameters()
                                     if p.requires_grad])
            diff = ""
            if comp:
                g0 = grads[False]
                diff = f"{float((grads[True] - g0).abs().max() / g0.abs().max()):.1e}"
            print(f"| {key} ({dtype}) | {'compile=True' if comp else 'eager'} | {first:.2f} | "
                  f"{statistics.median(ts):.3f} | {statistics.median(cs):.3f} | {diff} |",
                  flush=True)


if __name__ == "__main__":
    main()
