"""``deeplens design search``: design a lens from a specification, beyond the nearest local
minimum (quasi-random thin-lens starts refined by damped least squares, then basin hopping).

Writes ``OUT/best.json`` (a lens file every command reads), ``OUT/design_K.json`` (the other
kept designs), ``OUT/result.json`` (RMS spot per field and wavelength, EFL, F/#, total track,
constraints, time, every refinement) and, with matplotlib, ``convergence.png`` and
``layout.png``.  The spec comes from ``--spec FILE`` (YAML or JSON, keys as
:class:`~deeplens.design.search.spec.DesignSpec`'s fields) and/or flags (flags win).  Example:
``deeplens design search --efl 50 --fno 5 --hfov 20 --elements 3 --wavelengths
486.1,587.6,656.3 --glasses SCHOTT --seed 0 --out DIR``.
"""

from __future__ import annotations

import math
import sys

#: flag -> spec field (the values are parsed by DesignSpec, which names the field on error)
_SPEC_FLAGS = {"efl": "efl_mm", "fno": "fno", "epd": "epd_mm", "hfov": "hfov_deg",
               "elements": "elements", "aspheres": "aspheres", "wavelengths": "wavelengths_nm",
               "wavelength_weights": "wavelength_weights", "primary": "primary_wavelength_nm",
               "fields": "field_fractions", "field_weights": "field_weights", "stop": "stop",
               "glasses": "glasses", "glass_mode": "glass_mode", "object_distance": "object_distance_mm",
               "max_track": "max_track_mm", "min_center_glass": "min_center_glass_mm",
               "max_center_glass": "max_center_glass_mm", "min_edge_glass": "min_edge_glass_mm",
               "min_air": "min_air_mm", "min_bfl": "min_bfl_mm", "max_diameter": "max_diameter_mm",
               "max_distortion": "max_distortion_pct"}


def add_arguments(p) -> None:
    s = p.add_argument_group("specification (mm, degrees, nm)")
    s.add_argument("--spec", help="YAML or JSON spec file (flags below override its values)")
    s.add_argument("--efl", type=float, help="effective focal length")
    s.add_argument("--fno", type=float, help="F-number (or --epd)")
    s.add_argument("--epd", type=float, help="entrance-pupil diameter (or --fno)")
    s.add_argument("--hfov", type=float, help="half field of view")
    s.add_argument("--elements", type=int, help="number of singlets (default 3)")
    s.add_argument("--aspheres", type=int, help="surfaces allowed conic + a4, a6 (default 0)")
    s.add_argument("--wavelengths", help="comma-separated, e.g. 486.1,587.6,656.3")
    s.add_argument("--wavelength-weights", help="comma-separated relative weights")
    s.add_argument("--primary", type=float, help="primary wavelength (default: the middle)")
    s.add_argument("--fields", help="fractions of the half field (default 0,0.7,1)")
    s.add_argument("--field-weights", help="comma-separated relative weights")
    s.add_argument("--stop", help="front, middle, back, search (default) or an air-gap index")
    s.add_argument("--glasses", help="SCHOTT (default), MODEL, or comma-separated glass names; "
                   "with --glass-mode model: vendor catalogues (SCHOTT, OHARA, HOYA, CDGM, "
                   "HIKARI, SUMITA, comma-separated)")
    s.add_argument("--glass-mode", choices=["catalogue", "model"],
                   help="catalogue: glasses picked from --glasses and kept (default); model: "
                   "model glasses (n_d, V_d variables) in the catalogues' glass region, "
                   "substituted by the nearest real glasses at the end")
    s.add_argument("--object-distance", type=float, help="object to first vertex (default inf)")
    for flag in ("max-track", "min-center-glass", "max-center-glass", "min-edge-glass",
                 "min-air", "min-bfl", "max-diameter"):
        s.add_argument(f"--{flag}", type=float, help=f"{flag.replace('-', ' ')} (mm)")
    s.add_argument("--max-distortion", type=float, help="largest |distortion| over the non-zero "
                   "fields (percent; default: none)")
    g = p.add_argument_group("search")
    g.add_argument("--seed", type=int, default=0, help="seed of the starts and hops")
    g.add_argument("--starts", type=int, default=16, help="quasi-random starts (default 16)")
    g.add_argument("--start-kind", choices=["thin", "flat", "mixed"], default="thin",
                   help="thin-lens solve, flat surfaces with a curriculum, or both")
    g.add_argument("--polish", type=int, default=3, help="distinct designs polished")
    g.add_argument("--hops", type=int, default=6, help="basin-hopping hops (0: none)")
    g.add_argument("--keep", type=int, default=3, help="distinct designs kept and written")
    g.add_argument("--screen-steps", type=int, default=12, help="DLS steps per start (12)")
    g.add_argument("--polish-steps", type=int, default=30, help="DLS steps per polish (30)")
    g.add_argument("--hop-steps", type=int, default=20, help="DLS steps per hop (20)")
    g.add_argument("--substitute-k", type=int, default=2,
                   help="real glasses tried per model glass (--glass-mode model; default 2)")
    g.add_argument("--substitute-steps", type=int, default=15,
                   help="DLS steps re-optimising each substitution candidate (15)")
    g.add_argument("--substitution", choices=["snap", "nearest"], default="nearest",
                   help="nearest: model glasses substituted as they are (default); snap: first "
                        "pulled onto real ones while re-optimising")
    g.add_argument("--substitute-strategy", choices=["combined", "sequential", "joint"],
                   default="combined",
                   help="combined: the sequential candidates and the best 6 of every "
                        "combination of the 6 nearest glasses per element (fewer past 729 "
                        "combinations) ranked by a linearised re-optimisation, the better "
                        "kept (default); sequential: one element at a time, the most "
                        "sensitive first, the remaining model glasses re-optimised; joint: "
                        "every combination of the nearest glasses (one element at a time "
                        "past 27)")
    g.add_argument("--seidel-screen", type=int, default=2048,
                   help="Sobol thin-lens systems screened by their third-order RMS spot, in "
                        "total; the best distinct become the --starts starts (default 2048; "
                        "0: off; used for thin starts of an object at infinity only)")
    g.add_argument("--seidel-steps", type=int, default=100,
                   help="batched Adam steps of the third-order screen (100)")
    g.add_argument("--seidel-rebalance", type=int, default=300,
                   help="batched Adam steps re-balancing each thickened start's third order "
                        "(default 300; 0: off); with --seidel-ranking union both the plain "
                        "and the re-balanced starts are refined")
    g.add_argument("--seidel-rebalance-floor", choices=["thin", "none"], default="thin",
                   help="thin: the re-balancing gains nothing below the thin system's own "
                        "third-order RMS (default); none: no floor")
    g.add_argument("--seidel-ranking", choices=["union", "rebalanced"], default="union",
                   help="union: the best --starts of the plain and of the re-balanced "
                        "ranking of the thickened starts, each start once (up to 2 x "
                        "--starts; default); rebalanced: the re-balanced ranking's alone")
    g.add_argument("--converge-steps", type=int, default=120,
                   help="DLS steps at most refining each kept design on the final rays until "
                        "converged (default 120; 0: off)")
    g.add_argument("--converge-tol", type=float, default=0.01,
                   help="converged: two rounds of 10 steps each lowered the merit by less "
                        "than this fraction; also the glass substitution's convergence rule "
                        "(default 0.01)")
    g.add_argument("--count-trade", metavar="LO-HI",
                   help="element count as a variable: search at --elements, then thin down to "
                   "LO and split up to HI elements (each refined --polish-steps DLS steps); "
                   "writes OUT/count_trade.json and OUT/elements_N.json")
    g.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def spec_from_args(args):
    """The :class:`~deeplens.design.search.spec.DesignSpec` of ``--spec`` and the flags."""
    from ..search.spec import DesignSpec

    data = {}
    if args.spec:
        data = DesignSpec.from_file(args.spec).to_dict()
    for flag, name in _SPEC_FLAGS.items():
        v = getattr(args, flag, None)
        if v is not None:
            data[name] = v
    if args.fno is not None:
        data.pop("epd_mm", None)
    if args.epd is not None:
        data.pop("fno", None)
    for k in ("efl_mm", "hfov_deg"):
        if k not in data:
            raise ValueError(f"--{k.split('_')[0]} (or {k!r} in --spec) is required")
    return DesignSpec.from_dict({k: v for k, v in data.items() if v is not None},
                                source=args.spec or "")


def run(args) -> dict:
    from ..search import SearchConfig, Stage, search, write_outputs

    spec = spec_from_args(args)
    for flag in ("screen_steps", "polish_steps", "hop_steps", "substitute_steps"):
        if getattr(args, flag) < 1:
            raise ValueError(f"--{flag.replace('_', '-')} must be >= 1, got {getattr(args, flag)}")
    cfg = SearchConfig(starts=args.starts, start_kind=args.start_kind, polish_count=args.polish,
                       hops=args.hops, keep=args.keep, seed=args.seed,
                       screen=(Stage(args.screen_steps, "hexapolar:6"),),
                       polish=(Stage(args.polish_steps, "hexapolar:6", rounds=2),),
                       hop=(Stage(args.hop_steps, "hexapolar:6"),),
                       substitute_k=args.substitute_k,
                       substitute=(Stage(args.substitute_steps, "hexapolar:6"),),
                       substitution=args.substitution,
                       substitute_strategy=args.substitute_strategy,
                       seidel_screen=args.seidel_screen if args.start_kind == "thin"
                       and math.isinf(spec.object_distance_mm) else 0,
                       seidel_steps=args.seidel_steps,
                       seidel_rebalance=args.seidel_rebalance,
                       seidel_rebalance_floor=args.seidel_rebalance_floor,
                       seidel_ranking=args.seidel_ranking,
                       converge_steps=args.converge_steps, converge_tol=args.converge_tol)

    def progress(text):
        if not args.quiet:
            print(f"[search] {text}", file=sys.stderr, flush=True)

    if args.count_trade:
        return _count_trade(args, spec, cfg, progress)
    try:
        res = search(spec, cfg, progress=progress)
    except RuntimeError as e:
        raise ValueError(str(e)) from None
    paths = write_outputs(args.out, res, spec)
    best = res.best.metrics
    return {"rms_um": best["rms_um"], "rms_poly_um": best["rms_poly_um"],
            "efl_mm": best["efl_mm"], "fno": best["fno"], "total_track_mm": best["total_track_mm"],
            "feasible": best["feasible"], "seconds": res.seconds, "designs": len(res.designs),
            "best": paths.get("best"), "result": paths.get("result"),
            **({"model_rms_um": res.best.glass_record["model_rms_um"],
                "glasses_substituted": res.best.glass_record["substituted"]}
               if res.best.glass_record else {})}


def _counts(text: str) -> list[int]:
    try:
        lo, hi = (int(v) for v in text.split("-"))
    except ValueError:
        raise ValueError(f"--count-trade: expected LO-HI element counts such as 2-4, got "
                         f"{text!r}") from None
    if not 1 <= lo <= hi <= 8:
        raise ValueError(f"--count-trade: expected 1 <= LO <= HI <= 8, got {text!r}")
    return list(range(lo, hi + 1))


def _count_trade(args, spec, cfg, progress) -> dict:
    """``--count-trade``: :func:`~deeplens.design.search.count.count_trade`, its table in
    ``OUT/count_trade.json`` and each count's lens in ``OUT/elements_N.json``."""
    import json
    from pathlib import Path

    from ...optics.io import save_lens
    from ..search import Stage
    from ..search.count import count_trade
    from ..search.result import file_lens

    counts = _counts(args.count_trade)
    if not counts[0] <= spec.elements <= counts[-1]:
        raise ValueError(f"--count-trade {args.count_trade}: the range must hold --elements "
                         f"({spec.elements}), where the search runs")
    try:
        steps = count_trade(spec, counts, cfg, (Stage(args.polish_steps, "hexapolar:6"),),
                            progress=progress)
    except RuntimeError as e:
        raise ValueError(str(e)) from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for st in steps:
        row = st.row()
        if st.ok:
            path = out / f"elements_{st.elements}.json"
            save_lens(file_lens(st.lens)[0], path)
            row["lens"] = str(path)
        rows.append(row)
    table = {"spec": spec.to_dict(), "seed": args.seed, "trade": rows}
    (out / "count_trade.json").write_text(json.dumps(table, indent=1), encoding="utf-8")
    return {"trade": rows, "table": str(out / "count_trade.json")}
