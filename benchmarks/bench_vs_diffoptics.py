#!/usr/bin/env python
"""Our tracer (eager and compiled) against the paper's reference code (DiffOptics) on one lens.

The lens is the paper's double Gauss (US 2,532,751): ours loads ``data/lenses/double_gauss.json``,
DiffOptics its own table ``examples/lenses/DoubleGauss/US02532751-1.txt`` from the checkout given
by ``--reference`` (``git -C <mirror> archive HEAD diffoptics examples/lenses | tar -x -C DIR``;
nothing of DiffOptics is copied into this project, the script imports it from ``DIR``).  Both
trace the same rays: ``--rays`` on-axis rays on the entrance pupil (our ``field_rays``, 587.56
nm, float32), whose origins and directions are handed to DiffOptics' ``Ray`` unchanged.

Rows, per code:

* ``forward``: trace to the sensor plane without gradients (ours: ``trace_to_sensor``;
  DiffOptics: ``Lensgroup.trace`` plus the plane intersection of its ``trace_to_sensor``, which
  also returns the valid mask);
* ``trace + backward``: every curvature trainable, the RMS spot radius over the valid rays,
  ``backward()``.

Ours runs eager (``TraceOptions(compile=False)``) and compiled (``compile=True``; compiled and
warmed up before anything is timed).  Timing: one process holds all codes and alternates them
within each repeat (interleaved: a load change hits every code alike); process CPU time and wall
time, min and median of ``--repeats``.  Memory: each (code, row) in a fresh subprocess, peak RSS
during the call minus the RSS before it (``procmem``: glibc's mmap threshold at 16 KiB so that RSS
follows the live memory, the kernel's high-water mark reset before the call), after one warm-up
call at the full size.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_vs_diffoptics.py --reference /tmp/diffoptics
    OMP_NUM_THREADS=1 python benchmarks/bench_vs_diffoptics.py --reference /tmp/diffoptics \\
        --rays 1e5 --repeats 3          # smoke test
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

from procmem import maxrss_bytes, reset_peak_rss, rss_bytes, set_malloc_thresholds

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LENS = os.path.join(REPO, "data", "lenses", "double_gauss.json")
REF_LENS = os.path.join("examples", "lenses", "DoubleGauss", "US02532751-1.txt")
WAVELENGTH_NM = 587.5618
MIB = 1024.0 * 1024.0
ROWS = ("ours eager", "ours compiled", "DiffOptics")


class Setup:
    """Both lenses, the shared rays and the four calls (forward / backward per code)."""

    def __init__(self, reference: str, n: int):
        import torch

        sys.path.insert(0, REPO)
        sys.path.insert(1, reference)
        import diffoptics as do

        from deeplens.optics.io import load_lens
        from deeplens.optics.options import TraceOptions
        from deeplens.optics.paraxial import paraxial
        from deeplens.optics.sampling import field_rays, random_disk

        self.torch, self.do = torch, do
        self.lens = load_lens(LENS)
        self.curv = [s.c for s in self.lens.surfaces if hasattr(s, "c")]
        with torch.no_grad():
            p = paraxial(self.lens)
            r_ep, z_ep = 0.5 * float(p.entrance_pupil_diameter), float(p.entrance_pupil_z)
        xy = (r_ep * random_disk(n, seed=0)).to(torch.float32)
        self.rays = field_rays(self.lens, 0.0, WAVELENGTH_NM, xy, z_ep)
        self.opts = {"ours eager": TraceOptions(compile=False),
                     "ours compiled": TraceOptions(compile=True)}
        self.ref = do.Lensgroup(device=torch.device("cpu"))
        from pathlib import Path
        self.ref.load_file(Path(reference) / REF_LENS)
        self.ref_curv = [s.c for s in self.ref.surfaces if float(s.c) != 0.0]
        self.o = self.rays.o.detach().reshape(-1, 3).contiguous()
        self.d = self.rays.d.detach().reshape(-1, 3).contiguous()
        self.wl = torch.tensor([WAVELENGTH_NM])

    # ---------------------------------------------------------------- one call each
    def ours(self, row: str, grad: bool):
        torch = self.torch
        for c in self.curv:
            c.requires_grad_(grad)
            c.grad = None
        with torch.set_grad_enabled(grad):
            out = self.lens.trace_to_sensor(self.rays, options=self.opts[row])
            v = out.valid
            pts = out.o[..., :2][v]
            if grad:
                rms = torch.sqrt(((pts - pts.mean(0)) ** 2).sum(-1).mean())
                rms.backward()
        for c in self.curv:
            c.requires_grad_(False)
        return out.o.detach()[..., :2], v

    def diffoptics(self, grad: bool):
        torch = self.torch
        for c in self.ref_curv:
            c.requires_grad_(grad)
            c.grad = None
        with torch.set_grad_enabled(grad):
            ray = self.do.Ray(self.o.clone(), self.d.clone(), self.wl)
            final, valid = self.ref.trace(ray)
            t = (self.ref.d_sensor - final.o[..., 2]) / final.d[..., 2]
            p = final(t)[..., :2]
            if grad:
                pts = p[valid]
                rms = torch.sqrt(((pts - pts.mean(0)) ** 2).sum(-1).mean())
                rms.backward()
        for c in self.ref_curv:
            c.requires_grad_(False)
        return p.detach(), valid

    def call(self, row: str, grad: bool):
        return self.diffoptics(grad) if row == "DiffOptics" else self.ours(row, grad)


# ============================================================================ children
def _child_time(args) -> None:
    import torch
    torch.set_num_threads(args.threads)
    s = Setup(args.reference, int(float(args.rays)))
    small = Setup.__new__(Setup)  # compile on a few rays first (any count reuses the kernel)
    small.__dict__.update(s.__dict__)
    small.rays = s.rays[:4096]
    for grad in (False, True):
        small.ours("ours compiled", grad)
    res = {"threads": args.threads, "n": int(float(args.rays)), "surfaces": len(s.lens.surfaces)}
    # agreement: spot points and valid rays of the three
    pe, ve = s.call("ours eager", False)
    pc, vc = s.call("ours compiled", False)
    pr, vr = s.call("DiffOptics", False)
    both = ve & vr
    res.update(valid={"ours eager": int(ve.sum()), "ours compiled": int(vc.sum()),
                      "DiffOptics": int(vr.sum())},
               compiled_vs_eager_mm=float((pc - pe)[ve & vc].abs().max()),
               ref_vs_eager_mm=float((pr - pe)[both].abs().max()),
               ref_vs_eager_rms_mm=float(((pr - pe)[both] ** 2).sum(-1).mean().sqrt()))
    set_malloc_thresholds(32 * 1024 * 1024, 64 * 1024 * 1024)
    for row in ROWS:  # warm-up at full size
        for grad in (False, True):
            s.call(row, grad)
    times = {f"{row}|{g}": {"wall": [], "cpu": []} for row in ROWS for g in (False, True)}
    for _ in range(args.repeats):
        for grad in (False, True):
            for row in ROWS:
                t0, c0 = time.perf_counter(), time.process_time()
                s.call(row, grad)
                rec = times[f"{row}|{grad}"]
                rec["wall"].append(time.perf_counter() - t0)
                rec["cpu"].append(time.process_time() - c0)
    res["times"] = times
    res["load"] = os.getloadavg()[0]
    print(json.dumps(res))


def _child_mem(args) -> None:
    import torch
    torch.set_num_threads(args.threads)
    s = Setup(args.reference, int(float(args.rays)))
    grad = args.grad == "1"
    if args.row == "ours compiled":
        small = Setup.__new__(Setup)
        small.__dict__.update(s.__dict__)
        small.rays = s.rays[:4096]
        small.ours(args.row, grad)
    s.call(args.row, grad)  # warm-up at full size (allocator, caches)
    set_malloc_thresholds(16 * 1024, 128 * 1024)
    rss0 = rss_bytes()
    reset_peak_rss()
    s.call(args.row, grad)
    print(json.dumps({"extra_bytes": maxrss_bytes() - rss0}))


# ============================================================================ parent
def _run(args, extra: list) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--reference", args.reference, "--rays",
           str(args.rays), "--repeats", str(args.repeats), "--threads", str(args.threads), *extra]
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads))
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if out.returncode != 0:
        sys.stderr.write(out.stderr)
        raise SystemExit(f"benchmark child failed: {extra}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reference", required=True,
                    help="a DiffOptics checkout (the folder holding diffoptics/ and examples/)")
    ap.add_argument("--rays", default="1e6")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-memory", action="store_true", help="timing only")
    ap.add_argument("--json", default=None, help="save every number here")
    ap.add_argument("--child", choices=["time", "mem"], help=argparse.SUPPRESS)
    ap.add_argument("--row", help=argparse.SUPPRESS)
    ap.add_argument("--grad", help=argparse.SUPPRESS)
    args = ap.parse_args()
    args.reference = os.path.abspath(args.reference)
    if not os.path.isfile(os.path.join(args.reference, "diffoptics", "optics.py")):
        raise SystemExit(f"--reference {args.reference}: expected a DiffOptics checkout "
                         f"(diffoptics/optics.py and {REF_LENS}) there")
    if args.child == "time":
        _child_time(args)
        return
    if args.child == "mem":
        _child_mem(args)
        return
    load0 = os.getloadavg()
    print("[bench_vs_diffoptics] timing (interleaved)", file=sys.stderr, flush=True)
    res = _run(args, ["--child", "time"])
    mem = {}
    if not args.no_memory:
        for row in ROWS:
            for grad in ("0", "1"):
                print(f"[bench_vs_diffoptics] memory: {row}, grad={grad}", file=sys.stderr,
                      flush=True)
                mem[f"{row}|{grad == '1'}"] = _run(
                    args, ["--child", "mem", "--row", row, "--grad", grad])["extra_bytes"]
    res["memory"] = mem
    load1 = os.getloadavg()
    import torch
    n = res["n"]
    print(f"double Gauss, {n:.0e} on-axis rays, float32, {args.threads} thread(s), "
          f"CPU capability {torch.backends.cpu.get_cpu_capability()}, {args.repeats} interleaved "
          f"repeats; load average (1 min) {load0[0]:.1f} at the start, {res['load']:.1f} after "
          f"the timing, {load1[0]:.1f} at the end; {os.cpu_count()} CPUs\n")
    print("| row | code | CPU s (min) | CPU s (median) | wall s (min) | x DiffOptics (CPU, min) "
          "| peak extra MiB |")
    print("|---|---|---|---|---|---|---|")
    for grad, label in ((False, "forward"), (True, "trace + backward")):
        ref = min(res["times"][f"DiffOptics|{grad}"]["cpu"])
        for row in ROWS:
            t = res["times"][f"{row}|{grad}"]
            m = mem.get(f"{row}|{grad}")
            mtxt = "" if m is None else f"{m / MIB:.0f}"
            print(f"| {label} | {row} | {min(t['cpu']):.3f} | {statistics.median(t['cpu']):.3f} "
                  f"| {min(t['wall']):.3f} | {ref / min(t['cpu']):.2f} | {mtxt} |")
    print(f"\nvalid rays: {res['valid']}; spot points: compiled vs eager within "
          f"{res['compiled_vs_eager_mm']:.1e} mm, DiffOptics vs ours max {res['ref_vs_eager_mm']:.1e}"
          f" mm (RMS {res['ref_vs_eager_rms_mm']:.1e} mm; its glasses are a two-term Cauchy fit)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=1)


if __name__ == "__main__":
    main()
