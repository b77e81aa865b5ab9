#!/usr/bin/env python
"""The default tracer schedule (``TraceOptions(compile="default")``) against the forced modes.

Each workload runs in a fresh interpreter with an **empty** inductor cache (a new
``TORCHINDUCTOR_CACHE_DIR``), in three modes: ``eager`` (``compile=False``, the off switch),
``default`` (the ski-rental rule of :mod:`deeplens.optics.compile_policy`) and ``forced``
(``compile=True``).  The whole workload is timed, compilation included, so the table answers
"what does a user's call cost", not "how fast is a warm kernel".

Workloads (the shipped double Gauss, float32, rays uniformly random in the entrance pupil):

* ``one-off``: one forward trace of 1e6 rays (an analysis call);
* ``loop S x N``: ``S`` steps of Adam on every curvature, each a trace of ``N`` rays and the
  backward of the RMS spot (a design loop or a training step).

``--experiments`` also prints, for ``experiment=edof`` and ``experiment=doublet`` at their
shipped step counts, the choice ``render.compile=default`` makes after the first training step
(:mod:`deeplens.training.compile_choice`) and its reason.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_compile_policy.py            # ~15 min idle
    OMP_NUM_THREADS=1 python benchmarks/bench_compile_policy.py --quick    # ~3 min
    python benchmarks/bench_compile_policy.py --experiments-only
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODES = {"eager": False, "default": "default", "forced": True}


def _one(mode: str, steps: int, n_rays: int) -> dict:
    import torch

    from deeplens.optics.io import load_lens
    from deeplens.optics.options import TraceOptions
    from deeplens.optics.paraxial import paraxial
    from deeplens.optics.sampling import field_rays, random_disk

    torch.manual_seed(0)
    lens = load_lens(ROOT / "data" / "lenses" / "double_gauss.json")
    opts = TraceOptions(compile=MODES[mode])
    with torch.no_grad():
        p = paraxial(lens)
        r_ep, z_ep = 0.5 * float(p.entrance_pupil_diameter), float(p.entrance_pupil_z)
    rays = field_rays(lens, 0.0, 587.6, r_ep * random_disk(n_rays, seed=0), z_ep)
    t0, c0 = time.perf_counter(), time.process_time()
    if steps == 0:
        with torch.no_grad():
            out = lens.trace_to_sensor(rays, options=opts)
        result = float(out.valid.sum())
        switched = None
    else:
        params = [s.c for s in lens.surfaces if hasattr(s, "c") and s.c.numel() == 1]
        for p in params:
            p.requires_grad_(True)
        adam = torch.optim.Adam(params, lr=1e-6)
        switched = None
        for k in range(steps):
            before = dict(opts.ledger.saved)
            out = lens.trace_to_sensor(rays, options=opts)
            v = out.valid
            p = out.o[..., :2][v]
            loss = ((p - p.mean(0)) ** 2).sum(-1).mean().sqrt()
            adam.zero_grad()
            loss.backward()
            adam.step()
            if switched is None and mode == "default" and opts.ledger.saved == before \
                    and before:
                switched = k
        result = float(loss.detach())
    return {"s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
            "result": result, "switched_at_step": switched,
            "maxrss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _run(mode: str, steps: int, n_rays: int) -> dict:
    env = dict(os.environ)
    env["TORCHINDUCTOR_CACHE_DIR"] = tempfile.mkdtemp(prefix="inductor-empty-")
    env.pop("DEEPLENS_COMPILE", None)
    out = subprocess.run([sys.executable, __file__, "--one", mode, str(steps), str(n_rays)],
                         env=env, capture_output=True, text=True, cwd=ROOT)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def _experiment_choice(exp: str) -> str:
    """Run ``train.py experiment=<exp>`` until it prints its choice; the line."""
    env = dict(os.environ, TORCHINDUCTOR_CACHE_DIR=tempfile.mkdtemp(prefix="inductor-empty-"))
    out_dir = tempfile.mkdtemp(prefix=f"choice-{exp}-")
    p = subprocess.Popen([sys.executable, "train.py", f"experiment={exp}", "~logger",
                          "callbacks.image_logger=null", "trainer.enable_progress_bar=false",
                          f"hydra.run.dir={out_dir}"], cwd=ROOT, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    line = "(no choice printed)"
    try:
        for raw in p.stdout:
            if "render.compile=default" in raw:
                line = re.sub(r"^.*deeplens: ", "", raw.strip())
                break
    finally:
        p.kill()
        p.wait()
    return line


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller loops (~3 min)")
    ap.add_argument("--experiments", action="store_true",
                    help="also print the choice of experiment=edof and experiment=doublet")
    ap.add_argument("--experiments-only", action="store_true")
    ap.add_argument("--one", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        mode, steps, n = args.one
        print(json.dumps(_one(mode, int(steps), int(n))))
        return
    import torch

    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    print(f"torch {torch.__version__}, OMP_NUM_THREADS={threads}, "
          f"CPU capability {torch.backends.cpu.get_cpu_capability()}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"load average {os.getloadavg()[0]:.1f}\n")
    if not args.experiments_only:
        work = ([("one-off trace, 1e6 rays", 0, 1_000_000), ("loop 300 x 2e4 rays", 300, 20_000),
                 ("loop 800 x 2e5 rays", 800, 200_000)] if not args.quick else
                [("one-off trace, 1e5 rays", 0, 100_000), ("loop 100 x 2e4 rays", 100, 20_000)])
        print("| workload | mode | wall s (incl. compiling) | CPU s | switched at step | "
              "peak RSS MiB |")
        print("|---|---|---|---|---|---|")
        for label, steps, n in work:
            for mode in MODES:
                r = _run(mode, steps, n)
                sw = "" if mode != "default" else (
                    "never (eager)" if r["switched_at_step"] is None else r["switched_at_step"])
                print(f"| {label} | {mode} | {r['s']:.1f} | {r['cpu_s']:.1f} | {sw} | "
                      f"{r['maxrss_mib']:.0f} |", flush=True)
        print("\n(CPU s is the benchmark process's own: inductor's compiler runs in "
              "subprocesses, so it leaves compilation out; wall s includes it.)")
    if args.experiments or args.experiments_only:
        print()
        for exp in ("edof", "doublet"):
            print(f"- `experiment={exp}`: {_experiment_choice(exp)}", flush=True)


if __name__ == "__main__":
    main()
