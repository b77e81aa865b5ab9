"""A surface that starts a graded medium: OpticStudio's ``GRINSUR1`` (Gradient 1) in a file.

The shape is a conic (the Standard surface's, :class:`~.asphere.Asphere`); the gradient-index
medium after it (:class:`~deeplens.optics.grin.RadialGradient`) is the lens's material there,
and the surface keeps a reference to it (not a submodule: the lens owns it) so that the
``.zmx`` writer can write both as one ``GRINSUR1`` record (:mod:`deeplens.optics.io.zmx_grin`).
Tracing asks the medium, never this class (:mod:`deeplens.optics.grin_trace`).
"""

from __future__ import annotations

from .asphere import Asphere

__all__ = ["GradientSurface"]


class GradientSurface(Asphere):
    """A conic surface whose medium after it is ``medium`` (a graded one).

    Args:
        curvature: ``c`` (1/mm).
        semi_diameter: mm.
        medium: the graded medium after the surface (the same object as the lens's material
            there).
        conic: conic constant.
    """

    def __init__(self, curvature: float, semi_diameter: float, medium, conic: float = 0.0):
        super().__init__(curvature, semi_diameter, conic=conic)
        object.__setattr__(self, "medium", medium)   # a reference, not a submodule
