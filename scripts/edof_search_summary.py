"""Summarise an ``experiment=edof_search`` evaluation folder: the plate search's result (the
plate's terms, split into the cubic family's coma and trefoil parts) and, per seed, the learned
run's (``seeds``) and the frozen searched plate's (``searched``) restored test PSNR per depth,
mean and worst depth, and the plate each tested.

    python scripts/edof_search_summary.py DIR OUT.json

``DIR`` is the evaluation's ``hydra.run.dir`` (``DIR/search``, ``DIR/learned/seed<s>``,
``DIR/searched/seed<s>``).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path


def cubic_parts(terms_um: dict) -> dict:
    """The plate's cubic terms ``a x^3 + b x^2 y + c x y^2 + d y^3`` (um of sag at the rim) as
    coma ``Cx x(x^2+y^2) + Cy y(x^2+y^2)`` plus trefoil ``T1 (x^3 - 3xy^2) + T2 (3x^2y - y^3)``
    (exact: four terms, four coefficients).  The Dowski-Cathey plate ``α (x^3 + y^3)`` is
    coma ``3α/4`` and trefoil ``α/4`` on each axis: coma-dominated, 3:1."""
    a, b = terms_um.get("x^3", 0.0), terms_um.get("x^2*y", 0.0)
    c, d = terms_um.get("x*y^2", 0.0), terms_um.get("y^3", 0.0)
    t1, t2 = (a - c) / 4, (b - d) / 4
    cx, cy = a - t1, d + t2
    return {"coma_x": cx, "coma_y": cy, "coma": math.hypot(cx, cy),
            "trefoil_1": t1, "trefoil_2": t2, "trefoil": math.hypot(t1, t2)}


def plate_terms(lens_json: Path, surface: int = 4) -> dict:
    """``{monomial: um of sag at the rim}`` of the XY-polynomial plate in a lens file."""
    from deeplens.design.plate_search import describe_plate
    from deeplens.optics.io import load_lens

    lens = load_lens(lens_json)
    return {m: c * 1e3 for m, c in describe_plate(lens.surfaces[surface])}


def main(folder: str, out: str) -> dict:
    d = Path(folder)
    res = json.loads((d / "search" / "result.json").read_text())
    rec = json.loads((d / "search" / "search_record.json").read_text())
    terms = {m: c * 1e3 for m, c in res["plate_terms_mm_at_rim"]}
    summary = {"search": {"score": rec["score"], "invariance": rec["invariance"],
                          "blur_px": rec["blur_px"], "seconds": rec["seconds"],
                          # the restoration merit's worst-depth expected PSNR (dB), else None
                          "psnr_db": rec.get("psnr_db"),
                          "config": res["config"], "best_origin": res["designs"][0]["origin"],
                          "kept_scores": [k["score"] for k in res["designs"]],
                          "start_scores": [r["start_score"] for r in res["runs"]],
                          "refined_scores": [r["score"] for r in res["runs"]],
                          "plate_um": terms, "cubic_parts_um": cubic_parts(terms)},
               "seeds": {}, "searched": {}}
    runs = [("seeds", r) for r in sorted((d / "learned").glob("seed*"))]
    runs += [("searched", r) for r in sorted((d / "searched").glob("seed*"))]
    for where, run in runs:
        rp = run / "eval_run.json"
        if not rp.is_file():
            continue
        m = json.loads(rp.read_text())["metrics"]
        pre = "test/psnr_restored/d"
        depths = sorted((k[len(pre):-2] for k in m if k.startswith(pre) and k.endswith("mm")),
                        key=float)
        per = {k: m[f"{pre}{k}mm"] for k in depths}
        entry = {"restored_psnr": per, "mean": sum(per.values()) / len(per),
                 "worst": min(per.values()),
                 "worst_depth": min(per, key=per.get)}
        lens = run / "checkpoints" / "best.lens.json"
        if lens.is_file():
            t = plate_terms(lens)
            entry["plate_um"] = t
            entry["cubic_parts_um"] = cubic_parts(t)
        summary[where][run.name] = entry
    Path(out).write_text(json.dumps(summary, indent=1))
    return summary


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], sys.argv[2]), indent=1))
