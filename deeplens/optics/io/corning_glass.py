r"""Corning's glasses under the names of OpticStudio's ``CORNING`` catalogue, from a primary
published dispersion formula (λ in µm; indices relative to air at 20 °C).

Only one name is offered::

    C79-80   Corning HPFS 7980 (high-purity synthetic fused silica)       0.21 - 3.71 µm
             Malitson, "Interspecimen comparison of the refractive index of fused silica",
             J. Opt. Soc. Am. 55, 1205 (1965): the Sellmeier formula (AGF 2)
             n² = 1 + 0.6961663 λ²/(λ² − 0.0684043²) + 0.4079426 λ²/(λ² − 0.1162414²)
                    + 0.8974794 λ²/(λ² − 9.896161²),  20 °C

the coefficients of deeplens' ``SILICA`` (``MISC`` and ``INFRARED``), taken over Malitson's own
range (the refractiveindex.info entry of the paper: "Sellmeier formula is reported in Ref. 1 for
the 0.21–3.71 μm wavelength range"; its comment says only "Fused silica, 20 °C").  Which
makers' specimens the paper compared could not be read here, so no Corning grade is claimed
for it; Corning's own HPFS 7980 data sheet (coefficients or indices) was not found in any
source at hand either.  OpticStudio's ``CORNING`` coefficients are not public and may be
another fit: published fused-silica formulas differ by up to 6.1e-5 in 0.4-1.55 µm (Arosa & de la
Fuente, Opt. Lett. 45, 4268 (2020), against Malitson), so each use is reported in a located
note naming the source.  Lookup is by exact name (case-insensitive), never a guessed alias.
"""

from __future__ import annotations

from .agf import AGFGlass
from .infrared_glass import CRYSTALS, table_glass, table_note

__all__ = ["CORNING_GLASSES", "CORNING_NOTE_DIFF", "corning_glass", "corning_note"]

#: OpticStudio ``CORNING`` name -> :class:`~.infrared_glass.Crystal` (the module docstring)
CORNING_GLASSES = {
    "C79-80": CRYSTALS["SILICA"]._replace(
        range_nm=(210.0, 3710.0),
        source="Malitson, J. Opt. Soc. Am. 55, 1205 (1965), fused silica (Corning HPFS 7980 "
               "is synthetic fused silica; Corning's own coefficients were not found)",
        temperature="20 °C"),
}

#: how far OpticStudio's CORNING fit may lie from the one used (published fused-silica fits
#: differ by up to 6.1e-5 in 0.4-1.55 µm: the module docstring)
CORNING_NOTE_DIFF = "7e-5"


def corning_glass(glass: str) -> AGFGlass | None:
    """``glass`` from :data:`CORNING_GLASSES` (exact name, case-insensitive), or ``None``.

    A wavelength outside its range is refused by :meth:`~deeplens.optics.materials.Material.n`;
    :func:`corning_note` says where it comes from.
    """
    return table_glass(CORNING_GLASSES, glass, "CORNING")


def corning_note(glass: str) -> str:
    """The located note of a use of ``CORNING`` glass ``glass`` (a name in
    :data:`CORNING_GLASSES`)."""
    return table_note(CORNING_GLASSES, glass, "CORNING glass",
                      f"OpticStudio's own CORNING coefficients may be another fit: published "
                      f"fused-silica fits differ by up to {CORNING_NOTE_DIFF} in n")
