"""Deprecated alias of :mod:`deeplens.optics.paraxial` (paraxial analysis moved there: the lens
itself needs it to size its stop).  Importing this module warns once (``DeprecationWarning``)
and re-exports the same objects; it goes in the next release: import from
``deeplens.optics.paraxial``."""

import warnings

from ..optics.paraxial import ParaxialData, chief_ray_scale, exit_pupil, paraxial

warnings.warn("deeplens.analysis.paraxial is deprecated and will be removed in the next "
              "release: import from deeplens.optics.paraxial (the same objects)",
              DeprecationWarning, stacklevel=2)

__all__ = ["paraxial", "ParaxialData", "exit_pupil", "chief_ray_scale"]
