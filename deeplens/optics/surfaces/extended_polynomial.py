r"""OpticStudio's Extended Polynomial on a conic base.

    z = c r² / (1 + sqrt(1 − (1 + k) c² r²)) + Σ_{t=1..N} A_t x̂^i ŷ^j,   x̂ = x / R_n, ŷ = y / R_n

the terms ``t`` by total degree from 1, within a degree from ``x^d`` down to ``y^d`` (``x, y,
x², xy, y², x³, ...``), the coefficients ``A_t`` in mm, ``R_n`` the normalisation radius in mm
(OpticStudio User Guide, "Extended Polynomial": "The first term is x, then y, then x*x, x*y,
y*y, etc.", at most order 20, 230 terms; the position values "are divided by a normalization
radius so the polynomial coefficients are dimensionless" in x and y and in lens units in z).
Slopes: the conic's ``c x / sqrt(1 − (1 + k) c² r²)`` (and ``y``) plus the polynomial's
``Σ A_t i x̂^(i−1) ŷ^j / R_n`` (and ``j``).

On a flat base the same surface is deeplens' :class:`~.xy_polynomial.XYPolynomial` with
``a_ij = A_t / R_n^(i+j)`` (the reader builds that one, which has compiled kernels); this type
holds a curved base, which the XY polynomial's implicit form cannot: it traces on the generic
(eager) path, the conic's root as Newton's start.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .asphere import EvenBaseSag
from .base import (check_conic_domain, conic_polynomial_scale, make_param, norm_radius_mm,
                   register_surface)
from .xy_polynomial import xy_poly, xy_radial

__all__ = ["ExtendedPolynomial", "extended_terms", "MAX_EXTENDED_TERMS"]

#: OpticStudio's most terms (order 20)
MAX_EXTENDED_TERMS = 230


def extended_terms(n: int) -> list[tuple[int, int]]:
    """The exponents ``(i, j)`` of ``x̂^i ŷ^j`` of OpticStudio's polynomial terms ``1..n``: by
    total degree from 1, within a degree from ``x^d`` down to ``y^d`` (module docstring; term 12
    is ``x²y²``, term 13 ``xy³``).  The reader's ``XPOLYNOM``/``XYPOLYNOM`` term order too
    (:mod:`deeplens.optics.io.surface_handlers`)."""
    out, d = [], 1
    while len(out) < n:
        out += [(d - i, i) for i in range(d + 1)]
        d += 1
    return out[:n]


@register_surface("extended_polynomial")
class ExtendedPolynomial(EvenBaseSag):
    """A conic plus OpticStudio's normalised ``x^i y^j`` terms (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm.
        semi_diameter: clear semi-aperture, mm.
        norm_radius: ``R_n``, mm (``> 0``).
        terms: ``[A_1, ..., A_N]`` in OpticStudio's order, mm (``N <= 230``).
        conic: conic constant ``k`` of the base.

    Parameters: ``surface.c``, ``surface.k`` and ``surface.poly[t − 1]`` (``A_t``), each frozen
    until made trainable; the normalisation radius is a fixed buffer.
    """

    def __init__(self, curvature: float, semi_diameter: float, norm_radius: float, terms=(),
                 conic: float = 0.0):
        super().__init__(semi_diameter)
        rn = norm_radius_mm(norm_radius, "ExtendedPolynomial")
        terms = list(terms)
        if len(terms) > MAX_EXTENDED_TERMS:
            raise ValueError(f"ExtendedPolynomial: at most {MAX_EXTENDED_TERMS} terms (order "
                             f"20), got {len(terms)}")
        self.register_buffer("norm_radius", torch.tensor(rn, dtype=torch.float64))
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.a = nn.ParameterList()   # EvenBaseSag's r², r⁴, ... terms: none
        self.poly = nn.ParameterList([make_param(v, f"A{t + 1}") for t, v in enumerate(terms)])
        self.exponents = extended_terms(len(terms))

    def extra_part(self, x, y, slopes: bool = True):
        """``(W, ∂W/∂x, ∂W/∂y)`` of the polynomial (:meth:`EvenBaseSag.extra_part`), each
        ``(*B,)`` like the local ``x, y`` (mm): ``W`` in mm, the slopes dimensionless (``None``
        without ``slopes``); the XY polynomial's own evaluation
        (:func:`~.xy_polynomial.xy_poly`) at ``x / R_n, y / R_n``."""
        rn = self.norm_radius.to(x)
        d = max((i + j for i, j in self.exponents), default=0)
        W, Wu, Wv = xy_poly(x / rn, y / rn, self.poly, self.exponents, d)
        if slopes:
            return W, Wu / rn, Wv / rn
        return W, None, None

    def rotationally_symmetric(self) -> bool:
        """Whether the terms are a function of ``r`` alone (:func:`~.xy_polynomial.xy_radial`;
        the conic base is): the surface is unchanged by a turn about its axis."""
        return xy_radial({e: float(v) for e, v in zip(self.exponents, self.poly)})

    def paraxial_curvature(self):
        """``c + (A_x² + A_y²) / R_n²`` (1/mm, a 0-d tensor; ``A_x²``, ``A_y²`` the
        coefficients of the ``x̂²`` and ``ŷ²`` terms): the mean of the vertex's two principal
        curvatures (the vertex curvature itself where those terms are equal), as
        :meth:`XYPolynomial.paraxial_curvature <.xy_polynomial.XYPolynomial.paraxial_curvature>`."""
        cur = self.c
        rn2 = self.norm_radius.to(self.c) ** 2
        for A, e in zip(self.poly, self.exponents):
            if e in ((2, 0), (0, 2)):
                cur = cur + A / rn2
        return cur

    def check(self, where: str = "") -> None:
        check_conic_domain(float(self.semi_diameter), float(self.c), float(self.k),
                           "Extended Polynomial's conic base", where)

    def sag_scale(self, name: str) -> float:
        """``c``: ``R^2/2``; ``k``: :func:`~.base.conic_scale`; ``poly.t`` (mm): the term's
        largest size on the rim ``r = R``, ``(R / R_n)^(i+j) max_θ |cos^i θ sin^j θ|`` ``= (R /
        R_n)^(i+j) sqrt(i^i j^j / (i+j)^(i+j))`` (at ``tan² θ = j / i``; ``0^0 = 1``)."""
        parts = name.split(".")
        if parts[0] == "poly":
            i, j = self.exponents[int(parts[1])]
            peak = math.sqrt(i ** i * j ** j / (i + j) ** (i + j))
            return (float(self.semi_diameter) / float(self.norm_radius)) ** (i + j) * peak
        return conic_polynomial_scale(self, name)

    file_fields = ("curvature_per_mm", "conic", "norm_radius_mm", "polynomial_coefficients")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("curvature_per_mm"), semi_diameter, entry.get("norm_radius_mm"),
                   entry.get("polynomial_coefficients", "numbers", default=[]),
                   conic=entry.get("conic", default=0.0))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        d["conic"] = float(self.k)
        d["norm_radius_mm"] = float(self.norm_radius)
        d["polynomial_coefficients"] = [float(v) for v in self.poly]
        return d

    def extra_repr(self) -> str:
        return (f"c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"rn={float(self.norm_radius):.6g} mm, n_terms={len(self.poly)}, "
                + super().extra_repr())
