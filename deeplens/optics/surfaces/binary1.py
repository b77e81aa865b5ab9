r"""Diffractive surface with an x-y polynomial phase (OpticStudio's ``BINARY_1``, "Binary 1").

A conic base (curvature ``c``, conic ``k``: :class:`~.asphere.Asphere` without aspheric terms)
carrying the phase

    Φ(x, y) = M Σ_{t=1..N} A_t x̂^i ŷ^j   (radians),     x̂ = x / R_n,  ŷ = y / R_n,

with ``M`` the diffraction order, ``R_n`` the normalisation radius (mm) and the terms ``t`` in
OpticStudio's Extended Polynomial order (by total degree from 1, within a degree from ``x^d``
down to ``y^d``: ``x, y, x², xy, y², x³, x²y, ...``; :func:`~.extended_polynomial.extended_terms`,
at most order 20, 230 terms), the coefficients ``A_t`` in **radians**.  The polynomial is
evaluated by :func:`~.xy_polynomial.xy_poly` (the XY polynomial's and Extended Polynomial's own
code).  The ray law, optical path and eager trace are :class:`~.binary2.Binary2`'s
(``n' t' = n t + λ/(2π) ∇Φ``, the path gains ``λ Φ / 2π``): a ray's direction cosines change by
``M λ/(2π) ∂(Σ A_t x̂^i ŷ^j)/∂x`` (``λ`` in mm), a positive phase slope deflecting towards ``+x``.

Closed forms (used by the tests): a tilt ``A_1`` (``x``) alone turns every ray by the same
``Δl = M λ A_1 / (2π R_n)`` (``A_2``, ``y``: ``Δm``); ``A_3 = A_5 = a`` (``x² + y²``) alone is a
lens of paraxial power ``φ = −M λ a / (π R_n²)``, ``f = −π R_n² / (M λ a)`` (Binary 2's ``A_1``).
The paraxial power (:meth:`paraxial_phase_power`, added to ``c (n' − n)`` by :mod:`..paraxial`)
is that of the y-z section, as :class:`~.zernike_phase.ZernikeFringePhase`'s:
``φ_y = −(λ/2π) ∂²Φ/∂y² |_0 = −M λ A_5 / (π R_n²)``; tilts and the other terms do not enter it.

Sources:

* Zemax knowledge base, "How Diffractive Surfaces are Modeled in ZEMAX" (zemax.com/kb/articles/
  51): every diffractive surface bends rays by the grating law with a local period; "the Binary 1
  surface allows the grating period to vary as an x-y polynomial expansion".
* The phase coefficients are radians and ``OPL = Φ λ / 2π``: Zemax knowledge base, "How to
  design diffractive optics using the Binary 2 surface" (zemax.com/kb/articles/42); the
  OpticStudio manual's binary-optics section (its Chinese translation on opticsky.cn, thread
  144185): the binary optic surfaces carry polynomial terms for the phase "rather than the surface
  height", "therefore their coefficients are in radians rather than lens units".
* The records and term order: OpticStudio User Guide, "Extended Polynomial" (ansyshelp.ansys.com,
  2024 R2): the maximum term number, the normalisation radius, then the terms "x, then y, then
  x*x, x*y, y*y, etc." (extra data 1, 2, 3.. in a ``.zmx``: ``XDAT 1``, ``XDAT 2``, ``XDAT 3..``).
* OpticStudio's own numbers: its short-course sample "diffract3" (a flat Binary 1 stop, 18
  terms, ``R_n`` = 10 mm, EPD 20 mm, 0.55 µm, an image plane 80 mm behind) stores the automatic
  semi-diameter OpticStudio computed at the image, 7.07057849426 mm: the +y marginal ray's height
  there with the layout, radians, ``M = PARM 0 = 1`` and the sign above, to every printed digit
  (the terms in the other order within a degree miss by 7e-4 mm, the opposite sign by 20 mm,
  waves or ``M = 2`` by more).  No OpticStudio help page for "Binary 1" itself was found in the
  stored pages: what ``PARM 0`` other than 1 and the other ``PARM`` mean is left to the reader,
  which refuses them.
"""

from __future__ import annotations

import math

import torch

from .base import register_surface
from .conic_phase import ConicPhase
from .extended_polynomial import MAX_EXTENDED_TERMS, extended_terms
from .xy_polynomial import xy_poly

__all__ = ["Binary1"]


@register_surface("binary1")
class Binary1(ConicPhase):
    """A conic base with an x-y polynomial diffractive phase (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm (``0``: flat).
        semi_diameter: clear semi-aperture, mm.
        norm_radius: ``R_n``, the normalisation radius of ``x̂ = x / R_n``, mm (> 0).
        terms: ``[A_1, ..., A_N]`` in OpticStudio's Extended Polynomial order, radians
            (``N <= 230``).
        order: the diffraction order ``M`` (an integer).
        conic: conic constant ``k`` of the base.
        obscuration, clear_radius, clear_decenter: as :class:`~.asphere.Asphere`.

    Parameters: ``surface.c``, ``surface.k`` and ``surface.poly[t − 1]`` (``A_t``, radians),
    differentiable; ``order`` is a plain integer and ``norm_radius`` a fixed buffer (mm).  Rays'
    wavelengths are in nm.
    """

    #: OpticStudio's most terms (order 20)
    max_terms = MAX_EXTENDED_TERMS
    coef_attr, coef_prefix, coef_what = "poly", "A", "phase terms (order 20)"
    coef_field, coef_count = "phase_terms_rad", "n_terms"

    def __init__(self, curvature: float, semi_diameter: float, norm_radius: float, terms=(),
                 order: int = 1, conic: float = 0.0, obscuration: float = 0.0,
                 clear_radius: float = math.inf, clear_decenter=(0.0, 0.0)):
        super().__init__(curvature, semi_diameter, norm_radius, terms, order, conic,
                         obscuration, clear_radius, clear_decenter)
        self.exponents = extended_terms(len(self.poly))
        self._degree = max([i + j for i, j in self.exponents] + [0])

    # ---- the phase -----------------------------------------------------------------------
    def _values(self, u, v, slopes: bool):
        """``(Σ A_t u^i v^j, ∂/∂u, ∂/∂v)`` (radians), each ``(*B,)``."""
        return xy_poly(u, v, list(self.poly), self.exponents, self._degree)

    def paraxial_phase_power(self, wavelength_nm: float):
        """The paraxial power of the phase's y-z section, ``−M λ A_5 / (π R_n²)`` (1/mm, a 0-d
        tensor; ``A_5`` the ``y²`` term) at the vacuum wavelength ``wavelength_nm``."""
        rn = self.norm_radius
        if len(self.poly) < 5:
            return torch.zeros((), dtype=rn.dtype, device=rn.device)
        a5 = self.poly[4]
        return -self.order * a5 * (float(wavelength_nm) * 1e-6) / (math.pi * rn.to(a5) ** 2)

    def rotationally_symmetric(self) -> bool:
        """Whether the polynomial is a function of ``x² + y²``: every odd degree zero, every even
        degree ``2h`` proportional to ``(x² + y²)^h`` (the binomial coefficients on ``x^(2h−2m)
        y^(2m)``, odd powers zero; to 1e-12 relative)."""
        by_degree: dict[int, dict[tuple[int, int], float]] = {}
        for A, (i, j) in zip(self.poly, self.exponents):
            by_degree.setdefault(i + j, {})[(i, j)] = float(A)
        for d, row in by_degree.items():
            vals = list(row.values())
            if d % 2:
                if any(v != 0.0 for v in vals):
                    return False
                continue
            h = d // 2
            scale = row.get((d, 0), 0.0)
            tol = 1e-12 * max(abs(v) for v in vals)
            for (i, j), v in row.items():
                want = scale * math.comb(h, j // 2) if j % 2 == 0 else 0.0
                if abs(v - want) > tol:
                    return False
        return True

    # ---- lens file ----------------------------------------------------------------------
    file_fields = ConicPhase.base_fields + ("phase_terms_rad", "order")
