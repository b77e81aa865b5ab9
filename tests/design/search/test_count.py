"""Element count as a variable (deeplens.design.search.count): removing an element keeps a valid
lens whose focal length the solve restores, splitting keeps the power to first order (the
two-thin-lens formula), and a seed reproduces thinning, splitting and the trade."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch

from deeplens.design.search import DesignSpec, SearchConfig, Stage
from deeplens.design.search.count import (contributions, count_trade, element_powers, elements,
                                          remove_element, split, split_element, thin)
from deeplens.design.search.start import place_sensor, solve_efl
from deeplens.optics.io import lens_from_dict, load_lens
from deeplens.optics.paraxial import paraxial

ROOT = Path(__file__).resolve().parents[3]
TINY = (Stage(2, "hexapolar:3"),)


def _cooke():
    return load_lens(ROOT / "data" / "lenses" / "cooke_triplet.json").to(torch.float64)


def _singlet(t: float = 0.3, c: float = 0.0193):
    """A stop, then an equi-convex N-BK7 singlet of f ~ 50 mm and centre thickness ``t``."""
    return lens_from_dict({
        "format": "deeplens-lens", "version": 1, "object": {"distance_mm": "inf"},
        "aperture": {"type": "epd", "value": 4.0}, "fields_deg": [0.0, 2.0],
        "wavelengths_nm": [587.5618], "stop": 0,
        "surfaces": [
            {"type": "aperture", "semi_diameter_mm": 2.0, "distance_mm": 0.0, "material": "AIR"},
            {"type": "asphere", "semi_diameter_mm": 3.0, "curvature_per_mm": c,
             "distance_mm": 1.0, "material": "N-BK7"},
            {"type": "asphere", "semi_diameter_mm": 3.0, "curvature_per_mm": -c,
             "distance_mm": t, "material": "AIR"}],
        "sensor": {"distance_mm": 50.0}}).to(torch.float64)


def test_elements_and_contributions_of_the_cooke_triplet():
    lens = _cooke()
    assert elements(lens) == [(0, 1), (2, 3), (5, 6)]      # the stop is surface 4
    phis, ys = element_powers(lens)
    assert phis[0] > 0 > phis[1] and phis[2] > 0           # + - +
    assert ys[0] == pytest.approx(1.0)
    c = contributions(lens)
    assert min(range(3), key=c.__getitem__) == 2
    # the thick-lens power of a singlet in air is the paraxial power of that singlet alone
    (phi,), _ = element_powers(_singlet(t=2.0))
    assert phi == pytest.approx(1.0 / float(paraxial(_singlet(t=2.0)).efl), rel=1e-12)


@pytest.mark.parametrize("e", [0, 1, 2])
def test_removing_an_element_gives_a_valid_lens_with_the_efl_held(e):
    lens = _cooke()
    efl = float(paraxial(lens).efl)
    z = lens.z_vertices().tolist()
    out = remove_element(lens, e)
    assert len(out.surfaces) == len(lens.surfaces) - 2 and len(elements(out)) == 2
    a, b = elements(lens)[e]
    kept = [zi for i, zi in enumerate(z) if i not in (a, b)]
    shift = kept[0] - float(out.z_vertices()[0])        # only a first element moves the origin
    assert out.z_vertices().tolist() == pytest.approx([k - shift for k in kept], abs=1e-12)
    assert float(out.surfaces[out.stop_index].semi_diameter) == pytest.approx(
        float(lens.surfaces[lens.stop_index].semi_diameter))
    assert abs(float(paraxial(out).efl) - efl) > 1.0      # the power changed ...
    solve_efl(out, efl)
    place_sensor(out)                                     # ... the solve restores it
    out.check()
    assert float(paraxial(out).efl) == pytest.approx(efl, rel=1e-9)
    with pytest.raises(ValueError, match="one element"):
        remove_element(remove_element(out, 0), 0)


def test_splitting_a_thin_element_keeps_the_power_to_first_order():
    lens = _singlet()
    (phi,), _ = element_powers(lens)
    P = 1.0 / float(paraxial(lens).efl)
    rel = {}
    for g in (0.2, 0.4):
        out = split_element(lens, 0, g)
        out.check()
        (p1, p2), _ = element_powers(out)
        assert p1 == pytest.approx(p2) and p1 + p2 == pytest.approx(phi, rel=2e-3)
        c = [float(out.surfaces[i].c) for i in (1, 2, 3, 4)]
        assert c == pytest.approx([0.5 * 0.0193, -0.5 * 0.0193] * 2)   # the shape kept
        rel[g] = 1.0 / float(paraxial(out).efl) / P - 1.0
    assert abs(rel[0.2]) < 3e-3                     # first order: the power is kept ...
    # ... and the change is second order, -e phi^2 / 4 for two thin lenses phi / 2 a reduced
    # distance e apart: its slope in the gap is -phi / 4
    slope = (rel[0.4] - rel[0.2]) / 0.2
    assert slope == pytest.approx(-phi / 4, rel=0.02)


@pytest.mark.slow   # 3 refinements and evaluations: ~10 s
def test_thinning_and_splitting_are_deterministic_and_hold_the_efl():
    spec = DesignSpec(efl_mm=50.0, fno=8.0, hfov_deg=2.0, elements=1, glasses="N-BK7",
                      stop="front", wavelengths_nm=[587.5618])
    lens = _singlet(t=2.0)
    solve_efl(lens, 50.0)
    place_sensor(lens)
    a = split(copy.deepcopy(lens), spec, TINY)
    b = split(copy.deepcopy(lens), spec, TINY)
    assert a.ok and a.elements == 2 and len(elements(a.lens)) == 2
    assert a.metrics == b.metrics
    assert a.metrics["efl_mm"] == pytest.approx(50.0, rel=1e-9)
    two = DesignSpec(**{**spec.to_dict(), "elements": 2})
    c = thin(a.lens, two, TINY)
    assert c.ok and c.elements == 1 and c.metrics["efl_mm"] == pytest.approx(50.0, rel=1e-9)


@pytest.mark.slow
def test_a_seed_reproduces_the_trade():
    spec = DesignSpec(efl_mm=50.0, fno=8.0, hfov_deg=3.0, elements=2, glasses="N-BK7,N-F2",
                      stop="front")
    cfg = SearchConfig(starts=1, screen=(Stage(4, "hexapolar:3"),), polish_count=1,
                       polish=(Stage(4, "hexapolar:3"),), hops=0, keep=1, seed=3,
                       converge_steps=0)
    one = [s.row() for s in count_trade(spec, [1, 2, 3], cfg, TINY)]
    two = [s.row() for s in count_trade(spec, [1, 2, 3], cfg, TINY)]
    assert [r["elements"] for r in one] == [1, 2, 3]
    for r in one + two:
        r.pop("seconds")
    assert one == two
