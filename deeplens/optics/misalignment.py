"""Per-element misalignment: decenter and tilt of a rigid group of surfaces.

An element (a singlet, a cemented group, a stop) rotates about its pivot ``p`` (its first vertex
on the axis) and shifts by ``δ = (dx, dy, 0)``.  With ``R = R_y(tilt_y) R_x(tilt_x)``:

    global -> element frame:  x_e = R^T (x - p - δ),  d_e = R^T d
    element frame -> global:  x   = R x_e + p + δ,    d   = R d_e

Lengths in mm, angles in radians.
"""

from __future__ import annotations

import torch
from torch import nn

from .surfaces.base import host_flags, make_param

__all__ = ["Misalignment"]


class Misalignment(nn.Module):
    """Decenter ``dx, dy`` (mm) and tilt ``tilt_x, tilt_y`` (rad) of one element.

    All four are frozen parameters; unfreeze any of them to estimate or tolerance it.
    """

    def __init__(self, dx: float = 0.0, dy: float = 0.0, tilt_x: float = 0.0,
                 tilt_y: float = 0.0):
        super().__init__()
        self.dx = make_param(dx, "dx")
        self.dy = make_param(dy, "dy")
        self.tilt_x = make_param(tilt_x, "tilt_x")
        self.tilt_y = make_param(tilt_y, "tilt_y")

    def is_identity(self) -> bool:
        """True when every value is zero and none is trainable (the transform is skipped).  The
        values are read from the host once per change (:func:`~.surfaces.base.host_flags`):
        the tracer asks at every surface of every trace."""
        values = (self.dx, self.dy, self.tilt_x, self.tilt_y)
        if any(p.requires_grad for p in values):
            return False
        return host_flags(self, "_zero_flags", values,
                          lambda *v: all(float(p) == 0.0 for p in v))

    def rotation(self, like: torch.Tensor) -> torch.Tensor:
        """``R = R_y(tilt_y) R_x(tilt_x)`` as a ``(3, 3)`` tensor of ``like``'s dtype/device."""
        ax, ay = self.tilt_x.to(like), self.tilt_y.to(like)
        cx, sx, cy, sy = torch.cos(ax), torch.sin(ax), torch.cos(ay), torch.sin(ay)
        one, zero = torch.ones_like(cx), torch.zeros_like(cx)
        rx = torch.stack([torch.stack([one, zero, zero]),
                          torch.stack([zero, cx, -sx]),
                          torch.stack([zero, sx, cx])])
        ry = torch.stack([torch.stack([cy, zero, sy]),
                          torch.stack([zero, one, zero]),
                          torch.stack([-sy, zero, cy])])
        return ry @ rx

    def offset(self, like: torch.Tensor) -> torch.Tensor:
        z = torch.zeros_like(self.dx.to(like))
        return torch.stack([self.dx.to(like), self.dy.to(like), z])

    def to_element(self, x, d, pivot):
        """Global ``(x, d)`` (``(*B, 3)``) to the element frame about ``pivot`` ``(3,)``."""
        R = self.rotation(x)
        xe = (x - pivot - self.offset(x)) @ R  # row-vector form of R^T (x - p - δ)
        return xe, d @ R

    def to_global(self, xe, de, pivot):
        R = self.rotation(xe)
        return xe @ R.T + pivot + self.offset(xe), de @ R.T

    def to_dict(self) -> dict:
        return {"dx_mm": float(self.dx), "dy_mm": float(self.dy),
                "tilt_x_rad": float(self.tilt_x), "tilt_y_rad": float(self.tilt_y)}
