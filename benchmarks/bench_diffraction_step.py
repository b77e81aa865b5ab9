#!/usr/bin/env python
"""The EDOF training step with the diffraction PSF against the geometric one, in ONE process.

Composes ``experiment=edof`` as ``train.py`` does (``benchmarks/bench_train_step.py``'s set-up),
builds the objects once and then alternates, step by step, the PSF model of the run's shared
:class:`~deeplens.render.psf_model.PSFModel` between ``geometric`` and ``diffraction`` (the
renderer and the Wiener front end both follow it), so both variants see the same machine load.
Each step is the training step's work (capture, Wiener, restorer, loss, ``backward()``) at a
step after ``model.optics_warmup_steps`` (the optics train) or, with ``--fixed``, at step 0
(the optics fixed).  Reported: the minimum and median wall time (``time.perf_counter``) and CPU
time (``time.process_time``; robust to other processes on a shared machine) per variant and
their ratio.  ``--profile`` prints a cProfile of the diffraction step instead.

    OMP_NUM_THREADS=2 python benchmarks/bench_diffraction_step.py --threads 2 --rounds 8
    OMP_NUM_THREADS=1 python benchmarks/bench_diffraction_step.py --threads 1 --variants \
        geometric diffraction geometric:direct diffraction:direct diffraction:nocache
    OMP_NUM_THREADS=1 python benchmarks/bench_diffraction_step.py --threads 1 --profile
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)


def build(overrides):
    from bench_train_step import build as compose_and_build

    return compose_and_build(REPO, "edof", overrides, "/tmp/bench_diffraction_step")[1]


def set_model(pm, variant):
    """Point the shared PSF model at ``variant`` (the renderer and the Wiener filter follow):
    ``geometric`` or ``diffraction``, optionally with ``:direct`` (the renderer's convolution
    by ``F.conv2d``, as before the FFT) and ``:nocache`` (the OPD fit's least-squares map
    recomputed for every job, as before the cache)."""
    import torch.nn.functional as F

    from deeplens.render import fftconv, psf_conv

    name, *opts = variant.split(":")
    pm.model = pm.choice = name
    psf_conv.correlate_valid = F.conv2d if "direct" in opts else fftconv.correlate_valid
    if "nocache" in opts:
        pm.cache = None
    elif pm.cache is None:
        pm.cache = {}


def one_step(module, images, step, first):
    fixed = module.optics_fixed
    depths = module.sample_depths(images.shape[0], step)
    with fixed(step < first):
        y, gt = module.capture(images, depths, seed=module.seed * 1_000_003 + step)
        x = module.deconv(y) if module.deconv is not None else y
    loss, *_ = module.restore_loss(depths, y, gt, x)
    module.zero_grad(set_to_none=True)
    loss.backward()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=int(os.environ.get("OMP_NUM_THREADS", 1)))
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--fixed", action="store_true", help="the warm-up step (optics fixed)")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--variants", nargs="+", default=["geometric", "diffraction"],
                    help="geometric | diffraction, each optionally :direct and/or :nocache")
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    objs = build(args.overrides)
    module, dm = objs["module"], objs["datamodule"]
    pm = objs["renderer"].psf_model
    first = int(module.optics_warmup_steps or 0)
    step0 = 0 if args.fixed else first + 10
    batches = iter(dm.train_dataloader())
    images = next(batches)["image"]
    print(f"# PSF model at set-up: {pm.message}; sampling {pm.sampling}")
    if args.profile:
        import cProfile
        import pstats

        set_model(pm, "diffraction")
        one_step(module, images, step0, first)
        pr = cProfile.Profile()
        pr.enable()
        for i in range(3):
            one_step(module, images, step0 + 1 + i, first)
        pr.disable()
        pstats.Stats(pr).sort_stats("cumulative").print_stats(35)
        pstats.Stats(pr).sort_stats("tottime").print_stats(25)
        return
    times = {v: [] for v in args.variants}
    for r in range(args.rounds + 1):
        order = args.variants if r % 2 == 0 else args.variants[::-1]
        for name in order:
            set_model(pm, name)
            t0, c0 = time.perf_counter(), time.process_time()
            one_step(module, images, step0 + r, first)
            if r > 0:  # round 0: warm-up
                times[name].append((time.perf_counter() - t0, time.process_time() - c0))
    print(f"EDOF training step ({'optics fixed' if args.fixed else 'optics train'}), "
          f"{args.threads} threads (OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}), "
          f"{torch.backends.cpu.get_cpu_capability()}, {args.rounds} alternating rounds, "
          f"load average {os.getloadavg()[0]:.1f}\n")
    print("| PSF model | wall min s | wall median s | CPU min s | CPU median s |")
    print("|---|---|---|---|---|")
    stat = {}
    for name, v in times.items():
        w = [a for a, _ in v]
        c = [b for _, b in v]
        stat[name] = (min(w), statistics.median(w), min(c), statistics.median(c))
        print(f"| {name} | {stat[name][0]:.3f} | {stat[name][1]:.3f} | {stat[name][2]:.3f} | "
              f"{stat[name][3]:.3f} |")
    g = stat[args.variants[0]]
    for name in args.variants[1:]:
        d = stat[name]
        print(f"| {name} / {args.variants[0]} | {d[0] / g[0]:.2f} | {d[1] / g[1]:.2f} | "
              f"{d[2] / g[2]:.2f} | {d[3] / g[3]:.2f} |")


if __name__ == "__main__":
    main()
