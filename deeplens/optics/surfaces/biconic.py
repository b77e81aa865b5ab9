r"""Biconic: a conic-like surface with its own curvature and conic in x and in y (OpticStudio's
``BICONICX``).

    z(x, y) = N / (1 + S),     N = c_x x² + c_y y²,     S = sqrt(1 − Q),
    Q = (1 + k_x) c_x² x² + (1 + k_y) c_y² y²

with curvatures ``c_x = 1/R_x``, ``c_y = 1/R_y`` (1/mm) and conics ``k_x``, ``k_y``.  The section
``y = 0`` is the conic ``(c_x, k_x)``, the section ``x = 0`` the conic ``(c_y, k_y)``; with
``c_x = c_y`` and ``k_x = k_y`` it is the rotationally symmetric conic of
:class:`~.asphere.Asphere` (to rounding: ``c x² + c y²`` is summed, not ``c (x² + y²)``).  This
is OpticStudio's formula, one square root for both directions, and not the sum of an x conic
and a y conic (optiland's ``BiconicGeometry``, which agrees with it only on the two axes, or
everywhere when ``c_x`` or ``c_y`` is 0).  With ``(1 + k_x) c_x = (1 + k_y) c_y = m`` it is the
quadric ``c_x x² + c_y y² + m z² − 2 z = 0`` (an ellipsoid with three semi-axes), which is how
OpticStudio's manual converts an ellipsoid into biconic radii and conics.

The slopes (``S_x = −Q_x / (2 S)``):

    ∂z/∂x = 2 c_x x / (1 + S) + N (1 + k_x) c_x² x / (S (1 + S)²),
    ∂z/∂y = 2 c_y y / (1 + S) + N (1 + k_y) c_y² y / (S (1 + S)²).

**Domain.**  The surface exists where ``1 − Q > 0``; outside, the square root is taken of 1 (the
values stay finite, also in backward) and :meth:`Biconic.in_domain` is False, so the tracer marks
those rays invalid.  :meth:`Biconic.check` refuses a semi-diameter that reaches beyond the domain.

**Paraxial data** (which assume rotational symmetry) see the y-z section, as for the
:class:`~.cylinder.Cylinder` and :class:`~.toroid.Toroid`: :meth:`paraxial_curvature` is ``c_y``.
The x-z section has vertex curvature ``c_x``.

**Zemax.**  ``TYPE BICONICX``: ``CURV`` and ``CONI`` are ``c_y`` and ``k_y``; ``PARM 1`` is the
x *radius* ``R_x`` (0: infinite, flat in x) and ``PARM 2`` the x conic ``k_x``; no other
parameter (OpticStudio User Guide, "Biconic", Parameter definitions for biconic surfaces: 1 Rx,
2 kx; https://ansyshelp.ansys.com/public/Views/Secured/Zemax/v251/en/OpticStudio_User_Guide/
OpticStudio_Help/topics/Biconic.html).  The manual's sag formula is an image there; the one
above is the one whose ellipsoid conversion (the manual's own example) is exact, and the one
pyrate's independent ``.zmx`` reader uses with the same ``PARM`` layout (mess42/pyrate,
``pyrateoptics/raytracer/surface_shape.py`` ``Biconic`` and ``raytracer/io/zmx.py``).

The surface has no compiled Newton kernels: a compiled trace runs it eager between its fused runs
(:func:`~..tracer.fused_kind`); Newton starts from the vertex plane.
"""

from __future__ import annotations

import torch

from .base import SagSurface, conic_scale, curvature_scale, make_param, register_surface

__all__ = ["Biconic"]


@register_surface("biconic")
class Biconic(SagSurface):
    """A biconic surface (module docstring).

    Args:
        curvature: ``c_y = 1/R_y``, 1/mm (the y-z section; ``0``: flat in y).
        semi_diameter: clear semi-aperture, mm (circular).
        curvature_x: ``c_x = 1/R_x``, 1/mm (the x-z section; ``0``: flat in x).
        conic: ``k_y``, the y conic.
        conic_x: ``k_x``, the x conic.

    Parameters: ``surface.c`` (``c_y``), ``surface.k`` (``k_y``), ``surface.cx``, ``surface.kx``,
    each frozen until made trainable.
    """

    def __init__(self, curvature: float, semi_diameter: float, curvature_x: float,
                 conic: float = 0.0, conic_x: float = 0.0):
        super().__init__(semi_diameter)
        self.c = make_param(curvature, "curvature (y)")
        self.k = make_param(conic, "conic (y)")
        self.cx = make_param(curvature_x, "curvature (x)")
        self.kx = make_param(conic_x, "conic (x)")

    def _terms(self, x, y):
        """``(N, 1 − Q)`` (module docstring) in ``x``'s dtype."""
        cx, cy = self.cx.to(x), self.c.to(y)
        kx, ky = self.kx.to(x), self.k.to(y)
        xx, yy = x * x, y * y
        n = cx * xx + cy * yy
        arg = 1.0 - (1.0 + kx) * cx * cx * xx - (1.0 + ky) * cy * cy * yy
        return n, arg

    @staticmethod
    def _root(arg):
        """``sqrt(arg)`` where ``arg > 0``, else 1 (finite value and derivative everywhere)."""
        return torch.sqrt(torch.where(arg > 0, arg, torch.ones_like(arg)))

    def in_domain(self, x, y):
        return self._terms(x, y)[1] > 0

    def sag(self, x, y):
        n, arg = self._terms(x, y)
        return n / (1.0 + self._root(arg))

    def sag_grad(self, x, y):
        cx, cy = self.cx.to(x), self.c.to(y)
        kx, ky = self.kx.to(x), self.k.to(y)
        n, arg = self._terms(x, y)
        s = self._root(arg)
        p = 1.0 + s
        w = n / (s * p * p)
        gx = 2.0 * cx * x / p + w * (1.0 + kx) * cx * cx * x
        gy = 2.0 * cy * y / p + w * (1.0 + ky) * cy * cy * y
        return gx, gy

    def paraxial_curvature(self):
        """``c_y``: the y-z section (module docstring)."""
        return self.c

    def check(self, where: str = "") -> None:
        sd = float(self.semi_diameter)
        cx, kx, cy, ky = (float(p.detach()) for p in (self.cx, self.kx, self.c, self.k))
        qx, qy = (1.0 + kx) * cx * cx, (1.0 + ky) * cy * cy
        q = max(qx, qy, 0.0)
        if q * sd * sd >= 1.0:
            axis = "x" if qx >= qy else "y"
            raise ValueError(
                f"{where}semi-diameter {sd:g} mm lies beyond the domain of the biconic "
                f"(c_x = {cx:g}/mm, k_x = {kx:g}, c_y = {cy:g}/mm, k_y = {ky:g}): along {axis} the sag is only "
                f"defined for |{axis}| < {q ** -0.5:g} mm")

    def sag_scale(self, name: str) -> float:
        """``c``, ``cx``: ``R^2/2``; ``k``, ``kx``: :func:`~.base.conic_scale` of the section's
        own curvature (a biconic's x conic scales as a conic of curvature ``c_x``, its x-z
        section); else 1 (:meth:`Surface.sag_scale <.base.Surface.sag_scale>`)."""
        R = float(self.semi_diameter)
        if name in ("c", "cx"):
            return curvature_scale(R)
        if name == "k":
            return conic_scale(float(self.c), float(self.k), R)
        if name == "kx":
            return conic_scale(float(self.cx), float(self.kx), R)
        return 1.0

    file_fields = ("curvature_per_mm", "conic", "curvature_x_per_mm", "conic_x")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("curvature_per_mm"), semi_diameter,
                   entry.get("curvature_x_per_mm"), conic=entry.get("conic", default=0.0),
                   conic_x=entry.get("conic_x", default=0.0))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        d["conic"] = float(self.k)
        d["curvature_x_per_mm"] = float(self.cx)
        d["conic_x"] = float(self.kx)
        return d

    def extra_repr(self) -> str:
        return (f"c_y={float(self.c.detach()):.6g}/mm, k_y={float(self.k.detach()):.6g}, "
                f"c_x={float(self.cx.detach()):.6g}/mm, k_x={float(self.kx.detach()):.6g}, "
                + super().extra_repr())
