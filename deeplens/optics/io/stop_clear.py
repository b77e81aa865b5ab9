"""A flat stop in air whose clear aperture is narrower than the pupil the system aperture gives.

OpticStudio (a ``CLAP`` on the stop surface) and CODE V (a ``CIR`` on the stop) keep the pupil
the system aperture defines (``ENPD``/``FNUM``/``OBNA``, ``EPD``/``FNO``/``NA``: EPD, F-number,
paraxial data) and let the surface's clear aperture vignette its rim.  deeplens' lens or mirror
stop (:class:`~deeplens.optics.surfaces.Asphere`) holds that as two sizes: its semi-diameter is
the paraxial stop radius and its ``clear_radius`` the narrower opening.  An
:class:`~deeplens.optics.surfaces.Aperture` has one radius, so a flat stop in air is replaced by
a flat :class:`~deeplens.optics.surfaces.Asphere` (``c = 0`` between the same air: it refracts
no ray) that holds both (:func:`flat_stop_as_asphere`), as the readers already read a flat
mirror or flat face with a decentred opening.  The readers set its ``clear_radius`` and locate
any refusal at their own line.
"""

from __future__ import annotations

from ..surfaces import Aperture, Asphere

__all__ = ["plain_circular_stop", "flat_stop_as_asphere"]


def plain_circular_stop(stop) -> bool:
    """Whether ``stop`` is an :class:`Aperture` whose opening a flat :class:`Asphere` can hold:
    a centred circle, with at most a central obscuration (no rectangle or ellipse, ring
    baffle, elliptical obscuration, spider or decenter)."""
    return (type(stop) is Aperture and stop.shape == "circle" and not stop.decentred
            and float(stop.obscuration_inner) == 0.0
            and "obscuration_ellipse" not in stop._buffers and stop.spider_of() is None)


def flat_stop_as_asphere(lens) -> Asphere:
    """Replace ``lens``'s stop, a :func:`plain_circular_stop`, by a flat :class:`Asphere` of
    the same semi-diameter (mm; the paraxial stop radius the system aperture gave it) and
    central obscuration, with no clear aperture yet (the caller sets ``clear_radius``, mm), and
    return it.  Paraxial data do not change (a flat surface in one medium has no power); ray
    paths do not either, except that the new surface is *landed on* where the
    :class:`Aperture` was crossed (:meth:`~deeplens.optics.lens.Lens._cross_stop`).

    Raises:
        ValueError: the rays cannot land on it (a stop inside a neighbouring lens's sag: the
            lens check fails), or a gap traced backwards
            (:attr:`~deeplens.optics.lens.Lens.backward_gaps`) spans the stop; the lens is
            left as it was.
    """
    k = lens.stop_index
    old = lens.surfaces[k]
    if not plain_circular_stop(old):
        raise ValueError(f"the stop is a {type(old).__name__} with an opening a flat surface's "
                         f"clear aperture cannot hold")
    new = Asphere(0.0, float(old.semi_diameter), obscuration=float(old.obscuration))
    new = new.to(device=old.semi_diameter.device, dtype=old.semi_diameter.dtype)
    before = {q: a for a, q in lens._real_neighbours(across_breaks=True)}
    lens.surfaces[k] = new
    try:
        after = {q: a for a, q in lens._real_neighbours(across_breaks=True)}
        if any(after.get(j) != before[j] for j in lens.backward_gaps):
            raise ValueError("a gap traced backwards spans the stop")
        lens.check()
    except ValueError:
        lens.surfaces[k] = old
        raise
    return new
