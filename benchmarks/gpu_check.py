#!/usr/bin/env python
"""GPU check: the CUDA tests, tracer and adjoint-render throughput, training steps, a tiny run.

One results file, ``<out>/gpu_check.md``: a markdown table per section and, at its end, every
number as JSON (:func:`read_results` parses it back).  Sections (``SECTIONS``):

* ``env``: device name, memory, torch / CUDA / cuDNN versions, TF32 flags, CPU count, commit;
* ``cuda_tests``: ``pytest -k cuda`` over the test files that skip without CUDA (a
  ``skipif(not torch.cuda.is_available())``), one row per test with its outcome and seconds;
* ``trace``: ``lens.trace_to_sensor`` of the double Gauss (``bench_trace.py``'s workload:
  on-axis rays over the entrance pupil, float32), forward without grad and trace + RMS spot +
  backward into every curvature: rays/s, ray-surfaces/s, peak memory;
* ``adjoint_render``: ``MonteCarloRenderer(adjoint=True)`` of ``bench_render_memory.py`` (EDOF
  lens with a cubic plate, monochrome 256 x 256 sensor, MSE loss, backward into the plate and
  ``d_sensor``) at growing rays per pixel, plain autograd at the smallest for the gradient
  cosine and the memory ratio;
* ``train_step``: ``bench_train_step.py``'s split training step of ``experiment=edof`` and
  ``experiment=doublet`` at N x N sensor pixels (N = 256, 512; images 2N, the configs' ratio),
  same field of view as the configs' (EDOF: ``configs/experiment/edof.yaml``'s GPU recipe,
  1.2544 mm square; doublet: 64 x 0.0804 mm), module and batches on the device;
* ``e2e``: ``python train.py experiment=edof trainer=gpu`` for a few steps (optics training
  in the second half), with validation and test.

Every row carries ``device``, ``device_name``, ``torch``, ``cuda``, ``dtype``, its sizes and
``wall_s``.  A section that fails keeps the rows it finished and records the error; a row that
fails (e.g. CUDA out of memory) records its error and the next row runs.  Rows that the
section's time budget (``--budget``) would not fit are recorded as skipped.

Usage::

    bash benchmarks/gpu_check.sh --out /tmp/gc            # set-up, then every section with a
                                                          # hard `timeout` per section
    python benchmarks/gpu_check.py --out /tmp/gc --dry-run          # all sections in-process,
                                                                    # CPU, tiny sizes
    python benchmarks/gpu_check.py --section trace --out /tmp/gc --budget 40
    python benchmarks/gpu_check.py --report --out /tmp/gc           # (re)write gpu_check.md

``--dry-run`` runs every section on the CPU at tiny sizes (a few thousand rays, 16 and 32 px,
one step, a 2-step ``trainer=cpu`` run): it proves the code paths, not the speed.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import math
import os
import re
import subprocess
import sys
import time
import traceback
import xml.etree.ElementTree as ET
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
# bench_trace, bench_render_memory, bench_train_step, procmem; and this checkout's deeplens
# first (not an editable install of another checkout)
for _p in (str(REPO), str(HERE)):
    if _p in sys.path:
        sys.path.remove(_p)
    sys.path.insert(0, _p)

SECTIONS = ("env", "cuda_tests", "trace", "adjoint_render", "train_step", "e2e")
# seconds per section on the GPU: about 6 min in all, after ~2 min of `bash dev.sh` set-up
GPU_BUDGETS = {"env": 20, "cuda_tests": 60, "trace": 40, "adjoint_render": 55,
               "train_step": 110, "e2e": 70}
DRY_BUDGETS = {s: 90 for s in SECTIONS}
RESULTS = "gpu_check.md"
PARTS = "gpu_check_parts"
MIB = 2.0 ** 20
# field of view (mm square) of the training rows: EDOF at edof.yaml's GPU recipe
# (256 px of 4.9 um), the doublet at configs/sensor/doublet.yaml's (64 px of 80.4 um)
TRAIN_FOV_MM = {"edof": 256 * 0.0049, "doublet": 64 * 0.0804}

GPU_PLAN = dict(
    trace_rays=[1_000_000, 4_000_000, 16_000_000], trace_repeats=3,
    render_resolution=(256, 256), render_spp=[16, 64, 256], render_plain_spp=[16],
    render_chunk_rays=262144,
    # the doublet's Monte Carlo renderer is geometric: at these pixels `auto` would pick
    # diffraction (8-12 % of the energy misplaced), which it refuses (as bench_train_step.py)
    train_px=[256, 512], train_warmup=1, train_steps=3,
    train_extra={"edof": [], "doublet": ["render.psf_model=geometric"]},
    e2e=["trainer=gpu", "trainer.max_steps=20", "trainer.max_epochs=2",
         "data.train_steps_per_epoch=10", "data.val_size=4", "data.test_size=4",
         "model.optics_warmup_steps=10"],
)
DRY_PLAN = dict(
    trace_rays=[2000, 8000], trace_repeats=1,
    render_resolution=(16, 16), render_spp=[2, 4], render_plain_spp=[2], render_chunk_rays=128,
    train_px=[16, 32], train_warmup=0, train_steps=1,
    train_extra={"edof": ["render.psf_rays=1024", "model.deconvolution.rays=1024",
                          "data.batch_size=2"],
                 "doublet": ["render.spp=2", "data.batch_size=2"]},
    e2e=["trainer=cpu", "trainer.max_steps=2", "trainer.max_epochs=1",
         "data.train_steps_per_epoch=2", "data.val_size=2", "data.test_size=2",
         "data.batch_size=2", "sensor.resolution=[16,16]", "data.image_size=32",
         "render.psf_rays=1024", "model.deconvolution.rays=1024",
         "callbacks.image_logger.psf_rays=256", "model.optics_warmup_steps=1"],
)


# ============================================================================ context and rows
def environment(device: str) -> dict:
    """What every row carries: the device, its name, torch / CUDA versions."""
    import torch

    env = {"device": device, "torch": torch.__version__, "cuda": torch.version.cuda}
    if device.startswith("cuda") and torch.cuda.is_available():
        env["device_name"] = torch.cuda.get_device_name(torch.device(device))
    else:
        import platform
        env["device_name"] = f"CPU ({platform.processor() or platform.machine()})"
    return env


class Context:
    """Settings of one run: device, dry run, plan (sizes), output folder, budgets."""

    def __init__(self, out: Path, device: str = "auto", dry_run: bool = False,
                 plan: dict | None = None, budgets: dict | None = None):
        import torch

        self.dry_run = bool(dry_run)
        if device == "auto":
            device = "cuda" if torch.cuda.is_available() and not dry_run else "cpu"
        self.device = device
        self.cuda = device.startswith("cuda")
        self.out = Path(out)
        self.parts = self.out / PARTS
        self.parts.mkdir(parents=True, exist_ok=True)
        self.plan = dict(plan or (DRY_PLAN if dry_run else GPU_PLAN))
        self.budgets = dict(budgets or (DRY_BUDGETS if dry_run else GPU_BUDGETS))
        self.env = environment(device)

    def check_device(self) -> None:
        import torch

        if self.cuda and not torch.cuda.is_available():
            raise RuntimeError(f"device {self.device} requested but torch.cuda.is_available() "
                               "is False")
        if not self.cuda and not self.dry_run:
            raise RuntimeError("no CUDA device (torch.cuda.is_available() is False): the full "
                               "sizes are for a GPU; run with --dry-run for the CPU check")

    def sync(self) -> None:
        if self.cuda:
            import torch
            torch.cuda.synchronize(torch.device(self.device))


class Section:
    """Rows of one section, written to ``<out>/gpu_check_parts/<name>.json`` after each row (a
    section killed by ``timeout`` keeps what it finished)."""

    def __init__(self, name: str, ctx: Context, budget_s: float | None = None):
        self.name, self.ctx = name, ctx
        self.budget_s = float(budget_s if budget_s is not None else ctx.budgets[name])
        self.t0 = time.perf_counter()
        self.rows: list[dict] = []
        self.status, self.error = "running", None
        self.flush()

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def remaining(self) -> float:
        return self.budget_s - self.elapsed()

    def fits(self, predicted_s: float | None) -> bool:
        """Whether a step predicted to take ``predicted_s`` fits the rest of the budget (with a
        10 % + 3 s margin); unknown predictions fit."""
        return predicted_s is None or predicted_s < 0.9 * self.remaining() - 3.0

    def fits_memory(self, predicted_mib: float) -> bool:
        """Whether a predicted peak fits in 60 % of the CUDA device's memory (always on CPU)."""
        if not self.ctx.cuda:
            return True
        import torch
        total = torch.cuda.get_device_properties(torch.device(self.ctx.device)).total_memory
        return predicted_mib * MIB < 0.6 * total

    def row(self, **values) -> dict:
        r = {**self.ctx.env, **values}
        self.rows.append(r)
        self.flush()
        return r

    def skip(self, name: str, predicted_s: float, **values) -> None:
        self.row(name=name, skipped=f"predicted {predicted_s:.0f} s > {self.remaining():.0f} s "
                                    "left of the section's budget", **values)

    def guarded(self, name: str, fn, **values) -> dict | None:
        """``fn()`` (a dict of numbers) as a row; an exception becomes the row's ``error``."""
        t0 = time.perf_counter()
        try:
            res = fn()
        except (Exception, SystemExit) as e:  # noqa: BLE001 - recorded, the next row runs
            _free(self.ctx)
            self.row(name=name, error=_error_text(e), wall_s=time.perf_counter() - t0, **values)
            return None
        return self.row(name=name, **values, **res, wall_s=time.perf_counter() - t0)

    def finish(self, error: BaseException | None = None) -> None:
        """``ok``; ``partial`` when a row recorded an error; ``error`` when the section
        stopped on ``error``."""
        self.status = "error" if error is not None else \
            "partial" if any("error" in r for r in self.rows) else "ok"
        self.error = None if error is None else _error_text(error)
        self.flush()

    def flush(self) -> None:
        data = {"section": self.name, "status": self.status, "error": self.error,
                "budget_s": self.budget_s, "wall_s": self.elapsed(), "dry_run": self.ctx.dry_run,
                "env": self.ctx.env, "rows": self.rows}
        path = self.ctx.parts / f"{self.name}.json"
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(data, indent=1, default=str))
        os.replace(tmp, path)


def _error_text(e: BaseException) -> str:
    tb = traceback.extract_tb(e.__traceback__)
    where = f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
    return f"{type(e).__name__}: {str(e).strip()[:800]}{where}"


def _free(ctx: Context) -> None:
    gc.collect()
    if ctx.cuda:
        import torch
        torch.cuda.empty_cache()


@contextlib.contextmanager
def peak_memory(ctx: Context):
    """Yields a dict that gets ``peak_mib`` (the peak during the block minus the memory before
    it) and ``memory`` (what was measured: CUDA ``max_memory_allocated`` or the process's peak
    RSS, the latter ``None`` where the kernel's high-water mark cannot be reset)."""
    import torch

    out: dict = {}
    gc.collect()
    if ctx.cuda:
        dev = torch.device(ctx.device)
        torch.cuda.synchronize(dev)
        torch.cuda.reset_peak_memory_stats(dev)
        base = torch.cuda.memory_allocated(dev)
        yield out
        torch.cuda.synchronize(dev)
        out.update(peak_mib=(torch.cuda.max_memory_allocated(dev) - base) / MIB,
                   memory="cuda max_memory_allocated")
        return
    from procmem import maxrss_bytes, reset_peak_rss, rss_bytes
    ok = reset_peak_rss()
    base = rss_bytes()
    yield out
    out.update(peak_mib=(maxrss_bytes() - base) / MIB if ok else None, memory="cpu peak RSS")


def _timed(ctx: Context, fn, repeats: int) -> tuple[float, object]:
    """Min wall time of ``fn()`` over ``repeats`` runs (device synchronised), and its result."""
    best, res = math.inf, None
    for _ in range(max(1, repeats)):
        ctx.sync()
        t0 = time.perf_counter()
        res = fn()
        ctx.sync()
        best = min(best, time.perf_counter() - t0)
    return best, res


# ============================================================================ sections
def section_env(sec: Section) -> None:
    import torch

    import deeplens

    info = {"python": sys.version.split()[0], "cpu_count": os.cpu_count(),
            "torch_threads": torch.get_num_threads(), "cuda_available": torch.cuda.is_available(),
            "cudnn": torch.backends.cudnn.version() if torch.backends.cudnn.is_available()
            else None,
            "tf32_matmul": torch.backends.cuda.matmul.allow_tf32,
            "tf32_cudnn": torch.backends.cudnn.allow_tf32,
            "deeplens": getattr(deeplens, "__version__", None), "deeplens_path": deeplens.__file__}
    try:
        info["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                                        capture_output=True, text=True, timeout=10
                                        ).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        info["commit"] = None
    if sec.ctx.cuda and torch.cuda.is_available():
        dev = torch.device(sec.ctx.device)
        p = torch.cuda.get_device_properties(dev)
        info.update(capability=f"{p.major}.{p.minor}", memory_gib=p.total_memory / 2 ** 30,
                    multiprocessors=p.multi_processor_count)
        t0 = time.perf_counter()
        a = torch.randn(4096, 4096, device=dev)
        (a @ a).sum().item()  # first kernel: context and cuBLAS start-up
        info["first_matmul_s"] = time.perf_counter() - t0
    sec.row(name="environment", **info)


def cuda_test_files() -> list[str]:
    """Test files with a ``skipif`` on ``torch.cuda.is_available()`` (relative paths)."""
    files = []
    for p in sorted((REPO / "tests").rglob("test_*.py")):
        text = p.read_text(encoding="utf-8", errors="replace")
        if re.search(r"skipif\(\s*not\s+torch\.cuda\.is_available\(\)", text):
            files.append(str(p.relative_to(REPO)))
    return files


def section_cuda_tests(sec: Section) -> None:
    files = cuda_test_files()
    if not files:
        raise RuntimeError("no test file has a skipif(not torch.cuda.is_available()) test")
    xml = sec.ctx.parts / "cuda_tests.xml"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-k", "cuda",
           f"--junitxml={xml}", *files]
    t0 = time.perf_counter()
    timeout = max(5.0, sec.remaining() - 5.0)
    try:
        r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as e:
        raise RuntimeError(f"pytest did not finish within {timeout:.0f} s") from e
    wall = time.perf_counter() - t0
    (sec.ctx.parts / "cuda_tests.log").write_text(r.stdout + r.stderr)
    if not xml.exists():
        raise RuntimeError(f"pytest wrote no report (rc {r.returncode}): "
                           f"{(r.stdout + r.stderr)[-600:]}")
    counts = {"n_passed": 0, "n_failed": 0, "n_skipped": 0}
    for case in ET.parse(xml).getroot().iter("testcase"):
        outcome, msg = "passed", None
        for tag in ("failure", "error", "skipped"):
            el = case.find(tag)
            if el is not None:
                outcome = "skipped" if tag == "skipped" else "failed"
                msg = (el.get("message") or "")[:300]
        counts["n_" + outcome] += 1
        sec.row(name=f"{case.get('classname')}::{case.get('name')}", outcome=outcome,
                message=msg, wall_s=float(case.get("time") or 0.0))
    sec.row(name="pytest -k cuda (all)", files=files, returncode=r.returncode, **counts,
            wall_s=wall)
    if r.returncode not in (0, 5) or counts["n_failed"]:
        raise RuntimeError(f"{counts['n_failed']} CUDA test(s) failed (pytest rc {r.returncode}; "
                           f"log: {PARTS}/cuda_tests.log)")


def section_trace(sec: Section) -> None:
    import torch
    from bench_trace import LENS, WAVELENGTH_NM

    from deeplens.optics.paraxial import paraxial
    from deeplens.optics.io import load_lens
    from deeplens.optics.sampling import field_rays, random_disk

    ctx, plan = sec.ctx, sec.ctx.plan
    dev, dtype = torch.device(ctx.device), torch.float32
    lens = load_lens(REPO / LENS).to(dtype).to(dev)
    curv = [s.c for s in lens.surfaces if hasattr(s, "c")]
    with torch.no_grad():
        p = paraxial(lens)
        r_ep, z_ep = 0.5 * float(p.entrance_pupil_diameter), float(p.entrance_pupil_z)
    S = len(lens.surfaces)
    sizes = dict(lens="double_gauss", surfaces=S, field_deg=0.0, dtype="float32")

    def forward(rays):
        with torch.no_grad():
            return int(lens.trace_to_sensor(rays).valid.sum())

    def backward(rays):
        for c in curv:
            c.requires_grad_(True)
            c.grad = None
        out = lens.trace_to_sensor(rays)
        pts = out.o[..., :2][out.valid]
        rms = torch.sqrt(((pts - pts.mean(0)) ** 2).sum(-1).mean())
        rms.backward()
        for c in curv:
            c.requires_grad_(False)
        return float(rms.detach())

    last = {}
    for n in plan["trace_rays"]:
        xy = (r_ep * random_disk(n, seed=0)).to(dtype=dtype, device=dev)
        rays = field_rays(lens, 0.0, WAVELENGTH_NM, xy, z_ep)
        for kind, fn in (("forward (no grad)", forward), ("trace + RMS spot + backward", backward)):
            pred = None
            if kind in last:
                n0, t0, m0 = last[kind]
                pred = t0 * n / n0 * (plan["trace_repeats"] + 1)
                if not sec.fits_memory(m0 * n / n0):
                    sec.row(name=kind, rays=n, **sizes, skipped=f"predicted peak "
                            f"{m0 * n / n0 / 1024:.1f} GiB > 60 % of the device's memory")
                    continue
            if not sec.fits(pred):
                sec.skip(kind, pred, rays=n, **sizes)
                continue

            def run(fn=fn, rays=rays, n=n):
                fn(rays)  # warm-up (kernels, allocator)
                with peak_memory(ctx) as mem:
                    secs, res = _timed(ctx, lambda: fn(rays), plan["trace_repeats"])
                return {"s": secs, "rays_per_s": n / secs, "ray_surfaces_per_s": n * S / secs,
                        **mem, ("valid_rays" if isinstance(res, int) else "rms_mm"): res,
                        "repeats": plan["trace_repeats"]}

            r = sec.guarded(kind, run, rays=n, **sizes)
            if r is not None:
                last[kind] = (n, r["s"], r["peak_mib"] or 0.0)
        del xy, rays
        _free(ctx)


def section_adjoint_render(sec: Section) -> None:
    from bench_render_memory import LENSES, run_one

    from deeplens.optics.io import load_lens

    ctx, plan = sec.ctx, sec.ctx.plan
    name = LENSES["edof"][0]
    path = REPO / "data" / "lenses" / name
    S = len(load_lens(path).surfaces)
    with open(path) as f:
        circle = float(json.load(f)["sensor"]["semi_diameter_mm"])
    H, W = plan["render_resolution"]
    pixel_mm = round(2 * circle / math.hypot(H, W), 6)
    runs = [("plain", s) for s in plan["render_plain_spp"]] + \
        [("adjoint", s) for s in plan["render_spp"]]
    runs.sort(key=lambda m: (m[1], m[0] != "adjoint"))  # by size, adjoint first
    grads, last = {}, {}
    for mode, spp in runs:
        sizes = dict(lens="edof_achromat (cubic plate)", dtype="float32", surfaces=S,
                     resolution=[H, W],
                     pixel_mm=pixel_mm, spp=spp, chunk_rays=plan["render_chunk_rays"],
                     mode=mode)
        pred = None
        if mode in last:
            s0, t0 = last[mode]
            pred = t0 * spp / s0 * 2.5  # two passes (memory, time) and the set-up
        if not sec.fits(pred):
            sec.skip(f"{mode} render + backward", pred, **sizes)
            continue
        cfg = dict(device=ctx.device, dtype="float32", lens="edof", plate_alpha_mm=0.01,
                   resolution=(H, W), pixel_mm=pixel_mm, depth_mm=5000.0, mode=mode, spp=spp,
                   chunk_rays=plan["render_chunk_rays"], seed=3, threads=None, timed=True)

        def run(cfg=cfg, mode=mode, spp=spp):
            t0 = time.perf_counter()
            r = run_one(cfg)
            if "oom" in r:
                raise MemoryError(r["oom"])
            secs = r["time_s"]
            out = {"rays": r["rays"], "chunks": r["chunks"], "fwd_s": r["fwd_s"],
                   "bwd_s": r["bwd_s"], "s": secs, "rays_per_s": r["rays"] / secs,
                   "ray_surfaces_per_s": r["rays"] * S / secs, "loss": r["loss"],
                   "peak_mib": r["peak_cuda_mib"] if ctx.cuda else r["peak_rss_mib"],
                   "memory": "cuda max_memory_allocated" if ctx.cuda else "cpu peak RSS",
                   "held_after_fwd_mib": r.get("held_mib"), "total_s": time.perf_counter() - t0}
            grads[(mode, spp)] = (r["grad"], out["peak_mib"])
            other = grads.get(("plain" if mode == "adjoint" else "adjoint", spp))
            if other is not None:
                a, b = r["grad"], other[0]
                na, nb = math.sqrt(sum(x * x for x in a)), math.sqrt(sum(x * x for x in b))
                out["grad_cos_vs_other_mode"] = sum(x * y for x, y in zip(a, b)) / (na * nb)
                if mode == "plain" and other[1]:
                    out["plain_over_adjoint_peak"] = out["peak_mib"] / other[1]
            return out

        r = sec.guarded(f"{mode} render + backward", run, **sizes)
        if r is not None:
            last[mode] = (spp, r["total_s"])
        _free(ctx)


def section_train_step(sec: Section) -> None:
    import torch
    from bench_train_step import _child

    ctx, plan = sec.ctx, sec.ctx.plan
    rows = [(exp, n) for n in plan["train_px"] for exp in ("edof", "doublet")]
    last = {}
    for exp, n in rows:
        pixel = round(TRAIN_FOV_MM[exp] / n, 7)
        overrides = [f"sensor.resolution=[{n},{n}]", f"sensor.pixel_size_mm={pixel}",
                     f"data.image_size={2 * n}", *plan["train_extra"][exp]]
        spec = "|".join([exp, *overrides])
        sizes = dict(experiment=exp, sensor_px=n, image_px=2 * n, pixel_size_mm=pixel,
                     overrides=overrides)
        pred = None
        if exp in last:  # the set-up as before, the steps scaled by the pixel count
            n0, build_s, steps_s = last[exp]
            pred = build_s + steps_s * (n / n0) ** 2
        if not sec.fits(pred):
            sec.skip(f"{exp} {n} px", pred, **sizes)
            continue
        args = argparse.Namespace(code=str(REPO), threads=torch.get_num_threads(),
                                  device=ctx.device, warmup=plan["train_warmup"],
                                  steps=plan["train_steps"],
                                  output_dir=str(ctx.parts / "train_step_run"))
        t0 = time.perf_counter()
        try:
            res = _child(spec, args)
        except (Exception, SystemExit) as e:  # noqa: BLE001 - recorded, the next row runs
            _free(ctx)
            sec.row(name=f"{exp} {n} px", error=_error_text(e),
                    wall_s=time.perf_counter() - t0, **sizes)
            continue
        wall = time.perf_counter() - t0
        n_steps = plan["train_warmup"] + plan["train_steps"]
        steps_s = sum(res[k]["step"] * n_steps for k in ("optics train", "optics fixed")
                      if k in res)
        last[exp] = (n, max(0.0, wall - steps_s), steps_s)
        for label in ("optics train", "optics fixed"):
            if label not in res:
                continue
            p = res[label]
            sec.row(name=f"{exp} {n} px, {label}", **sizes, dtype=res["dtype"],
                    batch=res["batch"], warmup=plan["train_warmup"], steps=plan["train_steps"],
                    **{f"{k}_s" if k not in ("loss", "peak_mib", "rss_mib") else k: v
                       for k, v in p.items()},
                    memory="cuda max_memory_allocated" if ctx.cuda else None, wall_s=wall)
        _free(ctx)


_SUMMARY_ROW = re.compile(r"^\s+(\S+(?: m)?)\s+(-?[\d.]+) / (-?[\d.]+)\s*\|\s*(-?[\d.]+) / "
                          r"(-?[\d.]+)\s*$")


def parse_summary(log: str) -> list[dict]:
    """The test rows of ``train.py``'s closing summary (``deeplens.training.train.summary``):
    per depth (or field band) the restored and the sensor image's PSNR (dB) and SSIM."""
    rows = []
    for line in log.splitlines():
        t = _SUMMARY_ROW.match(line)
        if t:
            rows.append({"name": f"test {t.group(1)}", "psnr_restored_db": float(t.group(2)),
                         "ssim_restored": float(t.group(3)), "psnr_sensor_db": float(t.group(4)),
                         "ssim_sensor": float(t.group(5))})
    return rows


def section_e2e(sec: Section) -> None:
    ctx = sec.ctx
    run_dir = ctx.parts / "e2e_run"
    overrides = ["experiment=edof", *ctx.plan["e2e"], "trainer.enable_progress_bar=false",
                 f"hydra.run.dir={run_dir}"]
    cmd = [sys.executable, str(REPO / "train.py"), *overrides]
    timeout = max(5.0, sec.remaining() - 5.0)
    env = dict(os.environ)
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout,
                           env=env)
    except subprocess.TimeoutExpired as e:
        raise RuntimeError(f"train.py did not finish within {timeout:.0f} s") from e
    wall = time.perf_counter() - t0
    log = r.stdout + r.stderr
    (ctx.parts / "e2e.log").write_text(log)
    m = re.search(r"finished after (\d+) epoch\(s\), (\d+) step\(s\)", log)
    res = {"returncode": r.returncode, "epochs": int(m.group(1)) if m else None,
           "steps": int(m.group(2)) if m else None,
           "last_ckpt": (run_dir / "checkpoints" / "last.ckpt").is_file()}
    sec.row(name="train.py " + " ".join(overrides[:2]), overrides=overrides, **res,
            wall_s=wall)
    for row in parse_summary(log):
        sec.row(**row)
    if r.returncode != 0:
        raise RuntimeError(f"train.py exited with {r.returncode}: {log.strip()[-600:]}")


FUNCS = {"env": section_env, "cuda_tests": section_cuda_tests, "trace": section_trace,
         "adjoint_render": section_adjoint_render, "train_step": section_train_step,
         "e2e": section_e2e}


def run_section(name: str, ctx: Context, budget_s: float | None = None) -> Section:
    """Run one section, recording its rows and (if it fails) its error; never raises."""
    sec = Section(name, ctx, budget_s)
    try:
        if name != "env":
            ctx.check_device()
        FUNCS[name](sec)
    except (Exception, SystemExit) as e:  # noqa: BLE001 - recorded, the other sections still run
        sec.finish(e)
    else:
        sec.finish()
    _free(ctx)
    return sec


# ============================================================================ report
def collect(out: Path) -> dict:
    """Every section's part file (or why it has none) as one dict."""
    parts = Path(out) / PARTS
    sections, env = {}, None
    for name in SECTIONS:
        f = parts / f"{name}.json"
        rc_file = parts / f"{name}.rc"
        rc = rc_file.read_text().strip() if rc_file.exists() else None
        if not f.exists():
            sections[name] = {"status": "error", "rows": [],
                              "error": "not run" if rc is None else
                              f"no result (exit status {rc})"}
            continue
        d = json.loads(f.read_text())
        if d["status"] == "running":  # killed: by `timeout` (124 / 137) or a crash
            why = ("timed out" if rc in ("124", "137") else
                   f"did not finish (exit status {rc})" if rc is not None else "did not finish")
            d.update(status="error", error=f"{why} after {d['wall_s']:.0f} s of a "
                     f"{d['budget_s']:.0f} s budget; rows up to then kept (log: "
                     f"{PARTS}/{name}.log)")
        env = env or d.get("env")
        sections[name] = {k: d.get(k) for k in ("status", "error", "budget_s", "wall_s",
                                                 "dry_run", "rows")}
    return {"env": env, "sections": sections}


_FIRST = ("name", "outcome", "error", "skipped")
_HIDDEN = {"device", "device_name", "torch", "cuda", "message", "files", "overrides",
           "deeplens_path"}


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return "x".join(str(x) for x in v) if all(isinstance(x, int) for x in v) else str(v)
    return str(v).replace("|", "\\|").replace("\n", " ")


def markdown(results: dict) -> str:
    env = results.get("env") or {}
    lines = ["# deeplens GPU check", "",
             f"device `{env.get('device')}` ({env.get('device_name')}), torch "
             f"{env.get('torch')}, CUDA {env.get('cuda')}; written "
             f"{time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}"
             + (" — **dry run** (CPU, tiny sizes: code paths, not speed)"
                if results.get("dry_run") else ""), ""]
    for name, s in results["sections"].items():
        head = f"## {name}: {s['status']}"
        if s.get("wall_s") is not None:
            head += f" ({s['wall_s']:.1f} s of {s['budget_s']:.0f} s)"
        lines += [head, ""]
        if s.get("error"):
            lines += [f"**error:** {_cell(s['error'])}", ""]
        rows = s.get("rows") or []
        if not rows:
            continue
        cols = [c for c in _FIRST if any(c in r for r in rows)]
        for r in rows:
            cols += [k for k in r if k not in cols and k not in _HIDDEN]
        lines.append("| " + " | ".join(cols) + " |")
        lines.append("|" + "---|" * len(cols))
        for r in rows:
            lines.append("| " + " | ".join(_cell(r.get(c)) for c in cols) + " |")
        lines.append("")
    lines += ["## all numbers (JSON)", "", "```json", json.dumps(results, indent=1, default=str),
              "```", ""]
    return "\n".join(lines)


def report(out: Path, dry_run: bool | None = None) -> Path:
    """Write ``<out>/gpu_check.md`` from the part files; returns its path."""
    results = collect(out)
    if dry_run is None:
        dry_run = any(s.get("dry_run") for s in results["sections"].values())
    results["dry_run"] = bool(dry_run)
    path = Path(out) / RESULTS
    tmp = path.with_suffix(".md.tmp")
    tmp.write_text(markdown(results))
    os.replace(tmp, path)
    return path


def read_results(path) -> dict:
    """The JSON block of a ``gpu_check.md``."""
    text = Path(path).read_text()
    m = re.search(r"```json\n(.*)\n```", text, re.S)
    if m is None:
        raise ValueError(f"{path}: no ```json block (not a gpu_check results file?)")
    return json.loads(m.group(1))


# ============================================================================ command line
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=os.environ.get("OUT"),
                    help="results folder (default $OUT)")
    ap.add_argument("--dry-run", action="store_true",
                    help="CPU, tiny sizes: every code path, in well under 2 minutes")
    ap.add_argument("--device", default="auto", help="auto (cuda if available), cuda, cpu")
    ap.add_argument("--section", choices=SECTIONS, default=None,
                    help="run this section only (default: all, then the report)")
    ap.add_argument("--budget", type=float, default=None,
                    help="seconds for --section (default: its entry in GPU_BUDGETS)")
    ap.add_argument("--report", action="store_true", help="only (re)write the results file")
    args = ap.parse_args(argv)
    if not args.out:
        ap.error("--out DIR (or $OUT) is required")
    out = Path(args.out)
    if args.report:
        print(report(out))
        return 0
    ctx = Context(out, args.device, args.dry_run)
    for name in ([args.section] if args.section else SECTIONS):
        sec = run_section(name, ctx, args.budget)
        print(f"[gpu_check] {name}: {sec.status} in {sec.elapsed():.1f} s"
              + (f": {sec.error}" if sec.error else ""), flush=True)
    if not args.section:
        print(report(out, args.dry_run))
    return 0


if __name__ == "__main__":
    sys.exit(main())
