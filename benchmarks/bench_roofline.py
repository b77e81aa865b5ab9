#!/usr/bin/env python
"""This CPU's roofline, one thread, and where the compiled forward trace sits on it.

Three parts, each printed as a table:

* ``bandwidth``: a STREAM-like triad ``a = b + s c`` (``torch.add(b, c, alpha=s, out=a)``) and a
  copy on float32 arrays of ``--mib`` MiB each, counted as 3 (triad) and 2 (copy) array
  transfers (write-allocate traffic not counted, as STREAM), best of ``--repeats``;
* ``arithmetic``: throughput of the vector operations the tracer's kernels are made of, each a
  ``torch.compile``d element-wise kernel (the same compiler and flags as the tracer's) over a
  64 Ki-element float32 array (256 KiB, cache-resident) holding 8 independent chains of 32
  dependent operations per element: ``x * a + b`` (multiply-add), ``a / x`` (division),
  ``sqrt(x)``, ``rsqrt(x)``; nanoseconds per element-operation and operations per second;
* ``kernel``: the compiled forward of the double Gauss (``TraceOptions(compile=True)``, 4096
  rays, compiled into an empty temporary inductor cache), its generated C++ read back and its
  vectorised loop bodies counted per kernel: loads and stores (bytes per ray), multiply/add/
  fused multiply-add, division, square root, reciprocal square root, comparisons, selects and
  other operations per ray; then, with the measured costs above, the arithmetic time bound and
  the memory time bound per ray-surface against the measured compiled forward on ``--rays``
  rays (process CPU time, min of ``--repeats``);
* ``graph``: one trace + backward (RMS spot, every curvature trainable) per schedule (eager,
  compiled per surface, per run, per surface with ``checkpoint=True``), each in a fresh process:
  the per-ray tensors autograd saves for backward (a saved-tensor pack hook; storages counted
  once), bytes per ray-surface, the RSS held after the forward and the peak extra RSS.

All times are process CPU time (the machine is shared; wall time would count the others).

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_roofline.py               # ~3 min idle, 1 thread
    OMP_NUM_THREADS=1 python benchmarks/bench_roofline.py --parts bandwidth,arithmetic
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WAVELENGTH_NM = 587.5618


def bandwidth(mib: int, repeats: int) -> dict:
    import torch
    n = mib * 1024 * 1024 // 4
    a, b, c = torch.empty(n), torch.rand(n), torch.rand(n)
    triad, copy = [], []
    a.fill_(0.0)  # first touch outside the timing
    for _ in range(repeats):  # CPU time: on a shared machine wall time counts other processes
        t0 = time.process_time()
        torch.add(b, c, alpha=3.0, out=a)
        triad.append(3 * 4 * n / (time.process_time() - t0))
        t0 = time.process_time()
        a.copy_(b)
        copy.append(2 * 4 * n / (time.process_time() - t0))
    return {"triad_Bps": max(triad), "copy_Bps": max(copy), "array_mib": mib}


CHAINS, DEPTH, ELEMS = 8, 32, 64 * 1024


def _chains(op):
    def f(x):
        xs = [x + 0.125 * k for k in range(CHAINS)]
        for _ in range(DEPTH):
            xs = [op(v) for v in xs]
        out = xs[0]
        for v in xs[1:]:
            out = out + v
        return out
    return f


OPS = {
    "multiply (x * a)": lambda v: v * 0.999,
    "add (x + b)": lambda v: v + 0.001,
    "multiply-add (x * a + b)": lambda v: v * 0.999 + 0.001,
    "division (a / x)": lambda v: 1.5 / v,
    "sqrt": lambda v: v.sqrt(),
    "rsqrt": lambda v: v.rsqrt(),
}


#: one dependent chain this long per element: a loop body longer than the out-of-order window,
#: so iterations hardly overlap and the time per operation is its latency
LAT_DEPTH = 1024


def _chain(op):
    def f(x):
        for _ in range(LAT_DEPTH):
            x = op(x)
        return x
    return f


def latency(repeats: int) -> dict:
    """Nanoseconds per dependent vector operation (16 float32 lanes, AVX-512)."""
    import torch
    x = torch.rand(16 * 256) + 1.0
    res = {}
    for name, op in OPS.items():
        if "multiply-add" in name:
            continue
        fn = torch.compile(_chain(op), dynamic=False, options={"max_fusion_size": 1 << 16})
        fn(x)
        best = float("inf")
        for _ in range(repeats):
            t0 = time.process_time()
            for _ in range(20):
                fn(x)
            best = min(best, (time.process_time() - t0) / 20)
        res[name] = {"ns_per_vector_op": 1e9 * best / (x.numel() / 16 * LAT_DEPTH)}
    return res


def arithmetic(repeats: int) -> dict:
    import torch
    x = torch.rand(ELEMS) + 1.0
    res = {}
    for name, op in OPS.items():
        fn = torch.compile(_chains(op), dynamic=False, options={"max_fusion_size": 4096})
        fn(x)
        calls = 200
        best = float("inf")
        for _ in range(repeats):
            t0 = time.process_time()
            for _ in range(calls):
                fn(x)
            best = min(best, (time.process_time() - t0) / calls)
        ops = ELEMS * CHAINS * DEPTH
        res[name] = {"ns_per_elem_op": 1e9 * best / ops, "elem_ops_per_s": ops / best}
    return res


# ---------------------------------------------------------------- the tracer's generated code
_CLASSES = [  # (class, regex on the right-hand side of one `auto tmpN = ...;` line), first wins
    ("fma", r"fmadd|fmsub"),
    ("rsqrt", r"rsqrt\(\)"),
    ("sqrt", r"sqrt\(\)"),
    ("division", r" / "),
    ("select", r"blendv"),
    ("compare", r" (>|<|>=|<=|==|!=) "),
    ("mul/add", r" [-+*] "),
]
_SIMPLE = ("fma", "select", "compare", "mul/add", "other")


def _vector_body(src: str) -> str:
    """The first vectorised loop body of one kernel's source (the full-vector case: inductor
    writes the same operations again for the tail)."""
    m = re.search(r"Vectorized<", src)
    if m is None:
        return ""
    start = src.rfind("{", 0, m.start())
    depth, i = 0, start
    while i < len(src):
        if src[i] == "{":
            depth += 1
        elif src[i] == "}":
            depth -= 1
            if depth == 0:
                break
        i += 1
    return src[start:i + 1]


def count_ops(src: str) -> dict:
    """Per element of the vectorised loop: vector operations by class (mask casts and
    broadcasts of scalars not counted: they cost no or one instruction per loop, not per
    element) and bytes loaded/stored."""
    body = _vector_body(src)
    counts = {c: 0 for c, _ in _CLASSES}
    counts.update(other=0, load_bytes=0, store_bytes=0)
    for line in body.splitlines():
        line = line.strip()
        if ".store(" in line:
            counts["store_bytes"] += 1 if ("bool" in line or "int8" in line) else 4
            continue
        if not line.startswith("auto tmp"):
            continue
        rhs = line.split("=", 1)[1].strip()
        if "ptr" in rhs and ("loadu" in rhs or "::from(" in rhs):
            counts["load_bytes"] += 1 if ("bool" in rhs or "VecMask" in rhs) else 4
            continue
        if "ptr" in rhs or rhs.startswith(("float(", "static_cast<", "double(", "int")) \
                or re.fullmatch(r"at::vec::Vectorized<\w+>\(tmp\d+\);", rhs) \
                or re.fullmatch(r"tmp\d+\.template cast<[\w, ]+>\(\);", rhs) \
                or re.fullmatch(r"at::vec::convert<[\w, ]+>\(tmp\d+\);", rhs):
            continue  # scalars, broadcasts, mask casts
        for cls, pat in _CLASSES:
            if re.search(pat, rhs):
                counts[cls] += 1
                break
        else:
            counts["other"] += 1
    return counts


def critical_path(src: str, lat: dict) -> float:
    """Longest dependency chain (ns) through one vectorised loop body: each ``auto tmpN = ...``
    costs its class's latency (``lat``: class -> ns; loads, scalars, broadcasts and mask casts
    0) and waits for the ``tmp`` values it reads."""
    body = _vector_body(src)
    done = {}
    for line in body.splitlines():
        line = line.strip()
        m = re.match(r"auto (tmp\d+) = (.*);$", line)
        if not m:
            continue
        name, rhs = m.groups()
        start = max((done.get(d, 0.0) for d in re.findall(r"tmp\d+", rhs)), default=0.0)
        cost = 0.0
        if not ("ptr" in rhs or rhs.startswith(("float(", "static_cast<", "double(", "int"))
                or re.fullmatch(r"at::vec::Vectorized<\w+>\(tmp\d+\)", rhs)
                or re.fullmatch(r"tmp\d+\.template cast<[\w, ]+>\(\)", rhs)):
            for cls, pat in _CLASSES:
                if re.search(pat, rhs):
                    cost = lat.get(cls, lat["mul/add"])
                    break
            else:
                cost = lat["mul/add"]
        done[name] = start + cost
    return max(done.values(), default=0.0)


def _double_gauss_on_axis(n: int):
    """The double Gauss lens and ``n`` on-axis float32 rays at the d line, uniform over its
    entrance pupil (seed 0); imports deeplens, so ``REPO`` must be on ``sys.path`` first."""
    import torch

    from deeplens.optics.io import load_lens
    from deeplens.optics.paraxial import paraxial
    from deeplens.optics.sampling import field_rays, random_disk

    lens = load_lens(os.path.join(REPO, "data", "lenses", "double_gauss.json"))
    with torch.no_grad():
        p = paraxial(lens)
        r_ep, z_ep = 0.5 * float(p.entrance_pupil_diameter), float(p.entrance_pupil_z)
    xy = (r_ep * random_disk(n, seed=0)).to(torch.float32)
    return lens, field_rays(lens, 0.0, WAVELENGTH_NM, xy, z_ep)


def _kernel_child(args) -> None:
    """Runs with TORCHINDUCTOR_CACHE_DIR set to an empty folder: compile, time, count."""
    import torch
    sys.path.insert(0, REPO)
    from deeplens.optics.options import TraceOptions

    torch.set_num_threads(1)
    n = int(float(args.rays))
    lens, rays = _double_gauss_on_axis(n)
    opt = TraceOptions(compile=True)
    with torch.no_grad():
        lens.trace_to_sensor(rays[:4096], options=opt)
        lens.trace_to_sensor(rays, options=opt)
        best = float("inf")
        for _ in range(args.repeats):
            c0 = time.process_time()
            lens.trace_to_sensor(rays, options=opt)
            best = min(best, time.process_time() - c0)
        prof = {}
        from torch.profiler import ProfilerActivity, profile
        with profile(activities=[ProfilerActivity.CPU]) as pr:
            lens.trace_to_sensor(rays, options=opt)
        for ev in pr.key_averages():
            prof[ev.key] = ev.cpu_time_total * 1e-6 / max(ev.count, 1) * ev.count
    kernels = []
    for path in sorted(glob.glob(os.path.join(os.environ["TORCHINDUCTOR_CACHE_DIR"], "**",
                                              "*.py"), recursive=True)):
        with open(path) as fh:
            text = fh.read()
        for m in re.finditer(r"cpp_fused_(\w+?)\s*=\s*async_compile\.cpp_pybinding\(.*?'''(.*?)'''",
                             text, re.S):
            if any(k["src"] == hash(m.group(2)) for k in kernels):
                continue  # the same kernel in a second output file
            kernels.append({"name": "cpp_fused_" + m.group(1), "src": hash(m.group(2)),
                            "ops": count_ops(m.group(2)), "lines": m.group(2).count("\n")})
            if args.dump:
                os.makedirs(args.dump, exist_ok=True)
                with open(os.path.join(args.dump, kernels[-1]["name"] + ".cpp"), "w") as fh:
                    fh.write(m.group(2))
    print(json.dumps({"forward_cpu_s": best, "n": n, "surfaces": len(lens.surfaces),
                      "kernels": kernels, "profile_s": prof}))


def _graph_child(args) -> None:
    """One trace + backward (RMS spot, every curvature trainable) in mode ``args.mode``: the
    tensors autograd saves for backward (a saved-tensor pack hook: count, bytes by dtype,
    storages counted once), the RSS held after the forward and the peak RSS."""
    import ctypes

    import torch
    sys.path.insert(0, os.path.join(REPO, "benchmarks"))
    from procmem import maxrss_bytes, reset_peak_rss, rss_bytes
    sys.path.insert(0, REPO)
    from deeplens.optics.options import TraceOptions

    torch.set_num_threads(1)
    n = int(float(args.rays))
    lens, rays = _double_gauss_on_axis(n)
    curv = [s.c for s in lens.surfaces if hasattr(s, "c")]
    opts = {"eager": TraceOptions(compile=False),
            "compiled, per surface (compile=True)": TraceOptions(compile="surface"),
            "compiled, per run (compile=\"lens\")": TraceOptions(compile="lens"),
            "compiled, per surface, checkpoint=True": TraceOptions(compile="surface",
                                                                   checkpoint=True)}
    opt = opts[args.mode]
    for c in curv:
        c.requires_grad_(True)

    def step(record=None):
        for c in curv:
            c.grad = None
        ctx = torch.autograd.graph.saved_tensors_hooks(*record) if record else None
        if ctx is not None:
            ctx.__enter__()
        out = lens.trace_to_sensor(rays, options=opt)
        pts = out.o[..., :2][out.valid]
        rms = torch.sqrt(((pts - pts.mean(0)) ** 2).sum(-1).mean())
        if ctx is not None:
            ctx.__exit__(None, None, None)
        held = rss_bytes()
        rms.backward()
        return held

    step() if "compiled" in args.mode else None  # compile (warm)
    seen = {}

    def pack(t):
        try:
            key = t.untyped_storage().data_ptr()
            seen[key] = (str(t.dtype), t.untyped_storage().nbytes(), tuple(t.shape))
        except (RuntimeError, NotImplementedError):
            pass
        return t

    step((pack, lambda t: t))
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 16 * 1024)
        libc.mallopt(-1, 128 * 1024)
        libc.malloc_trim(0)
    except (OSError, AttributeError):
        pass
    rss0 = rss_bytes()
    reset_peak_rss()
    held = step()
    peak = maxrss_bytes() - rss0
    big = {k: v for k, v in seen.items() if v[1] >= n}  # per-ray tensors only
    by_dtype = {}
    for dt, nb, _ in big.values():
        by_dtype[dt] = by_dtype.get(dt, 0) + nb
    print(json.dumps({"mode": args.mode, "n": n, "surfaces": len(lens.surfaces),
                      "saved_tensors": len(big), "saved_bytes": sum(by_dtype.values()),
                      "saved_by_dtype": by_dtype, "held_bytes": held - rss0,
                      "peak_bytes": peak}))


GRAPH_MODES = ("eager", "compiled, per surface (compile=True)",
               "compiled, per run (compile=\"lens\")", "compiled, per surface, checkpoint=True")


def graph(args) -> list:
    rows = []
    for mode in GRAPH_MODES:
        env = dict(os.environ, OMP_NUM_THREADS="1")
        cmd = [sys.executable, os.path.abspath(__file__), "--child-graph", mode, "--rays",
               str(args.rays)]
        out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
        if out.returncode != 0:
            sys.stderr.write(out.stderr)
            raise SystemExit(f"graph child failed: {mode}")
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    return rows


def kernel(args) -> dict:
    with tempfile.TemporaryDirectory(prefix="roofline-inductor-") as cache:
        env = dict(os.environ, OMP_NUM_THREADS="1", TORCHINDUCTOR_CACHE_DIR=cache)
        cmd = [sys.executable, os.path.abspath(__file__), "--child", "--rays", str(args.rays),
               "--repeats", str(args.repeats)] + (["--dump", args.dump] if args.dump else [])
        out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
        if out.returncode != 0:
            sys.stderr.write(out.stderr)
            raise SystemExit("kernel child failed")
        return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", default="bandwidth,arithmetic,latency,kernel,graph")
    ap.add_argument("--sources", default=None,
                    help="a folder of kernels written by --dump: the critical paths only")
    ap.add_argument("--mib", type=int, default=256, help="MiB per triad array")
    ap.add_argument("--rays", default="1e6")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", default=None)
    ap.add_argument("--dump", default=None, help="write the generated kernels' C++ here")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--child-graph", dest="mode", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _kernel_child(args)
        return
    if args.mode:
        _graph_child(args)
        return
    import torch
    torch.set_num_threads(1)
    parts = args.parts.split(",")
    res = {"load_start": os.getloadavg()[0],
           "capability": torch.backends.cpu.get_cpu_capability()}
    if "bandwidth" in parts:
        res["bandwidth"] = bandwidth(args.mib, args.repeats)
    if "arithmetic" in parts:
        res["arithmetic"] = arithmetic(args.repeats)
    if "latency" in parts:
        res["latency"] = latency(args.repeats)
    if "kernel" in parts:
        res["kernel"] = kernel(args)
    if "graph" in parts:
        res["graph"] = graph(args)
    res["load_end"] = os.getloadavg()[0]
    print(f"1 thread, CPU capability {res['capability']}, load average (1 min) "
          f"{res['load_start']:.1f} at the start, {res['load_end']:.1f} at the end\n")
    if "bandwidth" in res:
        b = res["bandwidth"]
        print(f"bandwidth ({b['array_mib']} MiB arrays): triad {b['triad_Bps'] / 1e9:.1f} GB/s, "
              f"copy {b['copy_Bps'] / 1e9:.1f} GB/s\n")
    if "arithmetic" in res:
        print("| operation (float32, compiled, cache-resident) | ns per element-op | "
              "G element-ops/s |\n|---|---|---|")
        for name, r in res["arithmetic"].items():
            print(f"| {name} | {r['ns_per_elem_op']:.3f} | {r['elem_ops_per_s'] / 1e9:.2f} |")
        print()
    if "latency" in res:
        print("| operation (float32, one dependent chain) | ns per dependent 16-lane vector op |"
              "\n|---|---|")
        for name, r in res["latency"].items():
            print(f"| {name} | {r['ns_per_vector_op']:.3f} |")
        print()
        L = res["latency"]
        simple = 0.5 * (L["multiply (x * a)"]["ns_per_vector_op"]
                        + L["add (x + b)"]["ns_per_vector_op"])
        lat = {"mul/add": simple, "fma": simple, "select": simple, "compare": simple,
               "other": simple, "division": L["division (a / x)"]["ns_per_vector_op"],
               "sqrt": L["sqrt"]["ns_per_vector_op"], "rsqrt": L["rsqrt"]["ns_per_vector_op"]}
        srcs = []
        if args.sources:
            srcs = [(os.path.basename(f), open(f).read())
                    for f in sorted(glob.glob(os.path.join(args.sources, "*.cpp")))]
        elif args.dump:
            srcs = [(os.path.basename(f), open(f).read())
                    for f in sorted(glob.glob(os.path.join(args.dump, "*.cpp")))]
        for name, src in srcs:
            cp = critical_path(src, lat)
            print(f"critical path of {name[:50]}: {cp:.1f} ns per 16 rays = {cp / 16:.2f} ns "
                  f"per ray")
        print()
    if "kernel" in res:
        k = res["kernel"]
        tot = {}
        print("| kernel | loads B | stores B | mul/add | fma | div | sqrt | rsqrt | cmp | "
              "select | other |\n|---|---|---|---|---|---|---|---|---|---|---|")
        for kk in k["kernels"]:
            o = kk["ops"]
            for key, v in o.items():
                tot[key] = tot.get(key, 0) + v
            print(f"| {kk['name'][:40]} | {o['load_bytes']} | {o['store_bytes']} | {o['mul/add']} "
                  f"| {o['fma']} | {o['division']} | {o['sqrt']} | {o['rsqrt']} | {o['compare']} "
                  f"| {o['select']} | {o['other']} |")
        S, n = k["surfaces"], k["n"]
        print(f"| all ({len(k['kernels'])} kernels) per ray | {tot.get('load_bytes', 0)} | "
              f"{tot.get('store_bytes', 0)} | {tot.get('mul/add', 0)} | {tot.get('fma', 0)} | "
              f"{tot.get('division', 0)} | {tot.get('sqrt', 0)} | {tot.get('rsqrt', 0)} | "
              f"{tot.get('compare', 0)} | {tot.get('select', 0)} | "
              f"{tot.get('other', 0)} |\n")
        res["kernel_totals"] = tot
        t = k["forward_cpu_s"]
        print(f"compiled forward, {n:.0e} rays, {S} surfaces: {t:.4f} CPU s = "
              f"{1e9 * t / (n * S):.2f} ns per ray-surface")
        if "arithmetic" in res and "bandwidth" in res:
            a = res["arithmetic"]
            c_fma = 0.5 * (a["multiply (x * a)"]["ns_per_elem_op"]
                           + a["add (x + b)"]["ns_per_elem_op"])
            c_div = a["division (a / x)"]["ns_per_elem_op"]
            c_sqrt = a["sqrt"]["ns_per_elem_op"]
            c_rsqrt = a["rsqrt"]["ns_per_elem_op"]
            simple = sum(tot.get(c, 0) for c in _SIMPLE)
            t_ar = 1e-9 * n * (simple * c_fma + tot.get("division", 0) * c_div
                               + tot.get("sqrt", 0) * c_sqrt + tot.get("rsqrt", 0) * c_rsqrt)
            byt = n * (tot.get("load_bytes", 0) + tot.get("store_bytes", 0))
            t_mem = byt / res["bandwidth"]["triad_Bps"]
            res["bounds"] = {"arith_s": t_ar, "mem_s": t_mem, "measured_s": t}
            print(f"arithmetic bound (each op at its measured throughput, simple ops at the "
                  f"mean of the multiply's and the add's): {t_ar:.4f} s ({1e9 * t_ar / (n * S):.2f} ns per "
                  f"ray-surface); memory bound (triad bandwidth, {byt / n:.0f} B per ray): "
                  f"{t_mem:.4f} s; measured / arithmetic bound = {t / t_ar:.2f}")
        top = sorted(k["profile_s"].items(), key=lambda kv: -kv[1])[:12]
        print("\nprofile of one compiled forward (torch profiler, CPU s, top 12):")
        for key, v in top:
            print(f"  {v:.4f}  {key}")
    if "graph" in res:
        print("\n| trace + backward | tensors saved (per ray) | saved B per ray-surface | by dtype, "
              "MiB | RSS held after forward, MiB | peak extra MiB |\n|---|---|---|---|---|---|")
        for r in res["graph"]:
            rs = r["n"] * r["surfaces"]
            dts = ", ".join(f"{k.replace('torch.', '')} {v / 2**20:.0f}"
                            for k, v in r["saved_by_dtype"].items())
            print(f"| {r['mode']} | {r['saved_tensors']} | {r['saved_bytes'] / rs:.1f} | {dts} | "
                  f"{r['held_bytes'] / 2**20:.0f} | {r['peak_bytes'] / 2**20:.0f} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=1)


if __name__ == "__main__":
    main()
