"""Optimisers over a flat variable vector: damped least squares, Adam, L-BFGS.

Damped least squares (Levenberg-Marquardt with Marquardt's scaling) minimises the merit
``F(x) = sum_i r_i(x)^2`` of a residual vector ``r`` (``m`` values, ``n`` variables) by solving

    (J^T J + λ D) δ = -J^T r,        D = diag(J^T J)  (floored at 1e-12 · max diag)

for the step ``δ`` at each iterate, ``J = ∂r/∂x`` the ``(m, n)`` Jacobian.  The gain ratio
``ρ = (F(x) - F(x + δ)) / (F(x) - |r + J δ|^2)`` drives the damping (Nielsen's rule: accepted
steps shrink ``λ`` by ``max(1/3, 1 - (2ρ - 1)^3)``, rejected ones grow it by ``ν = 2, 4, 8...``).
A trial step is *rejected* (never accepted, never propagated) when the residual function raises
:class:`Infeasible` (surfaces that cross, rays that are lost, a constraint left) or returns a
non-finite value; the damping then grows, so the next trial is shorter.

The Jacobian is built by forward-mode AD (``n`` Jacobian-vector products with
:mod:`torch.autograd.forward_ad`, one per variable: cheap when ``n`` is small, the paper's
Eq. 10 direction), by reverse mode (one forward pass, ``m`` vector-Jacobian products batched
with ``is_grads_batched``), or by central differences in float64 (``mode="central"``:
``J e_j = (r(x + h_j e_j) - r(x - h_j e_j)) / 2 h_j``, ``h_j = 10^-6 max(1, |x_j|)`` in the scaled
variables, i.e. a micrometre of sag: truncation ``O(h^2)`` and rounding ``~ 10^-16 |r| / h``
both stay near ``10^-10`` relative).  On the lens tracer's small bundles a forward-mode JVP costs
~15 plain traces (per-op overhead; the Newton intersections carry tangents too) and a central
column 2 traces without a graph, so ``central`` is the cheapest for tens of variables;
``mode="auto"`` picks forward when ``n <= m``.

Adam and L-BFGS minimise a scalar (``F`` of a residual function, or any loss) for problems with
many variables (freeforms), where the Jacobian is too large to form.

All functions take and return plain tensors ``x`` of shape ``(n,)``; nothing here knows about
lenses (see :mod:`deeplens.design.lensopt` for the lens-level wrappers).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import torch
import torch.autograd.forward_ad as fwAD

__all__ = ["Infeasible", "OptimResult", "jacobian", "damped_least_squares", "adam", "lbfgs"]


class Infeasible(Exception):
    """Raised by a residual/loss function for a point it cannot (or must not) evaluate: the
    optimiser rejects the step and damps; the message is kept in the history (``"reason"``),
    and ``kind`` (e.g. ``"vignetted"``, ``"geometry"``, ``"constraint"``) beside it so that
    callers can act on the kind without reading the text."""

    def __init__(self, message: str = "", kind: str = "infeasible"):
        super().__init__(message)
        self.kind = kind


@dataclass
class OptimResult:
    """Result of an optimisation.

    Attributes:
        x: final variables ``(n,)`` (detached).
        merit: final merit ``sum r^2`` (DLS) or loss (Adam, L-BFGS).
        merit0: merit at ``x0``.
        history: one dict per iteration: ``{"step", "merit", "x" (list), "accepted", ...}``
            (DLS adds ``"lambda"`` and, for rejected trials, ``"reason"`` and ``"kind"``: the
            :class:`Infeasible` kind, ``"non_finite"`` or ``"no_decrease"``).
        steps: iterations run (Jacobian evaluations for DLS).
        evaluations: residual/loss evaluations.
        reason: why it stopped.
        seconds: wall time.
        rejected: number of rejected trial steps.
    """

    x: torch.Tensor
    merit: float
    merit0: float
    history: list = field(default_factory=list)
    steps: int = 0
    evaluations: int = 0
    reason: str = ""
    seconds: float = 0.0
    rejected: int = 0


def _check_x0(x0, name="x0") -> torch.Tensor:
    if not isinstance(x0, torch.Tensor):
        x0 = torch.as_tensor(x0, dtype=torch.float64)
    if x0.dim() != 1 or x0.numel() == 0:
        raise ValueError(f"{name} must be a non-empty 1-D tensor of variables, got shape "
                         f"{tuple(x0.shape)}")
    if not torch.isfinite(x0).all():
        raise ValueError(f"{name} has non-finite entries: {x0.tolist()}")
    return x0.detach().clone()


def _bounds(bounds, x0):
    """``(lo, hi)`` tensors like ``x0`` (``-inf``/``inf`` where unbounded), or ``(None, None)``."""
    if bounds is None:
        return None, None
    lo, hi = bounds
    n = x0.numel()

    def full(v, fill):
        if v is None:
            return torch.full_like(x0, fill)
        t = torch.as_tensor(v, dtype=x0.dtype, device=x0.device)
        if t.dim() == 0:
            t = t.expand(n)
        if t.shape != (n,):
            raise ValueError(f"bounds must be scalars or have {n} entries, got shape "
                             f"{tuple(t.shape)}")
        return torch.nan_to_num(t.clone(), nan=fill)

    lo, hi = full(lo, -math.inf), full(hi, math.inf)
    bad = (lo > hi).nonzero().flatten().tolist()
    if bad:
        raise ValueError(f"bounds: lower > upper for variable(s) {bad}")
    out = ((x0 < lo) | (x0 > hi)).nonzero().flatten().tolist()
    if out:
        i = out[0]
        raise ValueError(f"x0[{i}] = {float(x0[i]):.6g} lies outside its bounds "
                         f"[{float(lo[i]):.6g}, {float(hi[i]):.6g}] ({len(out)} variable(s) out)")
    return lo, hi


def _project(x, lo, hi):
    return x if lo is None else torch.maximum(torch.minimum(x, hi), lo)


def jacobian(fn, x: torch.Tensor, mode: str = "auto", m: int | None = None):
    """``(r, J)``: the residual ``r = fn(x)`` ``(m,)`` and its Jacobian ``J`` ``(m, n)``.

    Args:
        fn: ``x (n,) -> r (m,)``, differentiable with torch (forward mode needs every op to
            support forward AD; the lens tracer does).
        x: ``(n,)`` point.
        mode: ``"forward"`` (``n`` JVPs), ``"reverse"`` (one graph, ``m`` batched VJPs),
            ``"central"`` (``2 n`` evaluations without a graph; float64 only; a difference point
            that raises :class:`Infeasible` falls back to forward mode for this Jacobian) or
            ``"auto"`` (forward when ``n <= m``; ``m`` from a first evaluation if not given).

    Raises:
        ValueError: an unknown mode, or ``central`` on a function that is not float64.
    """
    x = x.detach()
    n = x.numel()
    if mode not in ("auto", "forward", "reverse", "central"):
        raise ValueError(f"jacobian mode must be auto, forward, reverse or central, got {mode!r}")
    if mode == "central":
        try:
            return _central_jacobian(fn, x)
        except Infeasible:  # a difference point left the feasible region
            mode = "forward"
    if mode == "auto":
        if m is None:
            with torch.no_grad():
                m = fn(x).numel()
        mode = "forward" if n <= m else "reverse"
    if mode == "forward":
        cols, r = [], None
        eye = torch.eye(n, dtype=x.dtype, device=x.device)
        # requires_grad keeps modules that skip identity transforms of frozen zeros (lens
        # misalignments) on their differentiable path; a function that needs no such care says
        # so with ``fn.needs_grad = False`` (recording the graph costs time)
        rg = bool(getattr(fn, "needs_grad", True))
        for j in range(n):
            with fwAD.dual_level(), torch.enable_grad():
                xd = fwAD.make_dual(x.clone().requires_grad_(rg), eye[j])
                out = fn(xd)
                primal, tangent = fwAD.unpack_dual(out)
                if tangent is None:  # the output does not depend on x
                    tangent = torch.zeros_like(primal)
                cols.append(tangent.detach())
                if r is None:
                    r = primal.detach()
        return r, torch.stack(cols, -1)
    xr = x.clone().requires_grad_(True)
    with torch.enable_grad():
        out = fn(xr)
    m = out.numel()
    if not out.requires_grad:
        return out.detach(), torch.zeros(m, n, dtype=x.dtype, device=x.device)
    eye = torch.eye(m, dtype=out.dtype, device=out.device)
    try:
        (J,) = torch.autograd.grad(out, xr, eye, is_grads_batched=True, allow_unused=True)
    except RuntimeError:  # an op without a batching rule: one VJP per residual
        rows = []
        for i in range(m):
            (g,) = torch.autograd.grad(out[i], xr, retain_graph=True, allow_unused=True)
            rows.append(torch.zeros_like(x) if g is None else g)
        J = torch.stack(rows)
    if J is None:
        J = torch.zeros(m, n, dtype=x.dtype, device=x.device)
    return out.detach(), J.detach()


def _central_jacobian(fn, x):
    """``(r, J)`` by central differences (module docstring); raises :class:`Infeasible`."""
    with torch.no_grad():
        r = fn(x).detach()
        if r.dtype != torch.float64:
            raise ValueError(f"central-difference Jacobians need float64 residuals (the step "
                             f"is 1e-6), got {r.dtype}: convert the lens with .to(torch.float64)")
        cols = []
        for j in range(x.numel()):
            h = 1e-6 * max(1.0, abs(float(x[j])))
            e = torch.zeros_like(x)
            e[j] = h
            cols.append((fn(x + e).detach() - fn(x - e).detach()) / (2.0 * h))
    return r, torch.stack(cols, -1)


def _evaluate(fn, x):
    """``(r, None, None)`` or ``(None, reason, kind)`` for an infeasible or non-finite point."""
    try:
        with torch.no_grad():
            r = fn(x)
    except Infeasible as e:
        return None, str(e), e.kind
    if not torch.isfinite(r).all():
        return None, "the residuals are not finite", "non_finite"
    return r.detach(), None, None


def damped_least_squares(residual_fn, x0, *, steps: int = 50, lam0: float = 1e-3,
                         bounds=None, callback=None, jacobian_mode: str = "auto",
                         ftol: float = 1e-10, xtol: float = 1e-12, gtol: float = 1e-14,
                         max_rejects: int = 30) -> OptimResult:
    """Levenberg-Marquardt with Marquardt scaling (module docstring).

    Args:
        residual_fn: ``x (n,) -> r (m,)``; may raise :class:`Infeasible` for points it rejects.
        x0: ``(n,)`` starting point; must be feasible and give finite residuals.
        steps: maximum number of iterations (Jacobian evaluations).
        lam0: initial damping ``λ`` (relative to ``diag(J^T J)``).
        bounds: ``(lower, upper)`` (scalars, ``(n,)`` tensors or ``None``): trial points are
            projected onto the box.
        callback: ``callback(iteration, x, merit)`` after each accepted step; returning
            ``True`` stops.
        jacobian_mode: see :func:`jacobian`.
        ftol: stop when an accepted step decreases the merit by less than ``ftol · merit``.
        xtol: stop when the step is below ``xtol · (|x| + xtol)``.
        gtol: stop when ``max |J^T r|`` falls below ``gtol``.
        max_rejects: consecutive rejected trials before giving up.

    Returns:
        :class:`OptimResult`.

    Raises:
        ValueError: ``x0`` is not a finite 1-D tensor, lies outside ``bounds``, or is itself
            infeasible / gives non-finite residuals (the message says why).

    Example:
        >>> A = torch.tensor([[1., 0], [1, 1], [1, 2]], dtype=torch.float64)
        >>> b = torch.tensor([1., 2, 2], dtype=torch.float64)
        >>> res = damped_least_squares(lambda x: A @ x - b, torch.zeros(2, dtype=A.dtype))
        >>> torch.allclose(res.x, torch.linalg.lstsq(A, b).solution)
        True
    """
    t_start = time.perf_counter()
    x = _check_x0(x0)
    lo, hi = _bounds(bounds, x)
    r, why, _ = _evaluate(residual_fn, x)
    if r is None:
        raise ValueError(f"damped least squares: the starting point is not feasible: {why}")
    F = float((r * r).sum())
    merit0 = F
    lam, nu = float(lam0), 2.0
    history = [{"step": 0, "merit": F, "x": x.tolist(), "lambda": lam, "accepted": True}]
    evals, rejected, reason, it = 1, 0, f"reached the step limit ({steps})", 0
    for it in range(1, steps + 1):
        r, J = jacobian(residual_fn, x, jacobian_mode, m=r.numel())
        evals += {"reverse": 1, "central": 2 * J.shape[1] + 1}.get(jacobian_mode, J.shape[1])
        g = J.T @ r
        if float(g.abs().max()) < gtol:
            reason = f"gradient below gtol ({gtol:g})"
            it -= 1
            break
        A = J.T @ J
        d = torch.diagonal(A).clone()
        d = torch.clamp(d, min=1e-12 * max(float(d.max()), 1e-300))
        accepted = False
        fails = 0
        while not accepted:
            M = A + lam * torch.diag(d)
            try:
                delta = torch.linalg.solve(M, -g)
            except RuntimeError:
                delta = torch.linalg.lstsq(M, -g[:, None]).solution[:, 0]
            x_try = _project(x + delta, lo, hi)
            delta = x_try - x
            if float(delta.abs().max()) <= xtol * (float(x.abs().max()) + xtol):
                reason = f"step below xtol ({xtol:g})"
                break
            r_try, why, kind = _evaluate(residual_fn, x_try)
            evals += 1
            pred = F - float(((r + J @ delta) ** 2).sum())
            if r_try is not None:
                F_try = float((r_try * r_try).sum())
                rho = (F - F_try) / pred if pred > 0 else -1.0
                if F_try < F and rho > 0:
                    accepted = True
                    lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                    nu = 2.0
                    dF = F - F_try
                    x, r, F = x_try, r_try, F_try
                    history.append({"step": it, "merit": F, "x": x.tolist(), "lambda": lam,
                                    "accepted": True})
                    break
                why, kind = "the merit did not decrease", "no_decrease"
            rejected += 1
            fails += 1
            history.append({"step": it, "merit": F, "x": x.tolist(), "lambda": lam,
                            "accepted": False, "reason": why, "kind": kind,
                            "merit_trial": None if r_try is None else F_try,
                            "x_trial": x_try.tolist()})
            lam *= nu
            nu *= 2.0
            if fails >= max_rejects or lam > 1e20:
                reason = (f"no acceptable step after {fails} trials (last: {why}); the merit "
                          f"cannot be decreased further from here")
                break
        if not accepted:
            break
        if callback is not None and callback(it, x.clone(), F):
            reason = "stopped by callback"
            break
        if dF < ftol * max(F, 1e-300):
            reason = f"relative merit decrease below ftol ({ftol:g})"
            break
    return OptimResult(x=x, merit=F, merit0=merit0, history=history, steps=it, evaluations=evals,
                       reason=reason, seconds=time.perf_counter() - t_start, rejected=rejected)


def _loss_of(fn, kind):
    """Wrap a residual function as a scalar loss ``sum r^2``; a loss function stays as is."""
    if kind == "residual":
        return lambda x: (fn(x) ** 2).sum()
    if kind == "loss":
        return fn
    raise ValueError(f"objective kind must be 'residual' or 'loss', got {kind!r}")


def adam(fn, x0, *, steps: int = 200, lr: float = 1e-2, objective: str = "residual",
         bounds=None, callback=None, betas=(0.9, 0.999), ftol: float = 0.0) -> OptimResult:
    """Adam on ``x`` (in the variables' scaled units, so ``lr`` is a step size in them).

    Args:
        fn: residual function ``x -> r (m,)`` (``objective="residual"``, minimises ``sum r^2``)
            or scalar loss ``x -> L`` (``objective="loss"``).
        steps: iterations.  lr: learning rate.  bounds: projected after each step.
        callback: ``callback(iteration, x, loss)``; returning ``True`` stops.
        ftol: stop when the best loss has not improved by ``ftol`` relative in 20 steps (0: off).

    A step whose loss is non-finite or that raises :class:`Infeasible` is undone, and the
    learning rate halved.  The result holds the best point seen.
    """
    t_start = time.perf_counter()
    loss_fn = _loss_of(fn, objective)
    x = _check_x0(x0)
    lo, hi = _bounds(bounds, x)
    p = x.clone().requires_grad_(True)
    opt = torch.optim.Adam([p], lr=lr, betas=betas)
    history, best, best_x, rejected, reason = [], math.inf, x.clone(), 0, f"reached {steps} steps"
    merit0, since_best, it = None, 0, 0
    for it in range(1, steps + 1):
        prev = p.detach().clone()
        opt.zero_grad()
        try:
            with torch.enable_grad():
                L = loss_fn(p)
            ok = bool(torch.isfinite(L))
        except Infeasible as e:
            ok, why = False, str(e)
        if ok:
            L.backward()
            ok = bool(torch.isfinite(p.grad).all())
            why = "non-finite gradient"
        else:
            why = locals().get("why", "non-finite loss")
        if not ok:
            if merit0 is None:
                raise ValueError(f"adam: the starting point is not feasible: {why}")
            rejected += 1
            with torch.no_grad():
                p.copy_(best_x)
            for g in opt.param_groups:
                g["lr"] *= 0.5
            history.append({"step": it, "merit": best, "x": p.detach().tolist(),
                            "accepted": False, "reason": why})
            continue
        Lf = float(L.detach())
        if merit0 is None:
            merit0 = Lf
        if Lf < best * (1 - ftol) or Lf < best:
            since_best = 0 if Lf < best * (1 - ftol) else since_best + 1
            best, best_x = Lf, prev
        else:
            since_best += 1
        history.append({"step": it, "merit": Lf, "x": prev.tolist(), "accepted": True})
        if callback is not None and callback(it, prev, Lf):
            reason = "stopped by callback"
            break
        if ftol > 0 and since_best >= 20:
            reason = f"no relative improvement above ftol ({ftol:g}) in 20 steps"
            break
        opt.step()
        if lo is not None:
            with torch.no_grad():
                p.copy_(_project(p, lo, hi))
    # evaluate the last iterate too
    try:
        with torch.no_grad():
            L = float(loss_fn(p.detach()))
        if math.isfinite(L) and L < best:
            best, best_x = L, p.detach().clone()
    except Infeasible:
        pass
    return OptimResult(x=best_x, merit=best, merit0=merit0, history=history, steps=it,
                       evaluations=it + 1, reason=reason, seconds=time.perf_counter() - t_start,
                       rejected=rejected)


def lbfgs(fn, x0, *, steps: int = 50, lr: float = 1.0, objective: str = "residual",
          bounds=None, callback=None, history_size: int = 20) -> OptimResult:
    """L-BFGS with strong-Wolfe line search (:class:`torch.optim.LBFGS`); one outer step per
    iteration.  Infeasible or non-finite points count as ``+inf`` for the line search;
    ``bounds`` are applied by projection after each step."""
    t_start = time.perf_counter()
    loss_fn = _loss_of(fn, objective)
    x = _check_x0(x0)
    lo, hi = _bounds(bounds, x)
    p = x.clone().requires_grad_(True)
    # max_eval bounds the line search too (its default, 1.25 max_iter, would stop it at once)
    opt = torch.optim.LBFGS([p], lr=lr, max_iter=1, max_eval=30, history_size=history_size,
                            line_search_fn="strong_wolfe")
    evals = [0]
    with torch.no_grad():
        try:
            merit0 = float(loss_fn(x))
        except Infeasible as e:
            raise ValueError(f"lbfgs: the starting point is not feasible: {e}") from None
    if not math.isfinite(merit0):
        raise ValueError("lbfgs: the loss at the starting point is not finite")

    def closure():
        opt.zero_grad()
        evals[0] += 1
        try:
            with torch.enable_grad():
                L = loss_fn(p)
            if not torch.isfinite(L):
                raise Infeasible("non-finite loss")
            L.backward()
            if not torch.isfinite(p.grad).all():
                raise Infeasible("non-finite gradient")
            return L
        except Infeasible:
            p.grad = torch.zeros_like(p)
            return torch.tensor(math.inf, dtype=p.dtype)

    history = [{"step": 0, "merit": merit0, "x": x.tolist(), "accepted": True}]
    best, best_x, reason, it, rejected = merit0, x.clone(), f"reached {steps} steps", 0, 0
    for it in range(1, steps + 1):
        opt.step(closure)
        if lo is not None:
            with torch.no_grad():
                p.copy_(_project(p, lo, hi))
        try:
            with torch.no_grad():
                Lf = float(loss_fn(p.detach()))
        except Infeasible:
            Lf = math.inf
        ok = math.isfinite(Lf)
        if not ok:
            rejected += 1
            with torch.no_grad():
                p.copy_(best_x)
            reason = "the line search left the feasible region; stopped at the best point"
            history.append({"step": it, "merit": best, "x": best_x.tolist(), "accepted": False,
                            "reason": "infeasible or non-finite"})
            break
        history.append({"step": it, "merit": Lf, "x": p.detach().tolist(), "accepted": True})
        improved = Lf < best
        if improved:
            rel = (best - Lf) / max(best, 1e-300)
            best, best_x = Lf, p.detach().clone()
        if callback is not None and callback(it, p.detach().clone(), Lf):
            reason = "stopped by callback"
            break
        if not improved or rel < 1e-12:
            reason = "no further decrease"
            break
    return OptimResult(x=best_x, merit=best, merit0=merit0, history=history, steps=it,
                       evaluations=evals[0], reason=reason, seconds=time.perf_counter() - t_start,
                       rejected=rejected)
