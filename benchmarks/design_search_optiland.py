"""optiland's global optimisers beside deeplens's design search on the Cooke spec (issue 36).

A benchmark, not a test.  The spec is ``benchmarks/design_search.py``'s Cooke triplet (EFL
101.18 mm, F/3.464, half field 11.86 deg at 0, 0.7, 1, the d, F, C lines, three SCHOTT
singlets, stop in the middle gap).  Both sides start from the same lens, the first thin-lens
start of the search's seed (:func:`deeplens.design.search.thin_lens_start` at the seed's first
Sobol point that gives a lens; its glasses are kept: glass is not a variable on either side),
vary the same quantities (every refracting curvature, every axial gap including both sides of
the stop, the image distance) and get the same wall-time budget:

* **ours**: :func:`deeplens.design.search.search` with the benchmark's settings and
  ``SearchConfig.time_limit_s = budget`` (it starts nothing new past the budget; what is under
  way finishes, so its wall time can exceed the budget by one refinement: both are printed);
* **optiland** ``DifferentialEvolution``, ``DualAnnealing`` (bounds: curvatures within
  +-0.06 /mm, glass 1-12 mm, air 0.2-30 mm, image distance 40-120 mm) and ``BasinHopping``
  (optiland refuses bounds for it), each on an optiland ``OptimizationProblem`` whose merit is
  the RMS spot (``rms_spot_size``, hexapolar rings, image surface) at each field and wavelength
  plus the focal length (``f2``, target the spec's EFL, weight 0.1 per mm).  Each runs until the
  budget is spent (the objective raises once it is; the best point seen is kept) with one
  worker.

The merits differ: optiland's RMS spot is about each wavelength's own centroid (ours: about the
field's polychromatic centroid) and its focal length is a penalty (ours: exact by a solve).  So
every final design is evaluated by OUR :func:`deeplens.design.search.evaluate` (the
polychromatic RMS over the three fields on hexapolar:12 rays) after it is scaled to the exact
EFL (all lengths times ``f / EFL``; the aperture stays the spec's EPD) and its semi-diameters
are fitted to its beam.  ``time to best`` is when the best objective value was first reached
(optiland: its own merit; ours: the whole search's wall time, an upper bound).

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/design_search_optiland.py [--budget 300]
        [--seed 0] [--only ours,de,da,bh] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np
import torch

from deeplens.analysis.paraxial import paraxial
from deeplens.design.search import SearchConfig, Stage, evaluate, search
from deeplens.design.search.refine import fit_semi_diameters
from deeplens.design.search.start import StartError, start_dimensions, thin_lens_start
from deeplens.optics.surfaces import Aperture

sys.path.insert(0, "benchmarks")
from design_search import SPECS  # noqa: E402

C_MAX = 0.06          # |curvature| bound (1/mm): |R| >= 16.7 mm (the shipped Cooke: 36 mm)
GLASS = (1.0, 12.0)   # the spec's centre-glass limits
AIR = (0.2, 30.0)
IMAGE = (40.0, 120.0)


class TimeUp(Exception):
    pass


def first_start(spec, seed):
    """The search's first thin-lens start for ``seed`` (the same Sobol draws)."""
    sobol = torch.quasirandom.SobolEngine(start_dimensions(spec.elements), scramble=True,
                                          seed=int(seed))
    for _ in range(64):
        u = sobol.draw(1, dtype=torch.float64)[0]
        try:
            return thin_lens_start(spec, u)
        except StartError:
            continue
    raise RuntimeError("no start")


def to_optiland(lens, spec):
    """An optiland ``Optic`` of ``lens`` (same radii, gaps, glasses by name, stop, fields,
    wavelengths, EPD)."""
    from optiland import optic

    op = optic.Optic()
    op.surfaces.add(index=0, radius=math.inf, thickness=math.inf)
    n = len(lens.surfaces)
    for i, s in enumerate(lens.surfaces):
        gap = float(lens.distances[i + 1]) if i + 1 < n else float(lens.d_sensor)
        kw = dict(index=i + 1, thickness=gap)
        if isinstance(s, Aperture):
            kw.update(radius=math.inf, is_stop=True)
        else:
            c = float(s.c)
            kw.update(radius=1.0 / c if c != 0 else math.inf)
        m = lens.materials[i + 1]
        if m.name not in ("AIR", "VACUUM"):
            kw["material"] = (m.name, "schott")
        op.surfaces.add(**kw)
    op.surfaces.add(index=n + 1)
    op.set_aperture(aperture_type="EPD", value=spec.epd)
    op.fields.set_type(field_type="angle")
    for f in spec.fields_deg:
        op.fields.add(y=f)
    prim = spec.primary_wavelength_nm
    for w in spec.wavelengths_nm:
        op.wavelengths.add(value=w / 1000.0, is_primary=(w == prim))
    return op


def problem(op, lens, spec, bounds: bool, rings: int = 4):
    from optiland.optimization import OptimizationProblem

    pb = OptimizationProblem()
    for f in spec.field_fractions:
        for w in spec.wavelengths_nm:
            pb.add_operand("rms_spot_size", target=0.0, weight=1.0,
                           input_data={"optic": op, "surface_number": -1, "Hx": 0.0,
                                       "Hy": float(f), "num_rays": rings,
                                       "wavelength": w / 1000.0, "distribution": "hexapolar"})
    pb.add_operand("f2", target=spec.efl_mm, weight=0.1, input_data={"optic": op})
    n = len(lens.surfaces)
    for i, s in enumerate(lens.surfaces):
        k = i + 1
        if not isinstance(s, Aperture):
            b = dict(min_val=-C_MAX, max_val=C_MAX) if bounds else {}
            pb.add_variable(op, "reciprocal_radius", surface_number=k, **b)
        glass = lens.materials[i + 1].name not in ("AIR", "VACUUM")
        lo, hi = IMAGE if i == n - 1 else (GLASS if glass else AIR)
        b = dict(min_val=lo, max_val=hi) if bounds else {}
        pb.add_variable(op, "thickness", surface_number=k, **b)
    return pb


def from_optiland(op, lens, spec):
    """Our lens with ``op``'s curvatures and gaps (a copy of ``lens``), scaled to the exact
    EFL, semi-diameters fitted to the beam."""
    import copy

    out = copy.deepcopy(lens)
    n = len(lens.surfaces)
    with torch.no_grad():
        for i, s in enumerate(out.surfaces):
            surf = op.surfaces[i + 1]
            t = float(np.asarray(surf.thickness))
            if not isinstance(s, Aperture):
                r = float(np.asarray(surf.geometry.radius))
                s.c.fill_(0.0 if math.isinf(r) else 1.0 / r)
            if i + 1 < n:
                out.distances[i + 1].fill_(t)
            else:
                out.d_sensor.fill_(t)
        efl = float(paraxial(out).efl)
        k = spec.efl_mm / efl
        for i, s in enumerate(out.surfaces):
            if not isinstance(s, Aperture):
                s.c.div_(k)
            out.distances[i].mul_(k)
        out.d_sensor.mul_(k)
    out.apply_aperture_spec()
    fit_semi_diameters(out, spec.fields_deg, spec.wavelengths_nm)
    return out, efl


def run_optiland(kind, lens, spec, budget):
    from optiland.optimization import BasinHopping, DifferentialEvolution, DualAnnealing

    op = to_optiland(lens, spec)
    pb = problem(op, lens, spec, bounds=kind != "bh")
    cls = {"de": DifferentialEvolution, "da": DualAnnealing, "bh": BasinHopping}[kind]
    opt = cls(pb)
    orig = opt._fun
    state = {"best": math.inf, "x": None, "t": 0.0, "n": 0, "first": None}
    t0 = time.perf_counter()

    def timed(x):
        if time.perf_counter() - t0 > budget:
            raise TimeUp
        try:
            f = float(orig(x))
        except (ValueError, RuntimeError, FloatingPointError):
            f = math.inf
        state["n"] += 1
        if state["first"] is None:
            state["first"] = f
        if not math.isfinite(f):
            return 1e6
        if f < state["best"]:
            state.update(best=f, x=np.array(x, dtype=float), t=time.perf_counter() - t0)
        return f

    opt._fun = timed
    try:
        if kind == "de":
            opt.optimize(maxiter=100000, disp=False, workers=1)
        elif kind == "da":
            opt.optimize(maxiter=100000, disp=False)
        else:
            opt.optimize(niter=100000)
    except TimeUp:
        pass
    wall = time.perf_counter() - t0
    if state["x"] is not None:
        for i, var in enumerate(pb.variables):
            var.update(state["x"][i])
        pb.update_optics()
    row = {"method": {"de": "optiland DifferentialEvolution", "da": "optiland DualAnnealing",
                      "bh": "optiland BasinHopping"}[kind],
           "own_merit_start": state["first"], "own_merit_best": state["best"],
           "time_to_best_s": state["t"], "wall_s": wall, "evaluations": state["n"]}
    try:
        ours, efl = from_optiland(op, lens, spec)
        m = evaluate(ours, spec)
        row.update(rms_um=m["rms_um"], rms_poly_um=m["rms_poly_um"], feasible=m["feasible"],
                   efl_before_scaling_mm=efl, broken=m["constraints_broken"])
    except (ValueError, RuntimeError) as e:
        row.update(rms_um=math.nan, error=f"{type(e).__name__}: {e}")
    return row


def run_ours(spec, seed, budget):
    cfg = SearchConfig(starts=3, hops=2, seed=seed, polish_count=1,
                       screen=(Stage(30, "hexapolar:6", rounds=1),),
                       polish=(Stage(40, "hexapolar:6", rounds=2),),
                       hop=(Stage(20, "hexapolar:6", rounds=1),), keep=1, time_limit_s=budget)
    t0 = time.perf_counter()
    res = search(spec, cfg, progress=lambda s: print(f"  ours: {s}", file=sys.stderr,
                                                     flush=True))
    wall = time.perf_counter() - t0
    m = res.best.metrics
    return {"method": "deeplens search (3 starts x 30, polish 40, 2 hops x 20)",
            "rms_um": m["rms_um"], "rms_poly_um": m["rms_poly_um"], "feasible": m["feasible"],
            "time_to_best_s": wall, "wall_s": wall,
            "refinements": sum(1 for r in res.runs if r.get("steps"))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--budget", type=float, default=300.0, help="wall seconds per method")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--only", default="ours,de,da,bh")
    p.add_argument("--json")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    spec = SPECS["cooke"][0]
    lens = first_start(spec, args.seed)
    start = evaluate(lens, spec)
    print(f"start: {start['rms_um']:.1f} um (glasses {[m.name for m in lens.materials]})",
          flush=True)
    rows = []
    for kind in args.only.split(","):
        row = run_ours(spec, args.seed, args.budget) if kind == "ours" else \
            run_optiland(kind, lens, spec, args.budget)
        rows.append(row)
        print(json.dumps(row), flush=True)
    print(f"\nbudget {args.budget:.0f} s per method, seed {args.seed}, start {start['rms_um']:.1f} um")
    print("| method | RMS spot, our evaluate (µm) | feasible | time to best (s) | wall (s) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['method']} | {r['rms_um']:.2f} | {r.get('feasible')} | "
              f"{r['time_to_best_s']:.0f} | {r['wall_s']:.0f} |")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"args": vars(args), "start_rms_um": start["rms_um"], "rows": rows}, fh,
                      indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
