r"""Lenslet array: a rectangular array of identical conic lenslets (OpticStudio's sample
user-defined surface ``US_ARRAY.DLL``, read by :mod:`deeplens.optics.io.zmx_lenslet_array`).

``n_x × n_y`` lenslets of widths ``w_x × w_y`` (mm) tile the rectangle ``|x| <= n_x w_x / 2``,
``|y| <= n_y w_y / 2`` about the vertex.  Lenslet ``(i, j)`` (``i = 0..n_x−1``, ``j =
0..n_y−1``) is the cell ``[x_i − w_x/2, x_i + w_x/2] × [y_j − w_y/2, y_j + w_y/2]`` centred at

    x_i = (i + 1/2 − n_x/2) w_x,        y_j = (j + 1/2 − n_y/2) w_y,

so that an odd count puts a lenslet's centre on the vertex (``x_i = (i − (n_x − 1)/2) w_x``, the
centres at whole multiples of the width) and an even count a corner between lenslets.  In its
cell each lenslet is the conic of curvature ``c`` (1/mm) and conic constant ``k`` about its own
centre:

    z(x, y) = c ρ² / (1 + sqrt(1 − (1 + k) c² ρ²)),     ρ² = (x − x_i)² + (y − y_j)²,

    ∂z/∂x = (x − x_i) c / sqrt(1 − (1 + k) c² ρ²),      ∂z/∂y likewise with (y − y_j).

The sag is continuous across the cells' edges (each lenslet is symmetric about its centre, so
two neighbours meet at the same height on their common edge); the slopes jump there.  A point
on an edge belongs to the cell above it (``floor``), the outer edges to the outermost cells.

**Outside the array** (``|x| > n_x w_x / 2`` or ``|y| > n_y w_y / 2``) the surface is not
defined: :meth:`LensletArray.in_domain` is false there and the tracer marks such rays invalid (a
ray that misses the surface), as it does beyond a lenslet's conic domain.  The sag there stays
finite (the outermost lenslet continued), as every surface's must.

**Paraxial data** use the curvature ``c`` of the lenslet on the axis
(:meth:`LensletArray.paraxial_curvature`).  With an even count in ``x`` or ``y`` the axis falls
on an edge between lenslets, where the surface has no single curvature: paraxial use is refused
there with a ``ValueError`` that says so.

**Tracing.**  Newton starts from the exact hit on the lenslet whose cell holds the ray's
vertex-plane crossing (:meth:`LensletArray.quadric`, that lenslet's conic in its own
coordinates), so a ray that stays in that lenslet is on the surface after the first step, and
one that crosses into a neighbour is carried there by Newton's steps on the sag.  The cell of a
point is a constant of the trace (a ``floor`` of the detached coordinates): the hit's derivative
in ``c`` and ``k`` is the implicit one of that lenslet.  The surface has no compiled Newton
kernels: a compiled trace runs it eager between its fused runs.
"""

from __future__ import annotations

import math

import torch

from .asphere import conic_arg, conic_dsag_ds, conic_quadric, conic_sag
from .base import SagSurface, conic_scale, make_param, register_surface

__all__ = ["LensletArray"]


@register_surface("lenslet_array")
class LensletArray(SagSurface):
    """A rectangular array of identical conic lenslets (module docstring).

    Args:
        curvature: ``c = 1/R`` of every lenslet, 1/mm.
        semi_diameter: clear semi-aperture, mm (a circle about the vertex; the array's
            rectangle bounds the surface as well).
        counts: ``(n_x, n_y)``, the number of lenslets along x and y (whole numbers >= 1).
        widths: ``(w_x, w_y)``, each lenslet's width along x and y, mm (``> 0``): the pitch.
        conic: conic constant ``k`` of every lenslet.

    Parameters: ``surface.c`` and ``surface.k``, frozen until made trainable; the counts are
    host integers and the widths a fixed buffer ``lenslet_widths``.
    """

    def __init__(self, curvature: float, semi_diameter: float, counts, widths,
                 conic: float = 0.0):
        super().__init__(semi_diameter)
        counts, widths = self.checked_counts(counts), self.checked_widths(widths)
        #: ``(n_x, n_y)``, host integers (the cells' arithmetic needs no device read)
        self.counts = counts
        self.register_buffer("lenslet_widths", torch.tensor(widths, dtype=torch.float64))
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")

    @staticmethod
    def checked_counts(counts) -> tuple[int, int]:
        """``(n_x, n_y)`` as host integers; ``ValueError`` unless two whole numbers >= 1."""
        counts = tuple(counts)
        if len(counts) != 2 or not all(
                isinstance(n, (int, float)) and float(n) == int(n) and int(n) >= 1
                for n in counts):
            raise ValueError(f"LensletArray: counts must be two whole numbers >= 1 (lenslets "
                             f"along x and y), got {counts!r}")
        return int(counts[0]), int(counts[1])

    @staticmethod
    def checked_widths(widths) -> tuple[float, float]:
        """``(w_x, w_y)`` (mm) as floats; ``ValueError`` unless two finite numbers > 0."""
        widths = tuple(float(w) for w in widths)
        if len(widths) != 2 or not all(0 < w < math.inf for w in widths):
            raise ValueError(f"LensletArray: widths must be two numbers of mm > 0 (each "
                             f"lenslet's width along x and y), got {widths!r}")
        return widths

    # ---- the cells ---------------------------------------------------------------------
    def _centre(self, t, axis: int):
        """The centre (mm) of the lenslet whose cell holds ``t`` along ``axis`` (0: x, 1: y),
        and ``t``'s position in cell units from the array's low edge (``0..n``: inside)."""
        n = self.counts[axis]
        w = self.lenslet_widths[axis].to(t)
        s = t / w + 0.5 * n
        i = torch.clamp(torch.floor(s.detach()), 0, n - 1)
        return (i + 0.5 - 0.5 * n) * w, s

    def local(self, x, y):
        """``(x − x_i, y − y_j)``: the coordinates (mm) about the centre of the lenslet whose
        cell holds ``(x, y)`` (the outermost lenslet's beyond the array); ``(*B,)`` each."""
        cx, _ = self._centre(x, 0)
        cy, _ = self._centre(y, 1)
        return x - cx, y - cy

    def half_diagonal(self) -> float:
        """A lenslet's half-diagonal ``sqrt(w_x² + w_y²) / 2`` (mm): the farthest point of its
        cell from its centre."""
        wx, wy = (float(w) for w in self.lenslet_widths)
        return 0.5 * math.hypot(wx, wy)

    def domain_radius(self) -> float:
        """The array's half-diagonal ``sqrt((n_x w_x)² + (n_y w_y)²) / 2`` (mm): no point of the
        surface lies farther from the vertex (a semi-diameter beyond it encloses nothing
        more)."""
        wx, wy = (float(w) for w in self.lenslet_widths)
        return 0.5 * math.hypot(self.counts[0] * wx, self.counts[1] * wy)

    def in_domain(self, x, y):
        _, sx = self._centre(x, 0)
        _, sy = self._centre(y, 1)
        inside = (sx >= 0) & (sx <= self.counts[0]) & (sy >= 0) & (sy <= self.counts[1])
        u, v = self.local(x, y)
        return inside & (conic_arg(u * u + v * v, self.c, self.k) > 0)

    # ---- the sag -------------------------------------------------------------------------
    def sag(self, x, y):
        u, v = self.local(x, y)
        return conic_sag(u * u + v * v, self.c, self.k)

    def sag_grad(self, x, y):
        u, v = self.local(x, y)
        g = 2.0 * conic_dsag_ds(u * u + v * v, self.c, self.k)
        return u * g, v * g

    def quadric(self, o, d):
        """The conic of the lenslet whose cell holds the ray's point ``o`` (the tracer passes
        the vertex-plane crossing), in that lenslet's coordinates: Newton's start (the surface
        itself is not one quadric).  ``(A, B, C, c', c)`` as :func:`~.asphere.conic_quadric`."""
        ox, oy, oz = o.unbind(-1)
        u, v = self.local(ox, oy)
        return conic_quadric(u, v, oz, *d.unbind(-1), self.c, self.k)

    def paraxial_curvature(self):
        """The curvature ``c`` of the lenslet on the axis (1/mm).

        Raises:
            ValueError: an even count: the axis falls on an edge between lenslets.
        """
        even = [f"{a} ({n} lenslets)" for a, n in zip("xy", self.counts) if n % 2 == 0]
        if even:
            raise ValueError(f"LensletArray: the axis falls on an edge between lenslets (an "
                             f"even count along {' and '.join(even)}): no lenslet is centred "
                             f"on it, so the surface has no paraxial curvature and paraxial "
                             f"data (EFL, pupils, back focus) are undefined")
        return self.c

    def check(self, where: str = "") -> None:
        """Each lenslet's cell lies within its conic's domain (its corners, the half-diagonal
        from its centre, where ``1 − (1 + k) c² ρ² > 0``)."""
        c, k, rho = float(self.c), float(self.k), self.half_diagonal()
        if 1.0 - (1.0 + k) * c * c * rho * rho <= 0:
            limit = (1.0 / ((1.0 + k) * c * c)) ** 0.5
            raise ValueError(f"{where}the lenslets' corners ({rho:g} mm from each lenslet's "
                             f"centre) lie beyond the domain of their conic (R = {1 / c:g} mm, "
                             f"k = {k:g}: defined for r < {limit:g} mm)")

    def sag_scale(self, name: str) -> float:
        """``c``: ``ρ²/2`` and ``k``: :func:`~.base.conic_scale` at ``ρ``, the lenslet's
        half-diagonal (the largest radius about its centre); else 1."""
        rho = self.half_diagonal()
        if name == "c":
            return rho * rho / 2
        if name == "k":
            return conic_scale(float(self.c), float(self.k), rho)
        return 1.0

    # ---- serialisation -------------------------------------------------------------------
    file_fields = ("curvature_per_mm", "conic", "lenslet_counts", "lenslet_widths_mm")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        counts = entry.get("lenslet_counts", "numbers")
        if len(counts) != 2:
            entry.fail("lenslet_counts", f"expected [n_x, n_y], got {counts!r}")
        widths = entry.get("lenslet_widths_mm", "numbers")
        if len(widths) != 2:
            entry.fail("lenslet_widths_mm", f"expected [w_x, w_y], got {widths!r}")
        for key, check in (("lenslet_counts", cls.checked_counts),
                           ("lenslet_widths_mm", cls.checked_widths)):
            try:   # each field's refusal names that field
                check(counts if key == "lenslet_counts" else widths)
            except ValueError as e:
                entry.fail(key, str(e))
        return cls(entry.get("curvature_per_mm"), semi_diameter, counts, widths,
                   conic=entry.get("conic", default=0.0))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        d["conic"] = float(self.k)
        d["lenslet_counts"] = list(self.counts)
        d["lenslet_widths_mm"] = [float(w) for w in self.lenslet_widths]
        return d

    def extra_repr(self) -> str:
        wx, wy = (float(w) for w in self.lenslet_widths)
        return (f"c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"lenslets={self.counts[0]}x{self.counts[1]} of {wx:.6g} x {wy:.6g} mm, "
                + super().extra_repr())
