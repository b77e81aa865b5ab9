"""The convergence rule of the glass substitution's reference (issue 36, item 4):
:func:`deeplens.design.search.converge.until_converged` on a quadratic whose rounds are known
in closed form.

``f(x) = 1 + x²`` and a round halves ``x``: from ``x_0 = 10`` round ``j`` gives
``f_j = 1 + 100 / 4^j`` and improves by ``(f_{j-1} - f_j) / f_{j-1} = 0.75 y / (1 + y)``,
``y = 100 / 4^(j-1)``.  That is below ``tol`` when ``y < tol / (0.75 - tol)``: for
``tol = 0.05``, ``y < 1 / 14``, ``4^(j-1) > 1400``, first at ``j = 7`` (``4^5 = 1024``,
``4^6 = 4096``).
"""

from __future__ import annotations

import pytest
import torch

from deeplens.design.search.converge import until_converged


def _halve(x: torch.Tensor) -> float:
    x.mul_(0.5)
    return float(1.0 + x * x)


def test_stops_at_the_first_round_below_the_tolerance():
    x0 = torch.tensor(10.0, dtype=torch.float64)
    out = until_converged(x0, _halve, 101.0, rel_tol=0.05, max_rounds=50)
    assert out.reason == "converged" and out.rounds == 7
    assert float(out.state) == 10.0 / 2 ** 7                     # that round is kept
    assert out.value == 1.0 + 100.0 / 4 ** 7
    assert out.history == [1.0 + 100.0 / 4 ** j for j in range(8)]
    gains = [(a - b) / a for a, b in zip(out.history, out.history[1:])]
    assert all(g >= 0.05 for g in gains[:-1]) and gains[-1] < 0.05
    assert float(x0) == 10.0                                      # the input is not changed


def test_max_rounds_and_zero_rounds():
    x0 = torch.tensor(10.0, dtype=torch.float64)
    out = until_converged(x0, _halve, 101.0, rel_tol=0.05, max_rounds=3)
    assert out.reason == "max_rounds" and out.rounds == 3 and float(out.state) == 1.25
    out = until_converged(x0, _halve, 101.0, max_rounds=0)
    assert out.rounds == 0 and out.state is x0 and out.value == 101.0


def test_a_round_that_is_worse_or_fails_is_thrown_away():
    def step(x):   # improves twice (10 -> 5.5 -> 1), then overshoots to -3.5 (f = 13.25 > 2)
        x.copy_(x - 4.5 if float(x) > 0 else x)
        return float(1.0 + x * x)

    out = until_converged(torch.tensor(10.0, dtype=torch.float64), step, 101.0, 0.0, 10)
    assert out.reason == "no improvement" and out.rounds == 3
    assert float(out.state) == 1.0 and out.value == 2.0 and out.history == [101.0, 31.25, 2.0]

    def fail(x):
        raise RuntimeError("no ray reaches the image")

    out = until_converged(torch.tensor(1.0), fail, 2.0)
    assert out.reason.startswith("failed: RuntimeError: no ray") and out.value == 2.0


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="starting value > 0"):
        until_converged(0, _halve, 0.0)
    with pytest.raises(ValueError, match="rel_tol must be"):
        until_converged(0, _halve, 1.0, rel_tol=-0.1)
    with pytest.raises(ValueError, match="max_rounds must be >= 0"):
        until_converged(0, _halve, 1.0, max_rounds=-1)
