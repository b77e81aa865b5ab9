"""The glass of a ``.zmx`` ``GLAS`` line: exact lookup in the catalogues the file names.

Per catalogue on the ``GCAT`` line (all vendor catalogues if it names none): the user's ``.agf``
of that name (it overrides), the current vendor catalogue (:mod:`.vendor_glass`), deeplens'
built-in entries (:data:`BUILTIN_CATALOGUES`); then the named vendors' archived and previous
catalogues; then, with a note, a vendor catalogue the file does not name (exact name only).
``GLAS ___BLANK 1 0 n_d V_d`` (and ``GLAS NAME 1 0 n_d V_d``) is a model glass.  A glass not found
is an error naming it and its line, unless the caller asked for a fallback.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

from ..materials import Air, Material, ModelGlass, get_material
from .agf import GlassCatalogue, read_agf
from .vendor_glass import (ARCHIVED_CATALOGUES, CURRENT_CATALOGUES, PREVIOUS_CATALOGUES,
                           archived_glass, catalogue_size, find_in_vendor_catalogues,
                           previous_glass, vendor_glass)
from .zmx_parse import Locator, ZmxSurface

__all__ = ["BUILTIN_CATALOGUES", "adjacent_catalogue", "catalogue_files", "load_catalogues",
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

# the n_d / V_d OpticStudio writes on the GLAS line of a catalogue glass it has not evaluated
_PLACEHOLDER_ND_VD = (1.5, 40.0)


def load_catalogues(path, gcat, glass_catalogs, p: Locator) -> dict[str, GlassCatalogue]:
    """The user's catalogues by name: those passed (paths or :class:`~.agf.GlassCatalogue`), and
    for each name on the ``GCAT`` line the caller did not pass, an ``.agf`` of that name next to
    the ``.zmx`` (how OpticStudio's own folders are laid out, so ``deeplens report x.zmx`` finds
    them).  The catalogues' own notes become the reader's."""
    cats: dict[str, GlassCatalogue] = {}
    for c in glass_catalogs:
        cat = c if isinstance(c, GlassCatalogue) else read_agf(c)
        cats[cat.name] = cat
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


def catalogue_files(path, glass_catalogs=()) -> list[Path]:
    """The ``.agf`` files :func:`~.zmx.read_zmx` reads for the ``.zmx`` ``path`` called with
    ``glass_catalogs``: the paths passed, then for each name on the file's ``GCAT`` line that
    none of them answers, the ``<NAME>.agf`` next to the file (:func:`adjacent_catalogue`).
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


def resolve_glass(glass, s: ZmxSurface, gcat, catalogues, fallback, p: Locator,
                  stacklevel: int = 2):
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
            m = model_glass(s, p)
        else:
            m = fallback if isinstance(fallback, Material) else get_material(str(fallback))
        warnings.warn(p.warning(s.glass_line, f"glass {glass!r} not found in "
                                              f"{'; '.join(searched) or 'any catalogue'}; using "
                                              f"the requested fallback {m.name!r}"),
                      stacklevel=stacklevel)
        return m
    others = [c for c in CURRENT_CATALOGUES if c not in named]
    if others:
        searched.append(f"by exact name also {', '.join(others)} (current) and their archived "
                        f"and previous catalogues")
    hint += _base_glass_hint(glass, s)
    p.fail(s.glass_line, f"glass {glass!r} not found by exact name in the catalogues searched "
                         f"({'; '.join(searched) or 'none'}){hint}; deeplens never substitutes "
                         f"a similar glass: give the vendor's .agf (glass_catalogs=[...]) or ask "
                         f"for a fallback (glass_fallback='model' uses the n_d/V_d on the GLAS "
                         f"line)")


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
        cat = where[0].split()[0]
        m = (previous_glass(base, cat) if where[0].endswith("(previous)")
             else archived_glass(base, cat) if where[0].endswith("(archived)")
             else vendor_glass(base, cat))
        nd = float(m.n(587.5618))
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


def surface_material(s, gcat, catalogues, fallback, p, stacklevel: int = 2):
    """The medium after ``SURF`` block ``s`` (air without a ``GLAS`` line); ``stacklevel`` (counted
    from this function, as :func:`warnings.warn` counts) is the frame a fallback warning names."""
    if s.glass is None and s.glass_model is not None and s.glass_line:
        return model_glass(s, p, s.glass_model_name)
    if s.glass is None:
        return Air()
    return resolve_glass(s.glass, s, gcat, catalogues, fallback, p, stacklevel + 1)

