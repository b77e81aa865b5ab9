"""Cost of the damped-least-squares Jacobian by mode on the Nikon application's merit, as a
markdown table (CPU seconds of this process, single-threaded).

The merit is ``deeplens design nikon``'s at its spherical start: 4 fields x 3 wavelengths,
hexapolar 4 rings (61 rays per block, 1465 residuals with the EFL target), 25 variables.  Each
Jacobian is compared with the forward-mode one (max relative difference).

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_design_jacobian.py
"""

from __future__ import annotations

import time

import torch

from deeplens.optics.paraxial import paraxial
from deeplens.design.apps import DATA_DIR
from deeplens.design.apps import nikon as N
from deeplens.design.lensopt import lens_residual_fn
from deeplens.design.merit import Merit, TargetMerit
from deeplens.design.optimizers import jacobian
from deeplens.design.variables import Variables
from deeplens.optics.io import load_lens


def main():
    lens = load_lens(DATA_DIR / "nikon_z35_f1.8_x10.json").to(torch.float64)
    with torch.no_grad():
        for i in N.ASPHERES:
            for a in lens.surfaces[i].a:
                a.zero_()
            lens.surfaces[i].k.zero_()
    v = Variables(lens, "surfaces.*.c," + ",".join(f"surfaces.{i}.a.*" for i in N.ASPHERES))
    merit = Merit(N._merit(N.FIELDS, "hexapolar:4"), TargetMerit("efl", float(paraxial(lens).efl)))
    merit.prepare(lens)
    fn = lens_residual_fn(v, merit)
    x = v.x0()
    t = time.process_time()
    with torch.no_grad():
        for _ in range(5):
            r = fn(x)
    t_eval = (time.process_time() - t) / 5
    rows, ref = [], None
    for mode in ("forward", "reverse", "central"):
        t = time.process_time()
        _, J = jacobian(fn, x, mode)
        dt = time.process_time() - t
        ref = J if ref is None else ref
        err = float((J - ref).abs().max() / ref.abs().max())
        rows.append((mode, dt, dt / t_eval, err))
    print(f"Nikon merit: m = {r.numel()} residuals, n = {len(v)} variables; one residual "
          f"evaluation (no graph) {t_eval * 1e3:.1f} ms CPU\n")
    print("| Jacobian mode | CPU s | in residual evaluations | max rel. diff. to forward |")
    print("|---|---|---|---|")
    for mode, dt, k, err in rows:
        print(f"| {mode} | {dt:.2f} | {k:.0f} | {err:.1e} |")


if __name__ == "__main__":
    main()
