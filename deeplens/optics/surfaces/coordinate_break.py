"""A coordinate break: a change of the frame for every following surface (Zemax ``COORDBRK``).

At a break whose vertex sits at ``z_b`` on the current axis, with decenter ``δ = (dx, dy, 0)``
and ``R = R_x(tilt_x) R_y(tilt_y) R_z(tilt_z)`` (Zemax's order flag 0: decenter, then tilt about
x, the new y, the new z; the same ``R_x``/``R_y`` as :mod:`~deeplens.optics.misalignment`):

    x_before - z_b e_z = δ + R (x_after - z_b e_z),        d_before = R d_after

so a point and a direction in the following frame are ``x_after = R^T (x_before - z_b e_z - δ)
+ z_b e_z`` and ``d_after = R^T d_before``.  Zemax's order flag 1 (tilt about z, then y, then x,
then decenter along the tilted axes) is ``R = R_z R_y R_x`` and ``δ`` replaced by ``R δ``
(``order=1``); a break with order 1 exactly undoes the same values negated with order 0.  The ``z_b e_z`` terms keep the vertex positions of a
:class:`~deeplens.optics.lens.Lens` a running sum of its distances across the break: the next
vertex lies ``distance`` further along the *new* axis.  A break is not a physical surface: rays
do not stop on it (their position and optical path are unchanged, only re-expressed), it has no
power, and paraxial analysis passes through it as Zemax's does (it follows the local axes).

A fold mirror at 45 degrees is ``break(tilt_x = 45°) -> flat mirror -> break(tilt_x = 45°)``:
the first break tilts the mirror, the second turns the axis onto the reflected beam (which then
travels towards ``-z`` or ``+z`` in the new frame, as the mirror count says).
"""

from __future__ import annotations

import math

import torch

from ..interactions import FRAME_CHANGE
from ..openings import Everywhere, Opening
from .base import Surface, make_param, register_surface

__all__ = ["CoordinateBreak"]


def _on_axis(z, like):
    """``(0, 0, z)`` as a ``(3,)`` tensor of ``like``'s dtype and device."""
    z = torch.as_tensor(z).to(like)
    zero = torch.zeros_like(z)
    return torch.stack([zero, zero, z])


@register_surface("coordinate_break")
class CoordinateBreak(Surface):
    """Decenter ``dx, dy`` (mm) and tilts ``tilt_x, tilt_y, tilt_z`` (rad) of the frame of every
    following surface (see the module docstring).  All five are frozen ``nn.Parameter`` objects;
    unfreeze one to optimise or differentiate a fold angle.

    Args:
        dx, dy: decenter, mm.
        tilt_x, tilt_y, tilt_z: rotations about x, then the new y, then the new z, radians.
        semi_diameter: drawn size in layouts only (a break has no aperture), mm.
        order: Zemax's order flag: 0 decenter then tilt, 1 tilt (z, y, x) then decenter.
    """

    file_fields = ("dx_mm", "dy_mm", "tilt_x_rad", "tilt_y_rad", "tilt_z_rad", "order")
    is_flat = True
    #: re-expresses the rays in the next frame (:meth:`to_next`, :meth:`to_previous`)
    interaction = FRAME_CHANGE

    def __init__(self, dx: float = 0.0, dy: float = 0.0, tilt_x: float = 0.0,
                 tilt_y: float = 0.0, tilt_z: float = 0.0, semi_diameter: float = 1.0,
                 order: int = 0):
        super().__init__(semi_diameter)
        if order not in (0, 1):
            raise ValueError(f"coordinate break order must be 0 (decenter, then tilt) or 1 "
                             f"(tilt, then decenter), got {order!r}")
        self.order = int(order)
        self.dx = make_param(dx, "coordinate break dx")
        self.dy = make_param(dy, "coordinate break dy")
        self.tilt_x = make_param(tilt_x, "coordinate break tilt_x")
        self.tilt_y = make_param(tilt_y, "coordinate break tilt_y")
        self.tilt_z = make_param(tilt_z, "coordinate break tilt_z")

    # a break is never intersected; these keep generic code (layouts, checks) finite
    def f(self, x, y, z):
        return -z

    def f_grad(self, x, y, z):
        return torch.zeros_like(x), torch.zeros_like(y), -torch.ones_like(z)

    def sag(self, x, y):
        return torch.zeros_like(x)

    def _build_opening(self) -> Opening:
        return Everywhere()

    def rotation(self, like: torch.Tensor) -> torch.Tensor:
        """``R = R_x(tilt_x) R_y(tilt_y) R_z(tilt_z)`` (order 1: ``R_z R_y R_x``), ``(3, 3)`` in
        ``like``'s dtype/device."""
        a, b, g = (p.to(like) for p in (self.tilt_x, self.tilt_y, self.tilt_z))
        one, zero = torch.ones_like(a), torch.zeros_like(a)

        def rot(t, i, j):  # rotation by t in the (i, j) plane
            c, s = torch.cos(t), torch.sin(t)
            m = [[one, zero, zero], [zero, one, zero], [zero, zero, one]]
            m[i][i], m[i][j], m[j][i], m[j][j] = c, -s, s, c
            return torch.stack([torch.stack(r) for r in m])

        if self.order == 1:
            return rot(g, 0, 1) @ rot(b, 2, 0) @ rot(a, 1, 2)
        return rot(a, 1, 2) @ rot(b, 2, 0) @ rot(g, 0, 1)

    def offset(self, like: torch.Tensor) -> torch.Tensor:
        """The new origin in the old frame, relative to the vertex, ``(3,)``: ``δ = (dx, dy, 0)``
        (order 1: ``R δ``)."""
        d = torch.stack([self.dx.to(like), self.dy.to(like), torch.zeros_like(self.dx.to(like))])
        return self.rotation(like) @ d if self.order == 1 else d

    def to_next(self, x: torch.Tensor, d: torch.Tensor, z_vertex):
        """Points ``x`` and directions ``d`` ``(*B, 3)`` of the frame before the break, in the
        frame after it; ``z_vertex``: the break's vertex position (mm, 0-d)."""
        R = self.rotation(x)
        zc = _on_axis(z_vertex, x)
        return (x - zc - self.offset(x)) @ R + zc, d @ R  # row-vector form of R^T (...)

    def to_previous(self, x: torch.Tensor, d: torch.Tensor, z_vertex):
        """The inverse of :meth:`to_next` (for backward tracing)."""
        R = self.rotation(x)
        zc = _on_axis(z_vertex, x)
        return (x - zc) @ R.T + zc + self.offset(x), d @ R.T

    def is_identity(self) -> bool:
        return all(float(p) == 0.0 and not p.requires_grad
                   for p in (self.dx, self.dy, self.tilt_x, self.tilt_y, self.tilt_z))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d.update(dx_mm=float(self.dx), dy_mm=float(self.dy), tilt_x_rad=float(self.tilt_x),
                 tilt_y_rad=float(self.tilt_y), tilt_z_rad=float(self.tilt_z))
        if self.order:
            d["order"] = self.order
        return d

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        order = entry.get("order", default=0.0)
        if order not in (0.0, 1.0):
            entry.fail("order", f"expected 0 (decenter, then tilt) or 1 (tilt, then decenter), "
                                f"got {order!r}")
        return cls(*(entry.get(k, default=0.0) for k in cls.file_fields[:5]), semi_diameter,
                   order=int(order))

    @classmethod
    def from_zemax(cls, parm: dict, scale_mm: float = 1.0, semi_diameter: float = 1.0):
        """From a ``COORDBRK``'s ``PARM`` values ``{1: dx, 2: dy, 3: tilt_x°, 4: tilt_y°,
        5: tilt_z°, 6: order flag}`` (lengths in file units times ``scale_mm``); any non-zero
        order flag is Zemax's "tilt, then decenter"."""
        def v(i):
            return float(parm.get(i, 0.0))

        return cls(v(1) * scale_mm, v(2) * scale_mm, math.radians(v(3)), math.radians(v(4)),
                   math.radians(v(5)), semi_diameter, order=0 if v(6) == 0 else 1)

    def extra_repr(self) -> str:
        return (f"dx={float(self.dx):g} mm, dy={float(self.dy):g} mm, "
                f"tilt=({math.degrees(float(self.tilt_x)):g}, "
                f"{math.degrees(float(self.tilt_y)):g}, {math.degrees(float(self.tilt_z)):g}) deg, "
                f"order={self.order}")
