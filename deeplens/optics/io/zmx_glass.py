"""The glass of a ``.zmx`` ``GLAS`` line: exact lookup in the catalogues the file names.

Order, when a name is in more than one place: per catalogue on the ``GCAT`` line (all vendor
catalogues if it names none) the user's ``.agf`` of that name (it overrides), the current vendor
catalogue (:mod:`.vendor_glass`; also deeplens' own formula entries ``INFRARED``, ``CORNING`` and
``BIREFRINGENT``, and ``SCHOTT_IRG`` from :mod:`.shelf_glass`, each use noted), deeplens' built-in entries (:data:`BUILTIN_CATALOGUES`;
``MISC`` also :mod:`.misc_glass`'s ``WATER``, each use noted), deeplens' named stand-ins
(:mod:`.standin_glass`: ``MISC`` ``ACRYLIC``, ``POLYSTYR``; ``ZEON`` ``E48R``; one warning per
file), a catalogue kept only as index tables, fitted (:mod:`.tabulated_glass`: LZOS; each use noted); then the named vendors' archived
and previous catalogues; then the user's other catalogues (``glass_catalogs``, then
:data:`GLASS_PATH_ENV`); then, with a note, a shipped vendor catalogue the file does not name
(exact name only).

A named glass found in a catalogue is that catalogue's glass, as in OpticStudio (its manual,
"Using Material Catalogs": the name is looked for in the loaded catalogues and the glass's
coefficients are used); the ``n_d``/``V_d`` columns of the line describe a model glass only
(``GLAS ___BLANK 1 0 n_d V_d``, or ``GLAS NAME 1 0 n_d V_d``: the ``Model`` material solve), and
OpticStudio leaves them stale on a catalogue glass's line.  A glass not found is a one-line
error naming it, its line and the catalogue to give, unless the caller asked for a fallback,
which is a located warning naming the values used.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import torch

from ..materials import Air, Material, ModelGlass, get_material
from .agf import GlassCatalogue, read_agf
from .birefringent_glass import birefringent_note
from .corning_glass import corning_note
from .infrared_glass import crystal_note
from .misc_glass import MISC_GLASSES, misc_glass, misc_note
from .shelf_glass import SHELF_CATALOGUES, shelf_note
from .standin_glass import STANDIN_CATALOGUES, standin_glass, standin_note, standin_refusal
from .tabulated_glass import TABULATED_CATALOGUES, tabulated_catalogue_size, tabulated_glass
from .withdrawn_glass import WITHDRAWN_CATALOGUES, withdrawn_glass, withdrawn_note
from .vendor_glass import (ARCHIVED_CATALOGUES, CURRENT_CATALOGUES, PARTIAL_CATALOGUES,
                           PREVIOUS_CATALOGUES, archived_glass, catalogue_size, find_in_vendor_catalogues,
                           BuchdahlGlass, previous_glass, vendor_glass)
from .zmx_glass_codes import GLASS_CODE_CAUSE, glass_code, glass_code_hint, glass_code_note
from .zmx_parse import Cause, Locator, ZmxSurface, literal

__all__ = ["BUILTIN_CATALOGUES", "GLASS_PATH_ENV", "adjacent_catalogue", "catalogue_files",
           "glass_path_catalogues", "load_catalogues", "range_refusal_source",
           "surface_material", "resolve_glass", "model_glass"]

# Which of deeplens' own catalogue entries answer for which Zemax catalogue name.
BUILTIN_CATALOGUES = {
    "SCHOTT": ("N-BK7", "N-SF5", "SF5", "N-SF6", "N-SF2", "N-SF10", "SF10", "N-SF11", "N-BAF10",
               "N-BAK1", "N-BAK4", "N-SK16", "N-SSK8", "F2", "N-F2", "N-LAK9", "N-LAK22",
               "N-LASF9", "N-LASF44", "N-K5", "N-PSK53A", "B270"),
    "MISC": ("F_SILICA", "SILICA", "FUSED_SILICA", "PMMA", "POLYCARB"),
}
"""Zemax catalogue name -> the names deeplens' built-in catalogue resolves for it (after the
vendor catalogues of :mod:`.vendor_glass`)."""

#: catalogue -> the located note of a use of one of deeplens' own formula entries in it
_SOURCE_NOTES = {"INFRARED": crystal_note, "CORNING": corning_note,
                 "BIREFRINGENT": birefringent_note}
# and the vendor shelves' (:mod:`.shelf_glass`: SCHOTT_IRG), whose note names the catalogue too
_SOURCE_NOTES |= {c: (lambda g, c=c: shelf_note(g, c)) for c in SHELF_CATALOGUES}

#: catalogue -> (lookup, names, note) of deeplens' own formula entries that answer for a
#: built-in catalogue after its table names (:mod:`.misc_glass`: ``MISC`` ``WATER``)
_BUILTIN_FORMULAS = {"MISC": (misc_glass, MISC_GLASSES, misc_note)}

# the n_d / V_d OpticStudio writes on the GLAS line of a catalogue glass it has not evaluated
_PLACEHOLDER_ND_VD = (1.5, 40.0)


#: the environment variable of the user's glass catalogues: ``.agf`` files and folders of them,
#: separated by :data:`os.pathsep`
GLASS_PATH_ENV = "DEEPLENS_GLASS_PATH"

#: how the one-line refusal of a glass not found says where to give a catalogue
_GIVE = "pass --glass-catalog {f}"

#: a named glass whose GLAS line's n_d/V_d differ from the catalogue glass's (:func:`_checked`;
#: ``{detail}``: the two pairs)
_STALE_CAUSE = Cause(
    one="glass {item}: {detail}; the catalogue glass is used (as OpticStudio does for a named "
        "glass: the n_d/V_d columns describe only model glasses)",
    many="{n} glasses ({items}): the GLAS lines' n_d/V_d differ from the catalogue glasses'; the "
         "catalogue glasses are used (as OpticStudio does for a named glass: the n_d/V_d columns "
         "describe only model glasses)")


def _glass_cause(one: str, many: str) -> Cause:
    """The :class:`~.zmx_parse.Cause` of glasses that share what ``one`` (after ``glass
    NAME``) and ``many`` (after ``N glasses (NAMES)``) say (both literal text)."""
    return Cause(one="glass {item}" + literal(one), many="{n} glasses ({items})" + literal(many))


def glass_path_catalogues(value: str | None = None) -> list[Path]:
    """The ``.agf`` files of :data:`GLASS_PATH_ENV` (``value``: that variable's text, read from
    the environment when ``None``): each entry a file, or a folder whose ``*.agf`` files (any
    case of the suffix) are taken in name order.  An entry that does not exist is an error
    naming it (a typo must not silently drop a catalogue)."""
    if value is None:
        value = os.environ.get(GLASS_PATH_ENV, "")
    out = []
    for entry in (e for e in value.split(os.pathsep) if e.strip()):
        path = Path(entry).expanduser()
        if path.is_dir():
            out += sorted(f for f in path.iterdir()
                          if f.suffix.lower() == ".agf" and f.is_file())
        elif path.is_file():
            out.append(path)
        else:
            raise FileNotFoundError(f"{GLASS_PATH_ENV}: {entry!r} is neither an .agf file nor a "
                                    f"folder")
    return out


def load_catalogues(path, gcat, glass_catalogs, p: Locator,
                    env: str | None = None) -> dict[str, GlassCatalogue]:
    """The user's catalogues by name: those passed (paths or :class:`~.agf.GlassCatalogue`), then
    those of :data:`GLASS_PATH_ENV` (``env``: its text, read from the environment when ``None``)
    whose names were not passed, and for each name on the ``GCAT`` line still missing, an
    ``.agf`` of that name next to the ``.zmx`` (how OpticStudio's own folders are laid out, so
    ``deeplens report x.zmx`` finds them).  The catalogues' own notes become the reader's."""
    cats: dict[str, GlassCatalogue] = {}
    for c in glass_catalogs:
        cat = c if isinstance(c, GlassCatalogue) else read_agf(c)
        cats.setdefault(cat.name, cat)
    for f in glass_path_catalogues(env):
        if f.stem.upper() not in cats:
            cat = read_agf(f)
            cats.setdefault(cat.name, cat)
    for name in gcat:
        if name not in cats:
            f = adjacent_catalogue(path, name)
            if f is not None:
                cats[name] = read_agf(f)
    for note in (n for cat in cats.values() for n in cat.notes):
        p.note(0, note)
    return cats


def adjacent_catalogue(path, name: str) -> Path | None:
    """The ``<NAME>.agf`` next to the ``.zmx`` ``path`` that answers for the ``GCAT`` name
    ``name`` (stem compared in upper case, suffix in any case; the first in sorted order), or
    ``None``."""
    for f in sorted(Path(path).parent.iterdir()):
        if f.suffix.lower() == ".agf" and f.stem.upper() == name and f.is_file():
            return f
    return None


def catalogue_files(path, glass_catalogs=(), env: str | None = None) -> list[Path]:
    """The ``.agf`` files :func:`~.zmx.read_zmx` reads for the ``.zmx`` ``path`` called with
    ``glass_catalogs``, in :func:`load_catalogues`' order: the paths passed, those of
    :data:`GLASS_PATH_ENV` (``env``: its text; the environment when ``None``) whose names were
    not passed, then for each name on the file's ``GCAT`` line that none of them answers, the
    ``<NAME>.agf`` next to the file (:func:`adjacent_catalogue`).
    Only the file's lines are parsed (no glass is read), so that a caller keying a run on its
    inputs can digest the catalogues as well as the lens file.

    Raises:
        ZemaxFileError: the file cannot be parsed (as :func:`~.zmx.read_zmx` would).
    """
    from .zmx_parse import parse

    path = Path(path)
    sysd, _, _ = parse(path)
    files, names = [], set()
    for c in glass_catalogs:
        if isinstance(c, GlassCatalogue):   # given in memory, not read from a file here
            names.add(c.name)
        else:
            files.append(Path(c))
            names.add(Path(c).stem.upper())
    for f in glass_path_catalogues(env):
        if f.stem.upper() not in names:
            files.append(f)
            names.add(f.stem.upper())
    for name in sysd["gcat"][0]:
        if name not in names:
            f = adjacent_catalogue(path, name)
            if f is not None:
                files.append(f)
                names.add(name)
    return files


def _builtin(glass: str) -> Material | None:
    try:
        return get_material(glass)
    except ValueError:
        return None


def _nd_vd(m: Material) -> tuple[float, float]:
    """``(n_d, V_d)`` of a material at the d, F and C lines."""
    n = [float(m.n(torch.tensor(w, dtype=torch.float64))) for w in (587.5618, 486.1327, 656.2725)]
    return n[0], (n[0] - 1.0) / (n[1] - n[2]) if n[1] != n[2] else math.inf


def _checked(m: Material, glass: str, s: ZmxSurface, where: str, p: Locator) -> Material:
    """The catalogue glass ``m`` found for a named ``GLAS`` line.  OpticStudio uses the
    catalogue's data for a named glass; the ``n_d``/``V_d`` columns of the line matter only
    for a model glass (a ``Model`` material solve), so they are never used here.  When they
    disagree with the catalogue's (|Δn_d| > 1e-3, not OpticStudio's 1.5/40 placeholder nor
    zeros) a located note says so: the file was written with another glass of that name."""
    model = s.glass_model
    if model is None or tuple(model) == _PLACEHOLDER_ND_VD or not model[0] > 1.0:
        return m
    try:
        nd, vd = _nd_vd(m)
    except (ValueError, RuntimeError):   # a catalogue glass not defined at the d line
        return m
    if abs(model[0] - nd) > 1e-3:
        p.note_each(s.glass_line, _STALE_CAUSE, repr(glass),
                    f"the GLAS line's n_d {model[0]:g}, V_d {model[1]:g} differ from {where}'s "
                    f"n_d {nd:.6f}, V_d {vd:.2f}")
    return m


def resolve_glass(glass, s: ZmxSurface, gcat, catalogues, fallback, p: Locator,
                  glass_codes: str = "refuse"):
    """The material of ``GLAS glass`` on ``s.glass_line``: exact lookup, in catalogue order.

    Per catalogue the file names on ``GCAT`` (all vendor catalogues if it names none): the
    user's ``.agf`` of that name (it overrides), the current vendor catalogue
    (:mod:`.vendor_glass`), deeplens' built-in entries; then the archived and previous vendor
    catalogues of the named ones; then the user's catalogues the file does not name (in the
    order given: ``glass_catalogs``, then :data:`GLASS_PATH_ENV`); then, with a note, a shipped
    vendor catalogue the file does not name (exact name only).  A glass found is the
    catalogue's (the ``GLAS`` line's ``n_d``/``V_d`` are not used: :func:`_checked`).  A glass
    not found is a one-line error (the catalogues searched are in its ``details``), or, when
    the caller asked for a fallback, a located note naming the glass and the values used.
    A name that is a six-digit ``n_d``/``V_d`` code in none of the catalogues the file names
    nor the user's is, under ``glass_codes="model"``, that model glass, with a located note
    (before the shipped catalogues the file does not name, where a code is ambiguous); under
    ``"refuse"`` the error says so (:mod:`.zmx_glass_codes`).  Each kind of note becomes one
    warning per file naming its lines and glasses (:class:`~.zmx_parse.Cause`).
    """
    searched = []
    named = list(gcat) if gcat else list(CURRENT_CATALOGUES) + ["MISC"]
    for cat in named:
        if cat in catalogues:
            searched.append(f"{cat} (user catalogue {catalogues[cat].path}, "
                            f"{len(catalogues[cat])} glasses)")
            m = catalogues[cat].get(glass)
            if m is not None:
                return _checked(m, glass, s, f"the user catalogue {cat}", p)
            continue
        if cat in CURRENT_CATALOGUES:
            searched.append(f"{cat} (current vendor catalogue, {catalogue_size(cat)} glasses)")
            m = vendor_glass(glass, cat)
            if m is not None:
                if cat in _SOURCE_NOTES:   # deeplens' own formulas: say whose is used
                    p.note(s.glass_line, f"glass {glass!r}: {_SOURCE_NOTES[cat](glass)}")
                return _checked(m, glass, s, f"the {cat} catalogue", p)
        if cat in BUILTIN_CATALOGUES:
            lookup, own, note = _BUILTIN_FORMULAS.get(cat, (None, {}, None))
            searched.append(f"{cat} (deeplens built-in, "
                            f"{len(BUILTIN_CATALOGUES[cat]) + len(own)} glasses)")
            if glass in BUILTIN_CATALOGUES[cat]:
                m = _builtin(glass)
                if m is not None:
                    return _checked(m, glass, s, f"deeplens' {cat} entry", p)
            m = lookup(glass) if lookup is not None else None
            if m is not None:   # deeplens' own formula: say whose is used
                p.note(s.glass_line, f"glass {glass!r}: {note(glass)}")
                return _checked(m, glass, s, f"deeplens' {cat} entry", p)
        if cat in STANDIN_CATALOGUES:
            searched.append(f"{cat} (deeplens' named stand-ins: "
                            f"{', '.join(STANDIN_CATALOGUES[cat])})")
            m = standin_glass(glass, cat)
            if m is not None:
                return _stand_in(m, glass, cat, s, p)
        if cat in TABULATED_CATALOGUES:
            searched.append(f"{cat} (index tables fitted by the Schott formula, "
                            f"{tabulated_catalogue_size(cat)} glasses)")
            m = tabulated_glass(glass, cat)
            if m is not None:
                p.note_each(s.glass_line,
                            Cause(one="glass {item}: {detail}",
                                  many="{n} glasses " + literal(f"of {cat} from {m.source}")
                                       + ": the Schott formula fitted to each one's indices "
                                         "(largest residual in n: {items})"),
                            repr(glass), m.note(), f"{glass!r} {m.residual:.1e}")
                return _checked(m, glass, s, f"the fitted {cat} table", p)
    # the named vendors' older catalogues, newest first:
    # (names answered, lookup, kind, what the catalogue is (with {n} glasses), why a use is noted)
    older = ((ARCHIVED_CATALOGUES, archived_glass, "archived",
              "the vendor's .agf as refractiveindex.info keeps it, {n} glasses",
              "the vendor's .agf as refractiveindex.info keeps it; not in the current {cat} "
              "catalogue"),
             # withdrawn glasses with a full-range formula, before the visible-only fit
             (WITHDRAWN_CATALOGUES, withdrawn_glass, "withdrawn",
              "{n} glass(es) with published Sellmeier coefficients", None),
             (PREVIOUS_CATALOGUES, previous_glass, "previous", "Robb & Mercado 1983, {n} glasses",
              "Robb & Mercado 1983, a visible-range fit: n within 6e-5, 400-700 nm"))
    for known, lookup, kind, what, why in older:
        for cat in named:
            if cat in known and cat not in catalogues:
                searched.append(f"{cat} {kind} ({what.format(n=catalogue_size(cat, kind))})")
                m = lookup(glass, cat)
                if m is not None:
                    because = (withdrawn_note(glass, cat) if why is None
                               else why.format(cat=cat))
                    p.note_each(s.glass_line,
                                _glass_cause(f": from the {kind} {cat} catalogue ({because})",
                                             f" from the {kind} {cat} catalogue: {because}"),
                                repr(glass))
                    return _checked(m, glass, s, f"the {kind} {cat} catalogue", p)
    # the user's catalogues the file does not name, in the order given
    for cat in (c for c in catalogues if c not in named):
        searched.append(f"{cat} (user catalogue {catalogues[cat].path}, "
                        f"{len(catalogues[cat])} glasses)")
        m = catalogues[cat].get(glass)
        if m is not None:
            using = (f"in the catalogues GCAT names ({', '.join(named)}); using the user "
                     f"catalogue {cat} ({catalogues[cat].path}, exact name")
            p.note_each(s.glass_line, _glass_cause(f" is not {using})", f" are not {using}s)"),
                        repr(glass))
            return _checked(m, glass, s, f"the user catalogue {cat}", p)
    code = glass_code(glass)
    if code is not None and glass_codes == "model":   # before the catalogues GCAT does not
        # name: there a code is ambiguous (CHANCE and CORNING-FRANCE both list a '620603')
        p.note_each(s.glass_line, GLASS_CODE_CAUSE, repr(code.name), glass_code_note(code))
        return code
    elsewhere = [c for c in find_in_vendor_catalogues(glass) if c.split()[0] not in named]
    if elsewhere:
        m = _found_glass(glass, elsewhere[0])
        using = f"in the catalogues GCAT names ({', '.join(named)}); using {elsewhere[0]}"
        if elsewhere[0] in _SOURCE_NOTES:   # deeplens' own formulas: the note names the source
            p.note(s.glass_line, f"glass {glass!r} is not {using} (exact name): "
                                 f"{_SOURCE_NOTES[elsewhere[0]](glass)}")
        else:
            p.note_each(s.glass_line, _glass_cause(f" is not {using} (exact name)",
                                                   f" are not {using} (exact names)"),
                        repr(glass))
        return _checked(m, glass, s, elsewhere[0], p)
    # a catalogue the file names of which deeplens ships a few names only (CORNING) counts as
    # not shipped: the glass is the vendor's, and its .agf is what to give
    missing = [c for c in named if c not in catalogues and c not in BUILTIN_CATALOGUES
               and (c not in CURRENT_CATALOGUES or (gcat and c in PARTIAL_CATALOGUES))
               and c not in PREVIOUS_CATALOGUES and c not in TABULATED_CATALOGUES]
    give = (_GIVE.format(f=" or ".join(f"{c}.agf" for c in missing)) if missing
            else "pass the vendor's .agf that has it with --glass-catalog")
    where = (f" (catalogue {' or '.join(missing)}) is not shipped" if missing else
             f" is not in the shipped {', '.join(named)} catalogue{'s' if len(named) > 1 else ''}")
    where_all = (f" (catalogue {' or '.join(missing)}) are not shipped" if missing else
                 f" are not in the shipped {', '.join(named)} "
                 f"catalogue{'s' if len(named) > 1 else ''}")
    give_all = give.replace("that has it", "that has them")
    for c in (c for c in missing if c in PARTIAL_CATALOGUES):
        searched.append(f"of {c} deeplens ships only {', '.join(PARTIAL_CATALOGUES[c])}")
    others = [c for c in CURRENT_CATALOGUES if c not in named]
    if others:
        searched.append(f"by exact name also {', '.join(others)} (current) and their archived "
                        f"and previous catalogues")
    details = (f"catalogues searched by exact name: {'; '.join(searched) or 'none'}"
               f"{_base_glass_hint(glass, s)}.  deeplens never substitutes a similar glass.  "
               f"A catalogue is given by --glass-catalog PATH (repeatable), read_zmx(..., "
               f"glass_catalogs=[PATH, ...]), the {GLASS_PATH_ENV} environment variable (.agf "
               f"files and folders, separated by {os.pathsep!r}) or as NAME.agf next to the "
               f".zmx; glass_fallback='model' uses the n_d/V_d on the GLAS line instead")
    if fallback is not None:
        if fallback == "model":
            if s.glass_model is None or not s.glass_model[0] > 1.0:
                p.fail(s.glass_line, f"glass {glass!r}{where}, and the GLAS line has no usable "
                                     f"n_d/V_d for the model-glass fallback; {give}",
                       details=details)
            if tuple(s.glass_model) == _PLACEHOLDER_ND_VD:
                p.fail(s.glass_line, f"glass {glass!r}{where}, and the GLAS line's n_d/V_d "
                                     f"(1.5, 40) is OpticStudio's placeholder for a catalogue "
                                     f"glass, not the glass's data: the model-glass fallback "
                                     f"cannot use it; {give}", details=details)
            m = model_glass(s, p)
            why = ("(glass_fallback='model', without which {} refused; OpticStudio does not "
                   "update these for a catalogue glass: they may be stale)")
            cause = Cause(one="glass {item}" + literal(f"{where}; using the GLAS line's model "
                                                    f"values ") + "{detail}"
                              + literal(f" {why.format('it is')}; for the glass itself {give}"),
                          many="{n} glasses ({items})"
                               + literal(f"{where_all}; using each GLAS line's model n_d/V_d "
                                      f"{why.format('they are')}; for the glasses themselves "
                                      f"{give_all}"))
            detail = f"n_d {s.glass_model[0]:g}, V_d {s.glass_model[1]:g}"
        else:
            m = fallback if isinstance(fallback, Material) else get_material(str(fallback))
            try:
                nd, vd = _nd_vd(m)
                used = f"the requested fallback {m.name!r} (n_d {nd:.6g}, V_d {vd:.4g})"
            except (ValueError, RuntimeError):
                used = f"the requested fallback {m.name!r}"
            cause = _glass_cause(f"{where}; using {used} (glass_fallback, without which it is "
                                 f"refused); for the glass itself {give}",
                                 f"{where_all}; using {used} for each (glass_fallback, without "
                                 f"which they are refused); for the glasses themselves "
                                 f"{give_all}")
            detail = ""
        p.note_each(s.glass_line, cause, repr(glass), detail)
        return m
    hint = "" if code is None else glass_code_hint(code)
    p.fail(s.glass_line, f"glass {glass!r}{where}; {give}{hint}", details=details)


def _stand_in(m: Material, glass: str, cat: str, s: ZmxSurface, p: Locator) -> Material:
    """The named stand-in ``m`` for ``glass`` of catalogue ``cat`` (:mod:`.standin_glass`): the
    line is refused where it writes an n_d of its own beyond what the stand-in is trusted to;
    otherwise the file gets one located warning (at the first line that uses it) naming the
    stand-in, its n_d against the line's and the flag that replaces it."""
    why = standin_refusal(glass, cat, s.glass_model)
    if why is not None:
        p.fail(s.glass_line, why)
    name = glass.strip().upper()   # one warning per file however the lines spell it
    head = f"glass {name!r}: a named stand-in"
    if not any(msg.startswith(head) for _, msg in p.notes):
        p.note(s.glass_line, standin_note(name, cat, s.glass_model))
    return m


def range_refusal_source(m: Material) -> tuple[str, str]:
    """What a refusal of a wavelength outside catalogue glass ``m``'s range adds: ``(where,
    give)``, the catalogue the glass came from and how to pass the user's own (both ``""`` for
    a material of no catalogue: a model glass, deeplens' built-in entries).

    A glass of a previous catalogue (:class:`~.vendor_glass.BuchdahlGlass`, Robb & Mercado's
    visible-only fit) says so: that is why its range is 400-700 nm.  The user's ``.agf`` named
    after the catalogue (``SCHOTT.agf``) is looked up before every shipped one
    (:func:`resolve_glass`), so that is the file to pass."""
    cat = str(getattr(m, "catalogue", "") or "")
    if not cat:
        return "", ""
    where = (f"previous {cat} catalogue, Robb & Mercado 1983, a visible-only fit"
             if isinstance(m, BuchdahlGlass) else f"catalogue {cat}")
    return where, f"pass {cat}.agf with --glass-catalog"


def _found_glass(glass: str, hit: str) -> Material:
    """``glass`` from one entry ``hit`` of :func:`~.vendor_glass.find_in_vendor_catalogues`
    (``"SCHOTT"``, ``"SCHOTT (archived)"``, ``"SCHOTT (withdrawn)"``, ``"SCHOTT (previous)"``)."""
    cat = hit.split()[0]
    return (previous_glass(glass, cat) if hit.endswith("(previous)")
            else withdrawn_glass(glass, cat) if hit.endswith("(withdrawn)")
            else archived_glass(glass, cat) if hit.endswith("(archived)")
            else vendor_glass(glass, cat))


def _base_glass_hint(glass: str, s: ZmxSurface) -> str:
    """For a name that is a vendor glass's plus a suffix (``L-TIM28_MOLD``: a moulded variant
    in a lens-moulder's catalogue; ``D-ZK3M``), the base glass and where it is, with the reason
    it is not used: a moulded glass's index differs from the base glass's by a drop that
    depends on the glass and the moulding process (no published rule), and the ``GLAS`` line's
    own ``n_d`` (when it is not OpticStudio's placeholder) says by how much."""
    g = glass.strip().upper()
    bases = [g[:-len("_MOLD")]] if g.endswith("_MOLD") else []
    bases += [g[:-1]] if len(g) > 3 and g[-1].isalpha() and g[-2].isdigit() else []
    for base in bases:
        where = find_in_vendor_catalogues(base)
        if not where:
            continue
        nd = float(_found_glass(base, where[0]).n(587.5618))
        own = ("" if s.glass_model is None or tuple(s.glass_model) == _PLACEHOLDER_ND_VD else
               f"; the GLAS line gives n_d {s.glass_model[0]:g}, V_d {s.glass_model[1]:g} for "
               f"{glass!r}")
        return (f"; {base!r} ({where[0]}, n_d {nd:.5f}) is the base glass of this name, not "
                f"used in its place: a moulded or variant glass's index differs from the base "
                f"glass's by an amount no rule gives{own}")
    return ""


def model_glass(s: ZmxSurface, p: Locator, name=None) -> ModelGlass:
    """The model glass of the ``GLAS`` line's ``n_d``/``V_d`` (``V_d = 0``: OpticStudio's
    non-dispersive model glass, deeplens' ``V_d = inf``)."""
    n_d, v_d = s.glass_model
    try:
        return ModelGlass(n_d, math.inf if v_d == 0 else v_d, name=name)
    except ValueError as e:
        p.fail(s.glass_line, f"model glass (GLAS ... n_d V_d): {e}")


def surface_material(s, gcat, catalogues, fallback, p, glass_codes: str = "refuse"):
    """The medium after ``SURF`` block ``s`` (air without a ``GLAS`` line); ``glass_codes`` is
    :func:`~.zmx_read.read_zmx`'s (:mod:`.zmx_glass_codes`)."""
    if s.glass is None and s.glass_model is not None and s.glass_line:
        return model_glass(s, p, s.glass_model_name)
    if s.glass is None:
        return Air()
    return resolve_glass(s.glass, s, gcat, catalogues, fallback, p, glass_codes)

