#!/usr/bin/env python
"""A/B speed of the tracer before and after a refactor, in one process (issue 24).

The "before" code is a copy of the ``deeplens`` package renamed ``deeplens_base`` (its
absolute imports rewritten), so both import side by side and the rows alternate A, B, A, B, ...
in the same interpreter; each row's figure is the minimum over ``--repeats`` runs (the machine
is shared: the minimum is the least disturbed run).  Make the copy with::

    git archive <base-commit> deeplens | tar -x -C /tmp/ab
    mv /tmp/ab/deeplens /tmp/ab/deeplens_base
    grep -rl deeplens /tmp/ab/deeplens_base --include=*.py | \\
        xargs sed -i -E 's/(from|import) deeplens([. ])/\\1 deeplens_base\\2/g'
    OMP_NUM_THREADS=1 python benchmarks/bench_refactor_ab.py --base-dir /tmp/ab

Rows (float32 double Gauss on-axis rays unless stated): eager forward (no gradient); eager
trace + backward (curvatures trainable, RMS spot loss); the same with ``checkpoint=True``;
eager forward through an even asphere (Newton, Thorlabs ACL5040U); compiled ``lens`` forward
and ``surface`` trace + backward (warmed up first: compilation is not timed).  The last column
is after/before (below 1: faster); the CPU-time columns (the process's own, min over the
same runs) are less sensitive to other processes on a shared machine.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]


def _setup(pkg, lens_file, n, dtype=torch.float32):
    io = importlib.import_module(f"{pkg}.optics.io")
    sampling = importlib.import_module(f"{pkg}.optics.sampling")
    lens = io.load_lens(REPO / "data" / "lenses" / lens_file).to(dtype)
    g = torch.Generator().manual_seed(0)
    r = 0.9 * float(lens.surfaces[0].semi_diameter) * torch.sqrt(torch.rand(n, generator=g,
                                                                          dtype=torch.float64))
    phi = 2 * torch.pi * torch.rand(n, generator=g, dtype=torch.float64)
    xy = torch.stack([r * torch.cos(phi), r * torch.sin(phi)], -1)
    rays = sampling.field_rays(lens, 0.0, 587.5618, xy, 0.0).to(dtype)
    return lens, rays


def _options(pkg, **kw):
    return importlib.import_module(f"{pkg}.optics.intersect").TraceOptions(**kw)


def _forward(lens, rays, opt):
    with torch.no_grad():
        return lens.trace_to_sensor(rays, options=opt)


def _backward(lens, rays, opt):
    out = lens.trace_to_sensor(rays, options=opt)
    p = out.o[..., :2][out.valid]
    loss = ((p - p.mean(0)) ** 2).sum(-1).mean().sqrt()
    loss.backward()
    return loss


def _rows(pkg, n):
    dg, rays = _setup(pkg, "double_gauss.json", n)
    for s in dg.surfaces:
        if hasattr(s, "c"):
            s.c.requires_grad_(False)
    asph, arays = _setup(pkg, "thorlabs_acl5040u.json", n)

    def trainable(on):
        for s in dg.surfaces:
            if hasattr(s, "c"):
                s.c.requires_grad_(on)
        dg.zero_grad(set_to_none=True)

    def fwd(opt):
        return lambda: (trainable(False), _forward(dg, rays, opt))

    def bwd(opt):
        return lambda: (trainable(True), _backward(dg, rays, opt))

    return {
        "eager forward": fwd(None),
        "eager trace + backward": bwd(None),
        "eager checkpoint trace + backward": bwd(_options(pkg, checkpoint=True)),
        "eager asphere forward (Newton)": lambda: _forward(asph, arays, None),
        "compiled lens forward": fwd(_options(pkg, compile="lens")),
        "compiled surface trace + backward": bwd(_options(pkg, compile="surface")),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--base-dir", required=True, help="folder holding deeplens_base/")
    ap.add_argument("--rays", type=int, default=200_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--skip-compiled", action="store_true")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(REPO))
    sys.path.insert(1, args.base_dir)
    rows = {"before": _rows("deeplens_base", args.rays), "after": _rows("deeplens", args.rays)}
    names = [k for k in rows["after"] if not (args.skip_compiled and k.startswith("compiled"))]
    for which in ("before", "after"):  # warm-up (compilation for the compiled rows)
        for k in names:
            rows[which][k]()
    best = {(w, k): float("inf") for w in rows for k in names}
    cpu = dict(best)
    for _ in range(args.repeats):
        for k in names:
            for w in ("before", "after"):
                t, c = time.perf_counter(), time.process_time()
                rows[w][k]()
                best[(w, k)] = min(best[(w, k)], time.perf_counter() - t)
                cpu[(w, k)] = min(cpu[(w, k)], time.process_time() - c)
    print(f"{args.rays} rays, float32, torch {torch.__version__}, threads "
          f"{torch.get_num_threads()}, CPU capability {torch.backends.cpu.get_cpu_capability()}, "
          f"min of {args.repeats} alternating runs")
    print("| row | before s | after s | after/before | before CPU s | after CPU s | after/before "
          "(CPU) |\n|---|---|---|---|---|---|---|")
    for k in names:
        a, b = best[("before", k)], best[("after", k)]
        ca, cb = cpu[("before", k)], cpu[("after", k)]
        print(f"| {k} | {a:.4f} | {b:.4f} | {b / a:.3f} | {ca:.4f} | {cb:.4f} | {cb / ca:.3f} |")


if __name__ == "__main__":
    main()
