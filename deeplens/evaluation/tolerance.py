"""Evaluation under tolerances: ``eval.tolerance=<group> eval.tolerance_samples=N``.

Each variant (and seed) is tested on the lenses drawn by seeds ``eval.tolerance_seed + k``,
``k < N`` (the same lenses for every variant and run, :meth:`ToleranceModel.draw`); per depth /
field band the restored PSNR and SSIM distribution over the drawn lenses is summarised by its
mean, 5th percentile and yield, the fraction of drawn lenses whose PSNR is ``>=
eval.tolerance_yield_db`` (:func:`summarize_samples`), written into ``eval_table.md/json``, a
histogram figure (``tolerance_hist.png``) and TensorBoard (``tolerance/<variant>/...``).

``eval.calibrate: distortion`` (default ``null``: off) scores every drawn lens after a per-unit
distortion calibration (:mod:`deeplens.render.calibration`): the drawn lens's image mapping is
measured against the nominal lens's on a grid over the sensor at each test depth, and the
restored image is resampled with that map before its PSNR / SSIM, as a camera maker registers
every unit.  The nominal lens's own scores are unchanged (its map is zero).
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from ..design.plots import save
from ..design.tolerance_groups import load_group
from ..optics.tolerance_model import ToleranceModel, drawn
from ..optics.errors import ConfigError
from ..training.tolerance import DistortionCalibration, check_calibrate

__all__ = ["EvalTolerance", "check_tolerance_eval_config", "evaluate_drawn",
           "summarize_samples", "format_tolerance_table", "histogram_figure"]


def evaluate_drawn(module, trainer, datamodule, model: ToleranceModel, n: int, seed: int = 0,
                   calibrate: str | None = None):
    """Test ``module`` (its current weights) on ``n`` drawn lenses (seeds ``seed + k``);
    returns a list of ``n`` test-metric dicts (the keys of ``trainer.test``).  With
    ``calibrate="distortion"`` each drawn lens's restored images are registered with its
    measured distortion map before their metrics (:class:`DistortionCalibration`)."""
    if int(n) < 1:
        raise ConfigError("eval.tolerance_samples", "an integer >= 1", n)
    check_calibrate(calibrate, "eval.calibrate")
    cal = None
    if calibrate == "distortion":
        cal = DistortionCalibration(module, module.val_depths_mm)
        cal.measure_nominal()
    out = []
    try:
        for d in model.draws(module.lens, int(n), int(seed)):
            with drawn(module.camera, d):
                module.calibration = None if cal is None else cal.unit()
                trainer.test(module, datamodule=datamodule, verbose=False)
            module.calibration = None
            out.append({k: float(v) for k, v in trainer.callback_metrics.items()
                        if k.startswith("test/")})
    finally:
        module.calibration = None
    return out


def _percentile(x: list[float], q: float) -> float:
    return float(torch.quantile(torch.tensor(x, dtype=torch.float64), q / 100.0))


def summarize_samples(samples: list[dict], columns, threshold_db: float) -> dict:
    """Per column (``(label, metric suffix)`` of :func:`~.evaluate._columns`) and for
    ``"mean"`` (over depths): restored PSNR / SSIM ``mean``, ``p5`` (5th percentile), and
    ``yield`` = fraction of drawn lenses with PSNR ``>= threshold_db``; also the raw values."""
    out = {"n": len(samples), "threshold_db": float(threshold_db), "columns": {}}
    depth_sfx = [s for _, s in columns if not s.startswith("band")]
    rows = [(lab, sfx) for lab, sfx in columns] + [("mean", None)]
    for lab, sfx in rows:
        if sfx is None:
            ps = [sum(m[f"test/psnr_restored/{s}"] for s in depth_sfx) / len(depth_sfx)
                  for m in samples]
            ss = [sum(m[f"test/ssim_restored/{s}"] for s in depth_sfx) / len(depth_sfx)
                  for m in samples]
        else:
            ps = [m[f"test/psnr_restored/{sfx}"] for m in samples]
            ss = [m[f"test/ssim_restored/{sfx}"] for m in samples]
        out["columns"][lab] = {
            "psnr_mean": sum(ps) / len(ps), "psnr_p5": _percentile(ps, 5),
            "ssim_mean": sum(ss) / len(ss), "ssim_p5": _percentile(ss, 5),
            "yield": sum(p >= threshold_db for p in ps) / len(ps),
            "psnr": ps, "ssim": ss}
    return out


def format_tolerance_table(per_variant: dict, columns) -> str:
    """Markdown: a row per variant, a column per depth / band and the mean over depths; cells
    ``mean / p5 / yield`` of the restored PSNR (dB) over the drawn lenses."""
    labs = [lab for lab, _ in columns] + ["mean"]
    head = "| variant | " + " | ".join(
        lab if (lab == "mean" or lab.startswith("band")) else f"{float(lab) / 1000:g} m"
        for lab in labs) + " |"
    rows = [head, "|---|" + "---|" * len(labs)]
    for v, runs in per_variant.items():
        for k, s in enumerate(runs):
            name = v if len(runs) == 1 else f"{v} (seed {k})"
            cells = [f"{c['psnr_mean']:.2f} / {c['psnr_p5']:.2f} / {100 * c['yield']:.0f}%"
                     for c in (s["columns"][lab] for lab in labs)]
            rows.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def histogram_figure(per_variant: dict, threshold_db: float):
    """Histograms of the depth-mean restored PSNR over the drawn lenses, one colour per variant,
    with the threshold and each variant's 5th percentile marked; a matplotlib Figure."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=100)
    allv = [p for runs in per_variant.values() for s in runs for p in s["columns"]["mean"]["psnr"]]
    lo, hi = min(allv + [threshold_db]), max(allv + [threshold_db])
    bins = torch.linspace(lo - 0.05, hi + 0.05, 31).tolist()
    for i, (v, runs) in enumerate(per_variant.items()):
        vals = [p for s in runs for p in s["columns"]["mean"]["psnr"]]
        col = f"C{i}"
        ax.hist(vals, bins=bins, alpha=0.5, color=col, label=f"{v} (n={len(vals)})")
        ax.axvline(_percentile(vals, 5), color=col, ls="--", lw=1.2)
    ax.axvline(threshold_db, color="k", lw=1.5, label=f"yield threshold {threshold_db:g} dB")
    ax.set_xlabel("restored PSNR, mean over depths (dB)")
    ax.set_ylabel("drawn lenses")
    ax.set_title("under tolerances (dashed: 5th percentile)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def _settings(cfg) -> dict | None:
    """``eval.tolerance*`` checked (errors name the key), the group parsed: ``None`` when
    ``eval.tolerance`` is null, else ``{model, n, seed, threshold_db, group}``."""
    ev = cfg.eval
    spec = ev.get("tolerance", None)
    if spec is None:
        if check_calibrate(ev.get("calibrate", None), "eval.calibrate") is not None:
            raise ConfigError("eval.calibrate", "null without eval.tolerance (the calibration "
                              "registers drawn lenses; the nominal lens needs none)",
                              ev.get("calibrate"))
        return None
    n = ev.get("tolerance_samples", 16)
    thr = ev.get("tolerance_yield_db", 25.0)
    seed = ev.get("tolerance_seed", 0)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ConfigError("eval.tolerance_samples", "an integer >= 1", n)
    if isinstance(thr, bool) or not isinstance(thr, (int, float)) or not math.isfinite(thr):
        raise ConfigError("eval.tolerance_yield_db", "a number of dB", thr)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError("eval.tolerance_seed", "an integer >= 0", seed)
    calibrate = check_calibrate(ev.get("calibrate", None), "eval.calibrate")
    if spec == "group":  # the composed tolerance group (tolerance=<name>)
        model = load_group(cfg.tolerance, where="tolerance")
        group = str(cfg.tolerance.get("name", "group"))
    else:
        model = load_group(spec, where="eval.tolerance")
        group = str(spec)
    return {"model": model, "n": int(n), "seed": int(seed), "threshold_db": float(thr),
            "group": group, "calibrate": calibrate}


def check_tolerance_eval_config(cfg) -> None:
    """Start-up check of ``eval.tolerance``, ``eval.tolerance_samples``, ``eval.tolerance_seed``,
    ``eval.tolerance_yield_db`` and ``eval.calibrate`` (the group is parsed, nothing drawn); raises
    :class:`~deeplens.optics.errors.ConfigError` naming the key."""
    _settings(cfg)


class EvalTolerance:
    """The ``eval.tolerance*`` settings and the samples gathered per variant (a no-op when
    ``eval.tolerance`` is null)."""

    def __init__(self, model: ToleranceModel | None, n: int = 0, seed: int = 0,
                 threshold_db: float = 25.0, group: str = "", calibrate: str | None = None):
        self.model, self.n, self.seed, self.threshold_db = model, n, seed, threshold_db
        self.group, self.calibrate = group, calibrate
        self.samples: dict[str, list[list[dict]]] = {}
        self.summary: dict[str, list[dict]] = {}

    @classmethod
    def from_cfg(cls, cfg) -> "EvalTolerance":
        s = _settings(cfg)
        if s is None:
            return cls(None)
        return cls(s["model"], s["n"], s["seed"], s["threshold_db"], s["group"], s["calibrate"])

    def run(self, variant: str, objs: dict) -> None:
        """Test the variant's module (its tested weights) on the drawn lenses."""
        if self.model is None:
            return
        s = evaluate_drawn(objs["module"], objs["trainer"], objs["datamodule"], self.model,
                           self.n, self.seed, calibrate=self.calibrate)
        self.samples.setdefault(variant, []).append(s)

    def markdown(self, columns) -> str:
        if self.model is None:
            return ""
        self.summary = {v: [summarize_samples(s, columns, self.threshold_db) for s in runs]
                        for v, runs in self.samples.items()}
        cal = (f", each scored after its per-unit {self.calibrate} calibration"
               if self.calibrate else "")
        return (f"\n## Under tolerances: group {self.group}, {self.n} drawn lenses (seeds "
                f"{self.seed}..{self.seed + self.n - 1}){cal}\n\nrestored PSNR (dB) over the drawn "
                f"lenses: mean / 5th percentile / yield (PSNR >= {self.threshold_db:g} dB)\n\n"
                f"{format_tolerance_table(self.summary, columns)}\n")

    def json(self) -> dict:
        if self.model is None:
            return {}
        out = {"group": self.group, "samples": self.n, "seed": self.seed,
               "yield_threshold_db": self.threshold_db, "variants": self.summary}
        if self.calibrate is not None:
            out["calibrate"] = self.calibrate
        return {"tolerance": out}

    def figures(self, folder: Path, enabled: bool) -> list[str]:
        """``tolerance_hist.png`` and TensorBoard scalars/figure under ``folder/tensorboard``."""
        if self.model is None or not enabled or not self.summary:
            return []
        from torch.utils.tensorboard import SummaryWriter


        fig = histogram_figure(self.summary, self.threshold_db)
        writer = SummaryWriter(str(Path(folder) / "tensorboard"))
        try:
            writer.add_figure("eval/tolerance_hist", fig, close=False)
            for v, runs in self.summary.items():
                for k, s in enumerate(runs):
                    for lab, c in s["columns"].items():
                        for key in ("psnr_mean", "psnr_p5", "yield", "ssim_mean", "ssim_p5"):
                            writer.add_scalar(f"tolerance/{v}/{lab}/{key}", c[key], k)
        finally:
            writer.close()
        return [save(fig, Path(folder) / "tolerance_hist.png")]
