#!/usr/bin/env python
"""Speed and accuracy of the renderers: rays per pixel, precision, Newton tolerance, PSF
convolution, and the named presets ``render=fast|balanced|accurate|psf``.

Two lenses, each with a fixed RGB dead-leaves texture (seeded, 2x the sensor resolution) filling
the field of view of one plane, and the sensor of its experiment config (64 x 64 pixels):

* ``edof``    the paper's EDOF set-up (data/lenses/edof_achromat.json, configs/sensor/edof.yaml,
  0.0195 mm pixels), plane at 6000 mm.  The phase plate (surface 4) is made non-zero first: a
  Dowski-Cathey cubic of 5 um rim sag plus 0.5 um of every other trainable term, so that every
  trainable coefficient ``surfaces.4.a.3 .. a.9`` has a generic gradient.
* ``doublet`` the wide-field doublet (data/lenses/wide_doublet.json, f = 10 mm, +-20 degrees,
  configs/sensor/doublet.yaml, 0.0804 mm pixels), plane at 10000 mm; trainable
  ``surfaces.1.a.0, surfaces.1.a.1, surfaces.3.a.0, surfaces.3.a.1, d_sensor``.

Renders use the training settings (configs/render/*.yaml): ``vignetting=false``, adjoint
gradients, 262144 rays per chunk.  The loss is non-constant: ``L = mean((I - T)^2)`` with ``T``
the ideal camera's sharp image (the ground truth of training).  Gradients are compared after
scaling each component to "per mm of sag at the rim" (:func:`parameter_scale`, the units the
optimiser's learning rates use), so that no coefficient dominates by its units.

Reference: float64, ``--ref-spp`` rays per pixel (default 1024) as two independent halves A, B
(different seeds).  Its own noise is estimated from the halves (``RMSE(A - B) / 2`` for the
image, ``|g_A - g_B| / |g_A + g_B|`` for the gradient) and printed as the "reference noise" row:
errors near it are not resolved.

Metrics (mean over ``--seeds`` independent seeds; time = median):

* image:    ``RMSE`` against the reference and ``PSNR = 10 log10(1 / MSE)`` (signal in [0, 1]);
* gradient: cosine similarity and relative norm error ``|g - g_ref| / |g_ref|``;
* time:     one render + ``loss.backward()`` (adjoint re-trace included) of one 64 x 64 RGB plane
  on this machine's CPU (``--threads``); the preset table also times a *training step's* render: a
  batch of 4 planes (EDOF at 4500, 5500, 6500, 8000 mm; doublet 4 x 10000 mm).

Sections:

1. rays per pixel (spp) 1 .. 256 in float32 (the training dtype, configs/lens/*.yaml);
2. float32 vs float64 at the same spp, also with *common random numbers* (the float32 render draws
   the same uniform samples as the float64 one) to isolate the precision error;
3. Newton tolerance and ``max_iter`` (float64 1e-3 .. 1e-10 mm, float32 1e-3 .. 1e-6 mm), again with
   common random numbers against float64 at its default tolerance: time, Newton iterations, rays
   lost, image and gradient differences;
4. PSF convolution (:class:`PSFConvRenderer`, 1x1, 3x3, 5x5 patches) against ray tracing, RMSE per
   radial field band (centre / mid / edge thirds of the half-diagonal, with their field angles);
5. the presets as configured in configs/render/{fast,balanced,accurate,psf}.yaml.

Usage (the machine is shared: hold the benchmark lock for the run)::

    flock /tmp/deeplens-bench.lock python benchmarks/bench_render_accuracy.py          # ~6 min
    flock /tmp/deeplens-bench.lock python benchmarks/bench_render_accuracy.py --quick  # < 1 min
    python benchmarks/bench_render_accuracy.py --lenses doublet --sections spp,psf --json out.json

One thread by default (``--threads 0``: torch's default): two intra-op threads on two busy cores
wait for each other at every operation's barrier and ran 4-5x *slower* than one thread here
(idle machine: 2 threads are 1.5x faster than 1).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import statistics
import sys
import time
import warnings

import torch

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from deeplens.data.textures import dead_leaves  # noqa: E402
from deeplens.optics.intersect import TraceOptions, default_tolerance  # noqa: E402
from deeplens.render import IdealCamera, MonteCarloRenderer, Scene, Sensor  # noqa: E402
from deeplens.render.psf_conv import PSFConvRenderer  # noqa: E402
from deeplens.training.lens_setup import (  # noqa: E402
    build_lens, cubic_phase_plate, parameter_scale)

F64 = torch.float64
CHUNK = 262144
PRESETS = ("fast", "balanced", "accurate", "psf")

LENSES = {
    "edof": dict(path="data/lenses/edof_achromat.json", pixel_mm=0.0195, depth_mm=6000.0,
                 train_depths=[4500.0, 5500.0, 6500.0, 8000.0],
                 trainable=[f"surfaces.4.a.{k}" for k in range(3, 10)]),
    "doublet": dict(path="data/lenses/wide_doublet.json", pixel_mm=0.0804, depth_mm=10000.0,
                    train_depths=[10000.0] * 4,
                    trainable=["surfaces.1.a.0", "surfaces.1.a.1", "surfaces.3.a.0",
                               "surfaces.3.a.1", "d_sensor"]),
}
RESOLUTION = (64, 64)
BANDS = ((0.0, 1 / 3), (1 / 3, 2 / 3), (2 / 3, 1.0 + 1e-9))


# ============================================================================ set-up
def make_lens(key: str, dtype: str):
    c = LENSES[key]
    lens = build_lens(os.path.join(REPO, c["path"]), trainable=c["trainable"], dtype="float64")
    if key == "edof":  # a small generic phase plate: cubic 5 um + 0.5 um of every other term
        cubic_phase_plate(lens, 4, 0.005)
        s = lens.surfaces[4]
        R = float(s.semi_diameter)
        with torch.no_grad():
            for k in range(3, 10):
                i, j = s.terms[k]
                if (i, j) not in ((3, 0), (0, 3)):
                    s.a[k].add_((0.0005 if k % 2 else -0.0005) / R ** (i + j))
    return lens.to(getattr(torch, dtype))


def make_sensor(key: str) -> Sensor:
    return Sensor(RESOLUTION, LENSES[key]["pixel_mm"])  # noise off: the renderer is measured


def make_textures(n: int, channels: int = 3, seed: int = 1234) -> torch.Tensor:
    """``(n, C, 2H, 2W)`` dead-leaves textures, fixed seeds."""
    H, W = RESOLUTION
    tex = torch.stack([dead_leaves((2 * H, 2 * W), seed + k) for k in range(n)])
    return tex if channels == 3 else tex.mean(1, keepdim=True)


def trainable(lens):
    return [(n, p) for n, p in lens.named_parameters() if p.requires_grad]


def grad_vector(lens) -> torch.Tensor:
    """Gradient per mm of rim sag (float64)."""
    return torch.stack([(p.grad if p.grad is not None else torch.zeros_like(p)).double()
                        * parameter_scale(lens, n) for n, p in trainable(lens)]).reshape(-1)


def mc(lens, sensor, spp, tol=None, max_iter=30):
    return MonteCarloRenderer(lens, sensor, spp=spp, vignetting=False, adjoint=True,
                              chunk_rays=CHUNK,
                              options=TraceOptions(tol=tol, max_iter=max_iter))


@contextlib.contextmanager
def common_random_numbers():
    """float32/16 renders draw float64 uniforms and round them: the same samples as float64."""
    orig = torch.rand

    def rand(*size, generator=None, dtype=None, device=None, **kw):
        if dtype in (torch.float32, torch.float16, torch.bfloat16):
            return orig(*size, generator=generator, dtype=F64, device=device, **kw).to(dtype)
        return orig(*size, generator=generator, dtype=dtype, device=device, **kw)

    torch.rand = rand
    try:
        yield
    finally:
        torch.rand = orig


class Probe:
    """Counts, inside the renderer's forward chunks only (not the pupil / image-circle probes,
    not the adjoint re-trace), the rays through ``lens.trace``, the valid ones, and the Newton
    residual evaluations per curved-surface intersection."""

    def __init__(self):
        self.rays = self.valid = self.newton = self.intersections = 0
        self.on = False

    def counting(self):
        return self.on

    @contextlib.contextmanager
    def attach(self, lens, renderer):
        import deeplens.optics.intersect as isect
        import deeplens.optics.lens as lens_mod

        orig_trace, orig_res, orig_isect = lens.trace, isect._residual, lens_mod.intersect
        orig_chunk = renderer.render_chunk
        probe = self

        def render_chunk(*a, **kw):
            probe.on = not torch.is_grad_enabled()  # the forward pass, not the adjoint re-trace
            try:
                return orig_chunk(*a, **kw)
            finally:
                probe.on = False

        def trace(rays, **kw):
            out = orig_trace(rays, **kw)
            if probe.counting():
                probe.rays += rays.o[..., 0].numel()
                probe.valid += int(out.valid.sum())
            return out

        def residual(surface, o, d, t):
            if probe.counting():
                probe.newton += 1
            return orig_res(surface, o, d, t)

        def intersect(surface, *a, **kw):
            if probe.counting() and not surface.is_flat:
                probe.intersections += 1
            return orig_isect(surface, *a, **kw)

        lens.trace = trace
        renderer.render_chunk = render_chunk
        isect._residual = residual
        lens_mod.intersect = intersect
        try:
            yield self
        finally:
            del lens.trace
            del renderer.render_chunk
            isect._residual = orig_res
            lens_mod.intersect = orig_isect


# ============================================================================ measuring
class Case:
    """One lens: lenses per dtype, sensor, scene(s), target and reference."""

    def __init__(self, key: str):
        self.key = key
        self.sensor = make_sensor(key)
        self.lenses = {d: make_lens(key, d) for d in ("float32", "float64")}
        self.tex = make_textures(1)
        self.depth = LENSES[key]["depth_mm"]
        cam = IdealCamera(self.lenses["float64"], self.sensor)
        self.camera = cam
        self.target = cam.render(Scene(self.tex.double(), self.depth), supersample=4)
        x, y = self.sensor.pixel_centers(F64)
        r = torch.sqrt(x * x + y * y) / self.sensor.half_diagonal_mm
        self.bands = [((r >= a) & (r < b)) for a, b in BANDS]
        self.band_deg = [(cam.field_angle_deg(a * self.sensor.half_diagonal_mm),
                          cam.field_angle_deg(min(b, 1.0) * self.sensor.half_diagonal_mm))
                         for a, b in BANDS]
        self.ref = self.ref_grad = None
        lens = self.lenses["float64"]
        self.scale = torch.tensor([parameter_scale(lens, n) for n, _ in trainable(lens)],
                                  dtype=F64)

    def scene(self, dtype):
        return Scene(self.tex.to(getattr(torch, dtype)), self.depth)

    def loss(self, img):
        return ((img.double() - self.target) ** 2).mean()

    def run(self, renderer, dtype, seed, scene=None):
        """One render + backward: ``(image float64, gradient vector, seconds)``."""
        lens = self.lenses[dtype]
        lens.zero_grad(set_to_none=True)
        scene = scene or self.scene(dtype)
        t0 = time.perf_counter()
        img = renderer(scene, seed=seed)
        self.loss(img).backward()
        dt = time.perf_counter() - t0
        return img.detach().double(), grad_vector(lens), dt

    def reference(self, spp: int):
        """Unbiased reference: image ``(A + B) / 2``; gradient ``(J_A^T c_B + J_B^T c_A) / 2``
        with ``c_X = dL/dI`` at image ``X`` (each half's Jacobian paired with the *other*
        half's residual, so the noise-variance term of the loss adds no bias)."""
        lens, dtype = self.lenses["float64"], "float64"
        r = mc(lens, self.sensor, max(1, spp // 2))
        params = [p for _, p in trainable(lens)]
        t0 = time.perf_counter()
        A = r(self.scene(dtype), seed=900_001)
        B = r(self.scene(dtype), seed=900_002)
        gA = self.vjp(A, params, self.cotangent(B))
        gB = self.vjp(B, params, self.cotangent(A))
        self.ref_time = time.perf_counter() - t0
        self.ref = ((A + B) / 2).detach()
        self.ref_grad = (gA + gB) / 2
        self.ref_noise = dict(rmse=float(((A - B).detach() ** 2).mean().sqrt()) / 2,
                              grad_rel=float((gA - gB).norm() / (gA + gB).norm()))
        self.ref_spp = 2 * max(1, spp // 2)

    def cotangent(self, img):
        """``dL/dI`` at ``img`` (float64, detached)."""
        I = img.detach().double().requires_grad_(True)
        (c,) = torch.autograd.grad(self.loss(I), I)
        return c

    def vjp(self, img, params, cot, retain=False):
        """``J^T cot`` scaled per mm of sag (float64 vector)."""
        gs = torch.autograd.grad(img, params, grad_outputs=cot.to(img.dtype), retain_graph=retain)
        return torch.stack([g.double().reshape(()) for g in gs]) * self.scale

    # ------------------------------------------------------------ metrics
    def image_err(self, img, ref=None, mask=None):
        ref = self.ref if ref is None else ref
        d2 = (img - ref) ** 2
        if mask is not None:
            d2 = d2[..., mask]
        return float(d2.mean())

    @staticmethod
    def grad_err(g, g_ref):
        cos = float(torch.dot(g, g_ref) / (g.norm() * g_ref.norm()).clamp_min(1e-300))
        rel = float((g - g_ref).norm() / g_ref.norm().clamp_min(1e-300))
        return cos, rel


def psnr(mse: float) -> float:
    return 10 * math.log10(1.0 / mse) if mse > 0 else float("inf")


def fmt_t(s: float) -> str:
    return f"{s:.3f}" if s < 10 else f"{s:.1f}"


def table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def warm_up(case: Case):
    for dtype in ("float32", "float64"):
        case.run(mc(case.lenses[dtype], case.sensor, 1), dtype, seed=7)


def sample(case, renderer_fn, dtype, seeds, crn=False, decorrelate=False):
    """Renders + gradients over ``seeds``: mean image error, mean gradient error of each seed's
    gradient (``cos``, ``rel``), error of the seeds' mean gradient (``rel_mean``: the bias plus
    noise / sqrt(n)), median time of render + backward; with ``decorrelate`` (>= 2 seeds) also the
    error of the decorrelated gradient ``J_k^T c(I_{k+1})`` (another seed's residual)."""
    lens = case.lenses[dtype]
    params = [p for _, p in trainable(lens)]
    scene = case.scene(dtype)
    mses, ts, imgs, grads, outs = [], [], [], [], []
    decorrelate = decorrelate and len(seeds) > 1
    ctx = common_random_numbers() if crn else contextlib.nullcontext()
    with ctx:
        for s in seeds:
            r = renderer_fn()
            t0 = time.perf_counter()
            img = r(scene, seed=s)
            gs = torch.autograd.grad(case.loss(img), params, retain_graph=decorrelate)
            ts.append(time.perf_counter() - t0)
            g = torch.stack([x.double().reshape(()) for x in gs]) * case.scale
            imgs.append(img.detach().double()), grads.append(g), outs.append(img)
            mses.append(case.image_err(imgs[-1]))
        dec = []
        if decorrelate:
            for k, img in enumerate(outs):
                dec.append(case.vjp(img, params, case.cotangent(imgs[(k + 1) % len(imgs)])))
    errs = [case.grad_err(g, case.ref_grad) for g in grads]
    m = dict(mse=statistics.mean(mses), rmse=statistics.mean(math.sqrt(x) for x in mses),
             cos=statistics.mean(e[0] for e in errs), rel=statistics.mean(e[1] for e in errs),
             rel_mean=case.grad_err(torch.stack(grads).mean(0), case.ref_grad)[1],
             time=statistics.median(ts), imgs=imgs, grads=grads)
    if dec:
        de = [case.grad_err(g, case.ref_grad) for g in dec]
        m.update(dec_cos=statistics.mean(e[0] for e in de),
                 dec_rel=statistics.mean(e[1] for e in de),
                 dec_rel_mean=case.grad_err(torch.stack(dec).mean(0), case.ref_grad)[1])
    return m


def fmt_opt(m, key, f="{:.3f}"):
    return f.format(m[key]) if key in m else "-"


# ============================================================================ sections
def section_spp(case, args, results):
    rows, res = [], []
    lens = case.lenses["float32"]
    for spp in args.spp_list:
        m = sample(case, lambda: mc(lens, case.sensor, spp), "float32", args.seed_list,
                   decorrelate=spp <= args.decorr_max_spp)
        rows.append([spp, fmt_t(m["time"]), f"{m['rmse']:.4f}", f"{psnr(m['mse']):.1f}",
                     f"{m['cos']:.4f}", f"{m['rel']:.3f}", f"{m['rel_mean']:.3f}",
                     fmt_opt(m, "dec_cos", "{:.4f}"), fmt_opt(m, "dec_rel"),
                     fmt_opt(m, "dec_rel_mean")])
        res.append(dict(spp=spp, time_s=m["time"], rmse=m["rmse"], psnr=psnr(m["mse"]),
                        grad_cos=m["cos"], grad_rel=m["rel"], grad_rel_of_mean=m["rel_mean"],
                        **{k: m[k] for k in ("dec_cos", "dec_rel", "dec_rel_mean") if k in m}))
    n = case.ref_noise
    rows.append([f"ref noise ({case.ref_spp}, f64)", fmt_t(case.ref_time), f"{n['rmse']:.4f}",
                 f"{psnr(n['rmse'] ** 2):.1f}", f"{1 - n['grad_rel'] ** 2 / 2:.5f}",
                 f"{n['grad_rel']:.4f}", "", "", "", ""])
    k = len(args.seed_list)
    print(f"\n### {case.key}: rays per pixel (float32, one {RESOLUTION[0]}x{RESOLUTION[1]} RGB "
          f"plane at {case.depth:g} mm, render + backward; mean of {k} seeds)\n")
    print(table(["spp", "time s", "RMSE", "PSNR dB", "grad cos", "grad rel err",
                 f"rel err of mean of {k}", "decorr. cos", "decorr. rel err",
                 f"decorr. rel err of mean of {k}"], rows))
    print("\n(grad: the loss gradient as training computes it, image and residual from the same "
          "samples; its error does not average out over steps: see 'rel err of mean'.  decorr.: "
          "the same Jacobian paired with the residual of an independent render, unbiased)")
    results["spp"] = res


def section_precision(case, args, results):
    rows, res = [], []
    for spp in args.prec_spp:
        per = {}
        for dtype in ("float32", "float64"):
            lens = case.lenses[dtype]
            per[dtype] = sample(case, lambda: mc(lens, case.sensor, spp), dtype,
                                args.seed_list[:2], crn=True)
        # precision-only differences (same samples)
        d_img = statistics.mean(math.sqrt(case.image_err(a, b)) for a, b in
                                zip(per["float32"]["imgs"], per["float64"]["imgs"]))
        d_g = statistics.mean(case.grad_err(a, b)[1] for a, b in
                              zip(per["float32"]["grads"], per["float64"]["grads"]))
        for dtype in ("float32", "float64"):
            m = per[dtype]
            own = dtype == "float64"
            rows.append([spp, dtype, fmt_t(m["time"]), f"{m['rmse']:.4f}", f"{psnr(m['mse']):.1f}",
                         f"{m['cos']:.4f}", f"{m['rel']:.3f}",
                         "0" if own else f"{d_img:.2e}", "0" if own else f"{d_g:.2e}"])
            res.append(dict(spp=spp, dtype=dtype, time_s=m["time"], rmse=m["rmse"],
                            grad_cos=m["cos"], grad_rel=m["rel"],
                            precision_rmse=0.0 if own else d_img,
                            precision_grad_rel=0.0 if own else d_g))
    print(f"\n### {case.key}: float32 vs float64 (mean of {min(2, len(args.seed_list))} seeds, "
          f"common random numbers; last two columns: float32 against float64 with the same "
          f"samples = the precision error alone)\n")
    print(table(["spp", "dtype", "time s", "RMSE", "PSNR dB", "grad cos", "grad rel err",
                 "RMSE vs f64", "grad rel vs f64"], rows))
    results["precision"] = res


def section_tolerance(case, args, results):
    spp = args.tol_spp
    configs = [("float64", None, 30), ("float64", 1e-7, 30), ("float64", 1e-5, 30),
               ("float64", 1e-3, 30), ("float64", None, 3), ("float32", None, 30),
               ("float32", 1e-6, 30), ("float32", 1e-4, 30), ("float32", 1e-3, 30),
               ("float32", None, 5), ("float32", None, 3), ("float32", None, 2)]
    if args.quick:
        configs = [configs[0], configs[3], configs[5], configs[6], configs[10]]
    base = None
    rows, res = [], []
    with common_random_numbers():
        for dtype, tol, it in configs:
            lens = case.lenses[dtype]
            r = mc(lens, case.sensor, spp, tol, it)
            ts, probe = [], Probe()
            for k in range(min(args.reps, 2)):
                if k == 0:
                    with probe.attach(lens, r):
                        img, g, dt = case.run(r, dtype, seed=4242)
                else:
                    img, g, dt = case.run(r, dtype, seed=4242)
                ts.append(dt)
            if base is None:
                base = (img, g)
            d_img = math.sqrt(case.image_err(img, base[0]))
            cos_b, rel_b = case.grad_err(g, base[1])
            mse = case.image_err(img)
            cos, rel = case.grad_err(g, case.ref_grad)
            lost = 1 - probe.valid / max(probe.rays, 1)
            its = probe.newton / max(probe.intersections, 1)
            eff = tol if tol is not None else default_tolerance(getattr(torch, dtype))
            rows.append([dtype, f"{eff:.0e}" + ("" if tol is not None else " (default)"), it,
                         fmt_t(statistics.median(ts)), f"{its:.1f}", f"{100 * lost:.2f}",
                         f"{d_img:.2e}", f"{rel_b:.2e}", f"{math.sqrt(mse):.4f}", f"{rel:.3f}"])
            res.append(dict(dtype=dtype, tol=eff, max_iter=it, time_s=statistics.median(ts),
                            newton_evals=its, rays_lost=lost, rmse_vs_base=d_img,
                            grad_rel_vs_base=rel_b, rmse=math.sqrt(mse), grad_rel=rel))
    print(f"\n### {case.key}: Newton tolerance and max_iter (spp {spp}, common random numbers; "
          f"'vs f64' = against float64 at tol 1e-10 with the same samples)\n")
    print(table(["dtype", "tol mm", "max_iter", "time s", "Newton evals / surface",
                 "rays lost %", "RMSE vs f64", "grad rel vs f64", "RMSE vs ref",
                 "grad rel err vs ref"], rows))
    print("\n(rays lost: rays entering the lens that do not come out valid, forward pass; "
          "Newton evals: residual evaluations per curved-surface intersection, including the "
          "final differentiable step; the loop runs until every ray of the chunk converged)")
    results["tolerance"] = res


def section_psf(case, args, results):
    lens = case.lenses["float32"]
    methods = [("ideal image (no blur)", None)]
    methods += [(f"PSF conv {p}x{p}", p) for p in args.patches]
    methods += [(f"MC spp {s} (float32)", -s) for s in args.psf_mc_spp]
    rows, res = [], []
    for name, p in methods:
        ts, cos, rel = [], float("nan"), float("nan")
        if p is None:
            t0 = time.perf_counter()
            img = case.camera.render(Scene(case.tex.double(), case.depth), supersample=4)
            ts.append(time.perf_counter() - t0)
        else:
            for k in range(args.reps):
                if p > 0:
                    r = PSFConvRenderer(lens, case.sensor, n_rays=args.psf_rays, patches=(p, p),
                                        options=TraceOptions())
                else:
                    r = mc(lens, case.sensor, -p)
                img, g, dt = case.run(r, "float32", seed=77 + k)
                ts.append(dt)
            cos, rel = case.grad_err(g, case.ref_grad)
        band = [math.sqrt(case.image_err(img, mask=m)) for m in case.bands]
        tot = math.sqrt(case.image_err(img))
        rows.append([name, fmt_t(statistics.median(ts))] + [f"{b:.4f}" for b in band]
                    + [f"{tot:.4f}", f"{psnr(tot ** 2):.1f}",
                       "-" if math.isnan(cos) else f"{cos:.4f}",
                       "-" if math.isnan(rel) else f"{rel:.3f}"])
        res.append(dict(method=name, time_s=statistics.median(ts), band_rmse=band, rmse=tot,
                        grad_cos=cos, grad_rel=rel))
    bd = [f"{a:.1f}-{b:.1f} deg" for a, b in case.band_deg]
    print(f"\n### {case.key}: PSF convolution vs ray tracing (float32, {args.psf_rays} rays per "
          f"PSF; RMSE against the ray-traced reference per radial field band)\n")
    print(table(["method", "time s", f"RMSE centre {bd[0]}", f"RMSE mid {bd[1]}",
                 f"RMSE edge {bd[2]}", "RMSE all", "PSNR dB", "grad cos", "grad rel err"], rows))
    results["psf"] = dict(bands_deg=case.band_deg, rows=res)


def load_preset(name: str) -> dict:
    """configs/render/<name>.yaml over the configs it lists under ``defaults`` (the base)."""
    import yaml

    with open(os.path.join(REPO, "configs", "render", f"{name}.yaml")) as fh:
        own = yaml.safe_load(fh)
    out = {}
    for parent in own.pop("defaults", []):
        if parent != "_self_":
            out.update(load_preset(parent))
    out.update(own)
    return out


def lens_dtype(key: str) -> str:
    import yaml

    with open(os.path.join(REPO, "configs", "lens", f"{key}.yaml")) as fh:
        return yaml.safe_load(fh).get("dtype", "float32")


def preset_renderer(cfg, lens, sensor):
    opts = TraceOptions(tol=cfg["newton_tol"], max_iter=cfg["max_iter"])
    if cfg["kind"] == "psf":
        return PSFConvRenderer(lens, sensor, n_rays=cfg["psf_rays"],
                               patches=tuple(cfg["psf_patches"]), options=opts)
    return MonteCarloRenderer(lens, sensor, spp=cfg["spp"], vignetting=cfg["vignetting"],
                              adjoint=cfg["adjoint"], chunk_rays=cfg["chunk_rays"], options=opts,
                              decorrelate=cfg.get("decorrelate", False) and cfg["adjoint"])


def section_presets(case, args, results):
    dtype = lens_dtype(case.key)
    lens = case.lenses[dtype]
    depths = LENSES[case.key]["train_depths"]
    batch = Scene(make_textures(len(depths), seed=555).to(getattr(torch, dtype)), depths)
    rows, res = [], []
    for name in args.preset_list:
        cfg = load_preset(name)
        if cfg["vignetting"]:
            case_note = " (vignetting on: not the reference's normalisation)"
        else:
            case_note = ""
        m = sample(case, lambda: preset_renderer(cfg, lens, case.sensor), dtype, args.seed_list,
                   decorrelate=True)
        ts = []
        for k in range(args.reps):
            r = preset_renderer(cfg, lens, case.sensor)
            lens.zero_grad(set_to_none=True)
            t0 = time.perf_counter()
            img = r(batch, seed=31 + k)
            (img ** 2).mean().backward()
            ts.append(time.perf_counter() - t0)
        what = (f"psf {cfg['psf_patches'][0]}x{cfg['psf_patches'][1]}, {cfg['psf_rays']} rays"
                if cfg["kind"] == "psf" else f"mc spp {cfg['spp']}")
        tol = cfg["newton_tol"] if cfg["newton_tol"] is not None else default_tolerance(
            getattr(torch, dtype))
        rows.append([name + case_note, what, dtype, f"{tol:.0e}", cfg["max_iter"],
                     fmt_t(statistics.median(ts)), fmt_t(m["time"]), f"{m['rmse']:.4f}",
                     f"{psnr(m['mse']):.1f}", f"{m['cos']:.4f}", f"{m['rel']:.3f}",
                     f"{m['rel_mean']:.3f}", fmt_opt(m, "dec_rel")])
        res.append(dict(preset=name, config=cfg, dtype=dtype, step_time_s=statistics.median(ts),
                        time_s=m["time"], rmse=m["rmse"], psnr=psnr(m["mse"]), grad_cos=m["cos"],
                        grad_rel=m["rel"], grad_rel_of_mean=m["rel_mean"],
                        dec_rel=m.get("dec_rel")))
    print(f"\n### {case.key}: presets (configs/render/*.yaml; lens dtype from "
          f"configs/lens/{case.key}.yaml; 'step s' = render + backward of a training batch of "
          f"{len(depths)} planes at {', '.join(f'{d:g}' for d in depths)} mm; errors as above)\n")
    print(table(["preset", "renderer", "dtype", "tol mm", "max_iter", "step s (B=4)",
                 "time s (B=1)", "RMSE", "PSNR dB", "grad cos", "grad rel err",
                 f"rel err of mean of {len(args.seed_list)}", "decorr. rel err"], rows))
    results["presets"] = res


SECTIONS = {"spp": section_spp, "precision": section_precision, "tolerance": section_tolerance,
            "psf": section_psf, "presets": section_presets}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smoke test, < 1 min")
    ap.add_argument("--lenses", default="edof,doublet")
    ap.add_argument("--sections", default=",".join(SECTIONS))
    ap.add_argument("--ref-spp", type=int, default=None, help="reference rays per pixel (1024)")
    ap.add_argument("--spp", default=None, help="comma list (1,2,4,...,256)")
    ap.add_argument("--seeds", type=int, default=None, help="independent seeds per point (3)")
    ap.add_argument("--reps", type=int, default=None, help="timing repeats (3)")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch CPU threads (default 1, see the docstring; 0: torch's default)")
    ap.add_argument("--json", default=None, help="write all numbers to this file")
    args = ap.parse_args(argv)
    sys.stdout.reconfigure(line_buffering=True)
    if args.threads:
        torch.set_num_threads(args.threads)
    q = args.quick
    args.ref_spp = args.ref_spp or (64 if q else 1024)
    args.spp_list = ([int(s) for s in args.spp.split(",")] if args.spp else
                     ([1, 4, 16] if q else [1, 2, 4, 8, 16, 32, 64, 128, 256]))
    args.seed_list = list(range(101, 101 + (args.seeds or (2 if q else 3))))
    args.reps = args.reps or (1 if q else 3)
    args.decorr_max_spp = 64  # the decorrelated gradient costs one more backward per seed
    args.prec_spp = [4] if q else [16, 64]
    args.tol_spp = 4 if q else 16
    args.patches = [1, 3] if q else [1, 3, 5]
    args.psf_rays = 1024 if q else 4096
    args.psf_mc_spp = [4] if q else [16, 64]
    args.preset_list = ["balanced"] if q else list(PRESETS)
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    for s in sections:
        if s not in SECTIONS:
            ap.error(f"unknown section {s!r}; choose from {', '.join(SECTIONS)}")
    warnings.filterwarnings("ignore", message=".*image circle.*")
    t_start = time.perf_counter()
    load0 = os.getloadavg()
    print(f"# bench_render_accuracy ({'quick' if q else 'default'}): torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads, load average {load0[0]:.2f}; reference float64 "
          f"spp {args.ref_spp}; seeds {len(args.seed_list)}, timing repeats {args.reps}")
    out = {"args": {k: v for k, v in vars(args).items()}, "lenses": {}}
    for key in [k.strip() for k in args.lenses.split(",") if k.strip()]:
        if key not in LENSES:
            ap.error(f"unknown lens {key!r}; choose from {', '.join(LENSES)}")
        case = Case(key)
        warm_up(case)
        case.reference(args.ref_spp)
        params = ", ".join(n for n, _ in trainable(case.lenses["float64"]))
        print(f"\n## {key}: depth {case.depth:g} mm, sensor {RESOLUTION[0]}x{RESOLUTION[1]} x "
              f"{case.sensor.pixel_size_mm} mm (half-diagonal {case.sensor.half_diagonal_mm:.3f} "
              f"mm = {case.camera.field_angle_deg(case.sensor.half_diagonal_mm):.2f} deg); "
              f"trainable: {params}; reference render+backward {case.ref_time:.1f} s; "
              f"reference |grad| {float(case.ref_grad.norm()):.3e} per mm of sag")
        res = {}
        for s in sections:
            SECTIONS[s](case, args, res)
        out["lenses"][key] = res
    wall = time.perf_counter() - t_start
    load1 = os.getloadavg()
    print(f"\n(wall time {wall:.0f} s; load average {load0[0]:.2f} at start, {load1[0]:.2f} at "
          f"end: other work on the machine inflates the times)")
    out["wall_s"] = wall
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
