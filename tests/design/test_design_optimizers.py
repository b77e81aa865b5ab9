"""Damped least squares, Adam and L-BFGS on problems with known solutions; Jacobians against
closed forms; infeasible and NaN steps rejected; bad input."""

import math

import pytest
import torch

from deeplens.design.optimizers import (Infeasible, adam, damped_least_squares, jacobian,
                                        lbfgs)

D = torch.float64


def _ls_problem():
    g = torch.Generator().manual_seed(1)
    A = torch.randn(20, 4, generator=g, dtype=D)
    b = torch.randn(20, generator=g, dtype=D)
    return A, b, torch.linalg.lstsq(A, b[:, None]).solution[:, 0]


@pytest.mark.parametrize("mode", ["forward", "reverse", "central"])
def test_dls_linear_least_squares(mode):
    A, b, xs = _ls_problem()
    res = damped_least_squares(lambda x: A @ x - b, torch.zeros(4, dtype=D), jacobian_mode=mode)
    assert torch.allclose(res.x, xs, atol=1e-8)
    assert res.merit <= res.merit0
    assert res.history[0]["merit"] == pytest.approx(float((b * b).sum()))


def test_dls_rosenbrock_and_history():
    ros = lambda x: torch.stack([10 * (x[1] - x[0] ** 2), 1 - x[0]])  # noqa: E731
    res = damped_least_squares(ros, torch.tensor([-1.2, 1.0], dtype=D), steps=200)
    assert torch.allclose(res.x, torch.ones(2, dtype=D), atol=1e-6)
    acc = [h["merit"] for h in res.history if h["accepted"]]
    assert all(b < a for a, b in zip(acc, acc[1:]))  # accepted steps decrease the merit
    assert res.rejected == sum(not h["accepted"] for h in res.history)


def test_jacobian_modes_match_closed_form():
    x = torch.tensor([0.3, -1.1, 2.0], dtype=D)
    fn = lambda x: torch.stack([x[0] * x[1], torch.sin(x[2]), x[0] ** 3 + x[2]])  # noqa: E731
    J_true = torch.tensor([[x[1], x[0], 0], [0, 0, math.cos(2.0)], [3 * x[0] ** 2, 0, 1]],
                          dtype=D)
    for mode in ("forward", "reverse", "auto"):
        r, J = jacobian(fn, x, mode)
        assert torch.allclose(J, J_true, atol=1e-14), mode
        assert torch.allclose(r, fn(x))
    # central differences: h = 1e-6 max(1, |x|), truncation h^2 |f'''| / 6 ~ 1e-12
    r, J = jacobian(fn, x, "central")
    assert torch.allclose(J, J_true, atol=1e-9, rtol=0)
    assert torch.allclose(r, fn(x))


def test_central_jacobian_costs_2n_evaluations_and_falls_back_at_a_boundary():
    calls = []

    def fn(x):
        calls.append(1)
        if float(x[0]) > 1.0:
            raise Infeasible("x0 beyond 1")
        return torch.stack([x[0] ** 2 * x[1], x[1] ** 3])

    x = torch.tensor([0.5, 2.0], dtype=D)
    J_true = torch.tensor([[2 * 0.5 * 2.0, 0.25], [0.0, 12.0]], dtype=D)
    _, J = jacobian(fn, x, "central")
    assert len(calls) == 2 * 2 + 1  # no graph, no tangents: plain evaluations only
    assert torch.allclose(J, J_true, atol=1e-8, rtol=0)
    # at x0 = 1 the point x0 + h is infeasible: forward mode takes over (exact)
    _, J = jacobian(fn, torch.tensor([1.0, 2.0], dtype=D), "central")
    assert torch.allclose(J, torch.tensor([[4.0, 1.0], [0.0, 12.0]], dtype=D), atol=1e-14)
    with pytest.raises(ValueError, match="float64"):
        jacobian(lambda x: (x * 2).float(), torch.zeros(2, dtype=D), "central")


def test_infeasible_and_nan_steps_are_rejected():
    """The unconstrained optimum (x = 3) lies where the function raises or returns NaN: every
    accepted iterate stays feasible and finite, and the rejections are recorded."""
    def fn(x):
        if float(x[0]) > 2.0:
            raise Infeasible("x beyond 2")
        return torch.stack([x[0] - 3.0, torch.sqrt(2.5 - x[0]) * 0.0])

    res = damped_least_squares(fn, torch.tensor([0.0], dtype=D), steps=100)
    assert 1.9 < float(res.x[0]) <= 2.0
    assert all(math.isfinite(h["merit"]) for h in res.history)
    reasons = [h["reason"] for h in res.history if not h["accepted"]]
    assert reasons and any("beyond 2" in r for r in reasons)


def test_bounds_are_kept():
    res = damped_least_squares(lambda x: x - 5.0, torch.zeros(2, dtype=D),
                               bounds=(None, torch.tensor([1.0, 10.0], dtype=D)))
    assert float(res.x[0]) == pytest.approx(1.0)
    assert float(res.x[1]) == pytest.approx(5.0, abs=1e-8)


def test_bad_input():
    with pytest.raises(ValueError, match="1-D"):
        damped_least_squares(lambda x: x, torch.zeros(2, 2, dtype=D))
    with pytest.raises(ValueError, match="not feasible"):
        damped_least_squares(lambda x: x / 0 * 0, torch.zeros(1, dtype=D))
    with pytest.raises(ValueError, match="outside its bounds"):
        damped_least_squares(lambda x: x, torch.zeros(1, dtype=D), bounds=(1.0, 2.0))
    with pytest.raises(ValueError, match="jacobian mode"):
        jacobian(lambda x: x, torch.zeros(1, dtype=D), "sideways")


def test_adam_and_lbfgs_reach_the_least_squares_solution():
    A, b, xs = _ls_problem()
    fn = lambda x: A @ x - b  # noqa: E731
    r = lbfgs(fn, torch.zeros(4, dtype=D), steps=100)
    assert torch.allclose(r.x, xs, atol=1e-6)
    r = adam(fn, torch.zeros(4, dtype=D), steps=1500, lr=0.05)
    assert torch.allclose(r.x, xs, atol=1e-3)
    assert r.merit < r.merit0
