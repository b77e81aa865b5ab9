"""A refinement's end (deeplens.design.search.refine): the stop placed back between its
neighbours after a stage (the projection onto the ``stop_gap`` constraints), a centre
thickness past its limit projected onto it, and the stop rule of a polish run to convergence
(against a sequence whose stopping point is known in closed form, and damped least squares on
a problem whose minimum is known)."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import torch

from deeplens.design.constraints import ConstraintSet
from deeplens.design.optimizers import damped_least_squares
from deeplens.design.search import DesignSpec, SearchConfig, Stage
from deeplens.design.search.imaging import stop_constraints
from deeplens.design.search.problem import real_surfaces, spec_constraints
from deeplens.design.search.refine import place_stops, refine, run_to_convergence
from deeplens.optics.io import load_lens

ROOT = Path(__file__).resolve().parents[3]
#: the shipped Cooke triplet's own first order (benchmarks/design_search.py)
COOKE = DesignSpec(efl_mm=101.18, fno=3.464, hfov_deg=11.86, elements=3,
                   wavelengths_nm=[486.1327, 587.5618, 656.2725], glasses="SCHOTT",
                   stop="middle", min_center_glass_mm=1.0, max_center_glass_mm=12.0,
                   min_edge_glass_mm=0.5, min_air_mm=0.2, max_track_mm=130.0)


def _cooke():
    return load_lens(ROOT / "data" / "lenses" / "cooke_triplet.json").to(torch.float64)


# ------------------------------------------------------------------ the stop rule
def _geometric(f_star: float, f0: float, q: float):
    """``step(n)``: ``n`` iterations of a merit ``f* + (f0 - f*) q^k`` (a linearly
    converging optimiser), returning ``(before, after, n)``."""
    k = [0]

    def f(i):
        return f_star + (f0 - f_star) * q ** i

    def step(n):
        before = f(k[0])
        k[0] += n
        return before, f(k[0]), n
    return step, f


@pytest.mark.parametrize("scale", [1.0, 1e-7])
@pytest.mark.parametrize("patience", [1, 2])
def test_stop_rule_stops_at_the_first_flat_chunks_and_not_before(scale, patience):
    """A chunk's relative gain ``(f_k - f_{k+c}) / f_k`` falls monotonically along
    ``f* + (f0 - f*) q^k``; the rule must stop after the first ``patience`` consecutive chunks
    below ``tol``, the same at any scale of the merit."""
    tol, chunk, q = 0.01, 10, 0.8
    step, f = _geometric(2.0 * scale, 100.0 * scale, q)
    merit, steps, reason, merits = run_to_convergence(step, tol=tol, max_steps=10_000,
                                                      chunk=chunk, patience=patience)
    gains = [(f(c * chunk) - f((c + 1) * chunk)) / f(c * chunk) for c in range(200)]
    first = next(c for c, g in enumerate(gains) if g < tol)   # closed form, chunk index
    assert all(g >= tol for g in gains[:first])
    assert steps == (first + patience) * chunk
    assert merit == f(steps) and reason.startswith("converged")
    assert len(merits) == first + patience
    # at the stop the merit is within the gain's bound of the optimum:
    # f - f* = gain f / (1 - q^c) < tol f / (1 - q^c)
    assert merit - 2.0 * scale < tol * merit / (1 - q ** chunk)


def test_stop_rule_caps_the_steps_and_stops_with_the_optimiser():
    step, f = _geometric(0.0, 1.0, 0.5)   # never flat: a pure contraction to zero
    merit, steps, reason, _ = run_to_convergence(step, tol=0.01, max_steps=35, chunk=10)
    assert steps == 35 and "step limit" in reason and merit == f(35)
    merit, steps, reason, _ = run_to_convergence(lambda n: (1.0, 1.0, 0), tol=0.01,
                                                 max_steps=35, chunk=10)
    assert steps == 0 and "stopped" in reason
    for bad in ({"tol": -1.0}, {"chunk": 0}, {"max_steps": -1}, {"patience": 0}):
        kw = {"tol": 0.01, "max_steps": 10, "chunk": 5, "patience": 1, **bad}
        with pytest.raises(ValueError):
            run_to_convergence(step, **kw)


def test_dls_run_to_convergence_ends_at_the_known_minimum():
    """Rosenbrock's residuals plus a constant one (so the minimum merit is 0.01, not 0):
    chunks of damped least squares stopped by the rule end at (1, 1)."""
    def residuals(x):
        return torch.stack([10 * (x[1] - x[0] ** 2), 1 - x[0],
                            torch.tensor(0.1, dtype=x.dtype)])

    x = [torch.tensor([-1.2, 1.0], dtype=torch.float64)]

    def step(n):
        res = damped_least_squares(residuals, x[0], steps=n, jacobian_mode="central")
        x[0] = res.x
        return res.merit0, res.merit, max(res.steps, 1)

    merit, steps, reason, merits = run_to_convergence(step, tol=1e-6, max_steps=500, chunk=2)
    assert reason.startswith("converged") and steps < 500
    assert torch.allclose(x[0], torch.ones(2, dtype=torch.float64), atol=1e-5)
    assert merit == pytest.approx(0.01, rel=1e-8)
    assert merits[0] > 0.01 + 1.0   # it did not stop at its first chunk


# ------------------------------------------------------------------ projections
@pytest.mark.parametrize("side", ["before", "after"])
def test_place_stops_moves_only_the_stop_back_between_its_neighbours(side):
    lens = _cooke()
    k = lens.stop_index
    cons = {c.label: c for c in stop_constraints(lens, 0.0)}
    gap = float(cons[f"stop_gap.{k}.{side}"].value(lens))
    push = gap + 0.3           # the stop 0.3 mm past its neighbour's vertex or rim
    with torch.no_grad():
        sign = -1.0 if side == "before" else 1.0
        lens.distances[k] += sign * push
        lens.distances[k + 1] -= sign * push
    assert float(cons[f"stop_gap.{k}.{side}"].value(lens)) < -0.29
    z0 = lens.z_vertices().clone()
    place_stops(lens, COOKE)
    z1 = lens.z_vertices()
    real = real_surfaces(lens)
    assert torch.allclose(z1[real], z0[real], atol=1e-12, rtol=0)   # no lens moved
    for c in stop_constraints(lens, 0.0):
        assert float(c.value(lens)) >= 0.0, c.label
    # moved by the shortfall (+ the 2 µm margin, re-done as the stop resizes), not more
    assert 0.29 < abs(float(z1[k] - z0[k])) < 0.3 + 0.05


@pytest.mark.slow
def test_a_refinement_round_projects_a_thickness_past_its_limit_and_ends_feasible():
    """The Cooke triplet with its first element 1 mm thicker than the spec allows (a kick's
    result) and its stop pushed into the lens before it: one DLS step later every constraint
    of the spec holds (the thickness projected onto its limit, the stop placed)."""
    lens = _cooke()
    spec = COOKE.__class__(**{**COOKE.to_dict(), "max_center_glass_mm": 8.0})
    k = lens.stop_index
    with torch.no_grad():
        lens.distances[1] += 8.0 + 1.0 - float(lens.distances[1])
        gap = float([c for c in stop_constraints(lens, 0.0)
                     if c.label.endswith("before")][0].value(lens))
        lens.distances[k] -= gap + 0.2
        lens.distances[k + 1] += gap + 0.2
    broken = ConstraintSet(spec_constraints(lens, spec)).broken(lens)
    assert any(b.startswith("max_center_glass") for b in broken)
    assert any(b.startswith("stop_gap") for b in broken)
    r = refine(lens, spec, (Stage(1, "hexapolar:2"),))
    assert r.ok and r.hard, r.reason
    assert ConstraintSet(spec_constraints(lens, spec)).broken(lens) == []
    assert float(lens.distances[1]) <= 8.0 + 1e-9


def test_search_config_converge_fields():
    assert SearchConfig().converge_steps == 0   # off by default (on in the command)
    for bad in ({"converge_steps": -1}, {"converge_chunk": 0}, {"converge_tol": -0.1},
                {"converge_tol": math.inf}):
        with pytest.raises(ValueError, match="converge"):
            SearchConfig(**bad)
    assert copy.copy(SearchConfig(converge_steps=40)).converge_steps == 40
