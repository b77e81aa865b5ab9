#!/usr/bin/env python
"""A run models only what its scene requires: the cost of a render falls with the scene.

Each scenario renders and back-propagates (adjoint) a 64 x 64 image with the training settings
of ``render=balanced`` (configs/render/balanced.yaml: spp, vignetting off, 262144 rays per chunk;
float32 lenses as configs/lens/*.yaml) and counts what is traced:

* ``lens rays``   rays traced through the lens by the render's forward pass (the adjoint backward
  re-traces the same rays once more); the set-up probes (image circle, pupil) are counted apart;
* ``plane hits``  rays intersected with a scene plane (``Lens.propagate_to_z``);
* ``time``        median wall time of render + backward (``--reps`` repeats after a warm-up).

Scenarios:

1. **channels**: a monochrome scene (1 wavelength, the sensor's ``mono_wavelength_nm``) vs an RGB
   scene (3 wavelengths) through the EDOF lens;
2. **depths**: one render of a batch of B = 4 planes (4500, 5500, 6500, 8000 mm; the lens is traced
   once per chunk and intersected with every plane) vs 4 separate renders of one plane each;
3. **image circle**: the wide doublet (image circle ~10 mm radius, ~45 degrees) with its own sensor
   (64 x 64 x 0.0804 mm, +-20 degrees, inside the circle), with a 64 x 64 x 0.5 mm sensor
   (half-diagonal 22.6 mm, larger than the circle: pixels outside are not traced) and the same
   large sensor with that culling switched off (every pixel traced; patched in this script only);
4. **PSF kernel**: PSF convolution (3 x 3 patches, 4096 rays per PSF) with the kernel sized from the
   measured spot (99.9 % of the rays) vs a fixed 65 and 129 pixel kernel, for the EDOF lens with a
   small cubic phase plate (5 um rim sag) and the doublet;
5. **geometry cache**: repeated renders (no gradient) through a frozen lens, as in the frozen-optics
   variants of ``eval.py`` and in validation, with the renderer's lens-geometry cache (exit pupil,
   image-circle probe, camera) against recomputing it on every call (the behaviour before it).

Usage (the machine is shared: hold the benchmark lock for the run)::

    flock /tmp/deeplens-bench.lock python benchmarks/bench_scene_cost.py          # ~2 min
    flock /tmp/deeplens-bench.lock python benchmarks/bench_scene_cost.py --quick  # < 1 min

One torch thread by default (``--threads 0``: torch's default), as bench_render_accuracy.py.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import sys
import time
import warnings

import torch

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from deeplens.data.textures import dead_leaves  # noqa: E402
from deeplens.optics.options import TraceOptions  # noqa: E402
from deeplens.render import IdealCamera, MonteCarloRenderer, Scene, Sensor  # noqa: E402
from deeplens.render.psf_conv import PSFConvRenderer  # noqa: E402
from deeplens.training.lens_setup import build_lens, cubic_phase_plate  # noqa: E402

EDOF = ("data/lenses/edof_achromat.json", [f"surfaces.4.a.{k}" for k in range(3, 10)], 0.0195)
DOUBLET = ("data/lenses/wide_doublet.json",
           ["surfaces.1.a.0", "surfaces.1.a.1", "surfaces.3.a.0", "surfaces.3.a.1"], 0.0804)


def load_yaml(*parts):
    import yaml

    with open(os.path.join(REPO, "configs", *parts)) as fh:
        return yaml.safe_load(fh)


def make_lens(spec, plate_alpha_mm=0.0):
    path, trainable, _ = spec
    dtype = load_yaml("lens", "edof.yaml" if "edof" in path else "doublet.yaml")["dtype"]
    lens = build_lens(os.path.join(REPO, path), trainable=trainable, dtype="float64")
    if plate_alpha_mm:
        cubic_phase_plate(lens, 4, plate_alpha_mm)
    return lens.to(getattr(torch, dtype))


def textures(n, channels=3, res=64, seed=2024):
    tex = torch.stack([dead_leaves((2 * res, 2 * res), seed + k) for k in range(n)])
    return tex if channels == 3 else tex.mean(1, keepdim=True)


class Counter:
    """Rays through ``lens.trace`` (render forward vs set-up) and scene-plane intersections."""

    def __init__(self):
        self.render = self.setup = self.plane = 0
        self.in_chunk = False

    @contextlib.contextmanager
    def attach(self, lens, renderer=None):
        orig_trace, orig_prop = lens.trace, lens.propagate_to_z
        orig_chunk = getattr(renderer, "render_chunk", None)
        c = self

        def trace(rays, **kw):
            n = rays.o[..., 0].numel()
            if c.in_chunk:
                c.render += n
            elif not torch.is_grad_enabled() or orig_chunk is None:
                c.setup += n
            return orig_trace(rays, **kw)

        def prop(rays, z, *a, **kw):
            if c.in_chunk:
                c.plane += rays.o[..., 0].numel()
            return orig_prop(rays, z, *a, **kw)

        def chunk(*a, **kw):
            c.in_chunk = not torch.is_grad_enabled()  # forward only, not the adjoint re-trace
            try:
                return orig_chunk(*a, **kw)
            finally:
                c.in_chunk = False

        lens.trace, lens.propagate_to_z = trace, prop
        if orig_chunk is not None:
            renderer.render_chunk = chunk
        try:
            yield self
        finally:
            del lens.trace, lens.propagate_to_z
            if orig_chunk is not None:
                del renderer.render_chunk


def timed(fn, reps):
    fn()  # warm-up
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def mc(lens, sensor, cfg):
    return MonteCarloRenderer(lens, sensor, spp=cfg["spp"], vignetting=cfg["vignetting"],
                              adjoint=cfg["adjoint"], chunk_rays=cfg["chunk_rays"],
                              options=TraceOptions(cfg["newton_tol"], cfg["max_iter"]))


def render_backward(lens, renderers_scenes):
    """Render every (renderer, scene) and back-propagate the summed loss."""
    lens.zero_grad(set_to_none=True)
    loss = 0.0
    for r, sc in renderers_scenes:
        loss = loss + (r(sc, seed=5) ** 2).mean()
    loss.backward()


def count(lens, renderers_scenes):
    """Rays traced by the forward renders (no gradient needed to count them)."""
    c = Counter()
    for r, sc in renderers_scenes:
        with c.attach(lens, r), torch.no_grad():
            r(sc, seed=5)
    return c


def row(scenario, case, c, t, extra=""):
    return [scenario, case, f"{c.render:,}", f"{c.plane:,}", f"{c.setup:,}", f"{t:.3f}", extra]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smoke test")
    ap.add_argument("--reps", type=int, default=None, help="timing repeats (3; quick 1)")
    ap.add_argument("--preset", default="balanced", help="configs/render/<preset>.yaml")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch CPU threads (default 1, see the docstring; 0: torch's default)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    sys.stdout.reconfigure(line_buffering=True)
    if args.threads:
        torch.set_num_threads(args.threads)
    reps = args.reps or (1 if args.quick else 3)
    cfg = {}
    for name in ("_base", args.preset):  # a preset lists only what differs from the base
        cfg.update({k: v for k, v in load_yaml("render", f"{name}.yaml").items()
                    if k != "defaults"})
    if args.quick:
        cfg = dict(cfg, spp=4)
    warnings.filterwarnings("ignore", message=".*image circle.*")
    t_start, load0 = time.perf_counter(), os.getloadavg()
    print(f"# bench_scene_cost ({'quick' if args.quick else 'default'}): torch "
          f"{torch.__version__}, {torch.get_num_threads()} threads, load average {load0[0]:.2f}; "
          f"render={args.preset}: spp {cfg['spp']}, vignetting {cfg['vignetting']}, chunk "
          f"{cfg['chunk_rays']} rays; timing = median of {reps} (render + backward)\n")
    rows, out = [], []

    def add(scenario, case, c, t, extra=""):
        rows.append(row(scenario, case, c, t, extra))
        out.append(dict(scenario=scenario, case=case, render_rays=c.render, plane_hits=c.plane,
                        setup_rays=c.setup, time_s=t, note=extra))

    # 1. channels --------------------------------------------------------------------------
    lens = make_lens(EDOF, 0.005)
    sensor = Sensor((64, 64), EDOF[2])
    for name, ch in (("monochrome (1 wavelength)", 1), ("RGB (3 wavelengths)", 3)):
        r = mc(lens, sensor, cfg)
        sc = Scene(textures(1, ch).to(lens.distances[0].dtype), 6000.0)
        c = count(lens, [(r, sc)])
        t = timed(lambda: render_backward(lens, [(r, sc)]), reps)
        add("1 channels (EDOF, 6000 mm)", name, c, t)

    # 2. depths ------------------------------------------------------------------------------
    depths = [4500.0, 5500.0, 6500.0, 8000.0]
    tex = textures(len(depths)).to(lens.distances[0].dtype)
    r = mc(lens, sensor, cfg)
    batch = [(r, Scene(tex, depths))]
    c = count(lens, batch)
    t = timed(lambda: render_backward(lens, batch), reps)
    add("2 depths (EDOF, RGB)", "B = 4 planes in one render", c, t)
    single = [(r, Scene(tex[b:b + 1], depths[b])) for b in range(len(depths))]
    c = count(lens, single)
    t = timed(lambda: render_backward(lens, single), reps)
    add("2 depths (EDOF, RGB)", "4 renders of 1 plane", c, t)
    c = count(lens, single[:1])
    t = timed(lambda: render_backward(lens, single[:1]), reps)
    add("2 depths (EDOF, RGB)", "1 render of 1 plane", c, t, "(for scale)")

    # 3. image circle --------------------------------------------------------------------------
    dl = make_lens(DOUBLET)
    tex1 = textures(1).to(dl.distances[0].dtype)
    for name, pix, cull in (("sensor inside the circle: 64x64 x 0.0804 mm (+-20 deg)", 0.0804,
                             True),
                            ("sensor larger: 64x64 x 0.5 mm (+-66 deg), culled", 0.5, True),
                            ("same large sensor, culling off (all pixels)", 0.5, False)):
        s = Sensor((64, 64), pix)
        r = mc(dl, s, cfg)
        if not cull:
            H, W = s.resolution
            r.active_pixels = lambda jobs, pupil=None, n=H * W: torch.arange(n)
        sc = Scene(tex1, 10000.0)
        c = count(dl, [(r, sc)])
        t = timed(lambda: render_backward(dl, [(r, sc)]), reps)
        pix_traced = c.render // (cfg["spp"] * 3)
        note = f"{pix_traced} of {64 * 64} pixels traced"
        if cull:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r.active_pixels(s.wavelengths_for(3))
            cam = IdealCamera(dl, s)
            note += (f"; image circle {r.image_circle_mm:.2f} mm "
                     f"({cam.field_angle_deg(r.image_circle_mm):.1f} deg), half-diagonal "
                     f"{s.half_diagonal_mm:.2f} mm")
        add("3 image circle (doublet, RGB, 10 m)", name, c, t, note)

    # 4. PSF kernel --------------------------------------------------------------------------
    n_rays = 1024 if args.quick else cfg.get("psf_rays", 4096)
    for lname, L, s, depth in (("EDOF + cubic plate", lens, sensor, 6000.0),
                               ("doublet", dl, Sensor((64, 64), DOUBLET[2]), 10000.0)):
        sc = Scene(textures(1).to(L.distances[0].dtype), depth)
        for K in (None, 65, 129):
            r = PSFConvRenderer(L, s, n_rays=n_rays, patches=(3, 3), kernel_size=K)
            c = Counter()
            with c.attach(L):
                with torch.no_grad():
                    r(sc)
            c.render, c.setup = c.setup, 0  # PSF conv: every trace is the render's own
            if K is None:  # the measured size (psf_grid's sizing probes: 1024 rays per patch)
                from deeplens.render.psf import psf_grid

                with torch.no_grad():
                    k, _ = psf_grid(L, s, depth, s.mono_wavelength_nm, (3, 3), n_rays)
                size = f"measured K = {k.shape[-1]} (green)"
            else:
                size = f"fixed K = {K}"
            t = timed(lambda: render_backward(L, [(r, sc)]), reps)
            add(f"4 PSF kernel ({lname}, 3x3 patches, {n_rays} rays)", size, c, t)

    # 5. lens geometry cache -------------------------------------------------------------------
    frozen = make_lens(EDOF, 0.005)
    for p in frozen.parameters():
        p.requires_grad_(False)
    r = mc(frozen, sensor, cfg)
    batch = Scene(tex, depths)

    def render_only(fresh):
        if fresh:
            r._geometry_cache = None
        with torch.no_grad():
            r(batch, seed=5)

    for name, fresh in (("geometry cached (default)", False), ("geometry recomputed per call",
                                                                True)):
        render_only(True)  # the first call always traces the probe
        c = Counter()
        with c.attach(frozen, r):
            render_only(fresh)  # what a second call traces
        t = timed(lambda: render_only(fresh), reps)
        add("5 frozen lens, repeated renders (EDOF, B = 4, RGB, no gradient)", name, c, t,
            "rays of every call after the first")

    print("| scenario | case | lens rays (render) | plane hits | set-up rays | time s | note |")
    print("|---|---|---|---|---|---|---|")
    for rw in rows:
        print("| " + " | ".join(str(x) for x in rw) + " |")
    wall = time.perf_counter() - t_start
    load1 = os.getloadavg()
    print(f"\n(lens rays: forward pass; the adjoint backward traces them once more.  PSF rows: all "
          f"rays traced, kernel sizing included.  Wall time {wall:.0f} s; load average "
          f"{load0[0]:.2f} at start, {load1[0]:.2f} at end)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(dict(rows=out, wall_s=wall, preset=args.preset, config=cfg), fh, indent=1)


if __name__ == "__main__":
    main()
