"""Backward (sensor-to-scene) rendering: the Monte Carlo renderer now lives in
:mod:`.monte_carlo` and the lens geometry it measures in :mod:`.geometry`; this module keeps the
old import path working."""

from .geometry import LensGeometry, lens_structure
from .monte_carlo import MonteCarloRenderer, RenderPlan

__all__ = ["MonteCarloRenderer", "RenderPlan", "LensGeometry", "lens_structure"]
