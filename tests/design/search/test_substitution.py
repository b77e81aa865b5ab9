"""Glass substitution that keeps what the model glasses found (issue 36, item 4): snapping (a
growing pull of each model glass onto its nearest real glass) and candidates ranked by a
linearised re-optimisation before the best few are re-optimised.

Sequential substitution (one element at a time, the most sensitive first, the remaining
model glasses re-optimised) and the fair reference (the model design converged before the
comparison, :mod:`deeplens.design.search.glass_stage`).

Planted bugs this file fails (tests/mutation/run_mutations.py): ``rank_keeps_the_worst``
(the ranked candidates sorted worst first), ``snap_without_pull`` (the pull's strength
ignored), ``substitution_keeps_unoptimised_lens`` (the kept lens is the candidate before its
re-optimisation), ``sequential_skips_reoptimisation`` (the sequential candidates not
re-optimised), ``loss_against_unconverged_model`` (the loss measured against the model design
as the search left it), ``real_design_not_converged`` (the kept candidate not converged).
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch

from test_glass import FDC, _doublet  # the cemented doublet of 1.5168/64.17 and 1.6727/32.25
from test_glass_search import SPEC
from test_glass_search import TINY as GLASS_SEARCH_TINY

from deeplens.design.lensopt import lens_residual_fn, optimize_lens
from deeplens.design.merit import Merit, SpotMerit, TargetMerit
from deeplens.design.optimizers import jacobian
from deeplens.design.search import DesignSpec, SearchConfig, Stage, search
from deeplens.design.search.glass import (
    GlassRegionPenalty, NearestGlassPull, dls_reoptimizer, glass_scales, glass_variable_names,
    RANK_CAP, project_model_glasses, ranked_per_element, snap_strengths, substitute_combined,
    TrainableModelGlass, substitute_glasses, substitute_sequentially, use_model_glasses)
from deeplens.design.search.glass_region import glass_distance, glasses, nearest_glasses
from deeplens.design.search.substitution import linear_ranker
from deeplens.design.variables import Variables
from deeplens.optics.io.agf import AGFGlass
from deeplens.optics.materials import LINE_C, LINE_D, LINE_F


pytestmark = pytest.mark.usefixtures("quiet_warnings")


# ------------------------------------------------------------------------ the pull, schedule
def test_nearest_pull_is_the_offset_to_the_nearest_target_with_its_gradient(schott):
    pts = [(1.52, 63.0), (1.75, 30.0), (1.62, 75.0), (1.9, 40.0)]
    labels = glasses("SCHOTT")
    allg = torch.tensor([(g.n_d, g.v_d) for g in labels], dtype=torch.float64)
    pull = NearestGlassPull(schott, 3.0)
    for nd, vd in pts:
        dist = glass_distance(allg[:, 0], allg[:, 1], nd, vd)
        g = labels[int(dist.argmin())]
        assert float(pull.nearest_distance(nd, vd)) == pytest.approx(float(dist.min()),
                                                                      rel=1e-12)
        want = [3.0 * (nd - g.n_d), 3.0 * 0.01 * (vd - g.v_d)]
        assert pull.pull(nd, vd).tolist() == pytest.approx(want, rel=1e-12, abs=1e-15)
        assert float(pull.excess(nd, vd)) == float(schott.excess(nd, vd))
    # with a target: the offset to that glass, not to the nearest of all
    g = next(g for g in labels if g.name == "N-SF6")
    one = NearestGlassPull(schott, 1.0, [g])
    assert float(one.nearest_distance(1.52, 63.0)) == pytest.approx(
        float(glass_distance(g.n_d, g.v_d, 1.52, 63.0)), rel=1e-12)
    # the penalty carries the pull: per glass its excess and the two pull residuals
    lens = _doublet()
    use_model_glasses(lens, region=schott)
    r = GlassRegionPenalty(schott, weight=10.0).residuals(lens)
    rp = GlassRegionPenalty(pull, weight=10.0).residuals(lens)
    assert r.shape == (2,) and rp.shape == (6,)
    for k, m in enumerate(lens.materials[1:3]):
        assert rp[3 * k] == r[k]
        assert rp[3 * k + 1:3 * k + 3].tolist() == pytest.approx(
            (10.0 * pull.pull(*m.values())).tolist(), rel=1e-12)
    # d pull / d(n_d, V_d) = strength * diag(1, w_V): against central differences
    x = torch.tensor([1.62, 75.0], dtype=torch.float64, requires_grad=True)
    (pull.pull(x[0], x[1]) ** 2).sum().backward()
    for j, h in ((0, 1e-6), (1, 1e-4)):
        e = torch.zeros(2, dtype=torch.float64)
        e[j] = h
        f = [float((pull.pull(*(x.detach() + sgn * e)) ** 2).sum()) for sgn in (1, -1)]
        assert float(x.grad[j]) == pytest.approx((f[0] - f[1]) / (2 * h), rel=1e-6, abs=1e-12)
    assert bool(pull.contains(1.5168, 64.17)) and pull.project(1.3, 90.0) == schott.project(
        1.3, 90.0)
    with pytest.raises(ValueError, match="strength must be finite and >= 0"):
        NearestGlassPull(schott, -1.0)


def test_snap_strengths_make_each_stage_distance_cost_the_merit():
    s = snap_strengths(4e-4, count=5, first_delta=0.01, last_delta=1e-4)
    assert snap_strengths(4e-4, count=1) == [math.sqrt(4e-4) / (10.0 * 0.03)]
    deltas = [0.01 * 0.01 ** (j / 4) for j in range(5)]
    for sj, dj in zip(s, deltas):
        assert (10.0 * sj * dj) ** 2 == pytest.approx(4e-4, rel=1e-12)
    assert s == sorted(s)
    with pytest.raises(ValueError, match="finite merit > 0"):
        snap_strengths(0.0)
    with pytest.raises(ValueError, match="last_delta <= first_delta"):
        snap_strengths(1.0, first_delta=1e-4, last_delta=1e-2)


# --------------------------------------------------------------- an achromat, ranked candidates
@pytest.fixture(scope="module")
def achromat(schott):
    """A cemented achromat (f = 100 mm, F/4.2, on axis, F/d/C) with model glasses optimised in
    SCHOTT's region: it ends among the fluor crowns (n_d 1.516, V_d 84.8 and 1.672 / 43.3)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = _doublet()
        use_model_glasses(lens, region=schott)
        spot = Merit(SpotMerit([0.0], [LINE_F, LINE_D, LINE_C], sampling="hexapolar:3"),
                     TargetMerit("efl", 100.0, 0.1))
        v = Variables(lens, ["surfaces.*.c", "d_sensor"] + glass_variable_names(lens),
                      scales=glass_scales(lens))
        optimize_lens(lens, v, Merit(*spot.terms, GlassRegionPenalty(schott)), steps=15,
                      jacobian_mode="central")
        project_model_glasses(lens, schott)
        model = float(spot.prepare(lens)(lens))
        reopt = dls_reoptimizer(spot, "surfaces.*.c,d_sensor", steps=8, jacobian_mode="central")
        return lens, spot, model, reopt


def test_ranked_substitution_of_an_achromat_finds_the_best_pair(achromat):
    """Nearest-neighbour (k = 1) puts in N-FK51A + N-BAF51 and re-optimises to ~4 x the model
    design's merit; every pair of the 3 nearest (9 re-optimisations, the slow test below)
    finds N-FK51A + N-KZFS11 (an anomalous-dispersion pair, below the model's merit).  Ranked
    by the linearised re-optimisation, that pair is the only one re-optimised."""
    lens, spot, model, reopt = achromat
    near = substitute_glasses(lens, "SCHOTT", reopt, k=1)
    spot.prepare(lens)
    rank = linear_ranker(lens, spot, Variables(lens, "surfaces.*.c,d_sensor"))
    ranked = substitute_glasses(lens, "SCHOTT", reopt, k=3, rank=rank, rank_keep=1)
    assert near.names == {1: "SCHOTT:N-FK51A", 2: "SCHOTT:N-BAF51"}
    assert ranked.strategy == "ranked" and len(ranked.table) == 1
    assert ranked.names == {1: "SCHOTT:N-FK51A", 2: "SCHOTT:N-KZFS11"}
    assert ranked.merit <= model                          # real beats model: within 5 %
    assert ranked.merit < 0.5 * near.merit                # and far better than nearest
    assert ranked.table[0]["predicted"] > 0 and ranked.table[0]["kept"]
    # the lens returned is the re-optimised candidate whose merit is reported
    assert float(spot.prepare(ranked.lens)(ranked.lens)) == pytest.approx(ranked.merit,
                                                                          rel=1e-9)


@pytest.mark.slow
def test_ranked_substitution_matches_the_exhaustive_one(achromat):
    lens, spot, model, reopt = achromat
    full = substitute_glasses(lens, "SCHOTT", reopt, k=3)
    spot.prepare(lens)
    rank = linear_ranker(lens, spot, Variables(lens, "surfaces.*.c,d_sensor"))
    ranked = substitute_glasses(lens, "SCHOTT", reopt, k=3, rank=rank, rank_keep=1)
    assert full.strategy == "product" and len(full.table) == 9
    assert ranked.names == full.names
    assert ranked.merit == pytest.approx(full.merit, rel=1e-9)
    # the prediction puts the re-optimisation's best pair first
    preds = {tuple(r["glasses"].values()): rank(_with(lens, r["glasses"])) for r in full.table}
    assert min(preds, key=preds.get) == tuple(full.names.values())


def _with(lens, names: dict):
    import copy

    cand = copy.deepcopy(lens)
    for i, label in names.items():
        g = next(g for g in glasses("SCHOTT") if g.label == label)
        cand.materials[i] = g.material()
    return cand


def test_linear_ranker_against_its_closed_forms(achromat):
    """``ridge -> inf``: no re-optimisation, the candidate's own merit at the model geometry;
    ``ridge = 0``: the linear least-squares residual, here against ``torch.linalg.lstsq`` on
    a forward-mode Jacobian (the ranker uses central differences)."""
    lens, spot, _, _ = achromat
    spot.prepare(lens)
    v = Variables(lens, "surfaces.*.c,d_sensor")
    cand = _with(lens, {1: "SCHOTT:N-FK51A", 2: "SCHOTT:N-KZFS11"})
    r = spot.residuals(cand).detach()
    assert linear_ranker(lens, spot, v, ridge=1e12)(cand) == pytest.approx(float(r @ r),
                                                                             rel=1e-9)
    _, J = jacobian(lens_residual_fn(v, spot), v.x0(), "forward")
    x = torch.linalg.lstsq(J, -r.unsqueeze(-1)).solution.squeeze(-1)
    ls = float(((r + J @ x) ** 2).sum())
    got = linear_ranker(lens, spot, v, ridge=0.0)(cand)
    # central-difference Jacobian error (h^2 x third derivative) is ~1e-10 relative to J
    assert got == pytest.approx(ls, rel=1e-5, abs=1e-12 * float(r @ r))
    assert ls < 0.01 * float(r @ r)                       # re-optimising the geometry matters
    assert linear_ranker(lens, spot, v, ridge=1e-3)(cand) >= got
    with pytest.raises(ValueError, match="ridge must be >= 0"):
        linear_ranker(lens, spot, v, ridge=-1.0)
    with pytest.raises(ValueError, match="rank_keep must be >= 1"):
        substitute_glasses(lens, "SCHOTT", lambda L: 0.0, k=1, rank=lambda L: 0.0, rank_keep=0)


# ---------------------------------------------------------------- snapping inside the search
#: an F/8 singlet, two colours, HOYA only, and test_glass_search.py's tiny search with one
#: substitution candidate and four snapping stages of two steps
TINY = {**GLASS_SEARCH_TINY, "substitute_k": 1, "snap_stage": (Stage(2, "hexapolar:2"),),
        "snap_count": 4}


def test_snapping_ends_with_every_medium_a_real_catalogue_glass():
    res = search(DesignSpec(**SPEC), SearchConfig(seed=2, substitution="snap",
                                                  substitute_strategy="sequential", **TINY))
    d = res.best
    rec = d.glass_record
    assert rec["substitution"] == "snap" and len(rec["snap"]) == 4
    hoya = {g.label for g in glasses("HOYA")}
    first, last = rec["snap"][0], rec["snap"][-1]
    (i,) = last["distance"]
    # the pull converged: the model glass ends on a real glass (the last stage's strength
    # makes a distance of 1e-4 cost the whole merit; the model glass started ~0.03 away)
    assert last["distance"][i] < 1e-5 and first["distance"][i] > last["distance"][i]
    assert rec["model_glasses"][str(i)] != pytest.approx(
        {"n_d": d.lens.materials[i].nd, "v_d": d.lens.materials[i].vd}, abs=1e-3)
    # ... and that glass, exactly, is what the substitution (k = 1) puts in
    m = d.lens.materials[i]
    assert isinstance(m, AGFGlass) and m.catalogue == "HOYA" and f"HOYA:{m.name}" in hoya
    assert rec["substituted"] == {str(i): last["nearest"][i]} == {str(i): f"HOYA:{m.name}"}
    for j, med in enumerate(d.lens.materials):
        assert med.name in ("AIR", "VACUUM") or (isinstance(med, AGFGlass)
                                                 and med.catalogue == "HOYA"), (j, med)
    with pytest.raises(ValueError, match="substitution must be one of nearest, snap"):
        SearchConfig(substitution="snapp")
    with pytest.raises(ValueError, match="rank_keep must be >= 0"):
        SearchConfig(rank_keep=-1)


# ------------------------------------------------------------------ sequential substitution
def test_sequential_substitution_goes_most_sensitive_first_and_lets_the_rest_follow():
    """A stand-in re-optimisation that moves every model glass still left to a fixed point P
    next to N-LAK9 (a closed-form "compensation") and marks the lens.  The first medium
    replaced is the one whose swap to its nearest glass raises ``score`` most; the second
    medium's candidates are the nearest glasses of P, where its model glass moved, not of
    where it started; the lens returned is the re-optimised candidate kept."""
    lens = _doublet("1.5300/62.0", "1.6500/34.0")
    use_model_glasses(lens)
    model = {i: lens.materials[i].n(FDC).detach() for i in (1, 2)}
    lak9 = next(g for g in glasses("SCHOTT") if g.name == "N-LAK9")
    p = (lak9.n_d + 1e-4, lak9.v_d)
    calls = []

    def mismatch(L, i):
        return float(((L.materials[i].n(FDC) - model[i]) ** 2).sum())

    def score(L):
        return mismatch(L, 1) + 30.0 * mismatch(L, 2)

    def reoptimize(L):
        calls.append(L)
        for m in L.materials:
            if hasattr(m, "v_d") and hasattr(m, "values"):   # a model glass still left
                with torch.no_grad():
                    m.n_d.fill_(p[0])
                    m.v_d.fill_(p[1])
        L.name = f"re-optimised {len(calls)}"
        return score(L)

    # the expected order, from the rule: swap each alone to its nearest, compare
    swap = {}
    for i in (1, 2):
        g, _ = nearest_glasses(*lens.materials[i].values(), "SCHOTT", 1)[0]
        t = _doublet("1.5300/62.0", "1.6500/34.0")
        use_model_glasses(t)
        t.materials[i] = g.material()
        swap[i] = score(t)
    first = max(swap, key=swap.get)
    second = 3 - first
    before = [lens.materials[i].values() for i in (1, 2)]
    res = substitute_sequentially(lens, "SCHOTT", reoptimize, k=2, score=score)
    assert res.strategy == "sequential" and len(res.table) == 4 and len(calls) == 4
    assert [r["step"] for r in res.table] == [first, first, second, second]
    near0 = [g.label for g, _ in nearest_glasses(*lens.materials[first].values(), "SCHOTT", 2)]
    assert [r["glasses"][first] for r in res.table[:2]] == near0
    near_p = [g.label for g, _ in nearest_glasses(*p, "SCHOTT", 2)]
    assert near_p[0] == "SCHOTT:N-LAK9"
    assert [r["glasses"][second] for r in res.table[2:]] == near_p   # where it moved to
    started = [g.label for g, _ in nearest_glasses(*lens.materials[second].values(),
                                                   "SCHOTT", 2)]
    assert not set(started) & set(near_p)                            # not where it started
    kept = [r for r in res.table if r["kept"]]
    assert len(kept) == 1 and kept[0]["merit"] == res.merit == score(res.lens)
    assert res.lens.name.startswith("re-optimised")
    assert res.merit == min(r["merit"] for r in res.table[2:])
    for i in (1, 2):
        m = res.lens.materials[i]
        assert isinstance(m, AGFGlass) and m.catalogue == "SCHOTT"
        assert res.names[i] == f"SCHOTT:{m.name}"
    assert [lens.materials[i].values() for i in (1, 2)] == before    # the input is unchanged
    with pytest.raises(ValueError, match="k must be >= 1"):
        substitute_sequentially(lens, "SCHOTT", reoptimize, k=0)
    with pytest.raises(ValueError, match="valid names"):
        substitute_sequentially(lens, "SCHOT", reoptimize)


# -------------------------------------------------------------------- combined substitution
def _target_merit(target: dict):
    """A stand-in re-optimisation (and prediction): the sum over media of the squared glass
    distance ``δ`` from the glass each medium holds to a target real glass; 0 exactly when
    every medium holds its target."""
    def merit(L) -> float:
        out = 0.0
        for i, t in target.items():
            m = L.materials[i]
            nd, vd = m.values() if hasattr(m, "values") else (m.nd, m.vd)
            out += float(glass_distance(nd, vd, t.n_d, t.v_d)) ** 2
        return out
    return merit


def test_combined_substitution_reaches_past_the_nearest_and_keeps_the_better_set():
    """Medium 2's target is the 5th nearest HOYA glass of its model glass: out of the
    sequential set's reach (its 2 nearest; the stand-in does not move the model glasses), so
    the sequential set ends above 0.  The ranked set combines the 6 nearest of each medium
    (36 combinations), ranks them by a perfect prediction and re-optimises the best 2: the
    targets, merit 0, kept.  With the prediction reversed and one ranked candidate
    re-optimised (the worst), the sequential set's result is kept instead."""
    lens = _doublet("1.5300/62.0", "1.6500/34.0")
    use_model_glasses(lens)
    near = {i: nearest_glasses(*lens.materials[i].values(), "HOYA", 6) for i in (1, 2)}
    target = {1: near[1][0][0], 2: near[2][4][0]}
    merit = _target_merit(target)
    res = substitute_combined(lens, "HOYA", merit, merit, merit, k=2, rank_k=6, rank_keep=2,
                              score=merit)
    seq = [r for r in res.table if r["part"] == "sequential"]
    ranked = [r for r in res.table if r["part"] == "ranked"]
    assert res.strategy == "combined" and len(seq) == 4 and len(ranked) == 2
    assert res.names == {1: target[1].label, 2: target[2].label} and res.merit == 0.0
    assert min(r["merit"] for r in seq) > 0                     # sequential cannot reach it
    assert [r["kept"] for r in res.table].count(True) == 1
    assert next(r for r in res.table if r["kept"]) is ranked[0]
    assert ranked[0]["predicted"] == 0.0 <= ranked[1]["predicted"]
    hoya = {g.label for g in glasses("HOYA")}
    assert all(set(r["glasses"].values()) <= hoya for r in res.table)
    for i in (1, 2):
        m = res.lens.materials[i]
        assert isinstance(m, AGFGlass) and m.catalogue == "HOYA"
    # a reversed prediction: the one ranked candidate is the worst pair, sequential wins
    worst = substitute_combined(lens, "HOYA", merit, merit, lambda L: -merit(L), k=2,
                                rank_k=6, rank_keep=1, score=merit)
    w_seq = [r for r in worst.table if r["part"] == "sequential"]
    w_ranked = [r for r in worst.table if r["part"] == "ranked"]
    assert len(w_ranked) == 1 and w_ranked[0]["merit"] > min(r["merit"] for r in w_seq)
    kept = [r for r in worst.table if r["kept"]]
    assert len(kept) == 1 and kept[0]["part"] == "sequential"
    assert worst.merit == min(r["merit"] for r in w_seq) == merit(worst.lens)
    assert all(isinstance(m, TrainableModelGlass) for m in (lens.materials[1],
                                                             lens.materials[2]))
    with pytest.raises(ValueError, match="rank_keep must be >= 1"):
        substitute_combined(lens, "HOYA", merit, merit, merit, rank_keep=0)
    with pytest.raises(ValueError, match="valid names"):
        substitute_combined(lens, "HOY", merit, merit, merit)


def test_combined_substitution_survives_one_failing_set_and_reports_both_failing():
    lens = _doublet("1.5300/62.0", "1.6500/34.0")
    use_model_glasses(lens)
    near = {i: nearest_glasses(*lens.materials[i].values(), "HOYA", 6) for i in (1, 2)}
    merit = _target_merit({1: near[1][0][0], 2: near[2][4][0]})

    def fail(L):
        raise RuntimeError("no step")

    res = substitute_combined(lens, "HOYA", fail, merit, merit, rank_keep=2)
    assert {r["part"] for r in res.table if r["merit"] is not None} == {"ranked"}
    assert res.merit == 0.0
    with pytest.raises(RuntimeError, match="sequential: .*ranked: "):
        substitute_combined(lens, "HOYA", fail, fail, merit, rank_keep=2)


@pytest.mark.parametrize("elements, k, want", [(1, 6, 6), (3, 6, 6), (4, 6, 5), (6, 6, 3),
                                               (7, 6, 2), (10, 6, 1), (3, 2, 2)])
def test_ranked_per_element_is_the_largest_count_under_the_cap(elements, k, want):
    m = ranked_per_element(elements, k)
    assert m == want
    assert m ** elements <= RANK_CAP or m == 1
    assert m == k or (m + 1) ** elements > RANK_CAP
    with pytest.raises(ValueError, match="elements, k and cap >= 1"):
        ranked_per_element(0, k)


def test_combined_is_the_default_and_its_settings_are_checked():
    cfg = SearchConfig()
    assert cfg.substitute_strategy == "combined"
    assert (cfg.combined_k, cfg.combined_keep) == (6, 6)
    for name in ("combined_k", "combined_keep"):
        with pytest.raises(ValueError, match=f"{name} must be >= 1"):
            SearchConfig(**{name: 0})


# ------------------------------------------------------- the fair reference, inside the search
def test_the_loss_is_measured_against_the_converged_model_design():
    """The tiny search leaves its model design after 3 DLS steps: converging it (rounds of the
    substitution's stage, rel_tol 0, at most 3) lowers its RMS spot, and that converged merit,
    not the search's, is the reference of the loss; the kept real candidate gets the same
    rounds.  Sequential substitution inside the search puts in HOYA glasses only."""
    cfg = SearchConfig(seed=2, **{**TINY, "substitution": "nearest",
                                  "substitute_strategy": "sequential", "converge_tol": 0.0,
                                  "converge_rounds": 3})
    res = search(DesignSpec(**SPEC), cfg)
    rec = res.best.glass_record
    mc, rc = rec["model_convergence"], rec["real_convergence"]
    assert rec["model_converged"] and 1 <= mc["rounds"] <= 3 and len(mc["history"]) >= 2
    assert mc["history"] == sorted(mc["history"], reverse=True)
    assert rec["model_rms_um"] < rec["model_rms_unconverged_um"]
    assert rec["merit_loss"] == pytest.approx(rec["real_rms_um"] / rec["model_rms_um"] - 1,
                                              rel=1e-12)
    assert rc is not None and rc["rounds"] >= 1 and rc["history"][0] == min(
        c["score_um"] for c in rec["candidates"] if c["score_um"] is not None)
    assert rec["strategy"] == "sequential" and rec["substitute_strategy"] == "sequential"
    # each model glass's distance to the nearest real glass: at most the region's bound,
    # radius + tau log N (GlassRegion's smooth distance)
    n_glass = len(glasses("HOYA"))
    for i, g in rec["model_glasses"].items():
        d = rec["model_glass_distance"][i]
        want = min(glass_distance(x.n_d, x.v_d, g["n_d"], g["v_d"]) for x in glasses("HOYA"))
        assert d == pytest.approx(float(want), rel=1e-9)
        assert 0 <= d <= cfg.glass_radius + 0.002 * math.log(n_glass) + 1e-12
    hoya = {g.label for g in glasses("HOYA")}
    assert set(rec["substituted"].values()) <= hoya
    assert all(set(c["glasses"].values()) <= hoya for c in rec["candidates"])
    with pytest.raises(ValueError,
                       match="substitute_strategy must be one of joint, sequential, combined"):
        SearchConfig(substitute_strategy="one by one")
    with pytest.raises(ValueError, match="converge_tol must be"):
        SearchConfig(converge_tol=-1.0)
    with pytest.raises(ValueError, match="converge_rounds must be >= 0"):
        SearchConfig(converge_rounds=-1)
