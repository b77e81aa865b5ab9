"""Model-glass design against its substituted real-glass design (issue 36, item 4), as a
markdown table: the 5 % check of docs/guide/design-search-glass.md for each model-glass
dispersion law and region radius.

The procedure is tests/design/search/test_glass.py's slow test: a cemented doublet (f = 100 mm,
F/4.2, on axis, F/d/C, EFL target), 20 DLS steps on curvatures, sensor and model glasses inside
the SCHOTT region (2 pupil rounds), projection, 5 steps without the glasses, then substitution
within SCHOTT (k = 3, every combination re-optimised by 10 DLS steps).

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_glass_substitution.py \
        [--dispersion normal cauchy] [--radius 0.03 0.01]
"""

from __future__ import annotations

import argparse
import time
import warnings

from deeplens.design.lensopt import optimize_lens
from deeplens.design.merit import Merit, SpotMerit, TargetMerit
from deeplens.design.search.glass import (
    GlassRegionPenalty, TrainableModelGlass, dls_reoptimizer, glass_scales,
    glass_variable_names, project_model_glasses, substitute_glasses, use_model_glasses)
from deeplens.design.search.glass_region import GlassRegion
from deeplens.design.variables import Variables
from deeplens.optics.lens import Lens, LensSpec
from deeplens.optics.materials import LINE_C, LINE_D, LINE_F, get_material
from deeplens.optics.surfaces import Sphere


def doublet() -> Lens:
    spec = LensSpec(fields_deg=[0.0], wavelengths_nm=[LINE_D, LINE_F, LINE_C])
    return Lens([Sphere(1 / 61.0, 12.0), Sphere(-1 / 44.0, 12.0), Sphere(-1 / 130.0, 12.0)],
                [get_material("AIR"), get_material("1.5168/64.17"),
                 get_material("1.6727/32.25"), get_material("AIR")],
                [0.0, 6.0, 2.5], 96.0, 0, spec=spec).double()


def run(dispersion: str, radius: float) -> dict:
    t0 = time.process_time()
    region = GlassRegion("SCHOTT", radius=radius)
    lens = doublet()
    use_model_glasses(lens, region=region, dispersion=dispersion)
    spot = Merit(SpotMerit([0.0], [LINE_F, LINE_D, LINE_C], sampling="hexapolar:4"),
                 TargetMerit("efl", 100.0, 0.1))
    v = Variables(lens, ["surfaces.*.c", "d_sensor"] + glass_variable_names(lens),
                  scales=glass_scales(lens))
    optimize_lens(lens, v, Merit(*spot.terms, GlassRegionPenalty(region)), steps=20, rounds=2,
                  jacobian_mode="central")
    project_model_glasses(lens, region)
    optimize_lens(lens, Variables(lens, "surfaces.*.c,d_sensor"), spot, steps=5,
                  jacobian_mode="central")
    model = float(spot.prepare(lens)(lens))
    glasses = [m.values() for m in lens.materials if isinstance(m, TrainableModelGlass)]
    res = substitute_glasses(lens, "SCHOTT", dls_reoptimizer(spot, "surfaces.*.c,d_sensor",
                                                             steps=10, jacobian_mode="central"))
    real = float(spot.prepare(res.lens)(res.lens))
    return dict(model=model, real=real, glasses=glasses, names=res.names,
                seconds=time.process_time() - t0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dispersion", nargs="+", default=["normal", "cauchy"])
    ap.add_argument("--radius", nargs="+", type=float, default=[0.03, 0.01])
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    print("| dispersion | radius | model glasses (n_d/V_d) | model merit (mm²) | substituted "
          "| real merit (mm²) | real / model | CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for disp in args.dispersion:
        for radius in args.radius:
            r = run(disp, radius)
            mg = ", ".join(f"{n:.4f}/{v:.1f}" for n, v in r["glasses"])
            names = " + ".join(n.split(":")[1] for n in r["names"].values())
            print(f"| {disp} | {radius:g} | {mg} | {r['model']:.4g} | {names} | "
                  f"{r['real']:.4g} | {r['real'] / r['model']:.2f} | {r['seconds']:.1f} |",
                  flush=True)


if __name__ == "__main__":
    main()
