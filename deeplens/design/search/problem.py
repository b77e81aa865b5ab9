"""The optimisation problem of a spec on a lens: variables, merit and constraints.

Merit ``F = sum r^2`` over

* the polychromatic spot (:class:`~deeplens.design.merit.SpotMerit`, ``reference=
  "polychromatic"``): per field ``f`` and wavelength ``λ`` the rays' offsets from the field's
  polychromatic centroid, block weights ``w_fλ = sqrt(W_f W_λ / sum W_λ)`` (the spec's field and
  wavelength weights), so a field's blocks sum to ``W_f`` times its polychromatic mean square
  spot radius (mm²);
* the focal length, exact by a solve (:class:`EflSolved`: the last refracting curvature is
  not a variable but the angle solve's value at every trial point, as lens-design programs
  hold a focal length), or a penalty (:class:`FocalPower`): ``r = w (f / EFL - 1)``,
  ``w = f`` by default, so ``r ≈ EFL - f`` in mm (for a flat start, whose power ``1 / EFL``
  is near zero);
* the constraints (:mod:`deeplens.design.constraints` penalties ``w max(0, b - q)``), soft while
  a start is far from them and hard (a step breaking one is rejected) once they all hold.  Besides the spec's limits, every stop stays between its refracting neighbours
  (``stop_gap.*``, :mod:`.imaging`: a stop is traced as a virtual plane, so nothing else keeps
  it from sliding past a lens), and with ``max_distortion_pct`` the distortion is bounded.

Variables: the curvature of every refracting surface (but the last, with the solve), every
axial gap after the first vertex
(glass, air, both sides of the stop: the stop moves within its gap), the sensor distance, and
the conic, ``a4`` and ``a6`` of the surfaces given as aspheric.
"""

from __future__ import annotations

import contextlib
import math

import torch

from ...optics.paraxial import paraxial
from ...optics.camera import unpack
from ...optics.materials import Air
from ...optics.paraxial import media_indices, trace_paraxial_ray
from ...optics.surfaces import Aperture
from ..constraints import Constraint, parse_constraint
from ..merit import Merit, SpotMerit
from ..variables import Variables
from .spec import DesignSpec

__all__ = ["FocalPower", "EflSolved", "solved_curvature", "StopLimitedSpotMerit", "stop_limited", "spot_merit", "search_merit", "spec_constraints", "search_variables",
           "real_surfaces"]


#: a spec's limits hold within this (mm): the soft penalties of a refinement leave violations
#: of this order, which a hard limit would count against an otherwise good design
TOLERANCE_MM = 1e-3


def real_surfaces(lens) -> list[int]:
    """Indices of the refracting surfaces (not stops)."""
    return [i for i, s in enumerate(lens.surfaces) if not isinstance(s, Aperture)]


class FocalPower:
    """``r = weight (f / EFL - 1)`` (module docstring); ``lens`` may be a Camera."""

    def __init__(self, efl_mm: float, weight: float | None = None):
        self.efl = float(efl_mm)
        self.weight = self.efl if weight is None else float(weight)

    def prepare(self, lens):
        return self

    def residuals(self, lens) -> torch.Tensor:
        p = paraxial(unpack(lens)[0])
        return (self.weight * (self.efl / p.efl - 1.0)).reshape(1)


@contextlib.contextmanager
def stop_limited(lens):
    """Within the block, every refracting surface's semi-diameter is 10^4 mm (restored after):
    only the stop limits the beam, as with clear apertures that float with it."""
    real = real_surfaces(lens)
    saved = [lens.surfaces[i].semi_diameter.clone() for i in real]
    with torch.no_grad():
        for i in real:
            lens.surfaces[i].semi_diameter.fill_(1e4)
    try:
        yield lens
    finally:
        with torch.no_grad():
            for i, v in zip(real, saved):
                lens.surfaces[i].semi_diameter.copy_(v)


class StopLimitedSpotMerit(SpotMerit):
    """A :class:`~deeplens.design.merit.SpotMerit` whose pupil regions are those the stop
    alone sets (:func:`stop_limited`), found on the lens itself with default trace options, so
    that the rays an optimiser traces unclipped (``clip_aperture=False``) are the rays that
    pass the stop: no vignetting by the other surfaces, as designs are evaluated."""

    def prepare(self, lens) -> "StopLimitedSpotMerit":
        L = unpack(lens)[0]
        with torch.no_grad(), stop_limited(L):
            super().prepare(L)
        return self


def spot_merit(spec: DesignSpec, *, sampling: str = "hexapolar:4", field_scale: float = 1.0,
               strict_rays: bool = True, shrink: float = 0.98, pupil: str = "traced",
               **kw) -> SpotMerit:
    """The polychromatic spot term over the spec's fields (times ``field_scale``, for a
    curriculum) and wavelengths, with the weights of the module docstring, on the pupils the
    stop alone sets (:class:`StopLimitedSpotMerit`)."""
    W = torch.tensor(spec.wavelength_weights, dtype=torch.float64)
    Fw = torch.tensor(spec.weights_of_fields, dtype=torch.float64)
    w = torch.sqrt(Fw[:, None] * W[None, :] / W.sum())
    fields = [field_scale * f for f in spec.fields_deg]
    return StopLimitedSpotMerit(fields, list(spec.wavelengths_nm), weights=w, sampling=sampling,
                                reference="polychromatic", strict_rays=strict_rays,
                                shrink=shrink, pupil=pupil, **kw)


def search_merit(spec: DesignSpec, constraints=(), *, sampling: str = "hexapolar:4",
                 field_scale: float = 1.0, efl_weight: float | None = None,
                 efl_solve: bool = True, glass_region=None):
    """Spot + soft constraints on the EFL-solved lens (:class:`EflSolved`), or with
    ``efl_solve=False`` spot + focal-length penalty + soft constraints (module docstring);
    with a ``glass_region`` (:class:`~.glass_region.GlassRegion`) also its
    :class:`~.glass.GlassRegionPenalty` on the lens's model glasses."""
    from ..constraints import ConstraintSet

    terms = [spot_merit(spec, sampling=sampling, field_scale=field_scale)]
    if not efl_solve:
        terms.append(FocalPower(spec.efl_mm, efl_weight))
    if constraints:
        terms.append(ConstraintSet(constraints))
    if glass_region is not None:
        from .glass import GlassRegionPenalty

        terms.append(GlassRegionPenalty(glass_region))
    return EflSolved(Merit(*terms), spec.efl_mm) if efl_solve else Merit(*terms)


class _Holder(torch.nn.Module):
    def __init__(self, lens):
        super().__init__()
        self.lens = lens

    def forward(self, fn):
        return fn(self.lens)


def last_refracting(lens) -> int:
    return real_surfaces(lens)[-1]


def solved_curvature(lens, efl: float) -> torch.Tensor:
    """The last refracting surface's curvature that makes the paraxial EFL ``efl`` (the angle
    solve of :func:`~.start.solve_efl`), differentiable in every other parameter."""
    last = last_refracting(lens)
    name = f"lens.surfaces.{last}.c"
    c0 = lens.surfaces[last].c

    def parts(L):
        n = media_indices(L)
        one = torch.ones((), dtype=L.dtype, device=L.device)
        _, u0, hs = trace_paraxial_ray(L, one, 0 * one, n)
        return u0, hs[last], n[last], n[last + 1]

    u0, y, n1, n2 = torch.func.functional_call(_Holder(lens), {name: torch.zeros_like(c0)},
                                               (parts,), strict=False)
    return n2 * (u0 + 1.0 / efl) / (y * (n2 - n1))


class EflSolved:
    """A merit evaluated on the lens with its last refracting curvature given by the EFL solve
    (:func:`solved_curvature`): the focal length is exact at every trial point, so the
    optimiser never trades focal length for spot size and needs no stiff penalty (which would
    make the power direction 10^4 times stiffer than the bending one).  ``lens`` may be a
    Camera (its options reach the inner merit).  The soft constraint penalties inside the
    merit see the solved curvature; the hard-constraint test of
    :func:`~deeplens.design.lensopt.lens_residual_fn` sees the stored one (the last stage's
    solve), which differs from it only by the trial step's change of focal power."""

    def __init__(self, merit, efl: float):
        self.merit, self.efl = merit, float(efl)

    def _on(self, lens, what):
        L, _, options = unpack(lens)
        c = solved_curvature(L, self.efl)
        name = f"lens.surfaces.{last_refracting(L)}.c"

        def fn(Ls):
            from ...optics.camera import Camera
            return what(Ls if options is None else Camera(Ls, None, options))

        return torch.func.functional_call(_Holder(L), {name: c.to(L.surfaces[0].semi_diameter
                                                                 .dtype)}, (fn,), strict=False)

    def prepare(self, lens):
        with torch.no_grad():
            self._on(lens, self.merit.prepare)
        return self

    def residuals(self, lens) -> torch.Tensor:
        return self._on(lens, self.merit.residuals)


# ---------------------------------------------------------------------------- constraints
def _air_pairs(lens) -> list[tuple[int, int]]:
    """Consecutive refracting surfaces with air between them (a stop may sit in the gap)."""
    real = real_surfaces(lens)
    return [(p, q) for p, q in zip(real, real[1:]) if isinstance(lens.materials[p + 1], Air)]


def _gap_center(p, q):
    def fn(lens):
        z = lens.z_vertices()
        return z[q] - z[p]
    return fn


def _gap_edge(p, q):
    def fn(lens):
        z = lens.z_vertices()
        a, b = lens.surfaces[p], lens.surfaces[q]
        r = torch.tensor(min(float(a.semi_diameter), float(b.semi_diameter)), dtype=lens.dtype)
        zero = torch.zeros_like(r)
        return z[q] + b.sag(zero, r) - z[p] - a.sag(zero, r)
    return fn


def back_clearance(lens) -> torch.Tensor:
    """Sensor minus last refracting vertex (mm): the back focal distance as built."""
    return lens.z_sensor() - lens.z_vertices()[real_surfaces(lens)[-1]]


def paraxial_footprint(lens, hfov_deg: float) -> torch.Tensor:
    """The largest ``|y_marginal| + |y_chief|`` over the refracting surfaces (mm): the paraxial
    beam's semi-diameter (marginal ray from infinity at the EPD's rim, chief ray at ``hfov``
    through the entrance pupil's centre)."""
    p = paraxial(lens)
    n = media_indices(lens)
    one = torch.ones((), dtype=lens.dtype)
    _, _, ym = trace_paraxial_ray(lens, 0.5 * p.entrance_pupil_diameter * one, 0 * one, n)
    u = math.tan(math.radians(hfov_deg)) * one
    _, _, yc = trace_paraxial_ray(lens, -p.entrance_pupil_position * u, u, n)
    return torch.stack([ym[i].abs() + yc[i].abs() for i in real_surfaces(lens)]).max()


def spec_constraints(lens, spec: DesignSpec) -> list[Constraint]:
    """The spec's limits as :class:`~deeplens.design.constraints.Constraint` objects on this
    lens's layout (thicknesses of every glass and air gap, track, back clearance, diameter)."""
    out = []
    for name, v in (("min_center_glass", spec.min_center_glass_mm),
                    ("max_center_glass", spec.max_center_glass_mm),
                    ("min_edge_glass", spec.min_edge_glass_mm),
                    ("max_track", spec.max_track_mm)):
        if v is not None:
            out += parse_constraint(lens, f"{name}={v!r}")
    if spec.min_air_mm is not None:
        for p, q in _air_pairs(lens):
            out.append(Constraint(f"min_center_air.{p}", "min", spec.min_air_mm,
                                  _gap_center(p, q), gap=None, where=None))
            out.append(Constraint(f"min_edge_air.{p}", "min", spec.min_air_mm,
                                  _gap_edge(p, q)))
    if spec.min_bfl_mm is not None:
        out.append(Constraint("min_bfl", "min", spec.min_bfl_mm, back_clearance))
    if spec.max_diameter_mm is not None:
        out.append(Constraint("max_diameter", "max", 0.5 * spec.max_diameter_mm,
                              lambda L, h=spec.hfov_deg: paraxial_footprint(L, h)))
    for c in out:   # a design meets a limit within a micrometre (soft penalties leave less)
        c.tol = TOLERANCE_MM
    from .imaging import distortion_constraint, stop_constraints

    out += stop_constraints(lens, TOLERANCE_MM)   # the stop stays between its neighbours
    if spec.max_distortion_pct is not None:
        out.append(distortion_constraint(spec))
    return out


# ---------------------------------------------------------------------------- variables
def search_variables(lens, aspheric_surfaces=(), efl_solve: bool = True,
                     glasses: bool = False) -> Variables:
    """The variables of the module docstring (without the last refracting curvature when the
    EFL solve sets it); with ``glasses`` also the ``n_d`` and ``V_d`` of every trainable model
    glass (:func:`~.glass.glass_variable_names`, scaled as the glass distance:
    :func:`~.glass.glass_scales`)."""
    real = real_surfaces(lens)
    names = [f"surfaces.{i}.c" for i in (real[:-1] if efl_solve else real)]
    names += [f"distances.{j}" for j in range(1, len(lens.surfaces))]
    names.append("d_sensor")
    for i in aspheric_surfaces:
        names += [f"surfaces.{i}.k"] + [f"surfaces.{i}.a.{j}"
                                         for j in range(len(lens.surfaces[i].a))]
    if glasses:
        from .glass import glass_scales, glass_variable_names

        gnames = glass_variable_names(lens)
        if gnames:
            return Variables(lens, names + gnames, scales=glass_scales(lens))
    return Variables(lens, names)
