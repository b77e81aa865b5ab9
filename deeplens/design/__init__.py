"""Classical lens design on the differentiable tracer: variables, merit functions, constraints,
optimisers (damped least squares, Adam, L-BFGS), sensitivity and Monte Carlo tolerancing.

Pure torch; builds on :mod:`deeplens.optics` and :mod:`deeplens.analysis` and is never imported
by them.
"""

from .lensopt import optimize_lens
from .merit import Merit, SpotMerit
from .variables import Variables

# the names a first program needs; everything else from its module (deeplens.design.tolerance...)
__all__ = ["optimize_lens", "Merit", "SpotMerit", "Variables"]
