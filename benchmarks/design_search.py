"""Design search from no starting lens against a shipped design (issue 36).

For the shipped Cooke triplet (``data/lenses/cooke_triplet.json``) the spec is its own first
order: EFL 101.18 mm, F/3.464 (its paraxial values), half field 11.86 deg sampled at 0, 0.7, 1,
the d, F, C lines; three singlets of SCHOTT glass, the stop in the middle gap, centre
thicknesses 1-12 mm, edges >= 0.5 mm, air >= 0.2 mm, total track <= 130 mm (the shipped lens:
116.5 mm).  Each seed runs :func:`deeplens.design.search.search`; the table compares the best
design's polychromatic RMS spot (:func:`deeplens.design.search.evaluate`, the root-mean-square
over the three fields, hexapolar:12 rays, no vignetting) with the shipped lens's, evaluated the
same way on its own semi-diameters (it vignettes its outer field).

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/design_search.py [--lens cooke]
        [--seeds 0,1,2,3,4] [--starts 3] [--hops 2] [--screen-steps 30] [--polish-steps 40]
        [--hop-steps 20] [--prescreen 0] [--glass-mode catalogue|model] [--substitute-k 2]
        [--substitute-steps 15] [--seidel-screen 0] [--seidel-steps 100] [--seidel-rebalance 300]
        [--seidel-rebalance-floor thin|none] [--seidel-ranking union|rebalanced]
        [--substitution nearest|snap] [--snap-steps 5] [--snap-count 6] [--rank-keep N]
        [--rank-k 4] [--substitute-strategy joint|sequential|combined] [--combined-k 6]
        [--combined-keep 6] [--converge-tol 0.01]
        [--converge-rounds 8] [--converge-steps 120] [--json OUT.json]
        [--save-models DIR [--models-only] | --from-models DIR]

``--glass-mode model``: the spec's glasses become model glasses in SCHOTT's glass region
(vendor catalogue), substituted at the end by the nearest real SCHOTT glasses; the table adds
the model-glass design's RMS spot and the substitution's merit loss (real / model - 1).  Both
are converged under the same rule (``SearchConfig.converge_tol``, ``converge_rounds``: rounds
of ``--substitute-steps`` DLS steps until one improves the RMS spot by less than
``--converge-tol``), so the loss is not the unconverged model design's shortfall; the table
also lists the model design as the search left it (unconverged).  ``--prescreen N``: N starts each get 4 DLS steps on
hexapolar:3 rays and the best ``--starts`` of them go on (``SearchConfig.prescreen``).

``--save-models DIR`` (model glass): the kept model-glass designs of each seed, just before
their substitution, are saved to ``DIR/<lens>_seed<k>.pt`` (``torch.save`` of the lenses with
their trainable model glasses, so the normal-line dispersion is kept).  ``--from-models DIR``:
no search; each seed's saved designs are loaded and only the substitution runs (with this
call's ``--substitute-*`` options), so that substitution variants are compared on the same
model designs for minutes of CPU instead of a 20-30 minute search each.  ``--models-only``
(with ``--save-models``): stop each seed once its designs are saved (no substitution).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import time

import torch

from deeplens.design.search import DesignSpec, SearchConfig, Stage, evaluate, search
from deeplens.design.search.glass_region import GlassRegion
from deeplens.design.search.multistart import (Design, SearchResult, signature,
                                               substitute_design)
from deeplens.optics.io import load_lens

SPECS = {
    "cooke": (DesignSpec(efl_mm=101.18, fno=3.464, hfov_deg=11.86, elements=3,
                         wavelengths_nm=[486.1327, 587.5618, 656.2725], glasses="SCHOTT",
                         stop="middle", min_center_glass_mm=1.0, max_center_glass_mm=12.0,
                         min_edge_glass_mm=0.5, min_air_mm=0.2, max_track_mm=130.0),
              "cooke_triplet.json"),
    # the shipped double Gauss: f 27.44 mm, F/3.61, half field 21 deg (its fields 0-21 deg),
    # the d line only (its wavelengths); six air-spaced singlets (the shipped lens cements two
    # pairs), SCHOTT glass (its SSK4, SK1, F15, SK16 are SCHOTT's), the stop in the middle gap;
    # limits from the shipped lens: centre glass 0.9-4 mm (it has 0.97-3.18), air >= 0.05 mm
    # (0.076), total track <= 40 mm (36.6)
    "double_gauss": (DesignSpec(efl_mm=27.4427, fno=3.6113, hfov_deg=21.0, elements=6,
                                wavelengths_nm=[587.5618], glasses="SCHOTT", stop="middle",
                                min_center_glass_mm=0.9, max_center_glass_mm=4.0,
                                min_edge_glass_mm=0.3, min_air_mm=0.05, max_track_mm=40.0),
                     "double_gauss.json"),
}


class _Saved(Exception):
    """Raised by the save hook of ``--models-only`` to stop a seed after saving."""


def substitute_saved(saved, spec, cfg, say) -> SearchResult:
    """The substitution step of :func:`search` alone, on saved model-glass designs."""
    region = GlassRegion(spec.catalogues, radius=cfg.glass_radius)
    t0, real = time.perf_counter(), []
    for k, d in enumerate(saved):
        dsg = Design(d["lens"], d["metrics"], d["origin"], signature(d["lens"], spec.efl_mm))
        r = substitute_design(dsg, spec, cfg, region)
        g = r.glass_record
        say(f"substitution {k + 1}/{len(saved)}: model {g['model_rms_um']:.2f} um -> "
            f"{', '.join(g['substituted'].values())}: {g['real_rms_um']:.2f} um "
            f"({len(g['candidates'])} candidates, {g['seconds']:.0f} s)")
        real.append(r)
    return SearchResult(sorted(real, key=lambda d: d.key), [], time.perf_counter() - t0, cfg)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--lens", choices=sorted(SPECS), default="cooke",
                   help="the shipped lens whose spec is searched")
    p.add_argument("--seeds", default="0,1,2,3,4")
    p.add_argument("--starts", type=int, default=3)
    p.add_argument("--hops", type=int, default=2)
    p.add_argument("--screen-steps", type=int, default=30)
    p.add_argument("--polish-steps", type=int, default=40)
    p.add_argument("--hop-steps", type=int, default=20)
    p.add_argument("--prescreen", type=int, default=0)
    p.add_argument("--glass-mode", choices=["catalogue", "model"], default="catalogue")
    p.add_argument("--substitute-k", type=int, default=2)
    p.add_argument("--substitute-steps", type=int, default=15)
    p.add_argument("--substitute-radius", type=float, default=None)
    p.add_argument("--glass-radius", type=float, default=None,
                   help="SearchConfig.glass_radius: the model glasses' region (default 0.03)")
    p.add_argument("--seidel-screen", type=int, default=0,
                   help="third-order screen: Sobol thin systems sampled (0: off)")
    p.add_argument("--seidel-steps", type=int, default=100)
    p.add_argument("--seidel-rebalance", type=int,
                   default=SearchConfig.seidel_rebalance,
                   help="SearchConfig.seidel_rebalance: Adam steps re-balancing each "
                        "thickened start's third order (default: SearchConfig's; 0: off)")
    p.add_argument("--seidel-rebalance-floor", choices=["thin", "none"],
                   default=SearchConfig.seidel_rebalance_floor,
                   help="SearchConfig.seidel_rebalance_floor: no gain below the thin "
                        "system's third order (thin) or none")
    p.add_argument("--seidel-ranking", choices=["union", "rebalanced"],
                   default=SearchConfig.seidel_ranking,
                   help="SearchConfig.seidel_ranking: the best --starts of the plain and of "
                        "the re-balanced ranking, each start once (union), or of the "
                        "re-balanced one alone")
    p.add_argument("--substitution", choices=["nearest", "snap"], default=None,
                   help="SearchConfig.substitution (default: its default)")
    p.add_argument("--snap-steps", type=int, default=5)
    p.add_argument("--snap-count", type=int, default=6)
    p.add_argument("--rank-keep", type=int, default=None,
                   help="SearchConfig.rank_keep: re-optimise only the best N of the "
                        "--rank-k nearest per element, ranked by a linearised prediction")
    p.add_argument("--rank-k", type=int, default=4)
    p.add_argument("--substitute-strategy", choices=["joint", "sequential", "combined"],
                   default=None,
                   help="SearchConfig.substitute_strategy (default: its default)")
    p.add_argument("--combined-k", type=int, default=None,
                   help="SearchConfig.combined_k: nearest glasses per element ranked by the "
                        "combined strategy (default: its default)")
    p.add_argument("--combined-keep", type=int, default=None,
                   help="SearchConfig.combined_keep: ranked candidates re-optimised")
    p.add_argument("--converge-tol", type=float, default=None,
                   help="SearchConfig.converge_tol (default: its default)")
    p.add_argument("--converge-rounds", type=int, default=None,
                   help="SearchConfig.converge_rounds (default: its default)")
    p.add_argument("--converge-steps", type=int, default=120,
                   help="SearchConfig.converge_steps: the kept design refined on the final "
                        "rays until converged, at most this many DLS steps (0: off; default "
                        "120, as the command)")
    p.add_argument("--json", help="also write the numbers here")
    p.add_argument("--save-models", metavar="DIR",
                   help="save each seed's model-glass designs before substitution")
    p.add_argument("--models-only", action="store_true",
                   help="with --save-models: stop each seed once its designs are saved")
    p.add_argument("--from-models", metavar="DIR",
                   help="no search: substitute the model-glass designs saved in DIR")
    args = p.parse_args(argv)
    if args.models_only and not args.save_models:
        p.error("--models-only needs --save-models DIR")
    if (args.save_models or args.from_models) and args.glass_mode != "model":
        p.error("--save-models and --from-models need --glass-mode model")
    torch.set_num_threads(1)
    spec, name = SPECS[args.lens]
    if args.glass_mode == "model":
        spec = dataclasses.replace(spec, glass_mode="model")
    shipped = evaluate(load_lens(name).to(torch.float64), spec)
    rows = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        cfg = SearchConfig(starts=args.starts, hops=args.hops, seed=seed, polish_count=1,
                           screen=(Stage(args.screen_steps, "hexapolar:6",
                                         rounds=max(1, args.screen_steps // 20)),),
                           polish=(Stage(args.polish_steps, "hexapolar:6",
                                         rounds=max(1, args.polish_steps // 20)),),
                           hop=(Stage(args.hop_steps, "hexapolar:6",
                                      rounds=max(1, args.hop_steps // 20)),), keep=1,
                           prescreen=args.prescreen, seidel_screen=args.seidel_screen,
                           seidel_steps=args.seidel_steps,
                           seidel_rebalance=args.seidel_rebalance,
                           seidel_rebalance_floor=args.seidel_rebalance_floor,
                           seidel_ranking=args.seidel_ranking, substitute_k=args.substitute_k,
                           substitute_radius=args.substitute_radius,
                           substitute=(Stage(args.substitute_steps, "hexapolar:6"),),
                           snap_stage=(Stage(args.snap_steps, "hexapolar:6"),),
                           snap_count=args.snap_count, rank_k=args.rank_k,
                           **({"rank_keep": args.rank_keep} if args.rank_keep is not None
                              else {}),
                           converge_steps=args.converge_steps,
                           **({"substitution": args.substitution} if args.substitution else {}),
                           **({"glass_radius": args.glass_radius} if args.glass_radius else {}),
                           **{k: getattr(args, k) for k in ("substitute_strategy",
                                                              "converge_tol", "converge_rounds",
                                                              "combined_k", "combined_keep")
                              if getattr(args, k) is not None})
        t0, c0 = time.perf_counter(), time.process_time()

        def say(s, seed=seed):
            print(f"  seed {seed}: {s}", file=sys.stderr, flush=True)

        path = f"{args.save_models or args.from_models}/{args.lens}_seed{seed}.pt"
        if args.from_models:
            res = substitute_saved(torch.load(path, weights_only=False), spec, cfg, say)
        else:
            save = None
            if args.save_models:
                os.makedirs(args.save_models, exist_ok=True)

                def save(kept, path=path):
                    torch.save([{"lens": d.lens, "metrics": d.metrics, "origin": d.origin}
                                for d in kept], path)
                    if args.models_only:
                        raise _Saved(path)
            try:
                res = search(spec, cfg, progress=say, model_designs=save)
            except _Saved:
                print(f"seed {seed}: model designs saved to {path} "
                      f"({time.process_time() - c0:.0f} s CPU)", flush=True)
                continue
        m = res.best.metrics
        rows.append({"seed": seed, "rms_um": m["rms_um"], "rms_poly_um": m["rms_poly_um"],
                     "feasible": m["feasible"], "efl_mm": m["efl_mm"], "fno": m["fno"],
                     "track_mm": m["total_track_mm"], "glasses": list(res.best.glasses),
                     "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0})
        g = res.best.glass_record
        if g:
            rows[-1].update(model_rms_um=g["model_rms_um"], merit_loss=g["merit_loss"],
                            model_rms_unconverged_um=g["model_rms_unconverged_um"],
                            model_convergence=g["model_convergence"],
                            real_convergence=g["real_convergence"],
                            model_glasses=g["model_glasses"], substituted=g["substituted"],
                            substitution_s=g["seconds"], glass_record=g)
        print(f"seed {seed}: {m['rms_um']:.2f} um (fields {', '.join(f'{x:.1f}' for x in m['rms_poly_um'])}), "
              + (f"model glass {g['model_rms_um']:.2f} um (unconverged "
                 f"{g['model_rms_unconverged_um']:.2f}), loss {100 * g['merit_loss']:+.1f} %, "
                 if g else "")
              + f"{rows[-1]['wall_s']:.0f} s wall, {rows[-1]['cpu_s']:.0f} s CPU", flush=True)
    if not rows:
        return 0
    best = min(r["rms_um"] for r in rows)
    med = statistics.median(r["rms_um"] for r in rows)
    ref = shipped["rms_um"]
    print("\n| spec | seeds | shipped RMS (um) | best (um) | median (um) | best/shipped | "
          "median/shipped | CPU s per seed (median) |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {args.lens} | {len(rows)} | {ref:.2f} | {best:.2f} | {med:.2f} | {best / ref:.2f} | "
          f"{med / ref:.2f} | {statistics.median(r['cpu_s'] for r in rows):.0f} |")
    if args.glass_mode == "model":
        print("\n| seed | model glass RMS, as searched (um) | converged (um) | real glass RMS "
              "(um) | loss | glasses | CPU s |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['seed']} | {r['model_rms_unconverged_um']:.2f} | "
                  f"{r['model_rms_um']:.2f} | {r['rms_um']:.2f} | "
                  f"{100 * r['merit_loss']:+.1f} % | {', '.join(r['substituted'].values())} | "
                  f"{r['cpu_s']:.0f} |")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"spec": spec.to_dict(), "shipped": shipped, "runs": rows,
                       "args": vars(args)}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
