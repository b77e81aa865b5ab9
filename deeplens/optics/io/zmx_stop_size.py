"""A stop with no semi-diameter under ``FLOA`` (float by stop size): the limiting aperture.

Under ``FLOA`` the entrance pupil floats on the stop's semi-diameter (its ``DIAM``, or a
``CLAP``'s radius).  Files written by other lens tools may omit the stop's ``DIAM`` while every
other surface has a fixed one (two real files of the unseen sets: the stop of a camera lens
exported without its iris size).  OpticStudio's pages at hand say only that under "float by
stop size" the stop's semi-diameter is entered in the Lens Data Editor and defines the beam
(Zemax knowledge base, *How to use Ray Aiming*); an automatic semi-diameter is "the radial
distance to the aperture required to pass all real rays" (User Guide, *Semi-Diameters*), which
for the stop of a floating pupil is circular: the file alone does not decide the beam.

The rule (:data:`STOP_SIZE` ``"limiting"``, the default): the stop floats to the largest
on-axis beam that the other surfaces' **fixed** apertures pass, as a real lens with its iris
opened fully -- the classical limiting-aperture search (the aperture stop is the surface whose
clear radius over the paraxial marginal ray's height is smallest; e.g. J. Greivenkamp, *Stops
and Pupils*, OPTI 201/202 notes, University of Arizona).  Found by paraxial marginal-ray
scaling: a paraxial ray from the axial object point (parallel to the axis at height 1 for an
object at infinity, slope 1 from the axis otherwise) is traced at the primary wavelength
through the lens; at every surface ``i`` whose semi-diameter the file fixes (``DIAM`` flag 1
or a ``CLAP``; not the stop, not a coordinate break) the ray may be scaled by ``m_i = r_i /
|y_i|``; the beam is the ray scaled by ``m = min_i m_i`` and the stop's semi-diameter is ``m
|y_stop|``.  Paraxial: a real marginal ray of that beam meets the limiting surface at a height
that differs by the surface's spherical aberration (rim rays there may be clipped).  One
located :class:`~deeplens.optics.errors.ZemaxWarning` at the stop's ``SURF`` line names the
value, the limiting surface and the flag that flips the rule; ``"refuse"`` refuses the file
there, as before.  Without any fixed semi-diameter to limit the beam the file is refused
either way.
"""

from __future__ import annotations

import math

import torch

__all__ = ["STOP_SIZE", "check_stop_size", "limiting_stop_radius"]

#: how a stop with no semi-diameter under ``FLOA`` is read: ``"limiting"`` (default) the
#: largest on-axis beam the other surfaces' fixed apertures pass, with one located warning;
#: ``"refuse"`` a located error
STOP_SIZE = ("limiting", "refuse")


def _fixed(block) -> bool:
    """Whether a ``SURF`` block fixes its semi-diameter (``DIAM`` flag 1 and > 0, or CLAP)."""
    return block.clap is not None or (block.diam_fixed and block.diam > 0)


def _limiting_candidates(seq) -> list[int]:
    """The kept indices of the surfaces that may limit the beam, in order: those whose
    semi-diameter the file fixes (:func:`_fixed`), not the stop, not a coordinate break."""
    return [i for i, (surf, _, b, _) in enumerate(seq.kept)
            if i != seq.stop_idx and i not in seq.autos and getattr(surf, "law", "") != "frame"
            and _fixed(b)]


def check_stop_size(seq, stop_size: str, p) -> None:
    """Under ``FLOA`` with a stop that has no semi-diameter (``seq.stop_idx in seq.autos``):
    refuse at the stop's ``SURF`` line with ``stop_size="refuse"``, or when no other surface
    fixes its semi-diameter; otherwise the stop floats to the limiting aperture once the lens is
    built (:func:`limiting_stop_radius`)."""
    blk = seq.kept[seq.stop_idx][2]
    base = ("the stop has no semi-diameter (no DIAM, or 0) and the system aperture is FLOA "
            "(float by stop size)")
    if stop_size == "refuse":
        p.fail(blk.line, f"{base}: refused (stop_size='refuse'); give the stop a DIAM or the "
                         f"system an ENPD/FNUM, or pass stop_size='limiting' (--stop-size "
                         f"limiting, the default) to float it to the largest on-axis beam the "
                         f"other surfaces' fixed apertures pass")
    if not _limiting_candidates(seq):
        p.fail(blk.line, f"{base}, and no other surface fixes its semi-diameter (DIAM flag 1 "
                         f"or CLAP) to limit the beam: give the stop a DIAM or the system an "
                         f"ENPD/FNUM")


def limiting_stop_radius(lens, seq, p, original: dict | None = None) -> tuple[float, int]:
    """``(r, i)``: the stop's semi-diameter (mm) of the largest on-axis paraxial beam the
    surfaces whose semi-diameter the file fixes pass, and the kept index ``i`` of the surface
    that limits it (module docstring).  ``original``: kept index -> the file's semi-diameter
    of a surface the reader has limited where it crosses its neighbour (the file's value is
    the one that sizes the beam; the reader then traces that gap backwards where the beam
    reaches past the crossing).  Refuses at the stop's line where the stop lies at an
    image of the object (the marginal ray's height there is 0) or no fixed surface meets the
    ray."""
    from ..paraxial import media_indices, trace_paraxial_ray

    k = seq.stop_idx
    blk = seq.kept[k][2]
    s = float(lens.spec.object_distance_mm)
    with torch.no_grad():
        one = torch.ones((), dtype=lens.dtype, device=lens.device)
        y0, u0 = (one, 0 * one) if math.isinf(s) else (s * one, one)
        _, _, heights = trace_paraxial_ray(lens, y0, u0, media_indices(lens))
        heights = [abs(float(h)) for h in heights]
    best, limit = math.inf, None
    for i in _limiting_candidates(seq):
        if not heights[i] > 0:
            continue
        m = (original or {}).get(i, float(lens.surfaces[i].semi_diameter)) / heights[i]
        if m < best:
            best, limit = m, i
    if limit is None or not heights[k] > 0:
        p.fail(blk.line, "the stop has no semi-diameter under FLOA (float by stop size) and the "
                         "largest on-axis beam the fixed apertures pass cannot size it (the stop "
                         "lies at an image of the object, or no fixed aperture meets the beam): "
                         "give the stop a DIAM or the system an ENPD/FNUM")
    return best * heights[k], limit
