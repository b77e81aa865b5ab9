"""Lens-level optimisation: a :class:`~.variables.Variables` set, a merit, constraints, a method.

The residual function handed to the optimiser is

    x  ->  merit residuals (+ constraint penalties)  of the lens with its variables set to x

evaluated through :meth:`Variables.call` (the lens itself is written only at the end).  A trial
``x`` is *infeasible* (rejected and damped by the optimiser, never a NaN) when the lens fails its
own geometry check (surfaces that cross, a semi-diameter beyond a conic's domain, a negative
gap), when an inequality constraint breaks, or when a ray that reached the image is lost.

Pupil regions are re-found between ``rounds`` (each round runs ``steps / rounds`` iterations),
so that a design whose vignetting changes is re-sampled.
"""

from __future__ import annotations

import time
import warnings
from collections import Counter
from dataclasses import dataclass, field

import torch

from ..optics.camera import Camera, unpack
from .constraints import ConstraintSet, check_start, variable_bounds
from .optimizers import Infeasible, OptimResult, adam, damped_least_squares, lbfgs
from .variables import on_camera

__all__ = ["optimize_lens", "LensOptResult", "lens_residual_fn"]

METHODS = ("dls", "adam", "lbfgs")


@dataclass
class LensOptResult:
    """``merit_before``/``merit_after`` (``sum r^2``), the variables before/after in their own
    units, the optimiser results of each round, steps and seconds."""

    merit_before: float
    merit_after: float
    variables_before: dict
    variables_after: dict
    rounds: list = field(default_factory=list)
    steps: int = 0
    seconds: float = 0.0
    reason: str = ""

    @property
    def history(self) -> list:
        return [h for r in self.rounds for h in r.history]

    @property
    def accepted(self) -> int:
        """Accepted steps (the starting points of the rounds not counted)."""
        return sum(1 for h in self.history if h["accepted"] and h["step"] > 0)

    @property
    def rejected(self) -> int:
        """Rejected trial steps."""
        return sum(r.rejected for r in self.rounds)

    def rejections(self) -> list:
        """``[(reason, count), ...]`` of the rejected trials, most frequent first."""
        return Counter(h.get("reason", "") for h in self.history
                       if not h["accepted"]).most_common()

    def rejection_kinds(self) -> list:
        """``[(kind, count), ...]`` (``"vignetted"``, ``"geometry"``, ``"constraint"``,
        ``"no_decrease"``, ``"non_finite"``, ...), most frequent first."""
        return Counter(h.get("kind", "infeasible") for h in self.history
                       if not h["accepted"]).most_common()


def lens_residual_fn(variables, merit, constraints=(), camera: Camera | None = None):
    """``x -> residuals`` for :func:`~.optimizers.damped_least_squares` (module docstring);
    with a ``camera`` (holding the variables' lens) the merit sees the lens through it, so its
    options reach every trace (:func:`~.variables.on_camera`)."""
    cset = ConstraintSet(constraints)

    def on_lens(L):
        with warnings.catch_warnings():
            # the geometry checks read substituted values that carry autograd/tangents
            warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad")
            return _on_lens(L)

    def _on_lens(L):
        try:
            L.check()
        except ValueError as e:
            raise Infeasible(f"the lens is not valid: {e}", kind="geometry") from None
        bad = cset.broken(L)
        if bad:
            raise Infeasible("constraint broken: " + "; ".join(bad), kind="constraint")
        r = merit.residuals(on_camera(camera, L))
        if cset.constraints:
            r = torch.cat([r, cset.residuals(L).to(r)])
        return r

    def fn(x):
        return variables.call(on_lens, x)

    fn.needs_grad = any(n.startswith("misalignments.") for n in variables.names)
    return fn


def optimize_lens(lens, variables, merit, *, method: str = "dls", steps: int = 50,
                  constraints=(), rounds: int = 1, lam0: float = 1e-3, lr: float = 1e-2,
                  jacobian_mode: str = "auto", callback=None, bounds=None) -> LensOptResult:
    """Optimise ``variables`` of ``lens`` for ``merit``; writes the result into ``lens``.

    Args:
        lens: the lens (float64 recommended for DLS), or a
            :class:`~deeplens.optics.camera.Camera` (its lens is optimised and its options
            reach every trace of the merit: preparation and every evaluation).
        variables: :class:`~.variables.Variables` of ``lens``.
        merit: an object with ``prepare(lens)`` and ``residuals(lens)`` (e.g. :class:`~.merit.Merit`).
        method: ``"dls"`` (damped least squares), ``"adam"`` or ``"lbfgs"``.
        steps: iterations in all (split over ``rounds``).
        constraints: :class:`~.constraints.Constraint` objects; inequalities must hold at the
            start (else :class:`~.constraints.ConstraintError` names them).
        rounds: pupil regions are re-found before each round.
        lam0, lr: DLS initial damping; Adam learning rate (in scaled units, mm of sag).
        jacobian_mode: DLS Jacobian (``auto``, ``forward``, ``reverse``, ``central``; see
            :func:`~.optimizers.jacobian`).
        callback: ``callback(iteration, x, merit)``.
        bounds: ``(lower, upper)`` on the scaled variables (combined with constraint bounds).

    Raises:
        ValueError: an unknown method or bad step counts; ConstraintError (a ValueError) for
            constraints unmet at the start.
    """
    if method not in METHODS:
        raise ValueError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
    if steps < 1 or rounds < 1:
        raise ValueError(f"steps and rounds must be >= 1, got steps={steps}, rounds={rounds}")
    t0 = time.perf_counter()
    camera = lens if isinstance(lens, Camera) else None
    lens = unpack(lens, where="optimize_lens")[0]
    if camera is not None and variables.lens is not lens:
        raise ValueError("optimize_lens: the variables belong to another lens than the camera's")
    constraints = list(constraints)
    check_start(lens, constraints)
    lo, hi = variable_bounds(variables, constraints)
    if bounds is not None:
        blo, bhi = (torch.as_tensor(b, dtype=torch.float64).expand(len(variables))
                    if b is not None else None for b in bounds)
        if blo is not None:
            lo = torch.maximum(lo, blo)
        if bhi is not None:
            hi = torch.minimum(hi, bhi)
    box = None if bool(torch.isinf(lo).all() & torch.isinf(hi).all()) else (lo, hi)
    before = variables.as_dict()
    results: list[OptimResult] = []
    per = [steps // rounds + (1 if k < steps % rounds else 0) for k in range(rounds)]
    merit_before = None
    done = 0
    for k, n in enumerate(per):
        if n == 0:
            continue
        merit.prepare(on_camera(camera, lens))
        fn = lens_residual_fn(variables, merit, constraints, camera)
        x0 = variables.x0()
        if method == "dls":
            res = damped_least_squares(fn, x0, steps=n, lam0=lam0, bounds=box, callback=callback,
                                       jacobian_mode=jacobian_mode)
        elif method == "adam":
            res = adam(fn, x0, steps=n, lr=lr, bounds=box, callback=callback)
        else:
            res = lbfgs(fn, x0, steps=n, bounds=box, callback=callback)
        variables.assign(res.x)
        results.append(res)
        done += res.steps
        if merit_before is None:
            merit_before = res.merit0
    return LensOptResult(merit_before=merit_before, merit_after=results[-1].merit,
                         variables_before=before, variables_after=variables.as_dict(),
                         rounds=results, steps=done, seconds=time.perf_counter() - t0,
                         reason=results[-1].reason)
