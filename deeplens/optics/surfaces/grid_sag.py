r"""Grid sag: an even asphere plus a rectangular grid of sag values, bicubically interpolated
(OpticStudio's ``GRID_SAG``, "Grid Sag").

    z(x, y) = c r² / (1 + sqrt(1 − (1 + k) c² r²)) + Σ_{i=1..8} α_i r^{2i} + G(x − x_d, y − y_d)

with ``r² = x² + y²``, curvature ``c`` (1/mm), conic ``k``, even coefficients ``α_i``
(mm^(1−2i), on ``r², r⁴, ..., r¹⁶``: OpticStudio's Even Asphere terms) and ``G`` the grid part:
``n_x × n_y`` nodes spaced ``h_x``, ``h_y`` (mm), centred on the grid decenter ``(x_d, y_d)``
(mm): node ``(i, j)`` (``i = 0..n_x−1``, ``j = 0..n_y−1``) sits at

    x_i = x_d + (i − (n_x − 1)/2) h_x,        y_j = y_d + (j − (n_y − 1)/2) h_y,

and carries the sag ``z_ij`` (mm), the slopes ``∂z/∂x``, ``∂z/∂y`` (dimensionless) and the cross
derivative ``∂²z/∂x∂y`` (1/mm).  Stored here with ``j`` the row and rising ``y`` (``z[j, i]``;
OpticStudio's files list the top row, ``+y``, first: the readers turn them).

**The interpolant.**  In the cell ``[x_i, x_{i+1}] × [y_j, y_{j+1}]``, with ``u = (x − x_i)/h_x``
and ``v = (y − y_j)/h_y`` in ``[0, 1]``, ``G`` is the bicubic Hermite interpolant of the four
corners' values and derivatives:

    G = Σ_{a,b ∈ {0,1}} [ z_ab A_a(u) A_b(v) + h_x z^x_ab B_a(u) A_b(v)
                          + h_y z^y_ab A_a(u) B_b(v) + h_x h_y z^xy_ab B_a(u) B_b(v) ]

with the cubic Hermite basis ``A_0 = (1 + 2u)(1 − u)²``, ``A_1 = u²(3 − 2u)``, ``B_0 = u(1 −
u)²``, ``B_1 = u²(u − 1)`` (the derivatives are per unit of ``u``, hence the cell sizes).  ``G``
takes each node's value, slopes and cross derivative, and ``G``, ``∂G/∂x``, ``∂G/∂y`` are
continuous across the cell edges (on an edge they depend on that edge's two nodes only): the
sag and the normal are continuous, the curvature jumps at the grid lines.  It reproduces every
polynomial of degree <= 3 in ``x`` and in ``y`` (``x^p y^q``, ``p, q <= 3``) exactly when the
nodes carry its exact derivatives; for a smooth sag the error is at most ``h_x⁴/384 max|∂⁴z/∂x⁴|
+ h_y⁴/384 (max|∂⁴z/∂y⁴| + h_x/4 max|∂⁵z/∂x∂y⁴|)`` (the one-dimensional Hermite bound, applied
in ``y`` and then in ``x``, whose basis sums to ``|A_0| + |A_1| = 1``, ``|B_0| + |B_1| =
u(1 − u) <= 1/4``).  OpticStudio's surface is "determined by either a linear or a bicubic
spline interpolation of the sag values", its data ``z``, ``dz/dx``, ``dz/dy``, ``d2z/dxdy`` per
node (OpticStudio User Guide, *Grid Sag*, ansyshelp.ansys.com, v242); the page gives no formula,
and this interpolant is taken for its bicubic: the one bicubic per cell that those sixteen corner
values fix (the classic bicubic interpolation, e.g. Numerical Recipes' ``bcuint``).  The linear
interpolation OpticStudio also offers is not here (its slopes jump at every grid line).

**Outside the grid** (``x`` beyond ``[x_0, x_{n_x−1}]`` or ``y`` beyond ``[y_0, y_{n_y−1}]``)
the surface is not defined: :meth:`GridSag.in_domain` is false there and the tracer marks
such rays invalid (a ray that misses the surface).  The sag itself stays finite there (the
edge cell's polynomial, continued), as every surface's must.

**Paraxial data** use the mean vertex curvature ``c + 2 α_1 + (∂²G/∂x² + ∂²G/∂y²)/2`` at
``(0, 0)`` (:meth:`GridSag.paraxial_curvature`): OpticStudio "computes the effective paraxial
curvature using the vertex radius of curvature, asphere coefficient data, and grid data points"
(*Grid Sag*, as above) without saying how; this is the interpolated surface's own.  Where the
vertex lies on a grid line the curvature across it jumps, and the mean of the two cells' is
taken (for a sphere of curvature ``c`` sampled with exact derivatives that is ``c (1 −
c² h²/4 + ...)``, a relative error ``c² h² / 4``).

The surface has no compiled Newton kernels: a compiled trace runs it eager between its fused
runs.  Newton starts from the conic base's root (:meth:`GridSag.quadric`).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .asphere import EvenBaseSag
from .base import (check_conic_domain, conic_polynomial_scale, make_param,
                   register_surface)

__all__ = ["GridSag", "MAX_GRID_EVEN_TERMS", "hermite_basis", "grid_slopes"]

#: the even part's terms: ``r², r⁴, ..., r¹⁶`` (OpticStudio's PARM 1..8)
MAX_GRID_EVEN_TERMS = 8


def hermite_basis(u, order: int = 0):
    """The cubic Hermite basis ``(A_0, A_1, B_0, B_1)`` at ``u`` (module docstring), or its
    ``order``-th derivative in ``u`` (0, 1 or 2); ``(*B,)`` each."""
    if order == 0:
        return ((1 + 2 * u) * (1 - u) ** 2, u * u * (3 - 2 * u), u * (1 - u) ** 2, u * u * (u - 1))
    if order == 1:
        return (6 * u * u - 6 * u, 6 * u - 6 * u * u, 3 * u * u - 4 * u + 1, 3 * u * u - 2 * u)
    if order == 2:
        return (12 * u - 6, 6 - 12 * u, 6 * u - 4, 6 * u - 2)
    raise ValueError(f"hermite_basis: order 0, 1 or 2, got {order}")


def grid_slopes(z, hx: float, hy: float):
    """``(∂z/∂x, ∂z/∂y, ∂²z/∂x∂y)`` of a grid of sag values ``z`` (``(n_y, n_x)``, rows of
    rising ``y``, spacings ``hx``, ``hy`` in mm) by finite differences: central in the interior,
    second-order one-sided at the edges (``(−3 z_0 + 4 z_1 − z_2) / 2h``), the cross
    derivative as the ``y`` difference of the ``x`` slopes.  Exact for quadratics in each
    variable; for the files that give sag values only (OpticStudio computes their derivatives
    by finite differences too, with a stencil it does not document)."""
    z = torch.as_tensor(z, dtype=torch.float64)

    def diff(a, h, dim):
        n = a.shape[dim]
        if n < 3:
            raise ValueError(f"grid_slopes: at least 3 nodes per direction, got {n}")
        a_ = a.movedim(dim, 0)
        d = torch.empty_like(a_)
        d[1:-1] = (a_[2:] - a_[:-2]) / (2 * h)
        d[0] = (-3 * a_[0] + 4 * a_[1] - a_[2]) / (2 * h)
        d[-1] = (3 * a_[-1] - 4 * a_[-2] + a_[-3]) / (2 * h)
        return d.movedim(0, dim)

    zx = diff(z, hx, 1)
    return zx, diff(z, hy, 0), diff(zx, hy, 0)


def _grid_array(values, name: str, shape=None):
    t = torch.as_tensor(values, dtype=torch.float64)
    if t.ndim != 2:
        raise ValueError(f"GridSag: {name} must be a 2-D grid (rows of rising y), got shape "
                         f"{tuple(t.shape)}")
    if shape is not None and tuple(t.shape) != shape:
        raise ValueError(f"GridSag: {name} has shape {tuple(t.shape)}, the sag grid "
                         f"{shape}")
    return make_param(t, name)


@register_surface("grid_sag")
class GridSag(EvenBaseSag):
    """An even asphere plus a bicubically interpolated grid of sag values (module docstring).

    Args:
        curvature: ``c = 1/R`` of the base, 1/mm.
        semi_diameter: clear semi-aperture, mm.
        spacing: ``(h_x, h_y)``, the node spacings, mm (``> 0``).
        z: ``(n_y, n_x)`` sag values at the nodes, mm; row ``j`` at ``y_j`` (rising ``y``),
            column ``i`` at ``x_i`` (``n_x, n_y >= 2``).
        dz_dx, dz_dy: ``(n_y, n_x)`` slopes at the nodes (dimensionless); zeros if omitted.
        d2z_dxdy: ``(n_y, n_x)`` cross derivatives at the nodes, 1/mm; zeros if omitted.
        decenter: ``(x_d, y_d)``, the grid's centre relative to the vertex, mm.
        conic: conic constant ``k`` of the base.
        coefficients: ``[α_1, ..., α_M]`` on ``r², r⁴, ..., r^(2M)`` (``M <= 8``), mm^(1−2i).

    Parameters: ``surface.c``, ``surface.k``, ``surface.a[i − 1]`` (``α_i``) and the four
    grids ``surface.grid_z``, ``surface.grid_dz_dx``, ``surface.grid_dz_dy``,
    ``surface.grid_d2z_dxdy`` (each entry one value), each frozen until made trainable; the
    spacing and decenter are fixed buffers.
    """

    def __init__(self, curvature: float, semi_diameter: float, spacing, z, dz_dx=None,
                 dz_dy=None, d2z_dxdy=None, decenter=(0.0, 0.0), conic: float = 0.0,
                 coefficients=()):
        super().__init__(semi_diameter)
        hx, hy = (float(v) for v in spacing)
        if not (0 < hx < math.inf and 0 < hy < math.inf):
            raise ValueError(f"GridSag: the grid spacing must be two numbers of mm > 0, got "
                             f"{spacing!r}")
        xd, yd = (float(v) for v in decenter)
        if not (math.isfinite(xd) and math.isfinite(yd)):
            raise ValueError(f"GridSag: the grid decenter must be finite, got {decenter!r}")
        coefficients = list(coefficients)
        if len(coefficients) > MAX_GRID_EVEN_TERMS:
            raise ValueError(f"GridSag: at most {MAX_GRID_EVEN_TERMS} even coefficients (r^2.."
                             f"r^{2 * MAX_GRID_EVEN_TERMS}), got {len(coefficients)}")
        self.grid_z = _grid_array(z, "grid_z")
        shape = tuple(self.grid_z.shape)
        if min(shape) < 2:
            raise ValueError(f"GridSag: the grid needs at least 2 nodes in x and in y, got "
                             f"{shape[1]} x {shape[0]}")
        zeros = torch.zeros(shape, dtype=torch.float64)
        self.grid_dz_dx = _grid_array(zeros if dz_dx is None else dz_dx, "grid_dz_dx", shape)
        self.grid_dz_dy = _grid_array(zeros if dz_dy is None else dz_dy, "grid_dz_dy", shape)
        self.grid_d2z_dxdy = _grid_array(zeros if d2z_dxdy is None else d2z_dxdy,
                                         "grid_d2z_dxdy", shape)
        self.register_buffer("grid_spacing", torch.tensor([hx, hy], dtype=torch.float64))
        self.register_buffer("grid_decenter", torch.tensor([xd, yd], dtype=torch.float64))
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.a = nn.ParameterList([make_param(v, f"alpha{i + 1}")
                                   for i, v in enumerate(coefficients)])

    # ---- the grid ----------------------------------------------------------------------
    @property
    def grid_shape(self) -> tuple[int, int]:
        """``(n_x, n_y)``, the nodes in ``x`` and in ``y``."""
        ny, nx = self.grid_z.shape
        return nx, ny

    def _index(self, t, axis: int):
        """Grid coordinate ``s = (t − t_0)/h`` of ``t`` along ``axis`` (0: x, 1: y)."""
        n = self.grid_z.shape[1 - axis]
        h = self.grid_spacing[axis].to(t)
        t0 = self.grid_decenter[axis].to(t) - 0.5 * (n - 1) * h
        return (t - t0) / h, n, h

    def grid_extent(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``((x_0, x_last), (y_0, y_last))``, the grid's outer nodes (mm)."""
        out = []
        for axis in (0, 1):
            n = self.grid_z.shape[1 - axis]
            h, d = float(self.grid_spacing[axis]), float(self.grid_decenter[axis])
            out.append((d - 0.5 * (n - 1) * h, d + 0.5 * (n - 1) * h))
        return out[0], out[1]

    def _cell(self, s, n, shift: int = 0):
        """Cell index (long, clamped to ``0..n−2``; ``shift`` moves it) and local ``u``."""
        i = torch.clamp(torch.floor(s.detach()) + shift, 0, n - 2)
        return i.long(), s - i

    def _hermite(self, ix, iy, u, v, hx, hy, du: int, dv: int):
        """``∂^(du+dv) G / ∂u^du ∂v^dv`` in cells ``(ix, iy)`` at local ``(u, v)``."""
        bu, bv = hermite_basis(u, du), hermite_basis(v, dv)
        Z, Zx = self.grid_z.to(u), self.grid_dz_dx.to(u)
        Zy, Zxy = self.grid_dz_dy.to(u), self.grid_d2z_dxdy.to(u)
        out = torch.zeros_like(u)
        for a in (0, 1):
            for b in (0, 1):
                jy, jx = iy + b, ix + a
                out = out + (Z[jy, jx] * bu[a] * bv[b] + hx * Zx[jy, jx] * bu[2 + a] * bv[b]
                             + hy * Zy[jy, jx] * bu[a] * bv[2 + b]
                             + hx * hy * Zxy[jy, jx] * bu[2 + a] * bv[2 + b])
        return out

    def extra_part(self, x, y, slopes: bool = True):
        """``(G, ∂G/∂x, ∂G/∂y)`` at ``(x, y)`` (mm, ``(*B,)`` each; the slopes ``None`` with
        ``slopes=False``): the grid's bicubic interpolant, the edge cells' polynomials continued
        outside the grid."""
        sx, nx, hx = self._index(x, 0)
        sy, ny, hy = self._index(y, 1)
        ix, u = self._cell(sx, nx)
        iy, v = self._cell(sy, ny)
        G = self._hermite(ix, iy, u, v, hx, hy, 0, 0)
        if not slopes:
            return G, None, None
        return (G, self._hermite(ix, iy, u, v, hx, hy, 1, 0) / hx,
                self._hermite(ix, iy, u, v, hx, hy, 0, 1) / hy)

    def in_domain(self, x, y):
        sx, nx, _ = self._index(x, 0)
        sy, ny, _ = self._index(y, 1)
        inside = (sx >= 0) & (sx <= nx - 1) & (sy >= 0) & (sy <= ny - 1)
        return inside & super().in_domain(x, y)

    # ---- the sag (conic + even terms + the grid: EvenBaseSag) ---------------------------
    def _grid_second(self, axis: int):
        """``∂²G/∂x²`` (``axis`` 0) or ``∂²G/∂y²`` (1) at the vertex ``(0, 0)``: the mean of
        the two cells' where the vertex lies on a grid line across ``axis``."""
        zero = torch.zeros(1, dtype=self.grid_z.dtype, device=self.grid_z.device)
        sx, nx, hx = self._index(zero, 0)
        sy, ny, hy = self._index(zero, 1)
        s, n = (sx, nx) if axis == 0 else (sy, ny)
        shifts = [0]
        if float(s) == math.floor(float(s)) and 0 < float(s) < n - 1:
            shifts.append(-1)   # on a grid line inside the grid: both cells
        ix, u = self._cell(sx, nx)
        iy, v = self._cell(sy, ny)
        vals = []
        for sh in shifts:
            if axis == 0:
                ix2, u2 = self._cell(sx, nx, sh)
                vals.append(self._hermite(ix2, iy, u2, v, hx, hy, 2, 0) / (hx * hx))
            else:
                iy2, v2 = self._cell(sy, ny, sh)
                vals.append(self._hermite(ix, iy2, u, v2, hx, hy, 0, 2) / (hy * hy))
        return (sum(vals) / len(vals))[0]

    def paraxial_curvature(self):
        """The mean vertex curvature ``c + 2 α_1 + (∂²G/∂x² + ∂²G/∂y²)/2`` (module
        docstring)."""
        return self.base_curvature() + 0.5 * (self._grid_second(0) + self._grid_second(1))

    def check(self, where: str = "") -> None:
        check_conic_domain(float(self.semi_diameter), float(self.c), float(self.k),
                           "grid sag surface's conic base", where)

    def sag_scale(self, name: str) -> float:
        """``c``: ``R^2/2``; ``k``: :func:`~.base.conic_scale`; ``a.i`` (of ``r^(2i+2)``):
        ``R^(2i+2)``; the grids, per node value, the most the sag moves per unit of one: ``grid_z``
        (mm) 1 (at the node), ``grid_dz_dx`` ``4/27 h_x`` and ``grid_dz_dy`` ``4/27 h_y`` (the
        largest ``|B_a|``, a third of the cell from the node), ``grid_d2z_dxdy`` ``(4/27)² h_x
        h_y``."""
        m = 4.0 / 27.0
        if name == "grid_dz_dx":
            return m * float(self.grid_spacing[0])
        if name == "grid_dz_dy":
            return m * float(self.grid_spacing[1])
        if name == "grid_d2z_dxdy":
            return m * m * float(self.grid_spacing[0] * self.grid_spacing[1])
        return conic_polynomial_scale(self, name, lambda i: 2 * i + 2)

    file_fields = ("curvature_per_mm", "conic", "even_coefficients", "grid_spacing_mm",
                   "grid_decenter_mm", "grid_sag_mm", "grid_dz_dx", "grid_dz_dy",
                   "grid_d2z_dxdy_per_mm")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        spacing = entry.get("grid_spacing_mm", "numbers")
        if len(spacing) != 2:
            entry.fail("grid_spacing_mm", f"expected [h_x, h_y], got {spacing!r}")
        decenter = entry.get("grid_decenter_mm", "numbers", default=[0.0, 0.0])
        if len(decenter) != 2:
            entry.fail("grid_decenter_mm", f"expected [x_d, y_d], got {decenter!r}")
        z = entry.get("grid_sag_mm", "grid")
        shape = (len(z), len(z[0]))
        grids = {}
        for key in ("grid_dz_dx", "grid_dz_dy", "grid_d2z_dxdy_per_mm"):
            g = entry.get(key, "grid", default=None)
            if g is not None and (len(g), len(g[0])) != shape:
                entry.fail(key, f"has {len(g)} rows of {len(g[0])}, the sag grid "
                                f"(grid_sag_mm) {shape[0]} rows of {shape[1]}")
            grids[key] = g
        try:
            return cls(entry.get("curvature_per_mm"), semi_diameter, spacing, z,
                       grids["grid_dz_dx"], grids["grid_dz_dy"], grids["grid_d2z_dxdy_per_mm"],
                       decenter, conic=entry.get("conic", default=0.0),
                       coefficients=entry.get("even_coefficients", "numbers", default=[]))
        except ValueError as e:
            entry.fail("grid_sag_mm", str(e))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["curvature_per_mm"] = float(self.c)
        d["conic"] = float(self.k)
        d["even_coefficients"] = [float(v) for v in self.a]
        d["grid_spacing_mm"] = [float(v) for v in self.grid_spacing]
        d["grid_decenter_mm"] = [float(v) for v in self.grid_decenter]
        d["grid_sag_mm"] = self.grid_z.detach().cpu().tolist()
        d["grid_dz_dx"] = self.grid_dz_dx.detach().cpu().tolist()
        d["grid_dz_dy"] = self.grid_dz_dy.detach().cpu().tolist()
        d["grid_d2z_dxdy_per_mm"] = self.grid_d2z_dxdy.detach().cpu().tolist()
        return d

    def extra_repr(self) -> str:
        nx, ny = self.grid_shape
        hx, hy = (float(v) for v in self.grid_spacing)
        return (f"c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"grid={nx}x{ny} at {hx:.6g} x {hy:.6g} mm, n_even={len(self.a)}, "
                + super().extra_repr())
