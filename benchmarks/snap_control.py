"""Control for the glass substitution's negative losses (issue 36, item 4): give saved
model-glass designs the snap's stage schedule (``snap_count`` stages of ``snap_stage`` DLS
steps, model glasses free in the region) *without* the pull onto real glasses, and print the
RMS spot after each stage.  If the model design improves as much as the snapped real design,
the loss measured the budget; if not, the pull itself moved the design to a better minimum.

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/snap_control.py DIR cooke:0 cooke:1

``DIR`` holds ``<lens>_seed<k>.pt`` of ``benchmarks/design_search.py --save-models DIR``.
"""

from __future__ import annotations

import copy
import dataclasses
import sys
import time

import torch

from design_search import SPECS

from deeplens.design.search import SearchConfig
from deeplens.design.search.glass_region import GlassRegion
from deeplens.design.search.glass_stage import _score
from deeplens.design.search.multistart import _finish
from deeplens.design.search.refine import refine


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2:
        print(__doc__)
        return 2
    torch.set_num_threads(1)
    folder, cfg = argv[0], SearchConfig()
    for item in argv[1:]:
        name, seed = item.split(":")
        spec = dataclasses.replace(SPECS[name][0], glass_mode="model")
        region = GlassRegion(spec.catalogues, radius=cfg.glass_radius)
        saved = torch.load(f"{folder}/{name}_seed{seed}.pt", weights_only=False)[0]
        c0 = time.process_time()
        lens = copy.deepcopy(saved["lens"])
        hist = [_score(lens, spec, cfg.score_sampling)]
        for _ in range(cfg.snap_count):
            ok = refine(lens, spec, cfg.snap_stage, glass_region=region).ok
            hist.append(_score(lens, spec, cfg.score_sampling) if ok else float("nan"))
        fin = _finish(copy.deepcopy(lens), spec, "control", cfg)
        print(f"{name} seed {seed}: saved {saved['metrics']['rms_um']:.2f} um; "
              f"{cfg.snap_count} x {cfg.snap_stage[0].steps} steps without the pull "
              f"({cfg.score_sampling}): {', '.join(f'{h:.2f}' for h in hist)}; finished "
              f"{fin.metrics['rms_um']:.2f} um; {time.process_time() - c0:.0f} s CPU",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
