"""Gather the tolerance experiment (docs/guide/tolerance.md): nominal vs tolerance-aware training of
the doublet, each checkpoint tested on the nominal lens and on N lenses drawn from a group.

Runs (one process per training kind and seed; OMP_NUM_THREADS=1):

    python eval.py experiment=doublet eval.variants=[learned] eval.seeds=[S] \
        eval.tolerance=commercial eval.tolerance_samples=64 eval.tolerance_yield_db=24 \
        trainer.max_epochs=4 [tolerance=commercial model.tolerance_training=true] \
        hydra.run.dir=outputs/tolerance_exp/{nominal|aware}/seedS

Then ``python benchmarks/tolerance_experiment.py outputs/tolerance_exp [THRESHOLD_DB]
[--table calibrated/eval_table.json]`` prints the table (the yield recomputed from the per-lens
values when a threshold is given; ``--table``: each seed folder's table at that relative path,
e.g. the re-evaluation with ``eval.calibrate=distortion eval.output=<seed
folder>/calibrated/eval_table.md``)
(restored PSNR in dB, test set mean over its images; "p5" the 5th percentile over the drawn
lenses; yield: fraction of drawn lenses at or above the threshold).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def load(root: Path, rel: str = "eval_table.json") -> dict:
    out = {}
    for kind in ("nominal", "aware"):
        for f in sorted((root / kind).glob(f"seed*/{rel}")):
            js = json.loads(f.read_text())
            seed = js["seeds"][0]
            # the folder's one trained variant (learned, or refined: from the classical design)
            name = "learned" if "learned" in js["variants"] else next(iter(js["variants"]))
            v = js["variants"][name]
            tol = js["tolerance"]
            c = tol["variants"][name][0]["columns"]
            out.setdefault(kind, {})[seed] = {
                "nominal_psnr": v["mean"]["psnr"], "nominal_ssim": v["mean"]["ssim"],
                "columns": c, "n": tol["samples"], "group": tol["group"],
                "threshold": tol["yield_threshold_db"],
                "calibrate": tol.get("calibrate")}
    return out


def table(res: dict, threshold: float | None = None) -> str:
    """``threshold``: recompute the yield from the per-lens values at this PSNR (dB)."""
    bands = None
    rows = ["| training | seed | nominal lens PSNR / SSIM | drawn: mean | drawn: p5 | drawn: yield "
            "| p5 edge band (0.66-1) | p5 centre band (0-0.33) | headroom: nominal lens - p5 |",
            "|---|---|---|---|---|---|---|---|---|"]
    for kind, seeds in res.items():
        for s, r in sorted(seeds.items()):
            c = r["columns"]
            bands = [k for k in c if k.startswith("band")]
            edge = c.get("band 0.66-1", {}).get("psnr_p5", float("nan"))
            centre = c.get("band 0-0.33", {}).get("psnr_p5", float("nan"))
            m = dict(c["mean"])
            if threshold is not None:
                m["yield"] = sum(p >= threshold for p in m["psnr"]) / len(m["psnr"])
            rows.append(f"| {kind} | {s} | {r['nominal_psnr']:.2f} / {r['nominal_ssim']:.3f} | "
                        f"{m['psnr_mean']:.2f} | {m['psnr_p5']:.2f} | {100 * m['yield']:.0f}% | "
                        f"{edge:.2f} | {centre:.2f} | {r['nominal_psnr'] - m['psnr_p5']:.2f} |")
    for kind, seeds in res.items():  # mean +- std (n - 1) over the seeds of each kind
        if len(seeds) < 2:
            continue
        cols = [("nominal", lambda r: r["nominal_psnr"]),
                ("mean", lambda r: r["columns"]["mean"]["psnr_mean"]),
                ("p5", lambda r: r["columns"]["mean"]["psnr_p5"]),
                ("edge p5", lambda r: r["columns"].get("band 0.66-1", {}).get("psnr_p5",
                                                                               float("nan"))),
                ("centre p5", lambda r: r["columns"].get("band 0-0.33", {}).get("psnr_p5",
                                                                                 float("nan"))),
                ("headroom", lambda r: r["nominal_psnr"] - r["columns"]["mean"]["psnr_p5"])]
        cells = {}
        for name, f in cols:
            v = [f(r) for r in seeds.values()]
            m = sum(v) / len(v)
            sd = (sum((x - m) ** 2 for x in v) / (len(v) - 1)) ** 0.5
            cells[name] = f"{m:.2f} ± {sd:.2f}"
        rows.append(f"| {kind} | mean ± std ({len(seeds)} seeds) | {cells['nominal']} | "
                    f"{cells['mean']} | {cells['p5']} | | {cells['edge p5']} | "
                    f"{cells['centre p5']} | {cells['headroom']} |")
    common = sorted(set(res.get("nominal", {})) & set(res.get("aware", {})))
    if common:
        def mean(kind, f):
            return sum(f(res[kind][s]) for s in common) / len(common)

        dp5 = mean("aware", lambda r: r["columns"]["mean"]["psnr_p5"]) - mean(
            "nominal", lambda r: r["columns"]["mean"]["psnr_p5"])
        dnom = mean("aware", lambda r: r["nominal_psnr"]) - mean("nominal",
                                                                  lambda r: r["nominal_psnr"])
        any_r = res["nominal"][common[0]]
        rows.append("")
        thr = any_r["threshold"] if threshold is None else threshold
        cal = (f", scored after per-unit {any_r['calibrate']} calibration"
               if any_r.get("calibrate") else "")
        rows.append(f"seeds {common}, group {any_r['group']}{cal}, {any_r['n']} drawn lenses per "
                    f"checkpoint, yield threshold {thr:g} dB: tolerance-aware - "
                    f"nominal training: 5th-percentile PSNR {dp5:+.2f} dB, nominal-lens PSNR "
                    f"{dnom:+.2f} dB")
    del bands
    return "\n".join(rows)


if __name__ == "__main__":
    args = sys.argv[1:]
    rel = "eval_table.json"
    if "--table" in args:
        k = args.index("--table")
        rel = args[k + 1]
        del args[k:k + 2]
    root = Path(args[0] if args else "outputs/tolerance_exp")
    print(table(load(root, rel), float(args[1]) if len(args) > 1 else None))
