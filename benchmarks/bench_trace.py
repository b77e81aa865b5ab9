#!/usr/bin/env python
"""Throughput and memory of the core tracer: double Gauss, on-axis rays, float32.

Rows (each code base runs in its own fresh subprocess, so memory and cold start are per process):

* ``forward``: ``lens.trace_to_sensor(rays)`` under ``torch.no_grad()``;
* ``trace + backward``: the same trace with every curvature trainable, the RMS spot radius
  ``sqrt(mean |p - mean p|^2)`` over the valid rays and ``loss.backward()``; again with
  ``TraceOptions(checkpoint=True)`` where the code has it (surfaces recomputed in backward);
* ``cold start``: a fresh interpreter: ``import torch, deeplens``, load the lens, build the rays,
  one trace + backward (the seconds column is the whole wall time, rays/s uses it too);
* ``compile=...`` rows (code with ``TraceOptions(compile=...)``): the same rows through the
  compiled kernels, ``"lens"`` (one kernel per run of spheres/planes/stop) and ``"surface"``
  (one per surface) for each; ``compile=True`` picks ``"lens"`` without and ``"surface"`` with
  gradients.  Their compilation is warmed up before anything is measured, and has its own rows:
  a fresh interpreter with an empty inductor cache (``TORCHINDUCTOR_CACHE_DIR`` a new temporary
  folder): the first compiled forward and the first compiled trace + backward, each including
  its compilation; then a second fresh interpreter on the now filled disk cache.

Columns:

* ``rays/s`` and ``s``: wall time, min over ``--repeats`` runs after one warm-up (the machine is
  shared: the minimum is the least disturbed run); ``CPU s``: the process's CPU time (all
  threads), min over the same runs (less sensitive to other processes than the wall time);
* ``extra MiB``: peak RSS during the run minus the RSS before it (glibc set up so that RSS follows
  the live memory: 16 KiB mmap threshold; the kernel's high-water mark is reset through
  ``/proc/self/clear_refs``);
* ``B/ray-surf``: memory held between forward and backward (the autograd graph) per ray and
  surface;
* ``% BW``: the traffic of a tracer that reads and writes each ray's state once per surface
  (o, d, opl in the working dtype plus the valid byte: 2 x 29 B in float32) at the measured
  rays/s, divided by the memory bandwidth measured *in the same process* by a large tensor copy
  (``b.copy_(a)``, 256 MiB, counted as read + write).  A ratio survives a noisy machine better
  than rays/s.

``--base PATH`` adds the same rows for the deeplens package found under ``PATH`` (e.g. the
original code: ``git worktree add /tmp/perf-base 4a786b9``), run in the same invocation, and the
largest relative difference of the curvature gradients between the two (results must not change).

Usage::

    python benchmarks/bench_trace.py                              # this checkout
    python benchmarks/bench_trace.py --base /tmp/perf-base        # before / after
    python benchmarks/bench_trace.py --quick                      # 1e5 rays, smoke test

CPU time is the benchmark process's own: inductor's C++ compiler runs in subprocesses, so the
cold rows' CPU time leaves compilation out; their wall time includes it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from procmem import maxrss_bytes as _maxrss_bytes
from procmem import reset_peak_rss as _reset_peak_rss
from procmem import rss_bytes as _rss_bytes
from procmem import set_malloc_thresholds

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LENS = os.path.join("data", "lenses", "double_gauss.json")
MIB = 1024.0 * 1024.0
WAVELENGTH_NM = 587.5618


# ============================================================================ child process

def _child(args) -> None:
    t_start = time.perf_counter()
    sys.path.insert(0, args.code)
    import torch

    import deeplens  # noqa: F401
    from deeplens.optics.paraxial import paraxial
    from deeplens.optics.io import load_lens
    from deeplens.optics.sampling import field_rays, random_disk

    torch.set_num_threads(args.threads)
    dtype = getattr(torch, args.dtype)
    n = int(float(args.rays))
    lens = load_lens(os.path.join(REPO, LENS))
    curv = [s.c for s in lens.surfaces if hasattr(s, "c")]
    with torch.no_grad():
        p = paraxial(lens)
        r_ep = 0.5 * float(p.entrance_pupil_diameter)
        z_ep = float(p.entrance_pupil_z)
    xy = (r_ep * random_disk(n, seed=0)).to(dtype)
    rays = field_rays(lens, 0.0, WAVELENGTH_NM, xy, z_ep)
    n_surf = len(lens.surfaces)

    from deeplens.optics.options import TraceOptions
    try:
        ckpt = TraceOptions(checkpoint=True)
    except TypeError:  # code without the option
        ckpt = None
    try:
        comp = {m: TraceOptions(compile=m) for m in ("lens", "surface")}
        comp["surface+ckpt"] = TraceOptions(compile="surface", checkpoint=True)
    except TypeError:  # code without compiled kernels
        comp = None

    def trace_backward(keep=None, options=None):
        for c in curv:
            c.requires_grad_(True)
            c.grad = None
        out = lens.trace_to_sensor(rays, options=options)
        v = out.valid
        pts = out.o[..., :2][v]
        cen = pts.mean(0)
        rms = torch.sqrt(((pts - cen) ** 2).sum(-1).mean())
        if keep is not None:
            keep()
        rms.backward()
        for c in curv:
            c.requires_grad_(False)
        return float(rms), [float(c.grad) for c in curv], int(v.sum())

    res = {"code": args.code, "n": n, "surfaces": n_surf, "threads": args.threads}
    if args.cold_compile:
        if comp is None:
            print(json.dumps(res))
            return
        res["import_s"] = time.perf_counter() - t_start
        t0, c0 = time.perf_counter(), time.process_time()
        with torch.no_grad():
            lens.trace_to_sensor(rays, options=TraceOptions(compile=True))
        res["first_fwd_s"], res["first_fwd_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
        t0, c0 = time.perf_counter(), time.process_time()
        trace_backward(None, TraceOptions(compile=True))
        res["first_bwd_s"], res["first_bwd_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
        res["cold_s"] = time.perf_counter() - t_start
        print(json.dumps(res))
        return
    if args.cold:
        rms, grads, nvalid = trace_backward()
        res.update(cold_s=time.perf_counter() - t_start, rms=rms, grads=grads, valid=nvalid)
        print(json.dumps(res))
        return

    # memory bandwidth: a large copy, read + write
    a = torch.rand(64 * 1024 * 1024)
    b = torch.empty_like(a)
    bw = []
    for _ in range(max(3, args.repeats)):
        t0 = time.perf_counter()
        b.copy_(a)
        bw.append(2 * a.numel() * a.element_size() / (time.perf_counter() - t0))
    res["bandwidth_Bps"] = max(bw)
    del a, b

    if comp is not None:  # compile every kernel before anything is measured, on a few rays (the
        all_rays, rays = rays, rays[:4096]  # kernels take any ray count; a full-size warm-up
        with torch.no_grad():               # would leave glibc's heap holding its memory)
            for opt in comp.values():
                lens.trace_to_sensor(rays, options=opt)
        for opt in comp.values():
            trace_backward(None, opt)
        rays = all_rays

    # memory: RSS follows the live memory
    set_malloc_thresholds(16 * 1024, 128 * 1024)
    graph = {}

    def held():
        graph["after_forward"] = _rss_bytes()

    rss0 = _rss_bytes()
    _reset_peak_rss()
    with torch.no_grad():
        lens.trace_to_sensor(rays)
    res["fwd_extra_bytes"] = _maxrss_bytes() - rss0
    fwd_modes, bwd_modes = [], [("bwd", None), ("ckpt", ckpt)]
    if comp is not None:
        fwd_modes = [("fwd_lens", comp["lens"]), ("fwd_surface", comp["surface"])]
        bwd_modes += [("bwd_surface", comp["surface"]), ("bwd_lens", comp["lens"]),
                      ("ckpt_surface", comp["surface+ckpt"])]
    for key, opt in fwd_modes:
        rss0 = _rss_bytes()
        _reset_peak_rss()
        with torch.no_grad():
            lens.trace_to_sensor(rays, options=opt)
        res[key + "_extra_bytes"] = _maxrss_bytes() - rss0
    for key, opt in bwd_modes:
        if opt is None and key != "bwd":
            continue
        rss0 = _rss_bytes()
        _reset_peak_rss()
        rms, grads, nvalid = trace_backward(held, opt)
        res[key + "_extra_bytes"] = _maxrss_bytes() - rss0
        res[key + "_graph_bytes"] = graph["after_forward"] - rss0
        if key == "bwd":
            res.update(rms=rms, grads=grads, valid=nvalid)
        else:
            res[key + "_grads"] = grads

    # timing: glibc recycles tensors in its heap; wall and process CPU time, min of N
    set_malloc_thresholds(32 * 1024 * 1024, 64 * 1024 * 1024)

    def timed(fn):
        fn()
        wall, cpu = [], []
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        return min(wall), min(cpu)

    def forward():
        with torch.no_grad():
            lens.trace_to_sensor(rays)

    res["fwd_s"], res["fwd_cpu_s"] = timed(forward)
    res["bwd_s"], res["bwd_cpu_s"] = timed(trace_backward)
    if ckpt is not None:
        res["ckpt_s"], res["ckpt_cpu_s"] = timed(lambda: trace_backward(None, ckpt))
    for key, opt in fwd_modes:
        def fwd(opt=opt):
            with torch.no_grad():
                lens.trace_to_sensor(rays, options=opt)
        res[key + "_s"], res[key + "_cpu_s"] = timed(fwd)
    for key, opt in bwd_modes[2:]:
        res[key + "_s"], res[key + "_cpu_s"] = timed(lambda opt=opt: trace_backward(None, opt))
    with torch.no_grad():  # results of the compiled forward against eager
        for key, opt in fwd_modes:
            a, b = lens.trace_to_sensor(rays), lens.trace_to_sensor(rays, options=opt)
            res[key + "_maxdiff_mm"] = float((a.o - b.o)[a.valid].abs().max())
            res[key + "_same_valid"] = bool(torch.equal(a.valid, b.valid))
    print(json.dumps(res))


# ============================================================================ parent
def _run(args, code: str, cold, cache_dir: str) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--one", code, "--rays", str(args.rays),
           "--repeats", str(args.repeats), "--threads", str(args.threads), "--dtype", args.dtype]
    if cold:
        cmd.append("--cold" if cold is True else "--cold-compile")
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads), TORCHINDUCTOR_CACHE_DIR=cache_dir)
    env.pop("PYTHONPATH", None)
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd="/", check=False)
    if out.returncode != 0:
        sys.stderr.write(out.stderr)
        raise SystemExit(f"benchmark child failed for {code}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _fmt_rate(x: float) -> str:
    return f"{x:.3g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rays", default="1e6")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    ap.add_argument("--base", default=None, help="path of a checkout with the code to compare")
    ap.add_argument("--quick", action="store_true", help="1e5 rays, 3 repeats")
    ap.add_argument("--json", default=None, help="save every number here")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--cold", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--cold-compile", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        args.code = args.one
        _child(args)
        return
    if args.quick:
        args.rays, args.repeats = "1e5", 3
    codes = ([("before", os.path.abspath(args.base))] if args.base else []) + [("after", REPO)]
    results = {}
    load = os.getloadavg()
    for label, code in codes:
        print(f"[bench_trace] {label}: {code}", file=sys.stderr, flush=True)
        with tempfile.TemporaryDirectory(prefix="bench-trace-inductor-") as cache:
            results[label] = {
                "cold": _run(args, code, True, cache),
                "cold_compile": _run(args, code, "compile", cache),   # empty inductor cache
                "cold_compile_cached": _run(args, code, "compile", cache),  # filled by the above
                "warm": _run(args, code, False, cache)}
    load_end = os.getloadavg()
    n = int(float(args.rays))
    per_ray_surface_traffic = 2 * (7 * (4 if args.dtype == "float32" else 8) + 1)
    print(f"double Gauss ({LENS}), {n:.0e} on-axis rays, {args.dtype}, {args.threads} threads, "
          f"min of {args.repeats}; load average (1 min) {load[0]:.1f} at the start, "
          f"{load_end[0]:.1f} at the end, {os.cpu_count()} CPUs\n")
    print("| code | row | rays/s | s | CPU s | extra MiB | B/ray-surf | % BW |")
    print("|---|---|---|---|---|---|---|---|")
    for label, r in results.items():
        w, c = r["warm"], r["cold"]
        S, bw = w["surfaces"], w["bandwidth_Bps"]
        rows = [("forward", "fwd"), ("trace + backward", "bwd"),
                ("trace + backward, checkpoint=True", "ckpt"),
                ("forward, compile=\"lens\" (= True)", "fwd_lens"),
                ("forward, compile=\"surface\"", "fwd_surface"),
                ("trace + backward, compile=\"surface\" (= True)", "bwd_surface"),
                ("trace + backward, compile=\"lens\"", "bwd_lens"),
                ("trace + backward, compile=\"surface\", checkpoint=True", "ckpt_surface")]
        for row, key in rows:
            if key + "_s" not in w:
                continue
            secs = w[key + "_s"]
            rate = n / secs
            frac = rate * S * per_ray_surface_traffic / bw
            graph = w.get(key + "_graph_bytes")
            bprs = "" if graph is None else f"{graph / (n * S):.0f}"
            print(f"| {label} | {row} | {_fmt_rate(rate)} | {secs:.3f} | {w[key + '_cpu_s']:.3f} | "
                  f"{w[key + '_extra_bytes'] / MIB:.0f} | {bprs} | {100 * frac:.1f} |")
        print(f"| {label} | cold start (import + first trace + backward) | "
              f"{_fmt_rate(n / c['cold_s'])} | {c['cold_s']:.2f} | | | | |")
        for key, what in (("cold_compile", "empty inductor cache"),
                          ("cold_compile_cached", "inductor disk cache filled")):
            cc = r[key]
            if "first_fwd_s" not in cc:
                continue
            print(f"| {label} | cold, {what}: import | | {cc['import_s']:.2f} | | | | |")
            print(f"| {label} | cold, {what}: first forward, compile=True (incl. compiling) | "
                  f"{_fmt_rate(n / cc['first_fwd_s'])} | {cc['first_fwd_s']:.2f} | "
                  f"{cc['first_fwd_cpu_s']:.2f} | | | |")
            print(f"| {label} | cold, {what}: first trace + backward, compile=True (incl. "
                  f"compiling) | {_fmt_rate(n / cc['first_bwd_s'])} | {cc['first_bwd_s']:.2f} | "
                  f"{cc['first_bwd_cpu_s']:.2f} | | | |")
    bws = ", ".join(f"{k} {v['warm']['bandwidth_Bps'] / 1e9:.1f}" for k, v in results.items())
    print(f"\nmemory bandwidth (copy, read + write) GB/s: {bws}")
    if "before" in results:
        gb, ga = results["before"]["warm"]["grads"], results["after"]["warm"]["grads"]
        scale = max(abs(g) for g in gb)
        diff = max(abs(a - b) for a, b in zip(ga, gb)) / scale
        rb, ra = results["before"]["warm"]["rms"], results["after"]["warm"]["rms"]
        print(f"RMS spot before {rb:.7g} mm, after {ra:.7g} mm (rel. diff {abs(ra - rb) / rb:.1e});"
              f" curvature gradients: max |after - before| / max |before| = {diff:.1e}; "
              f"valid rays {results['before']['warm']['valid']} / "
              f"{results['after']['warm']['valid']}")
    w = results["after"]["warm"]
    scale = max(abs(g) for g in w["grads"])
    for key in ("ckpt", "bwd_surface", "bwd_lens", "ckpt_surface"):
        if key + "_grads" in w:
            d = max(abs(a - b) for a, b in zip(w[key + "_grads"], w["grads"]))
            print(f"{key} gradients: max |difference| to the eager trace's / max |gradient| = "
                  f"{d / scale:.1e}")
    for key in ("fwd_lens", "fwd_surface"):
        if key + "_maxdiff_mm" in w:
            print(f"{key}: spot points within {w[key + '_maxdiff_mm']:.1e} mm of eager's, same "
                  f"valid rays: {w[key + '_same_valid']}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()
