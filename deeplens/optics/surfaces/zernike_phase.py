r"""Diffractive surface with a Zernike Fringe phase (OpticStudio's ``FZERNPHA``, "Zernike Fringe
Phase").

A conic base (curvature ``c``, conic ``k``: :class:`~.asphere.Asphere` without aspheric terms)
carrying the phase

    Φ(x, y) = 2π M Σ_{j=1..N} A_j Z_j(ρ, φ)   (radians),     ρ = r / R_n,  φ = atan2(y, x),

with ``M`` the diffraction order, ``R_n`` the normalisation radius (mm), ``Z_j`` the Zernike
Fringe polynomials (:func:`~.zernike_sag.fringe_nm`: ``Z1 = 1``, ``Z2 = ρ cos φ``, ``Z3 = ρ sin
φ``, ``Z4 = 2ρ² − 1``, ``Z5 = ρ² cos 2φ``, ..., ``Z9 = 6ρ⁴ − 6ρ² + 1``, ..., at most 37 terms;
evaluated by :func:`~.zernike_sag.zernike_values`, the code of :class:`~.zernike_sag.ZernikeFringeSag`)
and the coefficients ``A_j`` in **waves** of phase (one wave is ``2π`` radians at every
wavelength).  The ray law, optical path and eager trace are :class:`~.binary2.Binary2`'s
(``n' t' = n t + λ/(2π) ∇Φ``, the path gains ``λ Φ / 2π``): so a ray's direction cosines change
by ``M λ ∂(Σ A_j Z_j)/∂x`` (``λ`` in mm), and a positive phase slope deflects towards ``+x``.

Closed forms (used by the tests): a tilt ``A_2`` alone deflects every ray by the same
``Δl = M λ A_2 / R_n``; a defocus ``A_4`` alone is a lens of paraxial power ``φ = −4 M λ A_4 /
R_n²`` (``Φ ≈ 2π M A_4 (2ρ² − 1)``, ``φ = −(λ/2π)(dΦ/dr)/r``).  In general the paraxial power
(:meth:`paraxial_phase_power`, added to ``c (n' − n)`` by :mod:`..paraxial`) is that of the y-z
section, as OpticStudio's paraxial trace and deeplens' other anamorphic surfaces
(:class:`~.biconic.Biconic`: ``c_y``): ``φ_y = −(λ/2π) ∂²Φ/∂y² |_0 = −2 M λ (Σ_{m=0, n>=2} A_j
r_n − Σ_{cos 2φ} A_j q_n) / R_n²`` with ``r_n = (−1)^(n/2−1) (n/2)(n/2 + 1)`` the ``ρ²``
coefficient of ``R_n^0`` and ``q_n = r_n / 2`` that of ``R_n^2`` (``ρ² cos 2φ = (x² − y²)/R_n²``);
piston, tilts and the other terms do not enter it.

Sources (no OpticStudio help page for this surface was found in the stored pages):

* The coefficients are waves of phase, wavelength-independent as phase: Zemax knowledge base,
  "How to use the Zernike Sag surface to model an all-reflective system" (support.zemax.com,
  M. Nicholson): the Zernike *phase* surface's "one wave of phase is one wave at any
  wavelength" (which is why that article uses the sag surface for mirrors).
* The records (``XDAT 1`` the number of terms, ``XDAT 2`` the normalisation radius, ``XDAT 3..``
  the Fringe coefficients ``A_1, A_2, ...``, times ``2π``): the independent reader zmxtools
  (``FZERNPHA``: ``extra_data[1]`` the radius, ``extra_data[2:] * 2π`` the phase coefficients in
  Fringe order).
* OpticStudio's own numbers: three OpticStudio sample files (Test_Spherical, Test_Astigmatism,
  Test_Coma: a Zernike Fringe Phase surface before a paraxial lens of f = 100 mm, EPD 4 mm,
  λ = 0.55 µm, R_n = 4 mm) store the automatic semi-diameters OpticStudio computed: with
  ``A_1 = −2, A_4 = −3, A_9 = −1`` (``Σ A_j Z_j = −6ρ⁴``) the marginal ray meets the paraxial
  focus at 0.04125000351 mm = f tan(asin(0.75 λ)) and the plane 98 mm behind the lens at
  4.250034e-4 mm, which the waves, the Fringe order, ``XDAT 2`` as ``R_n`` and the sign above
  reproduce to every printed digit (radians would give 2π times less).
* ``PARM 0`` is 1 in every file seen; whether OpticStudio reads it as the diffraction order (as
  Binary 2's ``PARM 0``) or as an extrapolate flag (as Zernike Fringe Sag's) no stored source
  says: both read 1 the same way within the normalisation radius, so the reader accepts only 1
  (``M = 1``), keeps the terms beyond ``ρ = 1`` (the polynomial continued) and refuses any other
  value on its line.
"""

from __future__ import annotations

import math

import torch

from .base import register_surface
from .conic_phase import ConicPhase
from .zernike_sag import BASES, MAX_FRINGE_TERMS, zernike_values

__all__ = ["ZernikeFringePhase"]


@register_surface("zernike_fringe_phase")
class ZernikeFringePhase(ConicPhase):
    """A conic base with a Zernike Fringe diffractive phase (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm (``0``: flat).
        semi_diameter: clear semi-aperture, mm.
        norm_radius: ``R_n``, the normalisation radius of ``ρ = r / R_n``, mm (> 0).
        zernike: ``[A_1, ..., A_N]``, the Fringe-ordered coefficients, waves (``N <= 37``).
        order: the diffraction order ``M`` (an integer).
        conic: conic constant ``k`` of the base.
        obscuration, clear_radius, clear_decenter: as :class:`~.asphere.Asphere`.

    Parameters: ``surface.c``, ``surface.k`` and ``surface.zernike[j − 1]`` (``A_j``, waves),
    differentiable; ``order`` is a plain integer and ``norm_radius`` a fixed buffer (mm).  Rays'
    wavelengths are in nm.
    """

    #: the most Fringe terms (OpticStudio's Fringe set)
    max_terms = MAX_FRINGE_TERMS
    #: waves: one is ``2π`` radians
    phase_unit = 2.0 * math.pi
    coef_attr, coef_prefix, coef_what = "zernike", "Z", "Fringe terms"
    coef_field, coef_count = "zernike_waves", "n_zernike"

    def __init__(self, curvature: float, semi_diameter: float, norm_radius: float, zernike=(),
                 order: int = 1, conic: float = 0.0, obscuration: float = 0.0,
                 clear_radius: float = math.inf, clear_decenter=(0.0, 0.0)):
        super().__init__(curvature, semi_diameter, norm_radius, zernike, order, conic,
                         obscuration, clear_radius, clear_decenter)

    # ---- the phase -----------------------------------------------------------------------
    def _values(self, u, v, slopes: bool):
        """``(Σ A_j Z_j, ∂/∂u, ∂/∂v)`` (waves), each ``(*B,)``."""
        return zernike_values(u, v, self.zernike, slopes, "fringe")

    def paraxial_phase_power(self, wavelength_nm: float):
        """The paraxial power of the phase's y-z section, ``−2 M λ (Σ_{m=0} A_j r_n −
        Σ_{cos 2φ} A_j r_n / 2) / R_n²`` (1/mm, a 0-d tensor; module docstring) at the vacuum
        wavelength ``wavelength_nm``."""
        rn = self.norm_radius
        acc = torch.zeros((), dtype=rn.dtype, device=rn.device)
        nm = BASES["fringe"][0]
        for j, A in enumerate(self.zernike, start=1):
            n, m = nm(j)
            h = n // 2
            if m == 0 and n >= 2:
                acc = acc + (-1) ** (h - 1) * h * (h + 1) * A.to(acc)
            elif m == 2:   # R_n^2 ρ² coefficient r_n / 2; cos 2φ is −1 along y
                acc = acc - (-1) ** (h - 1) * h * (h + 1) / 2 * A.to(acc)
        return -2.0 * self.order * (float(wavelength_nm) * 1e-6) * acc / rn ** 2

    def rotationally_symmetric(self) -> bool:
        """Whether every non-zero term has ``m = 0`` (the phase is unchanged by a turn)."""
        nm = BASES["fringe"][0]
        return all(nm(j)[1] == 0 for j, A in enumerate(self.zernike, start=1)
                   if float(A) != 0.0)

    # ---- lens file ----------------------------------------------------------------------
    file_fields = ConicPhase.base_fields + ("zernike_waves", "order")
