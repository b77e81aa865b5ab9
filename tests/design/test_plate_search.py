"""The EDOF plate search (deeplens/design/plate_search.py): seeded and reproducible, better than
the zero plate and than every start it refined, and, at the experiment's settings, better than
the hand-picked 5 um cubic plate by the same merit (slow)."""

from __future__ import annotations

import pytest

from deeplens.design.plate_search import (PlateSearchConfig, describe_plate, plate_merit,
                                          plate_score, plate_search)
from deeplens.training.lens_setup import build_lens

LENS = "data/lenses/edof_achromat.json"
PLATE = [f"surfaces.4.a.{k}" for k in range(3, 10)]
CUBIC = ["surfaces.4.a.6", "surfaces.4.a.9"]  # y^3, x^3 (xy_terms order)
DEPTHS = [4500.0, 8000.0]
WAVES = [587.6]


def _lens(alpha_mm=0.0, trainable=PLATE, focus_waves=(587.5618,)):
    return build_lens(LENS, trainable, "float64", plate="cubic", plate_surface=4,
                      plate_alpha_mm=alpha_mm, focus_mm=5760.0, focus_wavelengths_nm=focus_waves)


def _tiny(seed=0, **kw):
    cfg = PlateSearchConfig(**{"starts": 2, "steps": 2, "sampling": "grid:8", "n_freq": 2,
                               "seed": seed, **kw})
    lens = _lens(trainable=CUBIC)
    return lens, plate_search(lens, 4, CUBIC, DEPTHS, WAVES, 0.0069, cfg)


@pytest.fixture(scope="module")
def tiny():
    return _tiny()


def test_the_search_beats_the_zero_plate_and_every_start(tiny):
    lens, r = tiny
    # the zero plate is the first start; the Sobol starts lie in the box
    assert r.runs[0].origin == "zero plate" and r.runs[0].start_x == [0.0, 0.0]
    assert all(abs(v) <= 0.006 for d in r.runs[1:] for v in d.start_x)
    assert len(r.runs) == 3 and r.skipped == 0
    # better than the zero plate and than the best start before refinement (by the score the
    # search ranks with, recomputed here on the returned lens)
    zero = r.runs[0].start_score
    best = plate_score(lens, plate_merit(DEPTHS, WAVES, 0.0069, r.blur_px, PlateSearchConfig(
        sampling="grid:8", n_freq=2)))[0]
    assert best == pytest.approx(r.best.score, rel=1e-9)
    assert best < 0.1 * zero and best < min(d.start_score for d in r.runs)
    assert r.best.score == min(d.score for d in r.runs)
    # the returned lens holds the best plate (mm of sag at the rim: a R^3), the others zero
    R = float(lens.surfaces[4].semi_diameter)
    x = [float(lens.surfaces[4].a[k].detach()) * R ** 3 for k in (6, 9)]
    assert x == pytest.approx(r.best.x, rel=1e-12)
    assert all(float(lens.surfaces[4].a[k].detach()) == 0.0 for k in (3, 4, 5, 7, 8))
    # the blur target is the 5 um cubic plate's, and the best plate meets it
    assert r.best.blur_px == pytest.approx(r.blur_px, rel=0.02)


def test_a_seed_reproduces_the_search_and_another_seed_draws_other_starts():
    a, b = _tiny(starts=1, steps=1)[1], _tiny(starts=1, steps=1)[1]
    assert [(d.x, d.score, d.start_x) for d in a.runs] == [(d.x, d.score, d.start_x)
                                                           for d in b.runs]
    c = _tiny(seed=1, starts=1, steps=1)[1]
    assert c.runs[1].start_x != a.runs[1].start_x


def test_kept_designs_are_distinct_and_bad_settings_are_named():
    _, r = _tiny(starts=1, steps=1, keep=3, dedup_tol_mm=1.0)  # all within 1 mm: one design
    assert len(r.runs) == 2 and len(r.designs) == 1
    assert r.designs[0].score == min(d.score for d in r.runs)
    for bad, field in (({"starts": 0}, "starts"), ({"box_mm": 0.0}, "box_mm"),
                       ({"blur_px": -1.0}, "blur_px"), ({"seed": -1}, "seed")):
        with pytest.raises(ValueError, match=field):
            PlateSearchConfig(**bad)
    with pytest.raises(ValueError, match=r"not coefficients of the plate"):
        plate_search(_lens(), 4, ["d_sensor"], DEPTHS, WAVES, 0.0069,
                     PlateSearchConfig(starts=1, steps=1))


def test_describe_plate_names_the_monomials():
    lens = _lens(0.005)
    terms = dict(describe_plate(lens.surfaces[4]))
    assert set(terms) == {"x^3", "y^3"}
    assert terms["x^3"] == pytest.approx(0.005, rel=1e-12)


@pytest.mark.slow
def test_at_the_experiments_settings_the_search_beats_the_5um_cubic_plate():
    """Four depths over 4.5-8 m, R/G/B, the classical variant's merit (grid:32, 6 frequency
    steps) at the 5 um cubic plate's blur (5.90 px): the cubic plate scores 4.64e-3, the zero
    plate 14.1; experiment=edof_search's 16 starts found 4.05e-3 from start 11, the only one
    of the first 11 below the cubic plate (so 11 starts here: about 4 CPU-min)."""
    depths = [1.0 / (1 / 4500 + (1 / 8000 - 1 / 4500) * k / 3) for k in range(4)]
    waves = [656.2725, 587.5618, 486.1327]
    cfg = PlateSearchConfig(starts=11)
    lens = _lens(focus_waves=waves)   # focused as training focuses it: over R, G, B
    r = plate_search(lens, 4, PLATE, depths, waves, 0.0069, cfg)
    cubic = plate_score(_lens(0.005, focus_waves=waves), plate_merit(depths, waves, 0.0069, r.blur_px, cfg))[0]
    assert r.best.score < cubic < 0.01 * r.runs[0].score
    assert r.best.origin == "start 11"


def test_a_refined_plate_whose_psf_exceeds_the_memory_budget_is_skipped(monkeypatch):
    # the restoration merit's fresh sampling of a refined plate can need more memory than its
    # budget (PSFMemoryError): that start is skipped and reported, the search goes on
    import deeplens.design.plate_search as ps
    from deeplens.render.diffraction import PSFMemoryError

    calls, real = [], ps.plate_score

    def score(lens, merit):
        calls.append(1)
        if len(calls) == 4:   # zero plate: start, refined; start 1: start, refined <- this
            raise PSFMemoryError("diffraction PSF: too large for the test")
        return real(lens, merit)

    monkeypatch.setattr(ps, "plate_score", score)
    said = []
    cfg = PlateSearchConfig(starts=1, steps=1, sampling="grid:8", n_freq=2, seed=0)
    r = plate_search(_lens(trainable=CUBIC), 4, CUBIC, DEPTHS, WAVES, 0.0069, cfg,
                     progress=said.append)
    assert r.skipped == 1 and [d.origin for d in r.runs] == ["zero plate"]
    assert any("start 1: skipped" in m and "too large for the test" in m for m in said)
