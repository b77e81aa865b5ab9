r"""Fresnel surface: a plane that refracts (or reflects) as a curved surface would.

OpticStudio's sequential "Fresnel" surface (``TYPE FRESNELS``) "models a plane surface which has
the refractive (or reflective) power of a curved surface" (OpticStudio User Guide, *Extended
Fresnel*); its facets are idealised to infinitesimal height: "OpticStudio traces rays to the
surface, ignoring the presence of the grooves, and then refracts rays as though the grooves
truly exist" (Zemax knowledge base, *How to model a Fresnel lens in OpticStudio*, 2018).  So a
ray meets the plane ``z = 0`` (the substrate) at ``(x, y, 0)`` and is refracted by vector
Snell's law about the normal of the *facet profile*

    z_f(r) = c r² / (1 + sqrt(1 − (1 + k) c² r²)) + Σ_{i=1..8} α_i r^{2i}

at the same ``(x, y)`` (``CURV``, ``CONI``, ``PARM 1..8``: OpticStudio's Even Asphere terms, the
``r²`` one included), held here as an :class:`~.odd_asphere.OddAsphere` (its even powers;
``facet``), whose parameters are this surface's (``facet.c``, ``facet.k``, ``facet.a.j``).  A
mirror reflects about the same normal.  Paraxial data see the facet profile's vertex curvature,
``c + 2 α_1``: a thin Fresnel lens has the power of the curved surface it replaces.

The optical path is the plane's geometric path; the facets' phase is not added (OpticStudio
computes one for a plane substrate, by a model its pages at hand do not give), so wavefront,
PSF and MTF analyses of a lens with a Fresnel surface miss that phase; ray positions,
directions, spots and first-order data do not.  The substrate's sag is 0, so the facet
parameters do not move it (their design scale is 1, :meth:`~.base.Surface.sag_scale`).  Traced
eagerly (no compiled kernel: the law is not Snell's law at the substrate's own normal).
"""

from __future__ import annotations

import torch

from ..interactions import Interaction
from ..reflect import reflect
from ..refract import refract
from .base import register_surface
from .odd_asphere import OddAsphere
from .plane import Plane

__all__ = ["Fresnel", "FacetRefraction", "FACET_REFRACTION"]


class FacetRefraction(Interaction):
    """Vector Snell's law (``n1 / n2``) about ``surface.facet_normal(x)``, or the law of
    reflection about it at a mirror: the idealised facets of a :class:`Fresnel` surface."""

    name = "refract"
    fusable = False

    def __call__(self, surface, x, d, n1, n2, wavelength, valid, opl, mirror: bool):
        normal = surface.facet_normal(x)
        valid = valid & surface.in_domain(x[..., 0], x[..., 1])   # the facet profile's conic
        if mirror:
            d, valid = reflect(d, normal, valid)
        else:
            d, valid = refract(d, normal, n1 / n2, valid)
        return d, valid, opl


#: the shared instance the surfaces hold (stateless)
FACET_REFRACTION = FacetRefraction()


@register_surface("fresnel")
class Fresnel(Plane):
    """A plane substrate with the facets of the profile ``facet`` (module docstring).

    Args:
        curvature: the facet profile's vertex curvature ``c`` (1/mm).
        semi_diameter: clear semi-aperture (mm).
        conic: its conic constant ``k``.
        coefficients: ``[α_1, α_2, ...]`` of ``r², r⁴, ...`` (mm^(1−2i)), at most 10.
    """

    interaction = FACET_REFRACTION

    def __init__(self, curvature: float, semi_diameter: float, conic: float = 0.0,
                 coefficients=()):
        super().__init__(semi_diameter)
        coefficients = [float(v) for v in coefficients]
        if len(coefficients) > 10:
            raise ValueError(f"Fresnel: at most 10 even coefficients (r² .. r²⁰), got "
                             f"{len(coefficients)}")
        radial = [0.0] * (2 * len(coefficients))
        radial[1::2] = coefficients           # r^(2i) is OddAsphere's coefficient 2i - 1
        self.facet = OddAsphere(curvature, semi_diameter, conic=conic, coefficients=radial)

    @property
    def even_coefficients(self) -> list[float]:
        """``[α_1, α_2, ...]`` of ``r², r⁴, ...`` (mm^(1−2i))."""
        return [float(a) for a in list(self.facet.a)[1::2]]

    def facet_normal(self, x):
        """Unit normal ``(*B, 3)`` of the facet profile above the hits ``x`` (local frame, on
        the plane): the profile's normal at ``(x, y, z_f(x, y))``, oriented as the plane's
        (``z`` component negative)."""
        X, Y, _ = x.unbind(-1)
        on_facet = torch.stack([X, Y, self.facet.sag(X, Y)], -1)
        return self.facet.normal(on_facet)

    def in_domain(self, x, y):
        return self.facet.in_domain(x, y)

    def paraxial_curvature(self):
        return self.facet.paraxial_curvature()

    def check(self, where: str = "") -> None:
        self.facet.check(where)

    file_fields = ("curvature_per_mm", "conic", "fresnel_coefficients")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("curvature_per_mm"), semi_diameter,
                   conic=entry.get("conic", default=0.0),
                   coefficients=entry.get("fresnel_coefficients", "numbers", default=[]))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.facet.c)
        d["conic"] = float(self.facet.k)
        d["fresnel_coefficients"] = self.even_coefficients
        return d

    def extra_repr(self) -> str:
        return (f"facets: c={float(self.facet.c.detach()):.6g}/mm, "
                f"k={float(self.facet.k.detach()):.6g}, " + super().extra_repr())
