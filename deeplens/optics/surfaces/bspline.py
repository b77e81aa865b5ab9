"""Bicubic B-spline freeform on fixed uniform knots.

    z(x, y) = sum_{p,q} C[p, q] N_p(x) N_q(y)

``N`` are uniform cubic B-splines whose ``n - 3`` spans cover ``[-L, L]`` (``L`` the
semi-diameter) with knot spacing ``h = 2L / (n - 3)``.  In span ``j`` with local ``u in [0, 1)``
the four non-zero bases are ``(1-u)^3/6, (3u^3 - 6u^2 + 4)/6, (-3u^3 + 3u^2 + 3u + 1)/6, u^3/6``.
Points outside the square ``[-L, L]^2`` are outside the domain (the tracer marks them invalid).
"""

from __future__ import annotations

import torch

from .base import SagSurface, make_param, register_surface

__all__ = ["BSpline"]


def _basis(u):
    u2, u3 = u * u, u * u * u
    w = torch.stack([(1 - u) ** 3, 3 * u3 - 6 * u2 + 4, -3 * u3 + 3 * u2 + 3 * u + 1, u3], -1) / 6
    dw = torch.stack([-3 * (1 - u) ** 2, 9 * u2 - 12 * u, -9 * u2 + 6 * u + 3, 3 * u2], -1) / 6
    return w, dw


@register_surface("bspline")
class BSpline(SagSurface):
    """Bicubic B-spline freeform.

    Args:
        semi_diameter: clear semi-aperture ``L`` in mm (the spline covers ``[-L, L]^2``).
        coefficients: ``(n_x, n_y)`` control heights in mm, ``n_x, n_y >= 4``.

    Parameter: ``surface.coefficients`` (one tensor; each entry is a coefficient).
    """

    def __init__(self, semi_diameter: float, coefficients):
        super().__init__(semi_diameter)
        c = torch.as_tensor(coefficients, dtype=torch.float64)
        if c.ndim != 2 or min(c.shape) < 4:
            raise ValueError(f"BSpline: coefficients must be a 2-D grid of at least 4x4, got "
                             f"shape {tuple(c.shape)}")
        self.coefficients = make_param(c, "coefficients")

    def _span(self, v, n):
        L = self.semi_diameter.to(v)
        h = 2 * L / (n - 3)
        u = (v + L) / h
        j = torch.clamp(torch.floor(u.detach()), 0, n - 4)
        return j.long(), u - j, h

    def _eval(self, x, y, deriv: bool):
        C = self.coefficients.to(x)
        nx, ny = C.shape
        jx, ux, hx = self._span(x, nx)
        jy, uy, hy = self._span(y, ny)
        wx, dwx = _basis(ux)
        wy, dwy = _basis(uy)
        z = torch.zeros_like(x)
        zx = torch.zeros_like(x)
        zy = torch.zeros_like(x)
        for a in range(4):
            for b in range(4):
                c = C[jx + a, jy + b]
                z = z + c * wx[..., a] * wy[..., b]
                if deriv:
                    zx = zx + c * dwx[..., a] * wy[..., b]
                    zy = zy + c * wx[..., a] * dwy[..., b]
        return z, zx / hx, zy / hy

    def in_domain(self, x, y):
        L = self.semi_diameter.to(x)
        return (x.abs() <= L) & (y.abs() <= L)

    def sag(self, x, y):
        return self._eval(x, y, False)[0]

    def sag_grad(self, x, y):
        _, zx, zy = self._eval(x, y, True)
        return zx, zy

    def paraxial_curvature(self):
        # second derivative of the sag at the vertex, by a central difference of the slope
        L = float(self.semi_diameter)
        e = 1e-3 * L
        x = torch.tensor([-e, e], dtype=self.coefficients.dtype, device=self.coefficients.device)
        zx, _ = self.sag_grad(x, torch.zeros_like(x))
        zy_y = self.sag_grad(torch.zeros_like(x), x)[1]
        return 0.5 * ((zx[1] - zx[0]) + (zy_y[1] - zy_y[0])) / (2 * e)

    file_fields = ("coefficients",)

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(semi_diameter, entry.get("coefficients", "grid"))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["coefficients"] = self.coefficients.detach().cpu().tolist()
        return d
