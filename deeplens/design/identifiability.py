"""How far to trust a least-squares fit: per-parameter uncertainties, correlations and the
parameters one data set does not identify (Gauss-Newton curvature and the residual's noise).

For ``min_θ |r(θ)|^2`` with ``m`` residuals, ``n`` parameters and independent noise of variance
``σ^2`` in the residuals, the estimate's covariance near the minimum is

    Cov(θ) ≈ σ^2 (J^T J)^+ ,   σ^2 = |r(θ̂)|^2 / (m - n)   (unless ``sigma`` is given)

with ``J = ∂r/∂θ`` at the estimate (forward-mode AD).  ``J`` is column-scaled before the
pseudo-inverse, so the conditioning is that of the parameters' *shapes*, not their units.
Standard deviations are ``sqrt(diag Cov)``, correlations ``Cov_ij / (std_i std_j)``.  A
parameter is reported *not identifiable* when it is almost a combination of the others
(``|corr| >=`` ``corr_limit`` with one of them) or when its standard deviation exceeds its
``scale`` (a change the user considers significant): the data then cannot say which of the
nearly equivalent values is right, and the estimate's error can be many times the fit's
residual suggests (issue 25, item 14: a spot image's small tilts trade against the source
position).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .optimizers import jacobian

__all__ = ["FitUncertainty", "fit_uncertainty"]


@dataclass
class FitUncertainty:
    """``std`` and ``correlation`` per parameter name; ``sigma`` the residual noise used;
    ``not_identifiable`` ``{name: reason}``; ``condition`` of the column-scaled ``J``."""

    std: dict
    correlation: dict
    sigma: float
    condition: float
    not_identifiable: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"std": self.std, "correlation": self.correlation, "sigma": self.sigma,
                "condition": self.condition, "not_identifiable": self.not_identifiable}


def fit_uncertainty(residual_fn, theta: torch.Tensor, names, *, sigma: float | None = None,
                    scale=None, corr_limit: float = 0.95) -> FitUncertainty:
    """Uncertainties of the fit ``theta`` (``(n,)``, float64) of ``min |residual_fn(θ)|^2``.

    Args:
        residual_fn: ``θ (n,) -> r (m,)``, differentiable (forward mode).
        names: ``n`` parameter names.
        sigma: noise standard deviation of one residual (default: from the residual).
        scale: ``n`` changes per parameter that matter (default: none, the rule is not used).
        corr_limit: the ``|correlation|`` above which a pair is nearly degenerate.
    """
    names = list(names)
    theta = torch.as_tensor(theta, dtype=torch.float64).detach()
    r, J = jacobian(residual_fn, theta, mode="forward")
    m, n = J.shape
    if sigma is None:
        sigma = math.sqrt(float(r @ r) / max(m - n, 1))
    norms = torch.linalg.vector_norm(J, dim=0)
    norms = torch.where(norms > 0, norms, torch.ones_like(norms))
    _, S, Vh = torch.linalg.svd(J / norms, full_matrices=False)
    cut = float(S[0]) * max(m, n) * torch.finfo(J.dtype).eps
    inv = torch.where(S > cut, 1.0 / S.clamp_min(cut) ** 2, torch.full_like(S, math.inf))
    cov = (Vh.T * inv) @ Vh * sigma ** 2 / torch.outer(norms, norms)
    cov = torch.nan_to_num(cov, nan=math.inf)
    std = torch.sqrt(torch.diagonal(cov).clamp_min(0))
    corr = cov / torch.outer(std, std)
    condition = float(S[0] / S[-1]) if float(S[-1]) > 0 else math.inf
    bad = {}
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            if i != j and math.isfinite(float(corr[i, j])) and abs(float(corr[i, j])) >= corr_limit:
                bad.setdefault(a, f"correlation {float(corr[i, j]):+.3f} with {b}")
        if scale is not None and not float(std[i]) <= float(scale[i]):
            bad.setdefault(a, f"standard deviation {float(std[i]):.3g} above {float(scale[i]):g}")
    return FitUncertainty(
        std={k: float(v) for k, v in zip(names, std)},
        correlation={a: {b: float(corr[i, j]) for j, b in enumerate(names)}
                     for i, a in enumerate(names)},
        sigma=float(sigma), condition=condition, not_identifiable=bad)
