#!/usr/bin/env python
"""Seconds per training step of the composed Hydra experiments, split into their parts.

Composes ``configs/train.yaml`` with ``experiment=...`` and the given overrides exactly as
``train.py`` does, builds the objects (:func:`deeplens.training.train.build_objects`) and times
what ``EndToEndModule.training_step`` does per batch, outside Lightning (no logging, no
validation):

* ``capture``: depths, the lens render of the batch (PSF convolution or Monte Carlo) and the
  sensor noise;
* ``deconv``: the depth-averaged Wiener filter (``model.deconvolution``), PSFs traced with
  gradients while the optics train;
* ``restorer``: the network's forward pass and the loss;
* ``backward``: ``loss.backward()`` (restorer, and through the render into the lens);
* ``step``: the sum, median over ``--steps`` steps after ``--warmup`` steps; ``CPU s`` the
  process's CPU time per step;
* ``data``: fetching the batch from the data loader (not in ``step``);
* within ``capture`` and ``deconv`` together (forward only; the backward is not split):
  ``rays`` (PSF ray tracing: the diffraction pupil trace and OPD fit, or the geometric PSF
  trace), ``prop`` (diffraction propagation, pupil to kernels), ``conv`` (the render's FFT
  convolution of the image with the kernels) and ``ideal`` (``IdealCamera.render``: the
  textures resampled onto the sensor grid, for the render and for the ground truth), timed by
  wrapping those functions from outside the package (exclusive times: a timed call inside
  another is not counted twice); the Monte Carlo render (``doublet``) is not split;
* ``RSS MiB``: the row process's resident-set high-water mark (``getrusage``) after the
  timed steps of that phase (the phases run in the table's order in one process, so the
  second phase's figure is at least the first's), and ``base MiB`` the mark before any step.

Logging is not timed (the steps run outside Lightning).

``--sizes 128,256`` adds, for every row, rows at ``N x N`` sensor pixels with the pitch scaled by
``shipped / N`` (the field of view kept) and textures of ``N x`` the shipped texture-to-sensor
ratio (``data.image_size``); ``shipped`` in the list keeps the row as given.

Rows are taken at a training step after ``model.optics_warmup_steps`` (the optics train) and,
where the experiment has a warm-up, at step 0 (the optics fixed).  Each row runs in its own
process, so threads and caches do not carry over.

Usage::

    python benchmarks/bench_train_step.py                         # experiment=edof, doublet
    python benchmarks/bench_train_step.py --rows "edof|render=balanced"
    python benchmarks/bench_train_step.py --base /tmp/before   # a checkout to compare
    OMP_NUM_THREADS=1 python benchmarks/bench_train_step.py --threads 1
    python benchmarks/bench_train_step.py --device cuda           # module and batches on a GPU
    OMP_NUM_THREADS=1 python benchmarks/bench_train_step.py --threads 1 --sizes shipped,128,256

On a CUDA device every part is timed between ``torch.cuda.synchronize`` calls, and each row
also records ``peak MiB``: ``torch.cuda.max_memory_allocated`` over the timed steps minus the
memory allocated before them.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import statistics
import subprocess
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_ROWS = ["edof", "edof|render=balanced", "edof|render=balanced|render.compile=true",
                "doublet"]


def size_overrides(code: str, experiment: str, overrides, n: int) -> list[str]:
    """Overrides for an ``n x n`` sensor with the field of view of ``experiment=...`` plus
    ``overrides`` (the pitch scaled by ``shipped / n``) and textures keeping the shipped
    texture-to-sensor ratio."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=os.path.join(code, "configs"), version_base="1.3"):
        cfg = compose(config_name="train.yaml",
                      overrides=[f"experiment={experiment}", "~logger", *overrides])
    h, w = (int(v) for v in cfg.sensor.resolution)
    if h != w:
        raise SystemExit(f"--sizes needs a square sensor, {experiment} has {h} x {w}")
    pitch = float(cfg.sensor.pixel_size_mm) * h / n
    image = int(round(int(cfg.data.image_size) * n / h))
    return [f"sensor.resolution=[{n},{n}]", f"sensor.pixel_size_mm={pitch:.6g}",
            f"data.image_size={image}"]


def build(code: str, experiment: str, overrides, output_dir: str) -> tuple:
    """``(cfg, objects)`` of ``experiment=...`` plus ``overrides`` composed as ``train.py`` does
    (no logger) from the checkout at ``code``; the datamodule set up for fitting."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    sys.path.insert(0, code)
    from deeplens.training.train import build_objects

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=os.path.join(code, "configs"), version_base="1.3"):
        cfg = compose(config_name="train.yaml", return_hydra_config=True,
                      overrides=[f"experiment={experiment}", "~logger", *overrides])
    HydraConfig().set_config(cfg)
    with open_dict(cfg):
        cfg.paths.output_dir = output_dir
        cfg.paths.root_dir = code
        cfg.paths.data_dir = os.path.join(code, "data")
    objs = build_objects(cfg)
    objs["datamodule"].setup("fit")
    return cfg, objs


class _Stages:
    """Exclusive wall time per stage of wrapped functions (see the module docstring)."""

    # (module, attribute, stage): replaced in the module whose globals the callers look up
    TARGETS = (("deeplens.render.diffraction", "_pupil_function", "rays"),
               ("deeplens.render.diffraction", "_kernels", "prop"),
               ("deeplens.render.psf_conv", "psf_grids", "rays"),
               ("deeplens.render.psf_conv", "correlate_valid", "conv"),
               ("deeplens.training.wiener", "psf_many", "rays"),
               ("deeplens.render.scene", "IdealCamera.render", "ideal"))

    def __init__(self, sync):
        self.sync, self.total, self.stack = sync, dict.fromkeys(("rays", "prop", "conv", "ideal"),
                                                             0.0), []
        self.wrapped = []
        for (mod, name, stage), (owner, attr, fn) in zip(self.TARGETS, self.originals()):
            if owner is None:
                continue  # older code: that stage reads 0
            setattr(owner, attr, self._wrap(fn, stage))
            self.wrapped.append(f"{mod}.{name}")

    @classmethod
    def originals(cls) -> list:
        """``(owner, attribute, function)`` per target as they are now (``owner`` None where
        the code lacks it)."""
        import importlib

        out = []
        for mod, name, _ in cls.TARGETS:
            try:
                owner = importlib.import_module(mod)
                *path, attr = name.split(".")
                for part in path:  # a method: replaced on its class
                    owner = getattr(owner, part)
                out.append((owner, attr, getattr(owner, attr)))
            except (ImportError, AttributeError):
                out.append((None, None, None))
        return out

    @staticmethod
    def restore(saved: list) -> None:
        for owner, attr, fn in saved:
            if owner is not None:
                setattr(owner, attr, fn)

    def _wrap(self, fn, stage):
        def timed(*a, **k):
            self.sync()
            self.stack.append(0.0)  # time spent in timed calls inside this one
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.sync()
                dt = time.perf_counter() - t0
                inner = self.stack.pop()
                self.total[stage] += dt - inner
                if self.stack:
                    self.stack[-1] += dt
        return timed

    def reset(self) -> dict:
        out, self.total = self.total, dict.fromkeys(self.total, 0.0)
        return out


def _child(spec: str, args) -> dict:
    """One row (``spec``) measured in this process; the wrapped functions are restored after
    (``gpu_check.py`` calls this in one process for several rows)."""
    code = args.code or REPO
    sys.path.insert(0, code)  # the stages' modules from the code measured
    import deeplens  # noqa: F401 - imported from ``code`` before the snapshot

    saved = _Stages.originals()
    try:
        return _row(spec, args)
    finally:
        _Stages.restore(saved)


def _row(spec: str, args) -> dict:
    import torch

    code = args.code or REPO
    torch.set_num_threads(args.threads)
    device = torch.device(getattr(args, "device", None) or "cpu")
    cuda = device.type == "cuda"

    def sync():
        if cuda:
            torch.cuda.synchronize(device)

    experiment, *overrides = spec.split("|")
    sizes = [o for o in overrides if o.startswith("@size=")]
    overrides = [o for o in overrides if not o.startswith("@size=")]
    for o in sizes:
        overrides += size_overrides(code, experiment, overrides, int(o.split("=")[1]))
    cfg, objs = build(code, experiment, overrides,
                      getattr(args, "output_dir", None) or "/tmp/bench_train_step")
    module, dm = objs["module"], objs["datamodule"]
    module.to(device)
    stages = _Stages(sync)
    batches = iter(dm.train_dataloader())
    first = int(getattr(module, "optics_warmup_steps", 0) or 0)
    import deeplens
    if not os.path.abspath(deeplens.__file__).startswith(os.path.abspath(code) + os.sep):
        raise SystemExit(f"imported {deeplens.__file__}, not the code under {code}")
    split = hasattr(module, "restore_loss")  # older code: the step timed as a whole
    fixed = getattr(module, "optics_fixed", lambda on: contextlib.nullcontext())
    out = {"code": code, "spec": spec, "threads": args.threads, "batch": int(cfg.data.batch_size),
           "image": int(cfg.data.image_size), "sensor": list(cfg.sensor.resolution),
           "pixel_size_mm": float(cfg.sensor.pixel_size_mm), "device": str(device),
           "dtype": str(module.lens.dtype).replace("torch.", ""), "wrapped": stages.wrapped,
           "base_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    for label, step0 in (("optics train", first + 10), ("optics fixed", 0)):
        if label == "optics fixed" and first == 0:
            continue
        parts = {k: [] for k in ("capture", "deconv", "restorer", "backward", "step", "cpu",
                                 "data", "rays", "prop", "conv", "ideal")}
        for i in range(args.warmup + args.steps):
            td = time.perf_counter()
            images = next(batches)["image"].to(device)
            sync()
            td = time.perf_counter() - td
            stages.reset()
            step = step0 + i
            if i == args.warmup and cuda:  # the peak over the timed steps only
                torch.cuda.reset_peak_memory_stats(device)
                base = torch.cuda.memory_allocated(device)
            sync()
            t0, c0 = time.perf_counter(), time.process_time()
            # step_loss's parts, timed one by one (the same calls in the same order)
            if split:
                depths = module.sample_depths(images.shape[0], step)
                with fixed(step < first):
                    y, gt = module.capture(images, depths, seed=module.seed * 1_000_003 + step)
                    sync()
                    t1 = time.perf_counter()
                    x = module.deconv(y) if module.deconv is not None else y
                    sync()
                    t2 = time.perf_counter()
                loss, *_ = module.restore_loss(depths, y, gt, x)
            else:
                loss, *_ = module.step_loss(images, step)
                t1 = t2 = t0
            sync()
            t3 = time.perf_counter()
            module.zero_grad(set_to_none=True)
            loss.backward()
            if step < first:
                for p in module.lens.parameters():
                    p.grad = None
            sync()
            t4 = time.perf_counter()
            if i >= args.warmup:
                st = stages.reset()
                for k, v in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0,
                                        time.process_time() - c0, td, st["rays"], st["prop"],
                                        st["conv"], st["ideal"])):
                    parts[k].append(v)
        out[label] = {k: statistics.median(v) for k, v in parts.items()}
        out[label]["loss"] = float(loss.detach())
        out[label]["rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        if cuda:
            out[label]["peak_mib"] = (torch.cuda.max_memory_allocated(device) - base) / 2 ** 20
        if not split:
            out[label].update(capture=None, deconv=None, restorer=None)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", nargs="*", default=DEFAULT_ROWS,
                    help='each "experiment|override|override..."')
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="cpu", help="cpu (default), cuda, cuda:1, ...")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--json", default=None)
    ap.add_argument("--sizes", default="shipped",
                    help="comma list of sensor sizes N (N x N px, field of view kept) and/or "
                         "'shipped' (the row as given)")
    ap.add_argument("--base", default=None,
                    help="also run every row on the code at this path (e.g. a git worktree)")
    ap.add_argument("--code", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(_child(args.one, args)))
        return
    results = []
    print(f"training step, {args.device}, {args.threads} threads, median of {args.steps} steps after "
          f"{args.warmup}; load average {os.getloadavg()[0]:.1f} at the start\n")
    print("| code | experiment and overrides | sensor px | optics | capture s | deconv s "
          "| restorer s | backward s | step s | CPU s | data s | rays s | prop s | conv s "
          "| ideal s | base MiB | RSS MiB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    codes = ([("before", args.base)] if args.base else []) + [("after", REPO)]
    sizes = [z.strip() for z in args.sizes.split(",") if z.strip()]
    rows = [r if z == "shipped" else f"{r}|@size={int(z)}" for r in args.rows for z in sizes]
    for spec, (name, code) in ((s, c) for s in rows for c in codes):
        cmd = [sys.executable, os.path.abspath(__file__), "--one", spec, "--threads",
               str(args.threads), "--steps", str(args.steps), "--warmup", str(args.warmup),
               "--code", code, "--device", args.device]
        env = dict(os.environ, OMP_NUM_THREADS=str(args.threads))
        r = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO, check=False)
        if r.returncode != 0:
            sys.stderr.write(r.stderr[-3000:])
            print(f"| {name} | `{spec.replace('|', ' ')}` | | failed (stderr above) "
                  "|||||||||||||||", flush=True)
            continue
        res = json.loads(r.stdout.strip().splitlines()[-1])
        results.append(res)
        for label in ("optics train", "optics fixed"):
            if label in res:
                p = res[label]
                f = {k: "" if v is None else f"{v:.3f}" for k, v in p.items()}
                px = "x".join(str(v) for v in res["sensor"])
                print(f"| {name} | `{spec.replace('|', ' ')}` | {px} | {label} | "
                      f"{f['capture']} | {f['deconv']} | {f['restorer']} | {f['backward']} | "
                      f"**{f['step']}** | {f['cpu']} | {f.get('data', '')} | "
                      f"{f.get('rays', '')} | {f.get('prop', '')} | {f.get('conv', '')} | "
                      f"{f.get('ideal', '')} | "
                      f"{res.get('base_mib', 0):.0f} | {p.get('rss_mib', 0):.0f} |", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
