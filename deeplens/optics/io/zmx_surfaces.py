"""One ``SURF`` block of a ``.zmx`` file -> one deeplens surface.

``STANDARD``/``EVENASPH`` -> :class:`~deeplens.optics.surfaces.Asphere` (or a
:class:`~deeplens.optics.surfaces.Plane`, or an :class:`~deeplens.optics.surfaces.Aperture` for a
flat surface in air, with ``SQAP``/``OBSC``/annular ``CLAP``), ``ODDASPHE`` and an ``EVENASPH``
with an ``r²`` term (``PARM 1`` != 0) -> :class:`~deeplens.optics.surfaces.OddAsphere`, ``TOROIDAL`` ->
:class:`~deeplens.optics.surfaces.Toroid` (:class:`~deeplens.optics.surfaces.Cylinder` with no
radius of rotation), ``BICONICX`` -> :class:`~deeplens.optics.surfaces.Biconic`, ``PARAXIAL`` ->
:class:`~deeplens.optics.surfaces.IdealLens`, ``DGRATING`` ->
:class:`~deeplens.optics.surfaces.Grating`, ``BINARY_2`` ->
:class:`~deeplens.optics.surfaces.Binary2`, ``XYPOLYNOM`` ->
:class:`~deeplens.optics.surfaces.XYPolynomial`, ``SZERNSAG`` ->
:class:`~deeplens.optics.surfaces.ZernikeSag`, ``XASPHERE`` -> :class:`~deeplens.optics.surfaces.Asphere`
(or :class:`~deeplens.optics.surfaces.OddAsphere` with a ρ² term); ``SQAP`` on any of these (a
rectangular clear aperture, :func:`~deeplens.optics.surfaces.base.set_clear_rect}); a flat surface between one medium, not the stop,
with no fixed aperture is a dummy (its thickness only).  Lengths are scaled from file units to
mm here (``s_mm``); errors are raised through the reader's :class:`~.zmx_parse.Locator`.
"""

from __future__ import annotations

import math

import torch

from ..errors import ZemaxFileError
from ..materials import Air, Material
from ..surfaces import (Aperture, Asphere, Biconic, Binary2, Cylinder, Grating, IdealLens,
                        OddAsphere, Plane, QType, Toroid, XYPolynomial, ZernikeSag)
from ..surfaces.base import SagSurface, clear_rect_of, set_clear_rect
from ..surfaces.binary2 import MAX_PHASE_TERMS
from ..surfaces.qtype import MAX_TERMS
from ..surfaces.xy_polynomial import xy_terms
from ..surfaces.zernike_sag import MAX_ZERNIKE_TERMS
from .zmx_parse import Locator, ZmxSurface

__all__ = ["build_surface", "is_air", "PROVISIONAL_SD_MM"]

# the semi-diameter a surface with no DIAM is built with before its automatic value is set
PROVISIONAL_SD_MM = 1e-3


def is_air(m: Material) -> bool:
    return isinstance(m, Air)


def build_surface(s: ZmxSurface, k: int, mat: Material, prev: Material, s_mm: float,
                  folded: bool, p: Locator):
    """The surface of ``SURF k`` (block ``s``), between ``prev`` and ``mat``: ``(surface,
    auto)`` with ``auto`` whether its semi-diameter is automatic (to be set from real rays once
    the lens is built), or ``None`` for a dummy surface (only its thickness counts).  ``folded``:
    the lens has a fold or an off-axis section, where every semi-diameter not fixed is
    automatic."""
    if s.obdc is not None and s.clap is None and s.sqap is None and s.obsc is None:
        p.note(s.obdc[2], f"OBDC on SURF {k}: the surface has no aperture (CLAP, SQAP) to "
                          f"decentre; ignored")
        s.obdc = None
    c = s.curv / s_mm
    sd = s.diam * s_mm
    if s.clap is not None:
        sd = s.clap[0] * s_mm
    surf = None
    coeffs, flat, fixed = [], False, s.diam_fixed and s.diam > 0
    radial = _radial_coefficients(s, k, s_mm, p)   # ODDASPHE, EVENASPH with PARM 1: r¹, r², ...
    if s.type in ("STANDARD", "EVENASPH", "ODDASPHE"):
        if s.type == "EVENASPH" and radial is None:
            # as many terms as PARM lines (a4 = PARM 2, ...); a file listing all 8 (as
            # OpticStudio writes) is trimmed of its trailing zero terms
            top = max([i for i in s.parm if i <= 8] + [1])
            coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i)
                      for i in range(2, top + 1)]
            if top == 8:
                while coeffs and coeffs[-1] == 0.0:
                    coeffs.pop()
        flat = c == 0 and s.coni == 0 and not coeffs and not radial
        same_medium = (type(mat) is type(prev) and mat.name == prev.name)
        if (flat and same_medium and not s.stop and not fixed and s.clap is None
                and s.sqap is None and s.obsc is None and not s.mirror):
            return None   # a dummy surface: its thickness only
    if sd < 0:
        p.fail(s.line, f"SURF {k}: the semi-diameter (DIAM) must be >= 0, got {s.diam!r}")
    auto = not sd > 0     # no DIAM (or 0): an automatic semi-diameter, set once built
    if folded and not fixed and s.clap is None:
        auto = True
    sd_build = sd if sd > 0 else PROVISIONAL_SD_MM
    try:
        if s.type == "XYPOLYNOM":
            surf = _xypolynom(s, c, sd_build, s_mm, p)
        elif s.type == "DGRATING":
            surf = _grating(s, k, c, sd_build, p)
        elif s.type == "BINARY_2":
            surf = _binary2(s, k, c, sd_build, s_mm, p)
        elif s.type == "QED_TYPE":
            surf = _qtype(s, k, c, sd_build, s_mm, p)
        elif s.type == "SZERNSAG":
            surf = _zernike_sag(s, k, c, sd_build, s_mm, p)
        elif s.type == "XASPHERE":
            surf = _xasphere(s, k, c, sd_build, s_mm, p)
        elif s.type == "PARAXIAL":
            surf = _paraxial_surface(s, k, mat, prev, sd_build, s_mm, p)
        elif s.type == "TOROIDAL":
            surf = _cylinder(s, k, c, sd_build, s_mm, p)
        elif s.type == "BICONICX":
            surf = _biconic(s, k, c, sd_build, s_mm, p)
        elif s.sqap is not None and flat and is_air(mat) and is_air(prev):
            hx, hy, _ = s.sqap
            surf = Aperture(sd if sd > 0 else None, "rect", hx * s_mm, hy * s_mm)
        elif s.obsc is not None and flat and is_air(mat) and is_air(prev):
            # OpticStudio clips only on the obscuration here (and on a CLAP or a fixed
            # DIAM): an automatic DIAM, the beam's extent, is widened by 1 %
            outer = sd if (s.clap is not None or fixed or s.stop) else 1.01 * sd
            ro = s.obsc[0] * s_mm
            surf = Aperture(outer if outer > 0 else 2.0 * ro, obscuration=ro)
        elif flat and is_air(mat) and is_air(prev) and not s.mirror:
            surf = Aperture(sd_build)
        elif flat:
            surf = Plane(sd_build)
        elif radial:
            surf = OddAsphere(c, sd_build, conic=s.coni, coefficients=radial)
        else:
            surf = Asphere(c, sd_build, conic=s.coni, coefficients=coeffs)
    except ZemaxFileError:
        raise   # already located (a helper's p.fail): not located twice
    except ValueError as e:
        p.fail(s.type_line or s.line, f"SURF {k}: {e}")
    if (s.sqap is not None and isinstance(surf, SagSurface) and s.clap is None
            and s.obsc is None and not isinstance(surf, (Aperture, Cylinder, IdealLens))):
        # a rectangular opening of a lens or mirror surface of any sag type (an off-axis
        # mirror's, with OBDC): the rectangle, within its circumscribed circle; the
        # semi-diameter encloses it
        hx, hy = s.sqap[0] * s_mm, s.sqap[1] * s_mm
        if s.stop:
            p.fail(s.sqap[2], f"SQAP on SURF {k}: a rectangular aperture stop on a lens or "
                              f"mirror surface is not supported (deeplens' stops are circular "
                              f"there)")
        try:
            set_clear_rect(surf, (hx, hy))
        except ValueError as e:
            p.fail(s.sqap[2], f"SQAP on SURF {k}: {e}")
        auto = False
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
    if s.obsc is not None and isinstance(surf, Asphere):
        # a central obscuration on a lens or mirror surface (a secondary's shadow on a
        # Cassegrain's primary): an aperture property of the surface
        ro = s.obsc[0] * s_mm
        if not 0 < ro < float(surf.semi_diameter) and not auto:
            p.fail(s.obsc[1], f"SURF {k}: the obscuration radius {s.obsc[0]:g} must be > 0 "
                              f"and below the semi-diameter {s.diam:g}")
        surf.obscuration.fill_(ro)
    elif s.obsc is not None and not isinstance(surf, Aperture):
        what = (("flat mirror" if s.mirror else "flat surface between two media") if flat
                else ("mirror" if s.mirror else "lens surface"))
        p.fail(s.obsc[1], f"SURF {k}: OBSC, a central obscuration on a {what} "
                          f"({type(surf).__name__}), is not supported (deeplens has "
                          f"obscurations on flat surfaces in air: put the obscuration on its "
                          f"own flat dummy surface where that is equivalent)")
    if s.sqap is not None and not (isinstance(surf, Cylinder) or (
            isinstance(surf, Aperture) and surf.shape == "rect") or (
            clear_rect_of(surf) is not None)):
        extra = (" with a CLAP" if s.clap is not None else
                 " with an OBSC" if s.obsc is not None else "")
        p.fail(s.sqap[2], f"SQAP on SURF {k}: a rectangular aperture on a "
                          f"{type(surf).__name__} surface{extra} is not supported (deeplens has "
                          f"rectangular apertures on flat stops in air, on cylinders, and alone "
                          f"(no CLAP or OBSC) on any other lens or mirror surface)")
    if auto and isinstance(surf, Aperture) and surf.shape == "rect":
        auto = False   # its semi-diameter is the rectangle's half-diagonal
    return surf, auto


def _aperture_decenter(s: ZmxSurface, k: int, surf, s_mm, p: Locator):
    """``OBDC x y``: the decenter (mm) of the surface's aperture: a ``CLAP`` (circular or
    annular) or ``SQAP`` on a flat surface in air (a deeplens :class:`Aperture`), or a circular
    ``CLAP`` or a ``SQAP`` on a lens or mirror surface (an :class:`Asphere`: an off-axis
    segment, such as an off-axis parabola's or an off-axis mirror's rectangular opening); never
    on the stop."""
    dx, dy, ln = s.obdc
    where = f"OBDC on SURF {k} (aperture decenter {dx:g}, {dy:g})"
    if s.clap is None and s.sqap is None:   # an OBSC alone (no aperture at all: not called)
        p.fail(ln, f"{where}: a decentred obscuration (OBSC) inside a centred semi-diameter is "
                   f"not supported (deeplens decentres a CLAP or SQAP opening, with its "
                   f"obscuration)")
    if s.stop:
        p.fail(ln, f"{where}: a decentred aperture stop is not supported (deeplens' entrance "
                   f"pupil is centred on the axis)")
    if not isinstance(surf, Aperture) and not (
            type(surf) is Asphere and (s.clap is None) != (s.sqap is None)
            and s.obsc is None):
        what = ("an annular or obscured" if s.obsc is not None else
                "a circular and rectangular (CLAP and SQAP)" if s.sqap is not None else "a")
        p.fail(ln, f"{where}: {what} decentred aperture on a lens or mirror surface "
                   f"({type(surf).__name__}) is not supported (deeplens decentres apertures on "
                   f"flat surfaces in air, and a circular CLAP or a rectangular SQAP on a "
                   f"STANDARD or EVENASPH lens or mirror surface: an off-axis segment)")
    return (dx * s_mm, dy * s_mm)


def _radial_coefficients(s: ZmxSurface, k: int, s_mm, p: Locator):
    """The coefficients ``[a_1, a_2, ...]`` of ``r¹, r², ...`` (mm^(1−i)) of an
    :class:`OddAsphere`: ``ODDASPHE``'s ``PARM i`` on ``r^i``, and an ``EVENASPH`` whose ``PARM 1``
    (the ``r²`` term) is not zero, ``PARM i`` on ``r^(2i)`` (the odd powers zero); trailing zero
    terms trimmed.  ``None`` for every other surface (an ``EVENASPH`` without an ``r²`` term stays
    an :class:`Asphere`), and ``[]`` for an ``ODDASPHE`` with no term (its conic base)."""
    if s.type not in ("EVENASPH", "ODDASPHE"):
        return None
    for i, (v, ln) in sorted(s.parm.items()):
        if (i > 8 or i < 1) and v != 0:
            kind = "even" if s.type == "EVENASPH" else "odd"
            p.fail(ln, f"SURF {k}: {s.type} PARM {i} is not read: Zemax's {kind} asphere has "
                       f"PARM 1-8")
    if s.type == "EVENASPH" and s.parm.get(1, (0.0, 0))[0] == 0:
        return None
    power = (lambda i: 2 * i) if s.type == "EVENASPH" else (lambda i: i)
    a = [0.0] * power(8)
    for i in range(1, 9):
        v = s.parm.get(i, (0.0, 0))[0]
        a[power(i) - 1] = v * s_mm ** (1 - power(i))
    while a and a[-1] == 0.0:
        a.pop()
    return a


def _cylinder(s: ZmxSurface, k: int, c, sd, s_mm, p: Locator):
    """``TOROIDAL``: the y profile (``CURV``, ``CONI``, ``PARM 2..9`` the coefficients of ``y²,
    y⁴, ..., y¹⁶``) rotated about an axis parallel to y at the radius of rotation ``PARM 1``: a
    :class:`Toroid`, or with ``PARM 1`` = 0 (an infinite radius) a :class:`Cylinder`, curved in
    y; ``SQAP`` its rectangular outline."""
    nz = s.xdat.get(1, (0.0, 0))
    if nz[0] != 0 or any(v != 0 for j, (v, _) in s.xdat.items() if j > 2):
        p.fail(nz[1] or s.type_line, f"SURF {k}: TOROIDAL Zernike terms (XDAT) are not supported")
    for i, (v, ln) in s.parm.items():
        if (i > 9 or i < 1) and v != 0:
            p.fail(ln, f"SURF {k}: TOROIDAL PARM {i} is not read (PARM 1 radius of rotation, "
                       f"PARM 2-9 the y² ... y¹⁶ coefficients)")
    top = max([i for i in s.parm if 2 <= i <= 9 and s.parm[i][0] != 0] + [1])
    coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (3 - 2 * i) for i in range(2, top + 1)]
    hw = None if s.sqap is None else (s.sqap[0] * s_mm, s.sqap[1] * s_mm)
    if hw is not None and sd == PROVISIONAL_SD_MM:
        sd = math.hypot(*hw)
    r_rot = s.parm.get(1, (0.0, 0))[0]
    if r_rot != 0:
        return Toroid(c, sd, r_rot * s_mm, conic=s.coni, coefficients=coeffs, half_widths=hw)
    return Cylinder(c, sd, conic=s.coni, coefficients=coeffs, half_widths=hw)


def _biconic(s: ZmxSurface, k: int, c, sd, s_mm, p: Locator):
    """``BICONICX``: ``CURV``/``CONI`` the y curvature and conic, ``PARM 1`` the x *radius* (0:
    infinite, flat in x), ``PARM 2`` the x conic (OpticStudio's "Biconic" surface; it has no
    other parameter and no extra data): a :class:`Biconic`."""
    for i, (v, ln) in sorted(s.parm.items()):
        if i not in (1, 2) and v != 0:
            p.fail(ln, f"SURF {k}: BICONICX PARM {i} is not read (a biconic has PARM 1, the x "
                       f"radius, and PARM 2, the x conic; a Biconic Zernike or other variant "
                       f"is not supported)")
    for j, (v, ln) in sorted(s.xdat.items()):
        if v != 0:
            p.fail(ln, f"SURF {k}: BICONICX XDAT {j} is not read (a biconic has no extra data; "
                       f"a Biconic Zernike or other variant is not supported)")
    r_x = s.parm.get(1, (0.0, 0))[0]
    c_x = 0.0 if r_x == 0 else 1.0 / (r_x * s_mm)
    return Biconic(c, sd, c_x, conic=s.coni, conic_x=s.parm.get(2, (0.0, 0))[0])


def _grating(s: ZmxSurface, k: int, c, sd, p: Locator):
    """``DGRATING``: a sphere or conic (``CURV``, ``CONI``) ruled with ``PARM 1`` lines per
    micrometre (in every lens unit) parallel to the local x axis, traced in order ``PARM 2``:
    a :class:`Grating` (transmitting, or reflecting with ``GLAS MIRROR``)."""
    for i, (v, ln) in s.parm.items():
        if i > 2 and v != 0:
            p.fail(ln, f"SURF {k}: DGRATING PARM {i} is not read (PARM 1 lines per micrometre, "
                       f"PARM 2 the diffraction order)")
    order, ln = s.parm.get(2, (0.0, s.type_line))
    if order != int(order):
        p.fail(ln, f"SURF {k}: the diffraction order (DGRATING PARM 2) must be an integer, got "
                   f"{order!r}")
    return Grating(c, sd, s.parm.get(1, (0.0, 0))[0], int(order), conic=s.coni)


def _binary2(s: ZmxSurface, k: int, c, sd, s_mm, p: Locator):
    """``BINARY_2`` (OpticStudio's "Binary 2"): an even asphere (``CURV``, ``CONI``, ``PARM 2..8``
    the ``r⁴ ... r¹⁶`` terms; ``PARM 1``, the ``r²`` term, must be 0) with the phase ``M Σ A_i
    ρ^{2i}``: ``PARM 0`` the diffraction order ``M``, ``XDAT 1`` the number of terms, ``XDAT 2``
    the normalisation radius (a length), ``XDAT 3..`` the ``A_i`` (radians): a :class:`Binary2`
    (transmitting, or reflecting with ``GLAS MIRROR``)."""
    for i, (v, ln) in sorted(s.parm.items()):
        if (i < 0 or i > 8) and v != 0:
            p.fail(ln, f"SURF {k}: BINARY_2 PARM {i} is not read (PARM 0 the diffraction order, "
                       f"PARM 1-8 the even-asphere terms on r², ..., r¹⁶)")
    if s.parm.get(1, (0.0, 0))[0] != 0:
        p.fail(s.parm[1][1], f"SURF {k}: BINARY_2 PARM 1 (the r² term of the base asphere) is "
                             f"not supported (deeplens' even asphere starts at r⁴): fold it "
                             f"into the curvature")
    if 0 not in s.parm:
        p.fail(s.type_line or s.line, f"SURF {k}: BINARY_2 without PARM 0 (the diffraction "
                                      f"order)")
    order, o_ln = s.parm[0]
    if order != int(order):
        p.fail(o_ln, f"SURF {k}: the diffraction order (BINARY_2 PARM 0) must be an integer, got "
                     f"{order!r}")
    n_v, n_ln = s.xdat.get(1, (0.0, s.type_line))
    if n_v != int(n_v) or not 0 <= n_v <= MAX_PHASE_TERMS:
        p.fail(n_ln, f"SURF {k}: BINARY_2 XDAT 1 (the number of phase terms) must be an integer "
                     f"0..{MAX_PHASE_TERMS}, got {n_v!r}")
    n = int(n_v)
    for j, (v, ln) in sorted(s.xdat.items()):
        if j > n + 2 and v != 0:
            p.fail(ln, f"SURF {k}: BINARY_2 XDAT {j} lies beyond the {n} phase terms XDAT 1 "
                       f"declares")
    rn_v, rn_ln = s.xdat.get(2, (0.0, s.type_line))
    if n > 0 and not rn_v > 0:
        p.fail(rn_ln, f"SURF {k}: BINARY_2 XDAT 2 (the normalisation radius) must be > 0, got "
                      f"{rn_v!r}")
    top = max([i for i in range(2, 9) if s.parm.get(i, (0.0, 0))[0] != 0] + [1])
    coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i) for i in range(2, top + 1)]
    phase = [s.xdat.get(j + 3, (0.0, 0))[0] for j in range(n)]
    while phase and phase[-1] == 0.0:
        phase.pop()
    rn = rn_v * s_mm if rn_v > 0 else 1.0   # no phase term: any radius (1 mm)
    return Binary2(c, sd, rn, phase, int(order), conic=s.coni, coefficients=coeffs)


def _qtype(s: ZmxSurface, k: int, c, sd, s_mm, p: Locator):
    """``QED_TYPE`` (OpticStudio's Q-type asphere): ``XDAT 1`` the type (0 Qbfs, 1 Qcon),
    ``XDAT 2`` the number of terms, ``XDAT 3`` the normalisation radius, ``XDAT 4..`` the
    coefficients ``a_0, a_1, ...`` (lengths): a :class:`QType`.  A Qbfs on a conic base
    (``CONI`` != 0) is refused: how OpticStudio combines the two could not be checked against
    an independent reader (deeplens' surface follows Forbes' generalisation, as optiland)."""
    kind_v, kind_ln = s.xdat.get(1, (0.0, s.type_line))
    if kind_v not in (0.0, 1.0):
        p.fail(kind_ln, f"SURF {k}: QED_TYPE XDAT 1 (the type) must be 0 (Qbfs) or 1 (Qcon), got "
                        f"{kind_v!r}")
    n_v, n_ln = s.xdat.get(2, (0.0, s.type_line))
    if n_v != int(n_v) or not 0 <= n_v <= MAX_TERMS:
        p.fail(n_ln, f"SURF {k}: QED_TYPE XDAT 2 (the number of terms) must be an integer "
                     f"0..{MAX_TERMS}, got {n_v!r}")
    rn_v, rn_ln = s.xdat.get(3, (0.0, s.type_line))
    if not rn_v > 0:
        p.fail(rn_ln, f"SURF {k}: QED_TYPE XDAT 3 (the normalisation radius) must be > 0, got "
                      f"{rn_v!r}")
    n = int(n_v)
    for j, (v, ln) in s.xdat.items():
        if j > n + 3 and v != 0:
            p.fail(ln, f"XDAT {j} lies beyond the {n} terms XDAT 2 declares")
    for i, (v, ln) in s.parm.items():
        if v != 0:
            p.fail(ln, f"SURF {k}: QED_TYPE PARM {i} is not read (the Q-type data are XDAT)")
    if kind_v == 0.0 and s.coni != 0:
        p.fail(s.type_line, f"SURF {k}: a QED_TYPE Qbfs surface on a conic base (CONI "
                            f"{s.coni:g}) is not supported: how OpticStudio combines the "
                            f"slope-orthogonal departure with a conic could not be checked here "
                            f"(Qbfs on a sphere and Qcon on any conic are read)")
    coeffs = [s.xdat.get(j + 4, (0.0, 0))[0] * s_mm for j in range(n)]
    return QType(c, sd, rn_v * s_mm, coeffs, "qcon" if kind_v == 1.0 else "qbfs",
                 conic=s.coni)


def _zernike_sag(s: ZmxSurface, k: int, c, sd, s_mm, p: Locator):
    """``SZERNSAG`` (OpticStudio's "Zernike Standard Sag"): an even asphere (``CURV``, ``CONI``,
    ``PARM 1..8`` the ``r², r⁴, ..., r¹⁶`` terms) plus Zernike standard terms in Noll's order:
    ``PARM 0`` the extrapolate flag (1: the terms also beyond the normalisation radius),
    ``PARM 9``/``PARM 10`` the Zernike decenter (must be 0), ``XDAT 1`` the number of terms,
    ``XDAT 2`` the normalisation radius, ``XDAT 3..`` the coefficients ``A_1, A_2, ...``
    (lengths): a :class:`ZernikeSag`."""
    for i, (v, ln) in sorted(s.parm.items()):
        if i in (9, 10) and v != 0:
            p.fail(ln, f"SURF {k}: SZERNSAG PARM {i} (the Zernike decenter in "
                       f"{'x' if i == 9 else 'y'}) is not supported: deeplens' Zernike terms are "
                       f"centred on the vertex")
        if (i < 0 or i > 10) and v != 0:
            p.fail(ln, f"SURF {k}: SZERNSAG PARM {i} is not read (PARM 0 the extrapolate flag, "
                       f"PARM 1-8 the even terms on r², ..., r¹⁶, PARM 9-10 the Zernike "
                       f"decenter)")
    ext, ext_ln = s.parm.get(0, (1.0, s.type_line))
    if ext not in (0.0, 1.0):
        p.fail(ext_ln, f"SURF {k}: SZERNSAG PARM 0 (the extrapolate flag) must be 0 or 1, got "
                       f"{ext!r}")
    n_v, n_ln = s.xdat.get(1, (0.0, s.type_line))
    if n_v != int(n_v) or not 0 <= n_v <= MAX_ZERNIKE_TERMS:
        p.fail(n_ln, f"SURF {k}: SZERNSAG XDAT 1 (the number of Zernike terms) must be an "
                     f"integer 0..{MAX_ZERNIKE_TERMS}, got {n_v!r}")
    n = int(n_v)
    for j, (v, ln) in sorted(s.xdat.items()):
        if (j > n + 2 or j < 1) and v != 0:
            p.fail(ln, f"SURF {k}: SZERNSAG XDAT {j} lies beyond the {n} Zernike terms XDAT 1 "
                       f"declares")
    rn_v, rn_ln = s.xdat.get(2, (0.0, s.type_line))
    if n > 0 and not rn_v > 0:
        p.fail(rn_ln, f"SURF {k}: SZERNSAG XDAT 2 (the normalisation radius) must be > 0, got "
                      f"{rn_v!r}")
    top = max([i for i in range(1, 9) if s.parm.get(i, (0.0, 0))[0] != 0] + [0])
    coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i) for i in range(1, top + 1)]
    zern = [s.xdat.get(j + 3, (0.0, 0))[0] * s_mm for j in range(n)]
    while zern and zern[-1] == 0.0:
        zern.pop()
    rn = rn_v * s_mm if rn_v > 0 else 1.0   # no Zernike term: any radius (1 mm)
    return ZernikeSag(c, sd, rn, zern, conic=s.coni, coefficients=coeffs,
                      extrapolate=ext == 1.0)


def _paraxial_surface(s: ZmxSurface, k: int, mat, prev, sd, s_mm, p: Locator):
    """``PARAXIAL`` (``PARM 1`` = focal length): deeplens' :class:`IdealLens`, in air."""
    if 1 not in s.parm or s.parm[1][0] == 0:
        p.fail(s.type_line or s.line, f"SURF {k}: a PARAXIAL surface needs a non-zero focal "
                                      f"length (PARM 1)")
    if not (is_air(mat) and is_air(prev)):
        p.fail(s.glass_line or s.type_line, f"SURF {k}: a PARAXIAL surface between glasses is "
                                            f"not supported (deeplens' ideal lens sits in air)")
    for i, (v, ln) in s.parm.items():
        if i > 2 and v != 0:
            p.fail(ln, f"SURF {k}: PARAXIAL PARM {i} is not read (only the focal length, PARM 1)")
    return IdealLens(s.parm[1][0] * s_mm, sd)


def _xypolynom(s: ZmxSurface, c, sd, s_mm, p: Locator):
    if c != 0:
        p.fail(s.line, "XYPOLYNOM with a base curvature (CURV != 0) is not supported: deeplens' XY "
                       "polynomial is z = P(x, y) (put the base sphere into the polynomial)")
    if 1 not in s.xdat or 2 not in s.xdat:
        p.fail(s.line, "XYPOLYNOM without XDAT 1 (number of terms) and XDAT 2 (normalisation "
                       "radius)")
    nterms = int(s.xdat[1][0])
    R = s.xdat[2][0] * s_mm
    if not R > 0:
        p.fail(s.xdat[2][1], f"XYPOLYNOM normalisation radius must be > 0, got {s.xdat[2][0]!r}")
    # Zemax term j (1-based): degrees 1, 2, ... each from x^d down to y^d
    zterms = [(d - i, i) for d in range(1, 64) for i in range(d + 1)]
    if not 1 <= nterms <= len(zterms):
        p.fail(s.xdat[1][1], f"XYPOLYNOM number of terms must be 1..{len(zterms)}, got {nterms}")
    for j, (v, ln) in s.xdat.items():
        if j > nterms + 2 and v != 0:
            p.fail(ln, f"XDAT {j} lies beyond the {nterms} terms XDAT 1 declares")
    vals = {zterms[j - 1]: s.xdat.get(j + 2, (0.0, 0))[0] for j in range(1, nterms + 1)}
    order = sum(zterms[nterms - 1])
    coeffs = []
    for (px, py) in xy_terms(order):
        a = vals.get((px, py), 0.0)
        # A (x/R)^px (y/R)^py with lengths scaled to mm: A s_mm / R^(px+py)
        coeffs.append(a * s_mm / R ** (px + py))
    return XYPolynomial(sd, coeffs)



#: the most terms of OpticStudio's Extended Asphere (XDAT 1), and the most deeplens reads: its
#: even asphere holds r² .. r²⁰ (:data:`~deeplens.optics.surfaces.asphere.MAX_ASPHERE_ORDER`)
XASPHERE_MAX_TERMS, XASPHERE_READ_TERMS = 240, 10


def _xasphere(s: ZmxSurface, k: int, c, sd, s_mm, p: Locator):
    """``XASPHERE`` (OpticStudio's "Extended Asphere"): the STANDARD sag (``CURV``, ``CONI``)
    plus ``Σ_{i=1..N} α_i ρ^{2i}``, ``ρ = r / R_n``, the coefficients ``α_i`` in lens units:
    ``XDAT 1`` the maximum term number ``N`` (<= 240), ``XDAT 2`` the normalisation radius
    ``R_n``, ``XDAT 3..`` ``α_1`` (on ρ²), ``α_2`` (on ρ⁴), ... (OpticStudio User Guide,
    "Extended Asphere": the even asphere's series in a normalised radial coordinate, even
    powers only).  The same surface as an even asphere: ``a_{2i} = α_i / R_n^{2i}`` (mm), an
    :class:`Asphere` (an :class:`OddAsphere` with its odd terms zero when ``α_1`` != 0).
    Terms up to ρ²⁰ (10) are read; a non-zero one beyond is refused with its line."""
    for i, (v, ln) in sorted(s.parm.items()):
        if v != 0:
            p.fail(ln, f"SURF {k}: XASPHERE PARM {i} is not read (the Extended Asphere's data "
                       f"are XDAT 1 the number of terms, XDAT 2 the normalisation radius, XDAT "
                       f"3.. the coefficients on ρ², ρ⁴, ...)")
    n_v, n_ln = s.xdat.get(1, (0.0, s.type_line))
    if n_v != int(n_v) or not 0 <= n_v <= XASPHERE_MAX_TERMS:
        p.fail(n_ln, f"SURF {k}: XASPHERE XDAT 1 (the maximum term number) must be an integer "
                     f"0..{XASPHERE_MAX_TERMS}, got {n_v!r}")
    n = int(n_v)
    for j, (v, ln) in sorted(s.xdat.items()):
        if (j > n + 2 or j < 1) and v != 0:
            p.fail(ln, f"SURF {k}: XASPHERE XDAT {j} lies beyond the {n} terms XDAT 1 declares")
    rn_v, rn_ln = s.xdat.get(2, (0.0, s.type_line))
    alpha = [(s.xdat.get(i + 2, (0.0, 0))[0], s.xdat.get(i + 2, (0.0, rn_ln))[1])
             for i in range(1, n + 1)]
    while alpha and alpha[-1][0] == 0.0:
        alpha.pop()
    if alpha and not rn_v > 0:
        p.fail(rn_ln, f"SURF {k}: XASPHERE XDAT 2 (the normalisation radius) must be > 0, got "
                      f"{rn_v!r}")
    if len(alpha) > XASPHERE_READ_TERMS:
        p.fail(alpha[-1][1], f"SURF {k}: XASPHERE term {len(alpha)} (on ρ^{2 * len(alpha)}) is "
                             f"not supported: deeplens' even asphere holds terms up to ρ²⁰ "
                             f"({XASPHERE_READ_TERMS} terms)")
    rn = rn_v * s_mm
    a = []   # a_{2i}, mm^(1-2i)
    for i, (v, ln) in enumerate(alpha, 1):
        ai = v * s_mm / rn ** (2 * i)
        if v != 0 and not (math.isfinite(ai) and ai != 0.0):
            p.fail(ln, f"SURF {k}: XASPHERE term {i}: {v!r} / R_n^{2 * i} (R_n = {rn:g} mm) is "
                       f"not representable as an even-asphere coefficient")
        a.append(ai)
    if a and a[0] != 0.0:   # a ρ² term: the odd asphere's r² slot, odd powers zero
        radial = [0.0] * (2 * len(a))
        radial[1::2] = a
        return OddAsphere(c, sd, conic=s.coni, coefficients=radial)
    return Asphere(c, sd, conic=s.coni, coefficients=a[1:])
