r"""Odd asphere: a conic base plus a polynomial in ``r`` with every power from ``r¹`` on.

    z(r) = c r² / (1 + sqrt(1 − (1 + k) c² r²)) + Σ_{i=1..N} a_i r^i,      r = sqrt(x² + y²)

with curvature ``c = 1/R`` (1/mm), conic constant ``k`` and coefficients ``a_i`` in mm^(1−i)
(OpticStudio's ``ODDASPHE``, ``PARM i = a_i``, and its ``EVENASPH`` with a non-zero ``r²`` term:
``a_{2i} = PARM i``, the odd ones zero).  ``N <= MAX_ODD_ORDER``.

The polynomial is evaluated split by parity, ``Σ a_i r^i = E(s) + r O(s)`` with ``s = r²``,
``E(s) = Σ_{i even} a_i s^{i/2}`` and ``O(s) = Σ_{i odd} a_i s^{(i−1)/2}`` (Horner in ``s``), so
the even terms never take a square root.  The slopes are ``∂z/∂x = x G``, ``∂z/∂y = y G`` with

    G = 2 dz_c/ds + Σ_{i even} i a_i s^{i/2 − 1} + (1/r) Σ_{i odd} i a_i s^{(i−1)/2}.

**The axis.**  An ``r¹`` term makes a cone tip (an axicon's): the slope ``a_1 x / r`` has no limit
at ``r = 0``.  There ``r`` and ``1/r`` are taken as 0 (every odd term drops out of the slope), so
the slope is that of the even part and the normal on the axis is ``(0, 0, −1)`` (normalised
``∇f``), the cone's axis — the mean of the normals around the tip, and what optiland's odd asphere
gives there.  ``r`` and ``1/r`` are taken as 0 wherever ``s <= sqrt(tiny)`` (``tiny`` the dtype's
smallest normal number: ``r < 1e-77`` mm in float64, ``3e-10`` mm in float32), through a square root
of a safe argument, so that the sag, the slope and their derivatives (in ``x``, ``y`` and every
parameter) stay finite everywhere, NaN-free in backward too; the sag's error there is at most
``|a_1| r`` (below 1e-77 mm in float64).

**Paraxial data.**  The vertex curvature is ``c + 2 a_2`` (the ``r²`` term's power).  The odd terms
have no paraxial power (an ``r¹`` term deviates every ray by about ``a_1 (n' − n)``, whatever its
height: an axicon, not a focal length), so they do not enter paraxial data.

The surface has no compiled Newton kernels: a compiled trace runs it eager between its fused runs
(:func:`~..tracer.fused_kind`).  Newton starts from the conic base's root (:meth:`quadric`).
"""

from __future__ import annotations

import torch
from torch import nn

from .asphere import conic_arg, conic_dsag_ds, conic_quadric, conic_sag
from .base import (SagSurface, check_conic_domain, conic_polynomial_scale, make_param,
                   register_surface)

__all__ = ["OddAsphere", "MAX_ODD_ORDER", "odd_dsag", "odd_poly", "safe_radius"]

#: the highest power of ``r`` an odd asphere takes (OpticStudio's EVENASPH reaches r¹⁶)
MAX_ODD_ORDER = 20


def safe_radius(s):
    """``(r, 1/r)`` at ``s = r²`` (mm²), both 0 where ``s <= sqrt(tiny)`` (the axis, see the module
    docstring): finite values and finite derivatives for every finite ``s >= 0``."""
    pos = s > torch.finfo(s.dtype).tiny ** 0.5
    safe = torch.where(pos, s, torch.ones_like(s))
    zero = torch.zeros_like(s)
    return torch.where(pos, torch.sqrt(safe), zero), torch.where(pos, torch.rsqrt(safe), zero)


def _horner(s, coeffs):
    """``Σ_j coeffs[j] s^j`` (``coeffs``: 0-d tensors or floats)."""
    p = torch.zeros_like(s)
    for a in reversed(coeffs):
        p = p * s + (a.to(s) if torch.is_tensor(a) else a)
    return p


def _split(coeffs):
    """``(even, odd)``: ``even[j] = a_{2j+2}``, ``odd[j] = a_{2j+1}`` for ``coeffs = (a_1, a_2,
    ...)``, with the indices ``i`` of each."""
    ev = [(i, a) for i, a in enumerate(coeffs, start=1) if i % 2 == 0]
    od = [(i, a) for i, a in enumerate(coeffs, start=1) if i % 2 == 1]
    return ev, od


def odd_poly(s, coeffs, r=None):
    """``Σ_i a_i r^i = E(s) + r O(s)`` (mm) for ``coeffs = (a_1, a_2, ...)`` (module docstring);
    ``r``: :func:`safe_radius`'s, computed here if not given."""
    ev, od = _split(list(coeffs))
    p = torch.zeros_like(s)
    if ev:
        p = p + s * _horner(s, [a for _, a in ev])
    if od:
        if r is None:
            r, _ = safe_radius(s)
        p = p + r * _horner(s, [a for _, a in od])
    return p


def odd_dsag(s, coeffs, inv_r=None):
    """``(1/r) d/dr Σ_i a_i r^i = Σ_{i even} i a_i s^{i/2−1} + (1/r) Σ_{i odd} i a_i s^{(i−1)/2}``
    (1/mm): the polynomial's part of ``G`` (``∂z/∂x = x G``); ``inv_r``: :func:`safe_radius`'s."""
    ev, od = _split(list(coeffs))
    g = torch.zeros_like(s)
    if ev:
        g = g + _horner(s, [i * a for i, a in ev])
    if od:
        if inv_r is None:
            _, inv_r = safe_radius(s)
        g = g + inv_r * _horner(s, [i * a for i, a in od])
    return g


@register_surface("odd_asphere")
class OddAsphere(SagSurface):
    """A conic plus ``Σ_{i=1..N} a_i r^i`` (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm (``0``: flat base).
        semi_diameter: clear semi-aperture, mm.
        conic: conic constant ``k`` of the base.
        coefficients: ``[a_1, a_2, ..., a_N]``, the coefficients of ``r¹ ... r^N`` (``N <=
            MAX_ODD_ORDER``), mm^(1−i).

    Parameters: ``surface.c``, ``surface.k`` and ``surface.a[i − 1]`` (the coefficient of ``r^i``),
    each frozen until made trainable.
    """

    def __init__(self, curvature: float, semi_diameter: float, conic: float = 0.0,
                 coefficients=()):
        super().__init__(semi_diameter)
        coefficients = list(coefficients)
        if len(coefficients) > MAX_ODD_ORDER:
            raise ValueError(f"OddAsphere: at most {MAX_ODD_ORDER} coefficients (r^1..r^"
                             f"{MAX_ODD_ORDER}), got {len(coefficients)}")
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.a = nn.ParameterList([make_param(v, f"a{i + 1}")
                                   for i, v in enumerate(coefficients)])

    def in_domain(self, x, y):
        return conic_arg(x * x + y * y, self.c, self.k) > 0

    def sag(self, x, y):
        s = x * x + y * y
        return conic_sag(s, self.c, self.k) + odd_poly(s, self.a)

    def sag_grad(self, x, y):
        s = x * x + y * y
        g = 2.0 * conic_dsag_ds(s, self.c, self.k) + odd_dsag(s, self.a)
        return x * g, y * g

    def paraxial_curvature(self):
        """``c + 2 a_2`` (the ``r²`` term's power; the odd terms have none, module docstring)."""
        if len(self.a) >= 2:
            return self.c + 2.0 * self.a[1]
        return self.c

    def quadric(self, o, d):
        """The conic base as a quadric (Newton's start; the surface itself is not one)."""
        return conic_quadric(*o.unbind(-1), *d.unbind(-1), self.c, self.k)

    def check(self, where: str = "") -> None:
        sd = float(self.semi_diameter)
        check_conic_domain(sd, float(self.c), float(self.k), "odd asphere's conic base", where)

    def sag_scale(self, name: str) -> float:
        """``c``: ``R^2/2``; ``k``: :func:`~.base.conic_scale`; ``a.i`` (``a_{i+1}`` of ``r^(i+1)``): ``R^(i+1)``
        (:meth:`Surface.sag_scale <.base.Surface.sag_scale>`)."""
        return conic_polynomial_scale(self, name, lambda i: i + 1)

    file_fields = ("curvature_per_mm", "conic", "radial_coefficients")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("curvature_per_mm"), semi_diameter,
                   conic=entry.get("conic", default=0.0),
                   coefficients=entry.get("radial_coefficients", "numbers", default=[]))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        d["conic"] = float(self.k)
        d["radial_coefficients"] = [float(v) for v in self.a]
        return d

    def extra_repr(self) -> str:
        return (f"c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"order={len(self.a)}, " + super().extra_repr())
