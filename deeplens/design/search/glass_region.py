r"""Real glasses of vendor catalogues on the glass map, the distance between glasses, and the
*glass region* a model glass must stay inside while a design is optimised.

Glass map coordinates.  A glass is the point ``(n_d, V_d)``, computed here from each real glass's
own dispersion formula exactly as :class:`~deeplens.optics.materials.ModelGlass` defines them::

    n_d = n(λ_d),    V_d = (n_d − 1) / (n(λ_F) − n(λ_C)),    λ_d, λ_F, λ_C = 587.5618, 486.1327,
    656.2725 nm

so a model glass placed at a real glass's ``(n_d, V_d)`` has that glass's index at the d line and
its Abbe number exactly.

Distance.  Between two glasses::

    δ = sqrt( (n_d − n_d')² + (w_V (V_d − V_d'))² ),     w_V = 0.01 by default

Why ``w_V ≈ 1/100``: a thin element's power is ``φ = (n_d − 1) K`` and its longitudinal colour
``φ / V_d``, so a change ``Δn_d`` changes the power by ``Δn_d / (n_d − 1)`` and a change ``ΔV_d``
changes the colour by ``ΔV_d / V_d`` (relative).  Equal relative effects need ``Δn_d ≈ ΔV_d
(n_d − 1) / V_d``, and at the middle of the glass map (``n_d − 1 ≈ 0.6``, ``V_d ≈ 60``) that is
``Δn_d ≈ ΔV_d / 100``.  The catalogues' spreads agree: ``n_d`` spans about 0.7 (1.41-2.14) and
``V_d`` about 85 (16-101).

Region.  The region of a catalogue set is the set of points within ``radius`` (in the distance
``δ``) of one of its real glasses, a union of disks, measured by a smooth nearest distance::

    D(p) = −τ log Σ_i exp(−sqrt(δ(p, g_i)² + ε²) / τ)          (τ = 0.002, ε = 1e-4)

``min_i δ_i − τ log N ≤ D ≤ min_i sqrt(δ_i² + ε²)``, so every real glass is inside (``D ≤ ε``),
a point inside has a real glass within ``radius + τ log N`` (0.044 for 1,000 glasses and the
default ``radius`` 0.03: ``Δn_d`` 0.03, or ``ΔV_d`` 3), and ``D`` is smooth (its gradient is
continuous; :meth:`GlassRegion.excess` is ``max(D − radius, 0)``).  Not a convex hull: the glass
map's upper edge (lanthanum glasses) is concave, and the convex hull of SCHOTT's glasses
includes points like ``n_d = 1.75, V_d = 60`` with no real glass within ``ΔV_d`` 10 (the
guide, docs/guide/design-search-glass.md, has the numbers).

Catalogues.  The six current vendor catalogues of :mod:`deeplens.optics.io.vendor_glass`
(``opticalglass``'s spreadsheets): SCHOTT, OHARA, HOYA, CDGM, HIKARI, SUMITA.  The spreadsheets
carry no production status (no "obsolete" or "inquiry" column; SCHOTT's remarks only say
"lead containing" or "suitable for precision molding"), so glasses are left out by name with
``exclude`` (``fnmatch`` globs, e.g. ``("*HT", "*HTI")``).  Tables are read once per process
(:func:`functools.lru_cache` on pure functions returning tuples).
"""

from __future__ import annotations

import fnmatch
import functools
import math
from typing import Iterable, NamedTuple

import torch

from ...optics.io.agf import AGFGlass
from ...optics.io.vendor_glass import VENDOR_CATALOGUES, _vendor_table, vendor_glass
from ...optics.materials import LINE_C, LINE_D, LINE_F

__all__ = ["CATALOGUES", "V_WEIGHT", "CatalogueGlass", "check_catalogues", "catalogue_glasses",
           "glasses", "glass_distance", "nearest_glasses", "GlassRegion"]

#: the catalogue names a glass search may choose from
CATALOGUES = tuple(VENDOR_CATALOGUES)

V_WEIGHT = 0.01
"""Default weight of ``ΔV_d`` against ``Δn_d`` in the glass distance (module docstring)."""


class CatalogueGlass(NamedTuple):
    """A real glass: its catalogue, name and ``(n_d, V_d)`` from its dispersion formula."""

    catalogue: str
    name: str
    n_d: float
    v_d: float

    @property
    def label(self) -> str:
        """``"CATALOGUE:NAME"``."""
        return f"{self.catalogue}:{self.name}"

    def material(self) -> AGFGlass:
        """A new material module of this glass (the catalogue's formula and coefficients)."""
        return vendor_glass(self.name, self.catalogue)


def check_catalogues(catalogues: str | Iterable[str]) -> tuple[str, ...]:
    """The catalogue names, upper case, each once, in the given order.

    Args:
        catalogues: one name (``"SCHOTT"``), a comma-separated string or an iterable of names.

    Raises:
        ValueError: an unknown name or none at all; the message lists the valid names.
    """
    if isinstance(catalogues, str):
        catalogues = [c for c in catalogues.split(",")]
    names = [str(c).strip().upper() for c in catalogues]
    names = [c for c in names if c]
    valid = ", ".join(CATALOGUES)
    if not names:
        raise ValueError(f"glass catalogues: none given; valid names: {valid}")
    bad = [c for c in names if c not in CATALOGUES]
    if bad:
        raise ValueError(f"unknown glass catalogue(s) {', '.join(map(repr, bad))}; valid "
                         f"names: {valid}")
    return tuple(dict.fromkeys(names))


@functools.lru_cache(maxsize=None)
def catalogue_glasses(catalogue: str) -> tuple[CatalogueGlass, ...]:
    """Every glass of one current vendor catalogue with ``(n_d, V_d)`` from its formula at the
    d, F and C lines (float64), in the catalogue's order.

    Raises:
        ValueError: an unknown catalogue (the message lists the valid names).
    """
    (cat,) = check_catalogues([catalogue])
    w = torch.tensor([LINE_D, LINE_F, LINE_C], dtype=torch.float64)
    out = []
    for name, formula, coefs in _vendor_table(cat).values():
        n_d, n_f, n_c = AGFGlass(name.upper(), formula, coefs, catalogue=cat).n(w).tolist()
        v_d = (n_d - 1.0) / (n_f - n_c)
        if math.isfinite(n_d) and math.isfinite(v_d) and v_d > 0:
            out.append(CatalogueGlass(cat, name.upper(), n_d, v_d))
    return tuple(out)


def glasses(catalogues, exclude: Iterable[str] = ()) -> tuple[CatalogueGlass, ...]:
    """The glasses of ``catalogues`` (see :func:`check_catalogues`) whose names match none of
    the ``exclude`` globs (case-insensitive).

    Raises:
        ValueError: an unknown catalogue; no glass left after ``exclude``.
    """
    cats = check_catalogues(catalogues)
    pats = [p.strip().upper() for p in ([exclude] if isinstance(exclude, str) else exclude)]
    out = tuple(g for c in cats for g in catalogue_glasses(c)
                if not any(fnmatch.fnmatchcase(g.name, p) for p in pats))
    if not out:
        raise ValueError(f"no glass of {', '.join(cats)} is left after exclude={pats}")
    return out


def _coords(n_d, v_d, v_weight: float) -> torch.Tensor:
    """``(..., 2)`` glass-map coordinates ``(n_d, w_V V_d)``."""
    n_d = torch.as_tensor(n_d, dtype=torch.float64) if not isinstance(n_d, torch.Tensor) else n_d
    v_d = torch.as_tensor(v_d, dtype=n_d.dtype) if not isinstance(v_d, torch.Tensor) else v_d
    n_d, v_d = torch.broadcast_tensors(n_d, v_d.to(n_d))
    return torch.stack([n_d, v_weight * v_d], -1)


def glass_distance(n_d, v_d, n_d2, v_d2, v_weight: float = V_WEIGHT) -> torch.Tensor:
    """``δ = sqrt(Δn_d² + (w_V ΔV_d)²)`` (module docstring), broadcast over the inputs."""
    a = _coords(n_d, v_d, v_weight)
    b = _coords(n_d2, v_d2, v_weight).to(a)
    return torch.linalg.vector_norm(a - b, dim=-1)


def nearest_glasses(n_d: float, v_d: float, catalogues, k: int = 5,
                    v_weight: float = V_WEIGHT, exclude: Iterable[str] = (),
                    distinct: bool = True) -> list[tuple[CatalogueGlass, float]]:
    """The ``k`` real glasses of ``catalogues`` nearest to ``(n_d, V_d)`` in the distance
    ``δ``, nearest first (ties in catalogue order), as ``(glass, δ)`` pairs.

    ``distinct``: skip a glass with exactly the ``(n_d, V_d)`` of one already listed (SCHOTT's
    ``N-BK7HT`` and ``N-BK7HTI`` are ``N-BK7`` with better transmission, the same formula).

    Raises:
        ValueError: an unknown catalogue (the valid names are listed), ``k < 1``, a
            non-finite point or a non-positive ``v_weight``.
    """
    if int(k) < 1:
        raise ValueError(f"k must be >= 1, got {k!r}")
    if not (math.isfinite(float(n_d)) and math.isfinite(float(v_d))):
        raise ValueError(f"model glass must be finite, got n_d={n_d!r}, V_d={v_d!r}")
    if not (math.isfinite(v_weight) and v_weight > 0):
        raise ValueError(f"v_weight must be a finite number > 0, got {v_weight!r}")
    pool = glasses(catalogues, exclude)
    pts = torch.tensor([(g.n_d, g.v_d) for g in pool], dtype=torch.float64)
    d = glass_distance(pts[:, 0], pts[:, 1], float(n_d), float(v_d), v_weight)
    out, seen = [], set()
    for i in torch.argsort(d, stable=True).tolist():
        key = (pool[i].n_d, pool[i].v_d)
        if distinct and key in seen:
            continue
        seen.add(key)
        out.append((pool[i], float(d[i])))
        if len(out) == int(k):
            break
    return out


class GlassRegion:
    """The glass region of a catalogue set: points within ``radius`` of a real glass (module
    docstring), with a smooth nearest distance for a penalty and a projection onto it.

    Args:
        catalogues: catalogue names (:func:`check_catalogues`).
        radius: the region's radius in the distance ``δ`` (``Δn_d`` units), > 0.
        v_weight: ``w_V`` of the distance.
        tau: smoothing length of the soft minimum (``Δn_d`` units), > 0.
        exclude: glass-name globs left out (:func:`glasses`).

    Attributes:
        glasses: the real glasses, ``points``: their ``(N, 2)`` coordinates ``(n_d, w_V V_d)``
        (float64, CPU; moved to the query's device and dtype on use).

    Raises:
        ValueError: an unknown catalogue or a bad number.

    Example:
        >>> region = GlassRegion("SCHOTT")
        >>> bool(region.contains(1.5168, 64.17)), bool(region.contains(1.3, 90.0))
        (True, False)
    """

    EPS = 1e-4

    def __init__(self, catalogues="SCHOTT", radius: float = 0.03, v_weight: float = V_WEIGHT,
                 tau: float = 0.002, exclude: Iterable[str] = ()):
        for what, v, lo in (("radius", radius, 2 * self.EPS), ("v_weight", v_weight, 0.0),
                            ("tau", tau, 0.0)):
            if not (math.isfinite(float(v)) and float(v) > lo):
                raise ValueError(f"glass region: {what} must be a finite number > {lo:g}, got "
                                 f"{v!r}")
        self.catalogues = check_catalogues(catalogues)
        self.radius, self.v_weight, self.tau = float(radius), float(v_weight), float(tau)
        self.glasses = glasses(self.catalogues, exclude)
        self.points = torch.tensor([(g.n_d, self.v_weight * g.v_d) for g in self.glasses],
                                   dtype=torch.float64)

    def __repr__(self) -> str:
        return (f"GlassRegion({'+'.join(self.catalogues)}, {len(self.glasses)} glasses, "
                f"radius={self.radius:g}, v_weight={self.v_weight:g})")

    def distance(self, n_d, v_d) -> torch.Tensor:
        """The smooth nearest distance ``D`` of ``(n_d, V_d)`` to the real glasses (module
        docstring); broadcast shape of the inputs, differentiable, on their device/dtype."""
        p = _coords(n_d, v_d, self.v_weight)
        g = self.points.to(p)
        d2 = ((p.unsqueeze(-2) - g) ** 2).sum(-1)                          # (..., N)
        d = torch.sqrt(d2 + self.EPS ** 2)
        return -self.tau * torch.logsumexp(-d / self.tau, dim=-1)

    def excess(self, n_d, v_d) -> torch.Tensor:
        """``max(D − radius, 0)``: how far outside the region (0 inside); differentiable."""
        return torch.relu(self.distance(n_d, v_d) - self.radius)

    def contains(self, n_d, v_d) -> torch.Tensor:
        """``D <= radius`` (a boolean tensor of the broadcast shape)."""
        return self.distance(n_d, v_d) <= self.radius

    def nearest(self, n_d: float, v_d: float) -> tuple[CatalogueGlass, float]:
        """The nearest real glass and its distance ``δ``."""
        p = _coords(float(n_d), float(v_d), self.v_weight)
        d = torch.linalg.vector_norm(self.points - p, dim=-1)
        i = int(torch.argmin(d))
        return self.glasses[i], float(d[i])

    def project(self, n_d: float, v_d: float) -> tuple[float, float]:
        """``(n_d, V_d)`` itself when inside, else the point at distance ``radius − ε`` from
        the nearest real glass towards it: inside, as ``D ≤ sqrt((radius − ε)² + ε²) ≤ radius``
        (the module docstring's bound; ``ε = 1e-4 < radius``)."""
        if bool(self.contains(float(n_d), float(v_d))):
            return float(n_d), float(v_d)
        g, d = self.nearest(n_d, v_d)
        t = (self.radius - self.EPS) / d
        return (g.n_d + t * (float(n_d) - g.n_d), g.v_d + t * (float(v_d) - g.v_d))
