"""The built-in file handlers: one :class:`~.surface_formats.SurfaceFormat` per surface type.

Each reads its Zemax ``TYPE`` (and CODE V type) and writes its deeplens class (the registry,
how a new type registers and how lookups work: :mod:`.surface_formats`):

* :class:`ApertureFormat`: writes ``Aperture`` (read through ``STANDARD`` / CODE V ``SPH``);
* :class:`PlaneFormat`: writes ``Plane`` (read through ``STANDARD`` / ``SPH``);
* :class:`AsphereFormat`: reads ``STANDARD``, ``EVENASPH`` / ``SPH``, ``CON``, ``ASP``; writes
  ``Asphere`` (and ``Sphere``);
* :class:`OddAsphereFormat`: reads ``ODDASPHE``; writes ``OddAsphere``;
* :class:`CoordinateBreakFormat`: ``COORDBRK`` (read by the reader's sequence);
  writes ``CoordinateBreak``;
* :class:`XYPolynomialFormat` (``XPOLYNOM``, ``XYPOLYNOM``, ``XYPolynomial``), :class:`ParaxialFormat`
  (``PARAXIAL``, ``IdealLens``), :class:`ToroidalFormat` (``TOROIDAL``, ``Cylinder`` and
  ``Toroid``), :class:`GratingFormat` (``DGRATING``, ``Grating``), :class:`QTypeFormat`
  (``QED_TYPE``, ``QType``), :class:`BiconicFormat` (``BICONICX``, ``Biconic``),
  :class:`Binary2Format` (``BINARY_2``, ``Binary2``), :class:`Binary1Format` (``BINARY_1``,
  ``Binary1``), :class:`ZernikeSagFormat` (``SZERNSAG``,
  ``ZernikeSag``), :class:`ZernikeFringePhaseFormat` (``FZERNPHA``, ``ZernikeFringePhase``);
* :class:`ExtendedAsphereFormat`: reads ``XASPHERE`` (an ``Asphere`` with terms beyond r¹⁶ is
  written so by :class:`AsphereFormat`);
* :class:`~.zmx_grid_sag.GridSagFormat` (in its own module, :mod:`.zmx_grid_sag`): ``GRID_SAG``,
  ``GridSag``;
* :class:`~.zmx_irregular.IrregularFormat` (in its own module, :mod:`.zmx_irregular`):
  ``IRREGULA``, ``Irregular``;
* :class:`~.zmx_hologram.HologramFormat` (in its own module, :mod:`.zmx_hologram`):
  ``HOLOGRM1``, ``HOLOGRM2``, ``Hologram``;
* :class:`~.zmx_grin.Gradient1Format` (in its own module, :mod:`.zmx_grin`): ``GRINSUR1``,
  ``GradientSurface`` with its graded medium;
* :class:`~.zmx_fresnel.FresnelFormat` (in its own module, :mod:`.zmx_fresnel`): ``FRESNELS``,
  ``Fresnel``;
* :class:`~.zmx_xosphere.ExtendedOddAsphereFormat` (in its own module, :mod:`.zmx_xosphere`):
  ``XOSPHERE``, ``ExtendedOddAsphere``.

``STANDARD``/``EVENASPH`` -> :class:`~deeplens.optics.surfaces.Asphere` (or a
:class:`~deeplens.optics.surfaces.Plane`, or an :class:`~deeplens.optics.surfaces.Aperture` for a
flat surface in air, with ``SQAP``/``OBSC``/annular ``CLAP``), ``ODDASPHE`` and an ``EVENASPH``
with an ``r²`` term (``PARM 1`` != 0) -> :class:`~deeplens.optics.surfaces.OddAsphere`,
``TOROIDAL`` -> :class:`~deeplens.optics.surfaces.Toroid` (:class:`~deeplens.optics.surfaces.Cylinder`
with no radius of rotation), ``BICONICX`` -> :class:`~deeplens.optics.surfaces.Biconic`,
``PARAXIAL`` -> :class:`~deeplens.optics.surfaces.IdealLens`, ``DGRATING`` ->
:class:`~deeplens.optics.surfaces.Grating`, ``BINARY_2`` ->
:class:`~deeplens.optics.surfaces.Binary2`, ``BINARY_1`` ->
:class:`~deeplens.optics.surfaces.Binary1`, ``XPOLYNOM`` (flat base) and ``XYPOLYNOM`` ->
:class:`~deeplens.optics.surfaces.XYPolynomial`, ``SZERNSAG`` ->
:class:`~deeplens.optics.surfaces.ZernikeSag`, ``XASPHERE`` -> :class:`~deeplens.optics.surfaces.Asphere`
(or :class:`~deeplens.optics.surfaces.OddAsphere` with a ρ² term).  Lengths are scaled from file
units to mm (``s_mm``); ``s`` is always a block, :class:`~.zmx_parse.ZmxSurface`, and errors
are raised through the reader's :class:`~.zmx_parse.Locator` ``p`` (neither imported here: the
parser imports this module).
The openings common to every type (``CLAP``, ``SQAP``, ``OBSC``, ``OBDC``) and dummy surfaces
are :func:`.zmx_surfaces.build_surface`'s.

Numbers are written with ``repr`` (shortest round-trip text), so a lens read, written and read
again is the same bit for bit.
"""

from __future__ import annotations

import math

import torch

from ..errors import LensFileError, ZemaxFileError
from ..materials import Air, Material
from ..surfaces import (Aperture, Asphere, Biconic, Binary1, Binary2, CoordinateBreak, Cylinder,
                        ExtendedPolynomial, Grating,
                        IdealLens, IdealLensXY, OddAsphere, Plane, QType, Toroid, XYPolynomial,
                        ZernikeFringePhase, ZernikeFringeSag, ZernikeSag)
from ..surfaces.base import clear_ellipse_of, clear_rect_of, obscuration_ellipse_of
from ..surfaces.binary2 import MAX_PHASE_TERMS
# OpticStudio's Extended Polynomial's term order and most terms (230, order 20), shared with the
# surface a curved base reads into
from ..surfaces.extended_polynomial import MAX_EXTENDED_TERMS as XPOLYNOM_MAX_TERMS
from ..surfaces.extended_polynomial import extended_terms as zemax_xy_terms
from ..surfaces.qtype import MAX_TERMS
from ..surfaces.xy_polynomial import xy_terms
from ..surfaces.zernike_sag import BASES
from .surface_formats import (FORMATS, SurfaceFormat, ZmxContext, refuse_unread, register_format,
                              xdat_term_count, zmx_diam as _diam, zmx_number as _f)
from .zmx_coordbrk import coordbrk_lines
from .zmx_notes import Cause

#: the registry (:mod:`.surface_formats`), filled with this module's handlers: import it from
#: here so that they are registered
__all__ = ["FORMATS", "PROVISIONAL_SD_MM", "is_air", "XASPHERE_MAX_TERMS", "XASPHERE_READ_TERMS",
           "XPOLYNOM_MAX_TERMS", "zemax_xy_terms"]

# the semi-diameter a surface with no DIAM is built with before its automatic value is set
PROVISIONAL_SD_MM = 1e-3

#: CODE V's aspheric coefficients A, B, ... J on r⁴ ... r²⁰
CODEV_ASPH = "ABCDEFGHJ"


def _xdat_radius_and_terms(p, s, k, type_name: str, n: int, s_mm, scale=1.0):
    """``XDAT 2`` of surface ``k`` (a ``type_name`` surface), the normalisation radius (a length,
    > 0 when there are terms; mm, any radius, 1 mm, with none), and the ``n`` terms ``XDAT 3..``
    times ``scale`` with the trailing zeros dropped.  Returns ``(terms, rn)``; a bad radius fails
    at its line."""
    rn_v, rn_ln = s.xdat.get(2, (0.0, s.type_line))
    if n > 0 and not rn_v > 0:
        p.fail(rn_ln, f"SURF {k}: {type_name} XDAT 2 (the normalisation radius) must be > 0, got "
                      f"{rn_v!r}")
    terms = [s.xdat.get(j + 3, (0.0, 0))[0] * scale for j in range(n)]
    while terms and terms[-1] == 0.0:
        terms.pop()
    return terms, (rn_v * s_mm if rn_v > 0 else 1.0)


def _phase_on_conic(p, s, k, type_name: str, parm0_why: str, count_what: str, cls, terms: str,
                    s_mm):
    """The records of a phase on a conic base (``BINARY_1``, ``FZERNPHA``: a
    :class:`~deeplens.optics.surfaces.conic_phase.ConicPhase`): ``PARM 0`` must be 1 (else
    refused on its line, ``parm0_why`` saying why), any other non-zero ``PARM`` is refused on its
    line, ``XDAT 1`` the number of terms (at most ``cls.max_terms``; ``count_what``, ``terms``
    name them), ``XDAT 2`` the normalisation radius, ``XDAT 3..`` the coefficients (unscaled).
    Returns ``(coefficients, rn)`` (``rn`` in mm)."""
    refuse_unread(p, s.parm, f"SURF {k}: {type_name}", "no stored OpticStudio source gives its "
                  "meaning; read: PARM 0 = 1 and the XDAT terms", (0,))
    m_v, m_ln = s.parm.get(0, (None, s.type_line))
    if m_v != 1.0:
        p.fail(m_ln, f"SURF {k}: {type_name} PARM 0 = {m_v!r} is refused: {parm0_why}")
    n = xdat_term_count(p, s, k, type_name, count_what, cls.max_terms, terms)
    return _xdat_radius_and_terms(p, s, k, type_name, n, s_mm)


def is_air(m: Material) -> bool:
    return isinstance(m, Air)


# --------------------------------------------------------------------------- Zemax readers
def _radial_coefficients(s, k: int, s_mm, p):
    """The coefficients ``[a_1, a_2, ...]`` of ``r¹, r², ...`` (mm^(1−i)) of an
    :class:`OddAsphere`: ``ODDASPHE``'s ``PARM i`` on ``r^i``, and an ``EVENASPH`` whose ``PARM 1``
    (the ``r²`` term) is not zero, ``PARM i`` on ``r^(2i)`` (the odd powers zero); trailing zero
    terms trimmed.  ``None`` for every other surface (an ``EVENASPH`` without an ``r²`` term stays
    an :class:`Asphere`), and ``[]`` for an ``ODDASPHE`` with no term (its conic base)."""
    if s.type not in ("EVENASPH", "ODDASPHE"):
        return None
    refuse_unread(p, s.parm, f"SURF {k}: {s.type}", f"Zemax's "
                  f"{'even' if s.type == 'EVENASPH' else 'odd'} asphere has PARM 1-8", range(1, 9))
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


def _cylinder(s, k: int, c, sd, s_mm, p):
    """``TOROIDAL``: the y profile (``CURV``, ``CONI``, ``PARM 2..9`` the coefficients of ``y²,
    y⁴, ..., y¹⁶``) rotated about an axis parallel to y at the radius of rotation ``PARM 1``: a
    :class:`Toroid`, or with ``PARM 1`` = 0 (an infinite radius) a :class:`Cylinder`, curved in
    y; ``SQAP`` its rectangular outline."""
    nz = s.xdat.get(1, (0.0, 0))
    if nz[0] != 0 or any(v != 0 for j, (v, _) in s.xdat.items() if j > 2):
        p.fail(nz[1] or s.type_line, f"SURF {k}: TOROIDAL Zernike terms (XDAT) are not supported")
    refuse_unread(p, s.parm, f"SURF {k}: TOROIDAL", "PARM 1 radius of rotation, PARM 2-9 the "
                  "y² ... y¹⁶ coefficients", range(1, 10))
    top = max([i for i in s.parm if 2 <= i <= 9 and s.parm[i][0] != 0] + [1])
    coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (3 - 2 * i) for i in range(2, top + 1)]
    hw = None if s.sqap is None else (s.sqap[0] * s_mm, s.sqap[1] * s_mm)
    if hw is not None and sd == PROVISIONAL_SD_MM:
        sd = math.hypot(*hw)
    r_rot = s.parm.get(1, (0.0, 0))[0]
    if r_rot != 0:
        return Toroid(c, sd, r_rot * s_mm, conic=s.coni, coefficients=coeffs, half_widths=hw)
    return Cylinder(c, sd, conic=s.coni, coefficients=coeffs, half_widths=hw)


def _biconic(s, k: int, c, sd, s_mm, p):
    """``BICONICX``: ``CURV``/``CONI`` the y curvature and conic, ``PARM 1`` the x *radius* (0:
    infinite, flat in x), ``PARM 2`` the x conic (OpticStudio's "Biconic" surface; it has no
    other parameter and no extra data): a :class:`Biconic`."""
    refuse_unread(p, s.parm, f"SURF {k}: BICONICX", "a biconic has PARM 1, the x radius, and "
                  "PARM 2, the x conic; a Biconic Zernike or other variant is not supported",
                  (1, 2))
    refuse_unread(p, s.xdat, f"SURF {k}: BICONICX", "a biconic has no extra data; a Biconic "
                  "Zernike or other variant is not supported", kind="XDAT")
    r_x = s.parm.get(1, (0.0, 0))[0]
    c_x = 0.0 if r_x == 0 else 1.0 / (r_x * s_mm)
    return Biconic(c, sd, c_x, conic=s.coni, conic_x=s.parm.get(2, (0.0, 0))[0])


def _grating(s, k: int, c, sd, p):
    """``DGRATING``: a sphere or conic (``CURV``, ``CONI``) ruled with ``PARM 1`` lines per
    micrometre (in every lens unit) parallel to the local x axis, traced in order ``PARM 2``:
    a :class:`Grating` (transmitting, or reflecting with ``GLAS MIRROR``)."""
    refuse_unread(p, s.parm, f"SURF {k}: DGRATING", "PARM 1 lines per micrometre, PARM 2 the "
                  "diffraction order", range(3))
    order, ln = s.parm.get(2, (0.0, s.type_line))
    if order != int(order):
        p.fail(ln, f"SURF {k}: the diffraction order (DGRATING PARM 2) must be an integer, got "
                   f"{order!r}")
    return Grating(c, sd, s.parm.get(1, (0.0, 0))[0], int(order), conic=s.coni)


def _binary2(s, k: int, c, sd, s_mm, p):
    """``BINARY_2`` (OpticStudio's "Binary 2"): an even asphere (``CURV``, ``CONI``, ``PARM 2..8``
    the ``r⁴ ... r¹⁶`` terms; ``PARM 1``, the ``r²`` term, must be 0) with the phase ``M Σ A_i
    ρ^{2i}``: ``PARM 0`` the diffraction order ``M``, ``XDAT 1`` the number of terms, ``XDAT 2``
    the normalisation radius (a length), ``XDAT 3..`` the ``A_i`` (radians): a :class:`Binary2`
    (transmitting, or reflecting with ``GLAS MIRROR``)."""
    refuse_unread(p, s.parm, f"SURF {k}: BINARY_2", "PARM 0 the diffraction order, PARM 1-8 the "
                  "even-asphere terms on r², ..., r¹⁶", range(9))
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
    n = xdat_term_count(p, s, k, "BINARY_2", "the number of phase terms", MAX_PHASE_TERMS,
                         "phase terms", below=False)
    phase, rn = _xdat_radius_and_terms(p, s, k, "BINARY_2", n, s_mm)
    top = max([i for i in range(2, 9) if s.parm.get(i, (0.0, 0))[0] != 0] + [1])
    coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i) for i in range(2, top + 1)]
    return Binary2(c, sd, rn, phase, int(order), conic=s.coni, coefficients=coeffs)


def _binary1(s, k: int, c, sd, s_mm, p):
    """``BINARY_1`` (OpticStudio's "Binary 1"): a conic base (``CURV``, ``CONI``) with the phase
    ``M Σ A_t E_t(x / R_n, y / R_n)`` (radians; the terms ``x, y, x², xy, y², ...`` of the
    Extended Polynomial): ``PARM 0`` must be 1 (``M`` = 1, the order OpticStudio's stored numbers
    confirm), ``XDAT 1`` the maximum term number (at most 230), ``XDAT 2`` the normalisation
    radius (a length), ``XDAT 3..`` ``A_1, A_2, ...`` (radians, unscaled): a :class:`Binary1`
    (sources: its module).  Other ``PARM`` values are refused on their line (no stored source
    gives their meaning)."""
    terms, rn = _phase_on_conic(p, s, k, "BINARY_1", "only 1 (diffraction order 1) is read, the "
                                "order OpticStudio's stored numbers confirm",
                                "the maximum term number", Binary1, "phase terms", s_mm)
    return Binary1(c, sd, rn, terms, 1, conic=s.coni)


def _qtype(s, k: int, c, sd, s_mm, p, qbfs_conic: str = "forbes"):
    """``QED_TYPE`` (OpticStudio's Q-type asphere): ``XDAT 1`` the type (0 Qbfs, 1 Qcon),
    ``XDAT 2`` the number of terms, ``XDAT 3`` the normalisation radius, ``XDAT 4..`` the
    coefficients ``a_0, a_1, ...`` (lengths): a :class:`QType`.  A Qbfs on a conic base
    (``CONI`` != 0), which no OpticStudio page defines: with ``qbfs_conic="forbes"`` read with
    Forbes' conic generalisation (the departure times ``sqrt((1 − k c² r²) / (1 − (1+k) c²
    r²))``, as optiland; deeplens' :class:`QType`) and one located warning at the ``TYPE``
    line naming that reading and the option; with ``"refuse"`` a located error."""
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
    refuse_unread(p, s.parm, f"SURF {k}: QED_TYPE", "the Q-type data are XDAT")
    if kind_v == 0.0 and s.coni != 0:
        if qbfs_conic == "refuse":
            p.fail(s.type_line, f"SURF {k}: a QED_TYPE Qbfs surface on a conic base (CONI "
                                f"{s.coni:g}) is refused (qbfs_conic='refuse'); "
                                f"qbfs_conic='forbes' (the default; --qbfs-conic forbes) reads "
                                f"it with Forbes' conic generalisation")
        p.note_each(s.type_line, QBFS_CONIC_CAUSE, f"SURF {k}", f"{s.coni:g}",
                    f"SURF {k}: CONI {s.coni:g}")
    coeffs = [s.xdat.get(j + 4, (0.0, 0))[0] * s_mm for j in range(n)]
    return QType(c, sd, rn_v * s_mm, coeffs, "qcon" if kind_v == 1.0 else "qbfs",
                 conic=s.coni)


_FORBES = ("Forbes' conic generalisation (2011; as optiland: the departure along the conic's "
           "normal, times sqrt((1 - k c^2 r^2)/(1 - (1+k) c^2 r^2))); OpticStudio's definition "
           "for a conic base is not documented")
#: QED_TYPE Qbfs surfaces on conic bases, read with Forbes' generalisation: one warning per file
QBFS_CONIC_CAUSE = Cause(
    one="{item}: a QED_TYPE Qbfs surface on a conic base (CONI {detail}) is read with "
        + _FORBES + "; qbfs_conic='refuse' (--qbfs-conic refuse) refuses it instead",
    many="{n} QED_TYPE Qbfs surfaces on conic bases ({items}) are read with " + _FORBES
         + "; qbfs_conic='refuse' (--qbfs-conic refuse) refuses them instead")
_PARAXIAL_CURV = ("deeplens' paraxial data (EFL, pupils, back focus) include them, as the sag's "
                  "curvature at the vertex; a reading from CURV alone (rayoptics 0.9's) gives "
                  "other first-order numbers")
#: Zernike sag surfaces whose rotationally symmetric terms curve the vertex
ZERNIKE_VERTEX_CAUSE = Cause(
    one="{item}: the rotationally symmetric Zernike terms {detail}: " + _PARAXIAL_CURV,
    many="{n} Zernike sag surfaces ({items}): their rotationally symmetric Zernike terms add to "
         "the vertex curvature from CURV: " + _PARAXIAL_CURV)


def _zernike_sag(s, k: int, c, sd, s_mm, p, cls=ZernikeSag):
    """``SZERNSAG`` (OpticStudio's "Zernike Standard Sag"): an even asphere (``CURV``, ``CONI``,
    ``PARM 1..8`` the ``r², r⁴, ..., r¹⁶`` terms) plus Zernike standard terms in Noll's order:
    ``PARM 0`` the extrapolate flag (1: the terms also beyond the normalisation radius),
    ``PARM 9``/``PARM 10`` the Zernike decenter (must be 0), ``XDAT 1`` the number of terms,
    ``XDAT 2`` the normalisation radius, ``XDAT 3..`` the coefficients ``A_1, A_2, ...``
    (lengths): a :class:`ZernikeSag`.  ``FZERNSAG`` (``cls`` :class:`ZernikeFringeSag`, the
    "Zernike Fringe Sag") has the same records with the Fringe terms (at most 37)."""
    tn = "FZERNSAG" if cls is ZernikeFringeSag else "SZERNSAG"
    for i, (v, ln) in sorted(s.parm.items()):
        if i in (9, 10) and v != 0:
            p.fail(ln, f"SURF {k}: {tn} PARM {i} (the Zernike decenter in "
                       f"{'x' if i == 9 else 'y'}) is not supported: deeplens' Zernike terms are "
                       f"centred on the vertex")
    refuse_unread(p, s.parm, f"SURF {k}: {tn}", "PARM 0 the extrapolate flag, PARM 1-8 the even "
                  "terms on r², ..., r¹⁶, PARM 9-10 the Zernike decenter", range(11))
    ext, ext_ln = s.parm.get(0, (1.0, s.type_line))
    if ext not in (0.0, 1.0):
        p.fail(ext_ln, f"SURF {k}: {tn} PARM 0 (the extrapolate flag) must be 0 or 1, got "
                       f"{ext!r}")
    n = xdat_term_count(p, s, k, tn, "the number of Zernike terms", cls.max_terms,
                         "Zernike terms")
    zern, rn = _xdat_radius_and_terms(p, s, k, tn, n, s_mm, scale=s_mm)
    top = max([i for i in range(1, 9) if s.parm.get(i, (0.0, 0))[0] != 0] + [0])
    coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i) for i in range(1, top + 1)]
    surf = cls(c, sd, rn, zern, conic=s.coni, coefficients=coeffs, extrapolate=ext == 1.0)
    # the rotationally symmetric terms (m = 0, n >= 2: Z4, Z9, ... in Fringe order, Z4, Z11, ...
    # in Noll's) curve the vertex: deeplens' paraxial data take the sag's vertex curvature with
    # them; a reader that takes CURV (+ the r² term) alone gets other first-order numbers
    nm = BASES[surf.basis][0]
    terms = [j for j, A in enumerate(zern, start=1) if A != 0.0 and nm(j)[1] == 0
             and nm(j)[0] >= 2]
    if terms:
        with torch.no_grad():
            dc = float(surf.paraxial_curvature()) - (c + 2.0 * (coeffs[0] if coeffs else 0.0))
        if dc != 0.0:
            p.note_each(s.xdat.get(terms[0] + 2, (0.0, s.type_line))[1] or s.type_line,
                        ZERNIKE_VERTEX_CAUSE, f"SURF {k}",
                        f"{', '.join(f'Z{j}' for j in terms)} add {dc:.4g} /mm to the vertex "
                        f"curvature ({c:.6g} /mm from CURV)", f"SURF {k}: {dc:+.4g} /mm")
    return surf


_FZERNPHA_BEYOND = Cause(
    one="{item}: the semi-diameter {detail}: the Zernike phase is continued beyond it (the "
        "polynomial extrapolated; OpticStudio's choice there is not in a stored source)",
    many="{n} FZERNPHA surfaces ({items}): the semi-diameter exceeds the normalisation radius: "
         "the Zernike phase is continued beyond it (the polynomial extrapolated; OpticStudio's "
         "choice there is not in a stored source)")


def _zernike_fringe_phase(s, k: int, c, sd, s_mm, p):
    """``FZERNPHA`` (OpticStudio's "Zernike Fringe Phase"): a conic base (``CURV``, ``CONI``)
    with the phase ``2π Σ A_j Z_j`` (Fringe order, ``A_j`` in waves): ``PARM 0`` must be 1 (the
    order 1 / extrapolate flag 1: no stored source says which, both read 1 alike), ``XDAT 1`` the
    number of terms (at most 37), ``XDAT 2`` the normalisation radius (a length), ``XDAT 3..``
    ``A_1, A_2, ...`` (waves, unscaled): a :class:`ZernikeFringePhase` (sources: its module).
    Other ``PARM`` values are refused on their line (no stored source gives their meaning)."""
    zern, rn = _phase_on_conic(p, s, k, "FZERNPHA", "only 1 is read (no stored source says "
                               "whether it is the diffraction order or the extrapolate flag; both "
                               "read 1 alike)", "the number of Zernike terms", ZernikeFringePhase,
                               "Zernike terms", s_mm)
    if zern and sd > rn and sd != PROVISIONAL_SD_MM:
        p.note_each(s.type_line, _FZERNPHA_BEYOND, f"SURF {k}",
                    f"{sd:g} mm exceeds the FZERNPHA normalisation radius {rn:g} mm",
                    f"SURF {k}: {sd:g} mm > {rn:g} mm")
    return ZernikeFringePhase(c, sd, rn, zern, 1, conic=s.coni)


def _paraxial_surface(s, k: int, mat, prev, sd, s_mm, p):
    """``PARAXIAL`` (``PARM 1`` = focal length): deeplens' :class:`IdealLens`, in air."""
    if 1 not in s.parm or s.parm[1][0] == 0:
        p.fail(s.type_line or s.line, f"SURF {k}: a PARAXIAL surface needs a non-zero focal "
                                      f"length (PARM 1)")
    if not (is_air(mat) and is_air(prev)):
        p.fail(s.glass_line or s.type_line, f"SURF {k}: a PARAXIAL surface between glasses is "
                                            f"not supported (deeplens' ideal lens sits in air)")
    refuse_unread(p, s.parm, f"SURF {k}: PARAXIAL", "only the focal length, PARM 1", range(3))
    return IdealLens(s.parm[1][0] * s_mm, sd)


def _xypolynom(s, c, sd, s_mm, p, k=None):
    """``XYPOLYNOM`` (deeplens' own record, CURV 0) and OpticStudio's ``XPOLYNOM`` ("Extended
    Polynomial": the STANDARD sag plus ``Σ_{t=1..N} A_t E_t(x / R_n, y / R_n)``, ``XDAT 1`` the
    maximum term number ``N`` <= 230, ``XDAT 2`` the normalisation radius ``R_n``, ``XDAT 3..``
    the ``A_t`` in lens units, terms in :func:`zemax_xy_terms` order).  On a flat base (``CURV``
    0, where a conic adds nothing) it is exactly the :class:`XYPolynomial` ``z = Σ a_ij x^i y^j``
    with, lengths in mm (``s`` mm per lens unit, ``x_mm = s x``, ``z_mm = s z``),
    ``a_ij = s A_t / (s R_n)^(i+j)`` (mm^(1-i-j)); on a curved base an
    :class:`ExtendedPolynomial` (the conic, ``R_n`` in mm and the ``s A_t``)."""
    typ = s.type if s.type in ("XPOLYNOM", "XYPOLYNOM") else "XYPOLYNOM"
    where = f"SURF {k}: " if k is not None else ""
    if typ == "XPOLYNOM":
        refuse_unread(p, s.parm, f"{where}XPOLYNOM", "the Extended Polynomial's data are XDAT 1 "
                      "the term count, XDAT 2 the normalisation radius, XDAT 3.. the terms")
    if c != 0 and typ == "XYPOLYNOM":
        p.fail(s.line, "XYPOLYNOM with a base curvature (CURV != 0) is not supported: deeplens' XY "
                       "polynomial is z = P(x, y) (put the base sphere into the polynomial)")
    if 1 not in s.xdat or 2 not in s.xdat:
        p.fail(s.type_line or s.line, f"{where}{typ} without XDAT 1 (number of terms) and XDAT 2 "
                                      f"(normalisation radius)")
    n_v, n_ln = s.xdat[1]
    R = s.xdat[2][0] * s_mm
    if not R > 0:
        p.fail(s.xdat[2][1], f"{where}{typ} normalisation radius must be > 0, got "
                             f"{s.xdat[2][0]!r}")
    most = XPOLYNOM_MAX_TERMS if typ == "XPOLYNOM" else 2079   # XYPOLYNOM: degrees 1..63
    if n_v != int(n_v) or not 1 <= n_v <= most:
        p.fail(n_ln, f"{where}{typ} number of terms (XDAT 1) must be an integer 1..{most}, got "
                     f"{n_v!r}")
    nterms = int(n_v)
    for j, (v, ln) in s.xdat.items():
        if j > nterms + 2 and v != 0:
            p.fail(ln, f"{where}XDAT {j} lies beyond the {nterms} terms XDAT 1 declares")
    zterms = zemax_xy_terms(nterms)
    if c != 0:
        # a curved base: the conic plus the terms, A_t (lens units) in mm on x / R_n, y / R_n
        return ExtendedPolynomial(c, sd, R, [s.xdat.get(j + 2, (0.0, 0))[0] * s_mm
                                             for j in range(1, nterms + 1)], conic=s.coni)
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


def _xasphere(s, k: int, c, sd, s_mm, p):
    """``XASPHERE`` (OpticStudio's "Extended Asphere"): the STANDARD sag (``CURV``, ``CONI``)
    plus ``Σ_{i=1..N} α_i ρ^{2i}``, ``ρ = r / R_n``, the coefficients ``α_i`` in lens units:
    ``XDAT 1`` the maximum term number ``N`` (<= 240), ``XDAT 2`` the normalisation radius
    ``R_n``, ``XDAT 3..`` ``α_1`` (on ρ²), ``α_2`` (on ρ⁴), ... (OpticStudio User Guide,
    "Extended Asphere": the even asphere's series in a normalised radial coordinate, even
    powers only).  The same surface as an even asphere: ``a_{2i} = α_i / R_n^{2i}`` (mm), an
    :class:`Asphere` (an :class:`OddAsphere` with its odd terms zero when ``α_1`` != 0).
    Terms up to ρ²⁰ (10) are read; a non-zero one beyond is refused with its line."""
    refuse_unread(p, s.parm, f"SURF {k}: XASPHERE", "the Extended Asphere's data are XDAT 1 the "
                  "number of terms, XDAT 2 the normalisation radius, XDAT 3.. the coefficients "
                  "on ρ², ρ⁴, ...")
    n = xdat_term_count(p, s, k, "XASPHERE", "the maximum term number", XASPHERE_MAX_TERMS,
                         "terms")
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


# --------------------------------------------------------------------------- writers' helpers
def _opening_records(s, i: int) -> list[str]:
    """The clear-aperture records of a curved surface: ``SQAP`` (a rectangular opening in its
    circumscribed circle) or ``CLAP`` (a circle narrower than the semi-diameter, or off-axis),
    each with ``OBDC`` when decentred, then ``OBSC`` (a central obscuration)."""
    out = []
    rect = getattr(s, "clear_rect", None)
    ell = clear_ellipse_of(s)
    if ell is not None:
        if abs(float(s.clear_radius) - max(ell)) > 1e-12 * float(s.clear_radius):
            raise ZemaxFileError(f"surface {i}: an elliptical clear aperture inside a narrower "
                                 f"clear circle has no Zemax record (ELAP or CLAP, not both)",
                                 surfaces=(i,))
        out.append(f"ELAP {_f(ell[0])} {_f(ell[1])} 0")
    elif rect is not None and bool(rect.any()):
        if abs(float(s.clear_radius) - math.hypot(*map(float, rect))) > 1e-12 * \
                float(s.clear_radius):
            raise ZemaxFileError(f"surface {i}: a rectangular clear aperture inside a narrower "
                                 f"clear circle has no Zemax record (SQAP or CLAP, not both)",
                                 surfaces=(i,))
        out.append(f"SQAP {_f(rect[0])} {_f(rect[1])} 0")
    elif math.isfinite(float(s.clear_radius)):
        out.append(f"CLAP 0 {_f(s.clear_radius)} 0")
    if out and bool(s.clear_decenter.any()):
        out.append(f"OBDC {_f(s.clear_decenter[0])} {_f(s.clear_decenter[1])}")
    obs = obscuration_ellipse_of(s)
    if obs is not None and (out or float(s.obscuration) > 0):
        raise ZemaxFileError(f"surface {i}: an elliptical obscuration beside another surface "
                             f"aperture has no Zemax record (one aperture type per surface)",
                             surfaces=(i,))
    if obs is not None:
        out.append(f"ELOB {_f(obs[0])} {_f(obs[1])} 0")
    if float(s.obscuration) > 0:
        out.append(f"OBSC 0 {_f(s.obscuration)} 0")
    return out


def _odd_asphere_lines(s: OddAsphere, i: int) -> list[str]:
    """An :class:`OddAsphere`: ``EVENASPH`` with ``PARM 1`` (the r² term) when its odd terms are
    all zero and it has an r² term (how the reader got it), else ``ODDASPHE`` (``PARM i`` on
    ``r^i``, up to r⁸)."""
    a = [float(v) for v in s.a]
    head = [f"CURV {_f(s.c)}", f"CONI {_f(s.k)}"]
    if len(a) >= 2 and a[1] != 0 and not any(a[0::2]):
        if len(a) > 16:
            raise ZemaxFileError(f"surface {i}: an odd asphere with terms up to r^{len(a)}; "
                                 f"Zemax's EVENASPH holds r^2..r^16", surfaces=(i,))
        return ["TYPE EVENASPH"] + head + [f"PARM {k + 1} {_f(v)}"
                                           for k, v in enumerate(a[1::2])]
    if len(a) > 8:
        raise ZemaxFileError(f"surface {i}: an odd asphere with terms up to r^{len(a)}; Zemax's "
                             f"ODDASPHE holds r^1..r^8", surfaces=(i,))
    return ["TYPE ODDASPHE"] + head + [f"PARM {k + 1} {_f(v)}" for k, v in enumerate(a)]


# --------------------------------------------------------------------------- the handlers
@register_format
class ApertureFormat(SurfaceFormat):
    """:class:`Aperture` (a flat opening in air): read through ``STANDARD`` (a flat surface in
    air, :class:`AsphereFormat`) and CODE V's ``SPH``; written as ``STANDARD`` with ``DIAM`` and
    its ``SQAP``, ``CLAP``/``OBSC``, ``OBDC``."""

    classes = (Aperture,)

    def write_zmx(self, s, i):
        lines = ["TYPE STANDARD", "CURV 0.0"]
        sd = None if s.semi_diameter is None else float(s.semi_diameter)
        if sd is not None:
            lines.append(_diam(sd))
        if s.shape == "rect":
            lines.append(f"SQAP {_f(s.half_widths[0])} {_f(s.half_widths[1])} 0")
        elif s.shape == "ellipse":
            lines.append(f"ELAP {_f(s.half_widths[0])} {_f(s.half_widths[1])} 0")
        elif s.decentred:   # OBDC moves a CLAP (annular: with its obscuration), not a DIAM
            if float(s.obscuration_inner) > 0:
                raise ZemaxFileError(f"surface {i}: a decentred opening with a ring obscuration "
                                     f"has no Zemax record here (OBDC moves a CLAP, whose "
                                     f"obscuration is central)", surfaces=(i,))
            lines.append(f"CLAP {_f(s.obscuration)} {_f(sd)} 0")
        if float(s.obscuration) > 0 and not s.decentred:   # a ring: OBSC inner outer
            ri = float(s.obscuration_inner)
            lines.append(f"OBSC {_f(ri) if ri > 0 else 0} {_f(s.obscuration)} 0")
        spi = s.spider_of()
        if spi is not None:   # its only surface aperture (no CLAP: one type per surface)
            if s.decentred or spi[2] != 0.0:
                raise ZemaxFileError(f"surface {i}: a decentred spider or one whose first arm "
                                     f"is not along +x (angle {math.degrees(spi[2]):g} deg) "
                                     f"has no Zemax record here (SPID's first arm lies along "
                                     f"+x; OBDC with SPID is not read)", surfaces=(i,))
            lines.append(f"SPID {_f(spi[0])} {spi[1]} 0")
        ell = obscuration_ellipse_of(s)
        if ell is not None:   # its only surface aperture (no CLAP: one type per surface)
            if s.decentred:
                raise ZemaxFileError(f"surface {i}: a decentred elliptical obscuration has no "
                                     f"Zemax record here (OBDC with ELOB is not read)",
                                     surfaces=(i,))
            lines.append(f"ELOB {_f(ell[0])} {_f(ell[1])} 0")
        if s.decentred:
            lines.append(f"OBDC {_f(s.decenter[0])} {_f(s.decenter[1])}")
        return lines

    def write_codev(self, s, i, stop):
        # a central obscuration is written by write_seq (CIR OBS); a ring one has no equivalent;
        # a rectangle (decentred or not) as REX/REY (ADX/ADY) by write_seq (codev_apertures)
        if float(s.obscuration_inner) > 0 or (s.decentred and s.shape == "circle"):
            raise LensFileError(f"surface {i}: a ring-obscured or decentred circular aperture "
                                f"has no CODE V equivalent here", surfaces=(i,))
        return ["0.0"]


@register_format
class PlaneFormat(SurfaceFormat):
    """:class:`Plane` (a flat surface between two media, or a flat mirror): read through
    ``STANDARD`` and CODE V's ``SPH``; written as a flat ``STANDARD``."""

    classes = (Plane,)

    def write_zmx(self, s, i):
        return ["TYPE STANDARD", "CURV 0.0", _diam(s.semi_diameter)]

    def write_codev(self, s, i, stop):
        return ["0.0"]


class _StandardFamily(SurfaceFormat):
    """What ``STANDARD``, ``EVENASPH`` and ``ODDASPHE`` share: a flat one is a dummy (when
    nothing else marks it), an :class:`Aperture` in air or a :class:`Plane`; a curved one an
    :class:`Asphere`, or an :class:`OddAsphere` with odd or ``r²`` terms."""

    @staticmethod
    def _terms(s, ctx: ZmxContext):
        """``(coeffs, radial)``: an :class:`Asphere`'s ``a4, a6, ...`` and an
        :class:`OddAsphere`'s ``a1, a2, ...`` (``None``: not an odd asphere)."""
        s_mm = ctx.s_mm
        radial = _radial_coefficients(s, ctx.k, s_mm, ctx.p)   # ODDASPHE, EVENASPH with PARM 1
        coeffs = []
        if s.type == "EVENASPH" and radial is None:
            # as many terms as PARM lines (a4 = PARM 2, ...); a file listing all 8 (as
            # OpticStudio writes) is trimmed of its trailing zero terms
            top = max([i for i in s.parm if i <= 8] + [1])
            coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i)
                      for i in range(2, top + 1)]
            if top == 8:
                while coeffs and coeffs[-1] == 0.0:
                    coeffs.pop()
        return coeffs, radial

    def zmx_flat(self, s, ctx):
        coeffs, radial = self._terms(s, ctx)
        return ctx.c == 0 and s.coni == 0 and not coeffs and not radial

    def read_zmx(self, s, ctx):
        coeffs, radial = self._terms(s, ctx)
        c, sd, sd_build, s_mm, flat = ctx.c, ctx.sd, ctx.sd_build, ctx.s_mm, ctx.flat
        in_air = is_air(ctx.mat) and is_air(ctx.prev)
        if s.sqap is not None and flat and in_air and not s.mirror:
            hx, hy, _ = s.sqap
            return Aperture(sd if sd > 0 else None, "rect", hx * s_mm, hy * s_mm)
        if s.elap is not None and flat and in_air and not s.mirror:   # ELAP: an ellipse
            a, b, _ = s.elap
            return Aperture(sd if sd > 0 else None, "ellipse", a * s_mm, b * s_mm)
        if s.obsc is not None and flat and in_air:
            # OpticStudio clips only on the obscuration here (and on a CLAP or a fixed
            # DIAM): an automatic DIAM, the beam's extent, is widened by 1 %
            outer = sd if (s.clap is not None or ctx.fixed or s.stop) else 1.01 * sd
            ro = s.obsc[0] * s_mm
            ri = 0.0 if s.obsc_inner is None else s.obsc_inner[0] * s_mm   # a ring baffle
            return Aperture(outer if outer > 0 else 2.0 * ro, obscuration=ro,
                            obscuration_inner=ri)
        if s.elob is not None and flat and in_air:   # ELOB: as OBSC, an elliptical one
            outer = sd if (ctx.fixed or s.stop) else 1.01 * sd
            ab = (s.elob[0] * s_mm, s.elob[1] * s_mm)
            return Aperture(outer if outer > max(ab) else 2.0 * max(ab), obscuration_ellipse=ab)
        if s.spid is not None and flat and in_air:   # SPID: a spider, the surface's obscuration
            outer = sd if (ctx.fixed or s.stop) else 1.01 * sd
            return Aperture(outer if outer > 0 else sd_build,
                            spider=(s.spid[0] * s_mm, s.spid[1], math.radians(s.spid_angle)))
        if flat and in_air and not s.mirror:
            return Aperture(sd_build)
        if flat and s.obdc is None:
            return Plane(sd_build)
        # (a flat surface between media or a flat mirror with a decentred opening, OBDC: a
        # flat Asphere, whose clear aperture can be off the vertex, as a curved one's)
        if radial:
            return OddAsphere(c, sd_build, conic=s.coni, coefficients=radial)
        return Asphere(c, sd_build, conic=s.coni, coefficients=coeffs)


@register_format
class AsphereFormat(_StandardFamily):
    """:class:`Asphere` (a sphere, a conic, an even asphere): Zemax ``STANDARD``/``EVENASPH``
    (``PARM 2..8`` on ``r⁴ ... r¹⁶``), beyond ``r¹⁶`` ``XASPHERE``; CODE V ``SPH``/``CON``/``ASP``
    with ``K`` and ``A`` ... ``J`` on ``r⁴ ... r²⁰``."""

    classes = (Asphere,)
    zmx_types = ("STANDARD", "EVENASPH")
    shape_only = True
    codev_types = ("SPH", "CON", "ASP")
    codev_data = ("K",) + tuple(CODEV_ASPH)

    def write_zmx(self, s, i):
        a = [float(v) for v in s.a]
        sd = s.semi_diameter
        if len(a) > 7:   # beyond EVENASPH's a16: OpticStudio's Extended Asphere, R_n = 1 mm
            lines = ["TYPE XASPHERE", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}",
                     f"XDAT 1 {len(a) + 1}", "XDAT 2 1", "XDAT 3 0"]
            lines += [f"XDAT {k + 4} {_f(v)}" for k, v in enumerate(a)]
            lines.append(_diam(sd))
            return lines + _opening_records(s, i)
        lines = ["TYPE EVENASPH" if a else "TYPE STANDARD", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}"]
        if a:
            lines.append("PARM 1 0")
            lines += [f"PARM {k + 2} {_f(v)}" for k, v in enumerate(a)]
        lines.append(_diam(sd))
        return lines + _opening_records(s, i)

    def codev_modifier(self, rec, cmd, value, fail):
        need = ("CON", "ASP") if cmd == "K" else ("ASP",)
        if rec["type"] not in need:
            fail(f"{cmd} on a {rec['type']} surface: expected {' or '.join(need)} before it")
        if cmd == "K":
            rec["k"] = value
        else:
            rec["coef"][CODEV_ASPH.index(cmd)] = value

    def read_codev(self, rec, c, sd, u, flat_air):
        if flat_air:
            return Aperture(sd)
        if rec["type"] == "SPH" and c == 0:
            return Plane(sd)
        n = max(rec["coef"], default=-1) + 1
        coef = [rec["coef"].get(j, 0.0) * u ** (1 - 2 * (j + 2)) for j in range(n)]
        while coef and coef[-1] == 0:   # trailing zero terms (A 1e-6; B 0) are no terms
            coef.pop()
        return Asphere(c, sd, rec["k"], coef)

    def write_codev(self, s, i, stop):
        # a central obscuration is written by write_seq (CIR OBS)
        rect = clear_rect_of(s)   # REX/REY (ADX/ADY), written by write_seq: its clear circle
        ell = clear_ellipse_of(s)   # ELX/ELY likewise
        as_read = ((rect is not None and float(s.clear_radius) == math.hypot(*rect))
                   or (ell is not None and float(s.clear_radius) == max(ell)))   # circumscribes
        if not as_read and ((math.isfinite(float(s.clear_radius)) and not stop) or
                            rect is not None or ell is not None
                            or any(float(v) for v in s.clear_decenter)):
            raise LensFileError(f"surface {i}: a decentred clear aperture or one narrower than "
                                f"the semi-diameter (other than on the stop) has no CODE V "
                                f"equivalent here", surfaces=(i,))
        a = [float(v) for v in s.a]
        while a and a[-1] == 0:
            a.pop()
        k = float(s.k)
        out = [_f(s.c)]
        if a:
            if len(a) > len(CODEV_ASPH):
                raise LensFileError(f"surface {i}: {len(a)} aspheric terms; CODE V's ASP holds "
                                    f"A..J (r⁴..r²⁰)", surfaces=(i,))
            out += ["ASP", f"K {_f(k)}"] + [f"{CODEV_ASPH[j]} {_f(v)}" for j, v in enumerate(a)]
        elif k != 0:
            out += ["CON", f"K {_f(k)}"]
        return out


@register_format
class OddAsphereFormat(_StandardFamily):
    """:class:`OddAsphere`: Zemax ``ODDASPHE`` (``PARM i`` on ``r^i``, i = 1..8; an ``EVENASPH``
    with ``PARM 1``, the ``r²`` term, is read as one too), written as ``EVENASPH`` when only its
    even terms and an ``r²`` term are non-zero, else ``ODDASPHE``."""

    classes = (OddAsphere,)
    zmx_types = ("ODDASPHE",)
    shape_only = True

    def write_zmx(self, s, i):
        return _odd_asphere_lines(s, i) + [_diam(s.semi_diameter)]


@register_format
class CoordinateBreakFormat(SurfaceFormat):
    """:class:`CoordinateBreak`: Zemax ``COORDBRK`` (``PARM 1..6``: decenter x, y, tilt about
    x, y, z in degrees, order).  Read by the reader's sequence, not one block at a time
    (:func:`.zmx_read._sequence`: a pair bracketing an element is its misalignment, any other a
    :class:`CoordinateBreak`, :mod:`.zmx_coordbrk`); written here."""

    classes = (CoordinateBreak,)
    zmx_types = ("COORDBRK",)
    shape_only = False

    def write_zmx(self, s, i):
        return coordbrk_lines(s, _f)


@register_format
class XYPolynomialFormat(SurfaceFormat):
    """:class:`XYPolynomial`: OpticStudio's ``XPOLYNOM`` ("Extended Polynomial", on a flat
    base) and deeplens' older ``XYPOLYNOM`` record of the same layout (``XDAT 1`` the number of
    terms, ``XDAT 2`` the normalisation radius, ``XDAT 3..`` the coefficients of ``x^i y^j`` by
    degree, :func:`zemax_xy_terms`); written as ``XPOLYNOM`` with ``R_n`` = 1 mm (so that a
    lens in mm reads back bit for bit).  ``XYPOLYNOM`` is deeplens' own name, in no OpticStudio
    source at hand; the writer wrote it until branch ``xpoly``."""

    classes = (XYPolynomial,)
    zmx_types = ("XPOLYNOM", "XYPOLYNOM")
    shape_only = True

    def read_zmx(self, s, ctx):
        return _xypolynom(s, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p, ctx.k)

    def write_zmx(self, s, i):
        if float(s.b) != 0:
            raise ZemaxFileError(f"surface {i}: an XY polynomial with b != 0 (z² term) has no "
                                 f"XPOLYNOM equivalent", surfaces=(i,))
        vals = {t: float(v) for t, v in zip(s.terms, s.a)}
        if vals.get((0, 0), 0.0) != 0:
            raise ZemaxFileError(f"surface {i}: an XY polynomial with a constant term has no "
                                 f"XPOLYNOM equivalent", surfaces=(i,))
        # every term up to the surface's order (its order reads back), at least one
        zterms = zemax_xy_terms(max(1, s.order * (s.order + 3) // 2))
        if len(zterms) > XPOLYNOM_MAX_TERMS:
            raise ZemaxFileError(f"surface {i}: an XY polynomial of order {s.order} has terms "
                                 f"beyond OpticStudio's Extended Polynomial's "
                                 f"{XPOLYNOM_MAX_TERMS} (order 20)", surfaces=(i,))
        lines = ["TYPE XPOLYNOM", "CURV 0.0", _diam(float(s.semi_diameter)),
                 f"XDAT 1 {len(zterms)}", "XDAT 2 1.0"]
        # R_n = 1 mm: A = a (x^i y^j in mm, z in mm), no scaling
        lines += [f"XDAT {j + 3} {_f(vals.get(t, 0.0))}" for j, t in enumerate(zterms)]
        return lines


@register_format
class ExtendedPolynomialFormat(SurfaceFormat):
    """:class:`ExtendedPolynomial` (an ``XPOLYNOM`` on a curved base, read by
    :class:`XYPolynomialFormat`): written as ``XPOLYNOM`` with its ``CURV``, ``CONI``,
    ``R_n`` and terms."""

    classes = (ExtendedPolynomial,)

    def write_zmx(self, s, i):
        terms = [float(v) for v in s.poly] or [0.0]
        return (["TYPE XPOLYNOM", f"CURV {_f(float(s.c))}", f"CONI {_f(float(s.k))}",
                 _diam(float(s.semi_diameter)), f"XDAT 1 {len(terms)}",
                 f"XDAT 2 {_f(float(s.norm_radius))}"]
                + [f"XDAT {t + 3} {_f(v)}" for t, v in enumerate(terms)])


@register_format
class TiltedFormat(SurfaceFormat):
    """Zemax ``TILTSURF`` (OpticStudio's "Tilted" surface: a plane ``z = x tan θ_x + y tan θ_y``,
    ``PARM 1`` = ``tan θ_x``, ``PARM 2`` = ``tan θ_y``, no curvature; it does not change the
    local frame; OpticStudio User Guide, "Tilted").  Both tangents zero: the flat ``STANDARD``
    surface (a dummy, an opening or an interface, read as one); otherwise an
    :class:`XYPolynomial` with the linear terms ``y tan θ_y + x tan θ_x`` (written back as
    ``XPOLYNOM``)."""

    zmx_types = ("TILTSURF",)
    shape_only = True

    @staticmethod
    def _tangents(s, k, p):
        refuse_unread(p, s.parm, f"SURF {k}: TILTSURF", "PARM 1 and 2 are the x and y tangents",
                      (1, 2))
        if s.curv != 0:
            p.fail(s.curv_line or s.type_line, f"SURF {k}: a TILTSURF (a tilted plane) has no "
                                               f"curvature, got CURV {s.curv:g}")
        return s.parm.get(1, (0.0, 0))[0], s.parm.get(2, (0.0, 0))[0]

    @staticmethod
    def _as_standard(s):
        import dataclasses

        return dataclasses.replace(s, type="STANDARD", parm={})

    def zmx_flat(self, s, ctx):
        return self._tangents(s, ctx.k, ctx.p) == (0.0, 0.0)

    def read_zmx(self, s, ctx):
        tx, ty = self._tangents(s, ctx.k, ctx.p)
        if (tx, ty) == (0.0, 0.0):
            return FORMATS.for_zmx_type("STANDARD").read_zmx(self._as_standard(s), ctx)
        return XYPolynomial(ctx.sd_build, [0.0, ty, tx])   # 1, y, x (dimensionless slopes)


@register_format
class JonesMatrixFormat(SurfaceFormat):
    """Zemax ``JONESMAT`` (OpticStudio's "Jones Matrix" surface: an idealised polarizer or
    retarder, ``PARM 1..8`` = Re/Im of the matrix elements A, B, C, D acting on (E_x, E_y)).
    The matrix changes a ray's polarization state and amplitude, not its path (Nicholson,
    "How to Use the Jones Matrix Surface", Zemax knowledge base, 2007: a "black box" for
    polarization effects "which do not affect beam direction"); the surface is a plane.  deeplens
    traces no polarization, so it is read as the flat ``STANDARD`` surface (an interface or a
    dummy, as the file's media make it) with one located note saying that the matrix is not
    applied.  A curvature or a ``PARM`` beyond 8 is refused with its line."""

    zmx_types = ("JONESMAT",)
    shape_only = True

    @staticmethod
    def _check(s, k, p):
        refuse_unread(p, s.parm, f"SURF {k}: JONESMAT", "PARM 1..8 are the Jones matrix's A, B, "
                      "C, D, real and imaginary parts", range(1, 9))
        if s.curv != 0:
            p.fail(s.curv_line or s.type_line, f"SURF {k}: a JONESMAT (Jones matrix) surface is "
                                               f"a plane, got CURV {s.curv:g}")

    def zmx_flat(self, s, ctx):
        self._check(s, ctx.k, ctx.p)
        return True

    def read_zmx(self, s, ctx):
        import dataclasses

        self._check(s, ctx.k, ctx.p)
        m = [s.parm.get(i, (0.0, 0))[0] for i in range(1, 9)]
        ctx.p.note_each(s.type_line, _JONES, f"SURF {ctx.k}",
                        f"A = {m[0]:g}{m[1]:+g}i, B = {m[2]:g}{m[3]:+g}i, C = "
                        f"{m[4]:g}{m[5]:+g}i, D = {m[6]:g}{m[7]:+g}i",
                        f"SURF {ctx.k}: A {m[0]:g}{m[1]:+g}i, B {m[2]:g}{m[3]:+g}i, C "
                        f"{m[4]:g}{m[5]:+g}i, D {m[6]:g}{m[7]:+g}i")
        return FORMATS.for_zmx_type("STANDARD").read_zmx(
            dataclasses.replace(s, type="STANDARD", parm={}), ctx)


_JONES = Cause(one="{item}: JONESMAT (Jones matrix {detail}) read as a plane: it changes "
                   "polarization and amplitude, not a ray's path, and deeplens traces no "
                   "polarization, so its transmission is not applied",
               many="{n} JONESMAT surfaces ({items}) read as planes: a Jones matrix changes "
                    "polarization and amplitude, not a ray's path, and deeplens traces no "
                    "polarization, so their transmission is not applied")

#: Birefringent In's mode flag (``PARM 1``): which ray is traced, and whether a beamsplitter
#: (split into configurations) or a waveplate (M. Nicholson, "The Birefringent Mode Flag",
#: Zemax knowledge base: modes 0 and 1 trace the ordinary or extraordinary ray of a
#: beamsplitter, modes 2 and 3 the input beam as the o or e ray of a waveplate)
BIREFRINGENT_MODES = {0: ("ordinary", "beamsplitter"), 1: ("extraordinary", "beamsplitter"),
                      2: ("ordinary", "waveplate"), 3: ("extraordinary", "waveplate")}


_BIRE_IN = Cause(one="{item}: birefringent-in surface ({detail}) read as a STANDARD surface into "
                     "its GLAS as the ordinary index: only the ordinary ray's path is traced, no "
                     "extraordinary ray, polarization or retardance",
                 many="{n} birefringent-in surfaces ({items}) read as STANDARD surfaces into "
                      "their GLAS as the ordinary index: only the ordinary ray's path is traced, "
                      "no extraordinary ray, polarization or retardance")


@register_format
class BirefringentFormat(SurfaceFormat):
    """Zemax ``BIRE__IN`` and ``BIRE_OUT`` (OpticStudio's "Birefringent In" and "Birefringent
    Out": birefringent ray tracing starts at the first and ends at the second; both have the
    Standard surface's shape, and the glass after ``BIRE__IN`` is the *ordinary* index, the
    extraordinary one a second catalogue glass of the name with ``-E``; M. Nicholson, "How to
    design birefringent polarizers", Zemax knowledge base, 2005: the "Birefringent-In Surface"
    page).  An ordinary ray "is refracted by n sin θ = n_o sin θ'", "just Snell's law" (ibid.),
    so where the mode flag (``PARM 1``, :data:`BIREFRINGENT_MODES`) traces the ordinary ray
    (0, 2) its path is exactly that through a plain glass of index ``n_o``: read as the
    ``STANDARD`` surface with one located warning naming the mode and that only the ordinary
    ray's path is traced (no extraordinary ray, no polarization or retardance).  An
    extraordinary mode (1, 3) is refused at its line: its index depends on the ray's angle to
    the crystal axis, and deeplens traces no birefringence.  ``BIRE_OUT``, where the ordinary
    ray leaves the crystal, is the ``STANDARD`` surface; a non-zero ``PARM`` on it is refused
    (no source at hand defines them).  ``PARM 1`` as the mode is read from the files (the
    knowledge base names the modes, not the column); the crystal axis and the other ``PARM``
    values do not change an ordinary ray's path."""

    zmx_types = ("BIRE__IN", "BIRE_OUT")
    shape_only = True

    @staticmethod
    def _mode(s, k, p):
        if s.type == "BIRE_OUT":
            refuse_unread(p, s.parm, f"SURF {k}: BIRE_OUT", "no source at hand defines a "
                          "Birefringent Out parameter")
            return None
        v, ln = s.parm.get(1, (0.0, s.type_line))
        if v not in BIREFRINGENT_MODES:
            p.fail(ln, f"SURF {k}: BIRE__IN mode (PARM 1) must be 0, 1, 2 or 3, got {v!r}")
        ray, kind = BIREFRINGENT_MODES[int(v)]
        if ray == "extraordinary":
            p.fail(ln, f"SURF {k}: a birefringent-in surface tracing the extraordinary ray "
                       f"(mode {int(v)}, {kind}): polarization ray tracing is not modelled")
        return int(v)

    @staticmethod
    def _as_standard(s):
        import dataclasses

        return dataclasses.replace(s, type="STANDARD", parm={}, xdat={})

    def zmx_flat(self, s, ctx):
        self._mode(s, ctx.k, ctx.p)
        return FORMATS.for_zmx_type("STANDARD").zmx_flat(self._as_standard(s), ctx)

    def read_zmx(self, s, ctx):
        mode = self._mode(s, ctx.k, ctx.p)
        if mode is not None:
            ray, kind = BIREFRINGENT_MODES[mode]
            ctx.p.note_each(s.type_line, _BIRE_IN, f"SURF {ctx.k}",
                            f"mode {mode}, the {ray} ray of a {kind}",
                            f"SURF {ctx.k}: mode {mode}")
        return FORMATS.for_zmx_type("STANDARD").read_zmx(self._as_standard(s), ctx)


@register_format
class ParaxialFormat(SurfaceFormat):
    """:class:`IdealLens`: Zemax ``PARAXIAL`` (``PARM 1`` the focal length), in air."""

    classes = (IdealLens,)
    zmx_types = ("PARAXIAL",)
    shape_only = False

    def read_zmx(self, s, ctx):
        return _paraxial_surface(s, ctx.k, ctx.mat, ctx.prev, ctx.sd_build, ctx.s_mm, ctx.p)

    def write_zmx(self, s, i):
        return ["TYPE PARAXIAL", "CURV 0.0", f"PARM 1 {_f(s.focal)}", _diam(s.semi_diameter)]


_PARAX_XY = Cause(one="{item}: PARAX_XY with {detail}: rays are traced through both; deeplens' "
                      "paraxial data (EFL, pupils, back focus) take the y section",
                  many="{n} PARAX_XY surfaces with unequal x and y powers ({items}): rays are "
                       "traced through both; deeplens' paraxial data (EFL, pupils, back focus) "
                       "take the y section")


def _paraxial_xy_surface(s, ctx):
    """``PARAX_XY`` (``PARM 1`` the x power, ``PARM 2`` the y power, 1/lens units): deeplens'
    :class:`IdealLensXY`, in air."""
    k, p = ctx.k, ctx.p
    if not (is_air(ctx.mat) and is_air(ctx.prev)):
        p.fail(s.glass_line or s.type_line, f"SURF {k}: a PARAX_XY surface between glasses is "
                                            f"not supported (deeplens' ideal lens sits in air)")
    refuse_unread(p, s.parm, f"SURF {k}: PARAX_XY", "PARM 1 the x power, PARM 2 the y power",
                  range(3))
    px, py = (s.parm.get(i, (0.0, 0))[0] / ctx.s_mm for i in (1, 2))
    if px == 0.0 and py == 0.0:
        p.fail(s.type_line or s.line, f"SURF {k}: a PARAX_XY surface needs a non-zero x or y "
                                      f"power (PARM 1, PARM 2)")
    if px != py:
        p.note_each(s.type_line or s.line, _PARAX_XY, f"SURF {k}",
                    f"x power {px:.6g} /mm and y power {py:.6g} /mm",
                    f"SURF {k}: {px:.6g} / {py:.6g} /mm")
    return IdealLensXY(px, py, ctx.sd_build)


@register_format
class ParaxialXYFormat(SurfaceFormat):
    """:class:`IdealLensXY`: Zemax ``PARAX_XY`` (``PARM 1``, ``PARM 2`` the x and y powers), in
    air."""

    classes = (IdealLensXY,)
    zmx_types = ("PARAX_XY",)
    shape_only = False

    def read_zmx(self, s, ctx):
        return _paraxial_xy_surface(s, ctx)

    def write_zmx(self, s, i):
        return ["TYPE PARAX_XY", "CURV 0.0", f"PARM 1 {_f(s.power_x)}", f"PARM 2 {_f(s.power_y)}",
                _diam(s.semi_diameter)]


@register_format
class ToroidalFormat(SurfaceFormat):
    """:class:`Cylinder` and :class:`Toroid`: Zemax ``TOROIDAL`` (``PARM 1`` the radius of
    rotation, 0 for a cylinder; ``PARM 2..9`` the y profile's ``y² ... y¹⁶`` terms; ``SQAP`` its
    rectangular outline)."""

    classes = (Cylinder,)
    zmx_types = ("TOROIDAL",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _cylinder(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p)

    def write_zmx(self, s, i):
        r_rot = _f(s.R) if isinstance(s, Toroid) else "0"
        lines = ["TYPE TOROIDAL", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}", f"PARM 1 {r_rot}"]
        lines += [f"PARM {j + 2} {_f(a)}" for j, a in enumerate(s.a)]
        lines.append(_diam(s.semi_diameter))
        if s.half_widths is not None:
            lines.append(f"SQAP {_f(s.half_widths[0])} {_f(s.half_widths[1])} 0")
        return lines


@register_format
class GratingFormat(SurfaceFormat):
    """:class:`Grating`: Zemax ``DGRATING`` (``PARM 1`` lines per micrometre, ``PARM 2`` the
    diffraction order)."""

    classes = (Grating,)
    zmx_types = ("DGRATING",)
    shape_only = False

    def read_zmx(self, s, ctx):
        return _grating(s, ctx.k, ctx.c, ctx.sd_build, ctx.p)

    def write_zmx(self, s, i):
        lines = ["TYPE DGRATING", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}", f"PARM 1 {_f(s.T)}",
                 f"PARM 2 {s.order}", _diam(s.semi_diameter)]
        return lines + _opening_records(s, i)


@register_format
class QTypeFormat(SurfaceFormat):
    """:class:`QType`: Zemax ``QED_TYPE`` (``XDAT 1`` the kind, ``XDAT 2`` the number of terms,
    ``XDAT 3`` the normalisation radius, ``XDAT 4..`` the coefficients)."""

    classes = (QType,)
    zmx_types = ("QED_TYPE",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _qtype(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p, ctx.qbfs_conic)

    def write_zmx(self, s, i):
        a = [float(v) for v in s.a]
        return ["TYPE QED_TYPE", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}",
                f"XDAT 1 {1 if s.kind == 'qcon' else 0}", f"XDAT 2 {len(a)}",
                f"XDAT 3 {_f(s.norm_radius)}"] + \
            [f"XDAT {j + 4} {_f(v)}" for j, v in enumerate(a)] + [_diam(s.semi_diameter)]


@register_format
class BiconicFormat(SurfaceFormat):
    """:class:`Biconic`: Zemax ``BICONICX`` (``PARM 1`` the x radius, 0 flat in x; ``PARM 2``
    the x conic)."""

    classes = (Biconic,)
    zmx_types = ("BICONICX",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _biconic(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p)

    def write_zmx(self, s, i):
        r_x = "0" if float(s.cx) == 0 else _f(1.0 / s.cx)
        return ["TYPE BICONICX", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}", f"PARM 1 {r_x}",
                f"PARM 2 {_f(s.kx)}", _diam(s.semi_diameter)]


@register_format
class Binary2Format(SurfaceFormat):
    """:class:`Binary2`: Zemax ``BINARY_2`` (``PARM 0`` the order, ``PARM 2..8`` ``a4 ... a16``,
    ``XDAT`` the phase terms)."""

    classes = (Binary2,)
    zmx_types = ("BINARY_2",)
    shape_only = False

    def read_zmx(self, s, ctx):
        return _binary2(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p)

    def write_zmx(self, s, i):
        a = [float(v) for v in s.a]
        if len(a) > 7:
            raise ZemaxFileError(f"surface {i}: {len(a)} aspheric terms; Zemax's BINARY_2 holds "
                                 f"a4..a16 (7 terms)", surfaces=(i,))
        A = [float(v) for v in s.A]
        lines = ["TYPE BINARY_2", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}", f"PARM 0 {s.order}",
                 "PARM 1 0"] + [f"PARM {j + 2} {_f(v)}" for j, v in enumerate(a)]
        lines += [f"XDAT 1 {len(A)}", f"XDAT 2 {_f(s.norm_radius)}"]
        lines += [f"XDAT {j + 3} {_f(v)}" for j, v in enumerate(A)]
        lines.append(_diam(s.semi_diameter))
        return lines + _opening_records(s, i)


def _phase_on_conic_lines(s, i: int, type_name: str, what: str, coefficients) -> list[str]:
    """The records of surface ``i``, a phase on a conic base (:class:`Binary1`,
    :class:`ZernikeFringePhase`, ``what`` in words) as ``type_name``: ``CURV``, ``CONI``,
    ``PARM 0 1``, ``XDAT 1`` the number of terms, ``XDAT 2`` the normalisation radius, ``XDAT
    3..`` the ``coefficients``, ``DIAM`` and the opening.  An order other than 1 is refused (the
    reader reads ``PARM 0 = 1`` only)."""
    if s.order != 1:
        raise ZemaxFileError(f"surface {i}: a {what} phase of order {s.order} is not written: "
                             f"{type_name} is read with PARM 0 = 1 only", surfaces=(i,))
    A = [float(v) for v in coefficients]
    lines = [f"TYPE {type_name}", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}", "PARM 0 1",
             f"XDAT 1 {len(A)}", f"XDAT 2 {_f(s.norm_radius)}"]
    lines += [f"XDAT {j + 3} {_f(v)}" for j, v in enumerate(A)]
    lines.append(_diam(s.semi_diameter))
    return lines + _opening_records(s, i)


@register_format
class Binary1Format(SurfaceFormat):
    """:class:`Binary1`: Zemax ``BINARY_1`` (``PARM 0 1``, ``XDAT 1`` the maximum term number,
    ``XDAT 2`` the normalisation radius, ``XDAT 3..`` the x-y polynomial phase terms in
    radians)."""

    classes = (Binary1,)
    zmx_types = ("BINARY_1",)
    shape_only = False

    def read_zmx(self, s, ctx):
        return _binary1(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p)

    def write_zmx(self, s, i):
        return _phase_on_conic_lines(s, i, "BINARY_1", "Binary 1", s.poly)


@register_format
class ZernikeSagFormat(SurfaceFormat):
    """:class:`ZernikeSag`: Zemax ``SZERNSAG`` (``PARM 0`` extrapolate, ``PARM 1..8``
    ``r² ... r¹⁶``, ``XDAT`` the Zernike standard terms)."""

    classes = (ZernikeSag,)
    zmx_types = ("SZERNSAG",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _zernike_sag(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p)

    def write_zmx(self, s, i):
        a = [float(v) for v in s.a]
        A = [float(v) for v in s.zernike]
        lines = [f"TYPE {self.zmx_types[0]}", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}",
                 f"PARM 0 {int(s.extrapolate)}"]
        lines += [f"PARM {j + 1} {_f(v)}" for j, v in enumerate(a)]
        lines += ["PARM 9 0", "PARM 10 0", f"XDAT 1 {len(A)}", f"XDAT 2 {_f(s.norm_radius)}"]
        lines += [f"XDAT {j + 3} {_f(v)}" for j, v in enumerate(A)]
        lines.append(_diam(s.semi_diameter))
        if float(s.obscuration) > 0:
            lines.append(f"OBSC 0 {_f(s.obscuration)} 0")
        return lines


@register_format
class ZernikeFringeSagFormat(ZernikeSagFormat):
    """:class:`ZernikeFringeSag`: Zemax ``FZERNSAG`` (the records of ``SZERNSAG``, the Zernike
    Fringe terms in ``XDAT 3..``)."""

    classes = (ZernikeFringeSag,)
    zmx_types = ("FZERNSAG",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _zernike_sag(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p, ZernikeFringeSag)


@register_format
class ZernikeFringePhaseFormat(SurfaceFormat):
    """:class:`ZernikeFringePhase`: Zemax ``FZERNPHA`` (``PARM 0 1``, ``XDAT 1`` the number of
    terms, ``XDAT 2`` the normalisation radius, ``XDAT 3..`` the Fringe coefficients in
    waves)."""

    classes = (ZernikeFringePhase,)
    zmx_types = ("FZERNPHA",)
    shape_only = False

    def zmx_flat(self, s, ctx):
        """A flat base with no non-zero coefficient (``XDAT 3..``) adds no phase: the flat
        ``STANDARD`` surface, a dummy between equal media (as OpticStudio's tolerancing files
        leave a zeroed phase surface at an off-axis mirror's vertex plane)."""
        return s.curv == 0 and not any(v != 0 for j, (v, _) in s.xdat.items() if j >= 3)

    def read_zmx(self, s, ctx):
        return _zernike_fringe_phase(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p)

    def write_zmx(self, s, i):
        return _phase_on_conic_lines(s, i, "FZERNPHA", "Zernike Fringe", s.zernike)


@register_format
class ExtendedAsphereFormat(SurfaceFormat):
    """Zemax ``XASPHERE`` (OpticStudio's Extended Asphere) -> an :class:`Asphere` (or an
    :class:`OddAsphere` with a ρ² term); an :class:`Asphere` with terms beyond ``r¹⁶`` is
    written as one by :class:`AsphereFormat`."""

    zmx_types = ("XASPHERE",)
    shape_only = True

    def read_zmx(self, s, ctx):
        return _xasphere(s, ctx.k, ctx.c, ctx.sd_build, ctx.s_mm, ctx.p)


# GRID_SAG's, IRREGULA's, HOLOGRM1/2's, GRINSUR1's, FRESNELS', US_ARRAY.DLL's and XOSPHERE's handlers live in their own modules; importing them registers them
# (after the built-in ones: the parser lists the types read in registration order)
from . import zmx_grid_sag  # noqa: E402,F401
from . import zmx_irregular  # noqa: E402,F401
from . import zmx_hologram  # noqa: E402,F401
from . import zmx_grin  # noqa: E402,F401
from . import zmx_fresnel  # noqa: E402,F401
from . import zmx_lenslet_array  # noqa: E402,F401
from . import zmx_xosphere  # noqa: E402,F401
