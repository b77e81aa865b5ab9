r"""OpticStudio's Irregular surface (``IRREGULA``): a conic with spherical aberration,
astigmatism and coma terms, decentred and tilted as a whole.

In the surface's own frame ``(x', y', z')`` the sag is (OpticStudio User Guide, *Irregular*,
ansyshelp.ansys.com, v242; the sag terms as the *TIRR* page and the Zemax manual write them,
"``... + Zs ρ⁴ + Za ρ_y'² + Zc ρ² ρ_y'``", ``ρ_y'`` "the normalized and rotated radial
coordinate"):

    z' = c r'² / (1 + sqrt(1 − (1 + k) c² r'²)) + Zs ρ⁴ + Za w² + Zc ρ² w,

    r'² = x'² + y'²,   ρ = r' / r_max,   w = (y' cos θ + x' sin θ) / r_max,

``c = 1/R`` (1/mm), ``k`` the conic constant, ``Zs``, ``Za``, ``Zc`` the spherical aberration,
astigmatism and coma "in lens units at the maximum radial aperture" ``r_max`` ("defined by the
clear semi-diameter or semi-diameter value for the surface": deeplens keeps the value it had
when read, a fixed buffer), the astigmatism and coma "oriented along a line that makes an angle
θ with respect to the y axis" (``w`` is the normalised coordinate along that line; θ = 0: along
y; the sense of a non-zero θ, towards +x here, is not shown by any file at hand).

The frame: "the tilt and decenter values work exactly like the coordinate break surface ...
however, the tilts and decenters are undone after the ray is traced to the surface": "decentered,
tilted about x, then about y" (same page), i.e. a :class:`~.coordinate_break.CoordinateBreak` of
order 0 with ``dx, dy, tilt_x, tilt_y``:

    p = δ + R p',   R = R_x(tilt_x) R_y(tilt_y),   δ = (dx, dy, 0),

so a local point ``p`` is ``p' = Rᵀ (p − δ)`` in the surface's frame.  The implicit function is
``f(p) = z'(x', y') − z'`` (``-1`` in ``z'``), its gradient ``∇f = R (∂z'/∂x', ∂z'/∂y', −1)``;
the hit, the normal and the refraction are those of any implicit surface (Newton from the conic
base's root when the surface is not tilted, from the vertex plane otherwise).  With every term,
decenter and tilt zero the surface is the STANDARD conic (``Asphere(c, k)``), bit for bit in its
sag.

**Paraxial data** (rotationally symmetric) take the y section of the surface at its own vertex,
``c + 2 Za cos²θ / r_max²`` (as deeplens' biconic and toroid do; the coma and spherical terms
have no curvature there); the decenter and tilt, OpticStudio's tolerancing errors, do not enter
them, as a misalignment does not.  ``sag(x, y)`` (layouts, crossing checks) solves ``f = 0``
along ``z`` by a few Newton steps from the untilted height.

The surface traces eagerly (no compiled Newton kernel).
"""

from __future__ import annotations

import math

import torch

from .asphere import conic_arg, conic_dsag_ds, conic_quadric, conic_sag
from .base import Surface, check_conic_domain, host_flags, make_param, register_surface

__all__ = ["Irregular"]


@register_surface("irregular")
class Irregular(Surface):
    """OpticStudio's Irregular surface (module docstring).

    Args:
        curvature: ``c = 1/R`` of the conic, 1/mm.
        semi_diameter: clear semi-aperture, mm.
        r_max: ``r_max``, the radius that normalises the Z terms, mm (``> 0``; OpticStudio's
            semi-diameter of the surface).
        conic: conic constant ``k``.
        decenter: ``(dx, dy)``, mm.
        tilt: ``(tilt_x, tilt_y)``, radians (about x, then the new y).
        z_spherical, z_astigmatism, z_coma: ``Zs``, ``Za``, ``Zc``, mm at ``r_max``.
        angle: ``θ``, the orientation of the astigmatism and coma from the y axis, radians.

    Parameters (frozen until made trainable): ``c``, ``k``, ``dx``, ``dy``, ``tilt_x``,
    ``tilt_y``, ``zs``, ``za``, ``zc``, ``angle``; ``r_max`` is a fixed buffer.
    """

    file_fields = ("curvature_per_mm", "conic", "r_max_mm", "decenter_x_mm", "decenter_y_mm",
                   "tilt_x_rad", "tilt_y_rad", "z_spherical_mm", "z_astigmatism_mm",
                   "z_coma_mm", "angle_rad")

    def __init__(self, curvature: float, semi_diameter: float, r_max: float, conic: float = 0.0,
                 decenter=(0.0, 0.0), tilt=(0.0, 0.0), z_spherical: float = 0.0,
                 z_astigmatism: float = 0.0, z_coma: float = 0.0, angle: float = 0.0):
        super().__init__(semi_diameter)
        rm = float(r_max)
        if not (rm > 0 and math.isfinite(rm)):
            raise ValueError(f"Irregular: r_max (the radius normalising the Z terms) must be a "
                             f"positive number of mm, got {r_max!r}")
        self.register_buffer("r_max", torch.tensor(rm, dtype=torch.float64))
        self.c = make_param(curvature, "curvature")
        self.k = make_param(conic, "conic")
        self.dx = make_param(decenter[0], "decenter x")
        self.dy = make_param(decenter[1], "decenter y")
        self.tilt_x = make_param(tilt[0], "tilt x")
        self.tilt_y = make_param(tilt[1], "tilt y")
        self.zs = make_param(z_spherical, "Zs")
        self.za = make_param(z_astigmatism, "Za")
        self.zc = make_param(z_coma, "Zc")
        self.angle = make_param(angle, "angle")

    # ---- the surface's own frame -------------------------------------------------------
    def _rotation(self, like):
        """``(cos a, sin a, cos b, sin b)`` of ``tilt_x = a``, ``tilt_y = b`` in ``like``'s
        dtype."""
        a, b = self.tilt_x.to(like), self.tilt_y.to(like)
        return torch.cos(a), torch.sin(a), torch.cos(b), torch.sin(b)

    def to_surface_frame(self, x, y, z):
        """``p' = Rᵀ (p − δ)`` (module docstring): ``(x', y', z')``, ``(*B,)`` each (mm)."""
        ca, sa, cb, sb = self._rotation(x)
        qx, qy = x - self.dx.to(x), y - self.dy.to(x)
        xs = cb * qx + sa * sb * qy - ca * sb * z
        ys = ca * qy + sa * z
        zs = sb * qx - sa * cb * qy + ca * cb * z
        return xs, ys, zs

    def _terms(self, xs, ys, slopes: bool):
        """The Z terms ``Zs ρ⁴ + Za w² + Zc ρ² w`` at ``(x', y')`` and, with ``slopes``, their
        ``∂/∂x'``, ``∂/∂y'``."""
        rm = self.r_max.to(xs)
        u, v = xs / rm, ys / rm
        th = self.angle.to(xs)
        ct, st = torch.cos(th), torch.sin(th)
        zs, za, zc = self.zs.to(xs), self.za.to(xs), self.zc.to(xs)
        p2 = u * u + v * v
        w = v * ct + u * st
        val = zs * p2 * p2 + za * w * w + zc * p2 * w
        if not slopes:
            return val, None, None
        gu = 4.0 * zs * p2 * u + 2.0 * za * w * st + zc * (2.0 * u * w + p2 * st)
        gv = 4.0 * zs * p2 * v + 2.0 * za * w * ct + zc * (2.0 * v * w + p2 * ct)
        return val, gu / rm, gv / rm

    def own_sag(self, xs, ys):
        """The sag ``z'(x', y')`` in the surface's own frame (mm)."""
        s = xs * xs + ys * ys
        val, _, _ = self._terms(xs, ys, slopes=False)
        return conic_sag(s, self.c, self.k) + val

    def own_sag_grad(self, xs, ys):
        """``(∂z'/∂x', ∂z'/∂y')`` in the surface's own frame."""
        s = xs * xs + ys * ys
        g = 2.0 * conic_dsag_ds(s, self.c, self.k)
        _, tx, ty = self._terms(xs, ys, slopes=True)
        return xs * g + tx, ys * g + ty

    # ---- the implicit function ---------------------------------------------------------
    def f(self, x, y, z):
        xs, ys, zs = self.to_surface_frame(x, y, z)
        return self.own_sag(xs, ys) - zs

    def f_grad(self, x, y, z):
        xs, ys, _ = self.to_surface_frame(x, y, z)
        gx, gy = self.own_sag_grad(xs, ys)
        ca, sa, cb, sb = self._rotation(x)
        # ∇f = R (gx, gy, -1), R = R_x(a) R_y(b)
        fx = cb * gx - sb
        fy = sa * sb * gx + ca * gy + sa * cb
        fz = -ca * sb * gx + sa * gy - ca * cb
        return fx, fy, fz

    def in_domain(self, x, y):
        # the conic's root in the surface's frame; the tilt moves z' by z sin(tilt) only, so
        # the point of the vertex plane stands for the hit (exact when untilted)
        xs, ys, _ = self.to_surface_frame(x, y, torch.zeros_like(x))
        return conic_arg(xs * xs + ys * ys, self.c, self.k) > 0

    def _tilted(self) -> bool:
        return host_flags(self, "_tilted_flag", (self.tilt_x, self.tilt_y),
                          lambda a, b: float(a) != 0.0 or float(b) != 0.0)

    def quadric(self, o, d):
        """The conic, decentred, as a quadric (Newton's start) when the surface is not tilted;
        ``None`` (Newton from the vertex plane) when it is."""
        if self._tilted():
            return None
        ox, oy, oz = o.unbind(-1)
        return conic_quadric(ox - self.dx.to(ox), oy - self.dy.to(ox), oz, *d.unbind(-1),
                             self.c, self.k)

    def sag(self, x, y):
        """The height ``z`` of the surface over ``(x, y)`` (local frame, mm): four Newton steps
        on ``f(x, y, z) = 0`` from the untilted height (for layouts and crossing checks)."""
        ok = self.in_domain(x, y)
        x0 = torch.where(ok, x, torch.zeros_like(x))
        y0 = torch.where(ok, y, torch.zeros_like(y))
        z = self.own_sag(x0 - self.dx.to(x), y0 - self.dy.to(x))
        if self._tilted():
            for _ in range(4):
                fz = self.f_grad(x0, y0, z)[2]
                z = z - self.f(x0, y0, z) / torch.where(fz.abs() > 1e-12, fz, -torch.ones_like(fz))
        return torch.where(ok, z, torch.zeros_like(z))

    def paraxial_curvature(self):
        """``c + 2 Za cos²θ / r_max²``: the y section at the surface's own vertex (module
        docstring)."""
        rm = self.r_max.to(self.c)
        return self.c + 2.0 * self.za * torch.cos(self.angle) ** 2 / (rm * rm)

    def check(self, where: str = "") -> None:
        sd = float(self.semi_diameter) + math.hypot(float(self.dx.detach()), float(self.dy.detach()))
        check_conic_domain(sd, float(self.c.detach()), float(self.k.detach()),
                           "irregular surface's conic (decentred)", where)

    def sag_scale(self, name: str) -> float:
        """The largest change of the sag on the rim ``r = R`` (72 azimuths) per unit of the
        parameter ``name`` (central differences in float64; the decenter, tilts and Z terms
        move the rim unevenly, so no single closed form serves them all); 1 where the parameter
        does not move the sag (the angle of zero astigmatism and coma)."""
        param = dict(self.named_parameters()).get(name)
        if param is None:
            return 1.0
        R = float(self.semi_diameter)
        phi = torch.arange(72, dtype=torch.float64) * (2 * math.pi / 72)
        x = (R * torch.cos(phi)).to(self.c)
        y = (R * torch.sin(phi)).to(self.c)
        p0 = float(param.detach())
        h = 1e-6 * max(1.0, abs(p0))
        with torch.no_grad():
            param.fill_(p0 + h)
            up = self.sag(x, y)
            param.fill_(p0 - h)
            down = self.sag(x, y)
            param.fill_(p0)
        ref = float(((up - down) / (2 * h)).abs().max())
        return ref if ref >= 1e-9 else 1.0

    # ---- lens files --------------------------------------------------------------------
    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(entry.get("curvature_per_mm"), semi_diameter, entry.get("r_max_mm"),
                   conic=entry.get("conic", default=0.0),
                   decenter=(entry.get("decenter_x_mm", default=0.0),
                             entry.get("decenter_y_mm", default=0.0)),
                   tilt=(entry.get("tilt_x_rad", default=0.0),
                         entry.get("tilt_y_rad", default=0.0)),
                   z_spherical=entry.get("z_spherical_mm", default=0.0),
                   z_astigmatism=entry.get("z_astigmatism_mm", default=0.0),
                   z_coma=entry.get("z_coma_mm", default=0.0),
                   angle=entry.get("angle_rad", default=0.0))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d.update(curvature_per_mm=float(self.c), conic=float(self.k), r_max_mm=float(self.r_max),
                 decenter_x_mm=float(self.dx), decenter_y_mm=float(self.dy),
                 tilt_x_rad=float(self.tilt_x), tilt_y_rad=float(self.tilt_y),
                 z_spherical_mm=float(self.zs), z_astigmatism_mm=float(self.za),
                 z_coma_mm=float(self.zc), angle_rad=float(self.angle))
        return d

    def extra_repr(self) -> str:
        return (f"c={float(self.c.detach()):.6g}/mm, k={float(self.k.detach()):.6g}, "
                f"decenter=({float(self.dx):g}, {float(self.dy):g}) mm, "
                f"tilt=({math.degrees(float(self.tilt_x)):g}, "
                f"{math.degrees(float(self.tilt_y)):g}) deg, Zs={float(self.zs):g}, "
                f"Za={float(self.za):g}, Zc={float(self.zc):g} mm, "
                f"angle={math.degrees(float(self.angle)):g} deg, r_max={float(self.r_max):g} mm, "
                + super().extra_repr())
