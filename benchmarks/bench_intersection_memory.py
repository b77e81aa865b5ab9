#!/usr/bin/env python
"""Memory and time of the gradient through the ray-surface intersection: implicit vs unrolled.

Reproduces the claim of the dO paper (Sec. II-C, Fig. 4): solving ``f(o + t d; θ) = 0`` by
Newton *without* autograd and then taking one differentiable Newton step (Eq. 7,
``TraceOptions(mode="implicit")``) needs several times less memory for the backward pass than
recording every Newton iteration in the autograd graph (``mode="unrolled"``).

Workload (one configuration = surface, size, number of rays, mode):

* a freeform surface with non-trivial coefficients, all of them trainable
  (``requires_grad_(True)``):
  - ``xy``:      :class:`XYPolynomial` of order J (``(J+1)(J+2)/2`` coefficients + ``b``): a conic-like
    toric base plus random higher-order terms;
  - ``bspline``: :class:`BSpline` on an ``n x n`` control grid: a curved base plus a smooth random
    deformation;
* ``N`` rays starting 1 mm before the vertex plane, spread over 85 % of the aperture and tilted up
  to 8 degrees, so that Newton needs several iterations from the vertex-plane start;
* ``t, x, ok = intersect(surface, o, d, valid, TraceOptions(mode=...))`` and the non-constant
  loss ``sum(ok * x * w)`` with fixed random weights ``w``; ``loss.backward()`` to the coefficients
  (``--ray-grad``: and to ``o`` and ``d``, as inside a lens where upstream surfaces move the rays;
  the implicit step then keeps more, and the ratio drops to about the Newton iteration count).

Each configuration runs in a fresh subprocess (``--one``) so that peak memory is per process:

* ``peak MiB`` = peak RSS during the first full-size forward + backward minus the RSS right
  before it (the kernel's high-water mark is reset after setup through ``/proc/self/clear_refs``
  and read back with ``resource.getrusage().ru_maxrss``).  On CUDA also
  ``torch.cuda.max_memory_allocated`` minus the allocation before the run.
* ``graph MiB`` = memory still held between forward and backward (the autograd graph).
* ``time s`` = median (and min) forward + backward wall time over a few repeats after the
  warm-up; slow configurations get fewer repeats, at least two (``--repeats``, ``--time-budget``).
* ``Newton its`` = mean / max Newton updates per ray to reach the tolerance (the unrolled graph
  records ``max`` iterations for every ray).
* ``grad diff`` = ``max|g_unrolled - g_implicit| / max|g_implicit|``: both modes compute the same
  gradient, up to the Newton tolerance.

Allocator (Linux/glibc).  The memory run uses a fixed 16 KiB mmap threshold, so that freed tensors
go back to the OS and RSS follows the live memory (with glibc's default dynamic threshold freed
tensors stay in the heap and RSS reaches 1.2-3x the live peak), and the subprocesses get
``THP_MEM_ALLOC_ENABLE=1`` (torch puts allocations >= 2 MiB in transparent huge pages) so that
those fresh mappings fault in 2 MiB pages.  The timed runs then switch to the steady state of
glibc's default thresholds (tensors recycled in the heap: fresh mappings are zero-filled and 2-5x
slower here), unless the heap could take the process past ``--max-mem-gib``: then both modes of
that size are timed like the memory run and marked †.  ``--malloc-default`` leaves malloc alone.

Threads: one per subprocess by default (``--threads``): with 2 OpenMP threads on a busy 2-core
machine a descheduled thread stalls every parallel op (0.1 s became 10 s in our runs).

Memory safety: a configuration whose peak, extrapolated linearly in the number of rays from the
smaller sizes, would exceed ``--max-mem-gib`` (default 8) is skipped, and a subprocess whose RSS
passes that budget plus 1.5 GiB is killed.

Usage::

    python benchmarks/bench_intersection_memory.py            # default: 1e4, 1e5, 1e6 rays
    python benchmarks/bench_intersection_memory.py --quick    # smoke test, < 1 min
    python benchmarks/bench_intersection_memory.py --large --device cuda --dtype float32
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import statistics
import subprocess
import sys
import time

from procmem import maxrss_bytes as _maxrss_bytes
from procmem import reset_peak_rss as _reset_peak_rss
from procmem import rss_bytes as _rss_bytes

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SEMI_DIAMETER = 10.0  # mm
BASE_RADIUS = 15.0    # mm, base curvature radius of both freeforms (sag ~3 mm at the edge)
MIB = 1024.0 * 1024.0


# ============================================================================ child process

def _glibc():
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt, libc.malloc_trim  # noqa: B018 - glibc only
        return libc
    except (OSError, AttributeError):
        return None


_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc <malloc.h>


def _malloc_for_memory() -> None:
    """glibc: every block above 16 KiB (2048 float64) gets its own mapping, returned to the OS
    when freed, and free heap memory is given back now, so that RSS follows the live memory
    (with glibc's default dynamic threshold freed tensors stay in the heap and the RSS of these
    runs reaches 2-3x the live peak).  A fixed threshold also turns the dynamic one off."""
    libc = _glibc()
    if libc is not None:
        libc.mallopt(_M_MMAP_THRESHOLD, 16 * 1024)
        libc.mallopt(_M_TRIM_THRESHOLD, 128 * 1024)
        libc.malloc_trim(0)


def _malloc_for_speed() -> None:
    """glibc: the steady state of its default dynamic thresholds after large frees (mmap threshold
    at its 32 MiB maximum, trim threshold twice that): tensors are recycled in the heap instead
    of being mapped and zero-filled anew, which is several times faster for mid-size tensors."""
    libc = _glibc()
    if libc is not None:
        libc.mallopt(_M_MMAP_THRESHOLD, 32 * 1024 * 1024)
        libc.mallopt(_M_TRIM_THRESHOLD, 64 * 1024 * 1024)



def make_surface(kind: str, size: int, seed: int = 0):
    """A freeform with non-trivial coefficients; ``size`` = XY order or B-spline grid side."""
    import torch
    from deeplens.optics.surfaces.bspline import BSpline
    from deeplens.optics.surfaces.xy_polynomial import XYPolynomial, xy_terms

    g = torch.Generator().manual_seed(seed)
    L, R = SEMI_DIAMETER, BASE_RADIUS
    if kind == "xy":
        terms = xy_terms(size)
        coeffs = []
        for (i, j) in terms:
            deg = i + j
            if deg == 0:
                c = 0.0
            elif deg == 1:
                c = 0.005 * (2 * torch.rand((), generator=g).item() - 1)
            elif deg == 2:
                # toric base (x^2 and y^2 curvatures differ by 10 %), small xy cross term
                c = {(2, 0): 1 / (2 * R), (0, 2): 1.1 / (2 * R)}.get((i, j), 2e-4)
            else:
                # each term contributes up to 0.2 / (deg + 1) mm of sag at the aperture edge
                amp = 0.2 / (deg + 1) / L ** deg
                c = amp * (2 * torch.rand((), generator=g).item() - 1)
            coeffs.append(c)
        surf = XYPolynomial(L, coeffs, b=0.5 / (2 * R))
    elif kind == "bspline":
        n = size
        h = 2 * L / (n - 3)
        p = torch.arange(n, dtype=torch.float64)
        xc = -L + (p - 1) * h  # Greville abscissae of uniform cubic B-splines
        X, Y = torch.meshgrid(xc, xc, indexing="ij")
        phase = 2 * math.pi * torch.rand(4, generator=g, dtype=torch.float64)
        C = ((X ** 2 + 1.1 * Y ** 2) / (2 * R)
             + 0.08 * torch.sin(1.3 * X / L * math.pi + phase[0]) * torch.cos(0.9 * Y / L * math.pi + phase[1])
             + 0.04 * torch.sin(2.1 * (X + Y) / L * math.pi + phase[2])
             + 0.002 * h * (2 * torch.rand(n, n, generator=g, dtype=torch.float64) - 1))
        surf = BSpline(L, C)
    else:
        raise ValueError(f"unknown surface kind {kind!r}")
    return surf


def make_rays(n: int, dtype, device, seed: int = 1):
    import torch

    g = torch.Generator().manual_seed(seed)
    L = SEMI_DIAMETER
    r = 0.85 * L * torch.rand(n, generator=g, dtype=torch.float64).sqrt()
    phi = 2 * math.pi * torch.rand(n, generator=g, dtype=torch.float64)
    ang = math.radians(8.0) * torch.rand(n, generator=g, dtype=torch.float64).sqrt()
    psi = 2 * math.pi * torch.rand(n, generator=g, dtype=torch.float64)
    o = torch.stack([r * phi.cos(), r * phi.sin(), torch.full_like(r, -1.0)], -1)
    d = torch.stack([ang.sin() * psi.cos(), ang.sin() * psi.sin(), ang.cos()], -1)
    w = torch.randn(n, 3, generator=g, dtype=torch.float64)
    valid = torch.ones(n, dtype=torch.bool)
    return (o.to(device=device, dtype=dtype), d.to(device=device, dtype=dtype),
            valid.to(device), w.to(device=device, dtype=dtype))


def newton_stats(surface, o, d, valid, tol, max_iter):
    """Per-ray number of Newton updates to reach |f| < tol (same iteration as ``intersect``)."""
    import torch

    with torch.no_grad():
        t = -o[..., 2] / d[..., 2]
        its = torch.zeros_like(t, dtype=torch.int32)
        active = valid.clone()
        for _ in range(max_iter):
            x = o + t.unsqueeze(-1) * d
            X, Y, Z = x.unbind(-1)
            fv = surface.f(X, Y, Z)
            fx, fy, fz = surface.f_grad(X, Y, Z)
            fp = fx * d[..., 0] + fy * d[..., 1] + fz * d[..., 2]
            active = active & ~(fv.abs() < tol) & (fp.abs() > 1e-12) & torch.isfinite(fv)
            if not bool(active.any()):
                break
            t = torch.where(active, t - fv / torch.where(active, fp, torch.ones_like(fp)), t)
            its = its + active.int()
        n = int(valid.sum())
        return float(its[valid].sum()) / max(n, 1), int(its.max())


def run_one(cfg: dict) -> dict:
    import torch
    from deeplens.optics.intersect import TraceOptions, default_tolerance, intersect

    if cfg.get("threads"):
        torch.set_num_threads(cfg["threads"])
    device = torch.device(cfg["device"])
    dtype = getattr(torch, cfg["dtype"])
    cuda = device.type == "cuda"

    def sync():
        if cuda:
            torch.cuda.synchronize(device)

    surf = make_surface(cfg["surface"], cfg["size"]).to(device)
    params = list(surf.parameters())  # every coefficient (XY: a_m and b; B-spline: the grid)
    for p in params:
        p.requires_grad_(True)
    n_coeffs = sum(p.numel() for p in params)
    opts = TraceOptions(mode=cfg["mode"], tol=cfg.get("tol"), max_iter=cfg["max_iter"])
    tol = opts.tol if opts.tol is not None else default_tolerance(dtype)

    def step(o, d, valid, w):
        for p in params:
            p.grad = None
        _, x, ok = intersect(surf, o, d, valid, opts)
        loss = torch.where(ok.unsqueeze(-1), x * w, torch.zeros_like(x)).sum()
        loss.backward()
        return loss, ok

    # warm-up on a few rays: autograd engine, thread pools, kernels
    small = make_rays(256, dtype, device, seed=7)
    step(*small)
    del small

    o, d, valid, w = make_rays(cfg["rays"], dtype, device)
    if cfg.get("ray_grad"):
        # as inside a lens, where o and d depend on upstream parameters: the intersection must
        # then also be differentiated with respect to the ray
        o.requires_grad_(True)
        d.requires_grad_(True)
    gc.collect()
    if cfg.get("tune_malloc", True):
        _malloc_for_memory()
    sync()

    # ---- memory: the first full-size forward + backward in this process.  ``graph`` = memory
    # still held between forward and backward (the autograd graph plus the few outputs).
    def run_measured():
        for p in params:
            p.grad = None
        _, x, ok = intersect(surf, o, d, valid, opts)
        loss = torch.where(ok.unsqueeze(-1), x * w, torch.zeros_like(x)).sum()
        del x
        sync()
        held = (torch.cuda.memory_allocated(device) - base_cuda) if cuda else \
            (_rss_bytes() - base_rss if reset_ok else -1)
        loss.backward()
        return loss, ok, held

    reset_ok = _reset_peak_rss()
    base_rss = _rss_bytes() if reset_ok else _maxrss_bytes()
    base_cuda = 0
    if cuda:
        torch.cuda.reset_peak_memory_stats(device)
        base_cuda = torch.cuda.memory_allocated(device)
    t0 = time.perf_counter()
    loss, ok, graph = run_measured()
    sync()
    first_time = time.perf_counter() - t0
    peak_rss = _maxrss_bytes() - base_rss
    peak_cuda = (torch.cuda.max_memory_allocated(device) - base_cuda) if cuda else None
    grad = torch.cat([p.grad.detach().reshape(-1).double().cpu() for p in params])
    valid_frac = float(ok.double().mean())
    loss_val = float(loss.detach())
    del loss, ok

    # the memory numbers first, so that the parent keeps them if it has to stop the timing
    mem = {
        **cfg,
        "n_coeffs": n_coeffs,
        "peak_rss_mib": peak_rss / MIB,
        "peak_rss_reset": reset_ok,
        "peak_cuda_mib": None if peak_cuda is None else peak_cuda / MIB,
        "graph_mib": graph / MIB if graph >= 0 else None,
        "base_rss_mib": base_rss / MIB,
        "first_run_s": first_time,
        "valid_frac": valid_frac,
        "loss": loss_val,
        "grad": grad.tolist(),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
    }
    print("MEMORY " + json.dumps(mem), flush=True)

    # ---- time: median of repeats after warm-up (the memory run was the warm-up); slow
    # configurations get fewer repeats (at least two: the first one also grows the heap).
    # Allocator: "heap" = glibc's usual steady state, "mmap" = as in the memory run, "auto" =
    # heap unless the heap could take the process past the memory budget.
    alloc = cfg.get("time_alloc", "auto")
    if alloc == "auto":
        # glibc's heap keeps freed blocks: measured here, the process then peaks ~1.25x the live
        # peak when the ray-sized tensors are >= 2 MiB (huge-page aligned), ~3x below that
        big = cfg["rays"] * torch.finfo(dtype).bits // 8 >= 2 * 1024 * 1024
        factor = 1.4 if big else 3.0
        fits = (base_rss + factor * max(peak_rss, 0)) / MIB <= cfg.get("mem_budget_mib", 1e12)
        alloc = "heap" if fits or cuda else "mmap"
    if cfg.get("tune_malloc", True) and alloc == "heap":
        _malloc_for_speed()
    times = []
    budget = cfg["time_budget"]
    for _ in range(max(cfg["repeats"], 1)):
        if len(times) >= 2 and sum(times) + first_time > budget:
            break
        gc.collect()
        sync()
        t0 = time.perf_counter()
        step(o, d, valid, w)
        sync()
        times.append(time.perf_counter() - t0)

    # Newton iteration counts do not depend on the mode: count them once, in the implicit run
    mean_its, max_its = newton_stats(surf, o, d, valid, tol, cfg["max_iter"]) \
        if cfg["mode"] == "implicit" else (None, None)

    return {
        **mem,
        "time_alloc": alloc,
        "time_s": statistics.median(times),
        "time_min_s": min(times),
        "n_time_repeats": len(times),
        "process_peak_mib": _maxrss_bytes() / MIB - mem["base_rss_mib"],
        "newton_mean": mean_its,
        "newton_max": max_its,
    }


# ============================================================================ parent process
def _child_rss_bytes(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _spawn(cfg: dict, rss_limit_gib: float, timeout: float) -> dict:
    """Run one configuration in a fresh interpreter; kill it if its RSS passes the limit."""
    import tempfile

    cmd = [sys.executable, os.path.abspath(__file__), "--one", json.dumps(cfg)]
    env = dict(os.environ)
    env["PYTHONPATH"] = REPO + os.pathsep + env.get("PYTHONPATH", "")
    if cfg.get("tune_malloc", True):
        # torch (c10 alloc_cpu): allocations >= 2 MiB are 2 MiB-aligned and madvise(MADV_HUGEPAGE)d,
        # so the fresh mappings of the memory run are faulted in 2 MiB instead of 4 KiB pages
        env.setdefault("THP_MEM_ALLOC_ENABLE", "1")
    limit = int(rss_limit_gib * 1024 ** 3)
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        p = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, env=env)
        t0, killed = time.time(), None
        while p.poll() is None:
            if time.time() - t0 > timeout:
                killed = f"timeout after {timeout:.0f} s"
            elif _child_rss_bytes(p.pid) > limit:
                killed = f"killed: RSS above {rss_limit_gib:g} GiB"
            if killed:
                p.kill()
                p.wait()
                break
            time.sleep(0.05)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    found = {}
    for line in stdout.splitlines():
        for tag in ("MEMORY", "RESULT"):
            if line.startswith(tag + " "):
                found[tag] = json.loads(line[len(tag) + 1:])
    if "RESULT" in found:
        return found["RESULT"]
    tail = (stderr or stdout).strip().splitlines()[-1:]
    why = killed or f"exit {p.returncode}: " + " | ".join(tail)
    if "MEMORY" in found:  # the memory run finished, the timing did not
        return {**found["MEMORY"], "time_error": why}
    return {**cfg, "error": why}


def _predict_mib(done: list, n: int) -> float:
    """Peak MiB at ``n`` rays, extrapolated linearly from the measured (rays, MiB), with margin."""
    (n1, m1) = done[-1]
    if len(done) >= 2:
        n0, m0 = done[-2]
        slope = max((m1 - m0) / (n1 - n0), 0.0) if n1 > n0 else m1 / n1
    else:
        slope = m1 / n1  # one point: proportional (an over-estimate: it scales the fixed part)
    return 1.25 * (m1 + slope * (n - n1)) + 128.0


def _fmt_rays(n: int) -> str:
    e = int(math.floor(math.log10(n)))
    m = n / 10 ** e
    return (f"{m:g}e{e}" if m != 1 else f"1e{e}") if m == int(m) else f"{n:g}"


def _grad_diff(a, b):
    m = max((abs(x) for x in a), default=0.0)
    if not m or len(a) != len(b):
        return float("nan")
    return max(abs(x - y) for x, y in zip(a, b)) / m


def _ok(r) -> bool:
    return r is not None and "error" not in r and "skipped" not in r


def _timed(r) -> bool:
    return _ok(r) and "time_s" in r


def print_table(results: list[dict], cuda: bool, out=sys.stdout):
    cols = ["surface", "#coeffs", "#rays", "mode", "Newton its mean/max", "valid %",
            "peak MiB (RSS)"]
    if cuda:
        cols.append("peak MiB (CUDA)")
    cols += ["graph MiB", "time s median (min)", "mem ratio unrolled/implicit", "time ratio",
             "grad diff"]
    print("| " + " | ".join(cols) + " |", file=out)
    print("|" + "|".join("---" if i < 4 else "---:" for i in range(len(cols))) + "|", file=out)
    by_key = {(r["surface"], r["size"], r["rays"], r["mode"]): r for r in results}
    newton = {(r["surface"], r["size"], r["rays"]): r for r in results
              if r.get("newton_mean") is not None}
    for r in results:
        name = f"XY poly order {r['size']}" if r["surface"] == "xy" else \
            f"B-spline {r['size']}x{r['size']}"
        ncoef = r.get("n_coeffs")
        row = [name, "" if ncoef is None else str(ncoef), _fmt_rays(r["rays"]), r["mode"]]
        if not _ok(r):
            row += [r.get("skipped") or r.get("error")] + [""] * (len(cols) - 5)
            print("| " + " | ".join(row) + " |", file=out)
            continue
        nt = newton.get((r["surface"], r["size"], r["rays"]))  # the same for both modes
        row += [f"{nt['newton_mean']:.2f} / {nt['newton_max']}" if nt else "",
                f"{100 * r['valid_frac']:.1f}", f"{r['peak_rss_mib']:.1f}"]
        if cuda:
            row.append("" if r["peak_cuda_mib"] is None else f"{r['peak_cuda_mib']:.1f}")
        row.append("" if r["graph_mib"] is None else f"{r['graph_mib']:.1f}")
        if _timed(r):
            mark = "†" if r.get("time_alloc") == "mmap" and r.get("tune_malloc", True) else ""
            row.append(f"{r['time_s']:.3f} ({r['time_min_s']:.3f}){mark}")
        else:
            row.append(f"not timed ({r.get('time_error', '?')})")
        other = by_key.get((r["surface"], r["size"], r["rays"], "implicit"))
        if r["mode"] == "unrolled" and _ok(other):
            key = "peak_cuda_mib" if cuda and r["peak_cuda_mib"] is not None else "peak_rss_mib"
            mem_ratio = r[key] / other[key] if other[key] > 0 else float("nan")
            same = _timed(r) and _timed(other) and r.get("time_alloc") == other.get("time_alloc")
            row += [f"**{mem_ratio:.1f}x**",
                    f"{r['time_s'] / other['time_s']:.2f}x" if same else "",
                    f"{_grad_diff(other['grad'], r['grad']):.1e}"]
        else:
            row += ["", "", ""]
        print("| " + " | ".join(row) + " |", file=out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    size = ap.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="small sizes, < 1 min (smoke test)")
    size.add_argument("--large", action="store_true", help="add 1e7 rays (CPU) / 1e7, 3e7 (CUDA)")
    ap.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    ap.add_argument("--dtype", default="float64", choices=["float64", "float32"])
    ap.add_argument("--rays", type=str, default=None,
                    help="comma-separated ray counts, overrides the preset (e.g. 1e4,1e5)")
    ap.add_argument("--xy-orders", type=str, default=None, help="comma-separated, e.g. 4,8")
    ap.add_argument("--bspline-grids", type=str, default=None, help="comma-separated, e.g. 8,64")
    ap.add_argument("--repeats", type=int, default=5, help="timed repeats (median)")
    ap.add_argument("--time-budget", type=float, default=None,
                    help="stop repeating a configuration after this many seconds")
    ap.add_argument("--ray-grad", action="store_true",
                    help="rays require grad too (as inside a lens, where upstream surfaces "
                         "move them); default: only the surface coefficients do")
    ap.add_argument("--max-iter", type=int, default=30)
    ap.add_argument("--tol", type=float, default=None, help="Newton tolerance, mm (dtype default)")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads per subprocess (default 1: stable timings; with 2+ "
                         "OpenMP threads on a busy machine one descheduled thread stalls every "
                         "parallel op; 0 = torch's default)")
    ap.add_argument("--max-mem-gib", type=float, default=8.0,
                    help="skip configurations predicted to need more (default 8 GiB)")
    ap.add_argument("--malloc-default", action="store_true",
                    help="leave glibc's malloc settings alone in the subprocesses (peak RSS "
                         "then includes freed heap memory the allocator keeps)")
    ap.add_argument("--timeout", type=float, default=600.0, help="per configuration, s")
    ap.add_argument("--json", type=str, default=None, help="also write all results here")
    ap.add_argument("--one", type=str, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.one is not None:  # child
        sys.path.insert(0, REPO)
        print("RESULT " + json.dumps(run_one(json.loads(args.one))), flush=True)
        return 0

    cuda = args.device.startswith("cuda")
    if cuda:
        import torch
        if not torch.cuda.is_available():
            print("CUDA requested but not available; falling back to --device cpu", file=sys.stderr)
            args.device, cuda = "cpu", False

    if args.quick:
        rays, orders, grids, budget = [2e3, 2e4], [4], [8], 1.0
    else:
        rays, orders, grids, budget = [1e4, 1e5, 1e6], [4, 8], [8, 64], 6.0
        if args.large:
            rays += [1e7, 3e7] if cuda else [1e7]
    if args.rays:
        rays = [float(v) for v in args.rays.split(",")]
    if args.xy_orders:
        orders = [int(v) for v in args.xy_orders.split(",") if v]
    if args.bspline_grids is not None:
        grids = [int(v) for v in args.bspline_grids.split(",") if v]
    rays = sorted(int(round(n)) for n in rays)
    budget = args.time_budget if args.time_budget is not None else budget

    groups = [("xy", o) for o in orders] + [("bspline", g) for g in grids]
    results = []
    ncoef: dict = {}
    t_start = time.time()
    max_mib = args.max_mem_gib * 1024
    def log(r, msg):
        print(f"[{time.time() - t_start:6.1f}s] {r['surface']} {r['size']} {r['mode']} "
              f"{_fmt_rays(r['rays'])}: {msg}", file=sys.stderr, flush=True)

    for surface, sz in groups:
        peak_hist = {"implicit": [], "unrolled": []}  # (rays, peak MiB of the memory run)
        failed = {"implicit": False, "unrolled": False}
        force_mmap = {"implicit": False, "unrolled": False}
        for n in rays:
            alloc_unrolled = None
            # unrolled first: the implicit run of the same size is timed with the same allocator
            for mode in ("unrolled", "implicit"):
                cfg = dict(surface=surface, size=sz, rays=n, mode=mode, device=args.device,
                           dtype=args.dtype, max_iter=args.max_iter, tol=args.tol,
                           repeats=args.repeats, time_budget=budget, threads=args.threads,
                           tune_malloc=not args.malloc_default, ray_grad=args.ray_grad)
                pred = _predict_mib(peak_hist[mode], n) if peak_hist[mode] else 0.0
                if failed[mode] or pred > max_mib:
                    r = {**cfg, "n_coeffs": ncoef.get((surface, sz)),
                         "skipped": "skipped: a smaller size failed" if failed[mode] else
                                    f"skipped: predicted {pred / 1024:.1f} GiB > "
                                    f"--max-mem-gib {args.max_mem_gib:g}"}
                    results.append(r)
                    log(r, r["skipped"])
                    continue
                cfg["mem_budget_mib"] = max_mib
                if args.malloc_default or cuda:
                    cfg["time_alloc"] = "heap"
                elif mode == "implicit" and alloc_unrolled:
                    cfg["time_alloc"] = alloc_unrolled  # time both modes alike
                else:
                    cfg["time_alloc"] = "mmap" if force_mmap[mode] else "auto"
                r = _spawn(cfg, args.max_mem_gib + 1.5, args.timeout)
                results.append(r)
                if "error" in r:
                    failed[mode] = True
                    log(r, r["error"])
                    continue
                ncoef[(surface, sz)] = r["n_coeffs"]
                mem = r["peak_cuda_mib"] if cuda and r["peak_cuda_mib"] is not None else \
                    r["peak_rss_mib"]
                peak_hist[mode].append((n, mem))
                if "time_error" in r:
                    force_mmap[mode] = True
                    log(r, f"peak {mem:.1f} MiB; timing stopped: {r['time_error']}")
                    continue
                if mode == "unrolled":
                    alloc_unrolled = r["time_alloc"]
                its = f", Newton {r['newton_mean']:.2f}/{r['newton_max']}" \
                    if r["newton_mean"] is not None else ""
                log(r, f"peak {mem:.1f} MiB, graph {r['graph_mib'] or 0:.1f} MiB, process "
                       f"{r['process_peak_mib']:.0f} MiB, {r['time_s']:.3f} s "
                       f"({r['time_alloc']}){its}")

    # order the table: surface, size, rays, mode
    order = {("xy", o): i for i, o in enumerate(orders)}
    order.update({("bspline", g): len(orders) + i for i, g in enumerate(grids)})
    results.sort(key=lambda r: (order[(r["surface"], r["size"])], r["rays"],
                                r["mode"] != "implicit"))
    ok = [r for r in results if _ok(r)]
    info = ok[0] if ok else {}
    print(f"\nIntersection gradient, implicit (Eq. 7) vs unrolled Newton: device={args.device}, "
          f"dtype={args.dtype}, torch {info.get('torch', '?')}, {info.get('threads', '?')} threads, "
          f"tol={'dtype default' if args.tol is None else args.tol}, max_iter={args.max_iter}, "
          f"{'rays and coefficients' if args.ray_grad else 'coefficients'} require grad, "
          f"total {time.time() - t_start:.0f} s\n")
    print_table(results, cuda)
    print("\npeak MiB: peak RSS increase of a fresh process over its first forward + backward"
          + (" (CUDA: max_memory_allocated increase)" if cuda else "")
          + "; graph MiB: memory held between forward and backward; mem ratio: unrolled / implicit "
          "peak; time: forward + backward; grad diff: max|g_unrolled - g_implicit| / "
          "max|g_implicit|.")
    if any(r.get("time_alloc") == "mmap" and _timed(r) and r.get("tune_malloc", True)
           for r in results):
        print("† timed with fresh mappings for every tensor, as in the memory run (glibc's heap "
              "would have passed --max-mem-gib): slower than usual; compare with other † times "
              "only.")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)
    return 0 if all("error" not in r for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
