"""Nikon Z 35 mm f/1.8 patent lens re-optimised from an all-spherical start (paper Sec. IV-A,
Fig. 11).

The shipped prescription (JPA2019090949 example 2, normalised units x10) is evaluated at
0/10/20/32.45 deg and 656.27/587.56/486.13 nm on its own sensor plane (``rms_original``); every
aspheric coefficient is removed (``rms_spherical_start``); then all curvatures and the aspheric
coefficients of the two aspheric surfaces (16 and 17) are optimised by damped least squares for
the RMS spot of all fields and wavelengths, with the paraxial EFL held to the original's by a
target residual (``rms_optimized``).  Goal: the original's mean RMS or better.  Pupil regions are
re-found between rounds.  The DLS Jacobian (25 variables) is taken by central differences in
float64 by default (``--jacobian central``: 50 traces without a graph, ~6x cheaper here than 25
forward-mode JVPs and equal to them to ~1e-8 relative); ``--jacobian forward`` is the paper's
AD route.

    deeplens design nikon --json
"""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path

import torch

from ...optics.paraxial import paraxial
from ...optics.io import load_lens, save_lens
from ..lensopt import optimize_lens
from ..merit import Merit, SpotMerit, TargetMerit
from ..variables import Variables
from . import DATA_DIR

FIELDS = [0.0, 10.0, 20.0, 32.45]
WAVES = [656.27, 587.56, 486.13]
ASPHERES = (16, 17)


def add_arguments(p) -> None:
    p.add_argument("--lens", default=str(DATA_DIR / "nikon_z35_f1.8_x10.json"))
    p.add_argument("--steps", type=int, default=24, help="damped least squares iterations")
    p.add_argument("--rounds", type=int, default=3, help="pupil re-sampling rounds")
    p.add_argument("--sampling", default="hexapolar:4", help="pupil pattern of the merit")
    p.add_argument("--fields", default=",".join(f"{f:g}" for f in FIELDS), help="degrees")
    p.add_argument("--jacobian", default="central", choices=("central", "forward", "reverse"),
                   help="how damped least squares builds its Jacobian")
    p.add_argument("--efl-weight", type=float, default=1.0,
                   help="weight of the EFL target residual (relative EFL error)")


def _merit(fields, sampling, shrink=0.9, strict=True):
    # a 10 % margin inside the traced pupil: the strongly vignetted 32.45 deg field would
    # otherwise lose rim rays at almost every step, and such steps are rejected
    return SpotMerit(fields, WAVES, sampling=sampling, pupil_grid=33, pupil_bisections=16,
                     shrink=shrink, strict_rays=strict)


def _mean_rms(sm, lens):
    """Mean RMS (µm) on freshly traced pupils (full size, lost rays allowed)."""
    sm = _merit(sm.fields, sm.sampling, shrink=1.0, strict=False)
    sm.prepare(lens)
    with torch.no_grad():
        r = sm.rms(lens) * 1e3
    return float(r.mean()), r.tolist()


def run(args) -> dict:
    fields = [float(f) for f in str(args.fields).split(",") if f.strip()]
    lens = load_lens(args.lens).to(torch.float64)
    efl0 = float(paraxial(lens).efl)
    sm = _merit(fields, args.sampling)
    orig_mean, orig_table = _mean_rms(sm, lens)
    original = copy.deepcopy(lens)
    with torch.no_grad():
        for i in ASPHERES:
            for a in lens.surfaces[i].a:
                a.zero_()
            lens.surfaces[i].k.zero_()
    start_mean, start_table = _mean_rms(sm, lens)
    start = copy.deepcopy(lens)
    vary = "surfaces.*.c," + ",".join(f"surfaces.{i}.a.*" for i in ASPHERES)
    v = Variables(lens, vary)
    merit = Merit(sm, TargetMerit("efl", efl0, args.efl_weight))
    t0 = time.perf_counter()
    res = optimize_lens(lens, v, merit, method="dls", steps=args.steps, rounds=args.rounds,
                       jacobian_mode=args.jacobian)
    seconds = time.perf_counter() - t0
    opt_mean, opt_table = _mean_rms(sm, lens)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    try:
        from ..plots import history_figure, save, spot_figure

        files.append(save(spot_figure(sm, {"original": original, "spherical start": start,
                                           "optimised": lens}), out / "spots.png"))
        files.append(save(history_figure(res.history, "Nikon: merit per accepted step"),
                          out / "history.png"))
    except ImportError:
        pass
    save_lens(lens, out / "nikon_optimized.json")
    result = {"rms_original_um": orig_mean, "rms_spherical_start_um": start_mean,
              "rms_optimized_um": opt_mean, "goal_met": opt_mean <= orig_mean,
              "rms_table_um": {"fields_deg": fields, "wavelengths_nm": WAVES,
                               "original": orig_table, "spherical_start": start_table,
                               "optimized": opt_table},
              "efl_mm": {"original": efl0, "optimized": float(paraxial(lens).efl)},
              "variables": len(v), "steps": res.steps, "seconds": seconds,
              "jacobian": args.jacobian,
              "evaluations": sum(r.evaluations for r in res.rounds),
              "merit_history": [h["merit"] for h in res.history if h["accepted"]],
              "stop_reason": res.reason, "figures": files,
              "lens_out": str(out / "nikon_optimized.json")}
    (out / "result.json").write_text(json.dumps(result, indent=1))
    return result
