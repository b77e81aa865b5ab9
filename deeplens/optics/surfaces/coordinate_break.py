"""A coordinate break: a change of the frame for every following surface (Zemax ``COORDBRK``).

At a break whose vertex sits at ``z_b`` on the current axis, with decenter ``δ = (dx, dy, 0)``
and ``R = R_x(tilt_x) R_y(tilt_y) R_z(tilt_z)`` (Zemax's order flag 0: decenter, then tilt about
x, the new y, the new z; the same ``R_x``/``R_y`` as :mod:`~deeplens.optics.misalignment`):

    x_before - z_b e_z = δ + R (x_after - z_b e_z),        d_before = R d_after

so a point and a direction in the following frame are ``x_after = R^T (x_before - z_b e_z - δ)
+ z_b e_z`` and ``d_after = R^T d_before``.  The ``z_b e_z`` terms keep the vertex positions of a
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
    """

    file_fields = ("dx_mm", "dy_mm", "tilt_x_rad", "tilt_y_rad", "tilt_z_rad")
    is_flat = True

    def __init__(self, dx: float = 0.0, dy: float = 0.0, tilt_x: float = 0.0,
                 tilt_y: float = 0.0, tilt_z: float = 0.0, semi_diameter: float = 1.0):
        super().__init__(semi_diameter)
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

    def in_aperture(self, x, y):
        return torch.ones_like(x, dtype=torch.bool)

    def rotation(self, like: torch.Tensor) -> torch.Tensor:
        """``R = R_x(tilt_x) R_y(tilt_y) R_z(tilt_z)``, ``(3, 3)`` in ``like``'s dtype/device."""
        a, b, g = (p.to(like) for p in (self.tilt_x, self.tilt_y, self.tilt_z))
        one, zero = torch.ones_like(a), torch.zeros_like(a)

        def rot(t, i, j):  # rotation by t in the (i, j) plane
            c, s = torch.cos(t), torch.sin(t)
            m = [[one, zero, zero], [zero, one, zero], [zero, zero, one]]
            m[i][i], m[i][j], m[j][i], m[j][j] = c, -s, s, c
            return torch.stack([torch.stack(r) for r in m])

        return rot(a, 1, 2) @ rot(b, 2, 0) @ rot(g, 0, 1)

    def offset(self, like: torch.Tensor) -> torch.Tensor:
        """``δ = (dx, dy, 0)`` as a ``(3,)`` tensor."""
        return torch.stack([self.dx.to(like), self.dy.to(like), torch.zeros_like(self.dx.to(like))])

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
        return d

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        return cls(*(entry.get(k, default=0.0) for k in cls.file_fields), semi_diameter)

    def extra_repr(self) -> str:
        return (f"dx={float(self.dx):g} mm, dy={float(self.dy):g} mm, "
                f"tilt=({math.degrees(float(self.tilt_x)):g}, "
                f"{math.degrees(float(self.tilt_y)):g}, {math.degrees(float(self.tilt_z)):g}) deg")
