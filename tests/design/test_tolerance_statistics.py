"""Monte Carlo tolerancing's statistics against a distribution known in closed form
("tests that a wrong implementation must not pass", issue 25).

The merit is replaced by ``ε = (θ_1 - θ_1⁰) + (θ_2 - θ_2⁰) + c`` (mm) of two lens parameters
drawn uniformly in ``±t``: a symmetric triangular distribution on ``c ± 2t``, whose mean ``c``,
RMS ``sqrt(c² + 2t²/3)`` and percentiles (``c - 2t + 2t sqrt(2p)`` below the median,
``c + 2t - 2t sqrt(2(1-p))`` above) are exact.  A draw shared between the parameters (uniform on
``c ± 2t``), a Gaussian draw, ``t`` taken as the standard deviation, an RMS about the mean or a
percentile off by one rank in ten all fail it.
"""

from __future__ import annotations

import math
import types

import pytest
import torch

import deeplens.design.tolerance as T
import helpers as H
from deeplens.optics.io import load_lens

N, TOL, C = 4000, 0.05, 0.2  # trials, half-width (mm), merit offset (mm)


@pytest.fixture(scope="module")
def mc():
    lens = load_lens(H.LENS_DIR / "cooke_triplet.json")
    names = ["distances.1", "distances.3"]
    nominal = [float(lens.distances[1]), float(lens.distances[3])]

    def merit_of(_merit, L):
        return torch.stack([L.distances[1] - nominal[0] + L.distances[3] - nominal[1] + C])

    fake = types.SimpleNamespace(fields=[0.0], strict_rays=True)
    mp = pytest.MonkeyPatch()
    mp.setattr(T, "field_merits", merit_of)
    try:
        yield T.monte_carlo(lens, fake, names, [TOL, TOL], n=N, seed=3)
    finally:
        mp.undo()


def _triangular_quantile(p: float) -> float:
    if p <= 0.5:
        return C - 2 * TOL + 2 * TOL * math.sqrt(2 * p)
    return C + 2 * TOL - 2 * TOL * math.sqrt(2 * (1 - p))


def _density(x: float) -> float:
    return max(0.0, 2 * TOL - abs(x - C)) / (4 * TOL ** 2)


def test_mean_and_rms_are_the_triangular_distributions(mc):
    """Statistical tolerances are four standard errors of each estimate at N trials."""
    var = 2 * TOL ** 2 / 3  # of the sum of two uniforms on ±t
    assert mc["nominal_um"][0] == pytest.approx(C * 1e3, rel=1e-12)
    mean, rms = mc["mean_um"][0] * 1e-3, mc["rms_um"][0] * 1e-3
    assert mean == pytest.approx(C, abs=4 * math.sqrt(var / N))
    # rms^2 = mean^2 + variance; the variance's relative standard error is sqrt((k - 1) / N)
    # with the triangular kurtosis k = 2.4
    assert rms ** 2 - mean ** 2 == pytest.approx(var, rel=4 * math.sqrt(1.4 / N))
    s = torch.tensor(mc["samples_um"], dtype=torch.float64)[:, 0] * 1e-3
    assert rms == pytest.approx(float(torch.sqrt((s * s).mean())), rel=1e-12)  # about zero
    assert float(s.min()) >= C - 2 * TOL and float(s.max()) <= C + 2 * TOL


@pytest.mark.parametrize("p", ["50", "90", "98"])
def test_percentiles_are_the_triangular_distributions(mc, p):
    """Within four standard errors of the sample quantile, ``sqrt(p(1-p)/N) / f(q)``."""
    f = int(p) / 100
    q = _triangular_quantile(f)
    se = math.sqrt(f * (1 - f) / N) / _density(q)
    assert mc["percentiles_um"][p][0] * 1e-3 == pytest.approx(q, abs=4 * se)
