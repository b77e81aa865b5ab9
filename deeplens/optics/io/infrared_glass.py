r"""Infrared crystals under the names of OpticStudio's ``INFRARED`` catalogue, from their
primary published dispersion formulas (λ in µm; indices relative to air at the stated
temperature), each mapped exactly onto a Zemax AGF formula of :mod:`.agf`.

Published forms and their AGF equivalents::

    Sellmeier        n² = 1 + A + Σ B_i λ² / (λ² − λ_i²)          -> AGF 2 (A = 0, ≤ 3 terms),
                                                                    AGF 11 (≤ 5 terms), A as a
                                                                    term with λ_i = 0 (B λ²/λ² = A)
    Klein (ZnS)      n² = ε + Σ_{i=1,2} A_i / (λ² − λ_i²)          -> AGF 9 (Sellmeier 4):
                     A / (λ² − C) = (A/C) λ² / (λ² − C) − A/C, so c0 = ε − Σ A_i/λ_i²,
                     c_{2i−1} = A_i/λ_i², c_{2i} = λ_i²

The table (:data:`CRYSTALS`; the coefficients as the papers print them, every entry equal to the
refractiveindex.info database's own evaluation of the same entry to 1e-9, ``tests/optics/io/
test_infrared_glass.py``)::

    CAF2      Malitson, Appl. Opt. 2, 1103 (1963), 24 °C                         0.23 - 9.7 µm
    BAF2      Malitson, J. Opt. Soc. Am. 54, 628 (1964), 25 °C                   0.27 - 10.3 µm
    MGF2      Dodge, Appl. Opt. 23, 1980 (1984), ordinary ray, 19 °C             0.20 - 7.0 µm
    SAPPHIRE  Malitson & Dodge, J. Opt. Soc. Am. 62, 1405 (1972), o-ray, 20 °C    0.20 - 5.0 µm
    ZNSE      Connolly et al., Proc. SPIE 0181 (1979), CVD ZnSe, 23 °C           0.54 - 18.2 µm
    GERMANIUM Burnett, Kaplan, Stover & Phenis, Proc. SPIE 9974, 99740X (2016),
              295 K (22 °C)                                                     2.0 - 14.0 µm
    SILICON   Salzberg & Villa, J. Opt. Soc. Am. 47, 244 (1957), 26 °C; Sellmeier
              fit of their data by Tatian, Appl. Opt. 23, 4477 (1984)            1.357 - 11.04 µm
    ZNS       Debenham, Appl. Opt. 23, 2238 (1984) (cubic ZnS, 20 °C); the modified
              Sellmeier fit of Klein, Appl. Opt. 25, 1873 (1986)                 0.405 - 13.0 µm
    GAAS      Skauli et al., J. Appl. Phys. 94, 6447 (2003), 22 °C               0.97 - 17.0 µm
    SILICA    Malitson, J. Opt. Soc. Am. 55, 1205 (1965), fused silica, 20 °C    0.21 - 6.7 µm
              (Malitson's range 0.21-3.71 µm; Tan, J. Non-Cryst. Solids 223, 158 (1998),
              verified the formula to 6.7 µm; deeplens' MISC entry ``SILICA`` is the same)
    F_SILICA  the same as SILICA: OpticStudio's INFRARED catalogue holds fused silica under this
              name too (LensForge's manual: "such as F_SILICA found in the INFRARED catalog";
              a real file names it under ``GCAT SCHOTT INFRARED``)
    LIF       Li, J. Phys. Chem. Ref. Data 5, 329 (1976), 297 K                  0.10 - 11.0 µm
    KCL       Li, J. Phys. Chem. Ref. Data 5, 329 (1976), 297 K                  0.18 - 35.0 µm
    CSI       Rodney, J. Opt. Soc. Am. 45, 987 (1955), 24 °C                     0.2967 - 50 µm
    CSBR      Rodney & Spindler, J. Res. Nat. Bur. Stand. 51, 123 (1953), 27 °C  0.365 - 39 µm

OpticStudio's own ``INFRARED`` coefficients are not public; they may be other fits of other
measurements (germanium's and silicon's published indices differ by 1e-3 to 7e-3 between
measurements and temperatures), so each use is reported in a located note naming the source.
The names follow OpticStudio's convention for its ``INFRARED`` catalogue (chemical formula or
element name, upper case); no copy of ``INFRARED.AGF`` was at hand to confirm each one.
Lookup is by exact name (case-insensitive).  Not offered: ``KBR`` and ``NACL`` (Li's formulas
have 6 and 8 terms, more than any AGF formula holds), chalcogenide glasses (``AMTIR1``, ``IRG``
...: manufacturers' data sheets only).
"""

from __future__ import annotations

from typing import NamedTuple

from .agf import AGFGlass

__all__ = ["Crystal", "CRYSTALS", "crystal_note", "glass_key", "infrared_glass", "table_glass",
           "table_note"]


class Crystal(NamedTuple):
    """One ``INFRARED`` entry: the AGF formula number and coefficients (``CD`` order, λ in µm),
    the validity range in nm, the source (for messages) and its temperature."""

    formula: int
    coefficients: tuple
    range_nm: tuple
    source: str
    temperature: str


def _sellmeier(terms, a: float = 0.0, squared: bool = True):
    """``(formula, coefficients)`` of ``n² = 1 + a + Σ B λ² / (λ² − C)``; ``terms`` are
    ``(B, λ_i)`` pairs in µm (``squared``: C = λ_i²) or ``(B, C)`` pairs in µm²."""
    pairs = [(float(b), float(c) ** 2 if squared else float(c)) for b, c in terms]
    if a:
        pairs.insert(0, (float(a), 0.0))   # B λ² / (λ² − 0) = B exactly
    for formula, n in ((2, 3), (6, 4), (11, 5)):
        if len(pairs) <= n:
            pairs += [(0.0, 0.0)] * (n - len(pairs))
            return formula, tuple(v for p in pairs for v in p)
    raise ValueError(f"{len(pairs)} Sellmeier terms: more than any AGF formula holds (5)")


def _klein(eps: float, terms):
    """``(9, coefficients)`` of ``n² = eps + Σ A_i / (λ² − λ_i²)`` (two terms), exactly as AGF
    formula 9 (Sellmeier 4) ``n² = c0 + c1 λ²/(λ² − c2) + c3 λ²/(λ² − c4)``."""
    (a1, l1), (a2, l2) = terms
    c2, c4 = l1 * l1, l2 * l2
    return 9, (eps - a1 / c2 - a2 / c4, a1 / c2, c2, a2 / c4, c4)


def _entry(fc, range_um, source, temperature) -> Crystal:
    lo, hi = range_um
    return Crystal(fc[0], fc[1], (lo * 1000.0, hi * 1000.0), source, temperature)


#: OpticStudio ``INFRARED`` name -> :class:`Crystal` (see the module docstring)
CRYSTALS = {
    "CAF2": _entry(_sellmeier([(0.5675888, 0.050263605), (0.4710914, 0.1003909),
                               (3.8484723, 34.649040)]), (0.23, 9.7),
                   "Malitson, Appl. Opt. 2, 1103 (1963)", "24 °C"),
    "BAF2": _entry(_sellmeier([(0.643356, 0.057789), (0.506762, 0.10968), (3.8261, 46.3864)]),
                   (0.27, 10.3), "Malitson, J. Opt. Soc. Am. 54, 628 (1964)", "25 °C"),
    "MGF2": _entry(_sellmeier([(0.48755108, 0.04338408), (0.39875031, 0.09461442),
                               (2.3120353, 23.793604)]), (0.2, 7.0),
                   "Dodge, Appl. Opt. 23, 1980 (1984), ordinary ray", "19 °C"),
    "SAPPHIRE": _entry(_sellmeier([(1.4313493, 0.0726631), (0.65054713, 0.1193242),
                                   (5.3414021, 18.028251)]), (0.2, 5.0),
                       "Malitson & Dodge, J. Opt. Soc. Am. 62, 1405 (1972), ordinary ray",
                       "20 °C"),
    "ZNSE": _entry(_sellmeier([(4.45813734, 0.200859853), (0.467216334, 0.391371166),
                               (2.89566290, 47.1362108)]), (0.54, 18.2),
                   "Connolly et al., Proc. SPIE 0181 (1979), CVD ZnSe", "23 °C"),
    "GERMANIUM": _entry(_sellmeier([(0.4886331, 1.393959), (14.5142535, 0.1626427),
                                    (0.0091224, 752.19)], squared=False), (2.0, 14.0),
                        "Burnett et al., Proc. SPIE 9974, 99740X (2016)", "295 K"),
    "SILICON": _entry(_sellmeier([(10.6684293, 0.301516485), (0.0030434748, 1.13475115),
                                  (1.54133408, 1104.0)]), (1.357, 11.04),
                      "Salzberg & Villa, J. Opt. Soc. Am. 47, 244 (1957), Tatian's fit",
                      "26 °C"),
    "ZNS": _entry(_klein(8.393, [(0.14383, 0.2421), (4430.99, 36.71)]), (0.405, 13.0),
                  "Debenham, Appl. Opt. 23, 2238 (1984), Klein's fit (cubic ZnS)", "20 °C"),
    "GAAS": _entry(_sellmeier([(5.466742, 0.4431307), (0.0242996, 0.8746453),
                               (1.957522, 36.9166)], a=4.372514), (0.97, 17.0),
                   "Skauli et al., J. Appl. Phys. 94, 6447 (2003)", "22 °C"),
    "SILICA": _entry(_sellmeier([(0.6961663, 0.0684043), (0.4079426, 0.1162414),
                                 (0.8974794, 9.896161)]), (0.21, 6.7),
                     "Malitson, J. Opt. Soc. Am. 55, 1205 (1965), fused silica", "20 °C"),
    # OpticStudio's INFRARED catalogue holds fused silica also as F_SILICA (LensForge's manual,
    # "How LensForge looks up glasses": "F_SILICA found in the INFRARED catalog"; a real file
    # names it under GCAT SCHOTT INFRARED): the same published formula as SILICA
    "F_SILICA": _entry(_sellmeier([(0.6961663, 0.0684043), (0.4079426, 0.1162414),
                                   (0.8974794, 9.896161)]), (0.21, 6.7),
                       "Malitson, J. Opt. Soc. Am. 55, 1205 (1965), fused silica", "20 °C"),
    "LIF": _entry(_sellmeier([(0.92549, 0.07376), (6.96747, 32.79)]), (0.1, 11.0),
                  "Li, J. Phys. Chem. Ref. Data 5, 329 (1976)", "297 K"),
    "KCL": _entry(_sellmeier([(0.30523, 0.1), (0.4162, 0.131), (0.1887, 0.162), (2.62, 70.42)],
                             a=0.26486), (0.18, 35.0),
                  "Li, J. Phys. Chem. Ref. Data 5, 329 (1976)", "297 K"),
    "CSI": _entry(_sellmeier([(0.34617251, 0.0229567), (1.0080886, 0.1466),
                              (0.285518, 0.181), (0.39743178, 0.212), (3.3605359, 161.0)]),
                  (0.2967, 50.0), "Rodney, J. Opt. Soc. Am. 45, 987 (1955)", "24 °C"),
    "CSBR": _entry(_sellmeier([(0.9533786, 0.0905643), (0.8303809, 0.1671517),
                               (2.847172, 119.0155)]), (0.365, 39.0),
                   "Rodney & Spindler, J. Res. Nat. Bur. Stand. 51, 123 (1953)", "27 °C"),
}


def glass_key(glass: str) -> str:
    """Lookup key of a name in deeplens' own formula tables: upper case without blanks."""
    return "".join(str(glass).split()).upper()


def table_glass(table: dict, glass: str, catalogue: str) -> AGFGlass | None:
    """``glass`` from ``table`` (name -> a record with ``formula``, ``coefficients`` and
    ``range_nm``, as :class:`Crystal`; exact name, case-insensitive) as an AGF glass of
    ``catalogue``, or ``None``."""
    rec = table.get(glass_key(glass))
    if rec is None:
        return None
    return AGFGlass(glass_key(glass), rec.formula, rec.coefficients, rec.range_nm,
                    catalogue=catalogue)


def infrared_glass(glass: str) -> AGFGlass | None:
    """``glass`` from the ``INFRARED`` crystals (exact name, case-insensitive), or ``None``.

    A wavelength outside its range is refused by :meth:`~deeplens.optics.materials.Material.n`;
    :func:`crystal_note` says where it comes from.
    """
    return table_glass(CRYSTALS, glass, "INFRARED")


def table_note(table: dict, glass: str, what: str, caveat: str) -> str:
    """The located note of a use of ``glass`` from ``table`` (as :func:`table_glass`'s): ``what``
    it is, its record's source, temperature and range (µm), then ``caveat`` in parentheses."""
    rec = table[glass_key(glass)]
    lo, hi = (v / 1000.0 for v in rec.range_nm)
    return f"{what} from {rec.source}, {rec.temperature}, valid {lo:g}-{hi:g} µm ({caveat})"


def crystal_note(glass: str) -> str:
    """The located note of a use of ``INFRARED`` crystal ``glass`` (a name in
    :data:`CRYSTALS`)."""
    return table_note(CRYSTALS, glass, "INFRARED crystal",
                      "OpticStudio's own INFRARED coefficients may be another fit: indices may "
                      "differ by 1e-3 or more")
