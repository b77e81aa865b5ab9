r"""Run a local optimiser in rounds until a round no longer pays (issue 36, item 4).

The glass substitution compares two designs, the model-glass design and the real-glass one;
the comparison is fair only when both are converged under the same rule, or the one given
more steps wins by its budget, not by its glasses.  :func:`until_converged` is that rule: from
a state with value ``v_0 > 0`` (lower is better), round ``j`` runs ``step`` on a copy and gives
``v_j``; it stops after the first round whose relative improvement

.. code-block:: text

    (v_{j-1} - v_j) / v_{j-1}  <  rel_tol

(that round is kept), after ``max_rounds`` rounds, or at a round that fails or does not
improve (that round is thrown away: the state before it is returned).  So the value returned
is never worse than ``v_0``.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Callable

from ..optimizers import Infeasible

__all__ = ["Convergence", "until_converged"]


@dataclass
class Convergence:
    """What :func:`until_converged` did.

    Attributes:
        state: the best state (the input object itself when no round was kept).
        value: its value.
        history: ``[v_0, v_1, ...]``, the value after each kept round (``v_0`` the start's).
        rounds: rounds run (kept or not).
        reason: ``"converged"`` (a kept round improved by less than ``rel_tol``),
            ``"max_rounds"``, ``"no improvement"`` (the last round was not better; thrown
            away) or ``"failed: <error>"`` (the last round raised; thrown away).
    """

    state: object
    value: float
    history: list = field(default_factory=list)
    rounds: int = 0
    reason: str = ""

    def to_dict(self) -> dict:
        """JSON-able: everything but the state."""
        return {"value": self.value, "history": list(self.history), "rounds": self.rounds,
                "reason": self.reason}


def until_converged(state, step: Callable[[object], float], value: float,
                    rel_tol: float = 0.01, max_rounds: int = 8) -> Convergence:
    """Repeat ``step`` on copies of ``state`` until the module docstring's rule stops it.

    Args:
        state: anything :func:`copy.deepcopy` copies (a lens); never modified.
        step: ``step(trial) -> value``, one round on ``trial`` (a copy; changed in place);
            lower is better.  A ``ValueError``, ``RuntimeError``, ``ArithmeticError`` or
            :class:`~deeplens.design.optimizers.Infeasible` ends the run (the round is
            thrown away).
        value: ``state``'s value, finite and ``> 0``.
        rel_tol: the relative improvement below which a round ends the run, ``>= 0``
            (0: run until a round does not improve or ``max_rounds``).
        max_rounds: at most this many rounds, ``>= 0``.

    Returns:
        :class:`Convergence`.

    Raises:
        ValueError: a ``value`` that is not finite and positive, a negative ``rel_tol`` or
            ``max_rounds``.
    """
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"until_converged needs a finite starting value > 0, got {value!r}")
    if not (math.isfinite(float(rel_tol)) and float(rel_tol) >= 0):
        raise ValueError(f"rel_tol must be a finite number >= 0, got {rel_tol!r}")
    if int(max_rounds) < 0:
        raise ValueError(f"max_rounds must be >= 0, got {max_rounds!r}")
    out = Convergence(state, value, [value], 0, "max_rounds")
    for _ in range(int(max_rounds)):
        trial = copy.deepcopy(out.state)
        out.rounds += 1
        try:
            v = float(step(trial))
        except (ValueError, RuntimeError, ArithmeticError, Infeasible) as e:
            out.reason = f"failed: {type(e).__name__}: {e}"
            break
        if not (math.isfinite(v) and v < out.value):
            out.reason = "no improvement"
            break
        gain = (out.value - v) / out.value
        out.state, out.value = trial, v
        out.history.append(v)
        if gain < rel_tol:
            out.reason = "converged"
            break
    return out
