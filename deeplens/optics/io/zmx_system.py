r"""First-order quantities of a lens read from a ``.zmx`` file, computed on the built lens.

* apertures given other than as an entrance-pupil diameter (object-space NA or cone angle, the
  paraxial working F-number) -> the EPD they define (:func:`aperture_to_epd`);
* field types -> field angles (:func:`fields_to_angles`): object heights, paraxial and real
  image heights (the chief ray bracketed and solved, :func:`real_image_height_angle`);
* OpticStudio's coordinate-break tilts ``R = R_x R_y R_z`` <-> deeplens' ``R_y R_x`` for a
  rotationally symmetric element (:func:`element_tilts`, :func:`zemax_tilts`);
* the pupil convention the file's ``RAIM`` line asks for (:func:`lens_pupil_convention`).

Errors go through the reader's ``p.fail(line, message)``, so they name the file and line.
"""

from __future__ import annotations

import math

import torch

from ..surfaces import (Aperture, Asphere, Biconic, Binary1, Cylinder, ExtendedOddAsphere,
                        ExtendedPolynomial,
                        OddAsphere, Plane, QType, XYPolynomial, ZernikeFringePhase, ZernikeSag)
from ..surfaces.grid_sag import GridSag

__all__ = ["aperture_to_epd", "chief_height", "chief_ray_stop", "real_image_height_angle",
           "rotationally_symmetric",
           "zemax_tilts", "element_tilts", "lens_pupil_convention", "fields_to_angles"]


def aperture_to_epd(lens, kind: str, value: float, line: int, p) -> float:
    """The entrance-pupil diameter (mm) of an aperture given as

    * ``obna``: object-space NA ``n sin θ`` of the marginal ray from the axial object point to
      the paraxial entrance pupil's rim, ``EPD = 2 |s + z_EP| tan θ`` (the convention optiland
      follows too);
    * ``cone``: that cone's half angle θ (degrees);
    * ``wfno``: the paraxial working F-number ``W = 1 / (2 n' |u'|)``, ``u'`` the image-space
      slope of the paraxial marginal ray (``W = EFL / EPD`` for an object at infinity in air).
    """
    from ..paraxial import media_indices, paraxial, trace_paraxial_ray

    with torch.no_grad():
        par = paraxial(lens)
        pos = float(par.entrance_pupil_position)
        s = float(lens.spec.object_distance_mm)
        n = media_indices(lens)
        if kind in ("obna", "cone"):
            if kind == "obna":
                n0 = float(n[0])
                if not value < n0:
                    p.fail(line, f"OBNA {value:g}: the numerical aperture must be below the "
                                 f"object-space index {n0:.6g}")
                theta = math.asin(value / n0)
            else:
                if not value < 90:
                    # a wider cone sends rays backwards from the object (a reflector around the
                    # source, OpticStudio's "320 degree light cone" sample): deeplens launches
                    # object rays forwards, at an entrance pupil in front of the object
                    p.fail(line, f"OBNA {value:g} (cone angle): must be below 90 degrees; a "
                                 f"wider cone sends rays backwards from the object, which "
                                 f"deeplens' forward object rays cannot carry")
                theta = math.radians(value)
            return 2.0 * abs(s + pos) * math.tan(theta)
        one = torch.ones_like(n[0])
        if math.isinf(s):
            y0, u0 = 1.0, 0.0          # per unit entrance-pupil radius
        else:
            u0 = 1.0 / (s + pos)
            y0 = u0 * s
        _, u, _ = trace_paraxial_ray(lens, y0 * one, u0 * one, n)
        g = abs(float(u))
        if not g > 0:
            p.fail(line, "FNUM (paraxial working F-number): the system is afocal")
        return 2.0 / (2.0 * float(n[-1]) * value * g)


def chief_height(lens, field_deg: float) -> float:
    """Image height (mm, on the sensor) of the chief ray at the primary wavelength: through the
    stop centre with ray aiming (the real chief ray), through the paraxial entrance pupil's
    centre without (as OpticStudio defines it in each case)."""
    from ..chief import chief_ray
    from ..options import TraceOptions
    from ..paraxial import paraxial
    from ..sampling import field_rays

    w = float(lens.spec.primary_wavelength_nm)
    with torch.no_grad():
        if lens.ray_aiming:
            return float(chief_ray(lens, field_deg, w)[0])
        z_ep = float(paraxial(lens).entrance_pupil_z)
        rays = field_rays(lens, field_deg, w, torch.zeros(1, 2, dtype=lens.dtype), z_ep)
        out = lens.trace_to_sensor(rays, options=TraceOptions(clip_aperture=False))
        return float(out.o[0, 1]) if bool(out.valid[0]) else math.nan


def chief_ray_stop(lens, field_deg: float):
    """Where the chief ray of ``field_deg`` (deg; the ray :func:`chief_height` traces, with the
    same apertures) stops: ``(surface index, why)``, ``why`` one of ``"misses"`` (its line
    never meets the surface's branch), ``"is totally reflected at"`` (it meets it, no refracted
    ray leaves) and ``"falls outside the clear aperture of"``; ``None`` where it reaches the
    last surface.  Traced surface by surface; each failure is told apart by tracing that
    surface once more without clear apertures, then without its law (``refract_=False``)."""
    from ..chief import chief_ray
    from ..options import TraceOptions
    from ..paraxial import paraxial
    from ..sampling import field_rays

    w = float(lens.spec.primary_wavelength_nm)
    free = TraceOptions(clip_aperture=False)
    opts = TraceOptions() if lens.ray_aiming else free   # as chief_height traces it
    with torch.no_grad():
        y_p = float(chief_ray(lens, field_deg, w)[1]) if lens.ray_aiming else 0.0
        z_ep = float(paraxial(lens).entrance_pupil_z)
        rays = field_rays(lens, field_deg, w, torch.tensor([[0.0, y_p]], dtype=lens.dtype), z_ep)
        z = lens.z_vertices()
        n = lens.indices(torch.tensor(w, dtype=lens.dtype))
        for i in range(len(lens.surfaces)):
            nxt = lens.trace_surface(i, rays, n[i], n[i + 1], z, opts)
            if bool(nxt.valid[0]):
                rays = nxt
                continue
            if bool(lens.trace_surface(i, rays, n[i], n[i + 1], z, free).valid[0]):
                return i, "falls outside the clear aperture of"
            if bool(lens.trace_surface(i, rays, n[i], n[i + 1], z, free,
                                       refract_=False).valid[0]):
                return i, "is totally reflected at"
            return i, "misses"
    return None


def real_image_height_angle(lens, h: float, line: int, p, *, y0: float = 0.0,
                            direction: float = 1.0, sigma: float = 1.0,
                            surface_name=None) -> float:
    """The field angle (deg, > 0) along ``direction`` (``+1``: positive angles, ``-1``: negative;
    the angle is ``direction`` times the value returned) whose chief ray lands ``h`` mm (> 0) from
    ``y0``, the image height of the axial field's chief ray (0 for a lens symmetric under
    ``y -> -y``; on a decentred or tilted lens it is not); ``sigma`` (:func:`slope_sign`) names
    the side of ``y0`` that positive angles land on, for the refusal's message.

    The root of ``g(θ) = |y_chief(direction θ) - y0| - h`` is bracketed first: the axis (``θ = 0``,
    height ``y0``) is the lower end, the first trial is the paraxial estimate ``h / slope``.  A trial whose
    chief ray fails (``NaN``: it misses a surface or is totally reflected, as far-off-axis rays
    of a wide-angle lens do beyond its field) is stepped back by bisection between the last
    good angle and the failing one; a trial still short of ``h`` steps forward by the scaling
    estimate (never past half-way to the smallest failing angle).  Inside the bracket,
    regula falsi (the Illinois variant), falling back to bisection where a trial fails.  A
    height no chief ray reaches is refused naming the last chief ray found and where the chief
    ray of the smallest failing angle stops (:func:`chief_ray_stop`; ``surface_name(i)``
    names lens surface ``i`` as the file does, e.g. ``"SURF 10 (line 140)"``)."""
    t0 = 1e-3
    slope = abs(chief_height(lens, direction * t0) - y0) / t0
    if not slope > 0:
        p.fail(line, "FTYP 3 (real image height): the chief ray does not reach the image")
    tol = 1e-12 * max(1.0, h)

    def g(theta: float) -> float:
        return abs(chief_height(lens, direction * theta) - y0) - h

    lo, glo = 0.0, -h          # below the height: the axis images at y0
    bad = 90.0                 # the smallest angle known to fail (90 deg never reaches)
    hi = ghi = None
    t = min(h / slope, 89.0)
    for _ in range(200):
        gt = g(t)
        if not math.isfinite(gt):
            bad, t = t, 0.5 * (lo + t)              # step back
        elif abs(gt) <= tol:
            return t
        elif gt < 0:
            lo, glo = t, gt                         # step forward
            t = min(max(lo * h / (glo + h), 1.05 * lo), 0.5 * (lo + bad))
        else:
            hi, ghi = t, gt
            break
        if bad - lo <= 1e-12 * bad:
            break
    if hi is None:
        up = direction * sigma   # the side of y0 where the chief rays of these angles land
        stop = chief_ray_stop(lens, direction * bad) if bad < 90.0 else None
        if stop is None:
            where = ("it misses a surface or is totally reflected" if bad < 90.0 else
                     "it would leave the object side at grazing incidence")
        else:
            name = surface_name(stop[0]) if surface_name else f"surface {stop[0]}"
            where = f"it {stop[1]} {name}"
        p.fail(line, f"FTYP 3 (real image height): no chief ray reaches image height "
                     f"{y0 + math.copysign(h, up):g} mm (the field lies beyond what the lens "
                     f"images: the chief ray of {direction * lo:.6g} deg lands at "
                     f"{y0 + math.copysign(glo + h, up):.6g} mm; from {direction * bad:.6g} deg on "
                     f"{where}){_beyond_90(g, lo, glo, h)}")
    side = 0
    for _ in range(200):
        if math.isfinite(ghi):
            t = (lo * ghi - hi * glo) / (ghi - glo)
            if not lo < t < hi:
                t = 0.5 * (lo + hi)
        else:
            t = 0.5 * (lo + hi)
        gt = g(t)
        if not math.isfinite(gt):
            hi, ghi, side = t, math.inf, 0          # a failing angle inside: bisect below it
        elif abs(gt) <= tol:
            return t
        elif gt < 0:
            lo, glo = t, gt
            if side == -1 and math.isfinite(ghi):
                ghi *= 0.5                          # Illinois: keep the far end moving
            side = -1
        else:
            hi, ghi = t, gt
            if side == 1:
                glo *= 0.5
            side = 1
        if hi - lo <= 1e-13 * hi:
            break
    if math.isfinite(ghi) and abs(ghi) < abs(glo):
        return hi
    return lo


def _beyond_90(g, lo: float, glo: float, h: float) -> str:
    """The refusal's tail where the chief ray's landing, carried on at its slope at ``lo`` (deg,
    the last angle found short of the height; ``glo = g(lo) < 0``, ``g`` the solver's residual),
    would reach the height only between 90 and 180 deg: a fisheye's field, which OpticStudio's
    field angles (to ±180 deg, User Guide *Field Angles and Heights*) allow and deeplens does
    not trace; ``""`` otherwise (an estimate, said so, never a reason to load)."""
    if not lo > 0:
        return ""
    d = 1e-3 * lo
    g2 = g(lo - d)
    slope = (glo - g2) / d if math.isfinite(g2) else math.nan   # mm per deg
    if not slope > 0:
        return ""
    est = lo - glo / slope
    if not 90.0 <= est <= 180.0:   # (beyond 180 deg: no field of OpticStudio's reaches it)
        return ""
    return (f"; at the chief ray's rate there ({slope:.3g} mm/deg) the height lies near "
            f"{est:.0f} deg, beyond the 90 deg deeplens traces (a fisheye's field)")


def slope_sign(lens, y0: float) -> float:
    """``+1`` where a small positive field angle's chief ray lands above ``y0`` (the axial
    field's chief-ray height), ``-1`` where below (an image turned over, as after an odd number
    of erecting stages), ``0`` where it does not move (afocal, or a failed trace)."""
    d = chief_height(lens, 1e-3) - y0
    return 1.0 if d > 0 else -1.0 if d < 0 else 0.0


def real_image_height_fields(lens, heights, line: int, p, surface_name=None) -> list[float]:
    """Field angles (deg) whose chief rays land at the real image heights ``heights`` (mm,
    signed: ``FTYP 3``, "the real ray coordinates of the primary wavelength chief ray on the
    image surface", OpticStudio User Guide, *Field Angles and Heights*).  The axial field's
    chief ray lands at ``y0`` (0 on a lens symmetric under ``y -> -y``); a height ``v`` is
    solved on the side of the axis whose chief rays move from ``y0`` towards it
    (:func:`real_image_height_angle`).  On a symmetric lens whose positive angles land above
    the axis this is ``±`` the angle of ``|v|``, bit for bit; a lens that turns the image over
    (positive angles landing below) or is decentred or tilted gets the angle whose chief ray
    lands at ``v`` itself (before branch ``objsign``: ``copysign(angle(|v|), v)``, and 0 for
    ``v = 0``, which there lands at ``-v`` or elsewhere)."""
    if not any(v != 0 for v in heights):
        return [0.0 for _ in heights]
    y0 = chief_height(lens, 0.0)
    if not math.isfinite(y0):
        p.fail(line, "FTYP 3 (real image height): the axial field's chief ray does not reach "
                     "the image")
    if abs(y0) <= 1e-12 * max(1.0, max(abs(v) for v in heights)):
        y0 = 0.0   # on the axis within the solver's tolerance (an aimed chief ray's rounding)
    sigma = slope_sign(lens, y0)
    if sigma == 0:
        p.fail(line, "FTYP 3 (real image height): the chief ray does not reach the image")
    out = []
    for v in heights:
        d = v - y0
        if d == 0:
            out.append(0.0)
            continue
        side = math.copysign(1.0, d * sigma)
        out.append(side * real_image_height_angle(lens, abs(d), line, p, y0=y0, direction=side,
                                                  sigma=sigma, surface_name=surface_name))
    return out


def rotationally_symmetric(surf) -> bool:
    """Whether a surface is unchanged by a turn about its own axis (for tilt conversions)."""
    if isinstance(surf, Aperture):
        return surf.shape == "circle"
    if getattr(surf, "diffracts", False) and not getattr(surf, "axisymmetric", False):
        return False   # a grating's lines turn with it (a radial phase does not)
    if isinstance(surf, ZernikeSag):
        return surf.rotationally_symmetric()
    return isinstance(surf, (Asphere, ExtendedOddAsphere, OddAsphere, Plane, QType))


def zemax_tilts(ta: float, tb: float) -> tuple[float, float]:
    """deeplens' tilts (deg) as OpticStudio's x-then-y tilts (deg) that point a rotationally
    symmetric element's axis the same way (the inverse of :func:`_element_tilts`)."""
    a, b = math.radians(ta), math.radians(tb)
    alpha = math.atan2(math.sin(a), math.cos(b) * math.cos(a))
    beta = math.asin(max(-1.0, min(1.0, math.sin(b) * math.cos(a))))
    return math.degrees(alpha), math.degrees(beta)


def element_tilts(d, kept, line, p):
    """Zemax's decenter and tilts ``(dx, dy, α, β, γ)`` (order 0: decenter, then tilts about x,
    the new y and the new z: ``R = R_x(α) R_y(β) R_z(γ)``) as deeplens' ``(dx, dy, a, b)`` with
    ``R' = R_y(b) R_x(a)`` (degrees).  For an element that is rotationally symmetric about its
    own axis only that axis, ``R e_z = (sin β, −sin α cos β, cos α cos β)``, matters, and
    ``R' e_z`` equals it for ``a = asin(sin α cos β)``, ``b = atan2(sin β, cos α cos β)``
    (exact; ``γ`` turns the element about its axis).  One tilt maps onto itself."""
    dx, dy, ta, tb, tg = d
    if (ta != 0 and tb != 0) or tg != 0:
        for surf, _, s, _ in kept:
            if not rotationally_symmetric(surf):
                p.fail(line, f"a COORDBRK with tilts about two axes (or about z) around a "
                             f"surface that is not rotationally symmetric (SURF on line "
                             f"{s.line}) is not supported")
    a, b = math.radians(ta), math.radians(tb)
    ta2 = math.degrees(math.asin(max(-1.0, min(1.0, math.sin(a) * math.cos(b)))))
    tb2 = math.degrees(math.atan2(math.sin(b), math.cos(a) * math.cos(b)))
    return (dx, dy, ta2, tb2)


def lens_pupil_convention(lens) -> str:
    """The pupil sampling that matches how the file's author saw the lens: ``"traced"`` (real
    rays that fill the stop) where the file asks for ray aiming (``RAIM`` type 1 or 2),
    ``"paraxial"`` (rays aimed at the paraxial entrance pupil, OpticStudio without ray aiming)
    where it does not; ``"traced"`` for a lens that did not come from a ``.zmx`` file."""
    return "traced" if getattr(lens, "ray_aiming", True) else "paraxial"


def _drop_sideways_fields(xs, ys, xline: int, yline: int, p):
    """The fields (``FTYP 0``, deg) whose x and y angles both lie within (-90, 90) deg; each
    one left out (90 deg or more in x or y) is named in one located note at its ``YFLN`` or
    ``XFLN`` line.  OpticStudio's field angles run "fully in the range of -180 to 180 degrees",
    the chief ray's axial direction cosine ``n`` negative beyond 90 deg (User Guide, *Field
    Angles and Heights*): a fisheye's field arriving sideways (90 deg) or from behind the lens.
    deeplens launches a field's rays towards ``+z`` from a plane in front of the lens (field
    angles within (-90, 90) deg), so it cannot trace them; the lens and its other fields are
    read.  (Before, 90 deg was refused by the lens's generic range check and 109 deg read as
    71 deg without a word: the radial combination takes ``atan`` of ``|tan 109 deg|``.)
    Returns ``(xs, ys)`` without those fields; where no field is left the file is refused at
    its ``YFLN`` line (an on-axis field the file does not have is not made up)."""
    keep = [abs(x) < 90.0 and abs(y) < 90.0 for x, y in zip(xs, ys)]
    if not any(keep):   # nothing left to read the lens with: say so, do not invent a field
        p.fail(yline or xline, f"every field lies at or beyond 90 deg (YFLN "
                               f"{', '.join(f'{v:g}' for v in ys)}; XFLN "
                               f"{', '.join(f'{v:g}' for v in xs)}): OpticStudio traces such "
                               f"fields arriving sideways or from behind the lens (Field Angles "
                               f"and Heights); deeplens traces fields within (-90, 90) deg only")
    for vals, rec, line in ((ys, "YFLN", yline), (xs, "XFLN", xline)):
        bad = [(k, v) for k, v in enumerate(vals, 1) if not abs(v) < 90.0]
        if bad:
            which = ", ".join(f"field {k} ({v:g} deg)" for k, v in bad)
            p.note(line, f"{rec}: {which} not read: OpticStudio traces a field at or beyond "
                         f"90 deg arriving sideways or from behind the lens (angles run to "
                         f"±180 deg, Field Angles and Heights), deeplens traces fields within "
                         f"(-90, 90) deg only; the lens is read with its other fields")
    return [x for x, k in zip(xs, keep) if k], [y for y, k in zip(ys, keep) if k]


def fields_to_angles(sysd, ftyp, ftyp_line, n_fields, s_mm, lens, p, surface_name=None):
    """The file's fields (``XFLN``/``YFLN`` of the ``FTYP`` field type) as deeplens' field
    angles (deg): for an object-space telecentric lens (``lens.object_telecentric``) the angle
    of the object point seen from the first vertex (:func:`~deeplens.optics.sampling.field_rays`).
    ``surface_name(i)``: how a refusal names lens surface ``i`` (the file's ``SURF`` and line)."""
    ys, _yline = sysd["yfln"] if sysd["yfln"] else ([0.0], 0)
    xs, xline = sysd["xfln"] if sysd["xfln"] else ([0.0] * len(ys), 0)
    if n_fields is not None:
        ys, xs = ys[:n_fields], xs[:n_fields]
    xs = xs + [0.0] * (len(ys) - len(xs))
    kind = ftyp[0]
    if kind == 0:
        xs, ys = _drop_sideways_fields(xs, ys, xline, _yline, p)
    tan_y = getattr(lens, "object_tilt", (0.0, 0.0))[1]
    if tan_y != 0 and any(x != 0 for x in xs):
        p.fail(xline, "XFLN: x field components with an object plane tilted about x (TILTSURF "
                      "object, PARM 2 != 0): deeplens' fields lie in the y-z plane, and a radial "
                      "field is not exact on a tilted object; give y fields only")
    # a tilted object plane, or an object at a first coordinate break's pivot (in the object's
    # frame, which the break turns away from the lens's axis): heights along y only
    at_pivot = float(lens.spec.object_distance_mm) == 0 and any(x != 0 for x in ys)
    if (tan_y != 0 or at_pivot) and kind in (1, 2, 3):
        return object_height_fields(kind, [v * s_mm for v in ys], lens, ftyp_line, tan_y, p)
    if any(x != 0 for x in xs):
        anamorphic = [i for i, s in enumerate(lens.surfaces) if isinstance(s, (Biconic, Cylinder, GridSag))
                      or (isinstance(s, (ZernikeSag, ZernikeFringePhase, XYPolynomial,
                                         ExtendedPolynomial, Binary1))
                          and not s.rotationally_symmetric())]
        if anamorphic:   # a biconic, cylinder, toroid, grid or freeform: x and y fields differ
            p.note(xline, f"XFLN: x field components are combined with y into a radial field, "
                          f"which is NOT exact for this lens (surface {anamorphic[0]}, a "
                          f"{type(lens.surfaces[anamorphic[0]]).__name__}, is not rotationally "
                          f"symmetric): its off-axis numbers are those of y fields")
        else:
            p.note(xline, "XFLN: x field components are combined with y into a radial field "
                          "(exact for a rotationally symmetric lens)")
    if kind == 0:
        return [math.copysign(math.degrees(math.atan(math.hypot(math.tan(math.radians(x)),
                                                                 math.tan(math.radians(y))))),
                              y if y != 0 else 1.0) for x, y in zip(xs, ys)]
    from ..paraxial import paraxial

    h = [math.copysign(math.hypot(x, y), y if y != 0 else 1.0) * s_mm for x, y in zip(xs, ys)]
    d_obj = float(lens.spec.object_distance_mm)
    if kind == 1 and math.isinf(d_obj):
        p.fail(ftyp_line, "FTYP 1 (object height) with the object at infinity cannot be "
                          "converted to field angles")
    if kind in (1, 2) and not math.isinf(d_obj):
        # object heights (paraxial image heights h' at a finite object: the object heights
        # h' / m): each object point where the file puts it, (0, h) (OpticStudio's convention,
        # below); x and y combined radially, the sign that of y
        return object_height_fields(kind, h, lens, ftyp_line, 0.0, p)
    if kind == 2:
        efl = float(paraxial(lens).efl)
        return [math.degrees(math.atan(v / efl)) for v in h]
    if kind == 3:
        return real_image_height_fields(lens, h, ftyp_line, p, surface_name)
    if kind == 4:
        # theodolite angles: for a single non-zero component the field angle itself (the two
        # together define a direction whose convention we have not checked against an oracle)
        out = []
        for x, y in zip(xs, ys):
            if x != 0 and y != 0:
                p.fail(ftyp_line, "FTYP 4 (theodolite angles) with both x and y non-zero in one "
                                  "field is not supported (give angles, FTYP 0)")
            out.append(y if y != 0 else x)
        return out
    names = {3: "real image height", 4: "theodolite angle"}
    p.fail(ftyp_line, f"FTYP {kind} ({names.get(kind, 'unknown field type')}) cannot be converted "
                      f"to deeplens' field angles (use angle, object height or paraxial image "
                      f"height)")


def object_height_fields(kind, heights, lens, ftyp_line, tan_y, p):
    """Field angles (deg) of object-height fields at a finite object (``FTYP 1``; ``FTYP 2``,
    paraxial image heights ``h'``, as the object heights ``h = h' / m``, ``m`` the paraxial
    magnification, exact at first order as the image height is): each object point goes where
    the file puts it, ``(0, h, z_obj + tan_y h)`` (``heights`` in mm; the object plane
    untilted, ``tan_y = 0``, tilted about x (``lens.object_tilt``, ``z = z_obj + tan_y y``), or
    at a first coordinate break's pivot (object distance 0: the plane in the object's frame,
    turned away from the axis after the break)), and the field angle is its chief ray's
    through the paraxial entrance pupil's centre, ``tan θ = -h / (s + z_EP - tan_y h)``
    (telecentric: ``tan θ = -h / s``, the object point ``y = -s tan θ``), the inverse of
    :func:`~deeplens.optics.sampling.object_point`.

    A positive height is a negative angle: OpticStudio's convention, "Positive field angles
    imply positive slope for the ray in that direction, and thus refer to negative coordinates
    on distant objects", object heights being the object's coordinates (OpticStudio User
    Guide, *Field Angles and Heights*).  Mirrored (``+h`` read as ``y = -h``, before branch
    ``objsign``), a lens that is not symmetric under ``y -> -y`` (decentred, tilted or folded
    in y, a tilted object) traces another field point than OpticStudio."""
    from ..paraxial import media_indices, paraxial, trace_paraxial_ray

    if kind == 3:
        p.fail(ftyp_line, "FTYP 3 (real image height) with an object plane tilted about x "
                          "(TILTSURF object, PARM 2 != 0) or at a first coordinate break's pivot "
                          "is not supported: give object heights (FTYP 1) or paraxial image "
                          "heights (FTYP 2)")
    s = float(lens.spec.object_distance_mm)
    with torch.no_grad():
        par = paraxial(lens)
        if kind == 2:
            n = media_indices(lens)
            one = torch.ones_like(n[0])
            y, u, _ = trace_paraxial_ray(lens, one, 0.0 * one, n)
            m = float(y + u * par.image_distance)
            if not abs(m) > 1e-12:
                p.fail(ftyp_line, "FTYP 2 (paraxial image height): the paraxial magnification "
                                  "is zero")
            heights = [v / m for v in heights]
        if getattr(lens, "object_telecentric", False):
            if s == 0:
                # (deeplens names a telecentric field by its object point's direction from
                # the first vertex: none when the object lies on it, as behind a coordinate
                # break at the object)
                p.fail(ftyp_line, "object-space telecentric fields with the object on the "
                                  "first surface deeplens traces (object distance 0, e.g. a "
                                  "COORDBRK at the object): deeplens names such a field by "
                                  "its direction from that vertex and cannot here")
            return [0.0 - math.degrees(math.atan(h / s)) for h in heights]
        d = s + float(par.entrance_pupil_position)
    out = []
    for h in heights:
        den = d - tan_y * h
        if tan_y == 0 and s != 0:
            # an untilted object plane (a virtual object too: the entrance pupil may lie before
            # it, den < 0, and the chief line still meets the plane at (0, h))
            if den == 0:
                p.fail(ftyp_line, f"FTYP {kind}: the paraxial entrance pupil lies on the object "
                                  f"plane, so an object height has no chief-ray angle")
            out.append(-math.degrees(math.atan(h / den)) + 0.0)   # + 0.0: never -0.0
            continue
        if not den > 0:
            p.fail(ftyp_line, f"the field of object height {h:g} mm lies on the tilted object "
                              f"plane at or behind the entrance pupil (its depth {den:g} mm "
                              f"before it): no real chief ray reaches it")
        out.append(0.0 - math.degrees(math.atan(h / den)))
    return out
