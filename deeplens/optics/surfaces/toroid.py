r"""Toroid: the cylinder's y profile rotated about an axis parallel to y (OpticStudio's
``TOROIDAL`` with a finite radius of rotation ``R``, ``PARM 1``).

The y profile (as :class:`~.cylinder.Cylinder`)

    z_y(y) = c y² / (1 + sqrt(1 − (1 + k) c² y²)) + Σ_{i=1..} a_{2i} y^{2i}

is rotated about the axis ``x = 0, z = R`` (parallel to y, a distance ``R`` from the vertex
along z).  A point of the profile lies ``ρ = R − z_y(y)`` from that axis, so with
``s = sqrt(1 − x² / ρ²)``

    z(x, y) = R − ρ s = z_y(y) + x² / (ρ (1 + s)),
    ∂z/∂x = x / (ρ s),        ∂z/∂y = z_y'(y) / s.

``R = inf`` is the cylinder.  The surface is defined where the profile is (``1 − (1 + k) c² y²
> 0``) and ``x² < ρ²``; outside, the tracer marks rays invalid.  Paraxial analysis (which assumes
rotational symmetry) sees the y section, like the cylinder's; the x section has curvature
``1/R`` at the vertex.  ``R`` is a parameter (``surface.R``), like ``c``, ``k`` and ``a``.
"""

from __future__ import annotations

import math

import torch

from .base import curvature_scale, make_param, register_surface
from .cylinder import Cylinder

__all__ = ["Toroid"]


@register_surface("toroid")
class Toroid(Cylinder):
    """A toroid: the y profile of a :class:`~.cylinder.Cylinder` rotated about an axis parallel
    to y at ``z = radius_of_rotation``.

    Args:
        curvature: ``c = 1/R_y`` of the y profile, 1/mm.
        semi_diameter: clear semi-aperture in mm (the half-diagonal of a rectangular outline).
        radius_of_rotation: ``R`` in mm (finite and non-zero; the x-z radius at the vertex).
        conic, coefficients, half_widths: as :class:`~.cylinder.Cylinder`.

    Parameters: ``surface.c``, ``surface.k``, ``surface.a[i]``, ``surface.R``.
    """

    def __init__(self, curvature: float, semi_diameter: float, radius_of_rotation: float,
                 conic: float = 0.0, coefficients=(), half_widths=None):
        super().__init__(curvature, semi_diameter, conic=conic, coefficients=coefficients,
                         half_widths=half_widths)
        r = float(radius_of_rotation)
        if not (math.isfinite(r) and r != 0.0):
            raise ValueError(f"Toroid: the radius of rotation must be finite and non-zero mm "
                             f"(a cylinder has none), got {radius_of_rotation!r}")
        self.R = make_param(r, "radius of rotation")

    def _profile(self, y):
        """``z_y(y)`` and ``z_y'(y)`` of the y profile (the cylinder's sag and slope)."""
        zero = torch.zeros_like(y)
        z = Cylinder.sag(self, zero, y)
        _, g = Cylinder.sag_grad(self, zero, y)
        return z, g

    def _rho_s(self, x, y):
        zy, g = self._profile(y)
        rho = self.R.to(y) - zy
        arg = 1.0 - x * x / (rho * rho)
        s = torch.sqrt(torch.where(arg > 0, arg, torch.ones_like(arg)))
        return zy, g, rho, s

    def in_domain(self, x, y):
        zy, _ = self._profile(y)
        rho = self.R.to(y) - zy
        return super().in_domain(x, y) & (x * x < rho * rho)

    def sag(self, x, y):
        zy, _, rho, s = self._rho_s(x, y)
        return zy + x * x / (rho * (1.0 + s))

    def sag_grad(self, x, y):
        _, g, rho, s = self._rho_s(x, y)
        return x / (rho * s), g / s

    def check(self, where: str = "") -> None:
        super().check(where)
        sd = float(self.semi_diameter)
        if self.half_widths is not None:
            sd = float(self.half_widths[0])
        if not sd < abs(float(self.R)):
            raise ValueError(f"{where}the clear aperture (x up to {sd:g} mm) lies beyond the "
                             f"toroid's radius of rotation ({float(self.R):g} mm)")

    def sag_scale(self, name: str) -> float:
        """The y profile's scales (:meth:`Cylinder.sag_scale <.cylinder.Cylinder.sag_scale>`);
        the radius of rotation ``R`` scales as the x section's curvature ``1/R`` does:
        ``|∂z/∂R| = (r^2/2) / R^2`` at the rim ``r`` (the semi-diameter)."""
        if name == "R":
            r = float(self.semi_diameter)
            return curvature_scale(r) / float(self.R) ** 2
        return super().sag_scale(name)

    file_fields = Cylinder.file_fields + ("radius_of_rotation_mm",)

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("curvature_per_mm"), semi_diameter,
                   entry.get("radius_of_rotation_mm"), **cls._profile_of(entry))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["radius_of_rotation_mm"] = float(self.R)
        return d

    def extra_repr(self) -> str:
        return f"R={float(self.R.detach()):.6g} mm, " + super().extra_repr()
