"""XY polynomial freeform (the paper authors' implicit form).

    f(x, y, z) = b z^2 + sum_{j=0..J} sum_{i=0..j} a_{j,i} x^i y^(j-i) - z = 0

Coefficients are ordered by total degree ``j`` and, within a degree, by the power of ``x``:
``1, y, x, y^2, xy, x^2, y^3, xy^2, x^2y, x^3, ...``; order ``J`` has ``(J+1)(J+2)/2`` terms.
With ``b = 0`` it is the explicit sag ``z = P(x, y)``; otherwise
``z = 2P / (1 + sqrt(1 - 4 b P))``, defined where ``1 - 4 b P >= 0``.
Gradient: ``(P_x, P_y, 2 b z - 1)``.

One sheet.  For ``b != 0`` the quadric in ``z`` has a second root, ``(1 + sqrt(1 - 4 b P)) / 2b``,
beyond its fold plane ``z* = 1 / 2b`` (where ``∂f/∂z = 0``); Newton from the vertex plane reached
it for rays near the fold and kept them as valid hits.  So ``f`` is continued past the fold with
slope ``-1`` in ``z``: ``f = b zc^2 + P - z`` with ``zc = z`` where ``b z < 1/2`` and ``zc = z*``
beyond.  It is unchanged on the vertex side, decreasing in ``z`` everywhere, and has no root
beyond ``z*`` inside the domain, so the root is unique: the sag.  ``check`` rejects a clear
aperture that reaches the fold (``1 - 4 b P <= 0``), as the conic check of an asphere does.
"""

from __future__ import annotations

import math

import torch

from .base import Surface, make_param, register_surface

__all__ = ["XYPolynomial", "xy_terms", "xy_poly", "xy_radial", "xy_fold", "xy_f_value", "xy_f_z",
           "xy_in_domain"]


def xy_terms(order: int) -> list[tuple[int, int]]:
    """The ``(i, j-i)`` exponent pairs ``(px, py)`` in coefficient order, up to ``order``."""
    return [(i, j - i) for j in range(order + 1) for i in range(j + 1)]


# ------------------------------------------------------------------ the maths, component-wise
def xy_radial(coefficients) -> bool:
    """Whether ``Σ c_ij x^i y^j`` (``coefficients``: ``(i, j) -> c_ij``, floats) is a function
    of ``r² = x² + y²`` alone (unchanged by a turn about the axis): every odd degree and every
    odd exponent zero, and each even degree ``2k`` a multiple of ``(x² + y²)^k``, ``c_(2k−2m,
    2m) = a_k C(k, m)`` (to 1e-12 of the degree's largest coefficient)."""
    by_degree: dict[int, dict[tuple[int, int], float]] = {}
    for (i, j), v in coefficients.items():
        by_degree.setdefault(i + j, {})[(i, j)] = float(v)
    for d, cs in by_degree.items():
        big = max(abs(v) for v in cs.values())
        if big == 0.0:
            continue
        if d % 2 or any(v != 0.0 and (i % 2 or j % 2) for (i, j), v in cs.items()):
            return False
        k = d // 2
        a = cs.get((d, 0), 0.0)
        if any(abs(cs.get((d - 2 * m, 2 * m), 0.0) - a * math.comb(k, m)) > 1e-12 * big
               for m in range(k + 1)):
            return False
    return True


# Written once: :class:`XYPolynomial` calls these with its parameters, the compiled Newton
# kernels (:mod:`..compiled`) with the values already in the rays' dtype (``.to`` is a no-op).
def xy_poly(x, y, coeffs, terms, order: int):
    """``(P, P_x, P_y)`` at ``(x, y)`` (mm): the polynomial and its slopes, ``coeffs`` 0-d
    tensors in :func:`xy_terms` order (``terms``), ``order`` the degree."""
    px, py = [torch.ones_like(x)], [torch.ones_like(y)]
    for _ in range(order):
        px.append(px[-1] * x)
        py.append(py[-1] * y)
    P = torch.zeros_like(x)
    Px = torch.zeros_like(x)
    Py = torch.zeros_like(x)
    for a, (i, j) in zip(coeffs, terms):
        a = a.to(x)
        P = P + a * px[i] * py[j]
        if i:
            Px = Px + (a * i) * px[i - 1] * py[j]
        if j:
            Py = Py + (a * j) * px[i] * py[j - 1]
    return P, Px, Py


def xy_fold(z, b):
    """``(beyond, zc)``: whether ``z`` lies past the fold plane ``z* = 1/2b``, and ``z``
    clamped to it (see the module docstring)."""
    b = b.to(z)
    beyond = b.detach() * z.detach() > 0.5
    z_fold = 0.5 / torch.where(b != 0, b, torch.ones_like(b))
    return beyond, torch.where(beyond, z_fold, z)


def xy_f_value(P, zc, z, b):
    """``f = b zc^2 + P - z`` (mm), ``zc`` from :func:`xy_fold`."""
    return b.to(z) * zc * zc + P - z


def xy_f_z(z, b, beyond):
    """``∂f/∂z``: ``2 b z - 1`` on the vertex side of the fold, ``-1`` beyond it."""
    return torch.where(beyond, -torch.ones_like(z), 2.0 * b.to(z) * z - 1.0)


def xy_in_domain(P, b):
    """Where the sag is defined, ``1 - 4 b P >= 0`` (for ``b != 0``)."""
    return 1.0 - 4.0 * b.to(P) * P >= 0


@register_surface("xy_polynomial")
class XYPolynomial(Surface):
    """XY polynomial freeform of any order.

    Args:
        semi_diameter: clear semi-aperture in mm.
        coefficients: ``a`` in the order above; its length must be ``(J+1)(J+2)/2``.
        b: the ``z^2`` coefficient (1/mm).

    The coefficients are one parameter each: ``surface.a[m]``; ``surface.b``.
    """

    #: the compiled Newton kernels below
    fused_geometry = "newton"

    def __init__(self, semi_diameter: float, coefficients=(0.0,), b: float = 0.0):
        super().__init__(semi_diameter)
        n = len(coefficients)
        order = (math.isqrt(8 * n + 1) - 3) // 2
        if n == 0 or (order + 1) * (order + 2) // 2 != n:
            raise ValueError(f"XYPolynomial: the number of coefficients must be (J+1)(J+2)/2 "
                             f"for an order J (1, 3, 6, 10, 15, ...), got {n}")
        self.order = order
        self.terms = xy_terms(order)
        self.b = make_param(b, "b")
        self.a = torch.nn.ParameterList([make_param(v, f"a{m}") for m, v in enumerate(coefficients)])

    def poly(self, x, y):
        """``(P, P_x, P_y)`` at ``(x, y)`` (:func:`xy_poly`)."""
        return xy_poly(x, y, self.a, self.terms, self.order)

    def f(self, x, y, z):
        P, _, _ = self.poly(x, y)
        _, zc = xy_fold(z, self.b)
        return xy_f_value(P, zc, z, self.b)

    def f_grad(self, x, y, z):
        _, Px, Py = self.poly(x, y)
        beyond, _ = xy_fold(z, self.b)
        return Px, Py, xy_f_z(z, self.b, beyond)

    def _disc(self, P):
        return 1.0 - 4.0 * self.b.to(P) * P

    def in_domain(self, x, y):
        if float(self.b.detach()) == 0.0:
            return torch.ones_like(x, dtype=torch.bool)
        P, _, _ = self.poly(x, y)
        return xy_in_domain(P, self.b)

    # ---- the compiled Newton kernels' interface (see Surface.kernel_values) ---------------
    def kernel_values(self, like):
        """``(b, coefficients, terms, order, b != 0)``: values in ``like``'s dtype
        (differentiable) and the static structure."""
        return (self.b.to(like), tuple(a.to(like) for a in self.a), tuple(self.terms),
                self.order, float(self.b.detach()) != 0.0)

    @staticmethod
    def kernel_f(x, y, z, values):
        """``(f, f_x, f_y, f_z)`` from :func:`xy_poly`, :func:`xy_fold`, :func:`xy_f_value` and
        :func:`xy_f_z` (continued past the fold plane)."""
        b, coeffs, terms, order, _ = values
        P, Px, Py = xy_poly(x, y, coeffs, terms, order)
        beyond, zc = xy_fold(z, b)
        return xy_f_value(P, zc, z, b), Px, Py, xy_f_z(z, b, beyond)

    @staticmethod
    def kernel_in_domain(x, y, values):
        b, coeffs, terms, order, b_nonzero = values
        if not b_nonzero:  # as in_domain: everywhere when b == 0
            return torch.ones_like(x, dtype=torch.bool)
        P, _, _ = xy_poly(x, y, coeffs, terms, order)
        return xy_in_domain(P, b)

    @staticmethod
    def kernel_start(bx, by, bz, dx, dy, dz, ok, values, root_fn):
        """Newton starts from the vertex plane."""
        return torch.zeros_like(bz)

    def set_cubic(self, alpha_mm: float) -> None:
        """Make this surface the Dowski-Cathey cubic phase plate ``z = α ((x/R)^3 + (y/R)^3)``
        (``α`` mm of sag at the rim on the x and y axes, ``R`` the semi-diameter): every
        coefficient zero but ``x^3`` and ``y^3``; ``b`` unchanged.  Needs order >= 3."""
        if self.order < 3:
            raise ValueError(f"a cubic plate needs an XY polynomial of order >= 3, not "
                             f"{self.order}")
        R = float(self.semi_diameter)
        with torch.no_grad():
            for k, (i, j) in enumerate(self.terms):
                self.a[k].zero_()
                if (i, j) in ((3, 0), (0, 3)):
                    self.a[k].fill_(alpha_mm / R ** 3)

    def sag(self, x, y):
        P, _, _ = self.poly(x, y)
        disc = self._disc(P)
        disc = torch.where(disc > 0, disc, torch.ones_like(disc))
        return 2.0 * P / (1.0 + torch.sqrt(disc))

    def check(self, where: str = "") -> None:
        """Raise ``ValueError`` when the clear aperture reaches the fold ``1 - 4 b P = 0``
        (sampled on a polar grid of the aperture disk: P is not rotationally symmetric)."""
        if float(self.b) == 0.0:
            return
        sd = float(self.semi_diameter)
        with torch.no_grad():
            r = torch.linspace(0.0, sd, 257, dtype=torch.float64)
            phi = torch.linspace(0.0, 2 * math.pi, 256, dtype=torch.float64)[:-1]
            x = (r[:, None] * torch.cos(phi)).reshape(-1)
            y = (r[:, None] * torch.sin(phi)).reshape(-1)
            P = sum(float(a) * x ** i * y ** j for a, (i, j) in zip(self.a, self.terms))
            bad = (1.0 - 4.0 * float(self.b) * P) <= 0
        if bool(bad.any()):
            rr = torch.sqrt(x * x + y * y)
            r_fold = float(rr[bad].min())
            raise ValueError(
                f"{where}semi-diameter {sd:g} mm lies beyond the domain of the XY polynomial "
                f"(b = {float(self.b):g}/mm): 1 - 4 b P(x, y) reaches 0 (its fold) by r = "
                f"{r_fold:.4g} mm; reduce the semi-diameter below it or change b / the "
                f"coefficients")

    def rotationally_symmetric(self) -> bool:
        """Whether the polynomial is a function of ``r`` alone (:func:`xy_radial`; the ``b z²``
        term is): the surface is unchanged by a turn about its axis."""
        return xy_radial({t: float(v) for t, v in zip(self.terms, self.a)})

    def paraxial_curvature(self):
        # z ≈ a_x2 x^2 + a_y2 y^2 + b z^2 near the vertex: mean of the two principal curvatures
        ix2 = self.terms.index((2, 0)) if self.order >= 2 else None
        iy2 = self.terms.index((0, 2)) if self.order >= 2 else None
        if ix2 is None:
            return torch.zeros_like(self.b)
        return self.a[ix2] + self.a[iy2]

    def sag_scale(self, name: str) -> float:
        """``a.m`` (of ``x^i y^j``): ``R^(i+j)``, the bound of the term on the rim; ``b``
        (1/mm): 1 (:meth:`Surface.sag_scale <.base.Surface.sag_scale>`)."""
        parts = name.split(".")
        if parts[0] == "a":
            i, j = self.terms[int(parts[1])]
            return float(self.semi_diameter) ** (i + j)
        return 1.0

    file_fields = ("coefficients", "b")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(semi_diameter, entry.get("coefficients", "numbers"),
                   b=entry.get("b", default=0.0))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["b"] = float(self.b)
        d["coefficients"] = [float(a) for a in self.a]
        return d
