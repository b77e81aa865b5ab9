"""The camera's constraints on a searched lens (deeplens.design.search.imaging): the stop between
its neighbours, and distortion, against the analysis module's distortion (itself checked
against optiland in tests/analysis/test_analysis_oracle.py), closed-form gaps and finite
differences."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import torch

from deeplens.analysis.aberrations import distortion
from deeplens.design.search import DesignSpec, SpecError
from deeplens.design.search.imaging import distortion_pct, repair_stop_gaps, stop_constraints
from deeplens.design.search.problem import spec_constraints
from deeplens.optics.io import lens_from_dict, load_lens

ROOT = Path(__file__).resolve().parents[3]
WL = 587.5618


def _doublet():
    return load_lens(ROOT / "data" / "lenses" / "wide_doublet.json").to(torch.float64)


def _singlet(gap_mm: float, c1: float) -> object:
    """A stop (semi-diameter 2 mm) then an N-BK7 singlet ``gap_mm`` behind it (front
    curvature ``c1``)."""
    return lens_from_dict({
        "format": "deeplens-lens", "version": 1, "object": {"distance_mm": "inf"},
        "aperture": {"type": "epd", "value": 4.0}, "fields_deg": [0.0, 10.0],
        "wavelengths_nm": [WL], "stop": 0,
        "surfaces": [
            {"type": "aperture", "semi_diameter_mm": 2.0, "distance_mm": 0.0, "material": "AIR"},
            {"type": "asphere", "semi_diameter_mm": 5.0, "curvature_per_mm": c1,
             "distance_mm": gap_mm, "material": "N-BK7"},
            {"type": "asphere", "semi_diameter_mm": 5.0, "curvature_per_mm": -0.02,
             "distance_mm": 3.0, "material": "AIR"}],
        "sensor": {"distance_mm": 40.0}}).to(torch.float64)


def test_distortion_matches_the_analysis_and_has_its_sign():
    lens = _doublet()
    ours = distortion_pct(lens, [10.0, 20.0], WL)
    ref = distortion(lens, [10.0, 20.0], WL, image_plane="sensor", aim="paraxial")
    assert torch.allclose(ours, ref, rtol=0, atol=1e-9)
    assert float(ours[1]) < -1.0        # the doublet's barrel distortion (about -4 % at 20 deg)
    with pytest.raises(ValueError, match="non-zero fields"):
        distortion_pct(lens, [0.0, 20.0], WL)


def test_distortion_gradient_matches_central_differences():
    lens = _doublet()
    c = lens.surfaces[1].c
    c.requires_grad_(True)
    g, = torch.autograd.grad(distortion_pct(lens, [20.0], WL)[0], c)
    h = 1e-6   # float64: truncation ~h^2 |d3|, rounding ~eps |d| / h: both < 1e-8 here
    with torch.no_grad():
        c0 = float(c)
        c.fill_(c0 + h)
        up = float(distortion_pct(lens, [20.0], WL)[0])
        c.fill_(c0 - h)
        down = float(distortion_pct(lens, [20.0], WL)[0])
        c.fill_(c0)
    fd = (up - down) / (2 * h)
    assert abs(fd) > 1.0                 # the curvature moves the distortion: the test has teeth
    assert float(g) == pytest.approx(fd, rel=1e-5)


@pytest.mark.parametrize("c1", [0.05, -0.08])
def test_stop_gap_is_the_signed_distance_at_vertex_and_rim(c1):
    r = 2.0   # the stop's semi-diameter
    sag = c1 * r * r / (1 + math.sqrt(1 - c1 * c1 * r * r))
    for gap in (1.5, -2.0):
        (con,) = stop_constraints(_singlet(gap, c1))
        assert con.label == "stop_gap.0.after" and con.kind == "min" and con.limit == 0.0
        expected = min(gap, gap + sag)       # the lens's front surface behind the stop plane
        assert float(con.value(_singlet(gap, c1))) == pytest.approx(expected, abs=1e-12)
        assert (con.violation(_singlet(gap, c1)) > 0) == (expected < 0)


def test_a_stop_between_elements_is_held_on_both_sides():
    lens = load_lens(ROOT / "data" / "lenses" / "cooke_triplet.json").to(torch.float64)
    cons = stop_constraints(lens)
    k = lens.stop_index
    assert [c.label for c in cons] == [f"stop_gap.{k}.before", f"stop_gap.{k}.after"]
    assert all(float(c.value(lens)) > 0 for c in cons)
    moved = copy.deepcopy(lens)
    with torch.no_grad():       # the stop pushed 1 mm past the next surface, gaps kept
        d = moved.distances
        d[k] += d[k + 1] + 1.0
        d[k + 1].fill_(-1.0)
    assert float(cons[1].value(moved)) <= -1.0 + 1e-9


def test_spec_constraints_add_distortion_only_when_asked():
    lens = _doublet()
    base = dict(efl_mm=10.0, fno=4.0, hfov_deg=20.0, elements=2, stop="front")
    labels = [c.label for c in spec_constraints(lens, DesignSpec(**base))]
    assert "max_distortion" not in labels and "stop_gap.0.after" in labels
    cons = spec_constraints(lens, DesignSpec(**base, max_distortion_pct=1.0))
    (dist,) = [c for c in cons if c.label == "max_distortion"]
    worst = float(distortion_pct(lens, [14.0, 20.0], WL).abs().max())
    assert float(dist.value(lens)) == pytest.approx(worst, abs=1e-12)
    assert dist.violation(lens) == pytest.approx(worst - 1.0, abs=1e-12)
    with pytest.raises(SpecError) as e:
        DesignSpec(**base, max_distortion_pct=-1.0)
    assert e.value.field == "max_distortion_pct"


@pytest.mark.parametrize("c1", [0.05, -0.08])
def test_repair_moves_the_lens_behind_the_stop_by_the_shortfall(c1):
    lens = _singlet(-2.0, c1)
    (con,) = stop_constraints(lens)
    short = -float(con.value(lens))
    assert short >= 2.0
    repair_stop_gaps(lens, margin_mm=1e-3)
    assert float(con.value(lens)) == pytest.approx(1e-3, abs=1e-12)
    before = float(lens.distances[1])
    repair_stop_gaps(lens)                      # nothing to repair: nothing moves
    assert float(lens.distances[1]) == before


@pytest.mark.parametrize("side", ["before", "after"])
def test_repair_stop_only_moves_the_stop_within_its_gap(side):
    """``stop_only``: the Cooke triplet's stop pushed 0.5 mm into the surface before (after)
    it comes back by the shortfall + margin, the gap on its other side shrinks by as much,
    and every refracting surface and the sensor stay where they were."""
    lens = load_lens(ROOT / "data" / "lenses" / "cooke_triplet.json").to(torch.float64)
    k = lens.stop_index
    cons = {c.label: c for c in stop_constraints(lens)}
    con = cons[f"stop_gap.{k}.{side}"]
    with torch.no_grad():       # the stop moved (alone) to 0.5 mm past the surface
        step = float(con.value(lens)) + 0.5
        sign = -1.0 if side == "before" else 1.0
        lens.distances[k] += sign * step
        lens.distances[k + 1] -= sign * step
    assert float(con.value(lens)) == pytest.approx(-0.5, abs=1e-9)
    z0 = lens.z_vertices().clone()
    sensor = float(lens.z_sensor())
    repair_stop_gaps(lens, margin_mm=1e-3, stop_only=True)
    assert float(con.value(lens)) == pytest.approx(1e-3, abs=1e-9)
    z = lens.z_vertices()
    keep = [i for i in range(len(lens.surfaces)) if i != k]
    assert torch.allclose(z[keep], z0[keep], rtol=0, atol=1e-12)
    assert float(lens.z_sensor()) == pytest.approx(sensor, abs=1e-12)
    assert float(z[k] - z0[k]) == pytest.approx(-sign * 0.501, abs=1e-9)
