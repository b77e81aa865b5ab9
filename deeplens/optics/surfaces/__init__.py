"""Optical surfaces, one type per file, all behind :class:`~.base.Surface`."""

from .aperture import Aperture
from .asphere import Asphere, Sphere
from .base import SURFACE_TYPES, SagSurface, Surface
from .binary1 import Binary1
from .binary2 import Binary2
from .biconic import Biconic
from .bspline import BSpline
from .coordinate_break import CoordinateBreak
from .cylinder import Cylinder
from .extended_odd_asphere import ExtendedOddAsphere
from .extended_polynomial import ExtendedPolynomial
from .fresnel import Fresnel
from .grating import Grating
from .grid_sag import GridSag
from .hologram import Hologram
from .ideal import IdealLens
from .ideal_xy import IdealLensXY
from .irregular import Irregular
from .lenslet_array import LensletArray
from .odd_asphere import OddAsphere
from .plane import Plane
from .qtype import QType
from .toroid import Toroid
from .xy_polynomial import XYPolynomial
from .zernike_phase import ZernikeFringePhase
from .zernike_sag import ZernikeFringeSag, ZernikeSag

__all__ = ["IdealLens", "IdealLensXY", "CoordinateBreak", "Aperture", "Asphere", "Sphere", "Biconic", "Binary1", "Binary2", "BSpline", "Cylinder", "ExtendedOddAsphere", "ExtendedPolynomial",
           "Fresnel", "Grating", "GridSag", "Hologram", "Irregular", "LensletArray", "OddAsphere", "Plane", "QType", "Toroid", "XYPolynomial", "ZernikeSag", "ZernikeFringeSag", "ZernikeFringePhase",
           "Surface", "SagSurface", "SURFACE_TYPES"]
