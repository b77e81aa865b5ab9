r"""A cheap prediction of a glass substitution's outcome, to rank many candidates before
re-optimising a few (issue 36, item 4).

For a design with residuals ``r(x)`` in its geometry variables ``x`` (curvatures, gaps, sensor
distance, the focal length held by the angle solve: :func:`~.problem.search_variables` and
:func:`~.problem.search_merit`), a candidate with real glasses put in at the same geometry
has residuals ``r_c`` (traced exactly: the real glass's whole dispersion, its partial
dispersions included, not only its ``(n_d, V_d)``).  Re-optimising the geometry, linearised
with the model design's Jacobian ``J = ∂r/∂x`` (central differences), reaches about::

    F_c ≈ min_x |r_c + J x|² + μ |x|²  =  Σ_i μ / (s_i² + μ) (u_iᵀ r_c)²  +  |r_c − U Uᵀ r_c|²

with ``J = U S Vᵀ`` (thin SVD) and ``μ = ridge · s_max²`` (a small damping: the linear model
is not trusted for steps along directions ``J`` barely sees).  One Jacobian (``2 n`` traces)
for the design, then one trace per candidate: ranking 64 candidates costs about what three
damped-least-squares steps cost, against 15 steps for each candidate re-optimised.
"""

from __future__ import annotations

import copy
from typing import Callable

import torch

from ...optics.camera import Camera
from ..lensopt import lens_residual_fn
from ..optimizers import jacobian
from ..variables import Variables
from .problem import search_merit, search_variables
from .refine import _FLOATING, set_curriculum
from .spec import DesignSpec

__all__ = ["linear_ranker", "linearised_ranker"]


def linear_ranker(lens, merit, variables: Variables, camera: Camera | None = None,
                  ridge: float = 1e-6) -> Callable:
    """``rank(candidate_lens) -> F_c`` of the module docstring for ``merit`` (already prepared
    on ``lens``: its ``residuals`` are read as they are) and the ``variables`` of ``lens`` (the
    geometry re-optimised), for candidates that differ from ``lens`` only in their media.

    Args:
        lens: the design (float64); ``variables`` must be of this lens.
        merit: an object with ``residuals(lens) -> (m,)`` (a prepared
            :class:`~deeplens.design.merit.Merit`).
        variables: :class:`~deeplens.design.variables.Variables` of ``lens``.
        camera: trace options for the merit (a Camera of ``lens``), as in
            :func:`~deeplens.design.lensopt.lens_residual_fn`.
        ridge: ``μ / s_max²``, ``>= 0``.

    Raises:
        ValueError: a negative ``ridge``.
    """
    if not ridge >= 0:
        raise ValueError(f"ridge must be >= 0, got {ridge!r}")
    _, J = jacobian(lens_residual_fn(variables, merit, camera=camera), variables.x0(),
                    "central")
    U, S, _ = torch.linalg.svd(J, full_matrices=False)
    mu = ridge * float(S[0]) ** 2 if S.numel() else 0.0
    keep = mu / (S ** 2 + mu) if mu > 0 else torch.zeros_like(S)
    opts = None if camera is None else camera.options

    def rank(cand) -> float:
        with torch.no_grad():
            r = merit.residuals(cand if opts is None else Camera(cand, None, opts)).to(U)
            c = U.T @ r
            perp = r - U @ c
            return float((perp @ perp) + (keep * c * c).sum())

    return rank


def linearised_ranker(lens, spec: DesignSpec, sampling: str = "hexapolar:6",
                      ridge: float = 1e-6) -> Callable:
    """:func:`linear_ranker` for a search design: the merit of :func:`~.problem.search_merit`
    on ``sampling`` (focal length by the angle solve, no constraints) and the geometry
    variables of :func:`~.problem.search_variables`, on a copy of ``lens`` at full aperture
    with floating clear apertures (as :func:`~.refine.refine` optimises).

    Raises:
        ValueError: a negative ``ridge``; the errors of the merit's preparation.
    """
    L = copy.deepcopy(lens)
    set_curriculum(L, spec, 1.0)
    cam = Camera(L, None, _FLOATING)
    merit = search_merit(spec, (), sampling=sampling, efl_solve=True)
    merit.prepare(cam)
    return linear_ranker(L, merit, search_variables(L, efl_solve=True), cam, ridge)
