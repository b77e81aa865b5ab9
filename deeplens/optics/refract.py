"""Vector Snell's law (paper Eq. 9).

With unit normal ``n`` oriented along the propagation (``cos ψ = d·n > 0``) and ``η = n1/n2``:

    d_t = η d + (sqrt(1 - η^2 (1 - cos^2 ψ)) - η cos ψ) n

evaluated as ``(1 - η^2) / (sqrt(k) + η cos ψ)`` (:func:`snell_coefficient`), which has no
cancellation: equal indices leave ``d`` unchanged exactly, also at grazing incidence.

The ray is totally internally reflected (marked invalid) where ``k = 1 - η^2 (1 - cos^2 ψ) <= 0``:
at the critical angle itself (``k == 0``, which float arithmetic does produce) the refracted ray
grazes the surface, carries no power, and ``d sqrt(k)/dk`` is infinite, so keeping it valid put
``0 * inf = NaN`` into every gradient through a shared parameter.
Invariant: ``n1 |d × n| = n2 |d_t × n|`` (n1 sin θ1 = n2 sin θ2), and ``d_t`` stays coplanar.
"""

from __future__ import annotations

import torch

__all__ = ["refract", "snell_coefficient", "snell_xyz", "unit_normal"]


def unit_normal(fx, fy, fz):
    """``∇f / |∇f|`` as a ``(*B, 3)`` tensor (finite also for a zero gradient)."""
    g = torch.stack([fx, fy, fz], -1)
    norm2 = (g * g).sum(-1, keepdim=True)
    ok = norm2 > 0
    return g / torch.sqrt(torch.where(ok, norm2, torch.ones_like(norm2)))


def snell_coefficient(cos_i, eta, ok):
    """The law itself, written once: ``coef = sign(cos ψ) sqrt(k) - η cos ψ`` with
    ``k = 1 - η^2 (1 - cos^2 ψ)``, so that ``d_t = η d + coef n`` (either orientation of ``n``);
    ``ok`` loses the rays with ``k <= 0`` (total internal reflection and the critical angle,
    module docstring).  Shapes ``(*B,)``; returns ``(coef, ok)``.  :func:`refract` (``(*B, 3)``
    rays), :func:`snell_xyz` (components) and the compiled plane step call it."""
    # k does not depend on the normal's orientation; flipping n to cos_i >= 0 turns
    # (sqrt(k) - eta cos_i) n into (sign(cos_i) sqrt(k) - eta cos_i) n for the given n
    # Written without cancellation (issue 38): k = (1 - η)(1 + η) + η² cos²ψ, not
    # 1 - η² (1 - cos²ψ), whose 1 - cos²ψ rounds to 1 at grazing incidence in float32 (η = 1,
    # cos ψ = 1e-4 gave k = 0: the ray was lost); and sqrt(k) - η|cos ψ| = (k - η² cos²ψ) /
    # (sqrt(k) + η|cos ψ|) = (1 - η)(1 + η) / (sqrt(k) + η|cos ψ|), a sum of two non-negative
    # terms in the denominator, so that η = 1 gives coef = 0 and d_t = d exactly.
    eta_sq_c2 = (eta * cos_i) * (eta * cos_i)
    one_minus_eta_sq = (1.0 - eta) * (1.0 + eta)
    k = one_minus_eta_sq + eta_sq_c2
    ok = ok & (k > 0)  # k == 0: grazing exit, infinite derivative (module docstring)
    sqrt_k = torch.sqrt(torch.where(ok, k, torch.ones_like(k)))
    denom = sqrt_k + (eta * cos_i).abs()  # >= sqrt(k) > 0 where ok
    sign = torch.copysign(torch.ones_like(cos_i), cos_i)  # exact ±1: same branch as before
    return sign * (one_minus_eta_sq / denom), ok


def refract(d: torch.Tensor, n: torch.Tensor, eta: torch.Tensor, valid: torch.Tensor):
    """Refract unit directions ``d`` at unit normals ``n`` (either orientation).

    Args:
        d: ``(*B, 3)`` incident unit directions.
        n: ``(*B, 3)`` unit surface normals.
        eta: ``n1 / n2``, broadcastable to ``B`` (computed once when it is one value).
        valid: ``(*B,)`` incoming mask.

    Returns:
        ``(d_t, valid)`` with TIR rays (and rays at the critical angle) marked invalid (their
        ``d_t`` is finite, equal to ``d``).
    """
    cos_i = (d * n).sum(-1)
    eta = torch.as_tensor(eta, dtype=d.dtype, device=d.device)
    coef, ok = snell_coefficient(cos_i, eta, valid)
    d_t = eta.unsqueeze(-1) * d + coef.unsqueeze(-1) * n
    d_t = torch.where(ok.unsqueeze(-1), d_t, d)
    return d_t, ok


def snell_xyz(dx, dy, dz, nx, ny, nz, n1, n2, ok):
    """:func:`refract` on components (the compiled kernels' layout), ``η = n1 / n2``: rays with
    total internal reflection leave ``ok`` and keep ``d``.  Returns ``(d_x, d_y, d_z, ok)``."""
    eta = n1 / n2
    cos_i = dx * nx + dy * ny + dz * nz
    coef, ok = snell_coefficient(cos_i, eta, ok)
    ex = torch.where(ok, eta * dx + coef * nx, dx)
    ey = torch.where(ok, eta * dy + coef * ny, dy)
    ez = torch.where(ok, eta * dz + coef * nz, dz)
    return ex, ey, ez, ok
