r"""Zemax OpticStudio sequential lens files (``.zmx``): read and write.

Surface sag of the types read (``c = CURV``, ``k = CONI``, ``r² = x² + y²``)::

    STANDARD   z = c r² / (1 + sqrt(1 − (1 + k) c² r²))
    EVENASPH   z = STANDARD + Σ_{i=1..8} α_i r^{2i}        (PARM i = α_i; deeplens has no r² term,
                                                          so PARM 1 must be 0)
    XYPOLYNOM  z = Σ_j A_j x^m y^n / R^(m+n)               (XDAT 1 = number of terms, XDAT 2 = the
                                                          normalisation radius R, XDAT 3.. = A_j in
                                                          the order x, y, x², xy, y², x³, ...;
                                                          read when CURV = 0)
    COORDBRK   x_before = δ + R x_after,  δ = (PARM 1, PARM 2, 0), R = R_x R_y R_z of the tilts
               PARM 3/4/5 in degrees (order flag PARM 6 = 0)
    PARAXIAL   an ideal thin lens of focal length PARM 1
    TOROIDAL   with PARM 1 (radius of rotation) = 0: a cylinder, z = conic(y) + Σ PARM (i+1) y^{2i}

Mapping onto :class:`~deeplens.optics.lens.Lens` (mm, nm):

* ``UNIT`` (MM, CM, IN, METER) scales every length to mm; ``WAVM``/``WAVL`` are micrometres in the
  file and become nm; ``PWAV`` picks the primary wavelength; ``FTYP`` gives the field type and the
  number of active fields and wavelengths.
* ``SURF 0`` is the object (its ``DISZ``, possibly ``INFINITY``, is the object distance), the last
  ``SURF`` the image (the gap before it is the sensor distance, its ``DIAM`` the sensor
  semi-diameter).  ``DIAM`` is a semi-diameter.  ``DISZ`` is the gap to the next vertex.
* Aperture: ``ENPD`` -> ``epd``, ``FNUM v 0`` -> ``fno`` (image-space F-number at infinity),
  ``FLOA`` -> ``stop`` (the stop's own ``DIAM``); ``OBNA`` (finite object) and ``FNUM v 1``
  (paraxial working F-number) become the EPD they define (:mod:`.zmx_system`).  With ``epd`` or
  ``fno`` the stop may be any surface (a lens surface too): :meth:`Lens.apply_aperture_spec`
  sizes it paraxially.  ``RAIM`` sets ``lens.ray_aiming``, which picks the pupil sampling
  ``deeplens report`` uses (:func:`~.zmx_system.lens_pupil_convention`).
* Fields ``YFLN`` (and ``XFLN``, combined radially for a rotationally symmetric lens) with
  ``FTYP`` 0 (angle), 1 (object height, finite object: ``θ = atan(h / (d_obj + z_EP))``), 2
  (paraxial image height: ``θ = atan(h' / f)`` at infinity, the object height ``h' / m`` at a
  finite object), 3 (real image height: the chief ray solved to land there) or 4 (theodolite
  angles, one component at a time).
* Dummy surfaces (flat, the same medium on both sides, not the stop, automatic ``DIAM``) carry only
  a thickness and are merged into the gaps; a flat air surface with a fixed ``DIAM`` becomes an
  :class:`~deeplens.optics.surfaces.Aperture` (rectangular with ``SQAP``, with a central
  obscuration with ``OBSC`` or an annular ``CLAP``; decentred by ``OBDC`` when it is not the
  stop); on a curved lens or mirror surface those are the surface's own ``obscuration``.  A
  ``CLAP`` on the stop surface narrower than the stop an ``ENPD``/``FNUM`` aperture defines is
  refused (it would vignette the pupil; deeplens' stop has one radius).  A surface with no
  ``DIAM`` gets an automatic semi-diameter from real rays; an image plane on a flat last vertex
  puts the sensor 1e-9 mm behind it (along the direction of travel: towards -z after an odd
  number of mirrors).
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
  Zemax's own model differs slightly elsewhere; ``V_d = 0`` is non-dispersive).  A glass not found is an error naming it and its
  line, unless the caller passes ``glass_fallback``.

Lines understood but not used are reported as :class:`ZemaxWarning` with their line; lines that
would change the optics if ignored (other surface types, obscurations on flat surfaces between
media, telecentric object space, ...) are errors naming the file, the line and the feature.
``GLAS MIRROR`` makes the surface a mirror (``Lens(mirrors=...)``; the medium after it is the one
before, and the file's negative thicknesses after it are kept: deeplens uses Zemax's sign
convention, see ``docs/guide/mirrors.md``).
:func:`write_zmx` writes what :func:`read_zmx` reads, so a lens read,
written and read again has the same prescription.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..lens import Lens, LensSpec
from ..materials import GLASS_TABLE, Air, Material, ModelGlass, check_wavelength_nm, get_material
from ..surfaces import (Aperture, Asphere, CoordinateBreak, Cylinder, IdealLens, Plane,
                        XYPolynomial)
from ..surfaces.xy_polynomial import xy_terms
from .agf import AGFGlass, GlassCatalogue, decode_zemax_text, read_agf
from ..errors import LensFileError
from .zmx_coordbrk import (coordbrk_lines, coordinate_break, is_identity, misalignment_brackets,
                           y_fields_only)
from .zmx_system import (aperture_to_epd, element_tilts, fields_to_angles, lens_pupil_convention,
                         rotationally_symmetric, zemax_tilts)
from .vendor_glass import (ARCHIVED_CATALOGUES, CURRENT_CATALOGUES, PREVIOUS_CATALOGUES,
                           BuchdahlGlass, archived_glass, catalogue_size,
                           find_in_vendor_catalogues, previous_glass, vendor_glass)

__all__ = ["BUILTIN_CATALOGUES", "ZemaxFileError", "ZemaxWarning", "lens_pupil_convention",
           "read_zmx", "write_zmx"]


class ZemaxFileError(LensFileError):
    """A ``.zmx`` file that cannot be read (or a lens that cannot be written as one)."""


class ZemaxWarning(UserWarning):
    """A line of a ``.zmx`` file that was understood but is not used."""


_UNITS = {"MM": 1.0, "CM": 10.0, "IN": 25.4, "METER": 1000.0, "M": 1000.0}

# Which of deeplens' own catalogue entries answer for which Zemax catalogue name.
BUILTIN_CATALOGUES = {
    "SCHOTT": ("N-BK7", "N-SF5", "SF5", "N-SF6", "N-SF2", "N-SF10", "SF10", "N-SF11", "N-BAF10",
               "N-BAK1", "N-BAK4", "N-SK16", "N-SSK8", "F2", "N-F2", "N-LAK9", "N-LAK22",
               "N-LASF9", "N-LASF44", "N-K5", "N-PSK53A", "B270"),
    "MISC": ("F_SILICA", "SILICA", "FUSED_SILICA", "PMMA", "POLYCARB"),
}
"""Zemax catalogue name -> the names deeplens' built-in catalogue resolves for it (after the
vendor catalogues of :mod:`.vendor_glass`)."""

# the n_d / V_d OpticStudio writes on the GLAS line of a catalogue glass it has not evaluated
_PLACEHOLDER_ND_VD = (1.5, 40.0)

# surface types met in real files that deeplens refuses, and what they are
_DIFFRACTIVE = "out of scope: deeplens traces refraction and reflection, not diffraction orders"
_UNSUPPORTED_TYPES = {
    "QED_TYPE": "a Q-type (Forbes) asphere", "QTYPEASP": "a Q-type (Forbes) asphere",
    "DGRATING": f"a diffraction grating, {_DIFFRACTIVE}",
    "ELEMGRAT": f"an elliptical grating, {_DIFFRACTIVE}",
    "BINARY_1": f"a binary-optic (diffractive) surface, {_DIFFRACTIVE}",
    "BINARY_2": f"a binary-optic (diffractive) surface, {_DIFFRACTIVE}",
    "ODDASPH": "an odd asphere", "BICONICX": "a biconic", "GRINSUR1": "a gradient-index surface",
    "SZERNSAG": "a Zernike sag surface", "USERSURF": "a user-defined (DLL) surface",
    "GRID_SAG": "a grid-sag surface", "IRREGULA": "an irregular surface",
    "TILTSURF": "a tilted surface",
}

# the sensor distance used when a file puts the image plane on the last (flat) vertex
_IMAGE_ON_VERTEX_MM = 1e-9

# the semi-diameter a surface with no DIAM is built with before its automatic value is set
_PROVISIONAL_SD_MM = 1e-3

# Lines that describe editor state, drawing, tolerancing or non-optical data: skipped silently.
_SILENT = {
    "VERS", "MODE", "NAME", "PFIL", "LANG", "GFAC", "PUSH", "SDMA", "OMMA", "ROPD", "HYPR",
    "PICB", "FWGN", "POLS", "GLRS", "GSTD", "NSCD",
    "COFN", "FIMP", "HIDE", "MIRR", "SLAB", "MEMA", "POPS", "FLAP", "BLNK", "TOL",
    "MOFF", "COMM", "NOTE", "WWGT", "FWGT", "VDSZ", "VCON", "VPAR", "VCRV",
    "VTHI", "VCNT", "MAZH", "TOLE", "SCOL", "SDRW", "PZUP", "PPAR", "CONF", "DMFS", "BLDM",
    "RSCE", "RWRE", "TSCM", "STYP", "OPDX", "COAT", "CURVSOLV", "ISNA", "EFFL", "THSO",
    "AUTH", "IWDP", "LUID", "EERA", "SSID", "DBDT",
}


@dataclass
class _Surf:
    line: int
    type: str = "STANDARD"
    type_line: int = 0
    curv: float = 0.0
    disz: float = 0.0
    disz_line: int = 0
    coni: float = 0.0
    diam: float = 0.0
    diam_fixed: bool = False
    stop: bool = False
    glass: str | None = None
    glass_model: tuple | None = None   # (n_d, V_d) on the GLAS line
    glass_line: int = 0
    glass_model_name: str | None = None   # GLAS NAME 1 0 n_d V_d: a named model glass
    parm: dict = field(default_factory=dict)   # index -> (value, line)
    xdat: dict = field(default_factory=dict)   # index -> (value, line)
    clap: tuple | None = None
    sqap: tuple | None = None   # (x half-width, y half-width, line) in file units
    obsc: tuple | None = None   # (central obscuration radius, line) in file units
    mirror: bool = False               # GLAS MIRROR
    obdc: tuple | None = None   # (x, y aperture decenter, line) in file units


class _Parser:
    def __init__(self, path: Path):
        self.path = path
        self.notes: list[tuple[int, str]] = []

    def fail(self, ln, msg):
        where = f"{self.path}:{ln}" if ln else str(self.path)
        raise ZemaxFileError(f"{where}: {msg}")

    def note(self, ln, msg):
        self.notes.append((ln, msg))

    def num(self, tok, ln, what):
        try:
            v = float(tok)
        except (ValueError, TypeError):
            self.fail(ln, f"{what}: expected a number, got {tok!r}")
        if not math.isfinite(v):
            self.fail(ln, f"{what}: expected a finite number, got {tok!r}")
        return v

    def arg(self, toks, i, ln, what):
        if len(toks) <= i:
            self.fail(ln, f"{toks[0]} line is truncated: missing {what}")
        return self.num(toks[i], ln, f"{toks[0]} {what}")


def _parse(path: Path):
    """The raw file: ``(system dict, [_Surf, ...], parser)`` with lengths still in file units."""
    p = _Parser(path)
    try:
        text = decode_zemax_text(path)
    except UnicodeDecodeError as e:
        p.fail(0, f"not a UTF-8 or UTF-16 text file ({e.reason} at byte {e.start})")
    sysd = {"unit": ("MM", 0), "aperture": None, "ftyp": None, "xfln": None, "yfln": None,
            "waves": {}, "wavl": None, "pwav": (1, 0), "gcat": ([], 0), "name": "",
            "mode": None, "raim": (0, 0)}
    surfs: list[_Surf] = []
    cur: _Surf | None = None
    unused: dict[str, tuple[int, int]] = {}   # keyword -> (first line, count)
    for ln, line in enumerate(text.splitlines(), start=1):
        toks = line.split()
        if not toks:
            continue
        key = toks[0].upper()
        if key == "SURF":
            idx = int(p.arg(toks, 1, ln, "surface number"))
            if idx != len(surfs):
                p.fail(ln, f"SURF {idx} out of order: expected SURF {len(surfs)}")
            cur = _Surf(line=ln)
            surfs.append(cur)
            continue
        if key == "NAME":
            sysd["name"] = line.strip()[4:].strip()
        elif key == "MODE":
            if len(toks) > 1 and toks[1].upper() != "SEQ":
                p.fail(ln, f"MODE {toks[1]}: only sequential (MODE SEQ) files can be read")
        elif key == "UNIT":
            if len(toks) < 2 or toks[1].upper() not in _UNITS:
                p.fail(ln, f"UNIT: unknown lens unit {toks[1] if len(toks) > 1 else ''!r}; "
                           f"expected one of {', '.join(_UNITS)}")
            sysd["unit"] = (toks[1].upper(), ln)
        elif key == "ENPD":
            sysd["aperture"] = ("epd", p.arg(toks, 1, ln, "entrance-pupil diameter"), ln)
        elif key == "FNUM":
            v = p.arg(toks, 1, ln, "F-number")
            flag = p.num(toks[2], ln, "FNUM flag") if len(toks) > 2 else 0
            # flag 1: the paraxial working F-number, converted to an EPD once the lens is built
            sysd["aperture"] = ("wfno" if flag == 1 else "fno", v, ln)
        elif key == "FLOA":
            sysd["aperture"] = ("stop", None, ln)
        elif key == "OBNA":
            v = p.arg(toks, 1, ln, "object-space numerical aperture")
            flag = p.num(toks[2], ln, "OBNA flag") if len(toks) > 2 else 0
            # flag 0: n sin(θ) of the marginal ray; flag 1: the cone angle θ (degrees)
            sysd["aperture"] = ("cone" if flag == 1 else "obna", v, ln)
        elif key == "RAIM":
            # RAIM <unused> <type: 0 off, 1 paraxial, 2 real> ...
            sysd["raim"] = (int(p.num(toks[2], ln, "RAIM ray-aiming type")) if len(toks) > 2
                            else 0, ln)
        elif key == "FTYP":
            p.arg(toks, 1, ln, "field type")
            sysd["ftyp"] = ([int(p.num(t, ln, "FTYP")) for t in toks[1:]], ln)
        elif key in ("XFLN", "YFLN", "XFLD", "YFLD"):
            slot = key[0].lower() + "fln"      # XFLD/YFLD: older files; XFLN/YFLN win
            if len(toks) < 2:
                p.fail(ln, f"{key} line is truncated: no field values")
            if key.endswith("FLN") or sysd[slot] is None:
                sysd[slot] = ([p.num(t, ln, key) for t in toks[1:]], ln)
        elif key == "WAVM":
            i = int(p.arg(toks, 1, ln, "wavelength number"))
            sysd["waves"][i] = (p.arg(toks, 2, ln, "wavelength (µm)"), ln)
        elif key == "WAVL":
            sysd["wavl"] = ([p.num(t, ln, "WAVL") for t in toks[1:]], ln)
        elif key == "PWAV":
            sysd["pwav"] = (int(p.arg(toks, 1, ln, "primary wavelength number")), ln)
        elif key == "GCAT":
            sysd["gcat"] = ([t.upper() for t in toks[1:]], ln)
        elif cur is not None and key == "TYPE":
            if len(toks) < 2:
                p.fail(ln, "TYPE line is truncated: missing the surface type")
            cur.type, cur.type_line = toks[1].upper(), ln
            if cur.type not in ("STANDARD", "EVENASPH", "COORDBRK", "XYPOLYNOM", "PARAXIAL",
                                "TOROIDAL"):
                what = _UNSUPPORTED_TYPES.get(cur.type, "a surface type deeplens does not know")
                p.fail(ln, f"surface type {toks[1]!r} (SURF {len(surfs) - 1}, {what}) is not "
                           f"supported; deeplens reads STANDARD, EVENASPH, COORDBRK, XYPOLYNOM, "
                           f"PARAXIAL and TOROIDAL cylinders")
        elif cur is not None and key == "CURV":
            cur.curv = p.arg(toks, 1, ln, "curvature")
        elif cur is not None and key == "DISZ":
            if len(toks) < 2:
                p.fail(ln, "DISZ line is truncated: missing the thickness")
            cur.disz = math.inf if toks[1].upper() == "INFINITY" else p.num(toks[1], ln, "DISZ")
            cur.disz_line = ln
        elif cur is not None and key == "CONI":
            cur.coni = p.arg(toks, 1, ln, "conic constant")
        elif cur is not None and key == "DIAM":
            cur.diam = p.arg(toks, 1, ln, "semi-diameter")
            cur.diam_fixed = len(toks) > 2 and toks[2] == "1"
        elif cur is not None and key == "STOP":
            cur.stop = True
        elif cur is not None and key == "PARM":
            cur.parm[int(p.arg(toks, 1, ln, "parameter number"))] = (
                p.arg(toks, 2, ln, "parameter value"), ln)
        elif cur is not None and key == "XDAT":
            cur.xdat[int(p.arg(toks, 1, ln, "extra-data number"))] = (
                p.arg(toks, 2, ln, "extra-data value"), ln)
        elif cur is not None and key == "GLAS":
            if len(toks) < 2:
                p.fail(ln, "GLAS line is truncated: missing the glass name")
            name = toks[1]
            if name.upper() == "MIRROR":  # a reflecting surface: Lens(mirrors=...)
                cur.mirror, cur.glass, cur.glass_line = True, None, ln
                continue
            if name.upper() in ("AIR", "VACUUM"):
                cur.glass, cur.glass_model, cur.glass_line = None, None, ln
                continue   # written by some converters: the same as no GLAS line
            code = toks[2] if len(toks) > 2 else "0"
            model = None
            if len(toks) >= 6:
                model = (p.num(toks[4], ln, "GLAS n_d"), p.num(toks[5], ln, "GLAS V_d"))
            if name.upper() == "___BLANK" or code == "1":
                if model is None:
                    p.fail(ln, "a model glass (GLAS ___BLANK 1 0 n_d V_d) line is truncated: "
                               "missing n_d and V_d")
                cur.glass = None
                cur.glass_model_name = None if name.upper() == "___BLANK" else name.upper()
            else:
                cur.glass = name.upper()
            cur.glass_model, cur.glass_line = model, ln
        elif cur is not None and key == "CLAP":
            lo = p.arg(toks, 1, ln, "minimum radius")
            hi = p.arg(toks, 2, ln, "maximum radius")
            if not 0 <= lo < hi:
                p.fail(ln, f"CLAP: expected 0 <= minimum radius < maximum radius, got {lo:g}, "
                           f"{hi:g}")
            cur.clap = (hi, ln)
            if lo > 0:   # an annular clear aperture
                cur.obsc = (lo, ln)
        elif cur is not None and key == "OBSC":
            lo = p.arg(toks, 1, ln, "minimum radius")
            hi = p.arg(toks, 2, ln, "maximum radius")
            if lo != 0 or not hi > 0:
                p.fail(ln, f"OBSC on SURF {len(surfs) - 1}: only a central circular obscuration "
                           f"(minimum radius 0, maximum > 0) is supported, got {lo:g}, {hi:g}")
            cur.obsc = (hi, ln)
        elif cur is not None and key == "SQAP":
            cur.sqap = (p.arg(toks, 1, ln, "x half-width"), p.arg(toks, 2, ln, "y half-width"),
                        ln)
        elif cur is not None and key == "OBDC":
            dec = (p.arg(toks, 1, ln, "x decenter"), p.arg(toks, 2, ln, "y decenter"))
            cur.obdc = (*dec, ln) if any(v != 0 for v in dec) else None
        elif cur is not None and key in ("ELAP", "SQOB", "ELOB", "UDAD", "SPID"):
            what = {
                    "ELAP": "an elliptical aperture",
                    "SQOB": "a rectangular obscuration", "ELOB": "an elliptical obscuration",
                    "UDAD": "a user-defined aperture", "SPID": "a spider"}[key]
            p.fail(ln, f"{key} on SURF {len(surfs) - 1}: {what} is not supported (deeplens reads "
                       f"circular clear apertures: DIAM, CLAP with minimum radius 0)")
        elif cur is not None and key in ("TCE", "COAT", "PZUP", "SCBD"):
            if key == "SCBD":
                p.note(ln, f"{key} (scattering) ignored")
        elif key in ("VDXN", "VDYN", "VCXN", "VCYN", "VANN", "ZVDX", "ZVDY", "ZVCX", "ZVCY",
                     "ZVAN"):
            if any(p.num(t, ln, key) != 0 for t in toks[1:]):
                p.note(ln, f"{key}: vignetting factors are ignored (deeplens finds each field's "
                           f"pupil by tracing)")
        elif key == "ENVD":
            env = [p.num(t, ln, key) for t in toks[1:3]]
            if env and (env[0] != 20 or (len(env) > 1 and env[1] != 1)):
                p.note(ln, f"ENVD: temperature {env[0]:g} °C / pressure {env[1:] or ['?']} atm "
                           f"ignored: indices are the catalogues' at their reference temperature")
        elif key == "MNUM":
            if len(toks) > 1 and p.num(toks[1], ln, key) > 1:
                n_cfg = int(p.num(toks[1], ln, key))
                cur_cfg = int(p.num(toks[2], ln, key)) if len(toks) > 2 else 1
                p.note(ln, f"multi-configuration file ({n_cfg} configurations): the surface data "
                           f"as saved (configuration {cur_cfg}, the active one) is read; the "
                           f"other configurations' values are not applied")
        elif key in _SILENT:
            continue
        else:
            first, count = unused.get(toks[0], (ln, 0))
            unused[toks[0]] = (first, count + 1)
    for kw, (first, count) in unused.items():   # one note per keyword, not one per line
        p.note(first, f"{kw} line not used by deeplens (ignored)"
                      + (f"; {count} such lines" if count > 1 else ""))
    if not surfs:
        p.fail(0, "no SURF line: not a Zemax lens file, or the file is truncated")
    if len(surfs) < 3:
        p.fail(surfs[-1].line, f"expected an object surface, at least one lens surface and an "
                               f"image surface; found {len(surfs)} SURF block(s) (truncated file?)")
    return sysd, surfs, p


def _builtin(glass: str) -> Material | None:
    try:
        return get_material(glass)
    except ValueError:
        return None


def _resolve_glass(glass, s: _Surf, gcat, catalogues, fallback, p: _Parser):
    """The material of ``GLAS glass`` on ``s.glass_line``: exact lookup, in catalogue order.

    Per catalogue the file names on ``GCAT`` (all vendor catalogues if it names none): the
    user's ``.agf`` of that name (it overrides), the current vendor catalogue
    (:mod:`.vendor_glass`), deeplens' built-in entries; then the previous (1983) vendor
    catalogues of the named ones; then, with a warning, a vendor catalogue the file does not
    name (exact name only).
    """
    searched = []
    named = list(gcat) if gcat else list(CURRENT_CATALOGUES) + ["MISC"]
    # the user's catalogues answer for their own names; unnamed ones are searched last
    order = named + [c for c in catalogues if c not in named]
    for cat in order:
        if cat in catalogues:
            searched.append(f"{cat} (user catalogue {catalogues[cat].path.name}, "
                            f"{len(catalogues[cat])} glasses)")
            m = catalogues[cat].get(glass)
            if m is not None:
                return m
            continue
        if cat in CURRENT_CATALOGUES:
            searched.append(f"{cat} (current vendor catalogue, {catalogue_size(cat)} glasses)")
            m = vendor_glass(glass, cat)
            if m is not None:
                return m
        if cat in BUILTIN_CATALOGUES:
            searched.append(f"{cat} (deeplens built-in, {len(BUILTIN_CATALOGUES[cat])} glasses)")
            if glass in BUILTIN_CATALOGUES[cat]:
                m = _builtin(glass)
                if m is not None:
                    return m
    # the named vendors' older catalogues, newest first:
    # (names answered, lookup, kind, what the catalogue is (with {n} glasses), why a use is noted)
    older = ((ARCHIVED_CATALOGUES, archived_glass, "archived",
              "the vendor's .agf as refractiveindex.info keeps it, {n} glasses",
              "the vendor's .agf as refractiveindex.info keeps it; not in the current {cat} "
              "catalogue"),
             (PREVIOUS_CATALOGUES, previous_glass, "previous", "Robb & Mercado 1983, {n} glasses",
              "Robb & Mercado 1983, a visible-range fit: n within 6e-5, 400-700 nm"))
    for known, lookup, kind, what, why in older:
        for cat in named:
            if cat in known and cat not in catalogues:
                n = catalogue_size(cat, previous=kind if kind == "archived" else True)
                searched.append(f"{cat} {kind} ({what.format(n=n)})")
                m = lookup(glass, cat)
                if m is not None:
                    p.note(s.glass_line, f"glass {glass!r}: from the {kind} {cat} catalogue "
                                         f"({why.format(cat=cat)})")
                    return m
    elsewhere = [c for c in find_in_vendor_catalogues(glass) if c.split()[0] not in named]
    if elsewhere:
        cat = elsewhere[0].split()[0]
        m = (previous_glass(glass, cat) if elsewhere[0].endswith("(previous)")
             else archived_glass(glass, cat) if elsewhere[0].endswith("(archived)")
             else vendor_glass(glass, cat))
        p.note(s.glass_line, f"glass {glass!r} is not in the catalogues GCAT names "
                             f"({', '.join(named)}); using {elsewhere[0]} (exact name)")
        return m
    missing = [c for c in named if c not in catalogues and c not in BUILTIN_CATALOGUES
               and c not in CURRENT_CATALOGUES and c not in PREVIOUS_CATALOGUES]
    hint = (f"; catalogue(s) {', '.join(missing)} named on the GCAT line are not shipped with "
            f"deeplens and were not given: pass glass_catalogs=['{missing[0]}.agf', ...] or put "
            f"{missing[0]}.agf next to the .zmx" if missing else "")
    if fallback is not None:
        if fallback == "model":
            if s.glass_model is None or not s.glass_model[0] > 1.0:
                p.fail(s.glass_line, f"glass {glass!r} not found, and the GLAS line has no usable "
                                     f"n_d/V_d for the model-glass fallback")
            if tuple(s.glass_model) == _PLACEHOLDER_ND_VD:
                p.fail(s.glass_line, f"glass {glass!r} not found, and the GLAS line's n_d/V_d "
                                     f"(1.5, 40) is OpticStudio's placeholder for a catalogue "
                                     f"glass, not the glass's data: the model-glass fallback "
                                     f"cannot use it{hint}")
            m = _model_glass(s, p)
        else:
            m = fallback if isinstance(fallback, Material) else get_material(str(fallback))
        warnings.warn(f"{p.path}:{s.glass_line}: glass {glass!r} not found in "
                      f"{'; '.join(searched) or 'any catalogue'}; using the requested fallback "
                      f"{m.name!r}", ZemaxWarning, stacklevel=4)
        return m
    p.fail(s.glass_line, f"glass {glass!r} not found by exact name in the catalogues searched "
                         f"({'; '.join(searched) or 'none'}){hint}; deeplens never substitutes "
                         f"a similar glass: give the vendor's .agf (glass_catalogs=[...]) or ask "
                         f"for a fallback (glass_fallback='model' uses the n_d/V_d on the GLAS "
                         f"line)")


def _model_glass(s: _Surf, p: _Parser, name=None) -> ModelGlass:
    """The model glass of the ``GLAS`` line's ``n_d``/``V_d`` (``V_d = 0``: OpticStudio's
    non-dispersive model glass, deeplens' ``V_d = inf``)."""
    n_d, v_d = s.glass_model
    try:
        return ModelGlass(n_d, math.inf if v_d == 0 else v_d, name=name)
    except ValueError as e:
        p.fail(s.glass_line, f"model glass (GLAS ... n_d V_d): {e}")


def _surface_material(s, gcat, catalogues, fallback, p):
    if s.glass is None and s.glass_model is not None and s.glass_line:
        return _model_glass(s, p, s.glass_model_name)
    if s.glass is None:
        return Air()
    return _resolve_glass(s.glass, s, gcat, catalogues, fallback, p)


def _is_air(m: Material) -> bool:
    return isinstance(m, Air)


def read_zmx(path, *, glass_catalogs=(), glass_fallback=None) -> Lens:
    """Read a sequential Zemax ``.zmx`` file into a :class:`~deeplens.optics.lens.Lens`.

    Args:
        path: the ``.zmx`` file (UTF-16 with byte-order mark, or UTF-8).
        glass_catalogs: ``.agf`` files (paths) or :class:`~.agf.GlassCatalogue` objects; each
            answers for the ``GCAT`` name equal to its file stem.  A catalogue the file names
            but the caller does not pass is looked for as ``<NAME>.agf`` next to the ``.zmx``.
        glass_fallback: ``None`` (default: a glass that is not found is an error), ``"model"``
            (use the ``n_d``/``V_d`` the ``GLAS`` line carries), or a material spec / material
            used for every missing glass.  Each use is reported as a :class:`ZemaxWarning`.

    Returns:
        The lens (lengths in mm, wavelengths in nm).

    Raises:
        ZemaxFileError: (a :class:`~.lensfile.LensFileError`) malformed or truncated lines,
            unknown surface types, unsupported apertures, coordinate breaks that do not bracket
            one element, unknown glasses, field types that cannot be converted, wavelengths
            outside a glass's range; each message names the file and line.

    Example::

        lens = read_zmx("US02532751-1.zmx")
        lens = read_zmx("vendor_lens.zmx", glass_catalogs=["OHARA.agf"])
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"lens file not found: {path}")
    sysd, surfs, p = _parse(path)
    cats: dict[str, GlassCatalogue] = {}
    for c in glass_catalogs:
        cat = c if isinstance(c, GlassCatalogue) else read_agf(c)
        cats[cat.name] = cat
    # catalogues the file names and the caller did not pass: an .agf of that name next to the
    # .zmx (how OpticStudio's own folders are laid out), so `deeplens report x.zmx` finds them
    for name in sysd["gcat"][0]:
        if name not in cats:
            for f in sorted(path.parent.iterdir()):
                if f.suffix.lower() == ".agf" and f.stem.upper() == name and f.is_file():
                    cats[name] = read_agf(f)
                    break
    for note in (n for cat in cats.values() for n in cat.notes):
        p.note(0, note)
    unit, _ = sysd["unit"]
    s_mm = _UNITS[unit]
    gcat, _ = sysd["gcat"]

    # ---- wavelengths (µm in the file)
    ftyp, ftyp_line = sysd["ftyp"] if sysd["ftyp"] else ([0], 0)
    if len(ftyp) > 1 and ftyp[1] == 1:
        p.fail(ftyp_line, "FTYP: object-space telecentric systems (second value 1) are not "
                          "supported (deeplens needs an entrance pupil at a finite distance)")
    if len(ftyp) > 6 and ftyp[6] == 1:
        p.fail(ftyp_line, "FTYP: afocal image space (seventh value 1) is not supported "
                          "(deeplens images onto a sensor)")
    n_fields = ftyp[2] if len(ftyp) > 2 and ftyp[2] > 0 else None
    n_waves = ftyp[3] if len(ftyp) > 3 and ftyp[3] > 0 else None
    if sysd["waves"]:
        nums = sorted(sysd["waves"])
        if n_waves is not None:
            nums = [i for i in nums if i <= n_waves]
        waves = [(sysd["waves"][i][0], sysd["waves"][i][1]) for i in nums]
    elif sysd["wavl"]:
        vals, ln = sysd["wavl"]
        waves = [(v, ln) for v in vals]
        nums = list(range(1, len(vals) + 1))
    else:
        p.fail(0, "no wavelength (WAVM or WAVL line)")
    if not waves:
        p.fail(ftyp_line, "no active wavelength")
    waves_nm = []
    for v, ln in waves:
        try:
            check_wavelength_nm(v * 1000.0)
        except ValueError as e:
            p.fail(ln, f"wavelength {v!r} µm: {e}")
        waves_nm.append(v * 1000.0)
    pw, pw_line = sysd["pwav"]
    if pw not in nums:
        p.fail(pw_line, f"PWAV {pw}: the primary wavelength is not one of the active wavelengths "
                        f"{nums}")
    primary = waves_nm[nums.index(pw)]

    # ---- surfaces
    obj, img = surfs[0], surfs[-1]
    if obj.type != "STANDARD" or obj.curv != 0:
        p.fail(obj.line, "the object surface (SURF 0) must be a flat STANDARD surface")
    obj_dist = obj.disz * (1 if math.isinf(obj.disz) else s_mm)
    if not obj_dist > 0:
        p.fail(obj.disz_line or obj.line, f"the object distance (DISZ of SURF 0) must be > 0 or "
                                          f"INFINITY, got {obj.disz!r}")
    obj_medium = _surface_material(obj, gcat, cats, glass_fallback, p)
    media = [obj_medium]
    kept = []            # (surface module, material after, zmx surf, gap before it in mm)
    groups = []          # [start, end] index ranges in kept for bracketed elements
    gap = 0.0            # axial distance from the last kept vertex to the current one (mm)
    bracket = None
    brackets = misalignment_brackets(surfs)   # COORDBRK pairs read as misalignments
    paired = set(brackets) | set(brackets.values())
    # a fold or an off-axis section: the beam leaves the local axes, and the file's automatic
    # semi-diameters (DIAM flag 0) are OpticStudio's footprints of its own (ray-aimed, all
    # fields) beam, which never vignette there: deeplens recomputes them from its rays
    folded = any(s.type == "COORDBRK" and not is_identity(s) and k not in paired
                 for k, s in enumerate(surfs))
    stop_idx = None
    autos = []           # kept indices whose semi-diameter is automatic
    mirrors = []         # indices in kept of GLAS MIRROR surfaces
    for k in range(1, len(surfs) - 1):
        s = surfs[k]
        prev = media[-1]
        if s.type == "COORDBRK":
            if s.glass is not None or s.stop:
                p.fail(s.line, "a COORDBRK surface cannot carry a glass or the stop")
            if is_identity(s):           # a dummy: its thickness only
                gap += s.disz * s_mm
                continue
            dx = s.parm.get(1, (0.0, 0))[0] * s_mm
            dy = s.parm.get(2, (0.0, 0))[0] * s_mm
            tx, ty, tz = (s.parm.get(i, (0.0, 0))[0] for i in (3, 4, 5))
            if k in brackets:            # opens an element's misalignment
                bracket = {"line": s.line, "d": (dx, dy, tx, ty, tz), "start": len(kept)}
            elif bracket is not None:    # closes it (misalignment_brackets checked the pair)
                if len(kept) > bracket["start"]:   # (around dummies only, the pair cancels)
                    groups.append((bracket["start"], len(kept) - 1,
                                   element_tilts(bracket["d"], kept[bracket["start"]:],
                                                 s.line, p), bracket["line"]))
                gap = gap + s.disz * s_mm   # gap: back at the pivot, + the thickness after
                bracket = None
            else:                        # a fold, an off-axis section: the frame turns
                kept.append((coordinate_break(s, s_mm), prev, s, gap))
                media.append(prev)
                gap = s.disz * s_mm
                if math.isinf(s.disz):
                    p.fail(s.disz_line, f"SURF {k}: an infinite thickness inside the lens")
            continue
        mat = prev if s.mirror else _surface_material(s, gcat, cats, glass_fallback, p)
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
        if s.type == "STANDARD" or s.type == "EVENASPH":
            if s.type == "EVENASPH":
                for i, (v, ln) in sorted(s.parm.items()):
                    if i == 1 and v != 0:
                        p.fail(ln, "EVENASPH PARM 1 (the r² term) is not supported: deeplens' "
                                   "even asphere starts at r⁴ (fold it into the curvature in "
                                   "Zemax)")
                    if i > 8 and v != 0:
                        p.fail(ln, f"EVENASPH PARM {i}: Zemax's even asphere has PARM 1-8")
                # as many terms as PARM lines (a4 = PARM 2, ...); a file listing all 8 (as
                # OpticStudio writes) is trimmed of its trailing zero terms
                top = max([i for i in s.parm if i <= 8] + [1])
                coeffs = [s.parm.get(i, (0.0, 0))[0] * s_mm ** (1 - 2 * i)
                          for i in range(2, top + 1)]
                if top == 8:
                    while coeffs and coeffs[-1] == 0.0:
                        coeffs.pop()
            flat = c == 0 and s.coni == 0 and not coeffs
            same_medium = (type(mat) is type(prev) and mat.name == prev.name)
            if (flat and same_medium and not s.stop and not fixed and s.clap is None
                    and s.sqap is None and s.obsc is None and not s.mirror):
                gap += s.disz * s_mm
                continue   # a dummy surface: its thickness only
        if sd < 0:
            p.fail(s.line, f"SURF {k}: the semi-diameter (DIAM) must be >= 0, got {s.diam!r}")
        auto = not sd > 0     # no DIAM (or 0): an automatic semi-diameter, set once built
        if folded and not fixed and s.clap is None:
            auto = True
        sd_build = sd if sd > 0 else _PROVISIONAL_SD_MM
        try:
            if s.type == "XYPOLYNOM":
                surf = _xypolynom(s, c, sd_build, s_mm, p)
            elif s.type == "PARAXIAL":
                surf = _paraxial_surface(s, k, mat, prev, sd_build, s_mm, p)
            elif s.type == "TOROIDAL":
                surf = _cylinder(s, k, c, sd_build, s_mm, p)
            elif s.sqap is not None and flat and _is_air(mat) and _is_air(prev):
                hx, hy, _ = s.sqap
                surf = Aperture(sd if sd > 0 else None, "rect", hx * s_mm, hy * s_mm)
            elif s.obsc is not None and flat and _is_air(mat) and _is_air(prev):
                # OpticStudio clips only on the obscuration here (and on a CLAP or a fixed
                # DIAM): an automatic DIAM, the beam's extent, is widened by 1 %
                outer = sd if (s.clap is not None or fixed or s.stop) else 1.01 * sd
                ro = s.obsc[0] * s_mm
                surf = Aperture(outer if outer > 0 else 2.0 * ro, obscuration=ro)
            elif flat and _is_air(mat) and _is_air(prev) and not s.mirror:
                surf = Aperture(sd_build)
            elif flat:
                surf = Plane(sd_build)
            else:
                surf = Asphere(c, sd_build, conic=s.coni, coefficients=coeffs)
        except ZemaxFileError:
            raise   # already located (a helper's p.fail): not located twice
        except ValueError as e:
            p.fail(s.type_line or s.line, f"SURF {k}: {e}")
        if s.obdc is not None:   # the decenter of the opening of an Aperture (not the stop)
            dec = _aperture_decenter(s, k, isinstance(surf, Aperture), s_mm, p)
            surf.decenter.copy_(torch.tensor(dec, dtype=surf.decenter.dtype))
        if s.obsc is not None and isinstance(surf, Asphere):
            # a central obscuration on a lens or mirror surface (a secondary's shadow on a
            # Cassegrain's primary): an aperture property of the surface
            ro = s.obsc[0] * s_mm
            if not 0 < ro < float(surf.semi_diameter) and not auto:
                p.fail(s.obsc[1], f"SURF {k}: the obscuration radius {s.obsc[0]:g} must be > 0 "
                                  f"and below the semi-diameter {s.diam:g}")
            surf.obscuration.fill_(ro)
        elif s.obsc is not None and not isinstance(surf, Aperture):
            what = "flat mirror" if s.mirror else "flat surface between two media"
            p.fail(s.obsc[1], f"SURF {k}: OBSC, a central obscuration on a {what} "
                              f"({type(surf).__name__}), is not supported (deeplens has "
                              f"obscurations on flat surfaces in air: put the obscuration on its "
                              f"own flat dummy surface where that is equivalent)")
        if s.sqap is not None and not (isinstance(surf, Cylinder) or (
                isinstance(surf, Aperture) and surf.shape == "rect")):
            p.fail(s.sqap[2], f"SQAP on SURF {k}: a rectangular aperture on a "
                              f"{type(surf).__name__} surface is not supported (deeplens has "
                              f"rectangular apertures on flat stops in air and on cylinders)")
        if auto and isinstance(surf, Aperture) and surf.shape == "rect":
            auto = False   # its semi-diameter is the rectangle's half-diagonal
        if auto:
            autos.append(len(kept))
        if s.stop:
            stop_idx = len(kept)
        if s.mirror:
            mirrors.append(len(kept))
        kept.append((surf, mat, s, gap))
        media.append(mat)
        gap = s.disz * s_mm
        if math.isinf(s.disz):
            p.fail(s.disz_line, f"SURF {k}: an infinite thickness inside the lens")
    if not kept:
        p.fail(img.line, "no lens surface between the object and the image surface")
    if stop_idx is None:
        p.fail(0, "no STOP line: the lens has no aperture stop")
    if img.type != "STANDARD" or img.curv != 0:
        p.note(img.line, "the image surface is not flat: deeplens uses a flat sensor at its "
                         "vertex")
    surfaces = [k_[0] for k_ in kept]
    distances = [0.0] + [k_[3] for k_ in kept[1:]]
    if not math.isinf(obj_dist):
        obj_dist += kept[0][3]   # dummy thickness in front of the first surface
    d_sensor = gap
    # the direction of travel after the last surface: -z after an odd number of mirrors
    # (Zemax's sign convention, Lens.directions), so "behind" the last vertex is sign * d > 0
    sign = -1.0 if len(mirrors) % 2 else 1.0
    # a thickness of the wrong sign inside the lens is reported by Lens (naming that surface)
    signs = [1.0]
    for i in range(len(kept)):
        signs.append(-signs[-1] if i in mirrors else signs[-1])
    inside_ok = all(kept[i][3] * signs[i] >= 0 for i in range(1, len(kept)))
    if d_sensor == 0 and isinstance(surfaces[-1], Plane):
        # the image plane on the last (flat) vertex: deeplens' sensor must lie after the last
        # surface, so it sits _IMAGE_ON_VERTEX_MM behind it (image points move by that times
        # the ray slope: < 1e-8 mm)
        d_sensor = sign * _IMAGE_ON_VERTEX_MM
        p.note(img.line, f"the image plane lies on the last (flat) surface's vertex: the sensor "
                         f"is placed {_IMAGE_ON_VERTEX_MM:g} mm behind it")
    elif d_sensor == 0:
        p.fail(img.line, "the image plane lies on the vertex of the last surface, which is "
                         "curved: deeplens' flat sensor would cut through it (give the last "
                         "surface a thickness)")
    elif sign * d_sensor < 0 and inside_ok:
        travel = (f" (light travels towards {'-' if sign < 0 else '+'}z there, after "
                  f"{len(mirrors)} mirror{'s' if len(mirrors) != 1 else ''})" if mirrors else
                  " (a virtual image, as a negative lens's file puts it at its virtual focus)")
        p.fail(img.line, f"the image plane lies {abs(d_sensor):g} mm before the last surface's "
                         f"vertex{travel}: deeplens' sensor must follow the last surface")
    sensor_sd = img.diam * s_mm if img.diam > 0 else None

    # ---- elements: bracketed groups, then deeplens' default grouping for the rest
    elements = _elements(kept, media, groups, p)

    # ---- aperture
    ap = sysd["aperture"]
    if ap is None:
        p.fail(0, "no system aperture (ENPD, FNUM or FLOA line)")
    ap_type, ap_value, ap_line = ap
    if ap_type == "epd":
        ap_value *= s_mm
    convert = None     # an aperture given another way, turned into an EPD once the lens is built
    if ap_type in ("wfno", "obna", "cone"):
        if ap_type != "wfno" and math.isinf(obj_dist):
            p.fail(ap_line, "OBNA (object-space numerical aperture / cone angle) needs an object "
                            "at a finite distance")
        if not ap_value > 0:
            p.fail(ap_line, f"the aperture value must be > 0, got {ap_value!r}")
        convert = (ap_type, ap_value, ap_line)
        ap_type, ap_value = "epd", 1.0
    if ap_type == "stop" and stop_idx in autos:
        p.fail(kept[stop_idx][2].line, "the stop has no semi-diameter (no DIAM, or 0) and the "
                                       "system aperture is FLOA (float by stop size): give the "
                                       "stop a DIAM or the system an ENPD/FNUM")

    # ---- glass wavelength ranges, before building (a clear error instead of a NaN)
    for (surf, mat, s, _), i in zip(kept, range(len(kept))):
        for w in waves_nm:
            try:
                check_wavelength_nm(w, mat)
            except ValueError as e:
                p.fail(s.glass_line or s.line, f"{e} (glass of SURF {surfs.index(s)})")
    for w in waves_nm:
        try:
            check_wavelength_nm(w, obj_medium)
        except ValueError as e:
            p.fail(obj.glass_line or obj.line, str(e))

    where_of = {i: kept[i][2].line for i in range(len(kept))}
    try:
        spec = LensSpec(object_distance_mm=obj_dist, aperture_type=ap_type,
                        aperture_value=ap_value, fields_deg=[0.0], wavelengths_nm=waves_nm,
                        primary_wavelength_nm=primary)
        lens = Lens(surfaces, media, distances, d_sensor, stop_idx, sensor_sd, spec,
                    elements=[(a, b) for a, b, _, _ in elements],
                    name=sysd["name"] or path.stem, mirrors=mirrors)
    except (ValueError, TypeError) as e:
        if "F-number aperture needs a positive" in str(e):
            p.fail(ap_line, str(e))
        raise ZemaxFileError(_locate(f"{path}: {e}", where_of)) from e
    for e, (a, b, d, _) in enumerate(elements):
        if d is not None:
            m = lens.misalignments[e]
            dx, dy, tx, ty = d
            with torch.no_grad():
                m.dx.fill_(dx)
                m.dy.fill_(dy)
                m.tilt_x.fill_(math.radians(tx))
                m.tilt_y.fill_(math.radians(ty))
    if _afocal(lens) and (convert is not None or ftyp[0] in (1, 2, 3)):
        # an afocal lens (flat folds only) has an infinite focal length: fields given as image
        # heights, a working F-number or an object-space NA have no meaning there
        p.fail(ftyp_line if convert is None else convert[2],
               "the system is afocal (no paraxial power: flat mirrors and folds only), and "
               "this aperture or field type needs a finite focal length")
    if convert is not None:
        ap_value = aperture_to_epd(lens, *convert, p)
        try:
            lens.spec = LensSpec(object_distance_mm=obj_dist, aperture_type="epd",
                                 aperture_value=ap_value, fields_deg=[0.0],
                                 wavelengths_nm=waves_nm, primary_wavelength_nm=primary)
            lens.apply_aperture_spec()
        except ValueError as e:
            p.fail(convert[2], str(e))

    # ---- fields
    lens.ray_aiming = sysd["raim"][0] != 0
    if folded:
        sysd, n_fields = y_fields_only(sysd, n_fields, p)
    fields = fields_to_angles(sysd, ftyp, ftyp_line, n_fields, s_mm, lens, p)
    autos = [i for i in autos if not (i == stop_idx and ap_type != "stop")]
    if autos:
        _auto_semi_diameters(lens, autos, fields, where_of, path)
    try:
        lens.spec = LensSpec(object_distance_mm=obj_dist, aperture_type=ap_type,
                             aperture_value=ap_value, fields_deg=fields, wavelengths_nm=waves_nm,
                             primary_wavelength_nm=primary)
    except ValueError as e:
        p.fail(sysd["yfln"][1] if sysd["yfln"] else 0, str(e))
    _check_stop_clear_aperture(lens, kept[stop_idx][2], s_mm, p)
    for ln, msg in p.notes:
        warnings.warn(f"{path}:{ln}: {msg}" if ln else msg, ZemaxWarning, stacklevel=2)
    return lens


def _check_stop_clear_aperture(lens: Lens, s: _Surf, s_mm: float, p: _Parser) -> None:
    """A ``CLAP`` on the stop surface narrower than the stop that the ``ENPD``/``FNUM`` aperture
    defines vignettes the pupil in OpticStudio; deeplens' stop has one radius, the paraxial one,
    so such a file is refused rather than traced with the wider beam."""
    if s.clap is None or lens.spec.aperture_type == "stop":
        return
    clap = s.clap[0] * s_mm
    sd = float(lens.surfaces[lens.stop_index].semi_diameter)
    if clap < sd * (1 - 1e-9):
        p.fail(s.clap[1], f"CLAP on the stop surface: its clear radius {clap:g} mm is smaller "
                          f"than the stop radius {sd:g} mm that the system aperture defines, so "
                          f"it cuts the entrance pupil; deeplens' stop has one radius (give the "
                          f"system aperture as FLOA, or an ENPD/FNUM the CLAP does not cut)")


def _auto_semi_diameters(lens, idx, fields, where_of, path):
    """Automatic semi-diameters of the surfaces ``idx``, as OpticStudio's: the largest height of
    the real rays that fill the pupil, over every field and wavelength.  A first paraxial
    estimate ``1.05 (|y_marginal| + |y_chief|)`` (full field) lets the lens be built; then rays
    over the paraxial entrance pupil enlarged by 2 % (48 rim points and the chief ray per field
    and wavelength, apertures ignored) are traced and each surface gets its largest hit radius.
    OpticStudio does not vignette on automatic semi-diameters, and the 2 % keep rim rays (and
    the slightly larger pupils of ray aiming) from being clipped by them.  Capped to the
    surface's domain."""
    from ..intersect import IntersectOptions
    from ..paraxial import _indices, _trace, paraxial
    from ..sampling import field_rays

    field_deg = max(abs(f) for f in fields)
    with torch.no_grad():
        par = paraxial(lens)
        n, p0 = _indices(lens, None)
        half = 0.5 * float(par.entrance_pupil_diameter)
        pos = float(par.entrance_pupil_position)
        s = float(lens.spec.object_distance_mm)
        t = math.tan(math.radians(field_deg))
        if math.isinf(s):
            ym0, um0 = half, 0.0
        else:
            um0 = half / (s + pos)
            ym0 = um0 * s
        one = torch.ones_like(p0)
        _, _, hm = _trace(lens, ym0 * one, um0 * one, n)
        _, _, hc = _trace(lens, -pos * t * one, t * one, n)
        for i in idx:
            surf = lens.surfaces[i]
            sd = 1.05 * (abs(float(hm[i])) + abs(float(hc[i])))
            c = float(surf.paraxial_curvature())
            k = float(getattr(surf, "k", 0.0)) if hasattr(surf, "k") else 0.0
            if c != 0 and 1 + k > 0:
                sd = min(sd, 0.999 / (abs(c) * math.sqrt(1 + k)))
            surf.semi_diameter.fill_(sd)
        # real rays
        phi = torch.arange(48, dtype=lens.dtype) * (2 * math.pi / 48)
        unit = torch.cat([torch.zeros(1, 2, dtype=lens.dtype),
                          torch.stack([torch.cos(phi), torch.sin(phi)], -1)])
        pts = unit * (1.02 * half)
        z_ep = float(par.entrance_pupil_z)
        top = {i: 0.0 for i in idx}
        for f in dict.fromkeys(fields):
            for w in lens.spec.wavelengths_nm:
                rays = field_rays(lens, float(f), float(w), pts, z_ep)
                out, hits = lens.trace(rays, options=IntersectOptions(clip_aperture=False),
                                       record=True)
                ok = out.valid
                for i in idx:
                    if bool(ok.any()):
                        r = torch.linalg.vector_norm(hits[i][ok][:, :2], dim=-1)
                        top[i] = max(top[i], float(r.max()))
        for i in idx:
            if top[i] > 0:
                surf = lens.surfaces[i]
                sd = top[i]
                c = float(surf.paraxial_curvature())
                k = float(getattr(surf, "k", 0.0)) if hasattr(surf, "k") else 0.0
                if c != 0 and 1 + k > 0:
                    sd = min(sd, 0.999 / (abs(c) * math.sqrt(1 + k)))
                surf.semi_diameter.fill_(sd)
    try:
        lens.check()
    except ValueError as e:
        raise ZemaxFileError(_locate(f"{path}: with automatic semi-diameters (no DIAM): {e}",
                                     where_of)) from e


def _afocal(lens) -> bool:
    from ..paraxial import paraxial

    return math.isinf(float(paraxial(lens).efl))


def _locate(msg: str, where_of: dict) -> str:
    idx = []
    for m in re.finditer(r"\bsurfaces? (\d+)(?: and (\d+))?", msg):
        idx += [int(g) for g in m.groups() if g is not None]
    lines = [f"deeplens surface {i} is the SURF block on line {where_of[i]}"
             for i in dict.fromkeys(idx) if i in where_of]
    return msg + (f" ({'; '.join(lines)})" if lines else "")


def _aperture_decenter(s: _Surf, k: int, is_aperture: bool, s_mm, p: _Parser):
    """``OBDC x y``: the decenter (mm) of the surface's aperture (``CLAP``, annular ``CLAP``,
    ``SQAP``), for a flat surface in air (a deeplens :class:`Aperture`) that is not the stop."""
    dx, dy, ln = s.obdc
    where = f"OBDC on SURF {k} (aperture decenter {dx:g}, {dy:g})"
    if s.clap is None and s.sqap is None:   # an OBSC alone (no aperture at all: not called)
        p.fail(ln, f"{where}: a decentred obscuration (OBSC) inside a centred semi-diameter is "
                   f"not supported (deeplens decentres a CLAP or SQAP opening, with its "
                   f"obscuration)")
    if s.stop:
        p.fail(ln, f"{where}: a decentred aperture stop is not supported (deeplens' entrance "
                   f"pupil is centred on the axis)")
    if not is_aperture:
        p.fail(ln, f"{where}: a decentred aperture on a lens or mirror surface is not supported "
                   f"(deeplens decentres apertures on flat surfaces in air; an off-axis mirror "
                   f"segment is not read)")
    return (dx * s_mm, dy * s_mm)


def _cylinder(s: _Surf, k: int, c, sd, s_mm, p: _Parser):
    """``TOROIDAL`` with ``PARM 1`` (the radius of rotation) 0: a cylinder, curved in y, with
    ``PARM 2..9`` the coefficients of ``y², y⁴, ..., y¹⁶``; ``SQAP`` its rectangular outline."""
    if s.parm.get(1, (0.0, 0))[0] != 0:
        p.fail(s.parm[1][1], f"SURF {k}: a TOROIDAL surface with a finite radius of rotation "
                             f"(PARM 1 = {s.parm[1][0]:g}) is not supported; cylinders "
                             f"(PARM 1 = 0) are")
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
    if hw is not None and sd == _PROVISIONAL_SD_MM:
        sd = math.hypot(*hw)
    return Cylinder(c, sd, conic=s.coni, coefficients=coeffs, half_widths=hw)


def _paraxial_surface(s: _Surf, k: int, mat, prev, sd, s_mm, p: _Parser):
    """``PARAXIAL`` (``PARM 1`` = focal length): deeplens' :class:`IdealLens`, in air."""
    if 1 not in s.parm or s.parm[1][0] == 0:
        p.fail(s.type_line or s.line, f"SURF {k}: a PARAXIAL surface needs a non-zero focal "
                                      f"length (PARM 1)")
    if not (_is_air(mat) and _is_air(prev)):
        p.fail(s.glass_line or s.type_line, f"SURF {k}: a PARAXIAL surface between glasses is "
                                            f"not supported (deeplens' ideal lens sits in air)")
    for i, (v, ln) in s.parm.items():
        if i > 2 and v != 0:
            p.fail(ln, f"SURF {k}: PARAXIAL PARM {i} is not read (only the focal length, PARM 1)")
    return IdealLens(s.parm[1][0] * s_mm, sd)


def _xypolynom(s: _Surf, c, sd, s_mm, p: _Parser):
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


def _elements(kept, media, groups, p):
    """``[(first, last, misalignment or None, line)]`` covering every kept surface."""
    out = []
    g = {a: (a, b, d, ln) for a, b, d, ln in groups}
    i, start = 0, 0
    n = len(kept)
    while i < n:
        if i in g:
            a, b, d, ln = g[i]
            if start < i:
                p.fail(ln, f"the COORDBRK on line {ln} starts inside an element (before it: "
                           f"SURF line {kept[start][2].line}); it must bracket whole elements")
            if not (_is_air(media[a]) and _is_air(media[b + 1])):
                p.fail(ln, f"the COORDBRK on line {ln} does not bracket a whole element (glass "
                           f"before its first or after its last surface)")
            out.append((a, b, d, ln))
            i = start = b + 1
            continue
        if _is_air(media[i + 1]) or isinstance(kept[i][0], Aperture):
            out.append((start, i, None, 0))
            start = i + 1
        i += 1
    if start < n:
        out.append((start, n - 1, None, 0))
    return out


# =========================================================================== writer
def _f(v: float) -> str:
    return repr(float(v))


# deeplens catalogue name -> the name Zemax's MISC catalogue uses
_ZEMAX_NAME = {"FUSED_SILICA": "F_SILICA", "PC": "POLYCARB"}


def _glass_line(m: Material, cats: list) -> str | None:
    """The ``GLAS`` line of medium ``m`` (``None`` for air); adds its catalogue to ``cats``."""
    if isinstance(m, Air):
        return None
    if isinstance(m, (AGFGlass, BuchdahlGlass)):
        if m.catalogue and m.catalogue not in cats:
            cats.append(m.catalogue)
        return f"GLAS {m.name} 0 0 {_f(m.nd)} {_f(m.vd)} 0 0 0 0 0 0"
    name = m.name.upper()
    rec = GLASS_TABLE.get(name)
    is_entry = rec is not None and (not isinstance(m, ModelGlass) or m.to_spec() == rec.name)
    if is_entry:
        zname = _ZEMAX_NAME.get(name, name)
        for cat, names in BUILTIN_CATALOGUES.items():
            if zname in names:
                if cat not in cats:
                    cats.append(cat)
                return f"GLAS {zname} 0 0 {_f(m.nd)} {_f(m.vd)} 0 0 0 0 0 0"
    if isinstance(m, ModelGlass):
        # a named entry of deeplens' table that is a model glass (SK1, F15, SK16: the paper
        # authors' n_d/V_d) keeps its name on a model-glass line (code 1)
        # (as does a model glass a file named: GLAS NAME 1 0 n_d V_d)
        named = m.name != m.to_spec() or is_entry
        label = m.name.upper() if named and len(m.name.split()) == 1 and "/" not in m.name \
            else "___BLANK"
        v_d = 0.0 if math.isinf(m.v_d) else m.v_d   # OpticStudio's non-dispersive model glass
        return f"GLAS {label} 1 0 {_f(m.n_d)} {_f(v_d)} 0 0 0 0 0 0"
    raise ZemaxFileError(f"material {m.name!r} ({type(m).__name__}) has no Zemax catalogue name; "
                         f"use a catalogue glass or an n_d/V_d model glass")


def write_zmx(lens: Lens, path, encoding: str = "utf-8") -> None:
    """Write ``lens`` as a sequential Zemax ``.zmx`` file that :func:`read_zmx` reads back.

    Args:
        lens: the lens (current parameter values).
        path: output file.
        encoding: ``"utf-8"`` (default) or ``"utf-16"`` (OpticStudio's own, with byte-order mark).

    Raises:
        ZemaxFileError: a surface or material with no Zemax equivalent (B-spline, rectangular
            aperture, XY polynomial with ``b != 0``, more than 7 aspheric terms), or a
            misalignment tilting one element about both x and y.
    """
    spec = lens.spec
    out = ["VERS 170912 299 123456", "MODE SEQ", f"NAME {lens.name}", "UNIT MM X W X CM MR CPMM"]
    if spec.aperture_type == "epd":
        out.append(f"ENPD {_f(spec.aperture_value)}")
    elif spec.aperture_type == "fno":
        out.append(f"FNUM {_f(spec.aperture_value)} 0")
    else:
        out.append("FLOA")
    if getattr(lens, "ray_aiming", False):
        out.append("RAIM 0 2 1 1 0 0 0 0 0 1")   # real ray aiming, as the file it came from
    cats: list[str] = []
    body: list[str] = []
    nsurf = 0

    def surf(lines):
        nonlocal nsurf
        body.append(f"SURF {nsurf}")
        body.extend("  " + ln for ln in lines)
        nsurf += 1

    def glas(m, extra):
        g = _glass_line(m, cats)
        if g:
            extra.append(g)

    od = float(spec.object_distance_mm)
    obj = ["TYPE STANDARD", "CURV 0.0", f"DISZ {'INFINITY' if math.isinf(od) else _f(od)}"]
    glas(lens.materials[0], obj)
    surf(obj)
    with torch.no_grad():
        n = len(lens.surfaces)
        elem_of = {}
        for e, (a, b) in enumerate(lens.elements):
            for i in range(a, b + 1):
                elem_of[i] = e
        for i, s in enumerate(lens.surfaces):
            e = elem_of[i]
            a, b = lens.elements[e]
            mis = lens.misalignments[e]
            tilted = not mis.is_identity() and any(
                float(v) != 0 for v in (mis.dx, mis.dy, mis.tilt_x, mis.tilt_y))
            d = (float(mis.dx), float(mis.dy), math.degrees(float(mis.tilt_x)),
                 math.degrees(float(mis.tilt_y)))
            if tilted and d[2] != 0 and d[3] != 0:
                if not all(rotationally_symmetric(s_) for s_ in lens.surfaces[a:b + 1]):
                    raise ZemaxFileError(f"element {e} (surfaces {a}-{b}) is tilted about both x "
                                         f"and y and is not rotationally symmetric: OpticStudio's "
                                         f"x-then-y tilts cannot express deeplens' R_y R_x")
                d = d[:2] + zemax_tilts(*d[2:])
            if tilted and i == a:
                surf(["TYPE COORDBRK", "CURV 0.0", "DISZ 0"] +
                     [f"PARM {k + 1} {_f(v)}" for k, v in enumerate(d)] +
                     ["PARM 5 0", "PARM 6 0"])
            after = float(lens.distances[i + 1]) if i + 1 < n else float(lens.d_sensor)
            if isinstance(s, CoordinateBreak):   # a fold or an off-axis section
                if tilted:
                    raise ZemaxFileError(f"surface {i}: a coordinate break inside a misaligned "
                                         f"element has no .zmx equivalent")
                surf(coordbrk_lines(s, _f) + [f"DISZ {_f(after)}"])
                continue
            inner = sum(float(lens.distances[j]) for j in range(a + 1, b + 1))
            gap = -inner if tilted and i == b else after   # back to the first vertex
            lines = _surface_lines(s, i, lens.stop_index == i)
            lines.append(f"DISZ {_f(gap)}")
            if i in lens.mirrors:
                lines.append("GLAS MIRROR 0 0 0 0 0 0 0 0 0 0 0")
            else:
                glas(lens.materials[i + 1], lines)
            surf(lines)
            if tilted and i == b:
                surf(["TYPE COORDBRK", "CURV 0.0", f"DISZ {_f(inner + after)}"] +
                     [f"PARM {k + 1} {_f(-v)}" for k, v in enumerate(d)] +
                     ["PARM 5 0", "PARM 6 1"])
    img = ["TYPE STANDARD", "CURV 0.0", "DISZ 0"]
    if lens.sensor_semi_diameter is not None:
        img.append(f"DIAM {_f(lens.sensor_semi_diameter)} 1 0 0 1 \"\"")
    surf(img)
    nf, nw = len(spec.fields_deg), len(spec.wavelengths_nm)
    out.append("GCAT " + " ".join(cats or ["SCHOTT"]))
    out.append(f"FTYP 0 0 {nf} {nw} 0 0 0")
    out.append("XFLN " + " ".join("0" for _ in spec.fields_deg))
    out.append("YFLN " + " ".join(_f(f) for f in spec.fields_deg))
    for k, w in enumerate(spec.wavelengths_nm, start=1):
        out.append(f"WAVM {k} {_f(float(w) / 1000.0)} 1")
    prim = [float(w) for w in spec.wavelengths_nm]
    pw = float(spec.primary_wavelength_nm)
    if pw in prim:
        out.append(f"PWAV {prim.index(pw) + 1}")
    else:
        raise ZemaxFileError(f"the primary wavelength {pw} nm is not one of the lens's "
                             f"wavelengths {prim}: Zemax's PWAV picks one of them")
    text = "\n".join(out + body) + "\n"
    Path(path).write_text(text, encoding=encoding)


def _surface_lines(s, i, is_stop) -> list[str]:
    from ..surfaces import BSpline

    lines = ["STOP"] if is_stop else []
    sd = s.semi_diameter
    sd = None if sd is None else float(sd)
    if isinstance(s, Aperture):
        lines += ["TYPE STANDARD", "CURV 0.0"]
        if sd is not None:
            lines.append(f"DIAM {_f(sd)} 1 0 0 1 \"\"")
        if s.shape == "rect":
            lines.append(f"SQAP {_f(s.half_widths[0])} {_f(s.half_widths[1])} 0")
        elif s.decentred:   # OBDC moves a CLAP (annular: with its obscuration), not a DIAM
            lines.append(f"CLAP {_f(s.obscuration)} {_f(sd)} 0")
        if float(s.obscuration) > 0 and not s.decentred:
            lines.append(f"OBSC 0 {_f(s.obscuration)} 0")
        if s.decentred:
            lines.append(f"OBDC {_f(s.decenter[0])} {_f(s.decenter[1])}")
        return lines
    if isinstance(s, Cylinder):
        lines += ["TYPE TOROIDAL", f"CURV {_f(s.c)}", f"CONI {_f(s.k)}", "PARM 1 0"]
        lines += [f"PARM {j + 2} {_f(a)}" for j, a in enumerate(s.a)]
        lines.append(f"DIAM {_f(sd)} 1 0 0 1 \"\"")
        if s.half_widths is not None:
            lines.append(f"SQAP {_f(s.half_widths[0])} {_f(s.half_widths[1])} 0")
        return lines
    if isinstance(s, IdealLens):
        return lines + ["TYPE PARAXIAL", "CURV 0.0", f"PARM 1 {_f(s.focal)}",
                        f"DIAM {_f(sd)} 1 0 0 1 \"\""]
    if isinstance(s, Plane):
        return lines + ["TYPE STANDARD", "CURV 0.0", f"DIAM {_f(sd)} 1 0 0 1 \"\""]
    if isinstance(s, Asphere):
        a = [float(v) for v in s.a]
        if len(a) > 7:
            raise ZemaxFileError(f"surface {i}: {len(a)} aspheric terms; Zemax's EVENASPH holds "
                                 f"a4..a16 (7 terms)")
        lines += ["TYPE EVENASPH" if a else "TYPE STANDARD", f"CURV {_f(s.c)}",
                  f"CONI {_f(s.k)}"]
        if a:
            lines.append("PARM 1 0")
            lines += [f"PARM {k + 2} {_f(v)}" for k, v in enumerate(a)]
        lines.append(f"DIAM {_f(sd)} 1 0 0 1 \"\"")
        if float(s.obscuration) > 0:
            lines.append(f"OBSC 0 {_f(s.obscuration)} 0")
        return lines
    if isinstance(s, XYPolynomial):
        if float(s.b) != 0:
            raise ZemaxFileError(f"surface {i}: an XY polynomial with b != 0 (z² term) has no "
                                 f"XYPOLYNOM equivalent")
        vals = {t: float(v) for t, v in zip(s.terms, s.a)}
        if vals.get((0, 0), 0.0) != 0:
            raise ZemaxFileError(f"surface {i}: an XY polynomial with a constant term has no "
                                 f"XYPOLYNOM equivalent")
        R = sd
        zterms = [(d - k, k) for d in range(1, s.order + 1) for k in range(d + 1)]
        lines += ["TYPE XYPOLYNOM", "CURV 0.0", f"DIAM {_f(sd)} 1 0 0 1 \"\"",
                  f"XDAT 1 {len(zterms)}", f"XDAT 2 {_f(R)}"]
        lines += [f"XDAT {j + 3} {_f(vals.get(t, 0.0) * R ** sum(t))}"
                  for j, t in enumerate(zterms)]
        return lines
    if isinstance(s, BSpline):
        raise ZemaxFileError(f"surface {i}: a B-spline surface has no .zmx equivalent")
    raise ZemaxFileError(f"surface {i}: {type(s).__name__} has no .zmx equivalent")
