r"""Diffraction grating on a sphere or conic (OpticStudio's ``DGRATING``, "Diffraction Grating").

The surface is the conic base of :class:`~.asphere.Asphere` (curvature ``c``, conic ``k``, no
aspheric terms); ruled with straight lines parallel to the local x axis, evenly spaced when
projected onto the local x-y plane: ``T`` lines per micrometre (``PARM 1``), traced in the
diffraction order ``m`` (``PARM 2``).  The grating is the phase ``φ(x, y) = 2π T y`` on the
surface, and a ray leaving it in order ``m`` obeys the vector grating equation

    n' t' = n t + m λ T p,        p = ŷ - (ŷ · N) N,

where ``t = d - (d · N) N`` is the tangential part of the unit direction ``d`` at the unit
normal ``N``, ``λ`` the vacuum wavelength (µm here; rays carry nm), ``n``, ``n'`` the indices
before and after (``n' = n`` at a reflecting grating, ``GLAS MIRROR``) and ``p`` the tangential
part of the grating vector ``ŷ`` (the surface gradient of ``y``).  The normal part follows from
``|d'| = 1``: ``d' = t' ± sqrt(1 - |t'|²) N``, on the far side of the surface for transmission
and back towards the incoming side for reflection.  On a flat grating and in the plane of
incidence this is ``n' sin θ' = n sin θ + m λ T`` (``θ`` measured from the normal towards
``+y``); OpticStudio's sign: an order ``m = -1`` at normal incidence leaves towards ``-y``.

Implementation: the ray is first refracted (:func:`~..refract.refract`) or reflected
(:func:`~..reflect.reflect`) as at the bare surface, then :meth:`Grating.diffract` adds
``m λ T p / n'`` to the tangential part and rebuilds the normal part, so order 0 is the bare
surface's refraction or reflection to round-off.  Where ``|t'| >= 1`` the order is evanescent
(no propagating ray): the ray is marked invalid and keeps a finite direction, so no NaN reaches
a gradient.  The optical path gains the grating's phase, ``m λ T y`` (mm): the eikonal's jump
whose tangential gradient is the change of ``n t``.

Paraxial analysis sees the base surface only: a constant line density has no paraxial power (it
turns the beam's axis, as a tilted mirror does, which the paraxial trace along the local axis
ignores, like OpticStudio's).  A grating traces eagerly (:func:`~..tracer.fused_kind`).
"""

from __future__ import annotations

import math

import torch

from ..interactions import DIFFRACTION
from .asphere import Asphere
from .base import make_param, register_surface

__all__ = ["Grating", "grating_direction", "integer_order", "conic_base_from_dict"]


def grating_direction(d, n, g, kick, valid):
    """Apply the vector grating equation to unit directions already refracted or reflected.

    Args:
        d: ``(*B, 3)`` unit directions after refraction or reflection at the bare surface.
        n: ``(*B, 3)`` unit normals (either orientation).
        g: ``(*B, 3)`` grating vector (unnormalised: its tangential part is taken here).
        kick: ``(*B,)`` or broadcastable: ``m λ T / n'`` (dimensionless) added along the
            tangential part of ``g``.
        valid: ``(*B,)`` incoming mask.

    Returns:
        ``(d', valid)``: ``d'`` keeps the side of the surface ``d`` is on (``sign(d · n)``);
        evanescent orders (``|t'| >= 1``) leave ``valid`` and keep ``d``.
    """
    cos_d = (d * n).sum(-1, keepdim=True)
    t = d - cos_d * n
    p = g - (g * n).sum(-1, keepdim=True) * n
    t = t + kick.unsqueeze(-1) * p
    arg = 1.0 - (t * t).sum(-1)
    ok = valid & (arg > 0)
    root = torch.sqrt(torch.where(ok, arg, torch.ones_like(arg))).unsqueeze(-1)
    out = t + torch.copysign(root, cos_d) * n
    return torch.where(ok.unsqueeze(-1), out, d), ok


def integer_order(order, owner: str) -> int:
    """The diffraction order ``order`` as an ``int``; ``ValueError`` naming ``owner`` (the
    surface class) unless it is a finite integer."""
    m = float(order)
    if not (math.isfinite(m) and m == int(m)):
        raise ValueError(f"{owner}: the diffraction order must be an integer, got {order!r}")
    return int(m)


def conic_base_from_dict(entry, semi_diameter, what: str):
    """The sphere-or-conic base and the order of a diffractive surface's lens-file ``entry``
    (``what`` names the surface in the errors): ``(c, order, base)``, ``c`` the curvature
    (1/mm), ``order`` an int and ``base`` the keyword arguments ``conic``, ``obscuration``,
    ``clear_radius`` and ``clear_decenter`` of :class:`~.asphere.Asphere`.  Refuses aspheric
    terms and an order that is not an integer, naming the field."""
    asph = Asphere.from_dict(entry, semi_diameter)
    if len(asph.a):
        entry.fail("aspheric", f"a {what}'s base is a sphere or conic (no aspheric terms)")
    order = entry.get("order")
    if order != int(order):
        entry.fail("order", f"the diffraction order must be an integer, got {order!r}")
    return float(asph.c), int(order), dict(
        conic=float(asph.k), obscuration=float(asph.obscuration),
        clear_radius=float(asph.clear_radius),
        clear_decenter=[float(v) for v in asph.clear_decenter])


@register_surface("grating")
class Grating(Asphere):
    """A ruled diffraction grating on a sphere or conic (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm (``0``: a flat grating).
        semi_diameter: clear semi-aperture, mm.
        lines_per_um: ``T``, grating lines per micrometre (OpticStudio's ``PARM 1``), lines
            parallel to the local x axis, evenly spaced in the local x-y projection.
        order: the diffraction order ``m`` traced (an integer; OpticStudio's ``PARM 2``).
        conic: conic constant ``k`` of the base.
        obscuration, clear_radius, clear_decenter: as :class:`~.asphere.Asphere`.

    Parameters: ``surface.c``, ``surface.k`` and ``surface.T`` (lines/µm, differentiable);
    ``order`` is a plain integer.  Rays' wavelengths are in nm (``Rays.wavelength``).
    """

    #: the tracer applies :meth:`diffract` after refraction or reflection (and runs it eager)
    interaction = DIFFRACTION

    def __init__(self, curvature: float, semi_diameter: float, lines_per_um: float,
                 order: int, conic: float = 0.0, obscuration: float = 0.0,
                 clear_radius: float = math.inf, clear_decenter=(0.0, 0.0)):
        super().__init__(curvature, semi_diameter, conic=conic, obscuration=obscuration,
                         clear_radius=clear_radius, clear_decenter=clear_decenter)
        t = float(lines_per_um)
        if not math.isfinite(t):
            raise ValueError(f"Grating: lines_per_um must be a finite number (lines per "
                             f"micrometre), got {lines_per_um!r}")
        self.order = integer_order(order, "Grating")
        self.T = make_param(t, "lines per micrometre")

    def kick(self, wavelength_nm, n_after):
        """``m λ T / n'`` (dimensionless) for vacuum wavelengths in nm and the index after."""
        return self.order * (wavelength_nm * 1e-3) * self.T.to(wavelength_nm) / n_after

    def diffract(self, x, d, wavelength_nm, n_after, valid):
        """The order-``m`` direction ``(*B, 3)`` from the refracted or reflected directions
        ``d`` at hits ``x`` (local frame, ``(*B, 3)``); ``wavelength_nm`` and ``n_after`` (the
        index the ray leaves into) broadcast to ``(*B,)``.  Returns ``(d', valid)``."""
        n = self.normal(x)
        g = torch.zeros_like(n)
        g[..., 1] = 1.0
        return grating_direction(d, n, g, self.kick(wavelength_nm, n_after), valid)

    def phase_opl(self, x, wavelength_nm):
        """The optical path (mm) the grating's phase adds at hits ``x``: ``m λ T y``
        (``λ T`` dimensionless, ``y`` in mm), ``(*B,)``."""
        return self.order * (wavelength_nm * 1e-3) * self.T.to(x) * x[..., 1]

    file_fields = Asphere.file_fields + ("lines_per_um", "order")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        c, order, base = conic_base_from_dict(entry, semi_diameter, "grating")
        return cls(c, semi_diameter, entry.get("lines_per_um"), order, **base)

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["lines_per_um"] = float(self.T)
        d["order"] = self.order
        return d

    def extra_repr(self) -> str:
        return f"T={float(self.T.detach()):.6g}/µm, m={self.order}, " + super().extra_repr()
