"""What a camera needs of a searched lens beyond its RMS spot: a real stop and low distortion.

The search's merit (:mod:`.problem`) is the RMS spot about each field's polychromatic centroid,
which sees neither where a field's image lands nor where the stop physically sits.  Two
constraints close that gap for a lens handed to a camera (issue 36, the searched doublet):

* **The stop stays between its neighbours** (:func:`stop_constraints`, always on).  A stop is
  traced as a virtual plane (the ray line is tested where it crosses ``z_stop``, the ray is not
  moved), so with the gaps on both sides of it free a refinement can move the stop past a
  lens: a ``stop: front`` doublet came out with its first element 5.1 mm *in front of* the
  stop, the stop plane inside the second element's glass, which cannot be built (and its
  total track, measured from the stop, hid 5.1 mm).  ``stop_gap.<k>.before`` /
  ``stop_gap.<k>.after``: the refracting surface before (after) stop ``k`` lies at or before
  (after) the stop plane, at the vertex and at the stop's rim (the surface's sag at the stop's
  semi-diameter), ``>= 0`` mm.
* **Distortion** (:func:`distortion_constraint`, with ``DesignSpec.max_distortion_pct``): the
  largest ``|y_chief - κ tan θ| / (κ tan θ)`` over the spec's non-zero fields, in percent,
  ``<=`` the limit.  ``y_chief`` is the real chief ray (through the paraxial entrance pupil's
  centre, the primary wavelength) on the sensor and ``κ`` the paraxial chief-ray scale there
  (:func:`~deeplens.optics.paraxial.chief_ray_scale`), the mapping an ideal camera images the
  field angle ``θ`` to: the ground truth a camera's image is scored against
  (:class:`~deeplens.render.scene.IdealCamera`).  A barrel-distorted design (the doublet's:
  −4.9 % at 20°) is misregistered by pixels at the sensor's edge and its border pixels look
  beyond the scene, which no RMS spot counts.  Traced with clear apertures off (the chief ray
  is never clipped by a semi-diameter fitted before a step).
"""

from __future__ import annotations

import math

import torch

from ...optics.options import TraceOptions
from ...optics.paraxial import chief_ray_scale, paraxial
from ...optics.sampling import field_rays
from ...optics.surfaces import Aperture
from ..constraints import Constraint

__all__ = ["stop_constraints", "repair_stop_gaps", "distortion_pct", "distortion_constraint"]

#: the chief ray is traced without clear apertures (they follow the beam only between stages)
_UNCLIPPED = TraceOptions(clip_aperture=False)


def _stop_gap(k: int, j: int, before: bool):
    """``lens -> min over (vertex, rim) of the signed gap`` between stop ``k`` and surface
    ``j`` (mm; ``>= 0`` when ``j`` lies on its side of the stop plane)."""
    def fn(lens):
        z = lens.z_vertices()
        s = lens.surfaces[j]
        r = lens.surfaces[k].semi_diameter.detach().to(z)
        zero = torch.zeros_like(r)
        sag = s.sag(zero, r) if hasattr(s, "sag") else zero
        pts = torch.stack([z[j], z[j] + sag])
        gaps = z[k] - pts if before else pts - z[k]
        return gaps.min()
    return fn


def stop_constraints(lens, tol: float = 1e-3) -> list[Constraint]:
    """``stop_gap.<k>.before`` / ``.after`` (module docstring) for every stop ``k`` of
    ``lens`` with a refracting neighbour on that side; ``tol`` mm of violation accepted."""
    out = []
    n = len(lens.surfaces)
    for k, s in enumerate(lens.surfaces):
        if not isinstance(s, Aperture):
            continue
        prev = next((j for j in range(k - 1, -1, -1)
                     if not isinstance(lens.surfaces[j], Aperture)), None)
        nxt = next((j for j in range(k + 1, n) if not isinstance(lens.surfaces[j], Aperture)),
                   None)
        for j, side in ((prev, "before"), (nxt, "after")):
            if j is not None:
                c = Constraint(f"stop_gap.{k}.{side}", "min", 0.0,
                               _stop_gap(k, j, side == "before"))
                c.tol = tol
                out.append(c)
    return out


def repair_stop_gaps(lens, margin_mm: float = 1e-3, stop_only: bool = False) -> None:
    """Widen the gap on the short side of every stop whose ``stop_gap`` constraint is unmet
    (in place): the stop (and everything behind it) moves back, or the surface after it (and
    everything behind that), by the shortfall + ``margin_mm``; so that a refinement can start
    with the stop's constraints met, and keep them hard.  ``stop_only``: the stop alone moves
    within its gap (the gap on its other side shrinks by as much; the lenses and the image
    stay where they are), which leaves the focus and the track as they were."""
    with torch.no_grad():
        for c in stop_constraints(lens, 0.0):
            short = -float(c.value(lens))
            if short > 0:
                k = int(c.label.split(".")[1])
                before = c.label.endswith("before")
                if stop_only and 0 < k < len(lens.surfaces) - 1:
                    step = (short + margin_mm) * (1.0 if before else -1.0)
                    lens.distances[k].add_(step)
                    lens.distances[k + 1].sub_(step)
                    continue
                j = k if before else next(
                    i for i in range(k + 1, len(lens.surfaces))
                    if not isinstance(lens.surfaces[i], Aperture))
                lens.distances[j].add_(short + margin_mm)


def distortion_pct(lens, fields_deg, wavelength_nm: float) -> torch.Tensor:
    """Signed relative distortion ``(F,)`` in percent of the real chief ray at each field
    (degrees, non-zero) on the sensor (module docstring); differentiable in the lens.

    Raises:
        ValueError: a field's chief ray does not reach the sensor (the message names it).
    """
    fields = [float(f) for f in fields_deg]
    if not fields or any(f == 0.0 for f in fields):
        raise ValueError(f"distortion_pct: non-zero fields needed, got {fields}")
    z_img = lens.z_sensor()
    kappa = chief_ray_scale(lens, z_img, wavelength_nm)
    z_ep = float(paraxial(lens).entrance_pupil_z)
    xy = torch.zeros(1, 2, dtype=lens.dtype, device=lens.device)
    out = []
    for f in fields:
        c = lens.trace_to_sensor(field_rays(lens, f, wavelength_nm, xy, z_ep),
                                 options=_UNCLIPPED)
        if not bool(c.valid[0]):
            raise ValueError(f"distortion_pct: the chief ray of field {f:g} deg does not reach "
                             f"the sensor")
        ideal = kappa * math.tan(math.radians(f))
        out.append(100.0 * (c.o[0, 1] - ideal) / ideal)
    return torch.stack(out)


def distortion_constraint(spec, tol: float = 1e-3) -> Constraint:
    """``max_distortion``: the largest ``|distortion|`` (percent) over ``spec``'s non-zero
    fields ``<= spec.max_distortion_pct`` (module docstring); ``tol`` percent accepted.  A
    chief ray that misses the sensor counts as 100 %."""
    fields = [f for f in spec.fields_deg if f > 0]
    wl = float(spec.primary_wavelength_nm)

    def fn(lens):
        if not fields:
            return torch.zeros((), dtype=lens.dtype)
        try:
            return distortion_pct(lens, fields, wl).abs().max()
        except ValueError:
            return torch.full((), 100.0, dtype=lens.dtype)

    c = Constraint("max_distortion", "max", float(spec.max_distortion_pct), fn)
    c.tol = tol
    return c
