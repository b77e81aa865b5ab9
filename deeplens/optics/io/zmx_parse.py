"""Zemax ``.zmx`` text -> records -> the raw file (system data and ``SURF`` blocks).

Two steps, both in the file's own units (lengths are scaled to mm by the reader,
:mod:`.zmx_read`):

* :func:`tokenize`: every non-blank line becomes a :class:`Record` -- its 1-based line number,
  its keyword (upper case), its tokens, its text and the ``SURF`` block it belongs to;
* :func:`parse`: the records become the system data (``sysd``: unit, aperture, field type,
  fields, wavelengths, glass catalogues, ray aiming, each value with the line it came from) and
  one :class:`ZmxSurface` per ``SURF`` block, with what the reader needs of each line.

Every error is raised through a :class:`Locator`, which knows the file and every record: the
:class:`~deeplens.optics.errors.ZemaxFileError` it raises carries ``source``, ``line``,
``feature`` (the record's keyword) and ``surf`` (the file's surface number) as attributes, and
its message is formatted from them.  Lines understood but not used are collected as notes and
become :class:`~deeplens.optics.errors.ZemaxWarning` s at the end of a successful read.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import LensFileError, ZemaxFileError, ZemaxWarning
from .agf import decode_zemax_text
from .file_limits import MAX_CURVATURE_PER_MM, MAX_LENGTH_MM
from .surface_handlers import FORMATS
from .zmx_notes import Cause, listed, literal
from .zmx_scbd import parse_scbd

__all__ = ["Cause", "Record", "ZmxSurface", "Locator", "listed", "literal", "tokenize", "parse",
           "UNITS", "UNUSED", "VIGNETTING"]

UNITS = {"MM": 1.0, "CM": 10.0, "IN": 25.4, "METER": 1000.0, "M": 1000.0}
"""``UNIT`` name -> millimetres per file unit."""

#: an object (``SURF 0``) thickness of this many lens units or more is an object at infinity
OBJECT_AT_INFINITY = 1e10
_MAX_CONFIGS = 10000   # MNUM: more is a damaged number (read_zmx_configs builds one lens each)

# surface types met in real files that deeplens refuses, and what they are
_DIFFRACTIVE = ("out of scope: deeplens traces refraction, reflection, straight-ruled gratings "
                "(DGRATING), radial phases (BINARY_2), x-y polynomial phases (BINARY_1) and "
                "Zernike Fringe phases (FZERNPHA), not other diffractive phase profiles")
_UNSUPPORTED_TYPES = {
    "QTYPEASP": "a Q-type (Forbes) asphere",
    "ELEMGRAT": f"an elliptical grating, {_DIFFRACTIVE}",
    "GRINSUR9": ("a SELFOC gradient-index surface, Gradient 9: its index needs the glass's "
                 "n0(λ) and A(λ) coefficients (B, C, K0, K1, K2), which OpticStudio keeps in "
                 "its GRADIENT_9.DAT and no public source gives"),
    "GRINSUR8": ("OpticStudio's GRADIUM surface, LightPath's axial-gradient blanks: its index "
                 "profile is the blank's, which OpticStudio keeps in its PROFILE.GRD and no "
                 "public source gives"),
}

# Lines that describe editor state, drawing, tolerancing or non-optical data: skipped silently.
_SILENT = {
    "VERS", "MODE", "NAME", "PFIL", "LANG", "GFAC", "PUSH", "SDMA", "OMMA", "ROPD", "HYPR",
    "PICB", "FWGN", "POLS", "GLRS", "GSTD", "NSCD",
    "COFN", "FIMP", "HIDE", "MIRR", "SLAB", "MEMA", "POPS", "FLAP", "BLNK", "TOL",
    "MOFF", "COMM", "NOTE", "WWGT", "FWGT", "VDSZ", "VCON", "VPAR", "VCRV",
    "VTHI", "VCNT", "MAZH", "TOLE", "SCOL", "SDRW", "PZUP", "CONF", "DMFS", "BLDM",
    "RSCE", "RWRE", "TSCM", "STYP", "OPDX", "COAT", "CURVSOLV", "ISNA", "EFFL", "THSO",
    "AUTH", "IWDP", "LUID", "EERA", "SSID", "DBDT",
}



@dataclass(frozen=True)
class Record:
    """One non-blank line of a ``.zmx`` file.

    Attributes:
        line: its 1-based line number.
        key: its keyword (the first token, upper case).
        tokens: every token (the keyword as written first).
        text: the line as written.
        surf: the number of the ``SURF`` block it belongs to (counted in file order; its lines
            are indented), ``None`` for system data.
    """

    line: int
    key: str
    tokens: tuple
    text: str
    surf: int | None


def tokenize(text: str) -> list[Record]:
    """The records of a ``.zmx`` text (blank lines skipped)."""
    out, surf = [], None
    for ln, line in enumerate(text.splitlines(), start=1):
        toks = line.split()
        if not toks:
            continue
        key = toks[0].upper()
        if key == "SURF":
            surf = 0 if surf is None else surf + 1
        # a SURF block's lines are indented; an unindented line after the blocks is system data
        in_block = key == "SURF" or line[:1].isspace()
        out.append(Record(ln, key, tuple(toks), line, surf if in_block else None))
    return out


@dataclass
class ZmxSurface:
    """One ``SURF`` block, values in file units, each with the line it came from where the
    reader may need to name it."""

    line: int
    type: str = "STANDARD"
    type_line: int = 0
    curv: float = 0.0
    curv_line: int = 0
    disz: float = 0.0
    disz_line: int = 0
    coni: float = 0.0
    diam: float = 0.0
    diam_line: int = 0
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
    elap: tuple | None = None   # (x half-axis, y half-axis, line): an elliptical aperture
    elob: tuple | None = None   # (x half-axis, y half-axis, line): an elliptical obscuration
    obsc: tuple | None = None   # (obscuration's outer radius, line) in file units
    spid: tuple | None = None   # (arm width in file units, number of arms, line): SPID
    spid_angle: float = 0.0     # the first arm's angle (degrees from +x): a bracket's z turn
    obsc_inner: tuple | None = None   # (a ring obscuration's inner radius > 0, line): OBSC lo hi
    mirror: bool = False               # GLAS MIRROR
    obdc: tuple | None = None   # (x, y aperture decenter, line) in file units
    # GDAT nx ny delx dely [xdec ydec]: a grid surface's header, (values..., line), file units
    grid: tuple | None = None
    # GARR i z dz/dx dz/dy d2z/dxdy [nodata]: index -> (z, zx, zy, zxy, nodata, line)
    grid_rows: dict = field(default_factory=dict)
    # SCBD (surface tilt/decenter, coordinate return): kind -> entry (.zmx_scbd.parse_scbd)
    scbd: dict = field(default_factory=dict)
    # PPAR p src scale offset column: parameter p's solve, p -> (src, scale, offset, column, line)
    # (src >= 0: a pick-up from SURF src; src < 0: another solve, such as a chief-ray decenter)
    ppar: dict = field(default_factory=dict)
    # GLAS NAME 2 src: the material picked up from SURF src, (src, line) (.zmx_mconf solves it
    # again in another configuration)
    glass_pickup: tuple | None = None
    # PZUP src scale offset column: the thickness picked up, (src, scale, offset, column, line)
    pzup: tuple | None = None


#: vignetting factors (``VDXN``, ``VDYN``, ``VCXN``, ``VCYN``, as lines or as
#: multi-configuration operands): not used
VIGNETTING = Cause(one="{item}: vignetting factors are ignored (deeplens finds each field's pupil "
                       "by tracing)",
                   many="{items}: vignetting factors are ignored (deeplens finds each field's "
                        "pupil by tracing)")

#: a line whose keyword deeplens does not use (``{detail}``: how many such lines)
UNUSED = Cause(one="{item} line not used by deeplens (ignored){detail}",
               many="{n} kinds of line not used by deeplens (ignored): {items}")


class Locator:
    """The file being read: raises located errors and collects notes (warnings to come).

    ``fail(line, message)`` raises a :class:`~deeplens.optics.errors.ZemaxFileError` whose
    ``source``, ``line``, ``feature`` and ``surf`` come from the file and the record on that line
    (``line`` 0: the file as a whole); ``note(line, message)`` keeps a note,
    ``note_each(line, cause, item)`` a note of a :class:`Cause` that other lines may share, and
    :meth:`warn_notes` issues them as :class:`~deeplens.optics.errors.ZemaxWarning` s: one per
    cause, and one per text (the same note on several lines), naming its lines.  ``notes``
    holds every note as ``(line, message)``, a cause's with its one-item message.
    """

    def __init__(self, path: Path, records=()):
        self.path = path
        self.notes: list[tuple[int, str]] = []
        self.causes: dict[int, tuple] = {}   # index in notes -> (cause, item, (detail, shown))
        self.records = {r.line: r for r in records}

    def error(self, ln, msg, surfaces=(), details=None) -> ZemaxFileError:
        """The located error (not raised) of ``msg`` on line ``ln`` (``details``: the longer
        explanation kept out of the one-line message)."""
        rec = self.records.get(ln) if ln else None
        return ZemaxFileError(msg, source=self.path, line=ln or None,
                              feature=None if rec is None else rec.key,
                              surf=None if rec is None else rec.surf, surfaces=surfaces,
                              details=details)

    def fail(self, ln, msg, surfaces=(), details=None):
        raise self.error(ln, msg, surfaces, details)

    def note(self, ln, msg):
        self.notes.append((ln, msg))

    def note_each(self, ln, cause: Cause, item: str, detail: str = "", shown: str | None = None):
        """A note of ``cause`` about ``item`` on line ``ln`` (``detail``: what is particular to
        it, said when it is the cause's only item; ``shown``: how a list of several names it,
        the item itself by default): the notes of one cause become one warning
        (:meth:`warn_notes`)."""
        self.causes[len(self.notes)] = (cause, item, (detail, shown))
        self.notes.append((ln, cause.message({item: (detail, shown)})))

    def warning(self, ln, msg, lines=()) -> ZemaxWarning:
        """The located warning (not issued) of ``msg`` on line ``ln``, or on ``lines``."""
        lines = [v for v in lines if v] or ([ln] if ln else [])
        rec = self.records.get(lines[0]) if lines else None
        return ZemaxWarning(msg, source=self.path if lines else None, lines=lines,
                            feature=None if rec is None else rec.key)

    def grouped_notes(self) -> list[tuple[list[int], str]]:
        """``(lines, message)`` of each warning to issue, in the order first met: the notes of
        one :class:`Cause` (its message over their distinct items) become one, and so do equal
        notes, naming their distinct lines in ascending order (a note of the file as a whole,
        line 0, names none)."""
        groups: dict = {}   # key -> [lines, {item: (detail, shown)}, cause or None]
        for i, (ln, msg) in enumerate(self.notes):
            cause, item, detail = self.causes.get(i, (None, msg, None))
            g = groups.setdefault(("cause", cause) if cause else ("text", msg), [[], {}, cause])
            if ln and ln not in g[0]:
                g[0].append(ln)
            g[1].setdefault(item, detail)
        return [(sorted(lines), next(iter(items)) if cause is None else cause.message(items))
                for lines, items, cause in groups.values()]

    def warn_notes(self, stacklevel: int = 3) -> None:
        """Issue the notes, :meth:`grouped_notes`, as located warnings."""
        for lines, msg in self.grouped_notes():
            warnings.warn(self.warning(0, msg, lines), stacklevel=stacklevel)

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


class _Parse:
    """A parse in progress: the system data, the ``SURF`` blocks so far (``cur`` the open one),
    the first ``STOP`` and the keywords not used; each operand handler reads one record into
    it."""

    def __init__(self, p: Locator):
        self.p = p
        self.sysd = {"unit": ("MM", 0), "aperture": None, "ftyp": None, "xfln": None,
                     "yfln": None, "waves": {}, "wavl": None, "pwav": (1, 0), "gcat": ([], 0),
                     "name": "", "mode": None, "raim": (0, 0), "mnum": None, "mce": []}
        self.surfs: list[ZmxSurface] = []
        self.cur: ZmxSurface | None = None
        self.unused: dict[str, tuple[int, int]] = {}   # keyword -> (first line, count)
        self.stop_at: tuple[int, int] | None = None   # (SURF number, line) of the first STOP
        self.skip: tuple[int, int, int] | None = None   # (line, expected, written): a SURF gap


# ---- system operands: read wherever they stand
def _name(st: _Parse, r: Record) -> None:
    st.sysd["name"] = r.text.strip()[4:].strip()


def _mode(st: _Parse, r: Record) -> None:
    toks = r.tokens
    if len(toks) > 1 and toks[1].upper() != "SEQ":
        st.p.fail(r.line, f"MODE {toks[1]}: only sequential (MODE SEQ) files can be read")


def _unit(st: _Parse, r: Record) -> None:
    toks = r.tokens
    if len(toks) < 2 or toks[1].upper() not in UNITS:
        st.p.fail(r.line, f"UNIT: unknown lens unit {toks[1] if len(toks) > 1 else ''!r}; "
                          f"expected one of {', '.join(UNITS)}")
    st.sysd["unit"] = (toks[1].upper(), r.line)


def _enpd(st: _Parse, r: Record) -> None:
    st.sysd["aperture"] = ("epd", st.p.arg(r.tokens, 1, r.line, "entrance-pupil diameter"),
                           r.line)


def _fnum(st: _Parse, r: Record) -> None:
    p, toks, ln = st.p, r.tokens, r.line
    v = p.arg(toks, 1, ln, "F-number")
    flag = p.num(toks[2], ln, "FNUM flag") if len(toks) > 2 else 0
    # flag 1: the paraxial working F-number, converted to an EPD once the lens is built
    st.sysd["aperture"] = ("wfno" if flag == 1 else "fno", v, ln)


def _floa(st: _Parse, r: Record) -> None:
    st.sysd["aperture"] = ("stop", None, r.line)


def _obna(st: _Parse, r: Record) -> None:
    p, toks, ln = st.p, r.tokens, r.line
    v = p.arg(toks, 1, ln, "object-space numerical aperture")
    flag = p.num(toks[2], ln, "OBNA flag") if len(toks) > 2 else 0
    # flag 0: n sin(θ) of the marginal ray; flag 1: the cone angle θ (degrees)
    st.sysd["aperture"] = ("cone" if flag == 1 else "obna", v, ln)


def _raim(st: _Parse, r: Record) -> None:
    # RAIM <unused> <type: 0 off, 1 paraxial, 2 real> ...
    toks, ln = r.tokens, r.line
    st.sysd["raim"] = (int(st.p.num(toks[2], ln, "RAIM ray-aiming type")) if len(toks) > 2
                       else 0, ln)


def _ftyp(st: _Parse, r: Record) -> None:
    p, toks, ln = st.p, r.tokens, r.line
    p.arg(toks, 1, ln, "field type")
    st.sysd["ftyp"] = ([int(p.num(t, ln, "FTYP")) for t in toks[1:]], ln)


def _field(st: _Parse, r: Record) -> None:
    p, toks, ln, key = st.p, r.tokens, r.line, r.key
    slot = key[0].lower() + "fln"      # XFLD/YFLD: older files; XFLN/YFLN win
    if len(toks) < 2:
        p.fail(ln, f"{key} line is truncated: no field values")
    if key.endswith("FLN") or st.sysd[slot] is None:
        st.sysd[slot] = ([p.num(t, ln, key) for t in toks[1:]], ln)


def _wavm(st: _Parse, r: Record) -> None:
    p, toks, ln = st.p, r.tokens, r.line
    i = int(p.arg(toks, 1, ln, "wavelength number"))
    st.sysd["waves"][i] = (p.arg(toks, 2, ln, "wavelength (µm)"), ln)


def _wavl(st: _Parse, r: Record) -> None:
    st.sysd["wavl"] = ([st.p.num(t, r.line, "WAVL") for t in r.tokens[1:]], r.line)


def _pwav(st: _Parse, r: Record) -> None:
    st.sysd["pwav"] = (int(st.p.arg(r.tokens, 1, r.line, "primary wavelength number")), r.line)


def _gcat(st: _Parse, r: Record) -> None:
    st.sysd["gcat"] = ([t.upper() for t in r.tokens[1:]], r.line)


def _vignetting(st: _Parse, r: Record) -> None:
    p, toks, ln, key = st.p, r.tokens, r.line, r.key
    if any(p.num(t, ln, key) != 0 for t in toks[1:]):
        p.note_each(ln, VIGNETTING, key)


def _envd(st: _Parse, r: Record) -> None:
    p, toks, ln, key = st.p, r.tokens, r.line, r.key
    env = [p.num(t, ln, key) for t in toks[1:3]]
    if env and (env[0] != 20 or (len(env) > 1 and env[1] != 1)):
        p.note(ln, f"ENVD: temperature {env[0]:g} °C / pressure {env[1:] or ['?']} atm "
                   f"ignored: indices are the catalogues' at their reference temperature")


def _mnum(st: _Parse, r: Record) -> None:
    # MNUM <configurations> <active configuration>: the operand rows follow
    # (:mod:`.zmx_mconf` reads them)
    p, toks, ln = st.p, r.tokens, r.line
    n_cfg = p.arg(toks, 1, ln, "number of configurations")
    cur_cfg = p.num(toks[2], ln, "MNUM active configuration") if len(toks) > 2 else 1
    if not (n_cfg == int(n_cfg) and 1 <= n_cfg <= _MAX_CONFIGS and cur_cfg == int(cur_cfg)
            and 1 <= cur_cfg <= n_cfg):
        p.fail(ln, f"MNUM {n_cfg:g} {cur_cfg:g}: expected a whole number of "
                   f"configurations from 1 to {_MAX_CONFIGS} and an active configuration "
                   f"from 1 to that number")
    n_cfg, cur_cfg = int(n_cfg), int(cur_cfg)
    st.sysd["mnum"] = (n_cfg, cur_cfg, ln)


# ---- surface operands: read inside a SURF block (before the first one, as an unknown line)
def _type(st: _Parse, r: Record) -> None:
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    if len(toks) < 2:
        p.fail(ln, "TYPE line is truncated: missing the surface type")
    cur.type, cur.type_line = toks[1].upper(), ln
    if cur.type == "USERSURF" and len(toks) > 2 and \
            FORMATS.for_zmx_type(f"USERSURF {toks[2].upper()}") is not None:
        # a compiled plug-in whose surface deeplens models (the registry's name for it is
        # "USERSURF <DLL>", the DLL's name in capitals: files write US_ARRAY.DLL and US_Array.dll)
        cur.type = f"USERSURF {toks[2].upper()}"
    if FORMATS.for_zmx_type(cur.type) is None:
        if cur.type == "USERSURF":   # a compiled plug-in: named, no list of the types read
            dll = f"plug-in {toks[2]}" if len(toks) > 2 else "plug-in (no DLL named)"
            p.fail(ln, f"surface type {toks[1]!r} (SURF {len(st.surfs) - 1}) is not supported: "
                       f"its shape is computed by OpticStudio's compiled {dll}, which deeplens "
                       f"cannot run")
        known = FORMATS.zmx_types()
        what = _UNSUPPORTED_TYPES.get(cur.type)
        if what is not None:   # a type met in real files: what it is and why, in one line
            p.fail(ln, f"surface type {toks[1]!r} (SURF {len(st.surfs) - 1}, {what}) is not "
                       f"supported")
        p.fail(ln, f"surface type {toks[1]!r} (SURF {len(st.surfs) - 1}, a surface type deeplens "
                   f"does not know) is not supported; deeplens reads {', '.join(known[:-1])} and "
                   f"{known[-1]}")


def _curv(st: _Parse, r: Record) -> None:
    cur = st.cur
    cur.curv, cur.curv_line = st.p.arg(r.tokens, 1, r.line, "curvature"), r.line


def _disz(st: _Parse, r: Record) -> None:
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    if len(toks) < 2:
        p.fail(ln, "DISZ line is truncated: missing the thickness")
    cur.disz = math.inf if toks[1].upper() == "INFINITY" else p.num(toks[1], ln, "DISZ")
    cur.disz_line = ln
    if len(st.surfs) == 1 and math.isfinite(cur.disz) and cur.disz >= OBJECT_AT_INFINITY:
        # the object surface's thickness: 1e10 lens units or more is an object at infinity
        # (as the multi-configuration THIC rows and CODE V's SO read it; OpTaliX writes 1e20)
        p.note(ln, f"object distance DISZ {toks[1]} (SURF 0) is {OBJECT_AT_INFINITY:g} lens "
                   f"units or more: read as an object at infinity (write DISZ INFINITY to say "
                   f"so, or a smaller number for a finite object)")
        cur.disz = math.inf


def _coni(st: _Parse, r: Record) -> None:
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    cur.coni = p.arg(toks, 1, ln, "conic constant")


def _diam(st: _Parse, r: Record) -> None:
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    cur.diam, cur.diam_line = p.arg(toks, 1, ln, "semi-diameter"), ln
    cur.diam_fixed = len(toks) > 2 and toks[2] == "1"


def _stop(st: _Parse, r: Record) -> None:
    p, ln, surfs = st.p, r.line, st.surfs
    if st.stop_at is not None:   # OpticStudio has one stop: a second is a corrupt file
        p.fail(ln, f"a second STOP (SURF {len(surfs) - 1}): the stop is already SURF "
                   f"{st.stop_at[0]} (STOP on line {st.stop_at[1]}); a lens has one aperture "
                   f"stop")
    st.stop_at = (len(surfs) - 1, ln)
    st.cur.stop = True


def _parm(st: _Parse, r: Record) -> None:
    p, toks, ln = st.p, r.tokens, r.line
    st.cur.parm[int(p.arg(toks, 1, ln, "parameter number"))] = (
        p.arg(toks, 2, ln, "parameter value"), ln)


def _ppar(st: _Parse, r: Record) -> None:
    """``PPAR p src scale offset column``: a solve on ``PARM p`` (saved already solved; read so
    that :mod:`.zmx_mconf` can re-evaluate pick-ups in another configuration).  ``src >= 0``: a
    pick-up, ``scale * (SURF src's PARM p) + offset`` (``column`` 0: the same parameter);
    ``src < 0`` (``PPAR 2 -1 1 0``): another solve (a chief-ray decenter), kept as saved."""
    p, toks, ln = st.p, r.tokens, r.line
    i = int(p.arg(toks, 1, ln, "parameter number"))
    src = int(p.arg(toks, 2, ln, "solve's source surface (or a negative solve type)"))
    if src < 0:
        st.cur.ppar[i] = (src, None, None, None, ln)
        return
    st.cur.ppar[i] = (src, *_pickup_terms(p, toks, 3, ln), ln)


def _pickup_terms(p, toks, at: int, ln: int) -> tuple:
    """``(scale, offset, column)`` of a pick-up record whose scale is token ``at`` (``PPAR``'s
    and ``PZUP``'s); ``column`` 0 (the same quantity) when the record omits it."""
    return (p.arg(toks, at, ln, "pick-up scale"), p.arg(toks, at + 1, ln, "pick-up offset"),
            int(p.arg(toks, at + 2, ln, "pick-up column")) if len(toks) > at + 2 else 0)


def _xdat(st: _Parse, r: Record) -> None:
    p, toks, ln = st.p, r.tokens, r.line
    st.cur.xdat[int(p.arg(toks, 1, ln, "extra-data number"))] = (
        p.arg(toks, 2, ln, "extra-data value"), ln)


def _glas(st: _Parse, r: Record) -> None:
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    if len(toks) < 2:
        p.fail(ln, "GLAS line is truncated: missing the glass name")
    name = toks[1]
    if name.upper() == "MIRROR":  # a reflecting surface: Lens(mirrors=...)
        cur.mirror, cur.glass, cur.glass_line = True, None, ln
        return
    if name.upper() in ("AIR", "VACUUM"):
        cur.glass, cur.glass_model, cur.glass_line = None, None, ln
        return   # written by some converters: the same as no GLAS line
    code = toks[2] if len(toks) > 2 else "0"
    if code == "2":   # the Pickup material solve: the glass of an earlier surface
        _glass_pickup(st, r)
        return
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


def _glass_pickup(st: _Parse, r: Record) -> None:
    """``GLAS NAME 2 k ...``: OpticStudio's *Pickup* material solve (solve code 2, after Fixed 0
    and Model 1, the order of its solve list): "uses a value from another surface as the glass
    on the target surface", and pickups "may only pickup values from prior surfaces" (OpticStudio
    User Guide, *Material Solves*, *Restrictions*).  The surface takes SURF ``k``'s material as
    read, air included: the name and n_d/V_d written on the line are a copy OpticStudio keeps
    (``___BLANK 1.5 40`` where ``k`` is air), not the material."""
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    here = len(st.surfs) - 1
    if len(toks) < 4:
        p.fail(ln, f"GLAS on SURF {here}: a material pickup (solve code 2) without the surface "
                   f"it picks up from")
    k = p.num(toks[3], ln, "GLAS pickup surface")
    if k != int(k) or not 0 <= k < here:
        p.fail(ln, f"GLAS on SURF {here}: a material pickup from surface {toks[3]}; expected an "
                   f"earlier surface, 0 to {here - 1} (pickups read prior surfaces only)")
    src = st.surfs[int(k)]
    if src.mirror:
        p.fail(ln, f"GLAS on SURF {here}: a material pickup from SURF {int(k)}, a mirror, is not "
                   f"supported")
    cur.glass, cur.glass_model, cur.glass_model_name = (
        src.glass, src.glass_model, src.glass_model_name)
    cur.glass_line = ln
    cur.glass_pickup = (int(k), ln)


def _pzup(st: _Parse, r: Record) -> None:
    """``PZUP src scale offset column``: a thickness pick-up (saved already solved, ``DISZ``
    holds its value; read so that :mod:`.zmx_mconf` can solve it again in another
    configuration): ``scale * (SURF src's DISZ) + offset`` (``column`` 0: the thickness)."""
    p, toks, ln = st.p, r.tokens, r.line
    st.cur.pzup = (int(p.arg(toks, 1, ln, "thickness pick-up's source surface")),
                   *_pickup_terms(p, toks, 2, ln), ln)


def _clap(st: _Parse, r: Record) -> None:
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    lo = p.arg(toks, 1, ln, "minimum radius")
    hi = p.arg(toks, 2, ln, "maximum radius")
    if not 0 <= lo < hi:
        p.fail(ln, f"CLAP: expected 0 <= minimum radius < maximum radius, got {lo:g}, "
                   f"{hi:g}")
    cur.clap = (hi, ln)
    if lo > 0:   # an annular clear aperture
        if cur.obsc is not None:
            p.fail(ln, f"CLAP on SURF {len(st.surfs) - 1}: an annular clear aperture on a "
                       f"surface that already has an obscuration (OBSC, line {cur.obsc[1]}): "
                       f"one per surface is supported")
        cur.obsc = (lo, ln)


def _obsc(st: _Parse, r: Record) -> None:
    """``OBSC lo hi``: a circular obscuration of radius ``hi`` (``lo`` = 0, a central one) or a
    ring ``lo <= r <= hi`` (``lo > 0``: a ring baffle, which rays pass inside and outside)."""
    p, toks, ln = st.p, r.tokens, r.line
    lo = p.arg(toks, 1, ln, "minimum radius")
    hi = p.arg(toks, 2, ln, "maximum radius")
    if not 0 <= lo < hi:
        p.fail(ln, f"OBSC on SURF {len(st.surfs) - 1}: expected 0 <= minimum radius < maximum "
                   f"radius, got {lo:g}, {hi:g}")
    if st.cur.obsc is not None:
        p.fail(ln, f"OBSC on SURF {len(st.surfs) - 1}: the surface already has an obscuration "
                   f"(an annular CLAP or another OBSC, line {st.cur.obsc[1]}); one per surface "
                   f"is supported")
    st.cur.obsc = (hi, ln)
    st.cur.obsc_inner = (lo, ln) if lo > 0 else None


def _sqap(st: _Parse, r: Record) -> None:
    p, toks, ln = st.p, r.tokens, r.line
    st.cur.sqap = (p.arg(toks, 1, ln, "x half-width"), p.arg(toks, 2, ln, "y half-width"), ln)


def _ellipse(st: _Parse, r: Record) -> None:
    """``ELAP a b`` (an elliptical aperture) or ``ELOB a b`` (an elliptical obscuration): the
    ellipse's half-axes along the local x and y axes, in lens units, as ``SQAP``/``SQOB`` give
    a rectangle's half-widths (further numbers, as ``SQAP``'s, are not read)."""
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    k = len(st.surfs) - 1
    a, b = p.arg(toks, 1, ln, "x half-axis"), p.arg(toks, 2, ln, "y half-axis")
    if not (a > 0 and b > 0):
        p.fail(ln, f"{r.key} on SURF {k}: expected two half-axes > 0 (x, then y), got {a:g}, "
                   f"{b:g}")
    if r.key == "ELAP":
        cur.elap = (a, b, ln)
    else:
        cur.elob = (a, b, ln)


def _spid(st: _Parse, r: Record) -> None:
    """``SPID width n``: a spider obscuration, ``n`` equally spaced arms of full width
    ``width`` (lens units) from the surface's vertex, the first along the local +x axis
    (OpticStudio's *Spider* surface aperture: arm width, number of arms)."""
    p, toks, ln = st.p, r.tokens, r.line
    k = len(st.surfs) - 1
    w, n = p.arg(toks, 1, ln, "arm width"), p.arg(toks, 2, ln, "number of arms")
    if not (w > 0 and math.isfinite(w)):
        p.fail(ln, f"SPID on SURF {k}: expected the arms' width > 0 (lens units), got {w:g}")
    if not (n >= 1 and n == int(n)):
        p.fail(ln, f"SPID on SURF {k}: expected the number of arms, an integer >= 1, got "
                   f"{toks[2]!r}")
    st.cur.spid = (w, int(n), ln)


def _obdc(st: _Parse, r: Record) -> None:
    p, toks, ln = st.p, r.tokens, r.line
    dec = (p.arg(toks, 1, ln, "x decenter"), p.arg(toks, 2, ln, "y decenter"))
    st.cur.obdc = (*dec, ln) if any(v != 0 for v in dec) else None


def _gdat(st: _Parse, r: Record) -> None:
    """``GDAT nx ny delx dely [xdec ydec]``: the header of a grid surface's data (the numbers of
    points, the spacings and the grid's decenter, in lens units; read by the ``GRID_SAG``
    handler, :mod:`.zmx_grid_sag`)."""
    p, toks, ln = st.p, r.tokens, r.line
    vals = [p.arg(toks, i, ln, what) for i, what in
            enumerate(("number of x points", "number of y points", "x spacing", "y spacing"), 1)]
    dec = [p.num(t, ln, "GDAT decenter") for t in toks[5:7]]
    st.cur.grid = (*vals, *(dec + [0.0] * (2 - len(dec))), ln)


def _garr(st: _Parse, r: Record) -> None:
    """``GARR i z dz/dx dz/dy d2z/dxdy [nodata]``: grid point ``i`` (from 0, row by row from the
    top left, -x +y) of the ``GDAT`` before it."""
    p, toks, ln, cur = st.p, r.tokens, r.line, st.cur
    k = len(st.surfs) - 1
    if cur.grid is None:
        p.fail(ln, f"GARR on SURF {k} before its GDAT line: the grid's header (GDAT nx ny delx "
                   f"dely) must come first")
    i = p.arg(toks, 1, ln, "grid point index")
    if i != int(i) or i < 0:
        p.fail(ln, f"GARR on SURF {k}: the grid point index must be an integer >= 0, got "
                   f"{toks[1]!r}")
    if int(i) in cur.grid_rows:
        p.fail(ln, f"GARR on SURF {k}: grid point {int(i)} is given twice (first on line "
                   f"{cur.grid_rows[int(i)][-1]})")
    vals = [p.arg(toks, j, ln, what) for j, what in
            enumerate(("sag", "dz/dx", "dz/dy", "d2z/dxdy"), 2)]
    nodata = p.num(toks[6], ln, "GARR nodata flag") if len(toks) > 6 else 0.0
    cur.grid_rows[int(i)] = (*vals, nodata, ln)


_APERTURES_REFUSED = {
    "SQOB": "a rectangular obscuration", "UDAD": "a user-defined aperture"}


def _aperture_refused(st: _Parse, r: Record) -> None:
    key = r.key
    what = _APERTURES_REFUSED[key]
    if key == "UDAD" and len(r.tokens) > 2 and r.tokens[1] == "0":   # UDAD 0 "NAME.UDA" scale
        what += f" (file {r.tokens[2].strip(chr(34))})"
    st.p.fail(r.line, f"{key} on SURF {len(st.surfs) - 1}: {what} is not "
                      f"supported (deeplens reads circular, rectangular and elliptical "
                      f"apertures: DIAM, CLAP, SQAP, ELAP; circular and elliptical "
                      f"obscurations and spiders: OBSC, ELOB, SPID)")


def _surface_ignored(st: _Parse, r: Record) -> None:
    """Records of a surface that the reader does not need (``TCE``, ``COAT``)."""


def _scbd(st: _Parse, r: Record) -> None:
    """``SCBD``: a surface's own tilt/decenter before/after it, or a break's coordinate return,
    decoded from the files (:mod:`.zmx_scbd`, which the reader applies)."""
    kind, entry = parse_scbd(st.p, r.tokens, r.line, len(st.surfs) - 1, st.cur.scbd)
    st.cur.scbd[kind] = entry


#: system operand -> its handler (read wherever it stands)
_SYSTEM_OPERANDS = {
    "NAME": _name, "MODE": _mode, "UNIT": _unit, "ENPD": _enpd, "FNUM": _fnum, "FLOA": _floa,
    "OBNA": _obna, "RAIM": _raim, "FTYP": _ftyp, "XFLN": _field, "YFLN": _field,
    "XFLD": _field, "YFLD": _field, "WAVM": _wavm, "WAVL": _wavl, "PWAV": _pwav,
    "GCAT": _gcat, "ENVD": _envd, "MNUM": _mnum,
    **dict.fromkeys(("VDXN", "VDYN", "VCXN", "VCYN", "VANN", "ZVDX", "ZVDY", "ZVCX", "ZVCY",
                     "ZVAN"), _vignetting),
}
#: surface operand -> its handler (read inside a SURF block)
_SURFACE_OPERANDS = {
    "TYPE": _type, "CURV": _curv, "DISZ": _disz, "CONI": _coni, "DIAM": _diam, "STOP": _stop,
    "PARM": _parm, "XDAT": _xdat, "GLAS": _glas, "CLAP": _clap, "OBSC": _obsc, "SQAP": _sqap,
    "OBDC": _obdc, "GDAT": _gdat, "GARR": _garr, "ELAP": _ellipse, "ELOB": _ellipse,
    "SPID": _spid, "PPAR": _ppar,
    **dict.fromkeys(_APERTURES_REFUSED, _aperture_refused),
    **dict.fromkeys(("TCE", "COAT"), _surface_ignored), "PZUP": _pzup, "SCBD": _scbd,
}


def parse(path: Path):
    """The raw file: ``(system dict, [ZmxSurface, ...], locator)``, lengths in file units.

    Each record is read by the handler of its keyword in :data:`_SYSTEM_OPERANDS` (anywhere) or
    :data:`_SURFACE_OPERANDS` (inside a ``SURF`` block); :data:`_SILENT` keywords are skipped,
    rows after ``MNUM`` kept for :mod:`.zmx_mconf`, and any other keyword noted once as not
    used."""
    p = Locator(path)
    try:
        text = decode_zemax_text(path, "lens file")
    except LensFileError as e:   # not a regular file, or too large
        p.fail(0, e.message)
    except UnicodeDecodeError as e:
        p.fail(0, f"not a UTF-8 or UTF-16 text file ({e.reason} at byte {e.start})")
    records = tokenize(text)
    p.records = {r.line: r for r in records}
    st = _Parse(p)
    for r in records:
        if r.key == "SURF":
            idx = int(p.arg(r.tokens, 1, r.line, "surface number"))
            want = len(st.surfs) + (st.skip[2] - st.skip[1] if st.skip else 0)
            if idx > len(st.surfs) > 0 and st.skip is None:
                st.skip = (r.line, len(st.surfs), idx)   # read in file order; checked below
            elif idx != want:
                p.fail(r.line, f"SURF {idx} out of order: expected SURF {want}" + (
                    f" (the numbers skip from {st.skip[1] - 1} to {st.skip[2]} at line "
                    f"{st.skip[0]})" if st.skip else ""))
            st.cur = ZmxSurface(line=r.line)
            st.surfs.append(st.cur)
            continue
        op = _SYSTEM_OPERANDS.get(r.key)
        if op is None and st.cur is not None:
            op = _SURFACE_OPERANDS.get(r.key)
        if op is not None:
            op(st, r)
        elif r.key in _SILENT:
            continue
        elif st.sysd["mnum"] is not None and r.surf is None:
            st.sysd["mce"].append(r)   # a multi-configuration operand row (after MNUM)
        else:
            first, count = st.unused.get(r.tokens[0], (r.line, 0))
            st.unused[r.tokens[0]] = (first, count + 1)
    for kw, (first, count) in st.unused.items():   # one note per keyword, not one per line
        p.note_each(first, UNUSED, kw, f"; {count} such lines" if count > 1 else "",
                    f"{kw} ({count} lines)" if count > 1 else kw)
    if st.skip is not None:
        _check_skip(st.skip, records, p)
    surfs, sysd = st.surfs, st.sysd
    if not surfs:
        p.fail(0, "no SURF line: not a Zemax lens file, or the file is truncated")
    if len(surfs) < 3:
        p.fail(surfs[-1].line, f"expected an object surface, at least one lens surface and an "
                               f"image surface; found {len(surfs)} SURF block(s) (truncated file?)")
    _check_magnitudes(sysd, surfs, p)
    _check_complete(surfs, p)
    return sysd, surfs, p


#: records that name a surface by its number (or may: a pickup's or solve's source, a tolerance
#: operand, a multi-configuration operand, the global coordinate reference surface)
_NAMES_SURFACES = {"PZUP", "PPAR", "CURVSOLV", "THSO", "MAZH", "GLRS", "TOL", "TOLE", "MNUM"}


def _names_a_surface(r: Record) -> bool:
    """Whether record ``r`` names a surface by its number (conservatively: every record of
    :data:`_NAMES_SURFACES` but ``GLRS 0`` and ``TOL TOFF``, a ``CURV`` whose solve type is not 0
    (none) or 1 (variable), a ``GLAS`` whose solve type is not 0 (fixed), 1 (model) or 3
    (substitute))."""
    t = r.tokens
    if r.key == "GLRS":
        return len(t) > 1 and t[1] not in ("0", "0.0")
    if r.key == "TOL":
        return not (len(t) > 1 and t[1].upper() == "TOFF")
    if r.key in _NAMES_SURFACES:
        return True
    if r.key == "CURV":
        return len(t) > 2 and t[2] not in ("0", "1")
    if r.key == "GLAS":
        return len(t) > 2 and t[2] not in ("0", "1", "3")
    return False


def _check_skip(skip: tuple[int, int, int], records, p: Locator) -> None:
    """A ``SURF`` number that skips (``SURF 39`` after ``SURF 37``): the blocks are read in file
    order, the written numbers from there on one more than their places (``skip`` = (line, the
    expected number, the written one)).  Refused when a record names a surface by number (then
    that number means one surface by the file's numbering and another by place); otherwise one
    located note."""
    ln, expected, written = skip
    refs = [r for r in records if _names_a_surface(r)]
    if refs:
        r = refs[0]
        p.fail(r.line, f"{r.key} names a surface by number, and the SURF numbers skip from "
                       f"{expected - 1} to {written} (line {ln}): from SURF {written} on the "
                       f"file's numbers and the surfaces' places differ by {written - expected}, "
                       f"so the number is ambiguous; renumber the SURF lines")
    p.note(ln, f"SURF {written} follows SURF {expected - 1} (no SURF {expected}): the blocks are "
               f"read in file order (SURF {written} is the lens' surface {expected}, and so on); "
               f"no line of the file names a surface by number")


def _check_magnitudes(sysd: dict, surfs: list[ZmxSurface], p: Locator) -> None:
    """Lengths and curvatures within the limits of deeplens lens files
    (:data:`~.file_limits.MAX_LENGTH_MM`, :data:`~.file_limits.MAX_CURVATURE_PER_MM`), in mm after the
    ``UNIT`` scaling: beyond them paraxial data overflow or round to nonsense (a ``DISZ 1e308``
    gave an EFL of -1e-305 mm, a ``CURV 1e308`` an ``OverflowError``)."""
    s_mm = UNITS[sysd["unit"][0]]
    unit = sysd["unit"][0]

    def length(v, ln, what, hint=""):
        if math.isfinite(v) and abs(v) * s_mm > MAX_LENGTH_MM:
            p.fail(ln, f"{what} {v:g} {unit}: expected a length of at most {MAX_LENGTH_MM:g} mm "
                       f"in magnitude (the limit of deeplens lens files: paraxial data would "
                       f"overflow or round to nonsense{hint})")

    if sysd["aperture"] is not None and sysd["aperture"][0] == "epd":
        length(sysd["aperture"][1], sysd["aperture"][2], "ENPD entrance-pupil diameter")
    for k, s in enumerate(surfs):
        if abs(s.curv) / s_mm > MAX_CURVATURE_PER_MM:
            p.fail(s.curv_line, f"CURV {s.curv:g} per {unit} (SURF {k}): expected a curvature of "
                                f"at most {MAX_CURVATURE_PER_MM:g} per mm in magnitude (a radius "
                                f"of at least {1 / MAX_CURVATURE_PER_MM:g} mm, the limit of "
                                f"deeplens lens files)")
        length(s.disz, s.disz_line, f"DISZ (SURF {k} thickness)",
               "; an object at infinity is DISZ INFINITY" if k == 0 else "")
        length(s.diam, s.diam_line, f"DIAM (SURF {k} semi-diameter)")
        for rec, what in ((s.clap, "CLAP radius"), (s.obsc, "obscuration radius"),
                          (s.obsc_inner, "ring obscuration's inner radius"),
                          (s.sqap, "SQAP half-width"), (s.obdc, "OBDC decenter"),
                          (s.elap, "ELAP half-axis"), (s.elob, "ELOB half-axis"),
                          (s.spid and (s.spid[0], s.spid[2]), "SPID arm width")):
            if rec is not None:
                for v in rec[:-1]:
                    length(v, rec[-1], f"{what} (SURF {k})")


def _check_complete(surfs: list[ZmxSurface], p: Locator) -> None:
    """A note (a located warning) when the file looks cut off: every file of the test corpus
    (OpticStudio's and converters') ends with its image surface, a ``SURF`` block with
    ``DISZ 0``; a file cut after a lens surface (or inside the image surface's block) would
    otherwise read as a shorter lens, the cut surface taken as the image surface."""
    last, k = surfs[-1], len(surfs) - 1
    if last.disz_line and last.disz == 0:
        return
    why = "has no DISZ line" if not last.disz_line else f"has DISZ {last.disz:g}"
    p.note(last.line, f"the file ends with SURF {k}, which {why}: OpticStudio ends every file "
                      f"with its image surface (a block with DISZ 0), so the file may be cut "
                      f"off; it was read as a lens whose image surface is SURF {k}")
