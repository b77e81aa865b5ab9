"""Merit vs element count for the Cooke triplet's spec (issue 36, Build item 5): a search at 3
elements (the design_search.py budget: 3 thin-lens starts x 30 DLS steps, a 40-step polish, 2
hops x 20 steps), then thinning to 2 and splitting to 4 (deeplens.design.search.count), each
refined by 30 DLS steps; with --direct also a search from scratch at 2 and 4 elements with the
same budget.  A benchmark, not a test.

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/count_trade.py --seed 2 [--direct]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import time

from deeplens.design.search import SearchConfig, Stage, search
from deeplens.design.search.count import count_trade

from design_search import SPECS


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--seed", type=int, default=2)
    p.add_argument("--direct", action="store_true", help="also search 2 and 4 elements")
    p.add_argument("--out", default=None, help="write the table as JSON here")
    a = p.parse_args()
    spec = SPECS["cooke"][0]
    cfg = SearchConfig(starts=3, hops=2, seed=a.seed, polish_count=1, keep=1,
                       screen=(Stage(30, "hexapolar:6"),),
                       polish=(Stage(40, "hexapolar:6", rounds=2),),
                       hop=(Stage(20, "hexapolar:6"),))
    stages = (Stage(30, "hexapolar:6"),)
    c0, t0 = _cpu(), time.perf_counter()
    rows = [s.row() for s in count_trade(spec, [2, 3, 4], cfg, stages, progress=print)]
    out = {"trade": rows, "cpu_s": _cpu() - c0, "wall_s": time.perf_counter() - t0}
    if a.direct:
        out["direct"] = []
        for n in (2, 4):
            c1 = _cpu()
            sp = dataclasses.replace(spec, elements=n)
            r = search(sp, cfg)
            m = r.best.metrics
            out["direct"].append({"elements": n, "rms_um": m["rms_um"], "feasible": m["feasible"],
                                  "efl_mm": m["efl_mm"], "cpu_s": _cpu() - c1})
            print(out["direct"][-1])
    print(json.dumps(out, indent=1))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
