"""deeplens: differentiable, memory-efficient ray tracing for end-to-end camera design.

Units: lengths in millimetres, wavelengths in nanometres, angles in degrees at user-facing
boundaries (lens files, reports) and radians inside misalignment parameters.
"""

__version__ = "0.1.0"
