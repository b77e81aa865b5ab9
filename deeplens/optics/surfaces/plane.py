"""Plane surface ``z = 0`` (local frame); intersected in closed form ``t = -o_z / d_z``."""

from __future__ import annotations

import torch

from .base import SagSurface, register_surface

__all__ = ["Plane"]


@register_surface("plane")
class Plane(SagSurface):
    """A flat refracting (or dummy) surface with a circular clear aperture.

    Args:
        semi_diameter: clear semi-aperture in mm.
    """

    is_flat = True
    fused_geometry = "plane"

    def sag(self, x, y):
        return torch.zeros_like(x)

    def sag_grad(self, x, y):
        return torch.zeros_like(x), torch.zeros_like(y)
