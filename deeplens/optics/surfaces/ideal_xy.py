"""An anamorphic ideal thin lens: a plane with one power in x and another in y (OpticStudio's
``PARAX_XY``, "Paraxial XY").

A ray crossing the plane at ``(x, y)`` with direction tangents ``(t_x, t_y) = (d_x, d_y) / d_z``
leaves with

    t_x' = t_x − x φ_x,    t_y' = t_y − y φ_y

(same sign of ``d_z``), ``φ_x``, ``φ_y`` the powers (1/mm; either may be 0: a perfect cylinder
lens).  With ``φ_x = φ_y = 1/f`` it is :class:`~.ideal.IdealLens` exactly.  Each section images
without aberration (a point at distance ``s`` goes to ``1/v = φ − 1/s`` in that section), so a
point is imaged to two lines when the powers differ.  No optical path is added, it does not
disperse, media on both sides should be equal (air).

Paraxial data (rotationally symmetric) take the y section, ``φ_y``, as deeplens' biconic,
toroid and cylinder do.
"""

from __future__ import annotations

import torch

from ..interactions import IDEAL_DEFLECTION
from .base import make_param, register_surface
from .plane import Plane

__all__ = ["IdealLensXY"]


@register_surface("ideal_lens_xy")
class IdealLensXY(Plane):
    """A perfect thin lens of powers ``power_x``, ``power_y`` (1/mm, not both 0) with a circular
    clear aperture (module docstring).

    Parameters: ``surface.power_x``, ``surface.power_y`` (1/mm).
    """

    #: the tracer hands the hit to :meth:`deflect` (never a mirror; eager)
    interaction = IDEAL_DEFLECTION

    def __init__(self, power_x: float, power_y: float, semi_diameter: float):
        super().__init__(semi_diameter)
        if float(power_x) == 0.0 and float(power_y) == 0.0:
            raise ValueError("IdealLensXY: at least one of power_x, power_y must be non-zero "
                             "(1/mm)")
        self.power_x = make_param(power_x, "power_x")
        self.power_y = make_param(power_y, "power_y")

    def deflect(self, x, d, valid):
        """New unit directions ``(*B, 3)`` for hits ``x`` (local frame) and directions ``d``."""
        dz = d[..., 2]
        ok = valid & (dz.abs() > 1e-12)
        dz_safe = torch.where(ok, dz, torch.ones_like(dz))
        sign = torch.sign(dz_safe)
        tx = d[..., 0] / dz_safe - x[..., 0] * self.power_x.to(x) * sign
        ty = d[..., 1] / dz_safe - x[..., 1] * self.power_y.to(x) * sign
        out = torch.stack([tx, ty, torch.ones_like(tx)], -1) * sign.unsqueeze(-1)
        out = out / torch.linalg.vector_norm(out, dim=-1, keepdim=True)
        return torch.where(ok.unsqueeze(-1), out, d), ok

    def paraxial_power(self):
        """``φ_y`` (1/mm): the y section (module docstring); paraxial analysis uses it in place
        of ``c (n2 - n1)``."""
        return self.power_y

    file_fields = ("power_x_per_mm", "power_y_per_mm")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("power_x_per_mm"), entry.get("power_y_per_mm"), semi_diameter)

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["power_x_per_mm"] = float(self.power_x)
        d["power_y_per_mm"] = float(self.power_y)
        return d

    def extra_repr(self) -> str:
        return (f"power_x={float(self.power_x.detach()):.6g}/mm, "
                f"power_y={float(self.power_y.detach()):.6g}/mm, " + super().extra_repr())
