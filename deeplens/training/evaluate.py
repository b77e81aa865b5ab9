"""``evaluate(cfg)``: the phase-plate comparison table.

For each variant a restorer is trained for its lens with the experiment's settings and all
three are tested on the same fixed test set, per depth:

* ``none``: the lens with its phase plate flattened (all coefficients zero), optics frozen;
* ``cubic``: the analytic cubic plate of Dowski and Cathey, ``z = α ((x/R)^3 + (y/R)^3)``,
  optics frozen;
* ``learned``: the plate and the restorer trained jointly (or loaded from ``eval.learned_ckpt``).
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch
from omegaconf import DictConfig, open_dict

from .train import build_objects, train

__all__ = ["evaluate", "format_table"]


def _variant_cfg(cfg: DictConfig, variant: str) -> DictConfig:
    c = copy.deepcopy(cfg)
    with open_dict(c):
        c.paths.output_dir = str(Path(cfg.paths.output_dir) / variant)
        c.test = True
        if variant == "none":
            c.lens.plate, c.lens.trainable = "none", []
        elif variant == "cubic":
            c.lens.plate, c.lens.trainable = "cubic", []
            c.lens.plate_alpha_mm = float(cfg.eval.cubic_alpha_mm)
        elif variant == "learned":
            c.lens.plate = "learned"
        else:
            raise ValueError(f"eval.variants: unknown variant {variant!r}; expected none, cubic, "
                             f"learned")
    return c


def _test_metrics(cfg: DictConfig, ckpt: str | None):
    if ckpt is None:
        metrics, _ = train(cfg)
        return metrics
    objs = build_objects(cfg)
    objs["trainer"].test(objs["module"], datamodule=objs["datamodule"], ckpt_path=ckpt,
                         verbose=False)
    return {k: float(v) for k, v in objs["trainer"].callback_metrics.items()}


def format_table(results: dict, depths) -> str:
    """Markdown table: one row per depth, PSNR/SSIM of sensor and restored image per variant."""
    variants = list(results)
    head = "| depth (m) | " + " | ".join(
        f"{v}: sensor PSNR / SSIM | {v}: restored PSNR / SSIM" for v in variants) + " |"
    sep = "|---|" + "---|---|" * len(variants)
    rows = [head, sep]
    for d in list(depths) + ["mean"]:
        cells = []
        for v in variants:
            m = results[v]
            if d == "mean":
                ps, pr = m["test/psnr_sensor"], m["test/psnr_restored"]
                ss = sum(m[f"test/ssim_sensor/d{x:g}mm"] for x in depths) / len(depths)
                sr = sum(m[f"test/ssim_restored/d{x:g}mm"] for x in depths) / len(depths)
            else:
                t = f"d{d:g}mm"
                ps, pr = m[f"test/psnr_sensor/{t}"], m[f"test/psnr_restored/{t}"]
                ss, sr = m[f"test/ssim_sensor/{t}"], m[f"test/ssim_restored/{t}"]
            cells += [f"{ps:.2f} / {ss:.3f}", f"{pr:.2f} / {sr:.3f}"]
        label = "mean" if d == "mean" else f"{d / 1000:g}"
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def evaluate(cfg: DictConfig) -> tuple[str, dict]:
    """Train/test each variant; write and return the markdown table and the raw metrics."""
    if cfg.lens.plate_surface is None:
        raise ValueError("eval: the experiment's lens has no phase plate (lens.plate_surface)")
    results = {}
    for v in cfg.eval.variants:
        vc = _variant_cfg(cfg, v)
        ckpt = cfg.eval.learned_ckpt if v == "learned" else None
        torch.manual_seed(cfg.seed)
        results[v] = _test_metrics(vc, ckpt)
    table = format_table(results, list(cfg.scene.val_depths_mm))
    out = Path(cfg.eval.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = (f"# Phase-plate comparison ({cfg.task_name})\n\n"
            f"cubic plate alpha = {cfg.eval.cubic_alpha_mm} mm; test set of "
            f"{cfg.data.test_size} textures, PSNR (dB) / SSIM\n\n{table}\n")
    out.write_text(text)
    return table, results
