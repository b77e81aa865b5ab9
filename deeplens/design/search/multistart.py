"""The global strategy: quasi-random starts, each refined by DLS, then basin hopping.

1. **Starts.**  ``starts`` points of a scrambled Sobol sequence (``torch.quasirandom.
   SobolEngine``, seeded) in the start cube of :mod:`.start` (sign pattern, glasses, powers,
   bendings, spacings, stop position); each becomes a thin-lens start (or a flat start, or
   alternately both: ``start_kind``).  Points that give no lens are skipped and replaced by
   further points (up to 4 x ``starts`` draws).
   **1b. Prescreen** (``prescreen > starts``): instead, ``prescreen`` starts (up to 4 x
   ``prescreen`` draws) each get a cheap refinement (``prescreen_stage``: a few DLS steps on
   few rays) and an RMS spot on ``prescreen_sampling``; the best ``starts`` of them (feasible
   first) go on to step 2.
   **1c. Third-order screen** (``seidel_screen > 0``): instead, ``seidel_screen`` Sobol points
   (in total, for the whole search) become thin systems at once, ``seidel_steps`` batched Adam
   steps refine them on their third-order RMS spot, and the best distinct ones, thickened and
   ranked again by the thick lens's third-order RMS, are the ``starts`` starts
   (:func:`~.screen.screened_starts`); with ``seidel_rebalance = K > 0`` (default 300; 0: off)
   every thickened system also gets ``K`` batched Adam steps on its own third-order merit
   (curvatures and distances, :mod:`.thick_polish`), which the thickening of strong
   elements upsets; ``seidel_rebalance_floor="thin"`` (default): no gain below the thin
   system's own third-order RMS (``"none"``: none).  ``seidel_ranking="union"`` (default):
   the best ``starts`` of the plain ranking and the best ``starts`` of the re-balanced
   ranking are refined, each start once (up to ``2 starts``; re-balancing brings the Cooke
   triplet's best starts to the top and pushes the double Gauss's off it);
   ``"rebalanced"``: the re-balanced ranking's best ``starts`` alone.
2. **Screen.**  Each start is refined briefly (``screen`` stages, coarse pupil sampling) and
   scored by :func:`~.result.evaluate` on finer rays (``score_sampling``): feasible designs
   first, then by the polychromatic RMS spot.
3. **De-duplicate.**  Two designs are the same when they have the same glasses and their
   signatures (every curvature times ``f``, every gap and the sensor distance over ``f``)
   differ by less than ``dedup_tol`` everywhere: DLS from neighbouring starts ends in the same
   basin, and polishing it twice buys nothing.
4. **Polish.**  The best ``polish_count`` distinct designs are refined longer on finer rays
   (``polish``), with aspheric terms on the ``spec.aspheres`` most bent surfaces if allowed.
5. **Basin hopping** (Wales and Doye 1997): ``hops`` times, the current design's scaled
   variables (mm of sag at the rim, mm of gap) are kicked by ``hop_size`` x a standard normal
   vector (up to 5 tries for a valid lens, each kick half the last), gaps whose centre or edge
   then falls short widened (:func:`~.refine.repair_edges`: a design resting on its edge
   limits crosses under any kick), the focal length restored by the angle solve, and
   the result refined (``hop``);
   it replaces the current design when it scores better (greedy; ``temperature > 0`` accepts a
   worse one with probability ``exp(-Δ / T)``, Δ in µm of RMS spot).
6. **Keep** the best ``keep`` distinct designs; each is refined on the final rays
   (``final_sampling``) until converged (:func:`~.refine.refine_to_convergence`: rounds of
   ``converge_chunk`` DLS steps until two rounds in a row each lower the merit by less than
   ``converge_tol`` of it, at most ``converge_steps`` steps; 0, the default here: off; the
   command and the benchmark use 120), then gets its focal
   length made exact (:func:`~.start.solve_efl`), semi-diameters fitted to its beam and a
   dense evaluation; the converged design replaces the design as found only if it scores
   better.
7. **Glass substitution** (a spec with ``glass_mode="model"`` only).  Every start's glasses
   become :class:`~.glass.TrainableModelGlass` (normal-line dispersion) at the start's
   ``(n_d, V_d)`` projected into the :class:`~.glass_region.GlassRegion` of the spec's
   catalogues (radius ``glass_radius``); every refinement varies their ``n_d`` and ``V_d``
   with the region's penalty in the merit and projects them back onto the region after each
   stage.  Each kept design's model glasses are then replaced by real glasses of those
   catalogues (:func:`~.glass.substitute_glasses`: the ``substitute_k`` nearest per element,
   every combination up to 27, else one element at a time), each candidate re-optimised
   (``substitute`` stages) and scored as in step 2; the best candidate, finished as in step 6,
   replaces the model design.  Its ``glass_record`` keeps the model glasses, the glasses put
   in, both RMS spots and every candidate tried.  ``substitute_radius`` (default ``None``: the
   search's region): before substitution the model glasses are projected into a region of
   this radius and the model design is re-optimised there (``substitute`` stages), so that
   substitution starts from glasses within that distance of real ones.
   ``substitution="snap"``: before substitution a copy of the model design is re-optimised
   ``snap_count`` times (``snap_stage``) with a growing pull of each model glass onto its
   nearest real glass (:func:`~.glass.snap_model_glasses`, strengths
   :func:`~.glass.snap_strengths` of the design's merit), and the substitution starts from
   it.  ``rank_keep > 0``: the ``rank_k`` nearest glasses per element are combined, ranked by
   a linearised re-optimisation (:func:`~.substitution.linearised_ranker`: the candidate's
   exact residuals at the design's geometry, projected off the geometry Jacobian) and only
   the ``rank_keep`` best are re-optimised.  ``substitute_strategy="sequential"``: one element
   at a time instead, the most sensitive first, the remaining model glasses free
   (:func:`~.glass.substitute_sequentially`).  ``"combined"`` (the default): the sequential
   candidates and a ranked joint set (every combination of the ``combined_k`` nearest per
   element, at most :data:`~.glass.RANK_CAP` of them, ranked by the linearised
   re-optimisation; the ``combined_keep`` best re-optimised), the lower merit kept
   (:func:`~.glass.substitute_combined`).  The reference of the comparison is the model
   design *converged* (rounds of ``substitute`` stages until one improves its RMS spot by less
   than ``converge_tol``, at most ``converge_rounds``), and the kept real candidate is
   converged by the same rule (:mod:`.glass_stage`).

``time_limit_s``: no new start, polish or hop begins once this much wall time has passed
(the one under way finishes, the designs found so far are kept and finished; glass
substitution still runs).  Everything random comes from ``seed`` (the Sobol scrambling and a ``torch.Generator`` for the
hops), and the arithmetic is float64 on the CPU, so a seed reproduces its designs.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field

import torch

from .glass import TrainableModelGlass, use_model_glasses
from .problem import search_variables
from .refine import (CURRICULUM, STANDARD, Stage, aspheric_choice, fit_semi_diameters, refine,
                     refine_to_convergence, repair_edges)
from .result import evaluate
from .spec import DesignSpec
from .start import StartError, flat_start, solve_efl, start_dimensions, thin_lens_start

__all__ = ["SearchConfig", "Design", "SearchResult", "search", "signature", "same_design",
           "deduplicate", "substitute_design"]

START_KINDS = ("thin", "flat", "mixed")
SUBSTITUTIONS = ("nearest", "snap")
SUBSTITUTE_STRATEGIES = ("joint", "sequential", "combined")
REBALANCE_FLOORS = ("thin", "none")
SEIDEL_RANKINGS = ("union", "rebalanced")   # screen.RANKINGS (not imported: screen is lazy)


@dataclass
class SearchConfig:
    """The search budget and strategy (module docstring)."""

    starts: int = 16
    start_kind: str = "thin"
    screen: tuple = STANDARD
    flat_screen: tuple = CURRICULUM
    score_sampling: str = "hexapolar:6"
    polish_count: int = 3
    polish: tuple = (Stage(30, "hexapolar:6", rounds=2),)
    hops: int = 6
    hop_size: float = 0.5
    hop: tuple = (Stage(20, "hexapolar:6"),)
    temperature: float = 0.0
    keep: int = 3
    dedup_tol: float = 0.02
    seed: int = 0
    final_sampling: str = "hexapolar:12"
    prescreen: int = 0
    prescreen_stage: tuple = (Stage(4, "hexapolar:3"),)
    prescreen_sampling: str = "hexapolar:4"
    substitute_k: int = 2
    substitute: tuple = (Stage(15, "hexapolar:6"),)
    glass_radius: float = 0.03
    substitute_radius: float | None = None
    substitution: str = "nearest"
    snap_stage: tuple = (Stage(5, "hexapolar:6"),)
    snap_count: int = 6
    rank_keep: int = 0
    rank_k: int = 4
    substitute_strategy: str = "combined"
    converge_tol: float = 0.01
    converge_rounds: int = 8
    time_limit_s: float | None = None
    seidel_screen: int = 0
    seidel_steps: int = 100
    seidel_rebalance: int = 300
    seidel_rebalance_floor: str = "thin"
    seidel_ranking: str = "union"
    converge_steps: int = 0
    converge_chunk: int = 10
    combined_k: int = 6
    combined_keep: int = 6

    def __post_init__(self):
        if self.start_kind not in START_KINDS:
            raise ValueError(f"start_kind must be one of {', '.join(START_KINDS)}, got "
                             f"{self.start_kind!r}")
        if self.substitute_radius is not None and not (
                math.isfinite(float(self.substitute_radius))
                and float(self.substitute_radius) > 2 * 1e-4):
            raise ValueError(f"substitute_radius must be None or a finite number > 0.0002, got "
                             f"{self.substitute_radius!r}")
        if self.substitution not in SUBSTITUTIONS:
            raise ValueError(f"substitution must be one of {', '.join(SUBSTITUTIONS)}, got "
                             f"{self.substitution!r}")
        if self.substitute_strategy not in SUBSTITUTE_STRATEGIES:
            raise ValueError(f"substitute_strategy must be one of "
                             f"{', '.join(SUBSTITUTE_STRATEGIES)}, got "
                             f"{self.substitute_strategy!r}")
        if not (math.isfinite(float(self.converge_tol)) and float(self.converge_tol) >= 0):
            raise ValueError(f"converge_tol must be a finite number >= 0, got "
                             f"{self.converge_tol!r}")
        if int(self.converge_rounds) < 0:
            raise ValueError(f"converge_rounds must be >= 0, got {self.converge_rounds!r}")
        if self.time_limit_s is not None and not float(self.time_limit_s) > 0:
            raise ValueError(f"time_limit_s must be None or > 0, got {self.time_limit_s!r}")
        if int(self.seidel_screen) < 0 or int(self.seidel_steps) < 0:
            raise ValueError(f"seidel_screen and seidel_steps must be >= 0, got "
                             f"{self.seidel_screen!r}, {self.seidel_steps!r}")
        if int(self.seidel_rebalance) < 0:
            raise ValueError(f"seidel_rebalance must be >= 0, got {self.seidel_rebalance!r}")
        if self.seidel_rebalance_floor not in REBALANCE_FLOORS:
            raise ValueError(f"seidel_rebalance_floor must be one of "
                             f"{', '.join(REBALANCE_FLOORS)}, got {self.seidel_rebalance_floor!r}")
        if self.seidel_ranking not in SEIDEL_RANKINGS:
            raise ValueError(f"seidel_ranking must be one of {', '.join(SEIDEL_RANKINGS)}, got "
                             f"{self.seidel_ranking!r}")
        if int(self.seidel_screen) and (self.prescreen or self.start_kind != "thin"):
            raise ValueError("seidel_screen needs start_kind='thin' and prescreen=0 (it "
                             "chooses the thin-lens starts itself)")
        if int(self.converge_steps) < 0 or int(self.converge_chunk) < 1 or not (
                math.isfinite(float(self.converge_tol)) and float(self.converge_tol) >= 0):
            raise ValueError(f"converge_steps must be >= 0, converge_chunk >= 1 and "
                             f"converge_tol a finite number >= 0, got {self.converge_steps!r}, "
                             f"{self.converge_chunk!r}, {self.converge_tol!r}")
        if int(self.prescreen) < 0:
            raise ValueError(f"prescreen must be >= 0, got {self.prescreen!r}")
        if int(self.rank_keep) < 0:
            raise ValueError(f"rank_keep must be >= 0, got {self.rank_keep!r}")
        for name in ("starts", "keep", "polish_count", "substitute_k", "rank_k", "combined_k",
                     "combined_keep"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if not (math.isfinite(float(self.glass_radius)) and float(self.glass_radius) > 0):
            raise ValueError(f"glass_radius must be a finite number > 0, got "
                             f"{self.glass_radius!r}")
        if int(self.hops) < 0 or not (self.hop_size >= 0 and self.temperature >= 0):
            raise ValueError(f"hops, hop_size and temperature must be >= 0, got {self.hops!r}, "
                             f"{self.hop_size!r}, {self.temperature!r}")

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        for k in ("screen", "flat_screen", "polish", "hop", "substitute", "prescreen_stage",
                  "snap_stage"):
            d[k] = [s.__dict__ for s in d[k]]
        return d


@dataclass
class Design:
    """A design: the lens (float64), its score (:func:`~.result.evaluate`), where it came from
    (``"start 3"``, ``"hop 2"``), its signature (:func:`signature`), its media's names
    (``"model"`` for a model glass) and, after glass substitution, ``glass_record``
    (module docstring, step 7)."""

    lens: object
    metrics: dict
    origin: str
    signature: torch.Tensor = None
    glasses: tuple = ()
    glass_record: dict | None = None

    @property
    def key(self):
        """Sort key: feasible first, then RMS spot."""
        return (not self.metrics["feasible"], self.metrics["rms_um"])


@dataclass
class SearchResult:
    """The kept designs (best first), one record per refinement (``runs``), the time."""

    designs: list
    runs: list = field(default_factory=list)
    seconds: float = 0.0
    config: SearchConfig | None = None
    starts_tried: int = 0

    @property
    def best(self) -> Design:
        return self.designs[0]

    def to_dict(self) -> dict:
        return {"best": self.designs[0].metrics if self.designs else None,
                "designs": [{"origin": d.origin, "glasses": list(d.glasses), **d.metrics,
                             **({"glass_substitution": d.glass_record} if d.glass_record
                                else {})}
                            for d in self.designs],
                "runs": [{k: v for k, v in r.items() if k != "history"} for r in self.runs],
                "seconds": self.seconds, "starts_tried": self.starts_tried,
                "config": self.config.to_dict() if self.config else None}


def signature(lens, efl: float) -> torch.Tensor:
    """Curvatures x ``f``, gaps / ``f`` and sensor distance / ``f`` (dimensionless), then the
    ``n_d`` and ``V_d / 100`` of every trainable model glass (glass-map units)."""
    from .problem import real_surfaces

    with torch.no_grad():
        c = [float(lens.surfaces[i].c) * efl for i in real_surfaces(lens)]
        real = real_surfaces(lens)
        z = lens.z_vertices()
        gaps = [float(z[q] - z[p]) / efl for p, q in zip(real, real[1:])]
        glass = [x for m in lens.materials if isinstance(m, TrainableModelGlass)
                 for x in (m.values()[0], 0.01 * m.values()[1])]
        return torch.tensor(c + gaps + [float(lens.d_sensor) / efl] + glass,
                            dtype=torch.float64)


def _glasses(lens) -> tuple:
    return tuple("model" if isinstance(m, TrainableModelGlass) else m.name
                 for m in lens.materials)


def same_design(a: Design, b: Design, tol: float) -> bool:
    """Module docstring, step 3."""
    return (a.glasses == b.glasses and a.signature.shape == b.signature.shape
            and float((a.signature - b.signature).abs().max()) < tol)


def deduplicate(designs, tol: float) -> list:
    """The designs sorted best first, each kept only if no better one is the same."""
    out = []
    for d in sorted(designs, key=lambda d: d.key):
        if not any(same_design(d, k, tol) for k in out):
            out.append(d)
    return out


def _score(lens, spec, origin, sampling) -> Design:
    m = evaluate(lens, spec, sampling)
    return Design(lens, m, origin, signature(lens, spec.efl_mm), _glasses(lens))


def _finish(lens, spec, origin, cfg) -> Design:
    """Step 6 on ``lens`` (in place): exact focal length, fitted semi-diameters, edges, name,
    dense evaluation."""
    solve_efl(lens, spec.efl_mm)
    fit_semi_diameters(lens, spec.fields_deg, spec.wavelengths_nm)
    repair_edges(lens, spec)
    lens.check()
    lens.name = (f"design search: {spec.elements} element(s), f {spec.efl_mm:g} mm "
                 f"F/{spec.f_number:.3g}, HFOV {spec.hfov_deg:g} deg ({origin}, "
                 f"seed {cfg.seed})")
    return _score(lens, spec, origin, cfg.final_sampling)


def substitute_design(dsg: Design, spec: DesignSpec, cfg: SearchConfig,
                      region=None) -> Design:
    """Step 7 of the module docstring on one finished model-glass design: the real-glass
    design (finished), with its ``glass_record`` (:func:`~.glass_stage.substitute_design`:
    the model design converged first, so that the two merits compared are both converged).

    Raises:
        RuntimeError: no candidate could be re-optimised.
    """
    from .glass_stage import substitute_design as run

    return run(dsg, spec, cfg, region, _finish)


def search(spec: DesignSpec, config: SearchConfig | None = None, *, glass_strategy=None,
           progress=None, model_designs=None) -> SearchResult:
    """Design lenses for ``spec`` (module docstring).

    Args:
        spec: the :class:`~.spec.DesignSpec`.
        config: the :class:`SearchConfig` (budget, seed).
        glass_strategy: ``(glasses, signs, u) -> [glass per element]`` for the starts (default
            :func:`~.start.crown_flint_by_sign`): the hook where glass handling plugs in.
        progress: ``progress(text)`` called after each refinement (a progress indicator).
        model_designs: ``model_designs(designs)`` called with the kept, finished model-glass
            designs (:class:`Design`, best first) just before their glass substitution (a spec
            with ``glass_mode="model"`` only): a hook to save them and re-run only the
            substitution (``benchmarks/design_search.py --save-models``).

    Returns:
        :class:`SearchResult` with up to ``config.keep`` distinct designs, best first.

    Raises:
        RuntimeError: no start gave a lens that could be refined (the message says why the
            first few failed).
    """
    cfg = config or SearchConfig()
    t0 = time.perf_counter()
    say = progress or (lambda text: None)
    runs, pool = [], []
    d = start_dimensions(spec.elements)
    sobol = torch.quasirandom.SobolEngine(d, scramble=True, seed=int(cfg.seed))
    gen = torch.Generator().manual_seed(int(cfg.seed))
    tried, made = 0, 0
    region = None
    if spec.glass_mode == "model":
        from .glass_region import GlassRegion

        region = GlassRegion(spec.catalogues, radius=cfg.glass_radius)
    def fresh(limit):
        """``(index, kind, lens, flat)`` of each new start that gives a lens."""
        nonlocal tried
        while tried < limit:
            u = sobol.draw(1, dtype=torch.float64)[0]
            kind = cfg.start_kind if cfg.start_kind != "mixed" else ("thin", "flat")[tried % 2]
            tried += 1
            try:
                lens = (thin_lens_start if kind == "thin" else flat_start)(
                    spec, u, glass_strategy=glass_strategy)
            except StartError as e:
                runs.append({"origin": f"start {tried - 1}", "kind": kind, "ok": False,
                             "reason": f"no lens: {e}", "seconds": 0.0})
                continue
            if region is not None:
                use_model_glasses(lens, region=region)
            yield tried - 1, kind, lens, kind == "flat"

    def out_of_time() -> bool:
        return cfg.time_limit_s is not None and time.perf_counter() - t0 > cfg.time_limit_s

    source = fresh(4 * cfg.starts)
    budget = int(cfg.starts)   # starts refined (the screen's union may give up to 2 x)
    if cfg.seidel_screen > 0:   # step 1c: starts from the third-order screen
        from .screen import screened_starts

        got, info = screened_starts(spec, int(cfg.seidel_screen), cfg.starts, seed=cfg.seed,
                                    steps=int(cfg.seidel_steps), glass_strategy=glass_strategy,
                                    rebalance=int(cfg.seidel_rebalance),
                                    rebalance_floor=cfg.seidel_rebalance_floor,
                                    ranking=cfg.seidel_ranking)
        runs.append(info)
        tried = info["sampled"]
        say(f"third-order screen: {info['sampled']} systems, {len(got)} starts at "
            + ", ".join(f"{x:.0f}" for x in info["thick_rms_um"]) + " um (third order); "
            + f"{info['seconds']:.0f} s")
        if region is not None:
            for _, lens in got:
                use_model_glasses(lens, region=region)
        source = iter([(label, "thin", lens, False) for label, lens in got])
        budget = max(budget, len(got))
    if cfg.prescreen > cfg.starts:   # step 1b: the best `starts` of `prescreen` cheap runs
        cands = []
        for idx, kind, lens, flat in fresh(4 * cfg.prescreen):
            r = refine(lens, spec, cfg.prescreen_stage, flat=flat, glass_region=region)
            rec = {"origin": f"start {idx}", "kind": kind, "prescreen": True, "ok": r.ok,
                   "reason": r.reason, "seconds": r.seconds, "steps": r.steps}
            if r.ok:
                try:
                    m = evaluate(lens, spec, cfg.prescreen_sampling)
                    rec["rms_um"] = m["rms_um"]
                    cands.append((m["rms_um"] + (0.0 if m["feasible"] else 1e6), idx, kind,
                                  lens))
                except (ValueError, RuntimeError) as e:
                    rec["ok"], rec["reason"] = False, f"evaluation: {e}"
            runs.append(rec)
            if len(cands) >= cfg.prescreen or out_of_time():
                break
        cands.sort(key=lambda c: (c[0], c[1]))
        say(f"prescreen: {len(cands)} starts, best "
            + ", ".join(f"{c[0]:.0f}" for c in cands[:cfg.starts]) + " um"
            + f"; {time.perf_counter() - t0:.0f} s")
        source = iter([(idx, kind, lens, False) for _, idx, kind, lens in cands[:cfg.starts]])
    for idx, kind, lens, flat in source:
        made += 1
        r = refine(lens, spec, cfg.screen if kind == "thin" else cfg.flat_screen,
                   flat=flat, glass_region=region)
        rec = {"origin": f"start {idx}", "kind": kind, "ok": r.ok, "reason": r.reason,
               "seconds": r.seconds, "history": r.history, "steps": r.steps}
        if r.ok:
            try:
                dsg = _score(lens, spec, f"start {idx} ({kind})", cfg.score_sampling)
                pool.append(dsg)
                rec["rms_um"] = dsg.metrics["rms_um"]
            except (ValueError, RuntimeError) as e:
                rec["ok"], rec["reason"] = False, f"evaluation: {e}"
        runs.append(rec)
        best = min((p.metrics["rms_um"] for p in pool), default=math.inf)
        say(f"start {made}/{budget} ({kind}): "
            + (f"{rec['rms_um']:.2f} um" if "rms_um" in rec else f"failed ({rec['reason'][:60]})")
            + f"; best {best:.2f} um; {time.perf_counter() - t0:.0f} s")
        if made >= budget or out_of_time():   # before the next draw
            break
    if not pool:
        why = "; ".join(r["reason"][:120] for r in runs[:3])
        raise RuntimeError(f"design search: none of {tried} starts gave a refinable lens "
                           f"({why})")
    # polish the best distinct designs
    polished = []
    for k, dsg in enumerate(deduplicate(pool, cfg.dedup_tol)[:cfg.polish_count]):
        if out_of_time():
            break
        lens = copy.deepcopy(dsg.lens)
        asph = aspheric_choice(lens, spec.aspheres) if spec.aspheres else ()
        r = refine(lens, spec, cfg.polish, aspheric_surfaces=asph, glass_region=region)
        rec = {"origin": f"polish {k} of {dsg.origin}", "ok": r.ok, "reason": r.reason,
               "seconds": r.seconds, "history": r.history, "steps": r.steps}
        if r.ok:
            p = _score(lens, spec, f"{dsg.origin}, polished", cfg.score_sampling)
            polished.append(p)
            rec["rms_um"] = p.metrics["rms_um"]
        runs.append(rec)
        say(f"polish {k + 1}: {rec.get('rms_um', math.nan):.2f} um ({dsg.origin}; "
            f"{r.steps} steps, {r.reason[:70]})")
    pool += polished
    # basin hopping from the best design
    current = deduplicate(pool, cfg.dedup_tol)[0]
    asph = aspheric_choice(current.lens, spec.aspheres) if spec.aspheres else ()
    for h in range(int(cfg.hops)):
        if out_of_time():
            break
        rec = {"origin": f"hop {h} from {current.origin}", "ok": False}
        for attempt in range(5):   # up to 5 kicks, each half the last, for a valid lens
            lens = copy.deepcopy(current.lens)
            size = cfg.hop_size * 0.5 ** attempt
            rec["kick"] = size
            try:
                v = search_variables(lens, asph, efl_solve=True)
                x = v.x0() + size * torch.randn(len(v), generator=gen, dtype=torch.float64)
                v.assign(x)
                repair_edges(lens, spec)   # a design on its edge limits crosses under a kick
                lens.check()
                solve_efl(lens, spec.efl_mm)
                lens.check()
                break
            except (ValueError, RuntimeError) as e:
                rec["reason"] = f"kick: {e}"
                lens = None
        if lens is None:
            runs.append(rec)
            say(f"hop {h + 1}/{cfg.hops}: 5 kicks left the feasible region")
            continue
        r = refine(lens, spec, cfg.hop, aspheric_surfaces=asph, glass_region=region)
        rec.update(ok=r.ok, reason=r.reason, seconds=r.seconds, history=r.history, steps=r.steps)
        accepted = False
        if r.ok:
            try:
                p = _score(lens, spec, f"hop {h}", cfg.score_sampling)
            except (ValueError, RuntimeError) as e:
                rec["ok"], rec["reason"] = False, f"evaluation: {e}"
            else:
                pool.append(p)
                rec["rms_um"] = p.metrics["rms_um"]
                delta = p.metrics["rms_um"] - current.metrics["rms_um"]
                if p.key < current.key:
                    accepted = True
                elif cfg.temperature > 0 and p.metrics["feasible"] >= current.metrics["feasible"]:
                    accepted = float(torch.rand(1, generator=gen)) < math.exp(
                        -delta / cfg.temperature)
                if accepted:
                    current = p
        rec["accepted"] = accepted
        runs.append(rec)
        feas = "" if not rec.get("ok") or "rms_um" not in rec else (
            "" if pool[-1].metrics["feasible"] else " (infeasible: "
            + "; ".join(pool[-1].metrics["constraints_broken"])[:60] + ")")
        say(f"hop {h + 1}/{cfg.hops}: {rec.get('rms_um', math.nan):.2f} um{feas}"
            f"{' (accepted)' if accepted else ''}; current {current.metrics['rms_um']:.2f} um")
    # keep the best distinct designs, each refined to convergence on the final rays, finished
    kept = []
    for dsg in deduplicate(pool, cfg.dedup_tol):
        if len(kept) >= cfg.keep:
            break
        try:
            done = _finish(copy.deepcopy(dsg.lens), spec, dsg.origin, cfg)
        except (ValueError, RuntimeError):
            continue
        if cfg.converge_steps > 0 and not out_of_time():
            plain = done.metrics["rms_um"]
            lens = copy.deepcopy(dsg.lens)
            r = refine_to_convergence(lens, spec, cfg.final_sampling, tol=cfg.converge_tol,
                                      max_steps=int(cfg.converge_steps),
                                      chunk=int(cfg.converge_chunk),
                                      aspheric_surfaces=aspheric_choice(lens, spec.aspheres)
                                      if spec.aspheres else (), glass_region=region)
            rec = {"origin": f"converge {dsg.origin}", "ok": r.ok, "reason": r.reason,
                   "seconds": r.seconds, "history": r.history, "steps": r.steps}
            if r.ok:
                try:
                    conv = _finish(lens, spec, f"{dsg.origin}, converged", cfg)
                    rec["rms_um"] = conv.metrics["rms_um"]
                    if conv.key < done.key:
                        done = conv
                except (ValueError, RuntimeError) as e:
                    rec["ok"], rec["reason"] = False, f"evaluation: {e}"
            runs.append(rec)
            say(f"converge: {rec.get('rms_um', math.nan):.2f} um from {plain:.2f} um "
                f"({dsg.origin}; {r.steps} steps, {r.reason})")
        kept.append(done)
    kept.sort(key=lambda d: d.key)
    if region is not None:   # step 7: real glasses for every kept model-glass design
        if model_designs is not None:
            model_designs(kept)
        real = []
        for k, dsg in enumerate(kept):
            t1 = time.perf_counter()
            try:
                r = substitute_design(dsg, spec, cfg, region)
            except (ValueError, RuntimeError) as e:
                runs.append({"origin": f"substitution of {dsg.origin}", "ok": False,
                             "reason": f"{type(e).__name__}: {e}",
                             "seconds": time.perf_counter() - t1})
                say(f"substitution {k + 1}/{len(kept)} failed: {str(e)[:80]}")
                continue
            real.append(r)
            g = r.glass_record
            runs.append({"origin": f"substitution of {dsg.origin}", "ok": True,
                         "reason": "", "seconds": g["seconds"], "rms_um": g["real_rms_um"],
                         "model_rms_um": g["model_rms_um"]})
            say(f"substitution {k + 1}/{len(kept)}: model {g['model_rms_um']:.2f} um -> "
                f"{', '.join(g['substituted'].values())}: {g['real_rms_um']:.2f} um "
                f"({len(g['candidates'])} candidates, {g['seconds']:.0f} s)")
        if kept and not real:
            raise RuntimeError("design search: glass substitution failed for every kept "
                               "design (" + "; ".join(r["reason"][:120] for r in runs[-2:])
                               + ")")
        kept = sorted(real, key=lambda d: d.key)
    return SearchResult(kept, runs, time.perf_counter() - t0, cfg, tried)
