"""Sphere, conic and even asphere.

    z(r) = c r^2 / (1 + sqrt(1 - (1 + k) c^2 r^2)) + sum_{i=2..10} a_{2i} r^{2i},   r^2 = x^2 + y^2

with curvature ``c = 1/R`` (1/mm), conic constant ``k`` and even coefficients ``a4 ... a20``
(mm^(1-2i)).  With ``s = r^2``:  dz/ds = c / (2 sqrt(1 - (1+k) c^2 s)) + sum i a_{2i} s^(i-1),
and ∂z/∂x = 2x dz/ds, ∂z/∂y = 2y dz/ds.

The conic is defined where ``1 - (1+k) c^2 s > 0``; outside it the tracer marks rays invalid.

The conic base (no coefficients) is the branch ``h = 1 - (1+k) c z > 0`` of the quadric

    F(x) = c (x^2 + y^2 + (1+k) z^2) - 2 z = 0,      ∇F = 2 (c x, c y, (1+k) c z - 1),

(on it ``h = sqrt(1 - (1+k) c^2 r^2)`` and ``∇F = 2 h ∇f``), so a ray ``o + s d`` meets it where
``A s^2 + 2 B s + C = 0`` with ``A = c (d_x^2 + d_y^2 + (1+k) d_z^2)``,
``B = c (o_x d_x + o_y d_y + (1+k) o_z d_z) - d_z`` and ``C = F(o)``
(:meth:`Asphere.quadric`; the tracer solves it in closed form, :mod:`..intersect`).

The maths is written once, as component-wise functions of tensors (:func:`conic_arg`,
:func:`asphere_sag`, :func:`asphere_dsag_ds`, :func:`conic_quadric`, :func:`conic_normal`):
:class:`Asphere` calls them with its parameters, the eager tracer through it, and the compiled
kernels (:mod:`..compiled`, :mod:`..intersect`'s ``*_step_xyz``) call the same functions with
the values already in the rays' dtype (``.to`` is then a no-op), so that a fix or a bug here
reaches both paths alike.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..openings import Circle, Opening, Rectangle
from .base import (CONIC_RIM_EPS, SagSurface, check_conic_domain, conic_polynomial_scale,
                   host_flags, make_param, register_surface, with_ellipses)

__all__ = ["Asphere", "Sphere", "MAX_ASPHERE_ORDER", "asphere_dsag_ds", "asphere_sag",
           "conic_arg", "conic_dsag_ds", "conic_normal", "conic_quadric", "conic_root",
           "conic_sag", "even_poly", "even_poly_ds", "even_terms_r2", "EvenBaseSag"]

MAX_ASPHERE_ORDER = 20


# ------------------------------------------------------------------ the maths, component-wise
def conic_arg(s, c, k):
    """``1 - (1 + k) c^2 s`` at ``s = r^2`` (mm^2); the conic is defined where it is ``> 0``.
    ``c`` (1/mm), ``k``: 0-d tensors (converted to ``s``'s dtype here)."""
    c, k = c.to(s), k.to(s)
    return 1.0 - (1.0 + k) * c * c * s


def conic_root(s, c, k):
    """``sqrt(1 - (1+k) c^2 s)``; 0 on the rim of the conic's domain (the argument within
    :data:`~.base.CONIC_RIM_EPS` rounding units of the points' dtype below 0: a hemisphere's
    rim, where the sag ``c s`` is exact; :func:`~.base.check_conic_domain` accepts a
    semi-diameter there),
    1 beyond it (finite).  Its derivative is finite everywhere (0 on the rim and beyond; the
    true one is infinite on the rim)."""
    arg = conic_arg(s, c, k)
    inside = arg > 0
    root = torch.sqrt(torch.where(inside, arg, torch.ones_like(arg)))
    rim = arg >= -CONIC_RIM_EPS * torch.finfo(arg.dtype).eps
    return torch.where(inside, root, torch.where(rim, torch.zeros_like(arg),
                                                 torch.ones_like(arg)))


def conic_sag(s, c, k, root=None):
    """The conic base's sag ``c s / (1 + sqrt(1 - (1+k) c^2 s))`` (mm); ``root``: a
    :func:`conic_root` already computed (the compiled kernel shares it with the slope)."""
    num = c.to(s) * s
    if root is None:
        root = conic_root(s, c, k)
    return num / (1.0 + root)


def conic_dsag_ds(s, c, k, root=None):
    """The conic base's ``dz/ds = c / (2 sqrt(1 - (1+k) c^2 s))`` (1/mm), see :func:`conic_sag`;
    ``c / 2`` on the rim and beyond (finite: the true slope is infinite on the rim, and the
    tracer marks a ray that lands there invalid)."""
    cs = c.to(s)
    if root is None:
        root = conic_root(s, c, k)
    return cs / (2.0 * torch.where(root > 0, root, torch.ones_like(root)))


def even_poly(s, coeffs):
    """``sum_i a_{2i} s^i`` for ``coeffs = (a4, a6, ...)`` (Horner), mm."""
    p = torch.zeros_like(s)
    for a in reversed(list(coeffs)):
        p = (p + a.to(s)) * s
    return p * s


def even_poly_ds(s, coeffs):
    """``d/ds sum_{i>=2} a_{2i} s^i = sum_i i a_{2i} s^(i-1)`` (Horner)."""
    q = torch.zeros_like(s)
    coeffs = list(coeffs)
    for j in range(len(coeffs) - 1, -1, -1):
        q = q * s + (j + 2) * coeffs[j].to(s)
    return q * s


def even_terms_r2(s, coeffs):
    """``(Σ_i α_i s^i, Σ_i i α_i s^(i−1))`` for ``coeffs = (α_1, α_2, ...)`` (Horner, ``s = r²``):
    OpticStudio's even-asphere terms from r² up (the base of its Zernike and grid sags), mm and
    its derivative in ``s``."""
    p = torch.zeros_like(s)
    dp = torch.zeros_like(s)
    for i in range(len(coeffs), 0, -1):
        a = coeffs[i - 1].to(s)
        p = p * s + a
        dp = dp * s + i * a
    return p * s, dp


def asphere_sag(s, c, k, coeffs, root=None):
    """The sag ``z(s)`` (mm) at ``s = r^2``: :func:`conic_sag` plus :func:`even_poly` of the
    coefficients ``coeffs = (a4, a6, ...)`` (0-d tensors).  Outside the conic's domain the root
    is taken of 1 (finite; the tracer marks those rays invalid)."""
    z = conic_sag(s, c, k, root)
    if len(coeffs):
        z = z + even_poly(s, coeffs)
    return z


def asphere_dsag_ds(s, c, k, coeffs, root=None):
    """``dz/ds`` (1/mm): :func:`conic_dsag_ds` plus :func:`even_poly_ds`; the slopes are
    ``∂z/∂x = 2 x dz/ds``, ``∂z/∂y = 2 y dz/ds``."""
    g = conic_dsag_ds(s, c, k, root)
    if len(coeffs):
        g = g + even_poly_ds(s, coeffs)
    return g


def conic_quadric(ox, oy, oz, dx, dy, dz, c, k):
    """``(A, B, C, c', c)`` of ``A s^2 + 2 B s + C = 0`` for rays ``o + s d`` (``(*B,)``
    components, local frame) on the conic base, ``c' = (1+k) c`` (module docstring)."""
    c, k1 = c.to(ox), 1.0 + k.to(ox)
    ck = c * k1
    A = c * (dx * dx + dy * dy) + ck * (dz * dz)
    B = c * (ox * dx + oy * dy) + (ck * oz - 1.0) * dz
    C = c * (ox * ox + oy * oy) + (ck * oz - 2.0) * oz
    return A, B, C, ck, c


def conic_normal(x, y, z, c, ck):
    """The conic's unit normal ``(c x, c y, c' z - 1) / |.|`` on components (``∇F / 2``, no
    square root in the gradient itself), ``c' = (1+k) c``.  Returns ``(n_x, n_y, n_z)``."""
    gx, gy, gz = c * x, c * y, ck * z - 1.0
    inv = torch.rsqrt((gx * gx + gy * gy + gz * gz).clamp_min(1e-30))
    return gx * inv, gy * inv, gz * inv


@register_surface("asphere", aliases=("sphere", "conic"))
class Asphere(SagSurface):
    """Even asphere on a conic base (a sphere when ``k = 0`` and no coefficients).

    Args:
        curvature: ``c = 1/R`` in 1/mm (``0`` is flat).
        semi_diameter: clear semi-aperture in mm.
        conic: conic constant ``k`` (0 sphere, -1 paraboloid).
        coefficients: ``[a4, a6, ..., a20]`` (at most 9 values), mm^(1-2i).
        obscuration: radius of a central obscuration, mm (``0``: none; below the
            semi-diameter): rays that meet the surface at ``x^2 + y^2 < obscuration^2`` are
            blocked (the shadow of a Cassegrain's secondary on its primary, Zemax's ``OBSC``).
            A fixed buffer, not a parameter.
        clear_radius: radius of a clear aperture narrower than the semi-diameter, mm (``inf``:
            none): rays that meet the surface at ``x^2 + y^2 > clear_radius^2`` are blocked.
            For a stop sized by an EPD or F-number (its semi-diameter, the paraxial stop radius,
            sets the pupil) with a smaller clear aperture on it (Zemax's ``CLAP`` on the stop
            surface): the pupil keeps its size and the opening is the smaller one, so the rim
            of the pupil is vignetted.  A fixed buffer (not saved in ``state_dict``: it comes
            with the lens file, ``clear_radius_mm``), not a parameter.
        clear_decenter: ``(d_x, d_y)``, mm: the centre of that clear aperture (an off-axis
            segment of the surface: an off-axis parabola's opening, Zemax's ``OBDC`` with a
            ``CLAP``); the semi-diameter must then enclose the whole opening.  A fixed buffer
            like ``clear_radius`` (lens file: ``clear_decenter_mm``).
        clear_rect: ``(h_x, h_y)``, mm, or ``None``: a rectangular clear aperture of these
            half-widths, centred at ``clear_decenter`` (Zemax's ``SQAP``, with ``OBDC`` an
            off-axis mirror's rectangular opening): rays that meet the surface at
            ``|x - d_x| > h_x`` or ``|y - d_y| > h_y`` are blocked.  The opening is the
            rectangle *and* the clear circle, so ``clear_radius`` defaults to the rectangle's
            half-diagonal (its circumscribed circle, which the semi-diameter must enclose).
            A fixed buffer like ``clear_radius`` (lens file: ``clear_rect_mm``).

    Each value is its own parameter: ``surface.c``, ``surface.k``, ``surface.a[0]`` (= a4), ...
    """

    def __init__(self, curvature: float, semi_diameter: float, conic: float = 0.0,
                 coefficients=(), obscuration: float = 0.0, clear_radius: float = math.inf,
                 clear_decenter: tuple[float, float] = (0.0, 0.0), clear_rect=None):
        super().__init__(semi_diameter)
        rect = (0.0, 0.0) if clear_rect is None else tuple(float(v) for v in clear_rect)
        if len(rect) != 2 or (clear_rect is not None and not all(
                0 < v < math.inf for v in rect)):
            raise ValueError(f"Asphere: clear_rect must be two half-widths > 0 mm, got "
                             f"{clear_rect!r}")
        if clear_rect is not None and not math.isfinite(float(clear_radius)):
            clear_radius = math.hypot(*rect)
        self.register_buffer("clear_rect", torch.tensor(rect, dtype=torch.float64),
                             persistent=False)
        obscuration = float(obscuration)
        if not (obscuration >= 0.0 and obscuration < float("inf")):
            raise ValueError(f"Asphere: the obscuration radius must be a number >= 0 mm, got "
                             f"{obscuration!r}")
        self.register_buffer("obscuration", torch.tensor(obscuration, dtype=torch.float64))
        clear_radius = float(clear_radius)
        if not clear_radius > 0:
            raise ValueError(f"Asphere: the clear radius must be a number > 0 mm (inf: none), "
                             f"got {clear_radius!r}")
        self.register_buffer("clear_radius", torch.tensor(clear_radius, dtype=torch.float64),
                             persistent=False)
        dec = [float(v) for v in clear_decenter]
        if len(dec) != 2 or not all(math.isfinite(v) for v in dec):
            raise ValueError(f"Asphere: clear_decenter must be two finite numbers (mm), got "
                             f"{clear_decenter!r}")
        if any(dec) and not math.isfinite(clear_radius):
            raise ValueError("Asphere: a clear_decenter needs a clear_radius (the opening it "
                             "moves)")
        self.register_buffer("clear_decenter", torch.tensor(dec, dtype=torch.float64),
                             persistent=False)
        coefficients = list(coefficients)
        if len(coefficients) > (MAX_ASPHERE_ORDER - 2) // 2:
            raise ValueError(f"Asphere: at most {(MAX_ASPHERE_ORDER - 2) // 2} even coefficients "
                             f"(a4..a{MAX_ASPHERE_ORDER}), got {len(coefficients)}")
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.a = nn.ParameterList([make_param(v, f"a{2 * i + 4}")
                                   for i, v in enumerate(coefficients)])

    def in_domain(self, x, y):
        return conic_arg(x * x + y * y, self.c, self.k) > 0

    def sag(self, x, y):
        return asphere_sag(x * x + y * y, self.c, self.k, self.a)

    def sag_grad(self, x, y):
        g = asphere_dsag_ds(x * x + y * y, self.c, self.k, self.a)
        return 2.0 * x * g, 2.0 * y * g

    def paraxial_curvature(self):
        return self.c

    # ---- the compiled Newton kernels' interface (see Surface.kernel_values) ---------------
    def kernel_values(self, like):
        """``(c, k, (a4, a6, ...))`` in ``like``'s dtype (differentiable); ``None`` for a
        sphere or conic (the closed-form kernel runs those)."""
        if self.is_quadric:
            return None
        return (self.c.to(like), self.k.to(like), tuple(a.to(like) for a in self.a))

    @staticmethod
    def kernel_f(x, y, z, values):
        """``(f, f_x, f_y, f_z)`` from :func:`conic_sag`, :func:`conic_dsag_ds`,
        :func:`even_poly` and :func:`even_poly_ds`, fused: one conic root for both."""
        c, k, coeffs = values
        s = x * x + y * y
        root = conic_root(s, c, k)  # shared by the sag and its slope
        sag, g = conic_sag(s, c, k, root), conic_dsag_ds(s, c, k, root)
        if len(coeffs):
            sag = sag + even_poly(s, coeffs)
            g = g + even_poly_ds(s, coeffs)
        return sag - z, 2.0 * x * g, 2.0 * y * g, -torch.ones_like(z)

    @staticmethod
    def kernel_in_domain(x, y, values):
        c, k, _ = values
        return conic_arg(x * x + y * y, c, k) > 0

    @staticmethod
    def kernel_start(bx, by, bz, dx, dy, dz, ok, values, root_fn):
        """Newton starts from the conic base's root (``root_fn``: the tracer's
        :func:`~..intersect._quadric_root`)."""
        c, k, _ = values
        s, _ = root_fn(conic_quadric(bx, by, bz, dx, dy, dz, c, k), bz, dz, ok)
        return s

    # ---- the conic base as a quadric (closed-form intersection, cheap normal) -------------
    @property
    def is_quadric(self) -> bool:
        """True without aspheric coefficients: the surface is its conic base."""
        return len(self.a) == 0

    @property
    def fused_geometry(self) -> str:
        """``"quadric"`` (a sphere or conic: the closed-form fused step), else ``"newton"``."""
        return "quadric" if self.is_quadric else "newton"

    def fused_values(self, like) -> tuple:
        """``(c, k, r)`` for the ``"quadric"`` kind, in ``like``'s dtype: ``r`` the clip radius
        of the opening (the semi-diameter unless another circle was assigned)."""
        return (self.c.to(like), self.k.to(like), self.opening.kernel_clip[1].to(like))

    def quadric(self, o, d):
        """Coefficients ``(A, B, C)`` of ``A s^2 + 2 B s + C = 0`` for rays ``o + s d`` on the
        conic base, then ``c' = (1+k) c`` (the branch test is ``h = 1 - c' (o_z + s d_z) > 0``)
        and ``c``, see the module docstring.  Shapes ``(*B,)``, differentiable."""
        return self.quadric_xyz(*o.unbind(-1), *d.unbind(-1))

    def quadric_xyz(self, ox, oy, oz, dx, dy, dz):
        """:meth:`quadric` from the ``(*B,)`` components of ``o`` and ``d``."""
        return conic_quadric(ox, oy, oz, dx, dy, dz, self.c, self.k)

    def normal(self, x):
        """Unit normal ``(*B, 3)`` at points ``x`` on the surface (same orientation as ``∇f``).
        A conic uses ``∇F / 2 = (c x, c y, (1+k) c z - 1)`` (no square root)."""
        if not self.is_quadric:
            return super().normal(x)
        c, ck = self.c.to(x), (1.0 + self.k.to(x)) * self.c.to(x)
        X, Y, Z = x.unbind(-1)
        g = torch.stack([c * X, c * Y, ck * Z - 1.0], -1)  # conic_normal's vector form: the
        # (*B, 3) layout keeps the eager path's graph (and its gradients' rounding) unchanged
        return g * torch.rsqrt((g * g).sum(-1, keepdim=True).clamp_min(1e-30))

    def _build_opening(self) -> Opening:
        """The semi-diameter's circle, with the clear circle (about ``clear_decenter``) and
        the clear rectangle or ellipse when given, less the central obscuration's circle and
        the elliptical obscuration (:func:`~.base.with_ellipses`)."""
        clear, decentred, rect, obscured = host_flags(
            self, "_opening_flags",
            (self.clear_radius, self.clear_decenter, self.clear_rect, self.obscuration),
            lambda r, dec, rect, obs: (math.isfinite(float(r)), bool(dec.any()),
                                       bool(rect.any()), float(obs) > 0))
        opening = Circle(self.semi_diameter, check=False)
        if clear:
            dec = self.clear_decenter if decentred else None
            opening = opening & Circle(self.clear_radius, dec, check=False)
            if rect:
                opening = opening & Rectangle(self.clear_rect, self.clear_decenter, check=False)
        if obscured:
            opening = opening - Circle(self.obscuration, check=False)
        return with_ellipses(self, opening)

    def check(self, where: str = "") -> None:
        sd = float(self.semi_diameter)
        if not float(self.obscuration) < sd and float(self.obscuration) > 0:
            raise ValueError(f"{where}the central obscuration ({float(self.obscuration):g} mm) "
                             f"must be smaller than the semi-diameter ({sd:g} mm)")
        if float(self.obscuration) > 0 and not float(self.obscuration) < float(self.clear_radius):
            raise ValueError(f"{where}the central obscuration ({float(self.obscuration):g} mm) "
                             f"must be smaller than the clear radius "
                             f"({float(self.clear_radius):g} mm)")
        check_conic_domain(sd, float(self.c), float(self.k), "conic", where)

    def sag_scale(self, name: str) -> float:
        """``c``: ``R^2/2``; ``k``: :func:`~.base.conic_scale`; ``a.i`` (``a_{2i+4}``):
        ``R^(2i+4)``; else 1 (:meth:`Surface.sag_scale <.base.Surface.sag_scale>`)."""
        return conic_polynomial_scale(self, name, lambda i: 2 * i + 4)

    file_fields = ("curvature_per_mm", "roc_mm", "conic", "aspheric", "obscuration_mm",
                   "clear_radius_mm", "clear_decenter_mm", "clear_rect_mm")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        if entry.has("curvature_per_mm") and entry.has("roc_mm"):
            entry.fail("roc_mm", "give curvature_per_mm or roc_mm, not both")
        if entry.has("roc_mm"):
            roc = entry.get("roc_mm")
            c = 0.0 if roc == 0 else 1.0 / roc
        elif entry.has("curvature_per_mm"):
            c = entry.get("curvature_per_mm")
        else:
            entry.fail("curvature_per_mm", "missing required field (the vertex curvature in "
                                           "1/mm; or give roc_mm)")
        return cls(c, semi_diameter, conic=entry.get("conic", default=0.0),
                   coefficients=entry.get("aspheric", "numbers", default=[]),
                   obscuration=entry.get("obscuration_mm", default=0.0),
                   clear_radius=entry.get("clear_radius_mm", default=math.inf),
                   clear_decenter=entry.get("clear_decenter_mm", "numbers",
                                            default=[0.0, 0.0]),
                   clear_rect=entry.get("clear_rect_mm", "numbers", default=None))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        if float(self.k) != 0.0 or len(self.a):
            d["conic"] = float(self.k)
        if len(self.a):
            d["aspheric"] = [float(a) for a in self.a]
        if float(self.obscuration) > 0:
            d["obscuration_mm"] = float(self.obscuration)
        if math.isfinite(float(self.clear_radius)):
            d["clear_radius_mm"] = float(self.clear_radius)
        if bool(self.clear_decenter.any()):
            d["clear_decenter_mm"] = [float(v) for v in self.clear_decenter]
        if bool(self.clear_rect.any()):
            d["clear_rect_mm"] = [float(v) for v in self.clear_rect]
        return d

    def extra_repr(self) -> str:
        return (f"c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"n_coeffs={len(self.a)}, "
                + super().extra_repr())


class Sphere(Asphere):
    """A spherical surface of curvature ``c = 1/R`` (1/mm)."""

    def __init__(self, curvature: float, semi_diameter: float):
        super().__init__(curvature, semi_diameter)


class EvenBaseSag(SagSurface):
    """OpticStudio's even asphere from ``r²`` up plus a term of the subclass's own: ``z = conic
    + Σ_i α_i r^(2i) + W(x, y)`` (:func:`even_terms_r2`), the shape shared by
    :class:`~.zernike_sag.ZernikeSag` (Zernike terms) and :class:`~.grid_sag.GridSag` (a
    bicubic grid).  Subclasses hold ``c``, ``k`` and ``a`` (``α_1, α_2, ...``) and implement
    :meth:`extra_part`."""

    def extra_part(self, x, y, slopes: bool = True):
        """``(W, ∂W/∂x, ∂W/∂y)`` at ``(x, y)`` (mm, ``(*B,)`` each; the slopes ``None`` with
        ``slopes=False``)."""
        raise NotImplementedError

    def in_domain(self, x, y):
        return conic_arg(x * x + y * y, self.c, self.k) > 0

    def sag(self, x, y):
        s = x * x + y * y
        p, _ = even_terms_r2(s, self.a)
        W, _, _ = self.extra_part(x, y, slopes=False)
        return conic_sag(s, self.c, self.k) + p + W

    def sag_grad(self, x, y):
        s = x * x + y * y
        _, dp = even_terms_r2(s, self.a)
        g = 2.0 * (conic_dsag_ds(s, self.c, self.k) + dp)
        _, Wx, Wy = self.extra_part(x, y, slopes=True)
        return x * g + Wx, y * g + Wy

    def base_curvature(self):
        """The even base's vertex curvature ``c + 2 α_1`` (1/mm)."""
        cur = self.c
        if len(self.a):
            cur = cur + 2.0 * self.a[0]
        return cur

    def quadric(self, o, d):
        """The conic base as a quadric (Newton's start; the surface itself is not one)."""
        return conic_quadric(*o.unbind(-1), *d.unbind(-1), self.c, self.k)
