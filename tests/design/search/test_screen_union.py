"""The start list of the third-order screen: the union of the plain and the re-balanced
rankings (``SearchConfig.seidel_ranking="union"``, deeplens.design.search.screen).

Oracles: the union's definition itself, checked on hand-made rankings (the best of each list
kept, each start once, a start taken from the other list not replaced, the other list's order
when one is empty) and, on a real screen of a Cooke-like triplet, against the two rankings it
joins, each computed on its own (``rebalance=0``: the plain ranking; ``ranking="rebalanced"``:
the re-balanced one): every start of either is in the union, nothing else is, and with
re-balancing off the union is the plain ranking bit for bit.
"""

import pytest
import torch

from deeplens.design.search import DesignSpec, SearchConfig
from deeplens.design.search.screen import _same_start, screened_starts, union_of_rankings

WL = [486.1327, 587.5618, 656.2725]
TRIPLET = DesignSpec(efl_mm=101.18, fno=3.464, hfov_deg=11.86, elements=3, wavelengths_nm=WL,
                     glasses="SCHOTT", stop="middle", min_center_glass_mm=1.0,
                     max_center_glass_mm=12.0, min_edge_glass_mm=0.5, min_air_mm=0.2,
                     max_track_mm=130.0)


def _ranked(names):
    """``[(t3, j, thin, lens)]`` best first, the lens a name."""
    return [(float(k), k, 0.0, n) for k, n in enumerate(names)]


def _names(union):
    return [(c[3], c[4]) for c in union]


def test_union_keeps_the_best_of_each_ranking_each_start_once():
    plain = _ranked(["a", "b", "c", "d"])
    reb = _ranked(["e", "b", "f", "g"])
    got = union_of_rankings(plain, reb, 3, same=lambda x, y: x == y)
    # interleaved best first; "b" (second of both) once, not replaced by "d" or "g"
    assert _names(got) == [("e", "rebalanced"), ("a", "plain"), ("b", "rebalanced"),
                           ("f", "rebalanced"), ("c", "plain")]
    assert union_of_rankings(plain, reb, 1, same=lambda x, y: x == y)[:2] == [
        (0.0, 0, 0.0, "e", "rebalanced"), (0.0, 0, 0.0, "a", "plain")]


def test_union_with_one_ranking_empty_is_the_other_in_its_order():
    plain = _ranked(["a", "b", "c", "d"])
    same = lambda x, y: x == y   # noqa: E731
    assert union_of_rankings(plain, [], 3, same) == [(*c, "plain") for c in plain[:3]]
    assert union_of_rankings([], plain, 3, same) == [(*c, "rebalanced") for c in plain[:3]]
    assert union_of_rankings(plain[:2], [], 3, same) == [(*c, "plain") for c in plain[:2]]


def _key(lens):
    """Curvatures and distances of a lens, as a hashable tuple (float64)."""
    return (tuple(float(s.c) for s in lens.surfaces if hasattr(s, "c")),
            tuple(float(d) for d in lens.distances))


def test_screened_union_is_the_two_rankings_joined():
    kw = dict(points=32, starts=2, seed=0, steps=10)
    plain, pinfo = screened_starts(TRIPLET, rebalance=0, **kw)
    reb, rinfo = screened_starts(TRIPLET, rebalance=20, ranking="rebalanced", **kw)
    union, uinfo = screened_starts(TRIPLET, rebalance=20, **kw)
    assert len(plain) == 2 and len(reb) == 2
    assert pinfo["ranked"] == ["plain"] * 2 and rinfo["ranked"] == ["rebalanced"] * 2
    assert pinfo["thick_rms_um"] == sorted(pinfo["thick_rms_um"])
    assert rinfo["thick_rms_um"] == sorted(rinfo["thick_rms_um"])
    want = {_key(L) for _, L in plain} | {_key(L) for _, L in reb}
    got = [_key(L) for _, L in union]
    assert len(got) == len(set(got)) == len(want) and set(got) == want
    # the first of each ranking are the union's first two, re-balanced first
    assert got[0] == _key(reb[0][1]) and got[1] == _key(plain[0][1])
    assert uinfo["ranked"][:2] == ["rebalanced", "plain"] and uinfo["ranking"] == "union"
    # re-balancing moved something here, or the test would not tell the rankings apart
    assert {_key(L) for _, L in reb} != {_key(L) for _, L in plain}
    # re-balancing off: "union" (``plain`` above) and "rebalanced" give the plain ranking
    off, info = screened_starts(TRIPLET, rebalance=0, ranking="rebalanced", **kw)
    assert [lab for lab, _ in off] == [lab for lab, _ in plain]
    assert [_key(L) for _, L in off] == [_key(L) for _, L in plain]
    assert info["thick_rms_um"] == pinfo["thick_rms_um"]


def test_same_start_compares_curvatures_and_distances():
    (_, a), (_, b) = screened_starts(TRIPLET, 32, 2, seed=0, steps=10, rebalance=0)[0]
    import copy

    a2 = copy.deepcopy(a)
    assert _same_start(a, a) and _same_start(a, a2) and not _same_start(a, b)
    with torch.no_grad():
        a2.distances[2].add_(1e-9)
    assert not _same_start(a, a2)


def test_ranking_setting_is_checked():
    with pytest.raises(ValueError, match="seidel_ranking must be one of union, rebalanced"):
        SearchConfig(seidel_ranking="plain")
    with pytest.raises(ValueError, match="ranking must be one of union, rebalanced"):
        screened_starts(TRIPLET, 8, 1, ranking="both")
    cfg = SearchConfig()   # the measured default (docs/guide/design-search.md)
    assert (cfg.seidel_rebalance, cfg.seidel_rebalance_floor, cfg.seidel_ranking) == (
        300, "thin", "union")



def test_the_search_refines_every_start_of_the_union(monkeypatch):
    """The search refines the whole union (up to ``2 starts``), not only its first ``starts``:
    each start handed to the refinement is recorded (the refinement itself stubbed to fail,
    so the search stops after its starts)."""
    from deeplens.design.search import multistart
    from deeplens.design.search.refine import RefineResult

    seen = []

    def refine(lens, spec, stages, **kw):
        seen.append(_key(lens))
        return RefineResult(ok=False, reason="stub")

    monkeypatch.setattr(multistart, "refine", refine)
    kw = dict(seidel_screen=32, seidel_steps=10, seidel_rebalance=20)
    cfg = SearchConfig(seed=0, starts=2, **kw)
    with pytest.raises(RuntimeError, match="none of 32 starts"):
        multistart.search(TRIPLET, cfg)
    union, info = screened_starts(TRIPLET, 32, 2, seed=0, steps=10, rebalance=20)
    assert len(union) > cfg.starts   # re-balancing moved a start into the union
    assert seen == [_key(L) for _, L in union]
    seen.clear()
    with pytest.raises(RuntimeError):
        multistart.search(TRIPLET, SearchConfig(seed=0, starts=2, seidel_ranking="rebalanced",
                                                **kw))
    reb, _ = screened_starts(TRIPLET, 32, 2, seed=0, steps=10, rebalance=20,
                             ranking="rebalanced")
    assert seen == [_key(L) for _, L in reb] and len(seen) == 2
