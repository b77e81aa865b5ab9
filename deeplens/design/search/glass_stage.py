r"""Step 7 of the search (:mod:`.multistart`): a finished model-glass design becomes a
real-glass design, and the two are compared fairly (issue 36, item 4).

1. **The reference.**  The model design (model glasses free in the search's glass region) is
   re-optimised in rounds of the ``substitute`` stages until a round improves its RMS spot
   (``score_sampling``) by less than ``converge_tol`` (relative), or ``converge_rounds``
   rounds (:func:`~.converge.until_converged`).  The search leaves its designs after a fixed
   number of steps, often short of convergence (a Cooke design went on from 115.8 to 84 µm
   under the substitution's own steps), so the unconverged merit would flatter any
   substitution that spends steps.  The converged design, finished, is the reference:
   ``model_rms_um`` of the record; the search's own is ``model_rms_unconverged_um``.
2. **Snapping** (``substitution="snap"``): a copy of the reference is pulled onto real glasses
   (:func:`~.glass.snap_model_glasses`).
3. **Candidates.**  ``substitute_strategy="joint"``: the ``substitute_k`` nearest real glasses
   per element, every combination up to 27, else one element at a time
   (:func:`~.glass.substitute_glasses`), each candidate re-optimised (``substitute`` stages,
   geometry only).  ``"sequential"``: one element at a time, the most sensitive first, each of
   its ``substitute_k`` nearest glasses re-optimised with the remaining model glasses free in
   the region (:func:`~.glass.substitute_sequentially`).  ``rank_keep > 0`` ranks the
   ``rank_k`` nearest by a linearised re-optimisation first (joint only).  ``"combined"``
   (the default): the sequential candidates and a ranked joint set, every combination of
   the ``combined_k`` nearest per element (fewer when there are more than
   :data:`~.glass.RANK_CAP` combinations) ranked by the linearised re-optimisation
   (:func:`~.substitution.linearised_ranker`) and the ``combined_keep`` best re-optimised;
   the lower merit is kept (:func:`~.glass.substitute_combined`).
4. **The same convergence for the kept candidate**: rounds of the ``substitute`` stages under
   the same rule, then the design is finished (exact focal length, semi-diameters, dense
   evaluation).  ``merit_loss = real_rms_um / model_rms_um - 1``.
"""

from __future__ import annotations

import copy
import time
from typing import Callable

from .converge import until_converged
from .glass import (TrainableModelGlass, project_model_glasses, snap_model_glasses,
                    snap_strengths, substitute_combined, substitute_glasses,
                    substitute_sequentially)
from .refine import refine
from .result import evaluate
from .spec import DesignSpec

__all__ = ["substitute_design", "converge_design"]

#: added to the RMS spot (µm) of a design that breaks a constraint, so that any feasible
#: design ranks first
INFEASIBLE_UM = 1e6


def _score(lens, spec: DesignSpec, sampling: str) -> float:
    m = evaluate(lens, spec, sampling)
    return m["rms_um"] + (0.0 if m["feasible"] else INFEASIBLE_UM)


def _refined(lens, spec, stages, glass_region=None) -> None:
    r = refine(lens, spec, stages, glass_region=glass_region)
    if not r.ok:
        raise RuntimeError(r.reason)


def converge_design(lens, spec: DesignSpec, cfg, glass_region=None):
    """:func:`~.converge.until_converged` of ``lens`` (not modified) under rounds of
    ``cfg.substitute`` (:func:`~.refine.refine`, model glasses free in ``glass_region`` when
    given), scored by the RMS spot on ``cfg.score_sampling`` (µm, + ``INFEASIBLE_UM`` when
    infeasible), ``cfg.converge_tol``, ``cfg.converge_rounds``; its ``state`` is the best
    lens (a copy when a round was kept).

    Raises:
        ValueError, RuntimeError: ``lens`` itself cannot be evaluated.
    """
    def step(trial) -> float:
        _refined(trial, spec, cfg.substitute, glass_region)
        return _score(trial, spec, cfg.score_sampling)

    return until_converged(lens, step, _score(lens, spec, cfg.score_sampling),
                           cfg.converge_tol, cfg.converge_rounds)


def substitute_design(dsg, spec: DesignSpec, cfg, region, finish: Callable):
    """The module docstring's steps on one finished model-glass design
    (:class:`~.multistart.Design`): the real-glass design (finished), with its
    ``glass_record``.  Without ``region`` (the search's glass region) step 1 is skipped and
    the design's own merit is the reference (the record says so: ``model_converged``
    False).  ``finish(lens, spec, origin, cfg) -> Design`` finishes a lens in place (the
    search's step 6).

    Raises:
        RuntimeError: no candidate could be re-optimised.
    """
    _finish = finish
    t0 = time.perf_counter()
    ref, conv, converged, err = dsg, None, False, ""
    if region is not None:
        lens = copy.deepcopy(dsg.lens)
        opt_region = region
        if cfg.substitute_radius is not None:   # pull the glasses towards real ones first
            from .glass_region import GlassRegion

            opt_region = GlassRegion(spec.catalogues, radius=cfg.substitute_radius)
            project_model_glasses(lens, opt_region)
        try:
            conv = converge_design(lens, spec, cfg, opt_region)
            d2 = _finish(copy.deepcopy(conv.state), spec, dsg.origin, cfg)
        except (ValueError, RuntimeError) as e:
            d2, err = None, f"{type(e).__name__}: {e}"
        # the reference is the better of the two (the search's design, finished, can score
        # a little better on the dense rays than the converged one)
        converged = d2 is not None
        if d2 is not None and (cfg.substitute_radius is not None or d2.key <= dsg.key):
            ref = d2
        region = opt_region
    model = {i: m.values() for i, m in enumerate(ref.lens.materials)
             if isinstance(m, TrainableModelGlass)}

    def reoptimize(cand) -> float:
        _refined(cand, spec, cfg.substitute)
        return _score(cand, spec, cfg.score_sampling)

    def reoptimize_free(cand) -> float:   # the remaining model glasses free in the region
        _refined(cand, spec, cfg.substitute, region)
        return _score(cand, spec, cfg.score_sampling)

    base, snap_rows = ref.lens, []
    if cfg.substitution == "snap" and region is not None:   # pull the glasses onto real ones
        lens = copy.deepcopy(ref.lens)
        merit0 = sum(spec.weights_of_fields) * (ref.metrics["rms_um"] / 1000.0) ** 2
        try:
            snap_rows = snap_model_glasses(
                lens, region, lambda L, pull: _refined(L, spec, cfg.snap_stage, pull),
                snap_strengths(merit0, cfg.snap_count))
            base = lens
        except (ValueError, RuntimeError) as e:
            snap_rows = [{"error": f"{type(e).__name__}: {e}"}]
    rank = None
    if cfg.substitute_strategy == "combined":
        from .substitution import linearised_ranker

        try:
            rank = linearised_ranker(base, spec, cfg.score_sampling)
        except (ValueError, RuntimeError):   # no prediction: the sequential set alone
            rank = None
    if rank is not None:
        sub = substitute_combined(base, spec.catalogues, reoptimize_free, reoptimize, rank,
                                  k=cfg.substitute_k, rank_k=cfg.combined_k,
                                  rank_keep=cfg.combined_keep,
                                  score=lambda L: _score(L, spec, cfg.score_sampling))
    elif cfg.substitute_strategy in ("sequential", "combined") and region is not None:
        sub = substitute_sequentially(base, spec.catalogues, reoptimize_free,
                                      k=cfg.substitute_k,
                                      score=lambda L: _score(L, spec, cfg.score_sampling))
    elif cfg.rank_keep > 0:   # rank the rank_k nearest by a linearised re-optimisation
        from .substitution import linearised_ranker

        sub = substitute_glasses(base, spec.catalogues, reoptimize, k=cfg.rank_k,
                                 rank=linearised_ranker(base, spec, cfg.score_sampling),
                                 rank_keep=cfg.rank_keep)
    else:
        sub = substitute_glasses(base, spec.catalogues, reoptimize, k=cfg.substitute_k)
    # the kept candidate converged under the same rule as the reference
    real_conv = None
    if sub.merit > 0:
        real_conv = until_converged(sub.lens, reoptimize, sub.merit, cfg.converge_tol,
                                    max_rounds=cfg.converge_rounds)
    real_lens = real_conv.state if real_conv is not None else sub.lens
    try:
        real = _finish(copy.deepcopy(real_lens), spec, f"{dsg.origin}, real glasses", cfg)
    except (ValueError, RuntimeError):   # finish the candidate as it came out instead
        real_conv = None
        real = _finish(sub.lens, spec, f"{dsg.origin}, real glasses", cfg)
    model_rms, real_rms = ref.metrics["rms_um"], real.metrics["rms_um"]
    real.glass_record = {
        "catalogues": list(spec.catalogues), "dispersion": "normal",
        "model_glasses": {str(i): {"n_d": nd, "v_d": vd} for i, (nd, vd) in model.items()},
        # how far each model glass of the reference is from the nearest real glass (δ; the
        # region's radius is the most it can be): what no substitution can give back
        "model_glass_distance": ({str(i): float(region.nearest(nd, vd)[1])
                                  for i, (nd, vd) in model.items()}
                                 if region is not None else None),
        "substituted": {str(i): g.label for i, g in sub.chosen.items()},
        "model_rms_um": model_rms, "model_feasible": ref.metrics["feasible"],
        "model_rms_poly_um": ref.metrics["rms_poly_um"],
        "model_rms_unconverged_um": dsg.metrics["rms_um"], "model_converged": converged,
        "model_convergence": (dict(conv.to_dict(), error=err) if conv is not None
                              else ({"error": err} if region is not None else None)),
        "real_convergence": real_conv.to_dict() if real_conv is not None else None,
        "real_rms_um": real_rms, "merit_loss": real_rms / model_rms - 1.0,
        "strategy": sub.strategy, "seconds": time.perf_counter() - t0,
        "substitution": cfg.substitution, "substitute_strategy": cfg.substitute_strategy,
        "snap": snap_rows,
        "candidates": [{"glasses": {str(i): g for i, g in row["glasses"].items()},
                        "score_um": row["merit"], "error": row["error"], "kept": row["kept"],
                        **({"predicted": row["predicted"]} if "predicted" in row else {}),
                        **({"step": row["step"]} if "step" in row else {}),
                        **({"part": row["part"]} if "part" in row else {})}
                       for row in sub.table]}
    return real
