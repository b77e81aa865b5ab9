"""The analysis suite against optiland: the largest differences, as a markdown table.

Uses the oracle models of ``tests/analysis/test_analysis_oracle.py`` (optiland is a test-only
dependency); see that file for the conventions.

    PYTHONPATH=. python benchmarks/bench_analysis_oracle.py
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "tests" / "analysis")]

import test_analysis_oracle as T  # noqa: E402
from optiland.analysis.distortion_strategies import create_distortion_model  # noqa: E402
from optiland.mtf import FFTMTF  # noqa: E402

from deeplens.analysis.aberrations import distortion  # noqa: E402
from deeplens.analysis.diffraction import mtf  # noqa: E402
from deeplens.analysis.wavefront import wavefront  # noqa: E402
from deeplens.optics.io import lens_from_dict  # noqa: E402


def main():
    print("| lens | fields (°) | distortion at the largest field (real chief ray) | "
          "max \\|Δ distortion\\| (%) | max \\|Δ OPD\\| per ray (waves) | max \\|Δ RMS\\| (waves) | "
          "largest RMS (waves) | max \\|Δ MTF\\| |")
    print("|---|---|---|---|---|---|---|---|")
    for name, spec in T.LENSES.items():
        lens = lens_from_dict(spec).to(torch.float64)
        op = T._quiet(T.build_optiland, spec)
        fields = [f for f in spec["fields_deg"] if f > 0]
        fmax = max(spec["fields_deg"])
        ddist, last = 0.0, None
        for aim in ("paraxial", "real"):
            ours = distortion(lens, fields, T.WL, image_plane="paraxial", aim=aim).numpy()
            if aim == "real":
                op.ray_tracer.set_aiming("iterative", max_iter=50, tol=1e-13)
            m = create_distortion_model("paraxial")
            r = T._quiet(m.compute, op, np.zeros(len(fields)), np.array(fields) / fmax,
                         T.WL / 1e3)
            ref = np.asarray(m.percent(r, signed=True), float)
            op.ray_tracer.set_aiming("paraxial")
            ddist = max(ddist, float(np.abs(ours - ref).max()))
            last = float(ours[-1])
        dopd = drms = dm = rmsmax = 0.0
        for f in spec["fields_deg"]:
            n = T.N_PUPILS[name]
            w = wavefront(lens, f, T.WL, n=n, image_plane="paraxial")
            ref, ok, _ = T._optiland_opd(op, f / fmax, n)
            inside = (w.pupil ** 2).sum(-1) <= 1 + 1e-12
            o, mk = w.opd[inside].numpy(), w.mask[inside].numpy()
            dopd = max(dopd, float(np.abs(o[mk] - ref[ok]).max()))
            r = ref[ok]
            drms = max(drms, abs(float(w.rms) - math.sqrt(((r - r.mean()) ** 2).mean())))
            rmsmax = max(rmsmax, float(w.rms))
            mm = mtf(lens, f, T.WL, n=n, image_plane="paraxial")
            oo = T._quiet(FFTMTF, op, fields=[(0.0, f / fmax)], wavelength=T.WL / 1e3,
                          num_rays=n, grid_size=2 * n)
            dm = max(dm, float(np.abs(mm.mtf_t.numpy() - np.asarray(oo.mtf[0][0], float)).max()),
                     float(np.abs(mm.mtf_s.numpy() - np.asarray(oo.mtf[0][1], float)).max()))
        print(f"| {name} | {'/'.join(f'{f:g}' for f in spec['fields_deg'])} | {last:.4f} % | "
              f"{ddist:.1e} | {dopd:.1e} | {drms:.1e} | {rmsmax:.2f} | {dm:.1e} |")


if __name__ == "__main__":
    main()
