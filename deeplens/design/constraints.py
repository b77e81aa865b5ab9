"""Design constraints: thicknesses, track length, back focus, focal length, surface domains.

Each constraint has a differentiable value ``q(lens)`` (mm) and a limit ``b``:

    min:  q >= b,   penalty residual  w max(0, b - q)
    max:  q <= b,   penalty residual  w max(0, q - b)
    eq:   q == b,   penalty residual  w (q - b)

The gap between surfaces ``i`` and ``i + 1`` is measured on the axis (centre thickness
``t_i = distances[i + 1]``) and at the rim ``r = min(R_i, R_i+1)`` (edge thickness
``t_i + sag_{i+1}(r) - sag_i(r)``); it is *glass* when the medium after surface ``i`` is not
air, otherwise *air*.  Total track is first vertex to sensor; BFL and EFL are paraxial.

Inequality constraints are checked before optimising (:func:`check_start` raises
:class:`ConstraintError` naming each one that is unmet and by how much) and then kept: a trial step
that breaks one is rejected by the optimiser (:class:`~.optimizers.Infeasible`) and damped.  The
penalty residuals let a merit see constraints that are nearly active.  A constraint on a single
variable (the centre thickness of a gap whose distance is varied) also gives a simple bound
(:func:`variable_bounds`).

Command-line form ``NAME=VALUE`` (:func:`parse_constraint`): ``min_center_glass``,
``max_center_glass``, ``min_edge_glass``, ``min_center_air``, ``max_center_air``, ``min_edge_air``
(each for every gap of that kind, or ``NAME.I=VALUE`` for the gap after surface ``I`` only),
``max_track``, ``min_bfl``, ``max_bfl``, ``bfl``, ``efl`` (equalities: ``bfl``, ``efl``).
"""

from __future__ import annotations

import math

import torch

from ..optics.paraxial import paraxial
from ..optics.camera import unpack
from ..optics.materials import Air
from ..optics.surfaces import Aperture

__all__ = ["Constraint", "ConstraintError", "parse_constraint", "check_start", "variable_bounds",
           "CONSTRAINT_NAMES", "ConstraintSet"]

CONSTRAINT_NAMES = ("min_center_glass", "max_center_glass", "min_edge_glass", "min_center_air",
                    "max_center_air", "min_edge_air", "max_track", "min_bfl", "max_bfl", "bfl",
                    "efl")


class ConstraintError(ValueError):
    """Constraints unmet at the start of an optimisation (the message lists them)."""


def _edge_r(lens, i):
    a, b = lens.surfaces[i], lens.surfaces[i + 1]
    return min(float(a.semi_diameter), float(b.semi_diameter))


class Constraint:
    """One constraint (module docstring).

    Args:
        label: a readable name (``"min_edge_air.3"``).
        kind: ``"min"``, ``"max"`` or ``"eq"``.
        limit: ``b`` (mm).
        fn: ``lens -> q`` (a 0-d tensor, mm).
        weight: penalty weight (per mm).
        tol: violations up to ``tol`` mm are accepted (``eq`` is a target, never checked).
        gap: for thickness constraints, the index ``i`` of the gap after surface ``i``.
        where: ``"center"``/``"edge"`` for thickness constraints.
    """

    def __init__(self, label, kind, limit, fn, weight: float = 10.0, tol: float = 1e-9,
                 gap: int | None = None, where: str | None = None):
        if kind not in ("min", "max", "eq"):
            raise ValueError(f"constraint kind must be min, max or eq, got {kind!r}")
        if not math.isfinite(float(limit)):
            raise ValueError(f"constraint {label}: the limit must be a finite number, got "
                             f"{limit!r}")
        self.label, self.kind, self.limit, self.fn = label, kind, float(limit), fn
        self.weight, self.tol, self.gap, self.where = float(weight), float(tol), gap, where

    def value(self, lens) -> torch.Tensor:
        """``q`` of ``lens`` (a Lens, or a Camera: its lens; geometry, nothing is traced)."""
        return self.fn(unpack(lens)[0])

    def signed_violation(self, q) -> float:
        """How far ``q`` is outside the limit (mm; ``<= 0`` when met)."""
        q = float(q)
        if self.kind == "min":
            return self.limit - q
        if self.kind == "max":
            return q - self.limit
        return abs(q - self.limit)

    def violation(self, lens) -> float:
        with torch.no_grad():
            return max(0.0, self.signed_violation(self.value(lens)))

    def residual(self, lens) -> torch.Tensor:
        q = self.value(lens)
        if self.kind == "min":
            v = torch.relu(self.limit - q)
        elif self.kind == "max":
            v = torch.relu(q - self.limit)
        else:
            v = q - self.limit
        return (self.weight * v).reshape(1)

    def describe(self, lens) -> str:
        with torch.no_grad():
            q = float(self.value(lens))
        op = {"min": ">=", "max": "<=", "eq": "=="}[self.kind]
        v = self.signed_violation(q)
        state = f"unmet by {v:.6g} mm" if v > self.tol else "met"
        return f"{self.label}: {q:.6g} {op} {self.limit:.6g} ({state})"

    def __repr__(self):
        return f"Constraint({self.label} {self.kind} {self.limit:g})"


def _gaps(lens, kind):
    """Gap indices ``i`` (after surface ``i``) of the given kind ("glass" or "air"); gaps
    touching an aperture stop count as air gaps only when both sides are real surfaces."""
    out = []
    for i in range(len(lens.surfaces) - 1):
        glass = not isinstance(lens.materials[i + 1], Air)
        if kind == "glass" and glass:
            out.append(i)
        if kind == "air" and not glass:
            if isinstance(lens.surfaces[i], Aperture) or isinstance(lens.surfaces[i + 1],
                                                                     Aperture):
                continue
            out.append(i)
    return out


def center_thickness(i):
    return lambda lens: lens.distances[i + 1]


def edge_thickness(i):
    def fn(lens):
        r = _edge_r(lens, i)
        a, b = lens.surfaces[i], lens.surfaces[i + 1]
        rr = torch.tensor(r, dtype=lens.dtype)
        zero = torch.zeros_like(rr)
        return lens.distances[i + 1] + b.sag(zero, rr) - a.sag(zero, rr)

    return fn


def _track(lens):
    return lens.z_sensor() - lens.z_vertices()[0]


def parse_constraint(lens, text: str) -> list[Constraint]:
    """Constraints from ``NAME=VALUE`` or ``NAME.I=VALUE`` (module docstring).

    Raises:
        ValueError: an unknown name (the message lists the known ones), a value that is not a
            number, or a gap index that is not a gap of that kind.
    """
    if "=" not in text:
        raise ValueError(f"--constraint must be NAME=VALUE, got {text!r}; names: "
                         f"{', '.join(CONSTRAINT_NAMES)}")
    name, val = (s.strip() for s in text.split("=", 1))
    try:
        value = float(val)
    except ValueError:
        raise ValueError(f"--constraint {name}: the value must be a number of mm, got "
                         f"{val!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"--constraint {name}: the value must be finite, got {val!r}")
    base, _, idx = name.partition(".")
    if base not in CONSTRAINT_NAMES:
        raise ValueError(f"--constraint: unknown constraint {base!r}; known: "
                         f"{', '.join(CONSTRAINT_NAMES)}")
    if base in ("max_track", "min_bfl", "max_bfl", "bfl", "efl"):
        if idx:
            raise ValueError(f"--constraint {base} takes no surface index")
        kind = "eq" if base in ("bfl", "efl") else base[:3]
        if base == "max_track":
            return [Constraint("max_track", "max", value, _track)]
        q = base.split("_")[-1]
        return [Constraint(base, kind, value, lambda lens, q=q: getattr(paraxial(lens), q),
                           weight=10.0 / max(abs(value), 1e-9))]
    kind, where, medium = base.split("_")
    gaps = _gaps(lens, medium)
    if idx:
        try:
            i = int(idx)
        except ValueError:
            raise ValueError(f"--constraint {name}: the suffix must be a surface index") from None
        if i not in gaps:
            raise ValueError(f"--constraint {name}: the gap after surface {i} is not a {medium} "
                             f"gap; {medium} gaps follow surfaces {gaps}")
        gaps = [i]
    fn = center_thickness if where == "center" else edge_thickness
    return [Constraint(f"{base}.{i}", kind, value, fn(i), gap=i, where=where) for i in gaps]


class ConstraintSet:
    """Constraints as a merit term (penalty residuals) and as a feasibility test."""

    def __init__(self, constraints):
        self.constraints = list(constraints)

    def prepare(self, lens):
        return self

    def residuals(self, lens) -> torch.Tensor:
        if not self.constraints:
            return torch.zeros(0, dtype=unpack(lens)[0].dtype)
        return torch.cat([c.residual(lens) for c in self.constraints])

    def broken(self, lens) -> list[str]:
        """Descriptions of the inequality constraints unmet (beyond their ``tol``) on ``lens``."""
        return [c.describe(lens) for c in self.constraints
                if c.kind != "eq" and c.violation(lens) > c.tol]


def check_start(lens, constraints) -> None:
    """Raise :class:`ConstraintError` listing every inequality unmet on the starting lens."""
    bad = ConstraintSet(constraints).broken(lens)
    if bad:
        raise ConstraintError("constraint(s) unmet at the start, so the optimiser cannot keep "
                              "them: " + "; ".join(bad))


def variable_bounds(variables, constraints):
    """``(lower, upper)`` ``(n,)`` bounds on the scaled variables from the centre-thickness
    constraints whose distance is itself a variable (others are ``∓inf``)."""
    n = len(variables)
    lo = torch.full((n,), -math.inf, dtype=torch.float64)
    hi = torch.full((n,), math.inf, dtype=torch.float64)
    for c in constraints:
        if c.where != "center" or c.kind == "eq":
            continue
        name = f"distances.{c.gap + 1}"
        if name in variables.labels:
            j = variables.labels.index(name)
            b = c.limit * float(variables.scale[j])
            if c.kind == "min":
                lo[j] = max(float(lo[j]), b)
            else:
                hi[j] = min(float(hi[j]), b)
    return lo, hi
