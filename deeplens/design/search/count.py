r"""Element count as a design variable: thinning and splitting, and the merit-vs-count trade.

A searched lens is a row of air-spaced singlets (:func:`elements`: two refracting surfaces with
glass between them and air after).  Element ``e`` has the thick-lens power

    φ_e = (n - 1) (c_1 - c_2) + (n - 1)^2 t c_1 c_2 / n

(``n`` at the primary wavelength, ``t`` its centre thickness) and meets the paraxial marginal
ray from infinity at height ``y_e`` (its first surface).  Its share of the system's power is
``φ_e y_e / (Φ y_1)`` (``Φ = sum φ_e y_e / y_1`` for thin elements); the element that
*contributes least* (:func:`contributions`) is the one with the smallest ``|φ_e y_e^2|``
(normalised by ``Φ y_1^2``): weak, or where the beam is narrow, it does the least bending of the
marginal ray and of its aberrations, which grow with ``y^2`` and more.

* **Thinning** (:func:`remove_element`, :func:`thin`): the least-contributing element is
  removed, the other surfaces keep their positions (its gap, glass and the gap after it become
  one air gap), the focal length is made exact again by the angle solve of the last refracting
  surface (:func:`~.start.solve_efl`), the sensor goes to the paraxial image and the lens is
  refined (:func:`~.refine.refine`) as a design of one element fewer.
* **Splitting** (:func:`split_element`, :func:`split`): the strongest element (largest
  ``|φ_e|``) becomes two copies of itself with every curvature halved (each of power ``φ_e /
  2`` to first order, the same shape factor ``(c_1 + c_2) / (c_1 - c_2)``), its centre
  thickness each, separated by the spec's minimum air gap (widened until the edge gap meets it
  too); everything behind moves back by the added length.  Two thin lenses ``φ / 2`` a reduced
  distance ``e`` apart have power ``φ - e φ^2 / 4``: the system's power is kept to first order
  in ``e``, and the angle solve then restores it exactly before the refinement.
* **The trade** (:func:`count_trade`): a search (:func:`~.multistart.search`) at the spec's
  element count, then thinning down and splitting up one element at a time to each count
  asked for, each step refined; per count the polychromatic RMS spot, the EFL and whether the
  spec's limits hold.  Deterministic for a seed (the search's Sobol starts and hops; thinning and
  splitting draw nothing).
"""

from __future__ import annotations

import copy
import dataclasses
import time

import torch

from ...optics.lens import Lens
from ...optics.materials import Air
from ...optics.paraxial import media_indices, paraxial, trace_paraxial_ray
from ...optics.surfaces import Aperture
from .imaging import repair_stop_gaps
from .refine import (STANDARD, aspheric_choice, fit_semi_diameters, refine, repair_edges,
                     set_curriculum)
from .result import evaluate
from .spec import DesignSpec
from .start import StartError, _sag, place_sensor, solve_efl

__all__ = ["elements", "element_powers", "contributions", "remove_element", "split_element",
           "thin", "split", "count_trade"]


def elements(lens) -> list[tuple[int, int]]:
    """``[(a, b), ...]``: the surface indices of each singlet (glass after ``a``, air after
    ``b``), object to image.

    Raises:
        ValueError: a refracting surface belongs to no singlet (a cemented group)."""
    out, i, n = [], 0, len(lens.surfaces)
    while i < n:
        if isinstance(lens.surfaces[i], Aperture) or isinstance(lens.materials[i + 1], Air):
            if not isinstance(lens.surfaces[i], Aperture):
                raise ValueError(f"surface {i} has air on both sides (not part of a singlet)")
            i += 1
            continue
        if i + 1 >= n or not isinstance(lens.materials[i + 2], Air):
            raise ValueError(f"surfaces {i}..{i + 1} are not a singlet in air (a cemented "
                             f"group or a lens ending in glass)")
        out.append((i, i + 1))
        i += 2
    return out


def element_powers(lens) -> tuple[list[float], list[float]]:
    """``(φ_e, y_e)`` per element (module docstring): thick-lens powers (1/mm) at the primary
    wavelength, and the marginal ray's height (mm, unit height at the first surface) there."""
    with torch.no_grad():
        n = media_indices(lens)
        one = torch.ones((), dtype=lens.dtype)
        _, _, hs = trace_paraxial_ray(lens, one, torch.zeros_like(one), n)
        phis, ys = [], []
        for a, b in elements(lens):
            ng = float(n[a + 1])
            c1, c2 = float(lens.surfaces[a].c), float(lens.surfaces[b].c)
            t = float(lens.distances[b])
            phis.append((ng - 1) * (c1 - c2) + (ng - 1) ** 2 * t * c1 * c2 / ng)
            ys.append(float(hs[a]))
    return phis, ys


def contributions(lens) -> list[float]:
    """``|φ_e y_e^2| / |Φ|`` per element (module docstring; ``y`` from unit height)."""
    phis, ys = element_powers(lens)
    power = abs(float(1.0 / paraxial(lens).efl))
    return [abs(p * y * y) / power for p, y in zip(phis, ys)]


def _rebuild(lens, surfaces, materials, distances, d_sensor, stop_index, name) -> Lens:
    out = Lens([copy.deepcopy(s) for s in surfaces], [copy.deepcopy(m) for m in materials],
               [float(d) for d in distances], float(d_sensor), stop_index,
               spec=copy.deepcopy(lens.spec), name=name)
    return out.to(lens.dtype)


def remove_element(lens, e: int) -> Lens:
    """A new lens without element ``e`` (index into :func:`elements`); the other surfaces
    and the sensor keep their positions, the stop its surface.  The focal length is *not*
    restored here (:func:`thin` does)."""
    els = elements(lens)
    if len(els) < 2:
        raise ValueError("a lens with one element has none to remove")
    a, b = els[e]
    S, M = list(lens.surfaces), list(lens.materials)
    D = [float(d) for d in lens.distances]
    merged = D[a] + D[b]                       # from the vertex before a to vertex b
    surfaces = S[:a] + S[b + 1:]
    materials = M[:a + 1] + M[b + 2:]
    d_sensor = float(lens.d_sensor)
    if b + 1 < len(S):
        distances = D[:a] + [merged + D[b + 1]] + D[b + 2:]
    else:
        distances, d_sensor = D[:a], d_sensor + merged
    if a == 0:                                  # the first vertex stays the origin
        distances[0] = 0.0
    stop = lens.stop_index - 2 if lens.stop_index > b else lens.stop_index
    return _rebuild(lens, surfaces, materials, distances, d_sensor, stop,
                    f"{lens.name} (element {e} removed)")


def split_element(lens, e: int, gap_mm: float = 0.2) -> Lens:
    """A new lens in which element ``e`` is two copies of itself with halved curvatures
    (module docstring), ``gap_mm`` of air apart at the centre and at least that at the
    edge; everything behind moves back by the added length."""
    a, b = elements(lens)[e]
    S, M = list(lens.surfaces), list(lens.materials)
    D = [float(d) for d in lens.distances]
    halves = []
    for _ in range(2):
        f, r = copy.deepcopy(S[a]), copy.deepcopy(S[b])
        with torch.no_grad():
            f.c.mul_(0.5)
            r.c.mul_(0.5)
        halves.append((f, r))
    h = min(float(S[a].semi_diameter), float(S[b].semi_diameter))
    edge = gap_mm + _sag(float(halves[1][0].c), h) - _sag(float(halves[0][1].c), h)
    gap = gap_mm + max(0.0, gap_mm - edge)
    surfaces = S[:a] + [halves[0][0], halves[0][1], halves[1][0], halves[1][1]] + S[b + 1:]
    materials = M[:a + 1] + [M[a + 1], M[b + 1], M[a + 1]] + M[b + 1:]
    distances = D[:a] + [D[a], D[b], gap, D[b]] + D[b + 1:]
    stop = lens.stop_index + 2 if lens.stop_index > b else lens.stop_index
    return _rebuild(lens, surfaces, materials, distances, float(lens.d_sensor), stop,
                    f"{lens.name} (element {e} split)")


@dataclasses.dataclass
class CountStep:
    """One design of the trade: ``elements``, how it was made (``origin``), the refinement's
    outcome (``ok``, ``reason``), the evaluation (``metrics``: :func:`~.result.evaluate`) and
    the lens."""

    elements: int
    origin: str
    ok: bool
    reason: str
    metrics: dict | None
    lens: object = None
    seconds: float = 0.0

    def row(self) -> dict:
        m = self.metrics or {}
        return {"elements": self.elements, "origin": self.origin, "ok": self.ok,
                "reason": self.reason, "rms_um": m.get("rms_um"), "efl_mm": m.get("efl_mm"),
                "feasible": m.get("feasible"), "broken": m.get("constraints_broken"),
                "total_track_mm": m.get("total_track_mm"),
                "seconds": round(self.seconds, 2)}


def _respec(spec: DesignSpec, n: int) -> DesignSpec:
    d = spec.to_dict()
    d["elements"] = n
    d["aspheres"] = min(spec.aspheres, 2 * n)
    return DesignSpec.from_dict(d)


def _finish(lens, spec: DesignSpec, origin: str, stages, t0: float) -> CountStep:
    """Angle solve, sensor at the paraxial image, refinement, evaluation (module docstring)."""
    try:
        for _ in range(2):   # halved curvatures move a rim towards a stop, whose opening
            set_curriculum(lens, spec, 1.0)   # (sized for the EPD) the solve changes
            repair_stop_gaps(lens)
            solve_efl(lens, spec.efl_mm)
        place_sensor(lens)
    except StartError as e:
        return CountStep(spec.elements, origin, False, f"StartError: {e}", None, lens,
                         time.perf_counter() - t0)
    res = refine(lens, spec, stages, aspheric_surfaces=aspheric_choice(lens, spec.aspheres))
    if res.ok:   # the refinement's last edge repair may move a gap: solve again (as a search
        try:     # design is finished), until the focal length holds
            for _ in range(3):
                solve_efl(lens, spec.efl_mm)
                fit_semi_diameters(lens, spec.fields_deg, spec.wavelengths_nm)
                repair_edges(lens, spec)
                repair_stop_gaps(lens)
                if abs(float(paraxial(lens).efl) / spec.efl_mm - 1.0) < 1e-9:
                    break
            lens.check()
        except (ValueError, RuntimeError) as e:
            res.ok, res.reason = False, f"{type(e).__name__}: {e}"
    metrics = evaluate(lens, spec) if res.ok else None
    return CountStep(spec.elements, origin, res.ok, res.reason, metrics, lens,
                     time.perf_counter() - t0)


def thin(lens, spec: DesignSpec, stages=STANDARD) -> CountStep:
    """Remove the least-contributing element of ``lens`` (:func:`contributions`), restore the
    focal length and refine for ``spec`` with one element fewer (module docstring)."""
    t0 = time.perf_counter()
    c = contributions(lens)
    e = min(range(len(c)), key=c.__getitem__)
    new = remove_element(lens, e)
    return _finish(new, _respec(spec, len(c) - 1), f"thinned (element {e} removed)", stages,
                   t0)


def split(lens, spec: DesignSpec, stages=STANDARD) -> CountStep:
    """Split the strongest element of ``lens`` (largest ``|φ_e|``) into two halves, restore
    the focal length and refine for ``spec`` with one element more (module docstring)."""
    t0 = time.perf_counter()
    phis, _ = element_powers(lens)
    e = max(range(len(phis)), key=lambda k: abs(phis[k]))
    new = split_element(lens, e, spec.min_air_mm or 0.2)
    return _finish(new, _respec(spec, len(phis) + 1), f"split (element {e})", stages, t0)


def count_trade(spec: DesignSpec, counts, config=None, stages=STANDARD, progress=None):
    """The merit-vs-count trade (module docstring): a search at ``spec.elements``, then thinning
    down to ``min(counts)`` and splitting up to ``max(counts)``, one element at a time.

    Returns:
        ``[CountStep, ...]`` sorted by element count (the searched design among them).

    Raises:
        ValueError: ``counts`` empty or outside 1..8.
    """
    from .multistart import search

    counts = sorted({int(n) for n in counts})
    if not counts or counts[0] < 1 or counts[-1] > 8:
        raise ValueError(f"count_trade: element counts in 1..8 needed, got {counts}")
    say = progress or (lambda text: None)
    t0 = time.perf_counter()
    res = search(spec, config)
    best = res.best
    base = CountStep(spec.elements, "searched", True, "", best.metrics, best.lens,
                     time.perf_counter() - t0)
    say(f"{spec.elements} elements (searched): {best.metrics['rms_um']:.4g} um")
    steps = [base]
    for direction, fn in ((-1, thin), (1, split)):
        cur, n = base, spec.elements
        while (n + direction) in range(counts[0], counts[-1] + 1) and cur.ok:
            sp = _respec(spec, n)
            cur = fn(copy.deepcopy(cur.lens), sp, stages)
            n += direction
            rms = cur.metrics["rms_um"] if cur.metrics else float("nan")
            say(f"{n} elements ({cur.origin}): {rms:.4g} um" + ("" if cur.ok else
                                                                f" ({cur.reason})"))
            steps.append(cur)
    return sorted((s for s in steps if s.elements in counts or s is base),
                  key=lambda s: s.elements)
