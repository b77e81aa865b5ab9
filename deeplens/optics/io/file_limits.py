"""The magnitudes a lens file may hold, whatever its format (JSON, ``.zmx``): one place, so
that the readers agree and import no reader of another format."""

from __future__ import annotations

__all__ = ["MAX_CURVATURE_PER_MM", "MAX_LENGTH_MM"]

#: largest length (mm) a lens file may hold: beyond it paraxial quantities overflow (a 1e308 mm
#: thickness gave an EFL of -1e-305 mm)
MAX_LENGTH_MM = 1e12

#: largest curvature (1/mm) a lens file may hold: a radius of at least 1 / MAX_LENGTH_MM = 1e-12 mm
#: (beyond it squares of curvatures overflow: a curvature of 1e308 per mm gave an
#: ``OverflowError`` traceback)
MAX_CURVATURE_PER_MM = 1e12
