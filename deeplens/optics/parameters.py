"""Lens parameters by name: selection by glob and their natural scale.

A parameter is named as in ``lens.named_parameters()``: ``surfaces.3.c`` (a curvature),
``surfaces.16.a.0`` (the a4 coefficient), ``surfaces.*.k``, ``distances.5``, ``d_sensor``,
``misalignments.2.tilt_x``.  :func:`select_names` / :func:`resolve_names` pick them by name or
``fnmatch`` glob (design variables, trainable lens parameters, tolerances: one rule, one
message).  :func:`parameter_scale` gives each one's scale, mm of sag at the rim per unit:

    s_j = ∂(sag at the rim) / ∂p_j

each surface type gives its own (:meth:`~.surfaces.Surface.sag_scale`, in the type's file):
a curvature scales by ``R^2 / 2`` (every type with one: sphere and asphere, odd asphere,
Zernike sag, biconic ``c`` and ``cx``, cylinder, toroid and Q-type), an even asphere ``a_2k``
by ``R^2k`` (an odd asphere's ``a_i`` by ``R^i``, a Zernike sag's even ``a[i]`` on ``r^(2i+2)``
by ``R^(2i+2)``, a cylinder's or toroid's ``a_2i`` on ``y^2i`` by ``R^2i``; Zernike and Q-type
coefficients are mm, scale 1), an XY coefficient of ``x^i y^j`` by ``R^(i+j)``, a conic ``k``
by ``∂z/∂k = c^3 R^4 / (2 q (1 + q)^2)`` (``q = sqrt(1 - (1+k) c^2 R^2)``), a toroid's radius
of rotation ``R_t`` by ``R^2 / (2 R_t^2)``; a tilt scales by the largest semi-diameter (mm of
rim displacement per rad); distances, decenters and B-spline heights are already mm, and
parameters that do not move the sag (a phase, a focal length) have scale 1.  ``R`` is the
surface's semi-diameter.  The design optimiser (:mod:`deeplens.design.variables`) and the
training step sizes (:mod:`deeplens.training.lens_setup`) use it.
"""

from __future__ import annotations

import fnmatch

__all__ = ["glob_names", "parameter_scale", "resolve_names", "select_names"]


def parameter_scale(lens, name: str) -> float:
    """mm of sag (at the rim) per unit of the parameter ``name`` (module docstring): a
    surface's parameter asks its surface (:meth:`~.surfaces.Surface.sag_scale`), a tilt is
    the largest semi-diameter, anything else (mm) is 1."""
    parts = name.split(".")
    if parts[0] == "surfaces":
        return lens.surfaces[int(parts[1])].sag_scale(".".join(parts[2:]))
    if parts[0] == "misalignments" and parts[-1].startswith("tilt"):
        return float(max(s.semi_diameter for s in lens.surfaces))
    return 1.0


def select_names(names, patterns, prefix: str, kind: str = "lens parameter") -> list[str]:
    """The entries of ``names`` matching ``patterns`` (names or ``fnmatch`` globs): in the
    order of the patterns, each glob's matches in ``names`` order, each name once.

    Raises:
        ValueError: ``"{prefix}{pattern!r} matches no {kind}; available: ..."``.
    """
    names = list(names)
    chosen = []
    for pat in patterns:
        hits = glob_names(names, pat, prefix, kind)
        chosen += [h for h in hits if h not in chosen]
    return chosen


def glob_names(names, pattern: str, prefix: str, kind: str = "lens parameter") -> list[str]:
    """The entries of ``names`` matching one ``pattern`` (a name or ``fnmatch`` glob).

    Raises:
        ValueError: nothing matches (the message lists ``names``, see :func:`select_names`).
    """
    hits = [n for n in names if fnmatch.fnmatchcase(n, pattern)]
    if not hits:
        raise ValueError(f"{prefix}{pattern!r} matches no {kind}; available: "
                         f"{', '.join(names)}")
    return hits


def resolve_names(lens, patterns, what: str = "--vary") -> list[str]:
    """Parameter names of ``lens`` matching ``patterns`` (names or ``fnmatch`` globs, or one
    comma-separated string), as :func:`select_names`.

    Raises:
        ValueError: no pattern given; a pattern matches nothing (the message lists the
            available names).
    """
    names = [n for n, _ in lens.named_parameters()]
    if isinstance(patterns, str):
        patterns = [p for p in patterns.split(",") if p.strip()]
    patterns = [p.strip() for p in patterns]
    if not patterns:
        raise ValueError(f"{what}: no variables given")
    return select_names(names, patterns, f"{what}: ")
