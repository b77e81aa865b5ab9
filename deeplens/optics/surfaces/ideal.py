"""Ideal (perfect thin) lens: a plane that maps ray tangents as a paraxial lens, exactly.

A ray crossing the plane at ``(x, y)`` with direction tangents ``(t_x, t_y) = (d_x, d_y) / d_z``
leaves with

    t_x' = t_x - x / f,    t_y' = t_y - y / f

(same sign of ``d_z``).  Every point at distance ``s`` is imaged without aberration to
``1/v = 1/f - 1/s`` for all field angles and apertures, which makes it the reference for tests
(a focused ideal lens has a delta PSF).  It does not disperse; media on both sides should be
equal (typically air).
"""

from __future__ import annotations

import torch

from ..interactions import IDEAL_DEFLECTION
from .base import make_param, register_surface
from .plane import Plane

__all__ = ["IdealLens"]


@register_surface("ideal_lens")
class IdealLens(Plane):
    """A perfect thin lens of focal length ``f`` (mm, ``!= 0``) with a circular clear aperture.

    Parameter: ``surface.focal`` (mm).
    """

    #: the tracer hands the hit to :meth:`deflect` (never a mirror; eager)
    interaction = IDEAL_DEFLECTION

    def __init__(self, focal_length: float, semi_diameter: float):
        super().__init__(semi_diameter)
        if float(focal_length) == 0.0:
            raise ValueError("IdealLens: focal_length must be non-zero (mm)")
        self.focal = make_param(focal_length, "focal_length")

    def deflect(self, x, d, valid):
        """New unit directions ``(*B, 3)`` for hits ``x`` (local frame) and directions ``d``."""
        dz = d[..., 2]
        ok = valid & (dz.abs() > 1e-12)
        dz_safe = torch.where(ok, dz, torch.ones_like(dz))
        f = self.focal.to(x)
        sign = torch.sign(dz_safe)
        tx = d[..., 0] / dz_safe - x[..., 0] / f * sign
        ty = d[..., 1] / dz_safe - x[..., 1] / f * sign
        out = torch.stack([tx, ty, torch.ones_like(tx)], -1) * sign.unsqueeze(-1)
        out = out / torch.linalg.vector_norm(out, dim=-1, keepdim=True)
        return torch.where(ok.unsqueeze(-1), out, d), ok

    def paraxial_power(self):
        """``1/f`` (1/mm); paraxial analysis uses it in place of ``c (n2 - n1)``."""
        return 1.0 / self.focal

    file_fields = ("focal_length_mm",)

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("focal_length_mm"), semi_diameter)

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["focal_length_mm"] = float(self.focal)
        return d
