r"""Withdrawn SCHOTT glasses that OpticStudio's ``SCHOTT`` catalogue still carries with a
Sellmeier formula, from a published source that names the glass (λ in µm)::

    BK7   n² = 1 + 1.03961212 λ²/(λ² − 0.00600069867) + 0.231792344 λ²/(λ² − 0.0200179144)
                 + 1.01046945 λ²/(λ² − 103.560653)                       0.3 - 2.5 µm

Source: RefractiveIndex.INFO (M. Polyanskiy), "Refractive index and related constants - BK7"
(http://refractiveindex.info/, 2008-2010 edition): "Dispersion formula ... C1 = 1.03961212;
C2 = 0.00600069867; C3 = 0.231792344; C4 = 0.0200179144; C5 = 1.01046945; C6 = 103.560653",
wavelength "(0.3~2.5)" µm, n_d "1.5168", "Source of refractive index data - SCHOTT optical glass
data sheets".  The page names the glass ``BK7`` (not ``N-BK7``) and attributes the coefficients
to SCHOTT's data sheets; SCHOTT's own withdrawn-glass data sheet was not found in any source at
hand, so each use is reported in a located note naming this source.

These entries are looked up after the current and archived ``SCHOTT`` catalogues and before the
previous one (Robb & Mercado's visible-only fit), so that a 400-700 nm fit does not shadow a
full-range formula.  Lookup is by exact name (case-insensitive), never a guessed alias.
"""

from __future__ import annotations

from typing import NamedTuple

from .agf import AGFGlass
from .infrared_glass import glass_key, table_glass

__all__ = ["WITHDRAWN_CATALOGUES", "WITHDRAWN_GLASSES", "withdrawn_glass", "withdrawn_note"]


class Withdrawn(NamedTuple):
    """One withdrawn glass: AGF formula number, its coefficients, range (nm) and source."""

    formula: int
    coefficients: tuple[float, ...]
    range_nm: tuple[float, float]
    source: str


_BK7_SOURCE = ("RefractiveIndex.INFO, 'Refractive index and related constants - BK7' "
               "(2008-2010), after SCHOTT optical glass data sheets")

#: catalogue -> {NAME: :class:`Withdrawn`} (the module docstring)
WITHDRAWN_GLASSES = {
    "SCHOTT": {
        "BK7": Withdrawn(2, (1.03961212, 0.00600069867, 0.231792344, 0.0200179144,
                             1.01046945, 103.560653), (300.0, 2500.0), _BK7_SOURCE),
    },
}

#: the catalogue names that have withdrawn entries
WITHDRAWN_CATALOGUES = tuple(WITHDRAWN_GLASSES)


def withdrawn_glass(glass: str, catalogue: str) -> AGFGlass | None:
    """``glass`` from the withdrawn entries of ``catalogue`` (exact name), or ``None``.

    A wavelength outside its range is refused by :meth:`~deeplens.optics.materials.Material.n`.
    """
    return table_glass(WITHDRAWN_GLASSES.get(catalogue.upper(), {}), glass, catalogue.upper())


def withdrawn_note(glass: str, catalogue: str) -> str:
    """Why a use of withdrawn ``glass`` of ``catalogue`` is noted (its source and range)."""
    rec = WITHDRAWN_GLASSES[catalogue.upper()][glass_key(glass)]
    lo, hi = (v / 1000.0 for v in rec.range_nm)
    return (f"a withdrawn glass, Sellmeier coefficients from {rec.source}, valid {lo:g}-{hi:g} "
            f"µm; not in the current {catalogue.upper()} catalogue")
