r"""The shared part of the phase surfaces on a plain conic base (:class:`~.binary1.Binary1`,
:class:`~.zernike_phase.ZernikeFringePhase`).

Each is a :class:`~.binary2.Binary2` without aspheric terms whose phase is

    Φ(x, y) = s M P(x / R_n, y / R_n)   (radians),

with ``M`` the diffraction order, ``R_n`` the normalisation radius (mm), ``P`` the subclass's
polynomial in its coefficients (:meth:`ConicPhase._values`) and ``s`` the coefficients' unit in
radians (:attr:`ConicPhase.phase_unit`: 1 for radians, ``2π`` for waves).  This class holds the
coefficient list's checks, ``Φ`` and ``∇Φ`` from ``P``, the lens-file fields and the rotation
rule; each subclass keeps its polynomial, its paraxial power and its symmetry test.  It is not a
registered surface type.
"""

from __future__ import annotations

import math

from torch import nn

from .asphere import Asphere
from .base import make_param
from .binary2 import Binary2

__all__ = ["ConicPhase"]


class ConicPhase(Binary2):
    """A conic base with the phase ``s M P(x / R_n, y / R_n)`` (module docstring); subclasses
    set the class attributes below and :meth:`_values`.

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm (``0``: flat).
        semi_diameter: clear semi-aperture, mm.
        norm_radius: ``R_n``, the normalisation radius, mm (> 0).
        coefficients: the phase coefficients, in :attr:`phase_unit` (at most :attr:`max_terms`).
        order: the diffraction order ``M`` (an integer).
        conic: conic constant ``k`` of the base.
        obscuration, clear_radius, clear_decenter: as :class:`~.asphere.Asphere`.
    """

    #: the most coefficients
    max_terms: int
    #: the coefficients' unit in radians (``s``)
    phase_unit: float = 1.0
    #: the attribute holding the coefficients (an ``nn.ParameterList``)
    coef_attr: str
    #: each coefficient's parameter name prefix (``A`` -> ``A1, A2, ...``)
    coef_prefix: str
    #: the coefficients in the too-many-terms error (``"phase terms (order 20)"``)
    coef_what: str
    #: the lens-file field of the coefficients
    coef_field: str
    #: the coefficient count's name in ``repr``
    coef_count: str
    #: the lens-file fields of the base and the radius (a subclass adds its coefficients, order)
    base_fields = ("curvature_per_mm", "roc_mm", "conic", "obscuration_mm", "clear_radius_mm",
                   "clear_decenter_mm", "norm_radius_mm")

    def __init__(self, curvature: float, semi_diameter: float, norm_radius: float,
                 coefficients=(), order: int = 1, conic: float = 0.0, obscuration: float = 0.0,
                 clear_radius: float = math.inf, clear_decenter=(0.0, 0.0)):
        super().__init__(curvature, semi_diameter, norm_radius, [], order, conic=conic,
                         obscuration=obscuration, clear_radius=clear_radius,
                         clear_decenter=clear_decenter)
        coefficients = [float(v) for v in coefficients]
        if len(coefficients) > self.max_terms:
            raise ValueError(f"{self._label}: at most {self.max_terms} {self.coef_what}, got "
                             f"{len(coefficients)}")
        setattr(self, self.coef_attr, nn.ParameterList(
            [make_param(v, f"{self.coef_prefix}{t + 1}") for t, v in enumerate(coefficients)]))

    @property
    def _label(self) -> str:
        return type(self).__name__

    @property
    def _coef_list(self) -> nn.ParameterList:
        """The phase coefficients (the subclass's own attribute, :attr:`coef_attr`)."""
        return getattr(self, self.coef_attr)

    # ---- the phase -----------------------------------------------------------------------
    def _values(self, u, v, slopes: bool):
        """``(P, ∂P/∂u, ∂P/∂v)`` at the normalised ``u = x / R_n``, ``v = y / R_n`` (each
        ``(*B,)``; the slopes may be ``None`` when ``slopes`` is false)."""
        raise NotImplementedError

    def _scaled(self, x, y, slopes: bool):
        rn = self.norm_radius.to(x)
        return self._values(x / rn, y / rn, slopes), rn

    def phase(self, x, y):
        """``Φ(x, y) = s M P(x / R_n, y / R_n)`` (radians), ``(*B,)`` from local ``x, y`` (mm)."""
        (P, _, _), _ = self._scaled(x, y, False)
        return (self.phase_unit * self.order) * P

    def phase_grad(self, x, y):
        """``(∂Φ/∂x, ∂Φ/∂y)`` (radians/mm), each ``(*B,)``."""
        (_, Pu, Pv), rn = self._scaled(x, y, True)
        k = self.phase_unit * self.order
        return k * Pu / rn, k * Pv / rn

    def rotationally_symmetric(self) -> bool:
        """Whether the phase is unchanged by a turn about the axis (the subclass's test)."""
        raise NotImplementedError

    @property
    def axisymmetric(self) -> bool:
        """The phase turns with the surface only when it is rotationally symmetric."""
        return self.rotationally_symmetric()

    # ---- lens file ----------------------------------------------------------------------
    @classmethod
    def from_dict(cls, entry, semi_diameter):
        order, rn = cls.order_and_radius(entry)
        base = Asphere.from_dict(entry, semi_diameter)   # the base's fields
        return cls(float(base.c), semi_diameter, rn,
                   entry.get(cls.coef_field, "numbers", default=[]), order,
                   conic=float(base.k), obscuration=float(base.obscuration),
                   clear_radius=float(base.clear_radius),
                   clear_decenter=[float(v) for v in base.clear_decenter])

    def to_dict(self) -> dict:
        d = super().to_dict()
        d.pop("phase_coefficients", None)
        d.pop("aspheric", None)
        d[self.coef_field] = [float(a) for a in self._coef_list]
        return d

    def extra_repr(self) -> str:
        return f"{self.coef_count}={len(self._coef_list)}, " + super().extra_repr()
