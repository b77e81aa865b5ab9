#!/usr/bin/env python
"""Memory and time of an image-space gradient vs the number of rays: adjoint vs plain back-prop.

Reproduces the claim of the dO paper (Sec. II-D "Adjoint back-propagation", Fig. 7): plain
back-propagation through a Monte Carlo render keeps every ray's autograd graph until the
backward pass, so its memory grows linearly with the number of rays (out of memory beyond 16 M
rays on an 11 GB GPU in the paper), while the adjoint method (render without a graph, get
``dL/dI`` from autograd, then re-trace chunk by chunk and accumulate ``J^T dL/dI``) stays at one
chunk's graph whatever the number of rays.

Workload (one configuration = number of rays, mode):

* ``--lens edof`` (default): the paper's EDOF lens ``data/lenses/edof_achromat.json``
  (achromat + plate + XY-polynomial phase plate), the plate set to a Dowski-Cathey cubic
  (``--plate-alpha-mm``, sag at the rim); trainable: the plate's cubic XY coefficients
  ``surfaces.4.a.6..9`` and ``d_sensor``; ``--lens double_gauss``: the double Gauss, every
  curvature and ``d_sensor`` trainable; the sensor covers the file's image circle;
* a monochrome scene (one wavelength): a random texture at 5 m filling the field of view;
* a ``H x W`` sensor (default 256 x 256, 4.9 um pixels, the whole image circle), ``spp`` rays per
  pixel: rays = active pixels x spp x 1 wavelength; the sweep varies ``spp``;
* ``MonteCarloRenderer(lens, sensor, spp, adjoint=..., chunk_rays=..., vignetting=False)``;
  loss = MSE of the render against the ideal camera's sharp image; ``loss.backward()``.
  Both modes use the same :meth:`plan` (seed), i.e. the same rays.

Each configuration runs in a fresh subprocess (``--one``), so memory is per process, and makes
two passes (forward + backward each, same rays, after a warm-up on a tiny sensor):

1. the memory pass, with glibc's mmap threshold fixed at ``--mmap-threshold`` (64 KiB): freed
   tensors go back to the OS, so the RSS follows the live memory.  With glibc's default dynamic
   threshold freed tensors stay in the heap and RSS reaches 1.9-2.6x the live peak.
2. the timed pass, with glibc's steady-state thresholds (tensors recycled in the heap; the memory
   pass is 2-5x slower from zero-filling fresh pages).  Skipped, and the times marked †, where the
   heap could take the process past the budget.

Columns:

* ``peak MiB`` = peak RSS during the memory pass minus the RSS after setup (lens, sensor, scene,
  target and sampling plan built, warm-up done): the kernel's RSS high-water mark is reset after
  setup (``/proc/self/clear_refs``) and read back with ``getrusage().ru_maxrss``.  On CUDA
  ``torch.cuda.max_memory_allocated`` minus the allocation after setup is reported as well.
* ``held MiB`` = memory still held after the forward (the autograd graph for plain back-prop).
* ``heap peak MiB`` = the same peak in the timed pass (what a default process shows).
* ``fwd s`` / ``bwd s`` / ``total s`` = wall time of the render, of ``loss.backward()`` (for the
  adjoint: the re-trace of every chunk with its graph) and of both, in the timed pass.
* ``grad cos`` = cosine similarity of the adjoint gradient with the plain one at the same size.

Configurations whose predicted peak (linear extrapolation from the two previous sizes of the
same mode, +10 %) exceeds ``--max-mem-gib`` (or the memory available now) are skipped and marked
"skipped (would need ~X GiB)"; on CPU every subprocess also runs under a hard ``RLIMIT_AS`` of
``--hard-limit-gib`` (address space, which includes ~3 GiB of libraries and reservations), so an
unexpected out-of-memory shows up as an "OOM" row instead of swapping or the OOM killer.

Usage::

    python benchmarks/bench_render_memory.py --quick     # smoke test, < 1 min
    python benchmarks/bench_render_memory.py             # full sweep 1.3e5 .. 3.4e7 rays
                                                         # (spp 2..512), 18-24 min on 2 CPU cores
    python benchmarks/bench_render_memory.py --spp 2,4,8,16,32,64,128,256   # up to 1.7e7, ~12 min
    python benchmarks/bench_render_memory.py --device cuda --json out.json

On a shared machine wrap heavy runs in ``flock /tmp/deeplens-bench.lock python ...``.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import resource
import subprocess
import sys
import time

from procmem import maxrss_bytes as _maxrss_bytes
from procmem import reset_peak_rss as _reset_peak_rss
from procmem import rss_bytes as _rss_bytes

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LENSES = {  # --lens: file, trainable parameters, plate
    "edof": ("edof_achromat.json",
             ["surfaces.4.a.6", "surfaces.4.a.7", "surfaces.4.a.8", "surfaces.4.a.9",
              "d_sensor"], "cubic"),
    "double_gauss": ("double_gauss.json", ["surfaces.*.c", "d_sensor"], None),
}
MIB = 1024.0 * 1024.0
GIB = 1024.0 * MIB
DONE_ADJ_RAYS = 1.6e7   # the "Done when": adjoint at >= 1.6e7 rays ...
DONE_PLAIN_RAYS = 4e6   # ... peaks below plain back-prop at 4e6 rays
MEM_MMAP_THRESHOLD = 64 * 1024  # bytes, glibc mmap threshold of the memory pass


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


def _malloc_for_memory(mmap_threshold: int) -> None:
    """glibc: every allocation above ``mmap_threshold`` bytes gets its own mapping, unmapped when
    freed, and the heap is trimmed above 128 KiB free: RSS follows the live memory (with the
    default dynamic thresholds freed tensors stay in the heap and inflate RSS)."""
    libc = _glibc()
    if libc is not None and mmap_threshold > 0:
        libc.mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))
        libc.mallopt(_M_TRIM_THRESHOLD, 128 * 1024)


def _malloc_for_speed() -> None:
    """glibc: the steady state of its default dynamic thresholds after large frees (mmap
    threshold 32 MiB, trim threshold 64 MiB): tensors are recycled in the heap, no fresh
    zero-filled pages per tensor."""
    libc = _glibc()
    if libc is not None:
        libc.mallopt(_M_MMAP_THRESHOLD, 32 * 1024 * 1024)
        libc.mallopt(_M_TRIM_THRESHOLD, 64 * 1024 * 1024)


def _malloc_trim() -> None:
    """Give free heap memory back to the OS (glibc), so that the baseline RSS is live memory."""
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)



def _is_oom(e: BaseException) -> bool:
    if isinstance(e, MemoryError):
        return True
    msg = str(e).lower()
    return isinstance(e, RuntimeError) and ("can't allocate memory" in msg
                                            or "out of memory" in msg
                                            or "cannot allocate memory" in msg)


def build_setup(cfg: dict):
    """Lens (trainable cubic plate + sensor distance), sensor, scene, target, renderer."""
    import torch
    from deeplens.render import IdealCamera, MonteCarloRenderer, Scene, Sensor
    from deeplens.training.lens_setup import build_lens

    device = torch.device(cfg["device"])
    name, trainable, plate = LENSES[cfg.get("lens", "edof")]
    lens = build_lens(os.path.join(REPO, "data", "lenses", name), trainable=trainable,
                      dtype=cfg["dtype"], plate=plate, plate_surface=4 if plate else None,
                      plate_alpha_mm=cfg["plate_alpha_mm"] if plate else 0.0).to(device)
    H, W = cfg["resolution"]
    sensor = Sensor((H, W), cfg["pixel_mm"])
    dtype = getattr(torch, cfg["dtype"])
    g = torch.Generator().manual_seed(0)
    tex = torch.rand(1, 1, 256, 256, generator=g, dtype=torch.float64).to(dtype=dtype,
                                                                          device=device)
    scene = Scene(tex, cfg["depth_mm"])
    with torch.no_grad():
        target = IdealCamera(lens, sensor).render(scene)  # the sharp image (1, 1, H, W)
    options = None
    if cfg["mode"].endswith("-compiled"):  # TraceOptions(compile=True): fused kernels
        from deeplens.optics.options import TraceOptions
        options = TraceOptions(compile=True)
    renderer = MonteCarloRenderer(lens, sensor, spp=cfg["spp"],
                                  adjoint=cfg["mode"].startswith("adjoint"),
                                  chunk_rays=cfg["chunk_rays"], vignetting=False, options=options)
    params = [p for p in lens.parameters() if p.requires_grad]
    return lens, sensor, scene, target, renderer, params


def run_one(cfg: dict) -> dict:
    import torch
    from deeplens.render import MonteCarloRenderer, Sensor

    if cfg.get("threads"):
        torch.set_num_threads(cfg["threads"])
    device = torch.device(cfg["device"])
    cuda = device.type == "cuda"

    def sync():
        if cuda:
            torch.cuda.synchronize(device)

    lens, sensor, scene, target, renderer, params = build_setup(cfg)
    names = [n for n, p in lens.named_parameters() if p.requires_grad]

    # warm-up (autograd engine, thread pools, kernels) on a tiny sensor, same mode
    tiny = MonteCarloRenderer(lens, Sensor((8, 8), sensor.pixel_size_mm * sensor.resolution[0] / 8),
                              spp=2, adjoint=renderer.adjoint, chunk_rays=64, vignetting=False,
                              options=renderer.options)
    img = tiny(scene, seed=99)
    img.square().mean().backward()
    for p in params:
        p.grad = None
    del img, tiny

    plan = renderer.plan(scene, seed=cfg["seed"])  # the rays: identical for both modes
    n_rays = int(plan.pixels.numel()) * renderer.spp * len(plan.jobs)
    n_chunks = renderer.n_chunks(plan) * len(plan.jobs)

    out = {**cfg, "rays": n_rays, "chunks": n_chunks, "pixels": int(plan.pixels.numel()),
           "torch": torch.__version__, "threads": torch.get_num_threads(), "params": names}

    def one_pass():
        """Forward + backward from a reset high-water mark: (peak, held, fwd s, bwd s, ...)."""
        for p in params:
            p.grad = None
        gc.collect()
        _malloc_trim()
        sync()
        reset_ok = _reset_peak_rss()
        base_rss = _rss_bytes() if reset_ok else _maxrss_bytes()
        base_cuda = 0
        if cuda:
            torch.cuda.reset_peak_memory_stats(device)
            base_cuda = torch.cuda.memory_allocated(device)
        t0 = time.perf_counter()
        img = renderer(scene, plan=plan)
        loss = ((img - target) ** 2).mean()
        sync()
        t1 = time.perf_counter()
        held = (torch.cuda.memory_allocated(device) - base_cuda) if cuda else \
            (_rss_bytes() - base_rss if reset_ok else -1)
        loss.backward()
        sync()
        t2 = time.perf_counter()
        return dict(
            base_rss_mib=base_rss / MIB, peak_rss_reset=reset_ok,
            peak_rss_mib=(_maxrss_bytes() - base_rss) / MIB,
            peak_cuda_mib=(torch.cuda.max_memory_allocated(device) - base_cuda) / MIB if cuda
            else None,
            held_mib=held / MIB if held >= 0 else None,
            fwd_s=t1 - t0, bwd_s=t2 - t1, time_s=t2 - t0, loss=float(loss),
            grad=[float(p.grad) for p in params])

    # 1) memory: glibc returns freed tensors to the OS, so RSS follows the live memory
    _malloc_for_memory(cfg.get("mmap_threshold", MEM_MMAP_THRESHOLD))
    try:
        mem = one_pass()
    except (MemoryError, RuntimeError) as e:
        if not _is_oom(e):
            raise
        out.update(oom=f"OOM ({type(e).__name__})")
        return out
    out.update(mem)
    out["mem_time_s"] = mem["time_s"]
    # 2) time: glibc's steady state (tensors recycled in the heap; RSS then includes freed heap
    # memory, reported as "heap peak").  Skipped where that could exceed the memory budget.
    heap_guess_gib = (mem["base_rss_mib"] + 2.2 * mem["peak_rss_mib"]) / 1024  # measured <= 2.1x
    if cfg.get("timed", True) and (cuda or heap_guess_gib < cfg.get("max_mem_gib", 1e9)):
        _malloc_for_speed()
        try:
            t = one_pass()
        except (MemoryError, RuntimeError) as e:
            if not _is_oom(e):
                raise
            out.update(timed_pass=False, timed_note="timed pass OOM")
            return out
        out.update(fwd_s=t["fwd_s"], bwd_s=t["bwd_s"], time_s=t["time_s"],
                   heap_peak_rss_mib=t["peak_rss_mib"], timed_pass=True,
                   grad_repeat_equal=t["grad"] == mem["grad"])
    else:
        out["timed_pass"] = False
    return out


# ============================================================================ parent process
def _mem_available_bytes() -> float:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except (OSError, ValueError):
        pass
    return float("inf")


def _spawn(cfg: dict, hard_limit_gib: float, timeout: float) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--one", json.dumps(cfg)]

    def limit():  # hard memory backstop (CPU only: CUDA reserves huge address ranges)
        if cfg["device"] == "cpu" and hasattr(resource, "RLIMIT_AS"):
            lim = int(hard_limit_gib * GIB)
            resource.setrlimit(resource.RLIMIT_AS, (lim, lim))

    env = dict(os.environ)
    env["PYTHONPATH"] = REPO + os.pathsep + env.get("PYTHONPATH", "")
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env,
                           preexec_fn=limit if os.name == "posix" else None)
    except subprocess.TimeoutExpired:
        return {**cfg, "error": f"timeout after {timeout:.0f} s"}
    for line in p.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT "):])
    tail = (p.stderr or p.stdout).strip().splitlines()[-3:]
    if any("memory" in t.lower() for t in tail) or p.returncode in (-9, 137):
        return {**cfg, "oom": f"OOM (exit {p.returncode})"}
    return {**cfg, "error": f"exit {p.returncode}: " + " | ".join(tail)}


def _fmt_rays(n: float) -> str:
    return f"{n:.3g}" if n < 1e4 else f"{n:.2e}".replace("e+0", "e").replace("e+", "e")


def _ok(r: dict) -> bool:
    return not any(k in r for k in ("error", "skipped", "oom"))


def _mem(r: dict, cuda: bool) -> float:
    return r["peak_cuda_mib"] if cuda and r.get("peak_cuda_mib") is not None else r["peak_rss_mib"]


def _cosine(a, b) -> float:
    na = math.sqrt(sum(x * x for x in a))
    nb = math.sqrt(sum(x * x for x in b))
    if not na or not nb:
        return float("nan")
    return sum(x * y for x, y in zip(a, b)) / (na * nb)


def _predict(done: list[dict], rays: float, cuda: bool) -> float | None:
    """Peak MiB at ``rays`` from the last two measured sizes (linear in the ray count)."""
    pts = [(r["rays"], _mem(r, cuda)) for r in done if _ok(r)]
    if not pts:
        return None
    if len(pts) == 1:
        n0, m0 = pts[-1]
        return m0 * rays / n0
    (n0, m0), (n1, m1) = pts[-2], pts[-1]
    slope = max((m1 - m0) / (n1 - n0), 0.0) if n1 != n0 else m1 / n1
    return m1 + slope * (rays - n1)


def print_table(results: list[dict], cuda: bool, out=sys.stdout):
    cols = ["rays", "H x W x spp", "mode", "chunks", "peak MiB (RSS)"]
    if cuda:
        cols.append("peak MiB (CUDA)")
    cols += ["held after fwd MiB", "heap peak MiB", "fwd s", "bwd s", "total s",
             "plain/adjoint peak", "grad cos"]
    print("| " + " | ".join(cols) + " |", file=out)
    print("|" + "|".join("---" if i < 3 else "---:" for i in range(len(cols))) + "|", file=out)
    by = {(r["spp"], r["mode"]): r for r in results}
    for r in results:
        H, W = r["resolution"]
        rays = r.get("rays") or H * W * r["spp"]
        row = [_fmt_rays(rays), f"{H}x{W}x{r['spp']}", r["mode"], str(r.get("chunks", ""))]
        if not _ok(r):
            msg = r.get("skipped") or r.get("oom") or r.get("error")
            row += [f"**{msg}**"] + [""] * (len(cols) - 5)
            print("| " + " | ".join(row) + " |", file=out)
            continue
        row.append(f"{r['peak_rss_mib']:.0f}")
        if cuda:
            row.append("" if r.get("peak_cuda_mib") is None else f"{r['peak_cuda_mib']:.0f}")
        dag = "" if r.get("timed_pass", True) else " †"
        row += ["" if r.get("held_mib") is None else f"{r['held_mib']:.0f}",
                "" if r.get("heap_peak_rss_mib") is None else f"{r['heap_peak_rss_mib']:.0f}",
                f"{r['fwd_s']:.2f}{dag}", f"{r['bwd_s']:.2f}{dag}", f"{r['time_s']:.2f}{dag}"]
        other = by.get((r["spp"], "plain"))
        if r["mode"] == "adjoint" and other and _ok(other):
            ratio = _mem(other, cuda) / max(_mem(r, cuda), 1e-9)
            row += [f"{ratio:.1f}x", f"{_cosine(other['grad'], r['grad']):.8f}"]
        else:
            row += ["", ""]
        print("| " + " | ".join(row) + " |", file=out)


def done_when(results: list[dict], cuda: bool) -> tuple[bool | None, str]:
    """The issue's check: adjoint >= 1.6e7 rays with gradients, peak below plain's at 4e6."""
    adj = [r for r in results if r["mode"] == "adjoint" and r.get("rays", 0) >= DONE_ADJ_RAYS]
    adj_ok = [r for r in adj if _ok(r) and all(math.isfinite(g) for g in r["grad"])
              and any(g != 0 for g in r["grad"])]
    plain = [r for r in results if r["mode"] == "plain" and "rays" in r]
    if not adj or not plain:
        return None, ("Done-when check n/a: the sweep did not reach "
                      f"{DONE_ADJ_RAYS:.2g} rays (adjoint) / {DONE_PLAIN_RAYS:.2g} rays (plain)")
    a = min(adj_ok, key=lambda r: r["rays"]) if adj_ok else None
    p = min(plain, key=lambda r: abs(math.log(r["rays"] / DONE_PLAIN_RAYS)))
    if abs(math.log(p["rays"] / DONE_PLAIN_RAYS)) > math.log(1.5):
        return None, f"Done-when check n/a: no plain back-prop size near {DONE_PLAIN_RAYS:.2g} rays"
    if _ok(p):
        y, y_txt = _mem(p, cuda), f"{_mem(p, cuda):.0f} MiB"
    elif "skipped" in p or "oom" in p:
        y = p.get("predicted_mib") or float("inf")
        y_txt = (f"OOM/skipped, would need ~{y:.0f} MiB" if math.isfinite(y) else "OOM")
    else:
        return None, f"Done-when check n/a: plain back-prop at {_fmt_rays(p['rays'])} failed"
    if a is None:
        return False, (f"adjoint renders >= {DONE_ADJ_RAYS:.2g} rays with gradients: false "
                       f"({adj[0].get('oom') or adj[0].get('error') or adj[0].get('skipped')})")
    x = _mem(a, cuda)
    ok = x < y
    return ok, (f"adjoint renders >= {DONE_ADJ_RAYS:.2g} rays with gradients "
                f"({_fmt_rays(a['rays'])} rays, {a['time_s']:.0f} s); its peak at "
                f"{_fmt_rays(a['rays'])} ({x:.0f} MiB) is {'below' if ok else 'NOT below'} plain "
                f"back-prop's at {_fmt_rays(p['rays'])} ({y_txt}): {str(ok).lower()}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny sizes, < 1 min (smoke test)")
    ap.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    ap.add_argument("--lens", default="edof", choices=sorted(LENSES),
                    help="edof (default: the plate's cubic terms and d_sensor train) or "
                         "double_gauss (every curvature and d_sensor train)")
    ap.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    ap.add_argument("--resolution", type=str, default=None, help="H,W (default 256,256)")
    ap.add_argument("--pixel-mm", type=float, default=None,
                    help="pixel pitch, mm (default: the sensor covers the lens's 1.77 mm image "
                         "circle diagonal, 0.0049 mm at 256 x 256)")
    ap.add_argument("--spp", type=str, default=None,
                    help="comma-separated samples per pixel (default 2,4,...,512)")
    ap.add_argument("--chunk-rays", type=int, default=262144,
                    help="rays traced at once (default 262144, the training configs' value; "
                         "the renderer's own default is 1048576)")
    ap.add_argument("--modes", type=str, default="plain,adjoint",
                    help="of plain, adjoint, plain-compiled, adjoint-compiled (the last two with "
                         "TraceOptions(compile=True); their compilation happens in the "
                         "warm-up, on the tiny sensor)")
    ap.add_argument("--plate-alpha-mm", type=float, default=0.01,
                    help="cubic plate sag at the rim, mm (configs/eval.yaml's cubic_alpha_mm)")
    ap.add_argument("--depth-mm", type=float, default=5000.0)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (default 1; 0 = torch default).  With 2 threads on a "
                         "busy 2-core machine one descheduled thread stalls every parallel op")
    ap.add_argument("--max-mem-gib", type=float, default=15.0,
                    help="skip configurations predicted to need more (default 15 GiB = 16.1 GB)")
    ap.add_argument("--hard-limit-gib", type=float, default=18.5,
                    help="RLIMIT_AS of each CPU subprocess (default 18.5 GiB = 19.9 GB)")
    ap.add_argument("--mmap-threshold", type=int, default=MEM_MMAP_THRESHOLD,
                    help="glibc mmap threshold (bytes) of the memory pass (default 64 KiB); 0 "
                         "keeps glibc's dynamic threshold (RSS then includes freed heap memory)")
    ap.add_argument("--no-timed-pass", action="store_true",
                    help="one pass per configuration (memory settings), no separate timed pass")
    ap.add_argument("--timeout", type=float, default=1800.0, help="per configuration, s")
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
        res, spps, chunk = (64, 64), [2, 8, 32], min(args.chunk_rays, 16384)
    else:
        res, spps, chunk = (256, 256), [2, 4, 8, 16, 32, 64, 128, 256, 512], args.chunk_rays
    if args.resolution:
        res = tuple(int(v) for v in args.resolution.split(","))
    if args.spp:
        spps = [int(v) for v in args.spp.split(",")]
    spps = sorted(set(spps))
    # the sensor half-diagonal matches the lens file's image circle (EDOF: 0.8832 mm)
    with open(os.path.join(REPO, "data", "lenses", LENSES[args.lens][0])) as f:
        circle = float(json.load(f)["sensor"]["semi_diameter_mm"])
    pixel_mm = args.pixel_mm or round(2 * circle / math.hypot(*res), 6)
    modes = [m for m in args.modes.split(",") if m]
    for m in modes:
        if m not in ("plain", "adjoint", "plain-compiled", "adjoint-compiled"):
            ap.error(f"--modes: unknown mode {m!r}")

    results = []
    t_start = time.time()
    for mode in modes:
        done = []
        for spp in spps:
            cfg = dict(lens=args.lens, mode=mode, spp=spp, resolution=list(res), pixel_mm=pixel_mm,
                       chunk_rays=chunk, device=args.device, dtype=args.dtype,
                       plate_alpha_mm=args.plate_alpha_mm, depth_mm=args.depth_mm,
                       seed=args.seed, threads=args.threads, mmap_threshold=args.mmap_threshold,
                       timed=not args.no_timed_pass, max_mem_gib=args.max_mem_gib)
            est_rays = res[0] * res[1] * spp
            pred = _predict(done, est_rays, cuda)
            if pred is not None:
                pred *= 1.10
                base = max((r.get("base_rss_mib", 0) for r in done), default=0)
                need_gib = (pred + base) / 1024
                avail_gib = _mem_available_bytes() / GIB - 1.0
                if need_gib > args.max_mem_gib or (not cuda and need_gib > avail_gib):
                    why = (f"> --max-mem-gib {args.max_mem_gib:g}" if need_gib > args.max_mem_gib
                           else f"> {avail_gib:.1f} GiB available now")
                    r = {**cfg, "rays": done[-1]["rays"] * spp // done[-1]["spp"],
                         "predicted_mib": pred,
                         "skipped": f"skipped (would need ~{need_gib:.1f} GiB {why})"}
                    results.append(r)
                    print(f"[{time.time() - t_start:7.1f}s] {mode} spp={spp}: {r['skipped']}",
                          file=sys.stderr, flush=True)
                    continue
            r = _spawn(cfg, args.hard_limit_gib, args.timeout)
            if "oom" in r and pred is not None:
                r["predicted_mib"] = pred
            results.append(r)
            if _ok(r):
                done.append(r)
                msg = (f"{_fmt_rays(r['rays'])} rays: peak {r['peak_rss_mib']:.0f} MiB, held "
                       f"{r['held_mib']:.0f} MiB, fwd {r['fwd_s']:.2f} s, bwd {r['bwd_s']:.2f} s"
                       f" (memory pass {r['mem_time_s']:.1f} s)")
                if "timed_note" in r:
                    msg += f", {r['timed_note']}"
            else:
                msg = r.get("oom") or r.get("error")
            print(f"[{time.time() - t_start:7.1f}s] {mode} spp={spp}: {msg}", file=sys.stderr,
                  flush=True)

    results.sort(key=lambda r: (r["spp"], r["mode"] != "plain"))
    info = next((r for r in results if "torch" in r), {})
    H, W = res
    print(f"\nImage-space gradient (MSE vs the sharp image) of the {args.lens} lens, "
          f"plain back-prop vs adjoint: device={args.device}, dtype={args.dtype}, "
          f"torch {info.get('torch', '?')}, {info.get('threads', '?')} threads, "
          f"sensor {H}x{W} @ {pixel_mm * 1000:.2f} um, 1 wavelength, chunk_rays={chunk}, "
          f"params {', '.join(info.get('params', LENSES[args.lens][1]))}; "
          f"total {time.time() - t_start:.0f} s\n")
    print_table(results, cuda)
    print("\npeak MiB: process peak RSS during forward + backward minus the RSS after setup "
          "(fresh process per row; memory pass, glibc mmap threshold "
          f"{args.mmap_threshold // 1024} KiB so that RSS follows live memory); held: memory "
          "still held after the forward (the graph); heap peak: the same in the timed pass "
          "(glibc heap recycling, freed memory kept); times: the timed pass († = the memory "
          "pass, no timed pass); bwd s for the adjoint includes re-tracing every chunk; "
          "grad cos: cosine similarity of the adjoint gradient with plain back-prop's (same "
          "rays).")
    cos = [(r, o) for r in results for o in results
           if r["mode"] == "adjoint" and o["mode"] == "plain" and r["spp"] == o["spp"]
           and _ok(r) and _ok(o)]
    if cos:
        r, o = min(cos, key=lambda t: t[0]["rays"])
        rel = max(abs(a - b) for a, b in zip(r["grad"], o["grad"])) / \
            max(max(abs(b) for b in o["grad"]), 1e-300)
        print(f"\nSame gradient at the smallest size ({_fmt_rays(r['rays'])} rays): cosine "
              f"similarity {_cosine(r['grad'], o['grad']):.10f}, max |g_adj - g_plain| / "
              f"max |g_plain| = {rel:.1e}")
    ok, line = done_when(results, cuda)
    print("\n" + line)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)
    return 0 if all("error" not in r for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
