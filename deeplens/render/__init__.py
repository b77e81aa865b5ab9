"""Rendering: sensor, scenes, backward Monte Carlo, forward splatting/PSFs, adjoint gradients."""

from .backward import MonteCarloRenderer
from .scene import IdealCamera, Scene, sample_texture
from .sensor import Sensor

__all__ = ["MonteCarloRenderer", "IdealCamera", "Scene", "sample_texture", "Sensor"]
