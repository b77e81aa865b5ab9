r"""Zernike standard sag: an even asphere plus Zernike standard polynomials (OpticStudio's
``SZERNSAG``, "Zernike Standard Sag").

    z(x, y) = c r² / (1 + sqrt(1 − (1 + k) c² r²)) + Σ_{i=1..8} α_i r^{2i} + Σ_{j=1..N} A_j Z_j(ρ, φ)

with ``r² = x² + y²``, curvature ``c = 1/R`` (1/mm), conic ``k``, even coefficients ``α_i``
(mm^(1−2i), on ``r², r⁴, ..., r¹⁶``), the normalised polar coordinates ``ρ = r / R_n``, ``φ =
atan2(y, x)`` (``R_n`` the normalisation radius, mm) and the coefficients ``A_j`` (mm) of

    Z_j = N_n^m R_n^|m|(ρ) × {cos(m φ) (m > 0),  1 (m = 0),  sin(|m| φ) (m < 0)},
    N_n^m = sqrt(2 (n + 1) / (1 + δ_{m0})),
    R_n^|m|(ρ) = Σ_{s=0..(n−|m|)/2} (−1)^s (n − s)! / (s! ((n+|m|)/2 − s)! ((n−|m|)/2 − s)!) ρ^(n−2s),

numbered ``j = 1, 2, ...`` in Noll's order (R. J. Noll, "Zernike polynomials and atmospheric
turbulence", J. Opt. Soc. Am. 66, 207 (1976)): by radial order ``n``, within it by ``|m|``, an
even ``j`` the cosine term and an odd ``j`` the sine term (:func:`noll_nm`).  This is
OpticStudio's "Zernike Standard" set: its Zernike Standard Coefficients table lists ``Z1 = 1``,
``Z2 = 4^(1/2) ρ cos φ``, ``Z3 = 4^(1/2) ρ sin φ``, ``Z4 = 3^(1/2) (2ρ² − 1)``, ``Z5 = 6^(1/2) ρ²
sin 2φ``, ``Z6 = 6^(1/2) ρ² cos 2φ``, ``Z7 = 8^(1/2) (3ρ³ − 2ρ) sin φ``, ..., ``Z11 = 5^(1/2) (6ρ⁴ −
6ρ² + 1)``, ... (unit RMS over the unit disc; optiland's ``ZernikeNoll`` is the same set).

**Zernike Fringe sag** (OpticStudio's ``FZERNSAG``, :class:`ZernikeFringeSag`): the same surface
with the Fringe set, at most 37 terms, no normalisation (``N = 1``: every term is ``R_n^|m|`` times
``cos``/``sin``, 1 at the rim for ``m = 0``), numbered by :func:`fringe_nm`: in groups ``d = (n +
|m|)/2 = 0, 1, ..., 5`` (terms ``d² + 1 .. (d + 1)²``), within a group by falling ``|m| = d, d − 1,
..., 0`` (``n = 2d − |m|``), the cosine term before the sine term; term 37 is the 12th-order
spherical ``R_12^0`` (not the next group's first).  So ``Z1 = 1``, ``Z2 = ρ cos φ``, ``Z3 = ρ sin
φ``, ``Z4 = 2ρ² − 1``, ``Z5 = ρ² cos 2φ``, ``Z6 = ρ² sin 2φ``, ``Z7 = (3ρ³ − 2ρ) cos φ``, ``Z8 = (3ρ³
− 2ρ) sin φ``, ``Z9 = 6ρ⁴ − 6ρ² + 1``, ``Z10 = ρ³ cos 3φ``, ..., ``Z16 = 20ρ⁶ − 30ρ⁴ + 12ρ² − 1``,
..., ``Z36 = R_10^0``, ``Z37 = 924ρ¹² − 2772ρ¹⁰ + 3150ρ⁸ − 1680ρ⁶ + 420ρ⁴ − 42ρ² + 1``.  Sources:
the University of Arizona FRINGE program's ordering (J. S. Loomis, FRINGE manual, 1982; its
36-term table reproduced at https://webs.optics.arizona.edu/gsmith/FRINGE.html, which numbers
from 0 without piston: deeplens' ``j`` is its index + 1), and the Fringe terms OpticStudio prints
(Z1..Z9, Z16, Z25, Z36, Z37 with the 12th-order term as Z37, in Opt. Express 20, 15928 (2012),
Tables 1-2, "provided by ZEMAX").  optiland's ``ZernikeFringe`` numbers the same way up to 36 and
continues its groups past it (its 37 is ``n = 6, m = 6``).

**Evaluation.**  No polar coordinates: with ``u = x / R_n``, ``v = y / R_n`` and ``s = ρ² = u² +
v²``, ``ρ^|m| cos(|m| φ) = Re (u + i v)^|m| = C_|m|`` and ``ρ^|m| sin(|m| φ) = Im (u + i v)^|m| =
S_|m|`` (by ``C_m = u C_{m−1} − v S_{m−1}``, ``S_m = u S_{m−1} + v C_{m−1}``), and
``R_n^|m|(ρ) = ρ^|m| P_q^{(0,|m|)}(2s − 1)``, ``q = (n − |m|)/2``, a Jacobi polynomial summed by
its three-term recurrence (:func:`zernike_series`; the monomial coefficients of ``R_20^0`` reach
8e5, a Horner sum would lose 6 digits, all of float32's).  So the Zernike part is

    W = Σ_|m| [F^c_|m|(s) C_|m| + F^s_|m|(s) S_|m|],     F_|m|(s) = Σ_q β_q P_q^{(0,|m|)}(2s − 1)

(``β`` the ``A_j N_n^m`` of that ``|m|``), a polynomial in ``u, v``: smooth everywhere, the axis
included, and so are its slopes ``∂W/∂u = Σ [2u F' C + |m| F C_{|m|−1} + ...]`` (``∂C_m/∂u = m
C_{m−1}``, ``∂C_m/∂v = −m S_{m−1}``, ``∂S_m/∂u = m S_{m−1}``, ``∂S_m/∂v = m C_{m−1}``).
``∂z/∂x = ∂W/∂u / R_n``.

**Extrapolate.**  OpticStudio's flag (``PARM 0``): 1 keeps the Zernike terms beyond ``ρ = 1``
(the polynomial continued), 0 drops them there (the surface is the even asphere outside the
normalisation radius, with a step at ``ρ = 1`` unless the terms vanish there).  Both are here.

**Paraxial data** (rotationally symmetric) use the vertex curvature of the rotationally
symmetric part, ``c + 2 α_1 + 2 Σ_{m=0} N_n^0 A_j r_n / R_n²`` with ``r_n = (−1)^(n/2−1) (n/2)
(n/2 + 1)`` the ``ρ²`` coefficient of ``R_n^0`` (:meth:`ZernikeSag.paraxial_curvature`); piston
``Z1`` (it moves the vertex off ``z = 0``), tilts and the non-symmetric terms (whose mean
curvature at the vertex is 0) do not enter them.

The surface has no compiled Newton kernels: a compiled trace runs it eager between its fused
runs (:func:`~..tracer.fused_kind`).  Newton starts from the conic base's root (:meth:`quadric`).
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from torch import nn

from .asphere import EvenBaseSag
from ..openings import Circle, Opening
from .base import (check_conic_domain, conic_polynomial_scale, host_flags, make_param,
                   norm_radius_mm,
                   register_surface)

__all__ = ["ZernikeSag", "ZernikeFringeSag", "MAX_EVEN_TERMS", "MAX_ZERNIKE_TERMS",
           "MAX_FRINGE_TERMS", "noll_nm", "fringe_nm", "zernike_norm", "zernike_series",
           "zernike_values"]

#: OpticStudio's Zernike Standard Sag takes up to 231 terms (every ``n <= 20``)
MAX_ZERNIKE_TERMS = 231
#: OpticStudio's Zernike Fringe Sag takes up to 37 terms
MAX_FRINGE_TERMS = 37
#: the even part's terms: ``r², r⁴, ..., r¹⁶`` (OpticStudio's PARM 1..8)
MAX_EVEN_TERMS = 8


def noll_nm(j: int) -> tuple[int, int]:
    """Noll's index ``j >= 1`` -> ``(n, m)``: ``m > 0`` the cosine term, ``m < 0`` the sine term
    (an even ``j`` is a cosine, an odd ``j`` a sine), ``m = 0`` rotationally symmetric."""
    if j < 1:
        raise ValueError(f"Noll's index starts at 1, got {j}")
    n = 0
    while (n + 1) * (n + 2) // 2 < j:
        n += 1
    pos = j - n * (n + 1) // 2 - 1          # 0-based place within the radial order n
    mabs = 2 * ((pos + 1) // 2) if n % 2 == 0 else 2 * (pos // 2) + 1
    if mabs == 0:
        return n, 0
    return n, (mabs if j % 2 == 0 else -mabs)


def fringe_nm(j: int) -> tuple[int, int]:
    """The Fringe index ``1 <= j <= 37`` -> ``(n, m)`` (module docstring; ``m > 0`` the cosine
    term, ``m < 0`` the sine term): ``d = floor(sqrt(j − 1))``, the place ``p = j − d² − 1`` in
    the group, ``|m| = d − p // 2``, ``n = 2d − |m|``, an even ``p`` the cosine; ``j = 37`` is
    ``(12, 0)``."""
    if not 1 <= j <= MAX_FRINGE_TERMS:
        raise ValueError(f"the Fringe index runs 1..{MAX_FRINGE_TERMS}, got {j}")
    if j == MAX_FRINGE_TERMS:
        return 12, 0
    d = math.isqrt(j - 1)
    pos = j - d * d - 1
    mabs = d - pos // 2
    n = 2 * d - mabs
    if mabs == 0:
        return n, 0
    return n, (mabs if pos % 2 == 0 else -mabs)


def zernike_norm(n: int, m: int) -> float:
    """``N_n^m = sqrt(2 (n + 1) / (1 + δ_{m0}))``: unit RMS over the unit disc."""
    return math.sqrt((2.0 * (n + 1)) / (2.0 if m == 0 else 1.0))


#: the term orderings: basis name -> (index -> (n, m), (n, m) -> normalisation factor)
BASES = {"standard": (noll_nm, zernike_norm), "fringe": (fringe_nm, lambda n, m: 1.0)}


@lru_cache(maxsize=None)
def _layout(n_terms: int, basis: str = "standard"):
    """For each ``|m|`` up to the highest: ``(q_max, [(q, j − 1, is_cos, N)])``, the terms of the
    first ``n_terms`` indices of ``basis`` (``"standard"``: Noll's, ``"fringe"``) grouped by
    ``|m|`` (``q = (n − |m|) / 2``)."""
    nm, norm = BASES[basis]
    groups: dict[int, list] = {}
    for j in range(1, n_terms + 1):
        n, m = nm(j)
        groups.setdefault(abs(m), []).append(((n - abs(m)) // 2, j - 1, m >= 0, norm(n, m)))
    return tuple((mabs, max(q for q, *_ in terms), tuple(terms))
                 for mabs, terms in sorted(groups.items()))


def zernike_series(t, mabs: int, betas):
    """``F(t) = Σ_q β_q P_q^{(0,|m|)}(t)`` and ``dF/dt`` (``t = 2ρ² − 1``) by the Jacobi
    recurrence (``α = 0``, ``β = |m|``, ``a = 2q + |m|``):
    ``2q (q + |m|)(a − 2) P_q = (a − 1)(a (a − 2) t − |m|²) P_{q−1} − 2 (q − 1)(q + |m| − 1) a
    P_{q−2}``, ``P_0 = 1``, ``P_1 = 1 + (|m| + 2)(t − 1)/2``, differentiated alongside.
    ``betas``: ``β_0, β_1, ...`` (0-d tensors or ``None`` for an absent term)."""
    F = torch.zeros_like(t)
    dF = torch.zeros_like(t)
    p_prev, d_prev = torch.ones_like(t), torch.zeros_like(t)
    if betas[0] is not None:
        F = F + betas[0] * p_prev
    if len(betas) == 1:
        return F, dF
    p = 1.0 + 0.5 * (mabs + 2) * (t - 1.0)
    d = torch.full_like(t, 0.5 * (mabs + 2))
    if betas[1] is not None:
        F = F + betas[1] * p
        dF = dF + betas[1] * d
    for q in range(2, len(betas)):
        a = 2 * q + mabs
        c1 = (a - 1) * a * (a - 2)
        c0 = -(a - 1) * mabs * mabs
        c2 = 2 * (q - 1) * (q + mabs - 1) * a
        den = 2 * q * (q + mabs) * (a - 2)
        p_next = ((c1 * t + c0) * p - c2 * p_prev) / den
        d_next = (c1 * p + (c1 * t + c0) * d - c2 * d_prev) / den
        p_prev, p, d_prev, d = p, p_next, d, d_next
        if betas[q] is not None:
            F = F + betas[q] * p
            dF = dF + betas[q] * d
    return F, dF


def zernike_values(u, v, coeffs, slopes: bool = True, basis: str = "standard"):
    """``(W, ∂W/∂u, ∂W/∂v)`` at the normalised ``(u, v)`` (``(*B,)`` each) for the coefficients
    ``coeffs = (A_1, ..., A_N)`` (0-d tensors, mm) in ``basis``'s order (``"standard"``: Noll's,
    normalised; ``"fringe"``): the Zernike part of the sag (module docstring), ``(*B,)`` each.
    With ``slopes=False`` the slopes are ``None``."""
    coeffs = list(coeffs)
    W = torch.zeros_like(u)
    Wu = torch.zeros_like(u) if slopes else None
    Wv = torch.zeros_like(u) if slopes else None
    if not coeffs:
        return W, Wu, Wv
    s = u * u + v * v
    t = 2.0 * s - 1.0
    C, S = torch.ones_like(u), torch.zeros_like(u)     # C_m, S_m at the current m
    C_prev, S_prev = None, None
    m_at = 0
    for mabs, q_max, terms in _layout(len(coeffs), basis):
        while m_at < mabs:   # advance (C, S) to this |m|
            C_prev, S_prev = C, S
            C, S = u * C - v * S, u * S + v * C
            m_at += 1
        bc = [None] * (q_max + 1)
        bs = [None] * (q_max + 1)
        for q, idx, is_cos, norm in terms:
            b = coeffs[idx].to(u) * norm
            if is_cos:
                bc[q] = b
            else:
                bs[q] = b
        Fc, dFc = zernike_series(t, mabs, bc) if any(b is not None for b in bc) else (None, None)
        Fs, dFs = zernike_series(t, mabs, bs) if any(b is not None for b in bs) else (None, None)
        if Fc is not None:
            W = W + Fc * C
        if Fs is not None:
            W = W + Fs * S
        if not slopes:
            continue
        # d/du, d/dv of F(2s − 1): 2 dF/dt · 2u, 2 dF/dt · 2v
        if Fc is not None:
            g = 4.0 * dFc * C
            Wu = Wu + g * u
            Wv = Wv + g * v
            if mabs:
                Wu = Wu + mabs * Fc * C_prev
                Wv = Wv - mabs * Fc * S_prev
        if Fs is not None:
            g = 4.0 * dFs * S
            Wu = Wu + g * u
            Wv = Wv + g * v
            if mabs:
                Wu = Wu + mabs * Fs * S_prev
                Wv = Wv + mabs * Fs * C_prev
    return W, Wu, Wv


@register_surface("zernike_sag")
class ZernikeSag(EvenBaseSag):
    """An even asphere plus Zernike standard (Noll) terms (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm.
        semi_diameter: clear semi-aperture, mm.
        norm_radius: ``R_n``, the Zernike normalisation radius, mm (``> 0``).
        zernike: ``[A_1, ..., A_N]``, the Noll-ordered coefficients (``N <=
            MAX_ZERNIKE_TERMS``), mm.
        conic: conic constant ``k`` of the base.
        coefficients: ``[α_1, ..., α_M]`` on ``r², r⁴, ..., r^(2M)`` (``M <= MAX_EVEN_TERMS``),
            mm^(1−2i).
        extrapolate: keep the Zernike terms beyond ``ρ = 1`` (OpticStudio's flag 1, the
            default) or drop them there (0).
        obscuration: radius of a central obscuration, mm (``0``: none; below the
            semi-diameter): rays meeting the surface at ``x² + y² < obscuration²`` are blocked
            (a telescope primary's hole, Zemax's annular ``CLAP`` or ``OBSC``).

    Parameters: ``surface.c``, ``surface.k``, ``surface.a[i − 1]`` (``α_i``, the coefficient
    of ``r^(2i)``) and ``surface.zernike[j − 1]`` (``A_j``), each frozen until made trainable;
    the normalisation radius is a fixed buffer.
    """

    #: the term ordering and normalisation (:data:`BASES`)
    basis = "standard"
    #: the most terms the basis takes
    max_terms = MAX_ZERNIKE_TERMS

    def __init__(self, curvature: float, semi_diameter: float, norm_radius: float,
                 zernike=(), conic: float = 0.0, coefficients=(), extrapolate: bool = True,
                 obscuration: float = 0.0):
        super().__init__(semi_diameter)
        rn = norm_radius_mm(norm_radius, "ZernikeSag")
        zernike, coefficients = list(zernike), list(coefficients)
        if len(zernike) > self.max_terms:
            raise ValueError(f"{type(self).__name__}: at most {self.max_terms} Zernike terms, "
                             f"got {len(zernike)}")
        if len(coefficients) > MAX_EVEN_TERMS:
            raise ValueError(f"ZernikeSag: at most {MAX_EVEN_TERMS} even coefficients (r^2.."
                             f"r^{2 * MAX_EVEN_TERMS}), got {len(coefficients)}")
        self.extrapolate = bool(extrapolate)
        obscuration = float(obscuration)
        if not 0.0 <= obscuration < float(semi_diameter):
            raise ValueError(f"{type(self).__name__}: the obscuration radius must be >= 0 mm and "
                             f"below the semi-diameter ({float(semi_diameter):g} mm), got "
                             f"{obscuration!r}")
        # not in state_dict (checkpoints keep their keys); it comes with the lens file
        self.register_buffer("obscuration", torch.tensor(obscuration, dtype=torch.float64),
                             persistent=False)
        self.register_buffer("norm_radius", torch.tensor(rn, dtype=torch.float64))
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.a = nn.ParameterList([make_param(v, f"alpha{i + 1}")
                                   for i, v in enumerate(coefficients)])
        self.zernike = nn.ParameterList([make_param(v, f"Z{j + 1}")
                                         for j, v in enumerate(zernike)])

    def _build_opening(self) -> Opening:
        """The semi-diameter's circle (and a clear rectangle when set), less the central
        obscuration's circle."""
        opening = super()._build_opening()
        obscured = host_flags(self, "_obscured", (self.obscuration,), lambda o: float(o) > 0)
        return opening - Circle(self.obscuration, check=False) if obscured else opening

    def extra_part(self, x, y, slopes: bool = True):
        """The Zernike terms ``(W, ∂W/∂x, ∂W/∂y)`` (:meth:`EvenBaseSag.extra_part`)."""
        rn = self.norm_radius.to(x)
        u, v = x / rn, y / rn
        W, Wu, Wv = zernike_values(u, v, self.zernike, slopes, self.basis)
        if not self.extrapolate and len(self.zernike):
            inside = u * u + v * v <= 1.0
            zero = torch.zeros_like(W)
            W = torch.where(inside, W, zero)
            if slopes:
                Wu, Wv = torch.where(inside, Wu, zero), torch.where(inside, Wv, zero)
        if slopes:
            return W, Wu / rn, Wv / rn
        return W, None, None

    def paraxial_curvature(self):
        """The vertex curvature of the rotationally symmetric part (module docstring)."""
        cur = self.base_curvature()
        rn2 = self.norm_radius.to(self.c) ** 2
        nm, norm = BASES[self.basis]
        for j, A in enumerate(self.zernike, start=1):
            n, m = nm(j)
            if m == 0 and n >= 2:
                h = n // 2
                r2 = (-1) ** (h - 1) * h * (h + 1)
                cur = cur + 2.0 * norm(n, 0) * r2 * A / rn2
        return cur

    def rotationally_symmetric(self) -> bool:
        """Whether every non-zero Zernike term has ``m = 0`` (then the surface is unchanged by a
        turn about its axis)."""
        nm = BASES[self.basis][0]
        return all(nm(j)[1] == 0 for j, A in enumerate(self.zernike, start=1)
                   if float(A) != 0.0)

    def check(self, where: str = "") -> None:
        sd = float(self.semi_diameter)
        if not float(self.obscuration) < sd:
            raise ValueError(f"{where}the central obscuration ({float(self.obscuration):g} mm) "
                             f"must be smaller than the semi-diameter ({sd:g} mm)")
        check_conic_domain(sd, float(self.c), float(self.k),
                           "Zernike sag surface's conic base", where)

    def sag_scale(self, name: str) -> float:
        """``c``: ``R^2/2``; ``k``: :func:`~.base.conic_scale`; ``a.i`` (of ``r^(2i+2)``): ``R^(2i+2)``; ``zernike.j`` (mm): 1
        (:meth:`Surface.sag_scale <.base.Surface.sag_scale>`)."""
        return conic_polynomial_scale(self, name, lambda i: 2 * i + 2)

    file_fields = ("curvature_per_mm", "conic", "even_coefficients", "norm_radius_mm",
                   "zernike_coefficients", "zernike_extrapolate", "obscuration_mm")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        ext = entry.get("zernike_extrapolate", "int", default=1)
        if ext not in (0, 1):
            entry.fail("zernike_extrapolate", f"must be 0 or 1, got {ext!r}")
        return cls(entry.get("curvature_per_mm"), semi_diameter, entry.get("norm_radius_mm"),
                   entry.get("zernike_coefficients", "numbers", default=[]),
                   conic=entry.get("conic", default=0.0),
                   coefficients=entry.get("even_coefficients", "numbers", default=[]),
                   extrapolate=bool(ext), obscuration=entry.get("obscuration_mm", default=0.0))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        d["conic"] = float(self.k)
        d["even_coefficients"] = [float(v) for v in self.a]
        d["norm_radius_mm"] = float(self.norm_radius)
        d["zernike_coefficients"] = [float(v) for v in self.zernike]
        d["zernike_extrapolate"] = int(self.extrapolate)
        if float(self.obscuration) > 0:
            d["obscuration_mm"] = float(self.obscuration)
        return d

    def extra_repr(self) -> str:
        return (f"c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"rn={float(self.norm_radius):.6g} mm, n_even={len(self.a)}, "
                f"n_zernike={len(self.zernike)}, " + super().extra_repr())


@register_surface("zernike_fringe_sag")
class ZernikeFringeSag(ZernikeSag):
    """An even asphere plus Zernike Fringe terms (OpticStudio's ``FZERNSAG``; the module
    docstring): :class:`ZernikeSag` with the Fringe numbering (:func:`fringe_nm`, at most
    ``MAX_FRINGE_TERMS`` = 37 terms) and no normalisation factor.  Arguments, parameters and
    lens-file fields as :class:`ZernikeSag` (``zernike``: ``[A_1, ..., A_N]`` in Fringe order,
    mm)."""

    basis = "fringe"
    max_terms = MAX_FRINGE_TERMS
