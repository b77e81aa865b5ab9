"""``evaluate(cfg)``: the phase-plate comparison table.

For each variant a restorer is trained for its lens with the experiment's settings and all
three are tested on the same fixed test set, per depth:

* ``none``: the lens with its phase plate flattened (all coefficients zero), optics frozen;
* ``cubic``: the analytic cubic plate of Dowski and Cathey, ``z = α ((x/R)^3 + (y/R)^3)``,
  optics frozen; ``eval.cubic_alpha_mm`` is one α or a list (a sweep: one variant, restorer and
  table column per α, named ``cubic@<α in µm>um``);
* ``learned``: the plate and the restorer trained jointly (or loaded from ``eval.learned_ckpt``).

The table has one row per variant and image (sensor, restored) and one column per test depth,
PSNR (dB) / SSIM.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf, open_dict

from .train import build_objects, train

__all__ = ["evaluate", "format_table", "variants"]


def _alphas(cfg: DictConfig) -> list[float]:
    a = cfg.eval.cubic_alpha_mm
    vals = list(a) if OmegaConf.is_list(a) or isinstance(a, (list, tuple)) else [a]
    try:
        vals = [float(v) for v in vals]
    except (TypeError, ValueError):
        raise ValueError(f"eval.cubic_alpha_mm: expected a number or a list of numbers (mm), got "
                         f"{a!r}") from None
    if not vals:
        raise ValueError("eval.cubic_alpha_mm: the list is empty")
    return vals


def variants(cfg: DictConfig) -> list[tuple[str, str, float | None]]:
    """``(name, kind, alpha_mm)`` of every variant to evaluate, in table order."""
    out = []
    for v in cfg.eval.variants:
        if v == "cubic":
            alphas = _alphas(cfg)
            if len(alphas) == 1:
                out.append(("cubic", "cubic", alphas[0]))
            else:
                out += [(f"cubic@{a * 1e3:g}um", "cubic", a) for a in alphas]
        elif v in ("none", "learned"):
            out.append((v, v, None))
        else:
            raise ValueError(f"eval.variants: unknown variant {v!r}; expected none, cubic, "
                             f"learned")
    return out


def _variant_cfg(cfg: DictConfig, name: str, kind: str | None = None,
                 alpha_mm: float | None = None) -> DictConfig:
    kind = kind or name
    c = copy.deepcopy(cfg)
    with open_dict(c):
        c.paths.output_dir = str(Path(cfg.paths.output_dir) / name.replace("@", "_"))
        c.test = True
        if kind == "none":
            c.lens.plate, c.lens.trainable = "none", []
        elif kind == "cubic":
            c.lens.plate, c.lens.trainable = "cubic", []
            c.lens.plate_alpha_mm = float(_alphas(cfg)[0] if alpha_mm is None else alpha_mm)
        elif kind == "learned":
            c.lens.plate = "learned"
        else:
            raise ValueError(f"eval.variants: unknown variant {kind!r}; expected none, cubic, "
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
    """Markdown table: a row per variant and image (sensor, restored), a column per depth and
    the mean, cells ``PSNR / SSIM``."""
    head = ("| variant | image | " + " | ".join(f"{d / 1000:g} m" for d in depths)
            + " | mean |")
    rows = [head, "|---|---|" + "---|" * (len(depths) + 1)]
    for v, m in results.items():
        for img in ("sensor", "restored"):
            cells = [f"{m[f'test/psnr_{img}/d{d:g}mm']:.2f} / "
                     f"{m[f'test/ssim_{img}/d{d:g}mm']:.3f}" for d in depths]
            ssim_mean = sum(m[f"test/ssim_{img}/d{d:g}mm"] for d in depths) / len(depths)
            cells.append(f"{m[f'test/psnr_{img}']:.2f} / {ssim_mean:.3f}")
            rows.append(f"| {v} | {img} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def evaluate(cfg: DictConfig) -> tuple[str, dict]:
    """Train/test each variant; write and return the markdown table and the raw metrics."""
    if cfg.lens.plate_surface is None:
        raise ValueError("eval: the experiment's lens has no phase plate (lens.plate_surface)")
    todo = variants(cfg)
    results = {}
    for name, kind, alpha in todo:
        vc = _variant_cfg(cfg, name, kind, alpha)
        ckpt = cfg.eval.learned_ckpt if kind == "learned" else None
        torch.manual_seed(cfg.seed)
        results[name] = _test_metrics(vc, ckpt)
    table = format_table(results, list(cfg.scene.val_depths_mm))
    out = Path(cfg.eval.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    alphas = ", ".join(f"{a * 1e3:g}" for a in _alphas(cfg))
    text = (f"# Phase-plate comparison ({cfg.task_name})\n\n"
            f"cubic plate alpha = {alphas} um (sag at the rim); test set of "
            f"{cfg.data.test_size} textures, PSNR (dB) / SSIM\n\n{table}\n")
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(out)
    return table, results
