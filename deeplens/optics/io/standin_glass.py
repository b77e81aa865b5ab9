r"""Named stand-ins for materials that OpticStudio's catalogues carry and real files name, but
whose catalogue data no licence-compatible source has: a published dispersion formula of the
same material (or the same product measured by others) is used under the catalogue's exact
name, and every file that uses one gets one located warning saying so (λ in µm inside the
formulas; indices relative to air, as the sources give them).

Which catalogue holds each name: real OpticStudio files name them only under these ``GCAT``
catalogues, and some name no other catalogue that could hold them (``GCAT SCHOTT MISC`` with
``ACRYLIC`` or ``POLYSTYR``; ``GCAT SCHOTT ZEON`` with ``E48R``: OpticStudio looks a name up in
the loaded catalogues only, User Guide, *Material*).  The stand-ins::

    MISC ACRYLIC   poly(methyl methacrylate)                                   0.42 - 1.62 µm
                   G. Beadie, M. Brindza, R. A. Flynn, A. Rosenberg, J. S. Shirk, "Refractive
                   index measurements of poly(methyl methacrylate) (PMMA) from 0.4-1.6 µm",
                   Appl. Opt. 54, F139 (2015), 20.1 °C, absolute accuracy < 2e-4:
                   n² = 2.1778 + 6.1209e-3 λ² − 1.5004e-3 λ⁴ + 2.3678e-2 λ⁻² − 4.2137e-3 λ⁻⁴
                        + 7.3417e-4 λ⁻⁶ − 4.5042e-5 λ⁻⁸                     (AGF 13, Extended 3)
    MISC POLYSTYR  polystyrene                                                 0.4368 - 1.052 µm
                   N. Sultanova, S. Kasarova, I. Nikolov, "Dispersion properties of optical
                   polymers", Acta Phys. Pol. A 116, 585 (2009), 20 °C (their measurements,
                   ±1e-3, fitted by M. Polyanskiy):
                   n² = 1 + 1.4435 λ² / (λ² − 0.020216)                     (AGF 2, Sellmeier 1)
    ZEON E48R      ZEONEX E48R (ZEON's cyclo-olefin polymer) as measured by Sultanova et al.
                   (the same paper; not ZEON's own data)                      0.4368 - 1.052 µm
                   n² = 1 + 1.2969 λ² / (λ² − 0.011721)                     (AGF 2, Sellmeier 1)

each as the refractiveindex.info database records it (CC0; ``organic/(C5H8O2)n - poly(methyl
methacrylate)/Beadie``, ``organic/(C8H8)n - polystyrene/Sultanova``, ``other/commercial
polymers/ZeonexE48R/Sultanova``).  Each is a *stand-in*: OpticStudio's own coefficients for the
name are not public and may be another grade or fit. Published fits of PMMA differ by 1.9e-3 in n_d
(1.49060 Sultanova, 1.49253 Beadie); the group's refractometer measures to ±1e-3 (Sultanova,
Nikolov & Ivanov, Opt. Quantum Electron. (2003), doi:10.1023/A:1021811200953, abstract: "an
accuracy of ±0.001"); so a stand-in is trusted to :data:`STANDIN_ND_TOL` (2e-3) in n_d. Where the
file's ``GLAS`` line writes its own n_d (not OpticStudio's ``1.5 40`` placeholder, not zeros) and
it differs from the stand-in's by more, the file is refused at that line; otherwise the warning
quotes the difference, or says that the line writes none. The one-term Sellmeier fits give V_d 29.5
for polystyrene and 51.8 for E48R, where real files write 30.8 and 56 and Apollo Optical Systems'
polymer table gives 31 (polystyrene) and 56 (cyclo-olefin polymers, ZEONEX among them); the warning
states V_d. A user's catalogue of that name
(``--glass-catalog MISC.agf``) replaces the stand-in.  Not offered: ``PYREX`` (no dispersion
formula of Corning 7740 in any source at hand) and ``D34-26`` (``CORNING``; none either).
Lookup is by exact name (case-insensitive), never an alias (``PMMA`` is deeplens' own ``MISC``
entry, another record; ``POLYSTYRENE``, ``ZEONEX`` are not names).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from .agf import AGFGlass
from .infrared_glass import glass_key

__all__ = ["StandIn", "STANDIN_GLASSES", "STANDIN_CATALOGUES", "STANDIN_ND_TOL",
           "standin_glass", "standin_nd_vd", "standin_note", "standin_refusal"]


class StandIn(NamedTuple):
    """One stand-in: the AGF formula number and coefficients (``CD`` order, λ in µm), the
    validity range in nm, what material it is, its source and temperature."""

    formula: int
    coefficients: tuple
    range_nm: tuple
    material: str
    source: str
    temperature: str


_SULTANOVA = "Sultanova, Kasarova & Nikolov, Acta Phys. Pol. A 116, 585 (2009)"

#: (OpticStudio catalogue, name) -> :class:`StandIn` (the module docstring)
STANDIN_GLASSES = {
    ("MISC", "ACRYLIC"): StandIn(
        13, (2.1778, 0.0061209, -0.0015004, 0.023678, -0.0042137, 0.00073417, -4.5042e-05,
             0.0, 0.0), (420.0, 1620.0), "poly(methyl methacrylate)",
        "Beadie et al., Appl. Opt. 54, F139 (2015)", "20.1 °C"),
    ("MISC", "POLYSTYR"): StandIn(
        2, (1.4435, 0.020216, 0.0, 0.0, 0.0, 0.0), (436.8, 1052.0), "polystyrene",
        _SULTANOVA, "20 °C"),
    ("ZEON", "E48R"): StandIn(
        2, (1.2969, 0.011721, 0.0, 0.0, 0.0, 0.0), (436.8, 1052.0),
        "ZEONEX E48R as measured by Sultanova et al. (not ZEON's data)", _SULTANOVA, "20 °C"),
}

#: the OpticStudio catalogues that have a stand-in, with their names
STANDIN_CATALOGUES = {cat: tuple(n for c, n in STANDIN_GLASSES if c == cat)
                      for cat, _ in STANDIN_GLASSES}

#: how far (in n_d) a stand-in is trusted to lie from the catalogue's own material (the module
#: docstring): a GLAS line writing an n_d further away is refused
STANDIN_ND_TOL = 2e-3

_LINES_NM = (587.5618, 486.1327, 656.2725)   # d, F, C


def standin_glass(glass: str, catalogue: str) -> AGFGlass | None:
    """The stand-in for ``glass`` in OpticStudio catalogue ``catalogue`` (exact name,
    case-insensitive), or ``None``.  A wavelength outside its range is refused by
    :meth:`~deeplens.optics.materials.Material.n`."""
    rec = STANDIN_GLASSES.get((catalogue.upper(), glass_key(glass)))
    if rec is None:
        return None
    return AGFGlass(glass_key(glass), rec.formula, rec.coefficients, rec.range_nm,
                    catalogue=catalogue.upper())


def standin_nd_vd(glass: str, catalogue: str) -> tuple[float, float]:
    """``(n_d, V_d)`` of the stand-in (d, F and C lines)."""
    m = standin_glass(glass, catalogue)
    n = [float(m.n(torch.tensor(w, dtype=torch.float64))) for w in _LINES_NM]
    return n[0], (n[0] - 1.0) / (n[1] - n[2])


def _file_nd(model) -> float | None:
    """The n_d a ``GLAS`` line writes of its own: ``None`` for none, OpticStudio's ``1.5 40``
    placeholder, or zeros."""
    if model is None or tuple(model) == (1.5, 40.0) or not model[0] > 1.0:
        return None
    return float(model[0])


def standin_refusal(glass: str, catalogue: str, model) -> str | None:
    """Why a ``GLAS`` line writing ``model`` (its ``(n_d, V_d)`` columns) cannot take the
    stand-in (its n_d further than :data:`STANDIN_ND_TOL` from the stand-in's), or ``None``."""
    nd_file = _file_nd(model)
    if nd_file is None:
        return None
    nd, _ = standin_nd_vd(glass, catalogue)
    if abs(nd_file - nd) <= STANDIN_ND_TOL:
        return None
    rec = STANDIN_GLASSES[(catalogue.upper(), glass_key(glass))]
    return (f"glass {glass!r} ({catalogue.upper()}): the GLAS line writes n_d {nd_file:g}, "
            f"{abs(nd_file - nd):.1e} from deeplens' stand-in ({rec.material}, n_d {nd:.5f}), "
            f"more than the {STANDIN_ND_TOL:g} it is trusted to; pass --glass-catalog "
            f"{catalogue.upper()}.agf")


def standin_note(glass: str, catalogue: str, model) -> str:
    """The located warning of a file's use of the stand-in for ``glass`` (its ``GLAS`` line
    writing ``model``): what is used, its n_d and V_d, the difference from the line's own n_d
    (or that it writes none), and the flag that replaces it."""
    cat = catalogue.upper()
    rec = STANDIN_GLASSES[(cat, glass_key(glass))]
    nd, vd = standin_nd_vd(glass, catalogue)
    nd_file = _file_nd(model)
    lo, hi = (v / 1000.0 for v in rec.range_nm)
    against = ("the GLAS line writes no n_d of its own (OpticStudio's 1.5/40 placeholder)"
               if nd_file is None else
               f"the GLAS line's n_d {nd_file:g} differs by {nd - nd_file:+.1e}")
    vd_text = f"{vd:.1f}" if math.isfinite(vd) else "inf"
    return (f"glass {glass!r}: a named stand-in for OpticStudio's {cat} material, whose data "
            f"deeplens does not have: {rec.material} from {rec.source}, {rec.temperature}, "
            f"valid {lo:g}-{hi:g} µm (n_d {nd:.5f}, V_d {vd_text}; trusted to "
            f"{STANDIN_ND_TOL:g} in n_d); {against}; pass --glass-catalog {cat}.agf for "
            f"the catalogue's own")
