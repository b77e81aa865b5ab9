r"""Two-point hologram on a sphere or conic (OpticStudio's ``HOLOGRM1`` and ``HOLOGRM2``).

An optically recorded hologram: the interference of two spherical construction beams at the
construction wavelength ``λ_c``, one through each construction point ``P_1``, ``P_2`` (local
frame of the surface, mm).  Played back at the vacuum wavelength ``λ`` in order ``m`` it bends a
ray by Welford's equation, which OpticStudio's help page "Hologram 1" quotes (Ansys OpticStudio
User Guide 2024 R2, *Hologram 1*; W. T. Welford, *Aberrations of Optical Systems*, 1986):

    n' (r'_o × N) = n (r'_r × N) + m (λ / λ_c) (r_o - r_r) × N,

``r_o``, ``r_r`` the unit vectors along the first and second construction beams at the hit
point, ``r'_r`` the incident and ``r'_o`` the outgoing ray, ``N`` the unit normal.  Crossed with
``N`` the equation says the tangential part of ``n d`` jumps by the tangential part of
``m (λ/λ_c) g`` with ``g = r_o - r_r``; the normal part follows from ``|d'| = 1``, on the far
side of the surface, or back towards the incoming side on a mirror (``GLAS MIRROR``: the
hologram recorded and used in reflection).

Which way each construction beam runs: with ``u_i = (x - P_i) / |x - P_i|`` (the unit vector
*away from* ``P_i`` at the hit ``x``),

* ``HOLOGRM2`` (``kind=2``): ``r_o = -u_1``, ``r_r = +u_2`` (the first beam converges towards
  ``P_1``, the second diverges from ``P_2``), so ``g = -(u_1 + u_2)``;
* ``HOLOGRM1`` (``kind=1``): ``r_o = -u_1``, ``r_r = -u_2`` (both of one kind), so
  ``g = u_2 - u_1``.

Decided from OpticStudio's own sample files (deeplens' Zemax guide, *Holograms*, says what each
source settles): a ``HOLOGRM2`` with ``P_1 = (0, 0, -200)``, ``P_2 = (0, 0, 100)``, order 1 and
the object 200 mm before it images the object on ``P_2`` (its image plane 100 mm behind), and a
mirror ``HOLOGRM2`` with ``P_1 = (0, 0, -100)``, ``P_2 = (0, 0, -200)`` images an object at
``P_2`` on ``P_1``; both hold under the ``g`` above and fail under its negative.  So at
``λ = λ_c`` and ``m = 1``, a ray from ``P_1`` leaves a ``HOLOGRM2`` through ``P_2`` and a
``HOLOGRM1`` as if from ``P_2`` (a virtual image): exactly, for every ray (the two beams are
stigmatic by construction).  The ``HOLOGRM1`` sense is by analogy (no sample file has one).

The phase in the optical path is the eikonal whose tangential gradient is ``m (λ/λ_c) g``:

    kind 2: OPL = -m (λ/λ_c) (|x - P_1| - |P_1| + |x - P_2| - |P_2|),
    kind 1: OPL =  m (λ/λ_c) (|x - P_2| - |P_2| - |x - P_1| + |P_1|)      (mm, 0 at the vertex).

Paraxial power (added to the base's ``c (n' - n)`` in :mod:`..paraxial`): the phase's second
derivative along ``y`` at the vertex, ``φ = -d²OPL/dy²``.  With ``L_i = |P_i|`` and
``f_i'' = (1 - c z_i) / L_i - y_i² / L_i³`` (the second derivative of ``|x - P_i|`` along the
base's ``y`` section, curvature ``c``): ``φ = m (λ/λ_c) (f_1'' + f_2'')`` for kind 2 and
``m (λ/λ_c) (f_1'' - f_2'')`` for kind 1.  On a flat hologram with both points on the axis
that is the thin lens ``φ = m (λ/λ_c) (1/|z_1| ± 1/|z_2|)``.  A construction point off the axis
also gives the phase a linear term (it turns the beam's axis, as a grating does), which the
paraxial trace along the local axis ignores, as for :class:`~.grating.Grating`.

Implementation: as :class:`~.grating.Grating` and :class:`~.binary2.Binary2`, the ray is first
refracted or reflected at the bare surface, then :func:`~.grating.grating_direction` adds
``m (λ/λ_c) g / n'`` along the tangential part of ``g`` and rebuilds the normal part; an
evanescent order is marked invalid with a finite direction (no NaN).  Not modelled: a negative
construction wavelength (OpticStudio's hologram recorded in transmission and used in
reflection), volume-hologram efficiency, a construction point at the vertex (``|P_i| = 0``, the
phase's curvature is infinite there).  A hologram traces eagerly (:func:`~..tracer.fused_kind`).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..interactions import DIFFRACTION
from .asphere import Asphere
from .base import make_param, register_surface
from .grating import conic_base_from_dict, grating_direction, integer_order

__all__ = ["Hologram"]


def _unit_away(x, p):
    """``(x - p) / |x - p|`` and ``|x - p|`` for hits ``x`` ``(*B, 3)`` and a point ``p`` ``(3,)``."""
    v = x - p
    r = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    # a hit exactly on a construction point (a point on the substrate) has no direction: a
    # finite one (0) instead of NaN
    return v / r.clamp_min(torch.finfo(x.dtype).tiny), r.squeeze(-1)


@register_surface("hologram")
class Hologram(Asphere):
    """A two-point hologram on a sphere or conic (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm (``0``: flat).
        semi_diameter: clear semi-aperture, mm.
        point1, point2: the construction points ``(x, y, z)`` in the surface's local frame, mm
            (OpticStudio's ``PARM 1-3`` and ``PARM 4-6``); neither at the vertex.
        construction_wavelength_nm: ``λ_c`` (> 0), nm (OpticStudio's ``PARM 7``, in µm).
        order: the diffraction order ``m`` (an integer; ``PARM 8``).
        kind: ``2`` (``HOLOGRM2``: one beam converging, one diverging) or ``1``
            (``HOLOGRM1``: both alike); the module docstring gives the senses.
        conic: conic constant ``k`` of the base.
        obscuration, clear_radius, clear_decenter: as :class:`~.asphere.Asphere`.

    Parameters: ``surface.c``, ``surface.k``, ``surface.P1[j]``, ``surface.P2[j]`` (the
    points' ``x, y, z``, mm; ``surface.p1``, ``surface.p2`` stack them, ``(3,)``) and
    ``surface.wl_c`` (nm), all differentiable; ``order`` and ``kind`` are plain integers.
    """

    #: the tracer applies :meth:`diffract` after refraction or reflection (and runs it eager)
    interaction = DIFFRACTION

    def __init__(self, curvature: float, semi_diameter: float, point1, point2,
                 construction_wavelength_nm: float, order: int = 1, kind: int = 2,
                 conic: float = 0.0, obscuration: float = 0.0, clear_radius: float = math.inf,
                 clear_decenter=(0.0, 0.0)):
        super().__init__(curvature, semi_diameter, conic=conic, obscuration=obscuration,
                         clear_radius=clear_radius, clear_decenter=clear_decenter)
        if kind not in (1, 2):
            raise ValueError(f"Hologram: kind must be 1 (HOLOGRM1) or 2 (HOLOGRM2), got {kind!r}")
        m = integer_order(order, "Hologram")
        wl = float(construction_wavelength_nm)
        if not (math.isfinite(wl) and wl > 0):
            raise ValueError(f"Hologram: the construction wavelength must be a finite number "
                             f"> 0 (nm), got {construction_wavelength_nm!r}")
        pts = []
        for name, p in (("point1", point1), ("point2", point2)):
            v = [float(t) for t in p]
            if len(v) != 3:
                raise ValueError(f"Hologram: {name} must be (x, y, z) in mm, got {p!r}")
            if not all(math.isfinite(t) for t in v):
                raise ValueError(f"Hologram: {name} must be finite (mm), got {p!r}")
            if math.hypot(*v) == 0.0:
                raise ValueError(f"Hologram: {name} is at the surface's vertex (0, 0, 0): the "
                                 f"construction beam's curvature is infinite there")
            pts.append(v)
        self.P1 = nn.ParameterList([make_param(v, f"point1 {a}") for v, a in zip(pts[0], "xyz")])
        self.P2 = nn.ParameterList([make_param(v, f"point2 {a}") for v, a in zip(pts[1], "xyz")])
        self.wl_c = make_param(wl, "construction wavelength")
        self.order = m
        self.kind = int(kind)

    @property
    def p1(self):
        """Construction point 1, ``(3,)`` (mm, local frame): ``P1[0..2]`` stacked."""
        return torch.stack(list(self.P1))

    @property
    def p2(self):
        """Construction point 2, ``(3,)`` (mm, local frame): ``P2[0..2]`` stacked."""
        return torch.stack(list(self.P2))

    # ---- the ray law ---------------------------------------------------------------------
    def _mu(self, wavelength_nm, like):
        """``m λ / λ_c`` (dimensionless), broadcastable to ``(*B,)``."""
        w = torch.as_tensor(wavelength_nm, dtype=like.dtype, device=like.device)
        return self.order * w / self.wl_c.to(like)

    def grating_vector(self, x):
        """``g`` ``(*B, 3)`` at hits ``x`` ``(*B, 3)`` (local frame, mm): ``-(u_1 + u_2)`` for
        kind 2, ``u_2 - u_1`` for kind 1 (module docstring)."""
        u1, _ = _unit_away(x, self.p1.to(x))
        u2, _ = _unit_away(x, self.p2.to(x))
        return -(u1 + u2) if self.kind == 2 else u2 - u1

    def diffract(self, x, d, wavelength_nm, n_after, valid):
        """The order-``m`` direction ``(*B, 3)`` from the refracted or reflected directions
        ``d`` at hits ``x`` (local frame, ``(*B, 3)``); ``wavelength_nm`` and ``n_after`` (the
        index the ray leaves into) broadcast to ``(*B,)``.  Returns ``(d', valid)``."""
        kick = self._mu(wavelength_nm, x) / n_after
        return grating_direction(d, self.normal(x), self.grating_vector(x), kick, valid)

    def phase_opl(self, x, wavelength_nm):
        """The optical path (mm) the hologram adds at hits ``x``, ``(*B,)`` (module
        docstring: 0 at the vertex)."""
        p1, p2 = self.p1.to(x), self.p2.to(x)
        _, r1 = _unit_away(x, p1)
        _, r2 = _unit_away(x, p2)
        e1 = r1 - torch.linalg.vector_norm(p1)
        e2 = r2 - torch.linalg.vector_norm(p2)
        w = -(e1 + e2) if self.kind == 2 else e2 - e1
        return self._mu(wavelength_nm, x) * w

    def paraxial_phase_power(self, wavelength_nm: float):
        """The hologram's paraxial power (1/mm, a 0-d tensor) at the vacuum wavelength
        ``wavelength_nm``: ``m (λ/λ_c) (f_1'' ± f_2'')`` (module docstring); added to
        ``c (n' - n)`` by :mod:`..paraxial`."""
        c = self.c
        terms = []
        for p in (self.p1, self.p2):
            L = torch.linalg.vector_norm(p)
            terms.append((1.0 - c.to(p) * p[2]) / L - p[1] ** 2 / L ** 3)
        f = terms[0] + terms[1] if self.kind == 2 else terms[0] - terms[1]
        return self.order * (float(wavelength_nm) / self.wl_c) * f

    # ---- lens file ----------------------------------------------------------------------
    file_fields = Asphere.file_fields + ("point1_mm", "point2_mm", "construction_wavelength_nm",
                                         "order", "kind")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        c, order, base = conic_base_from_dict(entry, semi_diameter, "hologram")
        kind = entry.get("kind")
        if kind not in (1, 2):
            entry.fail("kind", f"must be 1 (HOLOGRM1) or 2 (HOLOGRM2), got {kind!r}")
        pts = []
        for key in ("point1_mm", "point2_mm"):
            p = entry.get(key, "numbers")
            if len(p) != 3:
                entry.fail(key, f"must be three numbers (x, y, z) in mm, got {p!r}")
            pts.append(p)
        wl = entry.get("construction_wavelength_nm")
        if not wl > 0:
            entry.fail("construction_wavelength_nm", f"must be > 0 (nm), got {wl!r}")
        return cls(c, semi_diameter, pts[0], pts[1], wl, order, int(kind), **base)

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["point1_mm"] = [float(v) for v in self.p1]
        d["point2_mm"] = [float(v) for v in self.p2]
        d["construction_wavelength_nm"] = float(self.wl_c)
        d["order"] = self.order
        d["kind"] = self.kind
        return d

    def extra_repr(self) -> str:
        p1 = ", ".join(f"{float(v):.6g}" for v in self.p1.detach())
        p2 = ", ".join(f"{float(v):.6g}" for v in self.p2.detach())
        return (f"HOLOGRM{self.kind}, P1=({p1}), P2=({p2}) mm, λc={float(self.wl_c):.6g} nm, "
                f"m={self.order}, " + super().extra_repr())
