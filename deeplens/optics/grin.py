r"""Gradient-index (GRIN) media: a refractive index that varies with position.

A graded medium fills the gap after the surface that starts it (its *entry* surface) up to the
next surface.  Its index is a function of the position ``(x, y, z)`` in the entry surface's
frame (``z`` from its vertex, ``r² = x² + y²``), constant in wavelength:

* :class:`RadialGradient` (OpticStudio's Gradient 1, ``TYPE GRINSUR1``)::

      n(r) = n0 + nr2 r²

  OpticStudio User Guide, "Gradient 1" (parameters 1 ``Δt``, the maximum step, 2 ``n0``,
  3 ``nr2``; the sibling pages "Gradient 3" and "Gradient 12", ansyshelp.ansys.com, v242, list
  the same first three parameters).  ``n ∇n = (2 n nr2 x, 2 n nr2 y, 0)``.

* :class:`SquareLawGradient` (the textbook parabolic profile, exact sinusoidal meridional
  rays; used to test the tracer against a closed form)::

      n(r)² = n0² (1 − g² r²)            n ∇n = ½ ∇n² = −n0² g² (x, y, 0)

Paraxial transfer through a slab of length ``L`` of a radial quadratic medium, acting on
``(y, n0 u)`` (the reduced slope of :mod:`deeplens.analysis.cardinal`): near the axis both
profiles are ``n ≈ n0 (1 − g² r² / 2)`` with ``g² = −2 nr2 / n0`` (the square-law one by
definition), and the paraxial ray equation ``y'' = (1/n0) ∂n/∂y = −g² y`` gives

    [[cos gL,            sin(gL) / (n0 g)],
     [−n0 g sin gL,      cos gL          ]]

(:func:`radial_transfer`); ``g² < 0`` (an index rising off axis: a diverging rod) turns the
circular functions into hyperbolic ones, and ``g → 0`` into the homogeneous slab
``[[1, L/n0], [0, 1]]``.  Written with ``q = g² L²``: ``cos gL = C(q)``, ``sin(gL)/g = L S(q)``,
``g sin gL = g² L S(q)``, with ``C``, ``S`` the even functions ``cos √q``, ``sin √q / √q``
(``cosh``, ``sinh`` for ``q < 0``; a Taylor series for ``|q| < 1e-3``), so the matrix is one
smooth function of ``nr2`` and ``L`` for autograd.

Every graded medium has ``graded = True``, :meth:`GradedMedium.local` (index and ``n ∇n`` at
points), ``step_mm`` (the integration step, OpticStudio's ``Δt``) and
:meth:`GradedMedium.paraxial_transfer`; :meth:`~.materials.Material.n` gives the axial index
``n0`` (what paraxial refraction at the bounding surfaces uses).  The rays are propagated
through it by :mod:`.grin_trace`.  Coefficients are ``nn.Parameter`` objects created frozen
(``requires_grad_(True)`` to optimise them), in float64 until ``lens.to(dtype)``.
"""

from __future__ import annotations

import math

import torch

from .materials import Material
from .surfaces.base import make_param

__all__ = ["GradedMedium", "RadialGradient", "SquareLawGradient", "radial_transfer"]

#: below this ``|g² L²|`` the transfer matrix uses its Taylor series (truncation < 1e-19)
_SERIES_Q = 1e-3


def radial_transfer(g2: torch.Tensor, length: torch.Tensor, n0: torch.Tensor):
    """The paraxial matrix ``(A, B, C, D)`` of a radial quadratic slab (module docstring) acting
    on ``(y, n0 u)``: ``g2`` the gradient constant ``g²`` (1/mm², either sign), ``length`` (mm),
    ``n0`` the axial index; 0-d tensors.  Differentiable in all three, also at ``g² = 0``."""
    q = g2 * length * length
    small = q.abs() < _SERIES_Q
    qs = torch.where(small, torch.ones_like(q), q)       # keeps the unused branches finite
    pos = qs > 0
    root = torch.sqrt(qs.abs())
    c_far = torch.where(pos, torch.cos(root), torch.cosh(root))
    s_far = torch.where(pos, torch.sin(root), torch.sinh(root)) / root
    c_near = 1 - q / 2 + q * q / 24 - q * q * q / 720
    s_near = 1 - q / 6 + q * q / 120 - q * q * q / 5040
    c = torch.where(small, c_near, c_far)
    s = torch.where(small, s_near, s_far)
    return c, length * s / n0, -n0 * g2 * length * s, c


class GradedMedium(Material):
    """Base class of the graded media (module docstring).

    Args:
        name: a description.
        n0: the axial index (the index at the entry surface's vertex).
        step_mm: the integration step of :mod:`.grin_trace` (mm of path; OpticStudio's
            ``Δt``, the maximum step size), ``> 0``.
    """

    graded = True

    def __init__(self, name: str, n0: float, step_mm: float):
        # constant in wavelength: every wavelength (the range of a non-dispersive medium)
        super().__init__(name, (1e-9, math.inf))
        if not float(n0) >= 1e-3:
            raise ValueError(f"{name}: the axial index n0 must be >= 0.001, got {n0!r}")
        if not (float(step_mm) > 0 and math.isfinite(float(step_mm))):
            raise ValueError(f"{name}: the step (Delta T) must be a positive number of mm, "
                             f"got {step_mm!r}")
        self.n0 = make_param(float(n0), f"{name} n0")
        self.step_mm = float(step_mm)

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        return self.n0.to(w).expand(w.shape)

    def local(self, x, y, z):
        """``(n, Dx, Dy, Dz)`` at points ``(x, y, z)`` (``(*B,)`` each, mm, the entry surface's
        frame): the index and ``D = n ∇n`` (1/mm), the right-hand side of the ray equation in
        the optical-path parameter (:mod:`.grin_trace`)."""
        raise NotImplementedError

    def g2(self) -> torch.Tensor:
        """The paraxial gradient constant ``g² = −(1/n0) ∂²n/∂r²`` at the axis (1/mm²)."""
        raise NotImplementedError

    def paraxial_transfer(self, length, n):
        """``(A, B, C, D)`` acting on ``(y, n u)`` across ``length`` mm of this medium
        (:func:`radial_transfer`; ``n``, the caller's axial index, is unused: the medium's own
        ``n0`` is)."""
        like = torch.as_tensor(length)
        n0 = self.n0.to(like)
        return radial_transfer(self.g2().to(like), like, n0)

    def to_spec(self) -> str:
        raise ValueError(f"the graded medium {self.name!r} has no material name: deeplens' "
                         f"lens files have no gradient-index record; write the lens as .zmx "
                         f"(write_zmx: a GRINSUR1 surface)")


class RadialGradient(GradedMedium):
    """OpticStudio's Gradient 1: ``n = n0 + nr2 r²`` (module docstring).

    Args:
        n0: axial index.
        nr2: the radial coefficient (1/mm²); negative focuses.
        step_mm: integration step (``Δt``, mm).
    """

    def __init__(self, n0: float, nr2: float, step_mm: float = 0.1):
        super().__init__(f"GRADIENT1(n0={float(n0):g}, nr2={float(nr2):g})", n0, step_mm)
        self.nr2 = make_param(float(nr2), "GRADIENT1 nr2")

    def local(self, x, y, z):
        nr2 = self.nr2.to(x)
        n = self.n0.to(x) + nr2 * (x * x + y * y)
        k = 2.0 * nr2 * n
        return n, k * x, k * y, torch.zeros_like(z)

    def g2(self):
        return -2.0 * self.nr2 / self.n0


class SquareLawGradient(GradedMedium):
    """The square-law profile ``n² = n0² (1 − g² r²)`` (module docstring): meridional rays are
    exact sinusoids in ``z``.

    Args:
        n0: axial index.
        g: the gradient constant (1/mm).
        step_mm: integration step (mm).
    """

    def __init__(self, n0: float, g: float, step_mm: float = 0.1):
        super().__init__(f"SQUARELAW(n0={float(n0):g}, g={float(g):g})", n0, step_mm)
        self.g = make_param(float(g), "SQUARELAW g")

    def local(self, x, y, z):
        n0, g = self.n0.to(x), self.g.to(x)
        k = -(n0 * n0) * (g * g)
        n2 = n0 * n0 + k * (x * x + y * y)
        n = torch.sqrt(torch.clamp(n2, min=1e-12))
        return n, k * x, k * y, torch.zeros_like(z)

    def g2(self):
        return self.g * self.g
