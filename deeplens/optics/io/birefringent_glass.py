r"""Crystals under the names of OpticStudio's ``BIREFRINGENT`` catalogue, from a published
dispersion formula (λ in µm; indices relative to air): their *ordinary* index only.

OpticStudio's Birefringent In surface takes the glass named after it as the ordinary index
(M. Nicholson, "How to design birefringent polarizers", Zemax knowledge base, 2005), and
deeplens reads that surface only in its ordinary-ray modes (:mod:`.surface_handlers`,
``BirefringentFormat``), so a crystal's ordinary index is what a file needs.  One name is
offered::

    QUARTZ   crystalline α-quartz, ordinary ray, 18 °C                         0.18 - 3.0 µm
             T. Radhakrishnan, "Further studies on the temperature variation of the refractive
             index of crystals", Proc. Indian Acad. Sci. 31, 22 (1951), and "The dispersion,
             birefringence and optical activity of quartz", ibid. 25, 260 (1947): the five-term
             Sellmeier formula (AGF 11, Sellmeier 5)
             n_o² = 1 + 0.663044 λ²/(λ² − 0.060²) + 0.517852 λ²/(λ² − 0.106²)
                      + 0.175912 λ²/(λ² − 0.119²) + 0.565380 λ²/(λ² − 8.844²)
                      + 1.675299 λ²/(λ² − 20.742²)
             as the refractiveindex.info database records it (main/SiO2/Radhakrishnan-o, CC0)

Which formula OpticStudio's ``BIREFRINGENT`` catalogue uses for ``QUARTZ`` was not found: a
Zemax knowledge-base article says the sources of the ``INFRARED``, ``BIREFRINGENT`` and ``MISC``
materials are listed in the manual's "Using Glass Catalogs" chapter (and that its calcite came
from the Handbook of Optics, Vol. II), but that list was not in any source at hand.  So this is a
substitute, reported in a located note with each use, as deeplens' ``INFRARED`` crystals are:
Ghosh's independent fit of quartz's ordinary index (Opt. Commun. 163, 95 (1999); the database's
``Ghosh-o``) lies within 4.6e-5 of it over 0.4 - 0.7 µm and within 1.6e-3 over 0.2 - 2.05 µm (the
largest gap at 0.2 µm), which the note states.

Relative to air: the database marks the entry neither absolute nor relative; the formula gives
n_o = 1.544238 at 589.3 nm, where the commonly quoted ordinary index of quartz is 1.54425 (at
590 nm: Filmetrics' refractive-index database, "Quartz"); read as an absolute index, it would give 1.54382 relative to air, 4.3e-4 lower.  So it is used as a
relative index, as OpticStudio's catalogues hold them (User Guide, *Using Material Catalogs*) and
as deeplens' ``INFRARED`` crystals are.  The extraordinary index (``QUARTZ-E``, OpticStudio's name
for it) is not offered: deeplens traces no extraordinary ray, and no file at hand names it.
Lookup is by exact name (case-insensitive), never a guessed alias (``SIO2``, ``CRYSTAL_QUARTZ``
are not ``QUARTZ``; fused silica is ``SILICA``/``F_SILICA``, another material).
"""

from __future__ import annotations

from .agf import AGFGlass
from .infrared_glass import Crystal, table_glass, table_note

__all__ = ["BIREFRINGENT_GLASSES", "BIREFRINGENT_NOTE_DIFF", "birefringent_glass",
           "birefringent_note"]

#: OpticStudio ``BIREFRINGENT`` name -> :class:`~.infrared_glass.Crystal` (the module
#: docstring): AGF formula 11 ``n² = 1 + Σ K_i λ²/(λ² − L_i)``, coefficients (K_i, L_i) with
#: L_i = λ_i² (µm²) written out exactly (0.060² = 0.0036, ..., 20.742² = 430.230564)
BIREFRINGENT_GLASSES = {
    "QUARTZ": Crystal(11, (0.663044, 0.0036, 0.517852, 0.011236, 0.175912, 0.014161,
                           0.565380, 78.216336, 1.675299, 430.230564),
                      (180.0, 3000.0),
                      "Radhakrishnan, Proc. Indian Acad. Sci. 31, 22 (1951), crystalline quartz, "
                      "ordinary ray", "18 °C"),
}

#: how far OpticStudio's QUARTZ may lie from the one used, as the note states it (Ghosh's fit
#: differs by up to 4.6e-5 over 0.4-0.7 µm, 1.6e-3 over 0.2-2.05 µm: the module docstring)
BIREFRINGENT_NOTE_DIFF = ("5e-5", "1.6e-3")


def birefringent_glass(glass: str) -> AGFGlass | None:
    """``glass`` (its ordinary index) from :data:`BIREFRINGENT_GLASSES` (exact name,
    case-insensitive), or ``None``.

    A wavelength outside its range is refused by :meth:`~deeplens.optics.materials.Material.n`;
    :func:`birefringent_note` says where it comes from.
    """
    return table_glass(BIREFRINGENT_GLASSES, glass, "BIREFRINGENT")


def birefringent_note(glass: str) -> str:
    """The located note of a use of ``BIREFRINGENT`` crystal ``glass`` (a name in
    :data:`BIREFRINGENT_GLASSES`)."""
    vis, full = BIREFRINGENT_NOTE_DIFF
    return table_note(BIREFRINGENT_GLASSES, glass, "BIREFRINGENT crystal (ordinary index)",
                      f"a substitute: OpticStudio's own BIREFRINGENT formula for it was not "
                      f"found and may be another fit; published fits of quartz's ordinary index "
                      f"differ by up to {vis} in n over 0.4-0.7 µm, {full} at 0.2 µm")
