r"""Materials of OpticStudio's ``MISC`` catalogue that deeplens ships from a primary published
dispersion formula (λ in µm), beyond the built-in ``MISC`` names of
:mod:`deeplens.optics.materials` (``F_SILICA``, ``SILICA``, ``PMMA``, ``POLYCARB``).

One name is offered::

    WATER   distilled water, 20.0 °C                                        0.182 - 1.129 µm
            Daimon & Masumura, "Measurement of the refractive index of distilled water from
            the near-infrared region to the ultraviolet region", Appl. Opt. 46, 3811 (2007):
            the four-term Sellmeier formula (AGF 6, Sellmeier 3) of the absolute index
            n_abs² = 1 + Σ_{i=1..4} B_i λ² / (λ² − C_i)   (λ in vacuum, C_i in µm²)
            with the paper's 20.0 °C coefficients as the refractiveindex.info database records
            them (main/H2O/Daimon-20.0C, CC0; "Refractive index is absolute (relative to
            vacuum)", the database's page)

OpticStudio's catalogues hold indices *relative to air* at 1 atm and the catalogue's reference
temperature, with wavelengths measured in that air (OpticStudio User Guide, *Using Material
Catalogs*), so the absolute formula is used as such a catalogue would hold it:
``n(λ) = n_abs(λ n_air(λ)) / n_air(λ)`` with OpticStudio's own index of air at 20 °C, 1 atm
(Zemax knowledge base, "How ZEMAX calculates refractive index at arbitrary temperatures and
pressures", S. Gangadhara, 2008; the manual's *Thermal Analysis* chapter)::

    n_ref = 1 + 1e-8 (6432.8 + 2949810 λ² / (146 λ² − 1) + 25540 λ² / (41 λ² − 1))
    n_air = 1 + (n_ref − 1) P / (1 + (T − 15) 3.4785e-3)        (T in °C, P in atm)

This gives n = 1.332981 at the sodium D line (589.29 nm), 9e-6 from the published 1.33299 of
water at 20 °C relative to air (the absolute index, 1.333349, lies 3.6e-4 above it).  OpticStudio's own
``MISC`` coefficients for ``WATER`` are not public and may be another fit: published fits of
water at 20 °C differ by up to 1.1e-3 in n over 0.4-0.7 µm (``tests/optics/io/
test_misc_glass.py`` measures them from the database's other entries), so each use is reported
in a located note naming the source.  Lookup is by exact name (case-insensitive), never a
guessed alias; a name deeplens ships in another catalogue (``CAF2``, ``BAF2``, ``MGF2``,
``SAPPHIRE`` in ``INFRARED``) stays there.
"""

from __future__ import annotations

import torch

from .agf import AGFGlass
from .infrared_glass import Crystal, glass_key, table_note

__all__ = ["MISC_GLASSES", "MISC_NOTE_DIFF", "AirRelativeGlass", "misc_glass", "misc_note",
           "opticstudio_air_index"]


def opticstudio_air_index(lam_um, temperature_c: float = 20.0, pressure_atm: float = 1.0):
    """OpticStudio's index of air (the module docstring) at wavelength ``lam_um`` (µm; a
    float or a tensor of any shape, returned in the same shape), ``temperature_c`` (°C) and
    ``pressure_atm`` (atm)."""
    l2 = lam_um * lam_um
    n_ref = 1.0 + 1e-8 * (6432.8 + 2949810.0 * l2 / (146.0 * l2 - 1.0)
                          + 25540.0 * l2 / (41.0 * l2 - 1.0))
    return 1.0 + (n_ref - 1.0) * pressure_atm / (1.0 + (temperature_c - 15.0) * 3.4785e-3)


class AirRelativeGlass(AGFGlass):
    """An AGF formula of the *absolute* index of vacuum wavelength, evaluated relative to air
    at ``air_temperature_c`` and 1 atm as OpticStudio's catalogues are:
    ``n(λ) = n_abs(λ n_air(λ)) / n_air(λ)`` (λ in air, nm at the interface;
    :func:`opticstudio_air_index`).

    Args:
        name, formula, coefficients, wavelength_range_nm, catalogue: as :class:`~.agf.AGFGlass`
            (the formula gives the absolute index of the vacuum wavelength).
        air_temperature_c: the temperature of the air the index is relative to (°C).
    """

    def __init__(self, name: str, formula: int, coefficients, wavelength_range_nm,
                 catalogue: str = "", air_temperature_c: float = 20.0):
        super().__init__(name, formula, coefficients, wavelength_range_nm, catalogue=catalogue)
        self.air_temperature_c = float(air_temperature_c)

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        n_air = opticstudio_air_index(w / 1000.0, self.air_temperature_c)
        return super()._index(w * n_air) / n_air

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, absolute index relative to air at " \
               f"{self.air_temperature_c:g} °C, 1 atm"


#: OpticStudio ``MISC`` name -> :class:`~.infrared_glass.Crystal` (the module docstring); the
#: formula gives the absolute index (:class:`AirRelativeGlass`)
MISC_GLASSES = {
    "WATER": Crystal(6, (0.5684027565, 0.005101829712, 0.1726177391, 0.01821153936,
                         0.02086189578, 0.02620722293, 0.1130748688, 10.69792721),
                     (182.0, 1129.0),
                     "Daimon & Masumura, Appl. Opt. 46, 3811 (2007), distilled water (its absolute "
                     "index taken relative to OpticStudio's air at 20 °C, 1 atm)",
                     "20.0 °C"),
}

#: how far OpticStudio's WATER may lie from the one used (published fits of water at 20 °C
#: differ by up to 1.1e-3 in n over 0.4-0.7 µm: the module docstring)
MISC_NOTE_DIFF = "1.1e-3"


def misc_glass(glass: str) -> AirRelativeGlass | None:
    """``glass`` from :data:`MISC_GLASSES` (exact name, case-insensitive), or ``None``.

    A wavelength outside its range is refused by :meth:`~deeplens.optics.materials.Material.n`;
    :func:`misc_note` says where it comes from.
    """
    rec = MISC_GLASSES.get(glass_key(glass))
    if rec is None:
        return None
    return AirRelativeGlass(glass_key(glass), rec.formula, rec.coefficients, rec.range_nm,
                            catalogue="MISC", air_temperature_c=20.0)


def misc_note(glass: str) -> str:
    """The located note of a use of ``MISC`` material ``glass`` (a name in
    :data:`MISC_GLASSES`)."""
    return table_note(MISC_GLASSES, glass, "MISC material",
                      f"OpticStudio's own MISC coefficients may be another fit: published fits of "
                      f"water at 20 °C differ by up to {MISC_NOTE_DIFF} in n over 0.4-0.7 µm")
