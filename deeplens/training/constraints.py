"""Lens constraint for training: a bound on each trainable surface's departure from its start.

    C = sum_s mean_{(x, y) in G_s} relu(|z_s(x, y) - z_s0(x, y)| / m - 1)^2

``z_s`` is the sag (mm) of surface ``s`` now, ``z_s0`` its sag when training started, ``m`` the
bound ``max_sag_mm`` (e.g. the thickness budget of a phase plate) and ``G_s`` a 17 x 17 grid
over the square inscribed in the clear aperture (``|x|, |y| <= R / sqrt 2``, ``R`` the
semi-diameter).  Only surfaces with trainable parameters count.  ``C`` is zero while every
departure is within ``m`` (a curved surface is not penalised for its own sag), and grows
quadratically past it, so its gradient is continuous at the bound.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ..optics.errors import ConfigError

__all__ = ["SagDepartureConstraint"]


class SagDepartureConstraint(nn.Module):
    """``C(lens)`` of the module docstring, remembering the sags of ``lens`` at construction.

    Args:
        lens: the lens whose surfaces with ``requires_grad`` parameters are bounded.
        max_sag_mm: the bound ``m`` (mm, > 0), or ``None``/0 for no constraint (``C = 0``).
        grid: points per side of ``G_s``.

    Call with the (trained) lens: returns a float32 scalar on the lens's device.
    The reference sags are non-persistent buffers: they follow ``.to()`` but are not in the
    checkpoint (they are recomputed from the configured starting lens).
    """

    def __init__(self, lens, max_sag_mm: float | None, grid: int = 17):
        super().__init__()
        if max_sag_mm is not None and not (math.isfinite(max_sag_mm) and max_sag_mm >= 0):
            raise ConfigError("model.max_sag_mm", "a bound >= 0 mm (or null)", max_sag_mm)
        self.max_sag_mm = max_sag_mm or None
        self.grid = int(grid)
        self.surfaces: list[int] = []
        with torch.no_grad():
            for i, s in enumerate(lens.surfaces):
                if any(p.requires_grad for p in s.parameters()) and hasattr(s, "sag"):
                    X, Y = self._points(s, lens.dtype, lens.device)
                    self.register_buffer(f"sag0_{i}", s.sag(X, Y).detach().clone(),
                                         persistent=False)
                    self.surfaces.append(i)

    def _points(self, surface, dtype: torch.dtype, device):
        R = float(surface.semi_diameter)
        v = torch.linspace(-R, R, self.grid, dtype=torch.float64) / math.sqrt(2)
        Y, X = torch.meshgrid(v, v, indexing="ij")
        return X.to(dtype=dtype, device=device), Y.to(dtype=dtype, device=device)

    def forward(self, lens) -> torch.Tensor:
        total = torch.zeros((), device=lens.device)
        if not self.max_sag_mm:
            return total
        for i in self.surfaces:
            s = lens.surfaces[i]
            X, Y = self._points(s, lens.dtype, lens.device)
            dep = s.sag(X, Y) - getattr(self, f"sag0_{i}").to(dtype=lens.dtype,
                                                               device=lens.device)
            total = total + (F.relu(dep.abs() / self.max_sag_mm - 1) ** 2).mean().float()
        return total
