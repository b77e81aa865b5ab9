r"""OpticStudio's Extended Odd Asphere: a conic base plus a polynomial in the normalised radius
with every power from ``ρ¹`` on.

    z(r) = c r² / (1 + sqrt(1 − (1 + k) c² r²)) + Σ_{i=1..N} A_i ρ^i,    ρ = r / R_n,
    r = sqrt(x² + y²)

with curvature ``c = 1/R`` (1/mm), conic constant ``k``, the normalisation radius ``R_n`` (mm,
``> 0``) and the coefficients ``A_i`` in mm (OpticStudio's ``XOSPHERE``: ``XDAT 1`` the maximum
term number ``N``, ``XDAT 2`` ``R_n``, ``XDAT i + 2`` ``A_i`` on ``ρ^i``; the Zemax guide,
*What is read*).  The same surface as the :class:`~.odd_asphere.OddAsphere` with ``a_i = A_i /
R_n^i``; this type keeps OpticStudio's normalised coefficients (each ``A_i`` the sag in mm of its
term at ``r = R_n``), so that a file reads and writes back bit for bit and a design step in
``A_i`` has the same size for every term.

The polynomial is the odd asphere's (:func:`~.odd_asphere.odd_poly`,
:func:`~.odd_asphere.odd_dsag`) evaluated at ``σ = ρ² = r² / R_n²``: ``Σ A_i ρ^i = E(σ) +
ρ O(σ)`` (Horner in ``σ``, even terms without a square root).  The slopes are ``∂z/∂x = x G``,
``∂z/∂y = y G`` with ``G = 2 dz_c/ds + odd_dsag(σ, A) / R_n²`` (``odd_dsag`` is ``(1/ρ) d/dρ``
of the polynomial, and ``dρ/dx = x / (r R_n)``).

**The axis.**  As the odd asphere's: a ``ρ¹`` term is a cone tip; ``ρ`` and ``1/ρ`` are taken as
0 where ``σ <= sqrt(tiny)`` (:func:`~.odd_asphere.safe_radius`), so the sag, the slope and every
derivative stay finite and the normal on the axis is the axis.

**Paraxial data.**  The vertex curvature is ``c + 2 A_2 / R_n²`` (the ``ρ²`` term's power); odd
terms have no paraxial power (the odd asphere's rule).  The ``.zmx`` reader refuses a non-zero
``ρ¹`` term: no source at hand says how OpticStudio's paraxial data treat that cone.

The surface has no compiled Newton kernels: a compiled trace runs it eager between its fused runs
(:func:`~..tracer.fused_kind`), as the odd asphere.  Newton starts from the conic base's root
(:meth:`quadric`).
"""

from __future__ import annotations

import torch
from torch import nn

from .asphere import conic_arg, conic_dsag_ds, conic_quadric, conic_sag
from .base import (SagSurface, check_conic_domain, conic_polynomial_scale, make_param,
                   norm_radius_mm, register_surface)
from .odd_asphere import odd_dsag, odd_poly

__all__ = ["ExtendedOddAsphere", "MAX_XOSPHERE_TERMS"]

#: the most terms (``ρ¹ .. ρ^N``) this type holds: OpticStudio's Extended Asphere's maximum term
#: number (User Guide, *Extended Asphere*: "The maximum is 240"), its odd sibling's taken alike
MAX_XOSPHERE_TERMS = 240


@register_surface("extended_odd_asphere")
class ExtendedOddAsphere(SagSurface):
    """A conic plus ``Σ_{i=1..N} A_i (r / R_n)^i`` (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm (``0``: flat base).
        semi_diameter: clear semi-aperture, mm.
        norm_radius: ``R_n``, mm (``> 0``, finite).
        coefficients: ``[A_1, ..., A_N]``, the coefficients of ``ρ¹ ... ρ^N`` in mm (``N <=
            MAX_XOSPHERE_TERMS``).
        conic: conic constant ``k`` of the base.

    Parameters: ``surface.c``, ``surface.k`` and ``surface.a[i − 1]`` (``A_i``, on ``ρ^i``), each
    frozen until made trainable; the normalisation radius is a fixed buffer (float64).
    """

    def __init__(self, curvature: float, semi_diameter: float, norm_radius: float,
                 coefficients=(), conic: float = 0.0):
        super().__init__(semi_diameter)
        rn = norm_radius_mm(norm_radius, "ExtendedOddAsphere")
        coefficients = list(coefficients)
        if len(coefficients) > MAX_XOSPHERE_TERMS:
            raise ValueError(f"ExtendedOddAsphere: at most {MAX_XOSPHERE_TERMS} coefficients "
                             f"(ρ^1..ρ^{MAX_XOSPHERE_TERMS}), got {len(coefficients)}")
        self.register_buffer("norm_radius", torch.tensor(rn, dtype=torch.float64))
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.a = nn.ParameterList([make_param(v, f"A{i + 1}")
                                   for i, v in enumerate(coefficients)])

    def in_domain(self, x, y):
        return conic_arg(x * x + y * y, self.c, self.k) > 0

    def sag(self, x, y):
        s = x * x + y * y
        sigma = s / self.norm_radius.to(s) ** 2
        return conic_sag(s, self.c, self.k) + odd_poly(sigma, self.a)

    def sag_grad(self, x, y):
        s = x * x + y * y
        rn2 = self.norm_radius.to(s) ** 2
        g = 2.0 * conic_dsag_ds(s, self.c, self.k) + odd_dsag(s / rn2, self.a) / rn2
        return x * g, y * g

    def paraxial_curvature(self):
        """``c + 2 A_2 / R_n²`` (1/mm, a 0-d tensor: the ``ρ²`` term's power; the odd terms have
        none, module docstring)."""
        if len(self.a) >= 2:
            return self.c + 2.0 * self.a[1] / self.norm_radius.to(self.c) ** 2
        return self.c

    def quadric(self, o, d):
        """The conic base as a quadric (Newton's start; the surface itself is not one)."""
        return conic_quadric(*o.unbind(-1), *d.unbind(-1), self.c, self.k)

    def check(self, where: str = "") -> None:
        check_conic_domain(float(self.semi_diameter), float(self.c), float(self.k),
                           "Extended Odd Asphere's conic base", where)

    def sag_scale(self, name: str) -> float:
        """``c``: ``R^2/2``; ``k``: :func:`~.base.conic_scale`; ``a.i`` (``A_{i+1}`` on
        ``ρ^(i+1)``, mm): ``(R / R_n)^(i+1)``, the term's sag per unit at the rim ``r = R``
        (:meth:`Surface.sag_scale <.base.Surface.sag_scale>`)."""
        parts = name.split(".")
        if parts[0] == "a":
            return (float(self.semi_diameter) / float(self.norm_radius)) ** (int(parts[1]) + 1)
        return conic_polynomial_scale(self, name)

    file_fields = ("curvature_per_mm", "conic", "norm_radius_mm", "rho_coefficients_mm")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        rn = entry.get("norm_radius_mm")
        if not rn > 0:
            entry.fail("norm_radius_mm", f"the normalisation radius must be > 0 (mm), got {rn!r}")
        return cls(entry.get("curvature_per_mm"), semi_diameter, rn,
                   entry.get("rho_coefficients_mm", "numbers", default=[]),
                   conic=entry.get("conic", default=0.0))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        d["conic"] = float(self.k)
        d["norm_radius_mm"] = float(self.norm_radius)
        d["rho_coefficients_mm"] = [float(v) for v in self.a]
        return d

    def extra_repr(self) -> str:
        return (f"c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"rn={float(self.norm_radius):.6g} mm, n_terms={len(self.a)}, "
                + super().extra_repr())
