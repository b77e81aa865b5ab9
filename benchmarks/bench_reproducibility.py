"""How far results move with the CPU's vector capability and the thread count (issue 25, item 15).

Runs one small EDOF training (seed 0) per (``ATEN_CPU_CAPABILITY``, ``OMP_NUM_THREADS``) pair,
each in a fresh process (the capability is read once, when torch starts), twice for the first
pair (same-machine determinism), and prints a table: restored test PSNR per depth, the largest
difference to the first pair, and whether the final weights are bitwise equal to it.

    OMP_NUM_THREADS=1 python benchmarks/bench_reproducibility.py
    python benchmarks/bench_reproducibility.py --capabilities default avx2 --threads 1 2

A capability above what the CPU has falls back (torch warns); the table prints the capability
each run reports.  Settings: ``--steps`` training steps (default 40), 32x32 sensor, 64 px
textures, 4 spp; small on purpose (the machine is shared), so the spread it shows is that of
a short run; it grows with the number of steps, as rounding differences are amplified.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(steps: int, out: str) -> None:
    import torch
    from hydra import compose, initialize_config_dir
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    from deeplens.training.machine import machine_info
    from deeplens.training.train import train

    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        cfg = compose(config_name="train.yaml", return_hydra_config=True, overrides=[
            "experiment=edof", "sensor.resolution=[32,32]", "data.image_size=64",
            "data.batch_size=2", f"data.train_steps_per_epoch={steps}", "data.val_size=2",
            "data.test_size=4", "render.spp=4", "trainer.max_epochs=1",
            "callbacks.image_logger=null", "~logger", "trainer.enable_progress_bar=false"])
    HydraConfig().set_config(cfg)
    with open_dict(cfg):
        cfg.paths.output_dir = out
        cfg.paths.root_dir = str(ROOT)
        cfg.paths.data_dir = str(ROOT / "data")
    metrics, objs = train(cfg)
    h = hashlib.sha256()
    for k, v in sorted(objs["module"].state_dict().items()):
        h.update(k.encode() + v.detach().cpu().contiguous().numpy().tobytes())
    print("RESULT " + json.dumps({
        "machine": machine_info(), "weights_sha256": h.hexdigest(),
        "psnr": {k.split("/")[-1]: v for k, v in metrics.items()
                 if k.startswith("test/psnr_restored/d")}}))
    del torch


def run(capability: str, threads: int, steps: int) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "PYTHONPATH": str(ROOT)}
    if capability != "unset":
        env["ATEN_CPU_CAPABILITY"] = capability
    else:
        env.pop("ATEN_CPU_CAPABILITY", None)
    with tempfile.TemporaryDirectory() as out:
        p = subprocess.run([sys.executable, __file__, "--child", out, "--steps", str(steps)],
                           env=env, capture_output=True, text=True, cwd=ROOT)
        if p.returncode:
            raise RuntimeError(p.stderr[-3000:])
        line = next(x for x in p.stdout.splitlines() if x.startswith("RESULT "))
        res = json.loads(line[len("RESULT "):])
        return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--capabilities", nargs="+", default=["default", "avx2", "avx512"])
    ap.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--child")
    a = ap.parse_args()
    if a.child:
        return child(a.steps, a.child)
    pairs = [(c, t) for c in a.capabilities for t in a.threads]
    rows = [(pairs[0], run(*pairs[0], a.steps))]
    rows.append(((pairs[0][0], pairs[0][1], "again"), run(*pairs[0], a.steps)))
    rows += [(p, run(*p, a.steps)) for p in pairs[1:]]
    ref = rows[0][1]
    depths = sorted(ref["psnr"], key=lambda t: float(t[1:-2]))
    print(f"{a.steps} training steps, seed 0, torch {ref['machine']['torch']}")
    print("| ATEN_CPU_CAPABILITY | threads | capability reported | " +
          " | ".join(f"{float(d[1:-2]) / 1000:g} m" for d in depths) +
          " | max abs diff to first (dB) | weights bitwise equal to first |")
    print("|---|---|---|" + "---|" * len(depths) + "---|---|")
    for key, r in rows:
        diff = max(abs(r["psnr"][d] - ref["psnr"][d]) for d in depths)
        label = key[0] + (" (again)" if len(key) == 3 else "")
        print(f"| {label} | {key[1]} | {r['machine']['cpu_capability']} | " +
              " | ".join(f"{r['psnr'][d]:.4f}" for d in depths) +
              f" | {diff:.4f} | {'yes' if r['weights_sha256'] == ref['weights_sha256'] else 'no'} |")


if __name__ == "__main__":
    main()
