#!/usr/bin/env python
"""Per-surface-kind cost of a traced ray, eager and compiled: the constants of the compile
cost model (:mod:`deeplens.optics.compile_policy`).

For each kind the compiled tracer fuses (:func:`deeplens.optics.tracer.fused_kind`) a lens of
``K`` surfaces of that kind (alternating N-BK7 and air, 2 mm apart, a collimated on-axis beam
of ``N`` rays filling 0.8 of the 10 mm semi-diameter) is traced to its sensor, without and with
gradients (``backward()`` of the mean landing position; the curvatures and the aspheric or
polynomial coefficients trainable, as in a design loop or training run):

* ``quadric``: spheres (c = 0.02/mm, so every gap is 2 mm thick at every height);
* ``newton``: even aspheres (the same spheres with a4 = 1e-6/mm^3, a6 = 0), and XY-polynomial
  plates (cubic coefficients 1e-5), both through the Newton kernels;
* ``plane``: planes (with gradients: of the rays' origins, planes have no shape).

Each configuration runs in a fresh interpreter; the warm step's CPU time (median of ``--reps``
after two warm-up traces, so compiling is left out) is divided by ``N * K`` and printed per
kind, eager and compiled, with the modelled constants beside it.  Process CPU time is used, so
the numbers mostly hold on a loaded machine (cache sharing aside); the thread count is the
process's ``OMP_NUM_THREADS``.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_compile_kinds.py            # ~6 min idle
    OMP_NUM_THREADS=2 python benchmarks/bench_compile_kinds.py --rays 200000
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # this checkout's deeplens
KINDS = ("quadric", "newton_asphere", "newton_xy", "plane")


def _lens_dict(kind: str, k: int) -> dict:
    surfaces = []
    for i in range(k):
        mat = "N-BK7" if i % 2 == 0 else "AIR"
        c = 0.02   # concentric-like shells: every gap 2 mm thick at any height
        s = {"semi_diameter_mm": 10.0, "distance_mm": 0.0 if i == 0 else 2.0, "material": mat}
        if kind == "plane":
            s["type"] = "plane"
        elif kind == "newton_xy":
            s.update(type="xy_polynomial", b=0.0,
                     coefficients=[0.0] * 6 + [1e-5, 0.0, 0.0, 1e-5])
        else:
            s.update(type="asphere", curvature_per_mm=c, conic=0.0)
            if kind == "newton_asphere":
                s["aspheric"] = [1e-6, 0.0]
        surfaces.append(s)
    return {"format": "deeplens-lens", "version": 1, "name": f"{k} x {kind}",
            "units": {"length": "mm", "wavelength": "nm"},
            "object": {"distance_mm": "inf", "medium": "AIR"},
            "aperture": {"type": "epd", "value": 16.0}, "fields_deg": [0.0],
            "wavelengths_nm": [587.5618], "primary_wavelength_nm": 587.5618, "stop": 0,
            "surfaces": surfaces, "sensor": {"distance_mm": 20.0, "semi_diameter_mm": 30.0}}


def _one(kind: str, compiled: bool, grad: bool, n_rays: int, k: int, reps: int) -> dict:
    import torch

    from deeplens.optics.io.lensfile import lens_from_dict
    from deeplens.optics.options import TraceOptions
    from deeplens.optics.sampling import field_rays, random_disk

    lens = lens_from_dict(_lens_dict(kind, k))
    for name, p in lens.named_parameters():   # the shape, as a design or training run varies it
        p.requires_grad_(grad and (name.endswith(".c") or ".a." in name))
    opts = TraceOptions(compile=True if compiled else False)
    rays = field_rays(lens, 0.0, 587.5618, 8.0 * random_disk(n_rays, seed=0), -1.0)
    if grad and not any(p.requires_grad for p in lens.parameters()):
        rays.o.requires_grad_(True)   # planes: nothing to train, the rays carry the gradient

    def step():
        with torch.set_grad_enabled(grad):
            out = lens.trace_to_sensor(rays, options=opts)
            if grad:
                out.o[..., :2][out.valid].mean().backward()
        return int(out.valid.sum())

    for _ in range(2):
        kept = step()
    times = []
    for _ in range(reps):
        c0 = time.process_time()
        step()
        times.append(time.process_time() - c0)
    return {"cpu_s": statistics.median(times), "kept": kept}


def _run(kind, compiled, grad, n_rays, k, reps, cache) -> dict:
    env = dict(os.environ, TORCHINDUCTOR_CACHE_DIR=cache)
    env.pop("DEEPLENS_COMPILE", None)
    out = subprocess.run([sys.executable, __file__, "--one", kind, str(int(compiled)),
                          str(int(grad)), str(n_rays), str(k), str(reps)],
                         env=env, capture_output=True, text=True, cwd=ROOT)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--surfaces", type=int, default=8)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--json", help="also write the numbers here")
    ap.add_argument("--cache", help="inductor cache folder to use (default: a new, empty one)")
    ap.add_argument("--one", nargs=6, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        kind, comp, grad, n, k, reps = args.one
        print(json.dumps(_one(kind, bool(int(comp)), bool(int(grad)), int(n), int(k),
                              int(reps))))
        return 0
    import torch

    from deeplens.optics import compile_policy as P

    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    print(f"torch {torch.__version__}, OMP_NUM_THREADS={threads}, CPU capability "
          f"{torch.backends.cpu.get_cpu_capability()}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load average "
          f"{os.getloadavg()[0]:.1f}; {args.rays} rays x {args.surfaces} surfaces, CPU s per "
          f"ray-surface (median of {args.reps} warm traces)\n")
    print("| kind | gradients | eager | compiled | eager / compiled | saving | "
          "model saving |")
    print("|---|---|---|---|---|---|---|")
    cache = args.cache or tempfile.mkdtemp(prefix="inductor-kinds-")
    rows = []
    for kind in args.kinds.split(","):
        for grad in (False, True):
            e, c = (_run(kind, comp, grad, args.rays, args.surfaces, args.reps, cache)
                    for comp in (False, True))
            per = args.rays * args.surfaces
            es, cs = e["cpu_s"] / per, c["cpu_s"] / per
            model_kind = {"quadric": "quadric", "plane": "plane"}.get(kind, "newton")
            model = P.saving_per_ray_surface(model_kind, grad)
            rows.append({"kind": kind, "grad": grad, "eager_s": es, "compiled_s": cs,
                         "kept": e["kept"], "model_saving_s": model})
            print(f"| {kind} | {'yes' if grad else 'no'} | {es:.3g} | {cs:.3g} | {es / cs:.1f} | "
                  f"{es - cs:.3g} | {model:.3g} |", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"threads": threads, "rays": args.rays,
                                               "surfaces": args.surfaces, "rows": rows},
                                              indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
