"""Paraxial analysis moved to :mod:`deeplens.optics.paraxial` (the lens itself needs it to size
its stop); this module re-exports it so that ``deeplens.analysis.paraxial`` keeps working."""

from ..optics.paraxial import ParaxialData, chief_ray_scale, exit_pupil, paraxial

__all__ = ["paraxial", "ParaxialData", "exit_pupil", "chief_ray_scale"]
