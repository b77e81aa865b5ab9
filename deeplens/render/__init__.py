"""Rendering: sensor, scenes, backward Monte Carlo, forward splatting/PSFs, adjoint gradients."""

from .geometry import LensGeometry
from .monte_carlo import MonteCarloRenderer, RenderPlan
from .scene import IdealCamera, Scene, sample_texture
from .sensor import Sensor

__all__ = ["MonteCarloRenderer", "RenderPlan", "LensGeometry", "IdealCamera", "Scene",
           "sample_texture", "Sensor"]
