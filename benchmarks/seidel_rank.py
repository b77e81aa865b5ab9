"""How well the third-order merit ranks starts: Spearman rank correlation against the real RMS.

For a spec of ``benchmarks/design_search.py`` (``--lens cooke|double_gauss``):

* ``search starts``: ``--points`` Sobol points of the search's own start cube through
  :func:`deeplens.design.search.start.thin_lens_start` (thin-lens solve, thickening, EFL
  solve); for each thick start its third-order RMS (:func:`~deeplens.design.search.seidel.
  lens_system` + :func:`~deeplens.design.search.seidel.third_order_rms`) and its real
  polychromatic RMS spot (:func:`~deeplens.design.search.evaluate`, hexapolar:6 rays), both
  at the start's sensor (its paraxial image: ``refocus=False``); the third-order RMS at its
  best common focus (the screen's merit) is correlated too.
* ``screened``: the :func:`~deeplens.design.search.seidel.seidel_screen` of ``--screen``
  points keeps ``--points`` distinct thin systems; each thickened, the same numbers, plus the
  thin system's own third-order RMS (the number the screen ranks by).

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/seidel_rank.py --lens cooke --points 200
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import torch

sys.path.insert(0, "benchmarks")
from design_search import SPECS  # noqa: E402

from deeplens.design.search import evaluate  # noqa: E402
from deeplens.design.search.seidel import (_weights_with_primary, lens_system,  # noqa: E402
                                           seidel_screen, third_order_rms)
from deeplens.design.search.start import (StartError, start_dimensions,  # noqa: E402
                                          thick_lens, thin_lens_start)


def spearman(a, b) -> float:
    ra = torch.tensor(a, dtype=torch.float64).argsort().argsort().double()
    rb = torch.tensor(b, dtype=torch.float64).argsort().argsort().double()
    ra, rb = ra - ra.mean(), rb - rb.mean()
    return float((ra * rb).sum() / torch.sqrt((ra * ra).sum() * (rb * rb).sum()))


def third(lens, spec, refocus) -> float:
    ff = [x / spec.hfov_deg for x in spec.fields_deg]
    return float(third_order_rms(lens_system(lens, spec.wavelengths_nm), spec.epd,
                                 spec.hfov_deg, ff, spec.weights_of_fields,
                                 _weights_with_primary(spec), refocus=refocus))


def real(lens, spec) -> float:
    return evaluate(lens, spec, "hexapolar:6")["rms_um"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--lens", choices=sorted(SPECS), default="cooke")
    p.add_argument("--points", type=int, default=300)
    p.add_argument("--screen", type=int, default=2048)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    spec = SPECS[args.lens][0]
    out = {}
    # the search's own starts
    sob = torch.quasirandom.SobolEngine(start_dimensions(spec.elements), scramble=True,
                                        seed=args.seed)
    rows, tried, c0 = [], 0, time.process_time()
    while len(rows) < args.points and tried < 8 * args.points:
        u = sob.draw(1, dtype=torch.float64)[0]
        tried += 1
        try:
            lens = thin_lens_start(spec, u)
            rows.append((third(lens, spec, False), third(lens, spec, True), real(lens, spec)))
        except (StartError, ValueError):
            continue
    rows = [r for r in rows if all(math.isfinite(x) for x in r)]
    t3, t3f, re = zip(*rows)
    out["search_starts"] = {"n": len(rows), "tried": tried,
                            "spearman_thick3_vs_real": spearman(t3, re),
                            "spearman_thick3_refocused_vs_real": spearman(t3f, re),
                            "cpu_s": time.process_time() - c0,
                            "median_real_um": sorted(re)[len(re) // 2]}
    print("search starts:", out["search_starts"], flush=True)
    # the screened ones
    c0 = time.process_time()
    scr = seidel_screen(spec, args.screen, keep=args.points, seed=args.seed, steps=args.steps)
    rows2 = []
    for tl, r3 in zip(scr.starts, scr.rms_um):
        try:
            lens = thick_lens(tl, spec)
            rows2.append((r3, third(lens, spec, False), third(lens, spec, True), real(lens, spec)))
        except (StartError, ValueError):
            continue
    rows2 = [r for r in rows2 if all(math.isfinite(x) for x in r)]
    thin3, thick3, thick3f, re = zip(*rows2)
    out["screened"] = {"n": len(rows2), "kept": len(scr.starts), "screen_points": args.screen,
                       "steps": args.steps,
                       "spearman_thin3_vs_real": spearman(thin3, re),
                       "spearman_thick3_vs_real": spearman(thick3, re),
                       "spearman_thick3_refocused_vs_real": spearman(thick3f, re),
                       "cpu_s": time.process_time() - c0,
                       "median_real_um": sorted(re)[len(re) // 2]}
    print("screened:", out["screened"], flush=True)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
