"""One local refinement of a lens for a spec: stages of damped least squares.

A stage (:class:`Stage`) sets the curriculum (the entrance pupil at ``aperture`` times the
spec's, fields at ``field`` times the spec's), fits every refracting surface's semi-diameter to
the real beam (:func:`fit_semi_diameters`: the largest height of rim and chief rays of every
field and wavelength, times 1.05, + 0.1 mm; no vignetting), widens any gap whose edge then
falls short (:func:`repair_edges`), prepares the merit of :mod:`.problem` on
``sampling`` over the pupils the stop alone sets and runs ``steps`` DLS iterations (Jacobian by float64 central differences, the
cheapest for tens of variables, :mod:`deeplens.design.optimizers`).  While optimising, clear
apertures float with the beam (``TraceOptions(clip_aperture=False)``: no ray is clipped, so a
step is never rejected because the beam grew past a semi-diameter fitted a moment ago); the
semi-diameters are re-fitted after every stage, and the final evaluation clips at them.  Constraints are hard
(a trial step that breaks one is rejected) from the first stage that starts with all of them
met, soft (penalties only) before.  A stage that cannot start (a field fully vignetted,
surfaces that cross once the semi-diameters follow the beam) ends the refinement: the start
is then reported as failed, with the reason.

Each round of a stage (its ``rounds``, which re-find the pupils) first sizes the stop for the
EPD and projects the lens onto the constraints that can be met without changing its optics:
a stop that has slid into a neighbour's sag (its ``stop_gap`` constraint, which the stop's
growth on resizing alone can break) is shifted back by the shortfall (:func:`place_stops`),
and a centre thickness past its limit is set onto it; so the round can keep its constraints
hard rather than end a few µm infeasible (a double Gauss design at 9.5 µm was discarded for
a stop 0.10 mm inside the surface before it).  :func:`refine_to_convergence` runs rounds of
a few steps until :func:`run_to_convergence`'s relative stop rule ends them.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import torch

from ...analysis.spot import find_pupil
from ...optics.sampling import field_rays
from ...optics.surfaces import Aperture
from ...optics.camera import Camera
from ...optics.materials import Air
from ...optics.options import TraceOptions
from ..constraints import ConstraintSet, variable_bounds
from ..lensopt import optimize_lens
from .glass import project_model_glasses
from .imaging import repair_stop_gaps, stop_constraints
from .problem import real_surfaces, search_merit, search_variables, spec_constraints
from .spec import DesignSpec
from .start import solve_efl

__all__ = ["Stage", "RefineResult", "refine", "fit_semi_diameters", "set_curriculum",
           "repair_edges", "aspheric_choice", "place_stops", "run_to_convergence",
           "refine_to_convergence",
           "CURRICULUM", "STANDARD"]


#: trace options while optimising: clear apertures float with the beam (no clipping; the rays
#: fill the pupils the stop alone sets, found at each preparation), as in lens-design programs
_FLOATING = TraceOptions(clip_aperture=False)


@dataclass(frozen=True)
class Stage:
    """One stage: ``steps`` iterations of ``method`` (``"dls"``, or ``"lbfgs"``: quasi-Newton
    on the merit, which keeps converging where the least-squares model cannot, at a minimum
    with large residuals such as a singlet's least spherical aberration) on ``sampling``
    (split over ``rounds`` pupil re-samplings) at ``aperture`` x the EPD and ``field`` x the
    fields."""

    steps: int
    sampling: str = "hexapolar:6"
    aperture: float = 1.0
    field: float = 1.0
    rounds: int = 1
    method: str = "dls"


#: a flat start's curriculum: the aperture and field grown over the run
CURRICULUM = (Stage(8, "hexapolar:6", 0.3, 0.0), Stage(8, "hexapolar:6", 0.6, 0.5),
              Stage(12, "hexapolar:6", 1.0, 1.0))
#: a thin-lens start's refinement: the whole spec at once.  127 rays per field and wavelength
#: (hexapolar:6): on 37 (hexapolar:3) DLS fits the few rays it sees while the RMS spot of the
#: dense evaluation grows again (a Cooke start: 690 -> 422 -> 121 -> 273 µm over 3 x 20 steps);
#: the tracer's cost is per operation, not per ray, at these sizes
STANDARD = (Stage(12, "hexapolar:6"),)


@dataclass
class RefineResult:
    """``ok``: every stage ran; ``merit``: the last stage's final merit (its own sampling);
    ``history``: the merit after each accepted DLS step, over all stages; ``reason``: why it
    stopped (or failed); ``hard``: the constraints were hard in the last stage."""

    ok: bool
    merit: float = math.inf
    history: list = field(default_factory=list)
    reason: str = ""
    seconds: float = 0.0
    hard: bool = False
    steps: int = 0


def set_curriculum(lens, spec: DesignSpec, aperture: float = 1.0) -> None:
    """Size the stop for ``aperture`` x the spec's EPD (in place)."""
    lens.spec.aperture_type = "epd"
    lens.spec.aperture_value = aperture * spec.epd
    lens.apply_aperture_spec()


def fit_semi_diameters(lens, fields, waves, margin: float = 1.05, pad_mm: float = 0.1,
                       rim: int = 16) -> None:
    """Set every refracting surface's semi-diameter to the real beam's height there (module
    docstring), in place: the beam is the stop-limited pupil (traced) of every field, its rim
    and centre at every wavelength, traced with the other surfaces unclipped.

    Raises:
        ValueError: a field is fully vignetted (no ray passes the stop).
    """
    real = real_surfaces(lens)
    with torch.no_grad():
        saved = [lens.surfaces[i].semi_diameter.clone() for i in real]
        for i in real:
            lens.surfaces[i].semi_diameter.fill_(1e4)
        try:
            t = torch.arange(rim, dtype=lens.dtype) * (2 * math.pi / rim)
            unit = torch.cat([torch.zeros(1, 2, dtype=lens.dtype),
                              torch.stack([torch.sin(t), torch.cos(t)], -1)])
            reach = torch.zeros(len(lens.surfaces), dtype=torch.float64)
            primary = float(lens.spec.primary_wavelength_nm)
            for f in fields:
                reg = find_pupil(lens, f, primary, "traced", grid=33, bisections=16)
                for wl in waves:
                    rays = field_rays(lens, f, wl, reg.points(unit), reg.z)
                    out, hits = lens.trace(rays, record=True)
                    ok = out.valid
                    for i in real:
                        h = torch.linalg.vector_norm(hits[i][..., :2], dim=-1)[ok]
                        if h.numel():
                            reach[i] = torch.maximum(reach[i], h.max().double().cpu())
        except Exception:
            for i, v in zip(real, saved):
                lens.surfaces[i].semi_diameter.copy_(v)
            raise
        for i, v in zip(real, saved):
            s = lens.surfaces[i]
            sd = margin * float(reach[i]) + pad_mm if float(reach[i]) > 0 else float(v)
            c = abs(float(s.c)) if hasattr(s, "c") else 0.0
            if c > 0:
                sd = min(sd, 0.995 / c)
            s.semi_diameter.fill_(sd)


class _Normalised:
    """A merit whose residuals are divided by the root of its value at preparation, so that a
    gradient method starts at a merit of 1 whatever the design's scale (L-BFGS's first step
    and its stopping rule are absolute)."""

    def __init__(self, merit):
        self.merit, self.scale = merit, 1.0

    def prepare(self, lens):
        self.merit.prepare(lens)
        with torch.no_grad():
            r = self.merit.residuals(lens)
        self.scale = 1.0 / max(float(torch.sqrt((r * r).sum())), 1e-300)
        return self

    def residuals(self, lens):
        return self.merit.residuals(lens) * self.scale


def repair_edges(lens, spec: DesignSpec, margin_mm: float = 0.01) -> None:
    """Widen every gap between consecutive refracting surfaces whose centre or edge (at the
    smaller semi-diameter) is below the spec's minimum (``min_edge_glass_mm`` /
    ``min_center_glass_mm`` for glass, ``min_air_mm`` for air; 0 if none), by the shortfall +
    ``margin_mm``, in place: the edge-thickness solve of lens-design programs, needed after the
    semi-diameters grow with the beam."""
    real = real_surfaces(lens)
    with torch.no_grad():
        for p, q in zip(real, real[1:]):
            glass = not isinstance(lens.materials[p + 1], Air)
            need_e = (spec.min_edge_glass_mm if glass else spec.min_air_mm) or 0.0
            need_c = (spec.min_center_glass_mm if glass else spec.min_air_mm) or 0.0
            a, b = lens.surfaces[p], lens.surfaces[q]
            r = torch.tensor(min(float(a.semi_diameter), float(b.semi_diameter)),
                             dtype=lens.dtype)
            zero = torch.zeros_like(r)
            z = lens.z_vertices()
            centre = float(z[q] - z[p])
            edge = centre + float(b.sag(zero, r) - a.sag(zero, r))
            short = max(need_e - edge, need_c - centre)
            if short > 0:
                lens.distances[q].add_(short + margin_mm)


def place_stops(lens, spec: DesignSpec, aperture: float = 1.0, margin_mm: float = 2e-3,
                iterations: int = 4) -> None:
    """Move every stop that breaks its ``stop_gap`` constraint (:mod:`.imaging`) back between
    its neighbours, in place: the stop is resized for ``aperture`` x the spec's EPD (its
    semi-diameter follows the pupil, so a stop that met its constraint during a refinement,
    at the semi-diameter it had then, can break it once resized), and the stop alone is
    shifted within its air gap by the shortfall + ``margin_mm`` (``distances[k]`` and
    ``distances[k+1]`` change by opposite amounts: no lens moves), or, where the other side
    of the gap has less room than that, the short side is widened
    (:func:`~.imaging.repair_stop_gaps`).  Shifting the stop moves the pupils, hence its
    size; repeated up to ``iterations`` times, the stop resized each time.  The projection
    onto the stop's constraints that lets the next stage start with them met (and keep them
    hard), instead of leaving a design a few µm infeasible after its last stage."""
    with torch.no_grad():
        for _ in range(iterations):
            set_curriculum(lens, spec, aperture)
            short = [(c, -float(c.value(lens))) for c in stop_constraints(lens, 0.0)]
            short = [(c, s) for c, s in short if s > 0]
            if not short:
                return
            for c, s in short:
                k = int(c.label.split(".")[1])
                before = c.label.endswith("before")
                other = next((o for o in stop_constraints(lens, 0.0)
                              if o.label == f"stop_gap.{k}.{'after' if before else 'before'}"),
                             None)
                room = math.inf if other is None else float(other.value(lens))
                step = s + margin_mm
                if room >= step + margin_mm:   # the stop alone moves, the lens stays
                    sign = 1.0 if before else -1.0
                    lens.distances[k].add_(sign * step)
                    if k + 1 < len(lens.distances):
                        lens.distances[k + 1].sub_(sign * step)
                else:
                    repair_stop_gaps(lens, margin_mm)
        set_curriculum(lens, spec, aperture)


def _settle(lens, spec: DesignSpec) -> None:
    """A refinement's end (in place): the stop sized for the EPD and placed between its
    neighbours, semi-diameters fitted to the spec's full field, edges repaired, the stop moved
    within its gap if the repair made it cut a surface, the lens checked."""
    place_stops(lens, spec, 1.0)
    fit_semi_diameters(lens, spec.fields_deg, spec.wavelengths_nm)
    repair_edges(lens, spec)
    repair_stop_gaps(lens, stop_only=True)
    lens.check()


def _round(lens, spec, st: Stage, steps: int, aspheric_surfaces, efl_weight, flat: bool,
           glass_region):
    """One round of a stage: the stop sized and placed (:func:`place_stops`), semi-diameters
    fitted, edges repaired, constraints hard if they all hold, ``steps`` iterations; the EFL
    re-solved after.  Returns ``(LensOptResult, hard)``."""
    place_stops(lens, spec, st.aperture)
    fields = [st.field * f for f in spec.fields_deg]
    fit_semi_diameters(lens, fields, spec.wavelengths_nm)
    repair_edges(lens, spec)
    lens.check()
    cons = spec_constraints(lens, spec)
    solve = not flat
    v = search_variables(lens, aspheric_surfaces, efl_solve=solve,
                         glasses=glass_region is not None)
    # a centre thickness past its limit (a kick, the soft penalties of a stage before) is
    # projected onto it: the optimiser's box, where a hard stage keeps it (a thickness within
    # its limit's tolerance but past the limit itself would lie outside that box)
    lo, hi = variable_bounds(v, cons)
    x0 = v.x0()
    x = torch.minimum(torch.maximum(x0, lo), hi)
    if not torch.equal(x, x0):
        v.assign(x)
        repair_edges(lens, spec)
        lens.check()
    hard = not ConstraintSet(cons).broken(lens)
    merit = search_merit(spec, cons, sampling=st.sampling, field_scale=st.field,
                         efl_weight=efl_weight, efl_solve=solve, glass_region=glass_region)
    if st.method != "dls":
        merit = _Normalised(merit)
    out = optimize_lens(Camera(lens, None, _FLOATING), v, merit, method=st.method, steps=steps,
                        constraints=cons if hard else (), jacobian_mode="central")
    if glass_region is not None:
        project_model_glasses(lens, glass_region)
    if solve:
        solve_efl(lens, spec.efl_mm)
    return out, hard


def refine(lens, spec: DesignSpec, stages=STANDARD, aspheric_surfaces=(),
           efl_weight: float | None = None, flat: bool = False,
           glass_region=None) -> RefineResult:
    """Run ``stages`` on ``lens`` (float64; changed in place), see the module docstring.
    The focal length is held by the EFL solve (:class:`~.problem.EflSolved`), except in the
    first stage of a ``flat`` start (no power to solve from: a penalty then).

    ``glass_region`` (a :class:`~.glass_region.GlassRegion`): the lens's trainable model
    glasses are variables too, the merit gets the region's penalty, and after every stage any
    model glass left outside the region is projected onto it
    (:func:`~.glass.project_model_glasses`)."""
    t0 = time.perf_counter()
    res = RefineResult(ok=False)
    try:
        for st in stages:
            per = [st.steps // st.rounds + (1 if k < st.steps % st.rounds else 0)
                   for k in range(st.rounds)]
            for n in per:   # each round re-sizes the stop for the EPD before its pupils are
                # found (optimize_lens's own rounds would find them at the stop's old size,
                # and the entrance pupil drifts with the front group)
                if n == 0:
                    continue
                out, hard = _round(lens, spec, st, n, aspheric_surfaces, efl_weight, flat,
                                   glass_region)
                flat = False   # a flat start has power after its first stage
                res.history += [h["merit"] for h in out.history if h["accepted"]]
                res.merit, res.reason, res.hard = out.merit_after, out.reason, hard
                res.steps += out.steps
        _settle(lens, spec)
        res.ok = True
    except (ValueError, RuntimeError) as e:
        res.ok, res.reason = False, f"{type(e).__name__}: {e}"
    res.seconds = time.perf_counter() - t0
    return res


def run_to_convergence(step, *, tol: float, max_steps: int, chunk: int = 10,
                       patience: int = 2) -> tuple[float, int, str, list]:
    """The stop rule of a refinement run to convergence: ``step(n)`` runs ``n`` more
    iterations and returns ``(merit_before, merit_after, steps_done)`` (each chunk may
    re-prepare its merit, so a chunk's gain is measured on its own merit); chunks of
    ``chunk`` iterations run until ``patience`` consecutive chunks each lowered the merit by
    less than ``tol`` times their merit before (a relative rule: the same for any scale of the
    merit), until ``max_steps`` iterations, or until a chunk does no step (the optimiser
    stopped itself).

    Returns:
        ``(merit, steps, reason, merits)``: the final merit, the iterations run, why it
        stopped and the merit after each chunk.
    """
    if not (tol >= 0 and max_steps >= 0 and chunk >= 1 and patience >= 1):
        raise ValueError(f"run_to_convergence: tol, max_steps >= 0, chunk, patience >= 1, got "
                         f"{tol!r}, {max_steps!r}, {chunk!r}, {patience!r}")
    merit, done, flat, merits = math.nan, 0, 0, []
    while done < max_steps:
        before, merit, n = step(min(chunk, max_steps - done))
        before, merit = float(before), float(merit)
        merits.append(merit)
        done += n
        if n == 0:
            return merit, done, "the optimiser stopped", merits
        flat = flat + 1 if before - merit < tol * before else 0
        if flat >= patience:
            return merit, done, (f"converged: {patience} chunk(s) of {chunk} steps each "
                                 f"lowered the merit by less than {tol:g} of it"), merits
    return merit, done, f"reached the step limit ({max_steps})", merits


def refine_to_convergence(lens, spec: DesignSpec, sampling: str = "hexapolar:12", *,
                          tol: float = 0.01, max_steps: int = 120, chunk: int = 10,
                          aspheric_surfaces=(), glass_region=None) -> RefineResult:
    """DLS on ``lens`` (in place) in rounds of ``chunk`` steps on ``sampling`` (the stop
    placed and sized, pupils found, semi-diameters fitted, edges repaired before each, as in
    :func:`refine`) until :func:`run_to_convergence`'s rule stops it: a polish whose length
    follows the design (its number of variables, how far it is from its minimum) rather than
    a fixed count of steps.  A round that cannot start ends it: ``ok`` is then ``False``, and
    the lens keeps the last round's result."""
    t0 = time.perf_counter()
    res = RefineResult(ok=False)
    try:
        def step(n):
            out, hard = _round(lens, spec, Stage(n, sampling), n, aspheric_surfaces, None,
                               False, glass_region)
            res.history += [h["merit"] for h in out.history if h["accepted"]]
            res.hard = hard
            return out.merit_before, out.merit_after, out.steps

        res.merit, res.steps, res.reason, _ = run_to_convergence(
            step, tol=tol, max_steps=max_steps, chunk=chunk)
        _settle(lens, spec)
        res.ok = True
    except (ValueError, RuntimeError) as e:
        res.ok, res.reason = False, f"{type(e).__name__}: {e}"
    res.seconds = time.perf_counter() - t0
    return res


def aspheric_choice(lens, count: int) -> list[int]:
    """The ``count`` refracting surfaces with the largest sag at the rim (``|c| R^2``): where
    an aspheric term has the most to correct."""
    real = [i for i in real_surfaces(lens) if not isinstance(lens.surfaces[i], Aperture)]
    sag = {i: abs(float(lens.surfaces[i].c)) * float(lens.surfaces[i].semi_diameter) ** 2
           for i in real}
    return sorted(sorted(real, key=lambda i: -sag[i])[:count])
