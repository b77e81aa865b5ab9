r"""Zemax OpticStudio sequential lens files (``.zmx``): read and write.

Surface sag of the types read (``c = CURV``, ``k = CONI``, ``r² = x² + y²``)::

    STANDARD   z = c r² / (1 + sqrt(1 − (1 + k) c² r²))
    EVENASPH   z = STANDARD + Σ_{i=1..8} α_i r^{2i}        (PARM i = α_i: an Asphere from r⁴, or
                                                          with PARM 1 != 0 an OddAsphere)
    ODDASPHE   z = STANDARD + Σ_{i=1..8} β_i r^i           (PARM i = β_i: an OddAsphere)
    XPOLYNOM   z = Σ_j A_j x^m y^n / R^(m+n)               (OpticStudio's Extended Polynomial: XDAT 1 =
                                                          number of terms <= 230, XDAT 2 = the
                                                          normalisation radius R, XDAT 3.. = A_j in
                                                          the order x, y, x², xy, y², x³, ...;
                                                          an XYPolynomial when CURV = 0, else an
                                                          ExtendedPolynomial: the conic + the terms;
                                                          XYPOLYNOM, deeplens' own older name, the
                                                          same, CURV 0 only)
    COORDBRK   x_before = δ + R x_after,  δ = (PARM 1, PARM 2, 0), R = R_x R_y R_z of the tilts
               PARM 3/4/5 in degrees (order flag PARM 6 = 0)
    PARAXIAL   an ideal thin lens of focal length PARM 1 (converging along the light's way for
               PARM 1 > 0, also after a mirror: a located note there)
    TOROIDAL   the y profile z_y = conic(y) + Σ PARM (i+1) y^{2i} turned about the axis parallel
               to y at z = R = PARM 1 (radius of rotation): z = R − sgn(ρ) sqrt(ρ² − x²),
               ρ = R − z_y (a Toroid); R = 0 (infinite) is a cylinder, z = z_y
    BICONICX   z = (c_x x² + c_y y²) / (1 + sqrt(1 − (1 + k_x) c_x² x² − (1 + k_y) c_y² y²)),
               c_y = CURV, k_y = CONI, c_x = 1 / PARM 1 (0: flat in x), k_x = PARM 2 (a Biconic)
    SZERNSAG   z = EVENASPH (PARM 1..8 on r², ..., r¹⁶) + Σ_j A_j Z_j(r / R_n, φ): Zernike
               standard terms in Noll's order (XDAT 1 = number of terms, XDAT 2 = R_n, XDAT 3.. =
               A_j; PARM 0 the extrapolate flag; a ZernikeSag)
    FZERNSAG   as SZERNSAG with the Zernike Fringe terms (at most 37, unnormalised, the
               Fringe order: a ZernikeFringeSag)
    TILTSURF   z = x PARM 1 + y PARM 2 (tangents of the tilts): the flat STANDARD surface when
               both are 0, else an XYPolynomial of those slopes
    XASPHERE   z = STANDARD + Σ_{i=1..N} α_i (r / R_n)^{2i} (Extended Asphere: XDAT 1 = N, XDAT 2 =
               R_n, XDAT 3.. = α_1, α_2, ... in lens units; read up to ρ²⁰ as an Asphere, or an
               OddAsphere with an r² term)
    XOSPHERE   z = STANDARD + Σ_{i=1..N} A_i (r / R_n)^i   (Extended Odd Asphere: XDAT 1 = N, XDAT 2 =
               R_n, XDAT 3.. = A_1, A_2, ... in lens units: an ExtendedOddAsphere; a non-zero
               ρ¹ term refused, :mod:`.zmx_xosphere`)
    JONESMAT   z = 0 (a Jones matrix surface, PARM 1..8 its A..D: read as the plane, its
               polarization and transmission not applied, with a located note)
    BIRE__IN   STANDARD into its GLAS as the ordinary index, in an ordinary-ray mode (PARM 1 = 0
               or 2), with a located note; BIRE_OUT: STANDARD (Birefringent In / Out)
    GRID_SAG   z = EVENASPH (PARM 1..8 on r², ..., r¹⁶) + the bicubic Hermite interpolant of
               the grid GDAT nx ny delx dely xdec ydec, GARR i z dz/dx dz/dy d2z/dxdy nodata
               (from the top left, -x +y); PARM 0 = 0 (bicubic); a GridSag (:mod:`.zmx_grid_sag`)
    FRESNELS   z = 0, refracting (or reflecting) about the normal of the facet profile EVENASPH
               (PARM 1..8 on r², ..., r¹⁶) above each hit: a Fresnel (:mod:`.zmx_fresnel`)

Mapping onto :class:`~deeplens.optics.lens.Lens` (mm, nm):

* ``UNIT`` (MM, CM, IN, METER) scales every length to mm; ``WAVM``/``WAVL`` are micrometres in the
  file and become nm; ``PWAV`` picks the primary wavelength; ``FTYP`` gives the field type and the
  number of active fields and wavelengths.
* ``SURF 0`` is the object (its ``DISZ``, possibly ``INFINITY``, is the object distance; a
  negative one is a virtual object behind the first vertex), the last
  ``SURF`` the image (the gap before it is the sensor distance, its ``DIAM`` the sensor
  semi-diameter).  ``DIAM`` is a semi-diameter.  ``DISZ`` is the gap to the next vertex.
* Aperture: ``ENPD`` -> ``epd``, ``FNUM v 0`` -> ``fno`` (image-space F-number at infinity),
  ``FLOA`` -> ``stop`` (the stop's own ``DIAM``); ``OBNA`` (finite object) and ``FNUM v 1``
  (paraxial working F-number) become the EPD they define (:mod:`.zmx_system`).  With ``epd`` or
  ``fno`` the stop may be any surface (a lens surface too): :meth:`Lens.apply_aperture_spec`
  sizes it paraxially.  ``RAIM`` sets ``lens.ray_aiming``, which picks the pupil sampling
  ``deeplens report`` uses (:func:`~.zmx_system.lens_pupil_convention`).
* Fields ``YFLN`` (and ``XFLN``, combined radially for a rotationally symmetric lens) with
  ``FTYP`` 0 (angle), 1 (object height, finite object: ``θ = -atan(h / (d_obj + z_EP))``), 2
  (paraxial image height: ``θ = atan(h' / f)`` at infinity, the object height ``h' / m`` at a
  finite object), 3 (real image height: the chief ray solved to land there) or 4 (theodolite
  angles, one component at a time).
* Dummy surfaces (flat, the same medium on both sides, not the stop, automatic ``DIAM``) carry only
  a thickness and are merged into the gaps; a flat air surface with a fixed ``DIAM`` becomes an
  :class:`~deeplens.optics.surfaces.Aperture` (rectangular with ``SQAP``, with a central
  obscuration with ``OBSC`` or an annular ``CLAP``; decentred by ``OBDC`` when it is not the
  stop); on a curved lens or mirror surface those are the surface's own ``obscuration``, and a
  circular ``CLAP`` or a rectangular ``SQAP`` (``clear_rect``), moved by ``OBDC``, its
  off-axis opening (``clear_radius``, ``clear_decenter``: an off-axis parabola, an off-axis
  telescope's mirrors).  A ``CLAP`` on a lens-surface stop narrower than the stop an
  ``ENPD``/``FNUM`` aperture defines is its ``clear_radius``: the pupil keeps its size and its
  rim is vignetted (refused on a flat stop in air).  A surface with no
  ``DIAM`` gets an automatic semi-diameter from real rays; automatic semi-diameters of two
  surfaces that cross within them are limited to where they meet (a warning; the file is
  refused when its on-axis beam reaches past that radius, rays OpticStudio would trace
  backwards); an image plane on a flat last vertex
  puts the sensor 1e-9 mm behind it (along the direction of travel: towards -z after an odd
  number of mirrors); so does one on a last coordinate break.
* ``COORDBRK`` pairs that bracket one element (decenter/tilt, the element, a return to its first
  vertex, and the reversing break) become that element's
  :class:`~deeplens.optics.misalignment.Misalignment` (``R = R_y(tilt_y) R_x(tilt_x)``; tilts
  about two axes, or about z, of a rotationally symmetric element become the two tilts that
  point its axis the same way); any other coordinate break (a fold, an off-axis mirror, a
  decenter never undone) becomes a :class:`~deeplens.optics.surfaces.CoordinateBreak` surface
  (:mod:`.zmx_coordbrk` decides which), and is written back as one.  In a lens with such breaks
  the automatic semi-diameters (``DIAM`` flag 0) are recomputed from deeplens' rays and fields
  with an x component are dropped (with a warning).
* ``GLAS name`` is looked up exactly in the catalogues named by ``GCAT``: the user's ``.agf`` files
  (:mod:`.agf`) by file stem, the vendor catalogues of :mod:`.vendor_glass` (current, then
  archived .agf, then previous) and deeplens' own catalogue, which answers for ``MISC``.  ``GLAS ___BLANK 1 0 n_d V_d``
  (a Zemax model glass) becomes a
  :class:`~deeplens.optics.materials.ModelGlass` (deeplens' Cauchy model: exact at n_d and V_d,
  Zemax's own model differs slightly elsewhere; ``V_d = 0`` is non-dispersive, and may then
  have ``n_d < 1``: OpticStudio's indices are relative to air).  A glass not found is an error naming it and its
  line, unless the caller passes ``glass_fallback``.

Lines understood but not used are reported as :class:`ZemaxWarning` with their line (one warning
per cause, naming every line it concerns: :mod:`.zmx_notes`); lines that
would change the optics if ignored (other surface types, obscurations on flat surfaces between
media, telecentric object space without an ``OBNA`` aperture, ...) are errors naming the file, the line and the feature, as a
:class:`ZemaxFileError` whose ``source``, ``line``, ``feature`` (the line's keyword) and ``surf``
(the file's surface number) are attributes (:mod:`deeplens.optics.errors`).
``GLAS MIRROR`` makes the surface a mirror (``Lens(mirrors=...)``; the medium after it is the one
before, and the file's negative thicknesses after it are kept: deeplens uses Zemax's sign
convention, see ``docs/guide/mirrors.md``).
Multi-configuration files (``MNUM``: zoom, focus): ``read_zmx(path, config=N)`` reads configuration
``N`` (default: the active one, as saved) and :func:`read_zmx_configs` every one, sharing the
surfaces no configuration changes; :mod:`.zmx_mconf` lists the operands applied and refused;
:func:`write_zmx_configs` writes such lenses back as one file (:mod:`.zmx_write_configs`).
:func:`write_zmx` writes what :func:`read_zmx` reads, so a lens read,
written and read again has the same prescription.

This module is the public face of the Zemax reader and writer; the work is done in
:mod:`.zmx_parse` (text -> records -> system data and ``SURF`` blocks, with their lines),
:mod:`.zmx_read` (blocks -> :class:`~deeplens.optics.lens.Lens`), with :mod:`.zmx_surfaces` (one
block -> one surface, by its type's handler), :mod:`.zmx_glass` (``GLAS`` -> material),
:mod:`.zmx_coordbrk` and :mod:`.zmx_system`, and :mod:`.zmx_write` (lens -> ``.zmx``); each
surface type's records are read and written by its handler in the file-format registry
(:mod:`.surface_formats`, the built-in handlers in :mod:`.surface_handlers`).
"""

from __future__ import annotations

from ..errors import ZemaxFileError, ZemaxWarning
from .zmx_glass import BUILTIN_CATALOGUES
from .zmx_configs import read_zmx_configs
from .zmx_read import read_zmx
from .zmx_system import lens_pupil_convention
from .zmx_write import write_zmx
from .zmx_write_configs import write_zmx_configs

__all__ = ["BUILTIN_CATALOGUES", "ZemaxFileError", "ZemaxWarning", "lens_pupil_convention",
           "read_zmx", "read_zmx_configs", "write_zmx", "write_zmx_configs"]
