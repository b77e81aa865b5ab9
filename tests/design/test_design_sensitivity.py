"""Sensitivity matrices (paper Eq. 10) against central differences, the symmetry zeros, the RSS
estimate against Monte Carlo, tolerance files."""

import json

import pytest
import torch
from helpers import LENS_DIR

from deeplens.design.merit import SpotMerit
from deeplens.design.sensitivity import (finite_difference_matrix, rss_estimate,
                                         sensitivity_matrix, tolerance_parameters)
from deeplens.design.tolerance import load_tolerances, monte_carlo, resolve_tolerances
from deeplens.optics.io import load_lens

W = 587.5618


pytestmark = pytest.mark.usefixtures("quiet_warnings")


@pytest.fixture(scope="module")
def cooke():
    return load_lens(LENS_DIR / "cooke_triplet.json").to(torch.float64)


def test_cooke_triplet_first_order_data(cooke):
    """The shipped prescription reproduces Smith's EFL 101.181 mm and BFL 77.405 mm."""
    from deeplens.optics.paraxial import paraxial

    p = paraxial(cooke)
    assert float(p.efl) == pytest.approx(101.181, abs=2e-3)
    assert float(p.bfl) == pytest.approx(77.405, abs=2e-3)


def test_sensitivities_equal_finite_differences(cooke):
    names = ["misalignments.0.dy", "misalignments.1.tilt_x", "distances.1",
             "misalignments.3.dx", "surfaces.5.c"]
    sm = SpotMerit([0.0, 11.86], [W], sampling="hexapolar:3").prepare(cooke)
    J = sensitivity_matrix(cooke, sm, names)
    FD = finite_difference_matrix(cooke, sm, names)
    assert J.shape == (2, 5)
    big = float(FD.abs().max())
    assert float((J - FD).abs().max()) < 1e-5 * big
    # the columns are the named parameters: on axis, decenters and tilts are stationary by
    # symmetry while a spacing is not
    assert abs(float(J[0, 0])) < 1e-9 * big and abs(float(J[0, 1])) < 1e-9 * big
    assert abs(float(J[0, 2])) > 0.05  # mm of RMS per mm of spacing
    # off axis (field in the y-z plane) an x-decenter is still stationary, a y-tilt is not
    assert abs(float(J[1, 3])) < 1e-9 * big


def test_rss_estimate_agrees_with_monte_carlo(cooke):
    """E[ε²] ≈ ε0² + Σ σ² |J_r|² (second order) against the mean of ε² over random lenses."""
    names = ["misalignments.0.dy", "misalignments.3.dy", "distances.1"]
    t = torch.tensor([0.05, 0.05, 0.1], dtype=torch.float64)
    sm = SpotMerit([0.0], [W], sampling="hexapolar:3", strict_rays=False).prepare(cooke)
    rss = rss_estimate(cooke, sm, names, t / 3 ** 0.5)
    mc = monte_carlo(cooke, sm, names, t, n=60, seed=1)
    assert rss["rss_um"][0] > rss["nominal_um"][0]
    assert mc["nominal_um"][0] == pytest.approx(rss["nominal_um"][0], rel=1e-9)
    assert mc["rms_um"][0] == pytest.approx(rss["rss_um"][0], rel=0.1)


def test_tolerance_files_and_names(cooke, tmp_path):
    names = tolerance_parameters(cooke)
    assert "misalignments.2.dx" not in names  # the stop is no glass element
    assert "misalignments.0.dx" in names and "surfaces.0.c" in names
    f = tmp_path / "tol.json"
    f.write_text(json.dumps({"misalignments.*.dy": 0.01, "surfaces.0.c": "1%"}))
    n, t = resolve_tolerances(cooke, load_tolerances(f))
    assert n == ["misalignments.0.dy", "misalignments.1.dy", "misalignments.3.dy",
                 "surfaces.0.c"]
    assert float(t[-1]) == pytest.approx(0.01 / 37.40)
    f.write_text(json.dumps({"misalignments.*.dz": 0.01}))
    with pytest.raises(ValueError, match="matches no tolerance parameter"):
        resolve_tolerances(cooke, load_tolerances(f))
    f.write_text(json.dumps({"distances.*": "ten"}))
    with pytest.raises(ValueError, match="expected a number or 'P%'"):
        load_tolerances(f)
    f.write_text("{")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_tolerances(f)
