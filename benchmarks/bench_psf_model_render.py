"""The misplaced energy that ``render.psf_model=auto`` measures, against pixel pitch.

The renderer's own comparison (:class:`deeplens.render.psf_model.PSFModel`): the diffraction
kernel of :mod:`deeplens.render.diffraction` (the one the PSF renderer uses) against the
geometric PSF binned on the same pixels, TV = ½ Σ |P_geo - P_diff|, on axis at 6 m and
587.56 nm, for the EDOF achromat with a cubic plate of α waves at the beam's rim (as
``bench_psf_model.py``).

    PYTHONPATH=. python benchmarks/bench_psf_model_render.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from deeplens.optics.io import load_lens  # noqa: E402
from deeplens.render.psf_model import PSFModel  # noqa: E402
from deeplens.render.sensor import Sensor  # noqa: E402

WL = 587.5618


def main():
    t0 = time.time()
    lens = load_lens(ROOT / "data" / "lenses" / "edof_achromat.json").to(torch.float64)
    plate = lens.surfaces[4]
    n_glass = float(lens.materials[4].n(torch.tensor(WL, dtype=torch.float64)))
    print("| cubic α (waves) | pixel (µm) | TV (auto's measure) | diffraction K | pupil N |")
    print("|---|---|---|---|---|")
    for alpha in (0.0, 3.0, 10.0):
        a = alpha * WL * 1e-6 / ((n_glass - 1) * 6.0 ** 3)
        with torch.no_grad():
            plate.a[6].fill_(a)
            plate.a[9].fill_(a)
        for pix in (0.0195, 0.0069, 0.0049):
            sensor = Sensor((64, 64), pix, channels=[[WL]])
            m = PSFModel("auto")
            m.measure(lens, sensor, [((0.0, 0.0), 6000.0, WL)])
            print(f"| {alpha:g} | {pix * 1e3:.1f} | {m.error:.3f} | {m.sampling.kernel} | "
                  f"{m.sampling.pupil} |")
    print(f"\n({time.time() - t0:.0f} s, {torch.get_num_threads()} threads, "
          f"{torch.backends.cpu.get_cpu_capability()})")


if __name__ == "__main__":
    main()
