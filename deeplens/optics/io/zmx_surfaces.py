"""One ``SURF`` block of a ``.zmx`` file -> one deeplens surface.

The block's ``TYPE`` names its handler in the file-format registry
(:data:`~.surface_formats.FORMATS`; the built-in handlers, one per surface type, and the
mapping of each Zemax type onto deeplens: :mod:`.surface_handlers`), which builds the surface;
what is common to every type is here: a flat surface between one medium, not the stop, with no
fixed aperture is a dummy (its thickness only); an automatic semi-diameter; ``SQAP`` on any type
(a rectangular clear aperture, :func:`~deeplens.optics.surfaces.base.set_clear_rect`), ``ELAP``
likewise (an elliptical one, :func:`~deeplens.optics.surfaces.base.set_clear_ellipse`), ``OBDC``
(the decenter of a ``CLAP``, ``SQAP`` or ``ELAP``), ``OBSC`` (a central obscuration) and ``ELOB``
(an elliptical obscuration about the vertex of a lens or mirror surface,
:func:`~deeplens.optics.surfaces.base.set_obscuration_ellipse`); ``SPID`` (a spider, on a flat
surface in air: an :class:`Aperture` with a :class:`~deeplens.optics.openings.Spider`).  Lengths are
scaled from file units to mm here (``s_mm``); errors are raised through the reader's
:class:`~.zmx_parse.Locator`.
"""

from __future__ import annotations

import dataclasses
import math

import torch

from ..errors import ZemaxFileError
from ..materials import Material
from ..surfaces import Aperture, Asphere, Cylinder, IdealLens, ZernikeSag
from ..surfaces.base import (check_conic_domain, clear_ellipse_of, clear_rect_of,
                            set_clear_ellipse, set_clear_rect, set_obscuration_ellipse,
                            set_obscuration_spider, takes_clear_rect)
from .surface_formats import ZmxContext
from .surface_handlers import FORMATS, PROVISIONAL_SD_MM, is_air
from .zmx_parse import Cause, Locator, ZmxSurface, literal

__all__ = ["build_surface", "is_air", "PROVISIONAL_SD_MM"]


def _lens_or_mirror(surf) -> bool:
    """Whether a surface aperture (``SQAP``, ``ELAP``, ``ELOB``, ``SPID``) goes on ``surf`` as a
    lens or mirror surface's: a surface the rays land on (:func:`takes_clear_rect`), other than
    an :class:`Aperture` (built with its own), a :class:`Cylinder` or an :class:`IdealLens`."""
    return takes_clear_rect(surf) and not isinstance(surf, (Aperture, Cylinder, IdealLens))


_CLAP_BEYOND = Cause(
    one="CLAP on {item}: the outer radius {detail}, which OpticStudio calls not physically "
        "meaningful; read with the DIAM as the outer edge (the annulus' inner radius kept)",
    many="CLAP on {n} surfaces ({items}): the outer radius lies beyond the surface's "
         "semi-diameter, which OpticStudio calls not physically meaningful; each read with the "
         "DIAM as the outer edge (the annulus' inner radius kept)")
_OBDC_ALONE = Cause(one="OBDC on {item}: the surface has no aperture (CLAP, SQAP, ELAP) to "
                        "decentre; ignored",
                    many="OBDC on {n} surfaces ({items}): no aperture (CLAP, SQAP, ELAP) to "
                         "decentre; ignored")


def _unbounded_annular_clap(s: ZmxSurface, k: int, p: Locator) -> None:
    """An annular ``CLAP lo hi`` whose outer radius lies beyond the surface's semi-diameter
    (``DIAM``; OpticStudio's Schmidt-Cassegrain sample: ``CLAP 4 1e10`` on its primary, no real
    outer radius): OpticStudio allows it but calls a surface aperture extending beyond the
    surface's semi-diameter not physically meaningful (User Guide, *Aperture (surface
    properties)*), so the outer radius gives way to the ``DIAM`` (fixed or automatic, as the
    file gives it) and ``lo`` stays the central hole, with a located note.  Taken as the
    semi-diameter, ``hi`` would put the surface beyond its conic's domain.  Only where the hole
    lies within the ``DIAM`` (``lo < DIAM < hi``): an annulus wholly beyond the ``DIAM`` keeps
    its radii.  Changes ``s``."""
    if s.clap is None or s.obsc is None or s.obsc[1] != s.clap[1] or not s.diam > 0:
        return   # not an annular CLAP (its hole is an OBSC on the CLAP's line), or no DIAM
    hi, ln = s.clap
    if not s.obsc[0] < s.diam < hi:
        return   # within the DIAM; or the whole annulus beyond it (its radii are then the
        # only sizes the file gives the opening: kept, as a CLAP 85 180 beside DIAM 72.5)
    p.note_each(ln, _CLAP_BEYOND, f"SURF {k}",
                f"{hi:g} lies beyond the surface's semi-diameter (DIAM {s.diam:g})",
                f"SURF {k}: CLAP {hi:g}, DIAM {s.diam:g}")
    s.clap = None


def _diam_cause(what: str) -> Cause:
    """A fixed ``DIAM`` ``what`` (``"beside an OBSC ..."``) that does not clip: one warning per
    file naming every such surface (``{detail}``: the one surface's ``DIAM``)."""
    why = ("in OpticStudio (its floating aperture is applied only on a surface with power and no "
           "surface aperture)")
    return Cause(one="{item}: the fixed DIAM {detail} " + literal(
                     f"{what} does not clip rays {why}; read with an automatic semi-diameter "
                     f"(the beam's extent): give the surface a CLAP to make it an opening"),
                 many="{n} surfaces ({items}): a fixed DIAM " + literal(
                     f"{what} does not clip rays {why}; each is read with an automatic "
                     f"semi-diameter (the beam's extent): give a surface a CLAP to make it an "
                     f"opening"))


#: a fixed DIAM beyond the edge of its conic, read at the edge (:func:`_fixed_diam_to_domain`)
_DIAM_BEYOND_EDGE = Cause(
    one="{item}: the fixed DIAM {detail} " + literal(
        "lies beyond the edge of its conic (r = |R| / sqrt(1 + k)); OpticStudio's floating "
        "aperture there (Semi-Diameters) clips no ray the surface keeps, since none meets it "
        "beyond its edge: read at the edge"),
    many="{n} surfaces ({items}): a fixed DIAM " + literal(
        "beyond the edge of its conic (r = |R| / sqrt(1 + k)); OpticStudio's floating aperture "
        "there (Semi-Diameters) clips no ray the surface keeps, since none meets it beyond its "
        "edge: each is read at the edge"))


def build_surface(s: ZmxSurface, k: int, mat: Material, prev: Material, s_mm: float,
                  folded: bool, p: Locator, qbfs_conic: str = "forbes"):
    """The surface of ``SURF k`` (block ``s``), between ``prev`` and ``mat``: ``(surface,
    auto)`` with ``auto`` whether its semi-diameter is automatic (to be set from real rays once
    the lens is built), or ``None`` for a dummy surface (only its thickness counts).  ``folded``:
    the lens has a fold or an off-axis section, where every semi-diameter not fixed is
    automatic.  ``qbfs_conic``: :data:`~.surface_formats.QBFS_CONIC`."""
    _check_ellipses(s, k, p)
    if (s.obdc is not None and s.clap is None and s.sqap is None and s.obsc is None
            and s.elap is None and s.elob is None):
        p.note_each(s.obdc[2], _OBDC_ALONE, f"SURF {k}")
        s.obdc = None
    _unbounded_annular_clap(s, k, p)
    c = s.curv / s_mm
    sd = s.diam * s_mm
    if s.clap is not None:
        sd = s.clap[0] * s_mm
    surf = None
    fixed = s.diam_fixed and s.diam > 0
    handler = FORMATS.for_zmx_type(s.type)   # the parser refused a type with no handler
    ctx = ZmxContext(k=k, c=c, sd=sd, sd_build=sd, s_mm=s_mm, mat=mat, prev=prev, fixed=fixed,
                     flat=False, p=p, qbfs_conic=qbfs_conic)
    flat = handler.zmx_flat(s, ctx)
    same_medium = (type(mat) is type(prev) and mat.name == prev.name)
    if (flat and same_medium and not s.stop and not fixed and s.clap is None
            and s.sqap is None and s.obsc is None and s.elap is None and s.elob is None
            and s.spid is None and not s.mirror):
        return None   # a dummy surface: its thickness only
    # OpticStudio applies a floating aperture (a circular aperture at the semi-diameter) for a
    # user-defined semi-diameter only on a surface with refractive power and no surface
    # aperture (OpticStudio User Guide, "Semi-Diameters"): on a surface in one medium, which has
    # no power, flat (a dummy, or an OBSC's plane in air) or curved (a secondary's shadow drawn
    # as an OBSC on a curved dummy in air), a fixed DIAM is drawn, never clips.  Only surfaces
    # that are a shape alone (SurfaceFormat.shape_only) lose their power in one medium: an
    # ideal lens, a phase, a grating or a hologram keeps it in air, and its fixed DIAM clips.  The surface is
    # kept (its place, its obscuration) with an automatic semi-diameter: the beam's extent
    if (fixed and same_medium and (flat or handler.shape_only) and not s.stop
            and not s.mirror and s.clap is None and s.sqap is None and s.elap is None):
        what = ("beside an OBSC (a surface aperture)" if s.obsc is not None else
                "beside an ELOB (a surface aperture)" if s.elob is not None else
                "beside a SPID (a surface aperture)" if s.spid is not None else
                f"of a {'flat' if flat else 'curved'} surface in one medium (no refractive "
                f"power) with no surface aperture (CLAP, SQAP, OBSC)")
        p.note_each(s.diam_line, _diam_cause(what), f"SURF {k}", f"{s.diam:g}")
        fixed = False
        sd = 0.0
        ctx = dataclasses.replace(ctx, sd=sd, fixed=False)
    if sd < 0:
        p.fail(s.line, f"SURF {k}: the semi-diameter (DIAM) must be >= 0, got {s.diam!r}")
    auto = not sd > 0     # no DIAM (or 0): an automatic semi-diameter, set once built
    if folded and not fixed and s.clap is None:
        auto = True
    sd_build = sd if sd > 0 else PROVISIONAL_SD_MM
    try:
        surf = handler.read_zmx(s, dataclasses.replace(ctx, sd_build=sd_build, flat=flat))
    except ZemaxFileError:
        raise   # already located (a helper's p.fail): not located twice
    except ValueError as e:
        p.fail(s.type_line or s.line, f"SURF {k}: {e}")
    if s.sqap is not None and _lens_or_mirror(surf) and s.clap is None and s.obsc is None:
        # a rectangular opening of a lens or mirror surface of any type the rays land on (an
        # off-axis mirror's, with OBDC; a TILTSURF's, an implicit XYPolynomial: the rectangle
        # is tested at the hit's local x, y, as OpticStudio's surface apertures are): the
        # rectangle, within its circumscribed circle; the semi-diameter encloses it
        hx, hy = s.sqap[0] * s_mm, s.sqap[1] * s_mm
        try:
            set_clear_rect(surf, (hx, hy))
        except ValueError as e:
            p.fail(s.sqap[2], f"SQAP on SURF {k}: {e}")
        if s.stop and sd > 0:
            # on the stop, the opening vignettes the pupil: a floating pupil (FLOA) keeps the
            # stop's DIAM as its radius, as OpticStudio sizes it, and an ENPD/FNUM/OBNA pupil
            # its own size; the rectangle clips within that circle
            with torch.no_grad():
                surf.semi_diameter.fill_(sd)
        auto = False
    if s.elap is not None and _lens_or_mirror(surf):
        # an elliptical opening of a lens or mirror surface of any type the rays land on, as
        # SQAP's rectangle: within its circumscribed circle, which the semi-diameter encloses
        try:
            set_clear_ellipse(surf, (s.elap[0] * s_mm, s.elap[1] * s_mm))
        except ValueError as e:
            p.fail(s.elap[2], f"ELAP on SURF {k}: {e}")
        if s.stop and sd > 0:   # as SQAP's: vignettes the pupil the system aperture gives
            with torch.no_grad():
                surf.semi_diameter.fill_(sd)
        auto = False
    if s.elob is not None and not isinstance(surf, Aperture):   # (an Aperture: built with it)
        if not _lens_or_mirror(surf):
            p.fail(s.elob[2], f"ELOB on SURF {k}: an elliptical obscuration on a "
                              f"{type(surf).__name__} surface is not supported (deeplens has "
                              f"elliptical obscurations on flat surfaces in air and on lens "
                              f"and mirror surfaces)")
        if auto:   # the obscuration is compared with the semi-diameter once that is set
            with torch.no_grad():
                surf.semi_diameter.fill_(max(float(surf.semi_diameter),
                                             1.01 * max(s.elob[:2]) * s_mm))
        try:
            set_obscuration_ellipse(surf, (s.elob[0] * s_mm, s.elob[1] * s_mm))
        except ValueError as e:
            p.fail(s.elob[2], f"ELOB on SURF {k}: {e}")
    if s.spid is not None and not isinstance(surf, Aperture):   # (an Aperture: built with it)
        # a spider on a lens or mirror surface, about its vertex, as an ELOB there
        if not _lens_or_mirror(surf):
            p.fail(s.spid[2], f"SPID on SURF {k}: a spider on a {type(surf).__name__} surface "
                              f"is not supported (deeplens has spiders on flat surfaces in air "
                              f"and on lens and mirror surfaces)")
        try:
            set_obscuration_spider(surf, (s.spid[0] * s_mm, s.spid[1],
                                          math.radians(s.spid_angle)))
        except ValueError as e:
            p.fail(s.spid[2], f"SPID on SURF {k}: {e}")
    if s.obdc is not None:   # the decenter of the opening (not on the stop)
        dec = _aperture_decenter(s, k, surf, s_mm, p)
        if isinstance(surf, Aperture):
            surf.decenter.copy_(torch.tensor(dec, dtype=surf.decenter.dtype))
        else:   # an off-axis segment of a lens or mirror surface: its CLAP or SQAP, moved
            rc = float(surf.clear_radius) if s.clap is None else s.clap[0] * s_mm
            with torch.no_grad():
                surf.clear_radius.fill_(rc)
                surf.clear_decenter.copy_(torch.tensor(dec, dtype=torch.float64))
                # the semi-diameter (the disc about the vertex the surface is defined on)
                # encloses the whole decentred opening
                surf.semi_diameter.fill_(math.hypot(*dec) + rc)
            try:
                surf.check(where=f"SURF {k} with its decentred clear aperture: ")
            except ValueError as e:
                p.fail(s.obdc[2], f"OBDC on SURF {k}: {e}")
    if s.obsc_inner is not None and not isinstance(surf, Aperture):
        what = "mirror" if s.mirror else ("flat surface between two media" if flat
                                          else "lens surface")
        p.fail(s.obsc_inner[1], f"SURF {k}: OBSC {s.obsc_inner[0]:g} {s.obsc[0]:g}, a ring "
                                f"obscuration (a baffle; minimum radius > 0), on a {what} "
                                f"({type(surf).__name__}) is not supported (deeplens has ring "
                                f"obscurations on flat surfaces in air: put the ring on its own "
                                f"flat dummy surface where that is equivalent)")
    if s.obsc is not None and isinstance(surf, (Asphere, ZernikeSag)):
        # a central obscuration on a lens or mirror surface (a secondary's shadow on a
        # Cassegrain's primary): an aperture property of the surface
        ro = s.obsc[0] * s_mm
        if not 0 < ro < float(surf.semi_diameter) and not auto:
            p.fail(s.obsc[1], f"SURF {k}: the obscuration radius {s.obsc[0]:g} must be > 0 "
                              f"and below the semi-diameter {s.diam:g}")
        if auto:   # the obscuration is compared with the semi-diameter once that is set
            with torch.no_grad():
                surf.semi_diameter.fill_(max(float(surf.semi_diameter), 1.01 * ro))
        surf.obscuration.fill_(ro)
    elif s.obsc is not None and not isinstance(surf, Aperture):
        what = (("flat mirror" if s.mirror else "flat surface between two media") if flat
                else ("mirror" if s.mirror else "lens surface"))
        rec = ("CLAP with a minimum radius (an annular clear aperture, whose inner circle is a "
               "central obscuration)" if s.clap is not None and s.clap[1] == s.obsc[1]
               else "OBSC, a central obscuration")
        p.fail(s.obsc[1], f"SURF {k}: {rec} on a {what} ({type(surf).__name__}), is not "
                          f"supported (deeplens has central obscurations on flat surfaces in "
                          f"air and on STANDARD, EVENASPH and Zernike sag lens and mirror "
                          f"surfaces: put the "
                          f"obscuration on its own flat dummy surface where that is "
                          f"equivalent)")
    if s.sqap is not None and not (isinstance(surf, Cylinder) or (
            isinstance(surf, Aperture) and surf.shape == "rect") or (
            clear_rect_of(surf) is not None)):
        extra = (" with a CLAP" if s.clap is not None else
                 " with an OBSC" if s.obsc is not None else "")
        p.fail(s.sqap[2], f"SQAP on SURF {k}: a rectangular aperture on a "
                          f"{type(surf).__name__} surface{extra} is not supported (deeplens has "
                          f"rectangular apertures on flat stops in air, on cylinders, and alone "
                          f"(no CLAP or OBSC) on any other lens or mirror surface, tilted "
                          f"planes and XY polynomials included)")
    if s.elap is not None and not (
            (isinstance(surf, Aperture) and surf.shape == "ellipse")
            or clear_ellipse_of(surf) is not None):
        p.fail(s.elap[2], f"ELAP on SURF {k}: an elliptical aperture on a {type(surf).__name__} "
                          f"surface is not supported (deeplens has elliptical apertures on flat "
                          f"surfaces in air and on any other lens or mirror surface, cylinders "
                          f"and ideal lenses excepted)")
    if auto and isinstance(surf, Aperture) and surf.shape in ("rect", "ellipse"):
        auto = False   # its semi-diameter is the rectangle's or ellipse's circumscribed circle
    if not (fixed or auto or s.stop) and s.clap is None and type(surf) is Asphere:
        _automatic_diam_in_domain(s, k, surf, s_mm, p)
    if fixed and not s.stop and s.clap is None and type(surf) is Asphere:
        _fixed_diam_to_domain(s, k, surf, s_mm, p)
    return surf, auto


def _fixed_diam_to_domain(s: ZmxSurface, k: int, surf: Asphere, s_mm: float,
                          p: Locator) -> None:
    """A fixed ``DIAM`` (flag 1) on a surface with power written beyond the edge of its conic (a
    sphere's ``r = |R|``): OpticStudio applies a floating aperture at that semi-diameter (User
    Guide, *Semi-Diameters*), which clips no ray the surface keeps, since no ray meets the
    surface beyond its edge (such a ray misses it either way).  Read at the edge, with one note
    at the ``DIAM`` line; rays are traced as before (a hemisphere's face, to its rim: the ball
    lens's rule, :func:`~deeplens.optics.surfaces.base.check_conic_domain`)."""
    c, kk = float(surf.c), float(surf.k)
    sd = float(surf.semi_diameter)
    try:
        check_conic_domain(sd, c, kk, "conic")
        return
    except ValueError:
        pass
    edge = (1.0 / ((1.0 + kk) * c * c)) ** 0.5
    with torch.no_grad():
        surf.semi_diameter.fill_(edge)
    try:   # on the rim, to rounding (the ball lens's band)
        check_conic_domain(edge, c, kk, "conic")
    except ValueError as e:
        p.fail(s.diam_line, f"SURF {k}: the fixed DIAM {s.diam:g} lies beyond the edge of its "
                            f"conic, and its edge {edge / s_mm:.17g} is not on the rim: {e}")
    p.note_each(s.diam_line, _DIAM_BEYOND_EDGE, f"SURF {k}",
                f"{s.diam:g} (read as {edge / s_mm:.6g})",
                f"SURF {k} ({s.diam:g} -> {edge / s_mm:.6g})")


def _automatic_diam_in_domain(s: ZmxSurface, k: int, surf: Asphere, s_mm: float,
                              p: Locator) -> None:
    """An automatic ``DIAM`` (flag 0) written beyond the edge of the surface's conic (a
    sphere's ``r = |R|``): OpticStudio's automatic semi-diameter is the radius "required to pass
    all real rays" (User Guide, *Semi-Diameters*), the footprint of the file's beam, and no ray
    meets the surface beyond its edge, so the saved value says rays of the file's beam pass
    outside the surface (they miss it).  Refused at the ``DIAM`` line, in one line naming the
    value, the edge and why (before: the domain error of the built lens)."""
    c, kk = float(surf.c), float(surf.k)
    try:
        check_conic_domain(s.diam * s_mm, c, kk, "conic")
    except ValueError:
        edge = (1.0 / ((1.0 + kk) * c * c)) ** 0.5 / s_mm
        p.fail(s.diam_line, f"SURF {k}: the automatic semi-diameter (DIAM flag 0) {s.diam:g} "
                            f"lies beyond the edge of the surface (r = {edge:g}; R = "
                            f"{1.0 / (c * s_mm):g}, k = {kk:g}): OpticStudio sized it for rays "
                            f"of the file's beam that pass outside the surface and miss it")


def _check_ellipses(s: ZmxSurface, k: int, p: Locator) -> None:
    """An ``ELAP`` or ``ELOB`` is the surface's one surface aperture (OpticStudio gives each
    surface one aperture type): beside a ``CLAP``, ``SQAP``, ``OBSC`` or the other ellipse
    record it is refused with its line, as ``SQAP`` is beside a ``CLAP`` or ``OBSC``; an
    ``OBDC`` does not move an ``ELOB`` (refused, as for an ``OBSC`` on a lens surface)."""
    for rec, key in ((s.elap, "ELAP"), (s.elob, "ELOB"), (s.spid, "SPID")):
        if rec is None:
            continue
        others = [name for name, r in (("CLAP", s.clap), ("SQAP", s.sqap), ("OBSC", s.obsc),
                                       ("ELAP", s.elap), ("ELOB", s.elob), ("SPID", s.spid))
                  if r is not None and name != key]
        if others:
            what = {"ELAP": "an elliptical aperture", "ELOB": "an elliptical obscuration",
                    "SPID": "a spider"}[key]
            p.fail(rec[2], f"{key} on SURF {k}: {what} "
                           f"together with {', '.join(others)} on one surface is not supported "
                           f"(OpticStudio gives a surface one aperture type; deeplens reads "
                           f"each alone)")
    if s.elob is not None and s.obdc is not None:
        p.fail(s.obdc[2], f"OBDC on SURF {k} with ELOB: a decentred elliptical obscuration is "
                          f"not supported (deeplens' elliptical obscurations are centred on the "
                          f"surface's vertex)")
    if s.spid is not None and s.obdc is not None:
        p.fail(s.obdc[2], f"OBDC on SURF {k} with SPID: a decentred spider is not supported "
                          f"(deeplens' spiders from .zmx are centred on the surface's vertex)")


def _aperture_decenter(s: ZmxSurface, k: int, surf, s_mm, p: Locator):
    """``OBDC x y``: the decenter (mm) of the surface's aperture: a ``CLAP`` (circular or
    annular) or ``SQAP`` on a flat surface in air (a deeplens :class:`Aperture`), or a circular
    ``CLAP`` or a ``SQAP`` on a lens or mirror surface (an :class:`Asphere`: an off-axis
    segment, such as an off-axis parabola's or an off-axis mirror's rectangular opening); never
    on the stop."""
    dx, dy, ln = s.obdc
    where = f"OBDC on SURF {k} (aperture decenter {dx:g}, {dy:g})"
    if s.clap is None and s.sqap is None and s.elap is None:   # an OBSC alone
        p.fail(ln, f"{where}: a decentred obscuration (OBSC) inside a centred semi-diameter is "
                   f"not supported (deeplens decentres a CLAP or SQAP opening, with its "
                   f"obscuration)")
    if s.stop:
        p.fail(ln, f"{where}: a decentred aperture stop is not supported (deeplens' entrance "
                   f"pupil is centred on the axis)")
    if not isinstance(surf, Aperture) and not (
            type(surf) is Asphere and [s.clap, s.sqap, s.elap].count(None) == 2
            and s.obsc is None):
        what = ("an annular or obscured" if s.obsc is not None else
                "a circular and rectangular (CLAP and SQAP)" if s.sqap is not None
                and s.clap is not None else "a")
        p.fail(ln, f"{where}: {what} decentred aperture on a lens or mirror surface "
                   f"({type(surf).__name__}) is not supported (deeplens decentres apertures on "
                   f"flat surfaces in air, and a circular CLAP or a rectangular SQAP on a "
                   f"STANDARD or EVENASPH lens or mirror surface: an off-axis segment)")
    return (dx * s_mm, dy * s_mm)
