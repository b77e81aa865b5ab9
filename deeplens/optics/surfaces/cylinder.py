r"""Cylinder (a toroid with an infinite radius of rotation): curved in y, straight in x.

    z(x, y) = c y² / (1 + sqrt(1 − (1 + k) c² y²)) + Σ_{i=1..} a_{2i} y^{2i}

with curvature ``c = 1/R_y`` (1/mm), conic ``k`` and coefficients ``a2, a4, ...`` (mm^(1-2i);
``a2`` is OpticStudio's ``α1``).  ``∂z/∂x = 0`` and

    ∂z/∂y = c y / sqrt(1 − (1 + k) c² y²) + Σ 2i a_{2i} y^{2i−1}.

The conic is defined where ``1 − (1 + k) c² y² > 0``; outside it the tracer marks rays invalid.
Paraxial analysis (which assumes rotational symmetry) sees the y section: curvature
``c + 2 a2``.  The clear aperture is circular (the semi-diameter) or, with ``half_widths``, the
rectangle ``|x| <= w_x, |y| <= w_y`` (a cylinder lens's usual outline).
"""

from __future__ import annotations

import torch
from torch import nn

from ..openings import Opening, Rectangle
from .base import SagSurface, conic_polynomial_scale, make_param, register_surface

__all__ = ["Cylinder"]


@register_surface("cylinder")
class Cylinder(SagSurface):
    """A cylindrical (y-curved) surface with an optional even polynomial in ``y``.

    Args:
        curvature: ``c = 1/R_y`` in 1/mm.
        semi_diameter: clear semi-aperture in mm (the half-diagonal of a rectangular outline).
        conic: conic constant ``k`` of the y section.
        coefficients: ``[a2, a4, ...]`` of ``y², y⁴, ...`` (mm^(1-2i)).
        half_widths: ``(w_x, w_y)`` in mm for a rectangular clear aperture, else ``None``.

    Parameters: ``surface.c``, ``surface.k``, ``surface.a[i]``.
    """

    def __init__(self, curvature: float, semi_diameter: float, conic: float = 0.0,
                 coefficients=(), half_widths=None):
        super().__init__(semi_diameter)
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.a = nn.ParameterList([make_param(v, f"a{2 * i + 2}")
                                   for i, v in enumerate(coefficients)])
        if half_widths is not None:
            wx, wy = (float(v) for v in half_widths)
            if not (wx > 0 and wy > 0):
                raise ValueError(f"Cylinder: half-widths must be > 0 mm, got {half_widths!r}")
            self.register_buffer("half_widths", torch.tensor([wx, wy], dtype=torch.float64))
        else:
            self.half_widths = None

    def _arg(self, y):
        c, k = self.c.to(y), self.k.to(y)
        return 1.0 - (1.0 + k) * c * c * y * y

    def _safe_arg(self, y):
        arg = self._arg(y)
        return torch.where(arg > 0, arg, torch.ones_like(arg))

    def in_domain(self, x, y):
        return self._arg(y) > 0

    def _build_opening(self) -> Opening:
        """The rectangle ``|x| <= w_x, |y| <= w_y`` when given, else the semi-diameter's circle."""
        if self.half_widths is None:
            return super()._build_opening()
        return Rectangle(self.half_widths, check=False)

    def sag(self, x, y):
        c = self.c.to(y)
        s = y * y
        z = c * s / (1.0 + torch.sqrt(self._safe_arg(y)))
        p = torch.zeros_like(s)
        for a in reversed(list(self.a)):
            p = (p + a.to(s)) * s
        return z + p + torch.zeros_like(x)

    def sag_grad(self, x, y):
        c = self.c.to(y)
        g = c * y / torch.sqrt(self._safe_arg(y))
        s = y * y
        p = torch.zeros_like(s)
        coeffs = list(self.a)
        for j in range(len(coeffs) - 1, -1, -1):   # d/dy Σ a_{2i} y^{2i} = Σ 2i a_{2i} y^{2i-1}
            p = p * s + 2.0 * (j + 1) * coeffs[j].to(s)
        return torch.zeros_like(x), g + p * y

    def paraxial_curvature(self):
        c = self.c
        return c + 2.0 * self.a[0] if len(self.a) else c

    def check(self, where: str = "") -> None:
        ymax = (float(self.half_widths[1]) if self.half_widths is not None
                else float(self.semi_diameter))
        arg = 1.0 - (1.0 + float(self.k)) * float(self.c) ** 2 * ymax * ymax
        if arg <= 0:
            raise ValueError(f"{where}the clear aperture (y up to {ymax:g} mm) lies beyond the "
                             f"domain of the cylinder's conic section (R = "
                             f"{1 / float(self.c):g} mm, k = {float(self.k):g})")

    def sag_scale(self, name: str) -> float:
        """The y profile's: ``c``: ``R^2/2``; ``k``: :func:`~.base.conic_scale`; ``a.i`` (of
        ``y^(2i+2)``): ``R^(2i+2)`` at ``y = R`` (the semi-diameter); else 1
        (:meth:`Surface.sag_scale <.base.Surface.sag_scale>`)."""
        return conic_polynomial_scale(self, name, lambda i: 2 * i + 2)

    file_fields = ("curvature_per_mm", "conic", "coefficients", "half_width_x_mm",
                   "half_width_y_mm")

    @staticmethod
    def _profile_of(entry) -> dict:
        """The y profile's keyword arguments (conic, coefficients, half-widths) of a lens-file
        entry, shared with the surfaces built on this profile (:class:`~.toroid.Toroid`)."""
        hw = None
        if entry.has("half_width_x_mm") or entry.has("half_width_y_mm"):
            hw = (entry.get("half_width_x_mm"), entry.get("half_width_y_mm"))
        return {"conic": entry.get("conic", default=0.0),
                "coefficients": entry.get("coefficients", "numbers", default=[]),
                "half_widths": hw}

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("curvature_per_mm"), semi_diameter, **cls._profile_of(entry))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        if float(self.k) != 0.0:
            d["conic"] = float(self.k)
        if len(self.a):
            d["coefficients"] = [float(a) for a in self.a]
        if self.half_widths is not None:
            d["half_width_x_mm"] = float(self.half_widths[0])
            d["half_width_y_mm"] = float(self.half_widths[1])
        return d

    def extra_repr(self) -> str:
        return (f"c_y={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"n_coeffs={len(self.a)}, " + super().extra_repr())
