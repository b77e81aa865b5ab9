r"""Q-type (Forbes) aspheres: Qbfs (slope-orthogonal) and Qcon (sag-orthogonal) polynomials on a
conic base (OpticStudio's ``QED_TYPE``, "Q-Type Asphere"; G. W. Forbes, "Shape specification for
axially symmetric optical surfaces", Opt. Express 15, 5218 (2007)).

With ``s = r²`` (mm²), the normalised ``x = u² = s / ρ_n²`` (``ρ_n`` the normalisation radius, mm)
and the conic base ``z_c(s) = c s / (1 + sqrt(1 − (1+k) c² s))`` of :mod:`.asphere`:

* **Qbfs** ``z = z_c + φ(s) x (1 − x) Σ_m a_m Q^bfs_m(x)``, ``φ = sqrt((1 − k c² s) / (1 − (1+k)
  c² s))``: for a sphere (``k = 0``) ``φ = 1 / sqrt(1 − c² s)``, Forbes 2007 eq. (2.2) (the
  departure measured along the sphere's normal); a conic base follows Forbes' later
  generalisation (as optiland's ``ForbesQNormalSlopeGeometry``).
* **Qcon** ``z = z_c + x² Σ_m a_m Q^con_m(x)``, Forbes 2007 eq. (2.5).

The coefficients ``a_m`` are lengths (mm).  The polynomials are built here from their
definitions, exactly, in rational arithmetic (:func:`qbfs_matrix`, :func:`qcon_matrix`):
``Q^bfs_m`` by Gram–Schmidt, so that the slopes ``d/du [u²(1−u²) Q_m(u²)]`` are orthonormal under
the weight ``(1 − u²)^(-1/2)`` normalised to a unit mean (the sign: ``Q_m(0) > 0``; ``Q_0 = 1``,
``Q_1 = (13 − 16x)/√19``), and ``Q^con_m(x) = P_m^{(0,4)}(2x − 1)`` (Jacobi).  They are stored
exactly in the basis of the Jacobi polynomials ``P_j^{(0,4)}(2x − 1)`` and summed by their
three-term recurrence (:func:`jacobi_rows`, :func:`qtype_series`): their monomial coefficients
grow to 1e7 by ``m = 9``, a Horner sum would lose 9 digits.

The maths is written once, component-wise (:func:`qtype_sag`, :func:`qtype_dsag_ds`), and
:class:`QType` calls it for its sag and slope; the surface has no compiled Newton kernels, so it
traces eager between compiled runs (:func:`~..tracer.fused_kind`).
"""

from __future__ import annotations

import math
from fractions import Fraction
from functools import lru_cache

import torch
from torch import nn

from .asphere import conic_arg, conic_dsag_ds, conic_root, conic_sag
from .base import (SagSurface, check_conic_domain, conic_polynomial_scale, make_param,
                   norm_radius_mm,
                   register_surface)

__all__ = ["QType", "MAX_TERMS", "jacobi_rows", "qbfs_matrix", "qcon_matrix", "qtype_dsag_ds",
           "qtype_sag", "qtype_series"]

#: the most polynomial terms a Q-type surface takes (monomial evaluation stays accurate)
MAX_TERMS = 10


def _binom(n: int, k: int) -> int:
    return math.comb(n, k) if 0 <= k <= n else 0


def _qcon_exact(n: int) -> list[list[Fraction]]:
    """Row ``m``: the exact monomial coefficients of ``P_m^{(0,4)}(2x − 1)``,
    ``Σ_s C(m, m−s) C(m+4, s) (x − 1)^s x^(m−s)`` expanded."""
    rows = []
    for m in range(n):
        c = [Fraction(0)] * n
        for s in range(m + 1):
            w = _binom(m, m - s) * _binom(m + 4, s)
            for i in range(s + 1):   # (x - 1)^s = sum_i C(s, i) x^i (-1)^(s-i)
                c[m - s + i] += w * _binom(s, i) * (-1) ** (s - i)
        rows.append(c)
    return rows


@lru_cache(maxsize=None)
def qcon_matrix(n: int) -> tuple[tuple[float, ...], ...]:
    """Row ``m`` (``m < n``): the monomial coefficients of ``Q^con_m(x) = P_m^{(0,4)}(2x − 1)``
    (for tests and reference; the surface evaluates in the Jacobi basis, :func:`jacobi_rows`)."""
    return tuple(tuple(float(v) for v in r) for r in _qcon_exact(n))


@lru_cache(maxsize=None)
def qbfs_matrix(n: int) -> tuple[tuple[float, ...], ...]:
    """Row ``m`` (``m < n``): the monomial coefficients of ``Q^bfs_m(x)`` (:func:`_qbfs_exact`;
    for tests and reference, the surface evaluates in the Jacobi basis, :func:`jacobi_rows`)."""
    return tuple(tuple(float(a) * sc for a in v) for v, sc in _qbfs_exact(n))


@lru_cache(maxsize=None)
def _qbfs_exact(n: int):
    """``[(v_m, scale_m)]``: ``Q^bfs_m = scale_m · Σ_j v_mj x^j`` with ``v_m`` exact (rational)
    and the float ``scale_m = ±1/sqrt(<v_m, v_m>)``, built by Gram–Schmidt
    on ``1, x, x², ...`` under ``<f, g> = <d/du[u²(1−u²) f(u²)] d/du[u²(1−u²) g(u²)]>`` with
    the weight ``(1 − u²)^(-1/2) / (π/2)`` on ``[0, 1]``.  Every slope ``d/du[...]`` of a
    polynomial in ``x`` is odd in ``u``, so the products are even and their moments
    ``∫ u^(2j) (1−u²)^(-1/2) = (π/2) (2j−1)!!/(2j)!!``: rational times π/2, exact here."""
    def slope(p):   # d/du [u²(1-u²) p(u²)] as {odd power of u: coefficient}
        out = {}
        for j, b in enumerate(p):
            if b:
                for e, w in ((2 * j + 2, 1), (2 * j + 4, -1)):   # u^e -> e u^(e-1)
                    out[e - 1] = out.get(e - 1, Fraction(0)) + w * e * b
        return out

    def even_moment(k):   # ∫_0^1 u^(2k) (1-u^2)^(-1/2) du / (π/2) = (2k-1)!!/(2k)!!
        num, den = 1, 1
        for i in range(1, k + 1):
            num *= 2 * i - 1
            den *= 2 * i
        return Fraction(num, den)

    def inner(p, q):
        sp, sq = slope(p), slope(q)
        return sum((a * b * even_moment((i + j) // 2) for i, a in sp.items()
                    for j, b in sq.items()), Fraction(0))

    basis = []   # orthogonal (not yet normalised), exact
    for m in range(n):
        v = [Fraction(0)] * n
        v[m] = Fraction(1)
        e = list(v)
        for q in basis:
            w = inner(e, q) / inner(q, q)
            v = [a - w * b for a, b in zip(v, q)]
        basis.append(v)
    out = []
    for v in basis:
        scale = 1.0 / math.sqrt(inner(v, v))
        if v[0] < 0:   # the sign: Q_m(0) > 0
            scale = -scale
        out.append((v, scale))
    return out


@lru_cache(maxsize=None)
def jacobi_rows(kind: str, n: int) -> tuple[tuple[float, ...], ...]:
    """Row ``m``: ``Q_m`` of ``kind`` (``"qbfs"``/``"qcon"``) in the basis ``P_j^{(0,4)}(2x − 1)``
    (``j <= m``), converted exactly from the monomial rows (a triangular solve in rationals):
    the surface sums that series by the Jacobi recurrence (:func:`qtype_series`), whose
    round-off stays at the level of the polynomials' values (the monomial coefficients grow to
    1e7 by ``m = 9``)."""
    P = _qcon_exact(n)   # P[j][i]: coefficient of x^i in P_j; P[j][j] != 0
    rows = []
    if kind == "qcon":
        return tuple(tuple(1.0 if i == m else 0.0 for i in range(n)) for m in range(n))
    for v, scale in _qbfs_exact(n):
        beta = [Fraction(0)] * n
        r = list(v)
        for j in range(n - 1, -1, -1):   # peel off the highest power with P_j
            if r[j]:
                w = r[j] / P[j][j]
                beta[j] = w
                r = [a - w * b for a, b in zip(r, P[j])]
        rows.append(tuple(float(b) * scale for b in beta))
    return tuple(rows)


def qtype_series(x, betas):
    """``S(x) = Σ_j β_j P_j^{(0,4)}(2x − 1)`` and ``dS/dx`` by the three-term recurrence
    ``2n(n+4)(2n+2) P_n = (2n+3)((2n+4)(2n+2) t − 16) P_{n−1} − 2(n−1)(n+3)(2n+4) P_{n−2}``
    (``t = 2x − 1``, ``P_0 = 1``, ``P_1 = 3t − 2``), differentiated alongside.  ``betas``:
    0-d tensors."""
    betas = list(betas)
    t = 2.0 * x - 1.0
    p_prev, p = torch.ones_like(x), 3.0 * t - 2.0
    d_prev, d = torch.zeros_like(x), torch.full_like(x, 3.0)   # d/dt
    S = betas[0].to(x) * p_prev
    dS = torch.zeros_like(x)
    if len(betas) > 1:
        S = S + betas[1].to(x) * p
        dS = dS + betas[1].to(x) * d
    for n in range(2, len(betas)):
        a1 = (2 * n + 3) * (2 * n + 4) * (2 * n + 2)
        a0 = -(2 * n + 3) * 16
        c = 2 * (n - 1) * (n + 3) * (2 * n + 4)
        den = 2 * n * (n + 4) * (2 * n + 2)
        p_next = ((a1 * t + a0) * p - c * p_prev) / den
        d_next = (a1 * p + (a1 * t + a0) * d - c * d_prev) / den
        p_prev, p, d_prev, d = p, p_next, d, d_next
        S = S + betas[n].to(x) * p
        dS = dS + betas[n].to(x) * d
    return S, 2.0 * dS


def _phi(s, c, k):
    """Forbes' factor ``φ = sqrt((1 − k c² s) / (1 − (1+k) c² s))`` and ``dφ/ds``."""
    c2 = c.to(s) * c.to(s)
    num = 1.0 - k.to(s) * c2 * s
    num = torch.where(num > 0, num, torch.ones_like(num))
    den = conic_root(s, c, k) ** 2
    den = torch.where(den > 0, den, torch.ones_like(den))   # 0 on the conic's rim: finite
    phi = torch.sqrt(num / den)
    dphi = 0.5 * phi * (-k.to(s) * c2 / num + (1.0 + k.to(s)) * c2 / den)
    return phi, dphi


def qtype_sag(s, c, k, rn, coeffs, qcon: bool):
    """The sag ``z(s)`` (mm) at ``s = r²``: the conic base plus the Q departure (module
    docstring), ``Σ a_m Q_m(x) = Σ β_j P_j^{(0,4)}(2x − 1)`` with ``coeffs = (β_j)`` (0-d
    tensors, mm; :func:`jacobi_rows`), ``x = s / ρ_n²``."""
    x = s / (rn.to(s) * rn.to(s))
    p, _ = qtype_series(x, coeffs) if len(coeffs) else (torch.zeros_like(x),) * 2
    if qcon:
        dep = x * x * p
    else:
        phi, _ = _phi(s, c, k)
        dep = x * (1.0 - x) * phi * p
    return conic_sag(s, c, k) + dep


def qtype_dsag_ds(s, c, k, rn, coeffs, qcon: bool):
    """``dz/ds`` (1/mm): the slopes are ``∂z/∂x = 2 x dz/ds``, ``∂z/∂y = 2 y dz/ds``."""
    r2 = rn.to(s) * rn.to(s)
    x = s / r2
    p, dp = qtype_series(x, coeffs) if len(coeffs) else (torch.zeros_like(x),) * 2
    if qcon:
        ddep = (2.0 * x * p + x * x * dp) / r2
    else:
        phi, dphi = _phi(s, c, k)
        q = x * (1.0 - x)
        ddep = ((1.0 - 2.0 * x) * phi * p + q * phi * dp) / r2 + q * dphi * p
    return conic_dsag_ds(s, c, k) + ddep


@register_surface("qtype")
class QType(SagSurface):
    """A Q-type (Forbes) asphere (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm.
        semi_diameter: clear semi-aperture, mm.
        norm_radius: ``ρ_n``, the normalisation radius, mm (``> 0``).
        coefficients: ``[a_0, a_1, ...]`` (at most ``MAX_TERMS``), mm.
        kind: ``"qbfs"`` (slope-orthogonal, OpticStudio's type 0) or ``"qcon"`` (type 1).
        conic: conic constant ``k`` of the base.

    Parameters: ``surface.c``, ``surface.k``, ``surface.a[m]`` (differentiable); the
    normalisation radius is a fixed buffer.
    """

    def __init__(self, curvature: float, semi_diameter: float, norm_radius: float,
                 coefficients=(), kind: str = "qbfs", conic: float = 0.0):
        super().__init__(semi_diameter)
        if kind not in ("qbfs", "qcon"):
            raise ValueError(f"QType: kind must be 'qbfs' or 'qcon', got {kind!r}")
        rn = norm_radius_mm(norm_radius, "QType")
        coefficients = list(coefficients)
        if len(coefficients) > MAX_TERMS:
            raise ValueError(f"QType: at most {MAX_TERMS} polynomial terms, got "
                             f"{len(coefficients)}")
        self.kind = kind
        self.register_buffer("norm_radius", torch.tensor(rn, dtype=torch.float64))
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.a = nn.ParameterList([make_param(v, f"a{m}") for m, v in enumerate(coefficients)])

    def _betas(self, like):
        """``β = Tᵀ a``: the departure polynomial in the Jacobi basis (:func:`jacobi_rows`),
        differentiable in ``a``."""
        n = len(self.a)
        if n == 0:
            return ()
        M = torch.tensor(jacobi_rows(self.kind, n), dtype=like.dtype, device=like.device)
        a = torch.stack([v.to(like) for v in self.a])
        return tuple((M * a.unsqueeze(-1)).sum(0).unbind(0))

    def in_domain(self, x, y):
        s = x * x + y * y
        ok = conic_arg(s, self.c, self.k) > 0
        if self.kind == "qbfs":
            ok = ok & (1.0 - self.k.to(s) * self.c.to(s) ** 2 * s > 0)
        return ok

    def sag(self, x, y):
        s = x * x + y * y
        return qtype_sag(s, self.c, self.k, self.norm_radius, self._betas(s),
                         self.kind == "qcon")

    def sag_grad(self, x, y):
        s = x * x + y * y
        g = qtype_dsag_ds(s, self.c, self.k, self.norm_radius, self._betas(s),
                          self.kind == "qcon")
        return 2.0 * x * g, 2.0 * y * g

    def paraxial_curvature(self):
        """The vertex curvature: ``c`` for Qcon (its departure starts at r⁴); Qbfs adds
        ``2 a_0' / ρ_n²`` from the r² term of ``x (1 − x) φ P(x)`` (``a_0' = P(0)``)."""
        if self.kind == "qcon" or len(self.a) == 0:
            return self.c
        p0, _ = qtype_series(torch.zeros_like(self.c), self._betas(self.c))
        return self.c + 2.0 * p0 / (self.norm_radius.to(self.c) ** 2)

    def check(self, where: str = "") -> None:
        sd = float(self.semi_diameter)
        check_conic_domain(sd, float(self.c), float(self.k), "Q-type surface's conic base",
                           where)

    def sag_scale(self, name: str) -> float:
        """The conic base's: ``c``: ``R^2/2``; ``k``: :func:`~.base.conic_scale`; the Q
        coefficients ``a.m`` are lengths (mm): 1 (:meth:`Surface.sag_scale
        <.base.Surface.sag_scale>`)."""
        return conic_polynomial_scale(self, name)

    file_fields = ("curvature_per_mm", "conic", "norm_radius_mm", "q_coefficients", "q_kind")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        kind = entry.get("q_kind", "str", default="qbfs")
        if kind not in ("qbfs", "qcon"):
            entry.fail("q_kind", f"must be 'qbfs' or 'qcon', got {kind!r}")
        return cls(entry.get("curvature_per_mm"), semi_diameter, entry.get("norm_radius_mm"),
                   entry.get("q_coefficients", "numbers", default=[]), kind,
                   conic=entry.get("conic", default=0.0))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        d["conic"] = float(self.k)
        d["norm_radius_mm"] = float(self.norm_radius)
        d["q_coefficients"] = [float(v) for v in self.a]
        d["q_kind"] = self.kind
        return d

    def extra_repr(self) -> str:
        return (f"{self.kind}, c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"rn={float(self.norm_radius):.6g} mm, n_terms={len(self.a)}, "
                + super().extra_repr())
