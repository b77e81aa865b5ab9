"""Classical lens design on the differentiable tracer: variables, merit functions, constraints,
optimisers (damped least squares, Adam, L-BFGS), sensitivity and Monte Carlo tolerancing.

Pure torch; builds on :mod:`deeplens.optics` and :mod:`deeplens.analysis` and is never imported
by them.
"""
