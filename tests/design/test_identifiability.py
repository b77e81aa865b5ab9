"""Fit uncertainties (issue 25, item 14): against the closed form of linear least squares, the
degenerate pairs flagged, and the misalignment app reporting them."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.design.identifiability import fit_uncertainty
from deeplens.design.misalignment import (PARAMS, SpotSetup, estimate_uncertainty,
                                          synthesize_target)


def _linear(A, b):
    return lambda th: A @ th - b


def test_covariance_equals_the_linear_least_squares_closed_form():
    """``r = A θ - b`` with noise: Cov = σ² (AᵀA)⁻¹, σ² = |r̂|²/(m - n) at the least-squares
    solution (units differ by 1e4 between columns: the column scaling must not change it)."""
    g = torch.Generator().manual_seed(0)
    A = torch.randn(40, 3, generator=g, dtype=torch.float64) * torch.tensor([1.0, 1e-4, 3.0],
                                                                            dtype=torch.float64)
    b = A @ torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64) + 0.1 * torch.randn(
        40, generator=g, dtype=torch.float64)
    th = torch.linalg.lstsq(A, b[:, None]).solution[:, 0]
    u = fit_uncertainty(_linear(A, b), th, ["a", "b", "c"])
    r = A @ th - b
    s2 = float(r @ r) / (40 - 3)
    cov = s2 * torch.linalg.inv(A.T @ A)
    assert u.sigma == pytest.approx(math.sqrt(s2), rel=1e-12)
    for i, k in enumerate("abc"):
        assert u.std[k] == pytest.approx(math.sqrt(float(cov[i, i])), rel=1e-9)
        for j, q in enumerate("abc"):
            assert u.correlation[k][q] == pytest.approx(
                float(cov[i, j]) / math.sqrt(float(cov[i, i] * cov[j, j])), abs=1e-9)
    assert u.not_identifiable == {}
    fixed = fit_uncertainty(_linear(A, b), th, ["a", "b", "c"], sigma=0.5)
    assert fixed.std["a"] == pytest.approx(0.5 * math.sqrt(float(cov[0, 0]) / s2), rel=1e-9)


def test_nearly_degenerate_and_too_uncertain_parameters_are_named():
    g = torch.Generator().manual_seed(1)
    A = torch.randn(30, 3, generator=g, dtype=torch.float64)
    A[:, 2] = A[:, 0] + 1e-3 * A[:, 1]  # c is nearly a
    b = torch.randn(30, generator=g, dtype=torch.float64)
    th = torch.linalg.lstsq(A, b[:, None]).solution[:, 0]
    u = fit_uncertainty(_linear(A, b), th, ["a", "b", "c"], scale=[1e9, 1e-6, 1e9])
    assert set(u.not_identifiable) == {"a", "b", "c"}
    assert "correlation" in u.not_identifiable["a"]
    assert u.correlation["a"]["c"] < -0.99 or u.correlation["a"]["c"] > 0.99
    assert u.condition > 1e3


def test_misalignment_small_tilts_trade_against_the_source_position():
    """A spot image with small tilts: the estimate's tilt and the source's lateral position are
    nearly degenerate (issue 25, item 14), which the uncertainty report names."""
    st = SpotSetup(pixel_size_mm=0.01, resolution=(96, 96), binning=4, n_rays=3000)
    truth = dict(zip(PARAMS, [0.013, -0.009, 46.45, 0.4, -0.3]))
    target = synthesize_target(st, truth, noise=True, seed=1)
    u = estimate_uncertainty(target, st, truth)
    assert all(u.std[k] > 0 and math.isfinite(u.std[k]) for k in PARAMS)
    assert abs(u.correlation["tilt_x"]["source_y"]) > 0.95
    assert {"tilt_x", "source_y"} <= set(u.not_identifiable)
    assert 1e-3 < u.sigma < 0.1  # the synthetic image's noise, in units of its peak
