r"""CODE V sequence files (``.seq``): read and write the common subset.

Surface sag of the types read (``c`` the curvature, ``k = K``, ``r² = x² + y²``)::

    SPH   z = c r² / (1 + sqrt(1 − c² r²))                              (the default)
    CON   z = c r² / (1 + sqrt(1 − (1 + k) c² r²))
    ASP   z = CON + A r⁴ + B r⁶ + C r⁸ + D r¹⁰ + E r¹² + F r¹⁴ + G r¹⁶ + H r¹⁸ + J r²⁰

all read as an :class:`~deeplens.optics.surfaces.Asphere` (a flat stop in air as an
:class:`~deeplens.optics.surfaces.Aperture`).  Each surface type is read and written by its
handler in the file-format registry (:mod:`.surface_formats`; the built-in ones, with the
Zemax records of the same types, in :mod:`.surface_handlers`): the type commands ``SPH``/``CON``/
``ASP`` and the modifiers a type owns (``K``, ``A`` ... ``J``) are looked up there, and the
writer asks the handler of the surface's class.

The file is a sequence of commands, one per line or several separated by ``;``; ``!`` starts a
comment, ``&`` at the end of a line continues the command on the next, ``'...'`` or ``"..."``
quote a string, keywords are case-insensitive.  Mapping onto
:class:`~deeplens.optics.lens.Lens` (mm, nm):

* ``DIM M|C|I`` scales every length to mm (mm, cm, inch).  ``RDM Y`` (the default) reads the
  first number of a surface command as a radius (``0``: flat), ``RDM N`` as a curvature.
* ``SO r t [glass]`` is the object: ``t`` its distance (``|t| >= 1e10``: at infinity), ``r``
  must be 0.  ``S r t [glass]`` a surface, ``t`` the gap to the next vertex; no glass is air.
  ``SI r t`` the image: ``r`` must be 0, ``t`` (a defocus) is added to the last gap.  A flat
  surface in air that is not the stop and has no ``CIR`` is a dummy: its thickness joins the gap.
* After a surface command, ``STO`` (or ``STOP``) makes it the stop; ``SPH``/``CON``/``ASP``
  its type; ``K``, ``A`` ... ``J`` its conic and coefficients; ``CIR r`` (or ``CIR CLR r``) its
  clear semi-diameter; ``THI``, ``GLA``, ``RDY``/``CUY`` change its thickness, glass, radius or
  curvature.  ``CIR`` on ``SI`` is the sensor semi-diameter.  A surface without ``CIR`` gets
  the paraxial estimate ``1.05 (|y_marginal| + |y_chief|)`` at the largest field (capped to its
  conic's domain; two estimates that cross are limited to where the surfaces meet).
  ``CIR EDG`` (a mechanical edge) is read and not used.
* Glasses: ``NAME_CATALOGUE`` (CODE V drops the hyphen: ``NBK7_SCHOTT`` is SCHOTT's ``N-BK7``)
  from the vendor catalogues of :mod:`.vendor_glass` (current, archived, previous); a bare name
  from deeplens' catalogue (:func:`~deeplens.optics.materials.get_material`), else from the one
  vendor catalogue that holds it; a fictitious glass ``NNNNNN.VVVV`` (``n_d = 1.NNNNNN``,
  ``V_d = VV.VV``: ``517000.642000`` is 1.517 / 64.2) as a
  :class:`~deeplens.optics.materials.ModelGlass`.
* ``WL`` wavelengths in nm, ``REF`` the reference one (1-based; the first without one).
* ``EPD`` -> ``epd``; ``FNO`` -> ``fno`` (image-space F-number) at infinity, with a finite
  object the ``epd`` that gives the working F-number ``|u'| = 1/(2F)`` (a warning).  A ``CIR``
  on the stop narrower than the beam the EPD gives is the stop's ``clear_radius`` (a lens or
  mirror surface; a flat stop in air is read as a flat ``Asphere`` to hold it,
  :mod:`.stop_clear`).
* Fields: ``YAN`` (degrees), ``YOB`` (object heights, finite object: the object point
  ``(0, h)``, ``θ = -atan(h / (s + z_EP))``: a positive angle rises towards ``+y``),
  ``YIM`` (paraxial image heights: at infinity ``θ = atan(h' / f)``, with a finite object the
  object heights ``h' / m``, ``m`` signed, then as ``YOB``); the
  ``X`` components must be 0.
* Read and not used: ``TIT``/``TITLE`` (the lens name), ``LEN``, ``INI``, ``WTW``, ``WTF``,
  ``GO``, ``SLB``, ``TEM``, ``PRE``, solves and variables (``PIM``, ``CCY``, ``THC``, ...);
  vignetting factors (``VUY``, ``VLY``, ...) other than 0 are reported as a
  :class:`CodeVWarning` (deeplens fills the whole pupil).

``REFL`` in place of a glass makes the surface a mirror (``Lens(mirrors=...)``: the medium
after it is the one before, and the file's negative thicknesses after it are kept, CODE V's
sign convention being deeplens' and OpticStudio's).

Decenters and tilts (``XDE`` ... ``CDE``, ``DAR``, ``BEN``, ``REV``, ``RET``) become
:class:`~deeplens.optics.surfaces.CoordinateBreak` surfaces (:mod:`.codev_decenter`, which
states each convention and its source); rectangular and elliptical apertures (``REX``,
``REY`` or ``ELX``, ``ELY``, with ``ADX``, ``ADY``) a surface's clear rectangle or ellipse, or a
rectangular or elliptical aperture (:mod:`.codev_apertures`).
``DIM`` may stand anywhere (the unit of every length); ``POL N`` and a bare ``CA`` (with a
warning) are read and not used.  A zoom lens (``ZOO``, :mod:`.codev_zoom`) is read at one zoom
position (``read_seq(path, zoom=N)``) or at every one (:func:`read_seq_zooms`).

Defaults (docs/guide/codev.md, "Defaults"; each with a located :class:`CodeVWarning`): no
``STO``: the first surface is the stop; several ``WL`` without ``REF``: the first is the
reference; no ``SI``: ``SI 0 0``; no ``RDM``: radii (``read_seq(..., radius_mode=False)``:
curvatures).  ``PRV`` ... ``END`` private glasses (indices at the ``PWL`` wavelengths) are
:class:`~.codev_private.PrivateGlass` splines; ``CIR OBS r`` / ``CIR HOL r`` a central
obscuration; ``PIK`` pickups of ``RDY``, ``CUY``, ``THI`` are applied; ``AC 0`` is read.

Everything else (other surface types, ``NA``/``NAO``, real image heights, surface qualifiers
such as ``S3``) is refused: a
:class:`~deeplens.optics.errors.LensFileError` naming the file, the line and what was expected.

:func:`write_seq` writes what :func:`read_seq` reads (curvature mode ``RDM N``, numbers with
``repr``), so a lens read, written and read again has the same prescription; a lens whose
aperture is its stop's size is written with the ``EPD`` that stop gives.
"""

from __future__ import annotations

import math
import re
import warnings
from decimal import Decimal
from pathlib import Path

import torch

from ..errors import LensFileError, SurfacesCrossError
from ..lens import Lens, LensSpec
from ..materials import GLASS_TABLE, Air, Material, ModelGlass, get_material
from ..surfaces import Asphere
from .agf import AGFGlass
from .codev_apertures import APERTURE_COMMANDS, aperture_command, apply_aperture, write_aperture
from .codev_zoom import apply_zoom, set_surface_value, surface_value, zoom_command, zoom_count
from .codev_decenter import (DECENTER_COMMANDS, decenter_command, expand_decenters,
                             write_break)
from .filecheck import read_file_bytes
from .fictitious_glass import fictitious_glass as _fictitious
from .stop_clear import flat_stop_as_asphere, plain_circular_stop
from .surface_handlers import FORMATS
from .withdrawn_glass import withdrawn_glass
from .vendor_glass import (BuchdahlGlass, archived_glass, find_in_vendor_catalogues,
                           previous_glass, vendor_glass)

__all__ = ["CodeVWarning", "read_seq", "read_seq_zooms", "write_seq"]

_UNITS = {"M": 1.0, "MM": 1.0, "C": 10.0, "CM": 10.0, "I": 25.4, "IN": 25.4}
_INFINITE = 1e10                    # CODE V: an object this far (or farther) is at infinity
# read and not used (titles, weights, solves, variables, end of input)
_IGNORED = {"LEN", "INI", "WTW", "WTF", "GO", "SLB", "TEM", "PRE", "CWL", "PIM", "CCY", "THC",
            "CCX", "GLC", "DER", "CLS", "CUM", "THM"}
# pickups (PIK) of these surface parameters are applied: (target) = factor * (source) + offset
_PICKUPS = ("RDY", "CUY", "THI")
_VIGNETTING = {"VUX", "VLX", "VUY", "VLY"}
_FIELDS = {"XAN", "YAN", "XOB", "YOB", "XIM", "YIM"}
_BASE_CATALOGUES = ("SCHOTT",)      # deeplens-table glasses written as NAME_SCHOTT


class CodeVWarning(UserWarning):
    """A line of a ``.seq`` file that was understood but is not used."""


# --------------------------------------------------------------------------- tokens
def _commands(text: str, source: str) -> list[tuple[int, list[str]]]:
    """``[(line, tokens)]``: one entry per command, ``line`` 1-based (the line it starts on),
    comments removed, continuations joined, quoted strings kept as one token (unquoted)."""
    out: list[tuple[int, list[str]]] = []
    pending, start = "", 0
    for k, raw in enumerate(text.splitlines(), start=1):
        if not pending:
            start = k
        s = pending + _without_comment(raw).rstrip()
        if s.endswith("&"):
            pending = s[:-1] + " "
            continue
        pending = ""
        out += [(start, toks) for toks in _tokens(s, source, start) if toks]
    if pending:
        raise LensFileError("the last command ends in '&' (a continuation with no next line)",
                            source=source, line=start)
    return out


def _without_comment(line: str) -> str:
    """``line`` up to its first ``!`` outside quotes."""
    quote = None
    for j, ch in enumerate(line):
        if quote is None and ch == "!":
            return line[:j]
        if ch in "'\"":
            quote = ch if quote is None else (None if quote == ch else quote)
    return line


def _tokens(s: str, source: str, line: int) -> list[list[str]]:
    """The commands of one logical line: split at ``;`` and blanks outside quotes."""
    cmds, toks, cur, quote, quoted = [], [], [], None, False
    for ch in s + ";":
        if quote is not None:
            if ch == quote:
                quote = None
            else:
                cur.append(ch)
        elif ch in "'\"":
            quote, quoted = ch, True
        elif ch.isspace() or ch == ";":
            if cur or quoted:
                toks.append("".join(cur))
            cur, quoted = [], False
            if ch == ";":
                cmds.append(toks)
                toks = []
        else:
            cur.append(ch)
    if quote is not None:
        raise LensFileError(f"unbalanced quote {quote}: expected a closing {quote} on the same "
                            f"line", source=source, line=line)
    return cmds


# --------------------------------------------------------------------------- glasses
def _fictitious_code(m: ModelGlass, i: int) -> str:
    """The fictitious-glass token of ``m`` (exact: ``_fictitious`` gives back ``n_d``, ``V_d``)."""
    if not (1.0 < m.n_d < 2.0 and 0.0 < m.v_d < 100.0):
        raise LensFileError(f"medium after surface {i}: a model glass n_d = {m.n_d!r}, "
                            f"V_d = {m.v_d!r} has no CODE V fictitious-glass code (expected "
                            f"1 < n_d < 2 and 0 < V_d < 100)", surfaces=(i,))
    n = format(Decimal(repr(m.n_d)) - 1, "f").split(".")[1]
    v = format(Decimal(repr(m.v_d)) / 100, "f").split(".")[1]
    return f"{n}.{v}"


def _hyphenated(name: str) -> list[str]:
    """``name`` and the names CODE V writes without their hyphen: ``NBK7`` -> ``N-BK7``."""
    return [name] + [name[:k] + "-" + name[k:] for k in (1, 2)
                     if len(name) > k and name[:k].isalpha()]


def _catalogue_glass(name: str, cat: str) -> Material | None:
    for look in (vendor_glass, archived_glass, withdrawn_glass):
        for cand in _hyphenated(name):
            g = look(cand, cat)
            if g is not None:
                return g
    g = previous_glass(name, cat)
    if g is not None:
        return g
    from .zmx_glass import BUILTIN_CATALOGUES   # deeplens' own SCHOTT entries (B270, ...)

    for cand in _hyphenated(name):
        if cand in BUILTIN_CATALOGUES.get(cat, ()) and cand in GLASS_TABLE:
            return get_material(cand)
    return None


def _glass(tok: str, source: str, line: int, private=None) -> Material:
    """The material a glass token names (see the module docstring); ``private``: the file's
    ``PRV`` glasses by upper-case name, found first."""
    up = tok.upper()
    if private and up in private:
        return private[up]
    if re.fullmatch(r"[\d.]+", tok):
        m = _fictitious(tok)
        if m is None:
            raise LensFileError(f"glass {tok!r}: a numeric glass must be a fictitious-glass "
                                f"code NNNNNN.VVVV (n_d = 1.NNNNNN, V_d = VV.VV); a code "
                                f"without its decimal point is ambiguous", source=source,
                                line=line)
        return m
    if "_" in up:
        name, cat = up.rsplit("_", 1)
        g = _catalogue_glass(name, cat)
        if g is None:
            raise LensFileError(f"glass {tok!r}: {name} not found in the {cat} catalogue "
                                f"(searched current, archived and previous vendor catalogues "
                                f"with and without a hyphen after the prefix)", source=source,
                                line=line)
        return g
    for cand in _hyphenated(up):
        if cand in GLASS_TABLE:
            return get_material(cand)
    hits = [c for c in find_in_vendor_catalogues(up) if " " not in c]
    for cand in _hyphenated(up)[1:]:
        hits += [c for c in find_in_vendor_catalogues(cand) if " " not in c]
    hits = list(dict.fromkeys(hits))
    if len(hits) == 1:
        return _catalogue_glass(up, hits[0])
    if hits:
        raise LensFileError(f"glass {tok!r} is in several vendor catalogues ({', '.join(hits)}); "
                            f"expected NAME_CATALOGUE, e.g. {up}_{hits[0]}", source=source,
                            line=line)
    older = list(dict.fromkeys(c for cand in _hyphenated(up)
                               for c in find_in_vendor_catalogues(cand) if " " in c))
    if older:   # only in archived or previous catalogues: a bare name does not choose one
        cat = older[0].split()[0]
        raise LensFileError(f"glass {tok!r} is in no current catalogue, only in "
                            f"{', '.join(older)}; expected NAME_CATALOGUE, e.g. {up}_{cat}",
                            source=source, line=line)
    raise LensFileError(f"glass {tok!r} not found (deeplens' catalogue and the current vendor "
                        f"catalogues); expected NAME_CATALOGUE or a fictitious glass "
                        f"NNNNNN.VVVV", source=source, line=line)


def _glass_token(m: Material, i: int) -> str | None:
    """The glass token of the medium after surface ``i`` (``None`` for air)."""
    if isinstance(m, Air):
        return None
    if isinstance(m, (AGFGlass, BuchdahlGlass)) and m.catalogue and "_" not in m.catalogue \
            and m.catalogue.isalnum():
        return "".join(m.name.replace("-", "").split()).upper() + "_" + m.catalogue.upper()
    if isinstance(m, ModelGlass):
        return _fictitious_code(m, i)
    from .codev_private import PrivateGlass

    if isinstance(m, PrivateGlass):   # its table is written in a PRV block (write_seq)
        if "'" in m.name or not m.name.strip():
            raise LensFileError(f"medium after surface {i}: private glass name {m.name!r} "
                                f"cannot be quoted in a .seq file", surfaces=(i,))
        return f"'{m.name}'"
    rec = GLASS_TABLE.get(m.name.upper())
    if rec is not None:
        from .zmx_glass import BUILTIN_CATALOGUES

        for cat in _BASE_CATALOGUES:
            if rec.name in BUILTIN_CATALOGUES.get(cat, ()):
                return rec.name.replace("-", "").upper() + "_" + cat
    raise LensFileError(f"medium after surface {i}: {m.name!r} ({type(m).__name__}) has no "
                        f"CODE V catalogue name; expected a vendor catalogue glass, a SCHOTT "
                        f"glass of deeplens' catalogue or an n_d/V_d model glass",
                        surfaces=(i,))


# --------------------------------------------------------------------------- reader
def _num(tok: str, what: str, source: str, line: int) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise LensFileError(f"{what}: expected a number, got {tok!r}", source=source,
                            line=line) from None
    if not math.isfinite(v):
        raise LensFileError(f"{what}: expected a finite number, got {tok!r}", source=source,
                            line=line)
    return v


class _Reader:
    """Commands -> the file's system data and surface records (lengths still in file units)."""

    def __init__(self, source: str, radius_mode: bool | None = None):
        self.src = source
        self.radius_mode = True if radius_mode is None else bool(radius_mode)
        self.rdm_forced = radius_mode is not None   # the caller's choice beats the file's RDM
        self.rdm_line = None    # the file's RDM line
        self.prv = None         # inside a PRV block: {"line", "wl": ([nm], line) | None}
        self.private = {}       # NAME -> PrivateGlass (PRV blocks)
        self.pickups = []       # (line, (target param, surface), (source param, surface),
        #                          factor, offset): applied in _build
        self.unit = 1.0
        self.dim_line = None    # the file's DIM line
        self.title = ""
        self.wl = None          # ([nm], line)
        self.ref = None         # (k, line)
        self.pupil = None       # (kind, value, line)
        self.fields = {}        # cmd -> ([values], line)
        self.surfs = []         # dicts: kind, line, c, t, glass, ...
        self.zoom = {"n": None, "params": []}   # ZOO lines (codev_zoom)
        self.stage = "system"   # "system", "surfaces" (after SO), "done" (after SI)

    def fail(self, line, msg):
        raise LensFileError(msg, source=self.src, line=line)

    def nums(self, toks, line, what, n=None):
        if n is not None and len(toks) != n:
            self.fail(line, f"{what}: expected {n} number{'s' if n != 1 else ''}, got "
                            f"{len(toks)} ({' '.join(toks) or 'none'})")
        if not toks:
            self.fail(line, f"{what}: expected at least one number")
        return [_num(t, what, self.src, line) for t in toks]

    def command(self, line: int, toks: list[str]) -> None:
        cmd, args = toks[0].upper(), toks[1:]
        if self.prv is not None:
            self.private_glass(cmd, toks, line)
        elif cmd == "PRV":
            if args:
                self.fail(line, "PRV: expected it alone (then PWL, the glasses, END)")
            self.prv = {"line": line, "wl": None}
        elif cmd == "PIK":
            self.pickup(args, line)
        elif cmd == "ZOO":   # zoom positions and zoomed values: codev_zoom
            zoom_command(self.zoom, args, line, self.nums, self.fail)
        elif cmd == "AC":
            # read as a zero coefficient only: deeplens knows no meaning of a non-zero AC
            if self.nums(args, line, "AC", 1)[0] != 0:
                self.fail(line, "AC other than 0 is not supported (expected AC 0)")
        elif cmd in ("TIT", "TITLE"):
            self.title = " ".join(args)
        elif cmd in _IGNORED:
            return
        elif cmd == "POL":
            # polarization ray tracing: off (N) changes no ray; deeplens traces none
            if [a.upper() for a in args] not in (["N"], ["NO"]):
                self.fail(line, f"POL {' '.join(args)}: polarization ray tracing is not "
                                f"supported; expected POL N")
        elif cmd == "CA" and not args:
            # no CODE V source for a bare CA found; rayoptics' reader takes it (spec_data) and
            # sets nothing: read and not used, said
            _warn(self.src, line, "CA (no value): read and not used (rayoptics' reader does "
                                  "the same); the surfaces' apertures are their CIR/REX/REY")
        elif cmd == "DIM":
            if len(args) != 1 or args[0].upper() not in _UNITS:
                self.fail(line, f"DIM: expected M, C or I (mm, cm, inch), got {' '.join(args)!r}")
            # the unit of every length in the file, wherever DIM stands (the lengths are
            # scaled when the lens is built; rayoptics' reader also reads DIM after the
            # surfaces, as in its threemir.seq, and keeps the numbers as written)
            unit = _UNITS[args[0].upper()]
            if self.dim_line is not None and unit != self.unit:
                self.fail(line, f"DIM {args[0]}: a second, different unit (line "
                                f"{self.dim_line}); expected one DIM")
            self.unit, self.dim_line = unit, line
        elif cmd == "RDM":
            if len(args) > 1 or (args and args[0].upper() not in ("Y", "N", "YES", "NO")):
                self.fail(line, f"RDM: expected Y or N, got {' '.join(args)!r}")
            self.rdm_line = line
            if not self.rdm_forced:
                self.radius_mode = not args or args[0].upper().startswith("Y")
        elif cmd == "WL":
            self.wl = (self.nums(args, line, "WL (wavelengths, nm)"), line)
        elif cmd == "REF":
            v = self.nums(args, line, "REF (reference wavelength number)", 1)[0]
            if v != int(v):
                self.fail(line, f"REF: expected a wavelength number 1, 2, ..., got {args[0]}")
            self.ref = (int(v), line)
        elif cmd in ("EPD", "FNO"):
            v = self.nums(args, line, cmd, 1)[0]
            if self.pupil is not None:
                self.fail(line, f"{cmd}: the system aperture is already given by "
                                f"{self.pupil[0]} on line {self.pupil[2]}")
            self.pupil = (cmd, v, line)
        elif cmd in ("NA", "NAO"):
            self.fail(line, f"{cmd} (a numerical aperture) is not supported: expected EPD or FNO")
        elif cmd in _FIELDS:
            self.fields[cmd] = (self.nums(args, line, cmd), line)
        elif cmd in ("XRI", "YRI"):
            self.fail(line, f"{cmd} (real image heights) is not supported: expected YAN, YOB "
                            f"or YIM")
        elif cmd in _VIGNETTING:
            vals = self.nums(args, line, cmd)
            if any(vals):
                warnings.warn(CodeVWarning(f"{self.src}:{line}: {cmd}: vignetting factors are "
                                           f"not used (deeplens fills the whole pupil)"),
                              stacklevel=4)
        elif cmd in ("SO", "S", "SI"):
            self.surface(cmd, args, line)
        elif cmd in DECENTER_COMMANDS and self.surfs:   # decenters and tilts: codev_decenter
            decenter_command(self.surfs[-1], cmd, args, line, self.nums, self.fail)
        elif cmd in APERTURE_COMMANDS and self.surfs:   # rectangles, ellipses: codev_apertures
            aperture_command(self.surfs[-1], cmd, args, line, self.nums, self.fail)
        else:
            self.modifier(cmd, args, line)

    def private_glass(self, cmd, toks, line):
        """A line inside ``PRV ... END``: ``PWL`` wavelengths, a glass ``'NAME' n1 n2 ...``,
        or ``END``."""
        from .codev_private import PrivateGlass

        if cmd == "END":
            if self.prv["wl"] is None:
                self.fail(line, "END of a PRV block with no PWL line: expected PWL (nm)")
            self.prv = None
        elif cmd == "PWL":
            self.prv["wl"] = (self.nums(toks[1:], line, "PWL (private catalogue wavelengths, "
                                                         "nm)"), line)
        else:
            if self.prv["wl"] is None:
                self.fail(line, f"private glass {toks[0]!r} before the PWL line: expected PWL "
                                f"(the wavelengths, nm) first")
            waves, wl_line = self.prv["wl"]
            n = self.nums(toks[1:], line, f"private glass {toks[0]!r} (indices)")
            if len(n) != len(waves):
                self.fail(line, f"private glass {toks[0]!r}: {len(n)} indices for the "
                                f"{len(waves)} PWL wavelengths of line {wl_line}: expected one "
                                f"index per wavelength")
            try:
                self.private[toks[0].upper()] = PrivateGlass(toks[0], waves, n)
            except ValueError as e:
                self.fail(line, str(e))

    def pickup(self, args, line):
        """``PIK P Sk [Zn] Q Sm [Zn] [factor [offset]]``: parameter P of surface k is factor times
        parameter Q of surface m plus offset (RDY, CUY, THI; zoom position 1 only)."""
        toks = [a.upper() for a in args]
        parts, j = [], 0
        for _ in range(2):
            if j + 1 >= len(toks) or toks[j] not in _PICKUPS or \
                    not re.fullmatch(r"S(\d+|O|I)", toks[j + 1]):
                self.fail(line, f"PIK {' '.join(args)}: expected 'PIK P Sk Q Sm [factor "
                                f"[offset]]' with P, Q among {', '.join(_PICKUPS)}")
            q = toks[j + 1][1:]
            parts.append((toks[j], 0 if q == "O" else (-1 if q == "I" else int(q))))
            j += 2
            if j < len(toks) and re.fullmatch(r"Z\d+", toks[j]):
                if toks[j] != "Z1":
                    self.fail(line, f"PIK: zoom position {toks[j]}: only Z1 is read")
                j += 1
        nums = self.nums(args[j:], line, "PIK factor, offset") if j < len(toks) else []
        if len(nums) > 2:
            self.fail(line, "PIK: expected at most a factor and an offset after the source")
        factor, offset = (nums + [1.0, 0.0][len(nums):])[:2]
        self.pickups.append((line, parts[0], parts[1], factor, offset))

    def surface(self, cmd, args, line):
        if cmd == "SO" and self.stage != "system":
            self.fail(line, "SO: a second object surface")
        if cmd != "SO" and self.stage != "surfaces":
            self.fail(line, f"{cmd}: expected SO (the object) first" if self.stage == "system"
                      else f"{cmd} after SI (the image is the last surface)")
        if len(args) not in (2, 3):
            self.fail(line, f"{cmd}: expected '{cmd} radius thickness [glass]', got "
                            f"{' '.join(args)!r}")
        if cmd == "SO" and args[1].lower() in ("inf", "+inf", "infinity"):
            args = [args[0], "1e20", *args[2:]]   # an object at infinity (|t| >= 1e10)
        r, t = (_num(a, f"{cmd} {w}", self.src, line)
                for a, w in zip(args, ("radius" if self.radius_mode else "curvature",
                                       "thickness")))
        self.surfs.append({"kind": cmd, "line": line, "c": self.curvature(r), "t": t,
                           "glass": (args[2], line) if len(args) == 3 else None, "stop": False,
                           "type": "SPH", "k": 0.0, "coef": {}, "cir": None})
        self.stage = {"SO": "surfaces", "S": "surfaces", "SI": "done"}[cmd]

    def curvature(self, v: float) -> float:
        if self.radius_mode:
            return 0.0 if v == 0 else 1.0 / v
        return v

    def modifier(self, cmd, args, line):
        if not self.surfs:
            self.fail(line, f"unsupported command {cmd!r} (before the surfaces); expected a "
                            f"system command (DIM, RDM, WL, REF, EPD, FNO, YAN, YOB, YIM, TIT) "
                            f"or SO")
        s = self.surfs[-1]
        if args and re.fullmatch(r"S(\d+|O|I|S)(\.\.\S+)?", args[0].upper()):
            self.fail(line, f"{cmd} {args[0]}: surface qualifiers are not supported; expected "
                            f"the command in the surface's own block")
        if cmd in ("STO", "STOP"):
            if args or s["kind"] != "S":
                self.fail(line, f"{cmd}: expected it alone, after an S surface")
            s["stop"] = True
        elif FORMATS.for_codev_type(cmd) is not None:   # a surface type: SPH, CON, ASP
            if args:
                self.fail(line, f"{cmd}: expected no value")
            s["type"] = cmd
        elif cmd in FORMATS.for_codev_type(s["type"]).codev_data:   # K, A..J of an asphere
            v = self.nums(args, line, cmd, 1)[0]
            FORMATS.for_codev_type(s["type"]).codev_modifier(
                s, cmd, v, lambda msg: self.fail(line, msg))
        elif cmd == "CIR":
            # qualifiers: CLR, EDG, OBS or HOL, and an aperture label L'name' (not used)
            quals = [a.upper() for a in args[:-1]
                     if a.upper() in ("CLR", "EDG", "OBS", "HOL") or not a.upper().startswith("L")]
            v = self.nums(args[-1:], line, "CIR (semi-diameter)", 1)[0]
            if quals in ([], ["CLR"], ["OBS"], ["HOL"]) and not v > 0:
                self.fail(line, f"CIR: expected a radius > 0, got {args[-1]}")
            if quals in ([], ["CLR"]):
                s["cir"] = (v, line)
            elif quals in (["OBS"], ["HOL"]):
                if s["kind"] != "S":
                    self.fail(line, f"CIR {quals[0]}: expected it on an S surface")
                s["obs"] = (v, line, quals[0])
            elif quals != ["EDG"]:
                self.fail(line, f"CIR {' '.join(quals)}: only a clear aperture (CIR r, CIR CLR "
                                f"r), a central obscuration or hole (CIR OBS r, CIR HOL r) or an "
                                f"edge (CIR EDG r, not used) is supported")
        elif cmd == "THI":
            s["t"] = self.nums(args, line, "THI", 1)[0]
        elif cmd == "GLA":
            if len(args) != 1:
                self.fail(line, "GLA: expected one glass")
            s["glass"] = (args[0], line)
        elif cmd in ("RDY", "CUY"):
            v = self.nums(args, line, cmd, 1)[0]
            s["c"] = (0.0 if v == 0 else 1.0 / v) if cmd == "RDY" else v
        elif cmd == "CUF":
            if self.nums(args, line, cmd, 1)[0] != 0:
                self.fail(line, "CUF other than 0 is not supported")
        else:
            self.fail(line, f"unsupported command {cmd!r}; deeplens reads surfaces (S, SPH, "
                            f"CON, ASP, K, A..J, CIR, STO, THI, GLA, RDY, CUY), the system "
                            f"(DIM, RDM, WL, REF, EPD, FNO, YAN, YOB, YIM), decenters (XDE .. CDE, "
                            f"DAR, BEN, REV, RET) and nothing else (other surface types are "
                            f"refused)")


def read_seq(path, radius_mode: bool | None = None, zoom: int | None = None) -> Lens:
    """Read a CODE V ``.seq`` file (the common subset: see :mod:`.codev`).

    Args:
        path: the ``.seq`` file (UTF-8, UTF-16 with byte-order mark, or Latin-1 text).
        radius_mode: ``None`` (default): the file's ``RDM`` line, radius mode without one (with
            a :class:`CodeVWarning`: rayoptics reads such a file in curvature mode); ``True``
            or ``False``: read the surfaces' first numbers as radii or curvatures whatever the
            file says.
        zoom: the zoom position of a zoom lens (``ZOO`` lines, :mod:`.codev_zoom`), from 1;
            ``None``: position 1 (with a :class:`CodeVWarning` when the file has others).
            :func:`read_seq_zooms` reads every position.

    Returns:
        The lens (lengths in mm, wavelengths in nm).

    Raises:
        FileNotFoundError: no such file.
        LensFileError: an unsupported command or value; ``source`` and ``line`` say where, the
            message what was expected.

    Example::

        lens = read_seq("tests/data/codev/cooke_triplet.seq")
    """
    path = Path(path)
    rd = _read_commands(path, radius_mode)
    n = zoom_count(rd.zoom)
    if zoom is None and n > 1:
        _warn(rd.src, rd.zoom["n"][1], f"a zoom lens with {n} positions: position 1 read; "
                                       f"read_seq(path, zoom=N) reads position N, "
                                       f"read_seq_zooms(path) every position")
    apply_zoom(rd, 1 if zoom is None else int(zoom))
    return _build(rd, path)


def read_seq_zooms(path, radius_mode: bool | None = None) -> list[Lens]:
    """Every zoom position of a CODE V ``.seq`` file, one :class:`Lens` each (position 1
    first; a file without ``ZOO`` gives one lens), as :func:`~.zmx_configs.read_zmx_configs`
    gives a ``.zmx`` file's configurations: each lens is :func:`read_seq` ``(path, zoom=N)``,
    and the surfaces no position changes are shared **by object**
    (:func:`~.zmx_configs.share_surfaces`: the same module in every lens, its semi-diameter the
    largest of the positions'), so a change to a shared surface changes every position.

    Raises:
        LensFileError: as :func:`read_seq` for any position, or a shared surface whose largest
            semi-diameter does not fit a position (surfaces that then cross), located at the
            ``ZOO n`` line.
    """
    from .zmx_configs import share_surfaces

    path = Path(path)
    rd = _read_commands(path, radius_mode)
    n = zoom_count(rd.zoom)
    lenses = [read_seq(path, radius_mode, zoom=k) for k in range(1, n + 1)]
    share_surfaces(lenses)
    for k, lens in enumerate(lenses, start=1):
        try:
            lens.check()
        except ValueError as e:
            rd.fail(rd.zoom["n"][1], f"zoom position {k}, with the surfaces shared between the "
                                     f"positions (each the largest semi-diameter of any "
                                     f"position): {e}")
    return lenses


def _read_commands(path: Path, radius_mode: bool | None) -> "_Reader":
    """The file's commands read into a :class:`_Reader` (nothing built yet)."""
    if not path.exists():
        raise FileNotFoundError(f"lens file not found: {path}")
    src = str(path)
    raw = read_file_bytes(path)   # a regular file of at most 64 MiB (filecheck)
    try:
        text = raw.decode("utf-16" if raw[:2] in (b"\xff\xfe", b"\xfe\xff") else "utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    rd = _Reader(src, radius_mode)
    for line, toks in _commands(text, src):
        rd.command(line, toks)
    if rd.prv is not None:
        rd.fail(rd.prv["line"], "PRV block with no END: expected END after its glasses")
    if rd.rdm_line is None and radius_mode is None and any(
            s["c"] != 0 for s in rd.surfs):
        _warn(src, None, "no RDM line: the surfaces' first numbers are read as radii (RDM Y, "
                         "deeplens' reading of CODE V's default; rayoptics reads them as "
                         "curvatures); read_seq(..., radius_mode=False) reads curvatures")
    return rd


def _warn(src: str, line: int | None, msg: str) -> None:
    warnings.warn(CodeVWarning(f"{src}:{line}: {msg}" if line else f"{src}: {msg}"),
                  stacklevel=3)


def _build(rd: _Reader, path: Path) -> Lens:
    src, u = rd.src, rd.unit
    fail = rd.fail
    if rd.surfs and rd.surfs[-1]["kind"] == "S":
        # CODE V's image surface always exists (S inserts surfaces before it): a file without
        # SI has a flat image at the last surface's thickness (rayoptics: the same plane)
        last = rd.surfs[-1]
        _warn(src, last["line"], "no SI line: the image is a plane at the last surface's "
                                 "thickness (SI 0 0)")
        rd.surfs.append({"kind": "SI", "line": last["line"], "c": 0.0, "t": 0.0, "glass": None,
                         "stop": False, "type": "SPH", "k": 0.0, "coef": {}, "cir": None})
    if not rd.surfs or rd.surfs[-1]["kind"] != "SI":
        fail(rd.surfs[-1]["line"] if rd.surfs else None,
             "no image surface: expected SO, the surfaces and SI")
    _apply_pickups(rd)
    obj, img, body = rd.surfs[0], rd.surfs[-1], rd.surfs[1:-1]
    if not body:
        fail(img["line"], "no surface between SO and SI")
    for s, what in ((obj, "SO (the object)"), (img, "SI (the image)")):
        if s["c"] != 0 or s["type"] != "SPH" or s["stop"]:
            fail(s["line"], f"{what}: expected a flat surface (radius 0)")
    if img["glass"] is not None:
        fail(img["line"], "SI: the image surface takes no glass")
    obj, body, img = expand_decenters(obj, body, img, u, fail)   # -> coordinate breaks
    # wavelengths
    if rd.wl is None:
        fail(None, "no wavelengths: expected a WL line (nm)")
    waves, wl_line = rd.wl
    if rd.ref is None:
        if len(waves) > 1:
            # rayoptics' and optiland's CODE V readers both take the first (no CODE V source)
            _warn(src, wl_line, f"several wavelengths and no REF line: the first, {waves[0]!r} "
                                f"nm, is the reference wavelength (REF 1)")
        ref = 1
    else:
        ref, ref_line = rd.ref
        if not 1 <= ref <= len(waves):
            fail(ref_line, f"REF {ref}: expected 1..{len(waves)} (the WL numbers)")
    primary = waves[ref - 1]
    # object
    if not any(s["stop"] for s in body):
        # rayoptics and optiland: the first surface (no CODE V source found)
        _warn(src, body[0]["line"], "no STO line: the stop is the first surface (S 1)")
        body[0]["stop"] = True
    priv = rd.private
    media = [Air() if obj["glass"] is None else _glass(obj["glass"][0], src, obj["glass"][1],
                                                       priv)]
    od = obj["t"] * u
    obj_dist = math.inf if abs(obj["t"]) >= _INFINITE else od
    if obj_dist == 0:
        fail(obj["line"], "SO: the object distance must not be 0")
    # surfaces: dummies into gaps
    surfaces, distances, where, autos, stop = [], [], [], [], None
    gap, lead = 0.0, 0.0   # lead: leading dummies' thickness, added to the object distance
    obs = []               # (surface index, (radius, line, OBS | HOL))
    mirrors = []
    for s in body:
        if s["kind"] == "CB":   # a decenter's coordinate break (codev_decenter)
            if not surfaces:
                lead, gap = gap, 0.0
            surfaces.append(s["cb"])
            distances.append(gap)
            where.append(s["line"])
            media.append(media[-1])
            gap = s["t"] * u
            continue
        mirror = s["glass"] is not None and s["glass"][0].upper() == "REFL"
        if mirror:   # the medium after a mirror is the one before it
            mat = media[-1]
        else:
            mat = Air() if s["glass"] is None else _glass(s["glass"][0], src, s["glass"][1],
                                                          priv)
            _check_private(mat, waves, s, fail)
        c = s["c"] / u
        flat_air = (c == 0 and s["type"] == "SPH" and isinstance(mat, Air)
                    and isinstance(media[-1], Air) and not mirror)
        if flat_air and not s["stop"] and s["cir"] is None and s.get("obs") is None \
                and not s.get("rect"):
            gap += s["t"] * u          # a dummy surface
            continue
        sd = s["cir"][0] * u if s["cir"] is not None else _provisional(c, s["k"])
        if s["cir"] is None and not s.get("rect"):
            autos.append(len(surfaces))
        surf = FORMATS.for_codev_type(s["type"]).read_codev(s, c, sd, u, flat_air)
        surf = apply_aperture(s, surf, u, flat_air, fail)   # REX/REY, ELX/ELY
        if s.get("obs") is not None:
            obs.append((len(surfaces), s["obs"]))
        if s["stop"]:
            if stop is not None:
                fail(s["line"], f"STO: a second stop (the first is on line {where[stop]})")
            stop = len(surfaces)
        if not surfaces:
            lead, gap = gap, 0.0
        if mirror:
            mirrors.append(len(surfaces))
        surfaces.append(surf)
        distances.append(gap)
        where.append(s["line"])
        media.append(mat)
        gap = s["t"] * u
    if stop is None:
        fail(None, "no stop: expected STO after the stop surface's S line")
    if not math.isinf(obj_dist):
        obj_dist += lead
    d_sensor = gap + img["t"] * u
    sensor_sd = img["cir"][0] * u if img["cir"] is not None else None
    # system aperture
    if rd.pupil is None:
        fail(None, "no system aperture: expected EPD or FNO")
    kind, value, ap_line = rd.pupil
    ap_type, ap_value = ("epd", value * u) if kind == "EPD" else ("fno", value)
    fno_finite = kind == "FNO" and not math.isinf(obj_dist)
    if fno_finite:   # the EPD this working F-number gives, once the lens exists
        if not value > 0:
            fail(ap_line, f"FNO {value!r}: expected an F-number > 0")
        ap_type, ap_value = "epd", 1.0
    try:
        spec = LensSpec(object_distance_mm=obj_dist, aperture_type=ap_type,
                        aperture_value=ap_value, fields_deg=[0.0], wavelengths_nm=waves,
                        primary_wavelength_nm=primary)
    except ValueError as e:
        key = getattr(e, "key", None)
        line = {"aperture": ap_line, "object_distance_mm": obj["line"]}.get(key, wl_line)
        fail(line, str(e))
    name = rd.title or path.stem
    try:
        lens = Lens(surfaces, media, distances, d_sensor, stop, sensor_sd, spec, name=name,
                    mirrors=mirrors)
    except ValueError as e:
        idx = getattr(e, "surfaces", ())
        aperture = getattr(e, "key", None) == "aperture"   # e.g. EPD on a rectangular stop
        fail(where[idx[0]] if idx else ap_line if aperture else None, str(e))
    if fno_finite:
        ap_value = _working_fno_epd(lens, obj_dist, value, ap_line, fail)
        _warn(src, ap_line, f"FNO {value!r} with the object at a finite distance: read as the "
                            f"working (image-space paraxial) F-number, |u'| = 1/(2 F), as "
                            f"rayoptics does: EPD {ap_value!r} mm")
        lens.spec = LensSpec(object_distance_mm=obj_dist, aperture_type=ap_type,
                             aperture_value=ap_value, fields_deg=[0.0], wavelengths_nm=waves,
                             primary_wavelength_nm=primary)
        lens.apply_aperture_spec()
    fields = _fields(rd, lens, obj_dist, u)
    lens.spec = LensSpec(object_distance_mm=obj_dist, aperture_type=ap_type,
                         aperture_value=ap_value, fields_deg=fields, wavelengths_nm=waves,
                         primary_wavelength_nm=primary)
    autos = [i for i in autos if i != stop]
    if autos and any(s.interaction.changes_frame for s in surfaces):
        # decentred: the beam leaves the local axes, the paraxial estimate would clip it
        from .zmx_read import real_ray_semi_diameters

        real_ray_semi_diameters(lens, autos, fields)
    elif autos:
        _paraxial_semi_diameters(lens, autos, max(abs(f) for f in fields))
    if autos:
        for _ in range(2 * len(surfaces)):   # each round limits one surface for good
            try:
                lens.check()
                break
            except SurfacesCrossError as e:
                # estimated semi-diameters of two surfaces that meet within them: limited to
                # where they meet (a real lens's edge; CODE V's own come from real rays)
                hit = [i for i in e.surfaces if i in autos and
                       float(lens.surfaces[i].semi_diameter) > e.radius * (1 - 1e-9)]
                if not hit:
                    fail(where[e.surfaces[0]], str(e))
                for i in hit:
                    lens.surfaces[i].semi_diameter.fill_(e.radius * (1 - 1e-6))
            except ValueError as e:
                idx = getattr(e, "surfaces", ())
                fail(where[idx[0]] if idx else None,
                     f"{e} (with paraxial semi-diameters; give CIR)")
    for i, (r, line, kind) in obs:
        _obscuration(lens, i, r * u, line, kind, fail, src)
    cir = next(s["cir"] for s in body if s["stop"])
    if cir is not None:
        got = float(lens.surfaces[stop].semi_diameter)
        if cir[0] * u < got * (1 - 1e-9):
            _stop_clear_radius(lens, cir[0] * u, got, kind, cir[1], fail, u)
    return lens


def _axial_marginal(lens: Lens, obj_dist: float):
    """``(n, u_k)``: the media's signed indices ``(S + 1,)`` (:func:`~..paraxial.media_indices`)
    and the image-space slope (a float) of the paraxial ray from the axial object point
    ``obj_dist`` mm before the first vertex with object-space slope 1."""
    from ..paraxial import media_indices, trace_paraxial_ray

    with torch.no_grad():
        n = media_indices(lens)
        one = torch.ones((), dtype=n.dtype, device=n.device)
        _, u_k, _ = trace_paraxial_ray(lens, obj_dist * one, one, n)
    return n, float(u_k)


def _working_fno_epd(lens: Lens, obj_dist: float, fno: float, line: int, fail) -> float:
    """The entrance pupil diameter (mm) whose axial marginal ray leaves the lens at the slope
    ``|u'| = 1 / (2 F)`` (a working F-number, rayoptics' reading of CODE V's ``FNO``:
    ``compute_first_order`` sets the image-space marginal slope to ``-1 / (2 F)``).  The
    marginal ray from the object point with slope ``u0`` leaves at ``u_k u0`` (linear), and
    meets the entrance pupil at height ``u0 (s + l_EP)``."""
    from ..paraxial import paraxial

    _, u_k = _axial_marginal(lens, obj_dist)
    with torch.no_grad():
        to_pupil = obj_dist + float(paraxial(lens).entrance_pupil_position)
    if u_k == 0 or to_pupil == 0:
        fail(line, "FNO with a finite object: the marginal ray leaves parallel or the "
                   "entrance pupil is on the object; expected EPD")
    return abs(to_pupil) / (fno * abs(u_k))


def _obscuration(lens: Lens, i: int, r: float, line: int, kind: str, fail, src: str) -> None:
    """``CIR OBS r`` (a central obscuration) or ``CIR HOL r`` (a hole) on surface ``i``: rays
    that meet the surface within ``r`` (mm) of its axis are blocked.  A hole lets a ray through
    the surface without its refraction or reflection, which in a sequential trace leaves the
    system: the same blocking (with a warning naming the choice)."""
    s = lens.surfaces[i]
    if not hasattr(s, "obscuration"):
        fail(line, f"CIR {kind} on a {type(s).__name__}: deeplens has obscurations on lens, "
                   f"mirror and aperture surfaces only")
    if kind == "HOL":
        _warn(src, line, f"CIR HOL {r!r} mm: a hole in surface {i} read as a "
                                       f"central obscuration (a ray through it leaves the "
                                       f"sequential path)")
    sd = float(s.semi_diameter)
    if not r < sd:
        fail(line, f"CIR {kind} {r!r} mm: expected a radius below the surface's semi-diameter "
                   f"({sd!r} mm)")
    _set_checked(s, "obscuration", r, line, f"CIR {kind}", fail)


def _set_checked(surface, name: str, value: float, line: int, what: str, fail) -> None:
    """Set the surface's buffer ``name`` (mm) to ``value`` and check the surface; a check that
    fails is the file's error at ``line``, prefixed ``what``."""
    with torch.no_grad():
        getattr(surface, name).fill_(value)
    try:
        surface.check()
    except ValueError as e:
        fail(line, f"{what}: {e}")


def _check_private(mat: Material, waves, s: dict, fail) -> None:
    """A private (``PRV``) glass must be defined at every wavelength of the lens."""
    from .codev_private import PrivateGlass

    if not isinstance(mat, PrivateGlass):
        return
    lo, hi = mat.wavelength_range_nm
    out = [w for w in waves if not lo <= w <= hi]
    if out:
        fail(s["glass"][1], f"private glass {mat.name!r} is tabulated at {lo!r} - {hi!r} nm; "
                            f"the lens's wavelengths {out} nm lie outside: expected PWL "
                            f"wavelengths that span the WL ones")
    try:
        mat.n(torch.tensor(waves, dtype=torch.float64))
    except ValueError as e:
        fail(s["glass"][1], str(e))


def _apply_pickups(rd: _Reader) -> None:
    """The file's pickups (``PIK``), in file order: target = factor * source + offset."""
    n = len(rd.surfs)
    for line, (p, k), (q, m), factor, offset in rd.pickups:
        for j, what in ((k, "target"), (m, "source")):
            if not -n <= j < n:
                rd.fail(line, f"PIK: {what} surface S{j} does not exist (S0 .. S{n - 1})")
        src, dst = rd.surfs[m], rd.surfs[k]
        set_surface_value(dst, p, factor * surface_value(src, q) + offset)


def _stop_clear_radius(lens: Lens, clear: float, got: float, kind: str, line: int, fail,
                       u: float) -> None:
    """A ``CIR`` on the stop narrower than the beam the EPD or F-number gives there (``got``,
    mm): CODE V keeps the pupil and the clear aperture vignettes its rim.  On a lens or mirror
    surface (an :class:`Asphere`) the stop keeps its paraxial radius as its semi-diameter and the
    ``CIR`` becomes its ``clear_radius``; a flat stop in air with a circular opening is read the
    same way as a flat ``Asphere`` (:func:`~.stop_clear.flat_stop_as_asphere`); other stops
    are refused."""
    stop = lens.surfaces[lens.stop_index]
    if plain_circular_stop(stop):
        try:
            stop = flat_stop_as_asphere(lens)
        except ValueError as e:
            fail(line, f"CIR {clear / u!r} on the stop is narrower than the beam the {kind} "
                       f"gives there ({got / u!r}): deeplens reads such a flat stop as a flat "
                       f"surface whose clear aperture vignettes the pupil, which the rays land "
                       f"on, and here they cannot ({e}); expected a CIR at least that wide")
    if type(stop) is not Asphere:
        fail(line, f"CIR {clear / u!r} on the stop is narrower than the beam the {kind} gives "
                   f"there ({got / u!r}): deeplens vignettes a pupil so only on a lens or mirror "
                   f"surface or a flat stop in air with a circular opening, not on a "
                   f"{type(stop).__name__} stop; expected a CIR at least that wide")
    _set_checked(stop, "clear_radius", clear, line, "CIR on the stop", fail)


def _fields(rd: _Reader, lens: Lens, obj_dist: float, u: float) -> list[float]:
    """The field angles (degrees) of the file's YAN, YOB or YIM values."""
    from ..paraxial import paraxial

    given = dict(rd.fields)
    if not given:
        return [0.0]
    for x in ("XAN", "XOB", "XIM"):
        if x in given:
            vals, line = given.pop(x)
            if any(vals):
                rd.fail(line, f"{x}: x field components other than 0 are not supported "
                              f"(deeplens' fields lie in the y-z plane)")
    if len(given) != 1:
        rd.fail(max(v[1] for v in rd.fields.values()),
                f"fields given as {' and '.join(sorted(given)) or 'x only'}: expected one of "
                f"YAN, YOB, YIM")
    (kind, (vals, line)), = given.items()
    x_len = {x: len(v[0]) for x, v in rd.fields.items() if x[0] == "X"}
    for x, n in x_len.items():
        if n != len(vals):
            rd.fail(line, f"{kind} has {len(vals)} fields and {x} {n}: expected the same count")
    if kind == "YAN":
        return vals
    with torch.no_grad():
        par = paraxial(lens)
    if kind == "YOB":
        if math.isinf(obj_dist):
            rd.fail(line, "YOB (object heights) with the object at infinity: expected YAN")
        # the object point where the file puts it, (0, h): its chief ray through the paraxial
        # entrance pupil's centre has tan θ = -h / d (a positive angle rises towards +y, from
        # an object point below the axis: the .zmx reader's rule, zmx_system.object_height_fields)
        d = obj_dist + float(par.entrance_pupil_position)
        return [0.0 - math.degrees(math.atan(h * u / d)) for h in vals]
    if not math.isinf(obj_dist):
        # the object heights whose paraxial images are these (m, signed, from the Lagrange
        # invariant of the axial marginal ray, m = n u / (n' u')), then as YOB
        n, u_k = _axial_marginal(lens, obj_dist)
        if u_k == 0:
            rd.fail(line, "YIM with a finite object: the image is at infinity (no paraxial "
                          "image height); expected YAN or YOB")
        m = abs(float(n[0]) / (float(n[-1]) * float(u_k)))
        m = math.copysign(m, float(n[0]) * float(n[-1]) * float(u_k))
        d = obj_dist + float(par.entrance_pupil_position)
        return [0.0 - math.degrees(math.atan(h * u / m / d)) for h in vals]
    f = float(par.efl)
    return [math.degrees(math.atan(h * u / f)) for h in vals]


def _provisional(c: float, k: float) -> float:
    """A semi-diameter (mm) to build the lens with before the paraxial estimate: 1 mm, or half
    the conic's domain when that is smaller."""
    if c != 0 and 1 + k > 0:
        return min(1.0, 0.5 / (abs(c) * math.sqrt(1 + k)))
    return 1.0


def _paraxial_semi_diameters(lens: Lens, idx, field_deg: float) -> None:
    """Semi-diameters of the surfaces ``idx`` from the paraxial marginal and chief rays (the
    ``.zmx`` reader's first estimate, :func:`.zmx_read.paraxial_semi_diameters`)."""
    from .zmx_read import paraxial_semi_diameters

    paraxial_semi_diameters(lens, idx, field_deg)


# --------------------------------------------------------------------------- writer
def _f(v) -> str:
    return repr(float(v))


def _surface_lines(s, i: int, stop: bool = False) -> list[str]:
    """Surface ``i`` as ``[curvature, modifier lines ...]``: what its type's handler in the
    file-format registry writes (:mod:`.surface_handlers`)."""
    handler = FORMATS.for_surface(s)
    if handler is None or not handler.writes_codev():
        raise LensFileError(f"surface {i}: {type(s).__name__} has no CODE V equivalent in "
                            f"deeplens' writer (spheres, conics, even aspheres, planes and "
                            f"circular apertures)", surfaces=(i,))
    return handler.write_codev(s, i, stop)


def _private_blocks(lens: Lens) -> list[str]:
    """A ``PRV`` block per private glass of the lens (its table, as read)."""
    from .codev_private import PrivateGlass

    out, seen = [], {}
    for m in lens.materials:
        if not isinstance(m, PrivateGlass):
            continue
        key = m.name.upper()
        if key in seen:
            if seen[key] is not m and (seen[key].table_nm, seen[key].table_n) != (m.table_nm,
                                                                                 m.table_n):
                raise LensFileError(f"two private glasses named {m.name!r} with different "
                                    f"tables")
            continue
        seen[key] = m
        out += ["PRV", "  PWL " + " ".join(_f(w) for w in m.table_nm),
                f"  '{m.name}' " + " ".join(_f(n) for n in m.table_n), "END"]
    return out


def write_seq(lens: Lens, path) -> None:
    """Write ``lens`` as a CODE V ``.seq`` file that :func:`read_seq` reads back.

    Raises:
        LensFileError: something with no CODE V equivalent here (misalignments,
            other surface types, a telecentric object, a tilted object plane or one at a
            coordinate break's pivot, a virtual image, a material with no
            CODE V name); ``surfaces`` names the surfaces concerned.
    """
    from ..paraxial import paraxial

    spec = lens.spec
    if not all(m.is_identity() for m in lens.misalignments):
        raise LensFileError("a misaligned element is not written to .seq files")
    if getattr(lens, "object_telecentric", False) or lens.virtual_image:
        raise LensFileError("a telecentric object or a virtual image is not written to .seq "
                            "files")
    if getattr(lens, "object_tilt", (0.0, 0.0)) != (0.0, 0.0):
        raise LensFileError(f"a tilted object plane (object_tilt {lens.object_tilt}) is not "
                            f"written to .seq files")
    if spec.object_distance_mm == 0:
        raise LensFileError("an object at a coordinate break's pivot (object distance 0) is not "
                            "written to .seq files (CODE V's object thickness must not be 0)")
    title = lens.name.replace("'", '"') if lens.name else "deeplens"
    out = ["RDM N", f"TIT '{title}'", "DIM M"]
    waves = [float(w) for w in spec.wavelengths_nm]
    out.append("WL " + " ".join(_f(w) for w in waves))
    pw = float(spec.primary_wavelength_nm)
    if pw not in waves:
        raise LensFileError(f"the primary wavelength {pw} nm is not one of the lens's "
                            f"wavelengths {waves}: CODE V's REF picks one of them")
    out.append(f"REF {waves.index(pw) + 1}")
    with torch.no_grad():
        if spec.aperture_type == "fno":
            out.append(f"FNO {_f(spec.aperture_value)}")
        elif spec.aperture_type == "epd":
            out.append(f"EPD {_f(spec.aperture_value)}")
        else:
            out.append(f"EPD {_f(paraxial(lens).entrance_pupil_diameter)}")
        out.append("YAN " + " ".join(_f(f) for f in spec.fields_deg))
        out += _private_blocks(lens)
        od = float(spec.object_distance_mm)
        obj = f"SO 0.0 {'1e+20' if math.isinf(od) else _f(od)}"
        g = _glass_token(lens.materials[0], -1)
        out.append(obj + (f" {g}" if g else ""))
        n = len(lens.surfaces)
        for i, s in enumerate(lens.surfaces):
            is_stop = i == lens.stop_index
            after = float(lens.distances[i + 1]) if i + 1 < n else float(lens.d_sensor)
            if s.interaction.changes_frame:   # a coordinate break: a decentred dummy
                out += write_break(s, i, after, lens.materials[i + 1])
                continue
            head, *mods = _surface_lines(s, i, is_stop)
            g = "REFL" if i in lens.mirrors else _glass_token(lens.materials[i + 1], i)
            out.append(f"S {head} {_f(after)}" + (f" {g}" if g else ""))
            if is_stop:
                mods.insert(0, "STO")
            rect = write_aperture(s, i)   # REX/REY or ELX/ELY (ADX, ADY): codev_apertures
            clear = float(getattr(s, "clear_radius", math.inf))
            mods += rect or [f"CIR {_f(s.semi_diameter if math.isinf(clear) else clear)}"]
            if float(getattr(s, "obscuration", 0.0)) > 0:
                mods.append(f"CIR OBS {_f(s.obscuration)}")
            out += ["  " + m for m in mods]
    out.append("SI 0.0 0.0")
    if lens.sensor_semi_diameter is not None:
        out.append(f"  CIR {_f(lens.sensor_semi_diameter)}")
    out.append("GO")
    Path(path).write_text("\n".join(out) + "\n")
