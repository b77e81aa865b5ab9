r"""Optical materials: refractive index as a differentiable function of wavelength.

Dispersion formulas (λ in micrometres inside the formulas; every public function takes nanometres
and divides by 1000):

* Sellmeier, standard 3-term SCHOTT form (:class:`SellmeierGlass`)::

      n(λ)² = 1 + Σ_{i=1..3} B_i λ² / (λ² − C_i)          (C_i in µm²)

* SCHOTT power series, AGF formula 1 (:class:`SchottFormulaGlass`; B270, PMMA, PC)::

      n(λ)² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸

* Model glass from ``n_d`` and ``V_d`` with Cauchy's equation (:class:`ModelGlass`), the model of
  the paper ("Refractive index follows Cauchy's equation n(λ) = A + B/λ², with A and B determined
  from central refractive index and Abbe number")::

      n(λ) = A + B / λ²,   B = (n_d − 1) / (V_d (1/λ_F² − 1/λ_C²)),   A = n_d − B / λ_d²

  so that ``n(λ_d) = n_d`` and ``(n_d − 1) / (n_F − n_C) = V_d`` exactly.

* Abbe number: ``V_d = (n_d − 1) / (n_F − n_C)`` with the d, F and C lines
  :data:`LINE_D` = 587.5618 nm, :data:`LINE_F` = 486.1327 nm, :data:`LINE_C` = 656.2725 nm.

Unit: **all wavelengths are in nanometres** (:data:`WAVELENGTH_UNIT`); :func:`check_wavelength_nm`
rejects values that look like micrometres or picometres.

Air convention: as in optical design programs and glass catalogues, indices are *relative to
air*, and air itself is exactly 1.0 (:class:`Air`; ``"VACUUM"`` and ``"OCCLUDER"``, an opaque stop
plane, are media of index 1 as well).

Catalogue (:func:`catalogue`, :func:`get_material`): SCHOTT glasses with their Sellmeier
coefficients, fused silica (Malitson), B270, PMMA and polycarbonate (SCHOTT power series), and the
old glasses SSK4, SK1, F15 and SK16, for which no dispersion data was found.  Those four are
:class:`ModelGlass` entries built from the ``n_d``/``V_d`` of the paper authors' material table;
the Cauchy model is exact at 587.56 nm (and reproduces ``V_d`` exactly) but is only an
approximation at other wavelengths.  ``"SF5"`` and ``"N-SF5"`` (likewise F2/N-F2, SF10/N-SF10) are
different glasses.  Every entry of :data:`GLASS_TABLE` records its source, its wavelength range
and its published ``n_d``/``V_d``, against which the tests check the coefficients.
"""

from __future__ import annotations

import difflib
import math
import re
from types import MappingProxyType
from typing import NamedTuple, Sequence

import torch
from torch import nn

__all__ = [
    "WAVELENGTH_UNIT", "LINE_D", "LINE_F", "LINE_C",
    "Material", "Air", "SellmeierGlass", "SchottFormulaGlass", "ModelGlass",
    "UnknownMaterialError", "GlassRecord", "GLASS_TABLE",
    "get_material", "catalogue", "check_wavelength_nm",
]

WAVELENGTH_UNIT = "nm"
"""The package's single wavelength unit: every public function takes nanometres."""

LINE_D, LINE_F, LINE_C = 587.5618, 486.1327, 656.2725
"""Fraunhofer d (He), F (H) and C (H) lines in nm, used for ``n_d`` and ``V_d``."""

DEFAULT_RANGE_NM = (310.0, 2500.0)
"""Wavelength range (nm) assumed for a material whose source gives none."""

_NM_PER_UM = 1000.0


# --------------------------------------------------------------------------- wavelength checks
def _prefix(where: str) -> str:
    if not where:
        return ""
    if where.endswith(" "):
        return where
    return where + (" " if where.endswith(":") else ": ")


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _fmt_beyond(x: float, edge: float) -> str:
    """``x`` with as many digits as it takes to differ from ``edge`` (2500.001, not 2500)."""
    for digits in range(6, 18):
        s = f"{x:.{digits}g}"
        if float(s) != edge:
            return s
    return repr(x)


def _minmax(w) -> tuple[float, float] | None:
    """``(min, max)`` of the wavelengths as python floats (NaN if any is NaN), ``None`` if empty.

    One reduction and one device synchronisation for a tensor; never part of the autograd graph.
    """
    if isinstance(w, torch.Tensor):
        t = w.detach()
        if t.numel() == 0:
            return None
        if not t.is_floating_point():
            t = t.to(torch.float64)
        if t.numel() == 1:
            v = float(t.reshape(()).item())
            return v, v
        lo, hi = torch.aminmax(t.reshape(-1))
        lo, hi = torch.stack([lo, hi]).tolist()
        if math.isnan(lo) or math.isnan(hi):
            return math.nan, math.nan
        return float(lo), float(hi)
    if isinstance(w, (int, float)):
        v = float(w)
        return v, v
    t = torch.as_tensor(w, dtype=torch.float64)
    return _minmax(t)


def check_wavelength_nm(w, material: "Material | None" = None, where: str = "", *,
                        stated_unit: bool = False) -> None:
    """Raise ``ValueError`` unless every wavelength in ``w`` (nm) is usable.

    Args:
        w: wavelength(s) in nanometres: a python number, a sequence or a tensor of any shape.
            Tensors are read detached (no autograd effect) with a single device synchronisation.
        material: if given, every value must lie in its ``wavelength_range_nm`` (inclusive).
        where: context put in front of the message, e.g. ``"lens wavelengths: "``.
        stated_unit: the values were read with their unit stated (a ``.zmx`` file's ``WAVM``,
            in µm by the format): the two unit guards below, which are for bare numbers, are
            not applied (every other check is).

    Raises:
        ValueError: a value is not finite or ``<= 0``; all values are ``< 10`` (they look like
            micrometres); a value is ``> 1e5`` nm (100 µm; it looks like ångström or picometres)
            and ``material``'s range does not reach it (a medium defined there, such as a
            constant index or a millimetre-wave material, says the value is meant); a value is
            ``< 10`` nm among plausible ones; or a value lies outside the material's range (the
            message names the material, the value and the range).
    """
    mm = _minmax(w)
    if mm is None:
        return
    lo, hi = mm
    pre = _prefix(where)
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo <= 0:
        bad = lo if (math.isnan(lo) or lo <= 0) else hi
        raise ValueError(f"{pre}wavelengths must be finite and > 0 nm; got {_fmt(bad)}")
    if hi < 10.0 and not stated_unit:
        if lo == hi:
            got, fix = _fmt(lo), f"use {_fmt(lo * _NM_PER_UM)}"
        else:
            got = f"values in [{_fmt(lo)}, {_fmt(hi)}]"
            fix = f"use [{_fmt(lo * _NM_PER_UM)}, {_fmt(hi * _NM_PER_UM)}] (multiply by 1000)"
        raise ValueError(f"{pre}deeplens takes wavelengths in nanometres; got {got} — did you pass "
                         f"micrometres? {fix}")
    covered = (material is not None and material.wavelength_range_nm[0] <= lo
               and hi <= material.wavelength_range_nm[1])
    if hi > 1e5 and not (stated_unit or covered):
        raise ValueError(f"{pre}deeplens takes wavelengths in nanometres; got {_fmt(hi)}, which is "
                         f"over 100 µm — did you pass ångström (divide by 10) or picometres "
                         f"(divide by 1000)? e.g. 587.56 nm = 5875.6 Å = 587560 pm")
    if lo < 10.0:
        raise ValueError(f"{pre}wavelength {_fmt(lo)} nm is below 10 nm, far outside optics "
                         f"(deeplens takes nanometres; other values reach {_fmt(hi)} nm)")
    if material is not None:
        r_lo, r_hi = material.wavelength_range_nm
        if lo < r_lo or hi > r_hi:
            bad, edge = (lo, r_lo) if lo < r_lo else (hi, r_hi)
            raise ValueError(f"{pre}wavelength {_fmt_beyond(bad, edge)} nm is outside the valid "
                             f"range {r_lo:.10g}–{r_hi:.10g} nm of material {material.name!r}")


def _is_compiling() -> bool:
    try:
        return bool(torch.compiler.is_compiling())
    except AttributeError:  # pragma: no cover - older torch
        return False


# --------------------------------------------------------------------------- materials
class Material(nn.Module):
    """A refractive medium: ``n(wavelength_nm)``, its index relative to air.

    Attributes:
        name: catalogue name (``"N-BK7"``) or description (``"1.5168/64.17"``).
        wavelength_range_nm: ``(min, max)`` wavelengths in nm where the formula is valid;
            :meth:`n` raises ``ValueError`` outside it.

    Subclasses implement :meth:`_index` for a validated floating-point tensor of wavelengths in
    nm.  Materials hold their coefficients as python floats, so ``.to(device)`` / ``.double()``
    never change them; the result follows the dtype and device of the wavelength tensor.
    """

    #: the index varies with position (a gradient-index medium, :mod:`.grin`): the tracer
    #: propagates rays through it along curved paths (:mod:`.grin_trace`)
    graded = False

    def __init__(self, name: str, wavelength_range_nm: tuple[float, float] = DEFAULT_RANGE_NM):
        super().__init__()
        lo, hi = (float(v) for v in wavelength_range_nm)
        if not (0 <= lo < hi):
            raise ValueError(f"material {name!r}: wavelength range must satisfy 0 <= min < max "
                             f"(nm), got {wavelength_range_nm}")
        self.name = str(name)
        self.wavelength_range_nm = (lo, hi)

    # -- public API
    def n(self, wavelength_nm: torch.Tensor | float) -> torch.Tensor:
        """Refractive index (relative to air) at ``wavelength_nm`` (nm), of the same shape.

        A tensor keeps its dtype and device (integer tensors become float64); a python number
        or sequence becomes a float64 tensor.  The wavelengths are checked with
        :func:`check_wavelength_nm` against this material's range (detached: autograd is
        unaffected, and the index is differentiable w.r.t. a wavelength tensor).
        """
        w = wavelength_nm
        if not isinstance(w, torch.Tensor):
            w = torch.as_tensor(w, dtype=torch.float64)
        elif not w.is_floating_point():
            w = w.to(torch.float64)
        if not _is_compiling():
            check_wavelength_nm(w, self)
        return self._index(w)

    def forward(self, wavelength_nm: torch.Tensor | float) -> torch.Tensor:
        """Same as :meth:`n`."""
        return self.n(wavelength_nm)

    @property
    def nd(self) -> float:
        """Index at the d line (587.5618 nm)."""
        return float(self.n(LINE_D))

    @property
    def vd(self) -> float:
        """Abbe number ``(n_d − 1) / (n_F − n_C)`` (d, F, C lines); ``inf`` if non-dispersive."""
        n = self.n(torch.tensor([LINE_D, LINE_F, LINE_C], dtype=torch.float64)).tolist()
        dn = n[1] - n[2]
        if dn == 0.0:
            return math.inf
        return (n[0] - 1.0) / dn

    def to_spec(self) -> str:
        """The string :func:`get_material` turns back into an equal material."""
        return self.name

    def paraxial_transfer(self, length, n):
        """The paraxial matrix ``(A, B, C, D)`` acting on ``(y, n u)`` across ``length`` mm of
        this medium of (signed) axial index ``n``: ``(1, length / n, 0, 1)`` for a homogeneous
        medium (a graded one has its own, :mod:`.grin`)."""
        one = torch.ones_like(torch.as_tensor(length))
        return one, length / n, torch.zeros_like(one), one

    def _index(self, w: torch.Tensor) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def extra_repr(self) -> str:
        return self.name


class Air(Material):
    """Air, the reference medium: ``n == 1`` exactly at every wavelength.

    ``name`` is ``"AIR"``, ``"VACUUM"`` or ``"OCCLUDER"`` (an opaque stop plane in air); all
    three have index 1 and :meth:`to_spec` keeps the name.  Any positive finite wavelength (nm,
    10 nm to 100 µm) is accepted.
    """

    NAMES = ("AIR", "VACUUM", "OCCLUDER")

    def __init__(self, name: str = "AIR"):
        key = str(name).strip().upper()
        if key not in self.NAMES:
            raise ValueError(f"Air name must be one of {', '.join(self.NAMES)}; got {name!r}")
        super().__init__(key, (0.0, math.inf))

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        return torch.ones_like(w)


class SellmeierGlass(Material):
    """Glass with the 3-term Sellmeier formula ``n² = 1 + Σ B_i λ²/(λ² − C_i)``.

    Args:
        name: glass name.
        B: ``(B1, B2, B3)``, dimensionless.
        C: ``(C1, C2, C3)`` in µm² (SCHOTT convention; λ is converted from nm to µm).
        wavelength_range_nm: validity range in nm.
    """

    def __init__(self, name: str, B: Sequence[float], C: Sequence[float],
                 wavelength_range_nm: tuple[float, float] = DEFAULT_RANGE_NM):
        super().__init__(name, wavelength_range_nm)
        B, C = tuple(float(b) for b in B), tuple(float(c) for c in C)
        if len(B) != len(C) or not B:
            raise ValueError(f"glass {name!r}: need as many B as C coefficients, got {B}, {C}")
        self.B, self.C = B, C

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        l2 = (w / _NM_PER_UM) ** 2
        n2 = 1.0
        for b, c in zip(self.B, self.C):
            n2 = n2 + b * l2 / (l2 - c)
        return torch.sqrt(n2)


class SchottFormulaGlass(Material):
    """Glass with the SCHOTT power series (AGF formula 1), λ in µm::

        n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸

    Used for catalogue entries published only in this form (B270, PMMA, polycarbonate).

    Args:
        name: material name.
        a: ``(a0, …, a5)`` (a1 in µm⁻², a2 in µm², a3 in µm⁴, …).
        wavelength_range_nm: validity range in nm.
    """

    def __init__(self, name: str, a: Sequence[float],
                 wavelength_range_nm: tuple[float, float] = DEFAULT_RANGE_NM):
        super().__init__(name, wavelength_range_nm)
        a = tuple(float(v) for v in a)
        if len(a) != 6:
            raise ValueError(f"glass {name!r}: the SCHOTT formula has 6 coefficients, got {len(a)}")
        self.a = a

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        a0, a1, a2, a3, a4, a5 = self.a
        l2 = (w / _NM_PER_UM) ** 2
        u = 1.0 / l2
        # Horner in 1/λ² for the negative powers.
        n2 = a0 + a1 * l2 + u * (a2 + u * (a3 + u * (a4 + u * a5)))
        return torch.sqrt(n2)


class ModelGlass(Material):
    """Model glass from ``n_d`` and ``V_d``: Cauchy ``n(λ) = A + B/λ²`` (λ in µm).

    ``B = (n_d − 1) / (V_d (1/λ_F² − 1/λ_C²))`` and ``A = n_d − B/λ_d²``, so the model returns
    ``n_d`` at 587.5618 nm and has Abbe number ``V_d`` exactly; elsewhere it approximates.

    Args:
        n_d: index at the d line, ``>= 1``; a non-dispersive medium (``v_d = inf``) may have
            ``0 < n_d < 1``: a *relative* index, as in files whose indices are relative to air
            (OpticStudio's are), where a vacuum or purge-gas gap is below 1 (refraction depends
            only on the ratio of the indices on either side).
        v_d: Abbe number, ``> 0`` (``inf`` gives a non-dispersive medium).
        name: catalogue name; by default the spec string ``"n_d/V_d"``.
        wavelength_range_nm: range in nm where the model is accepted (default: 310-2500 nm,
            where the Cauchy form approximates glasses; every wavelength for a non-dispersive
            medium, whose index is constant by definition).
    """

    def __init__(self, n_d: float, v_d: float, name: str | None = None,
                 wavelength_range_nm: tuple[float, float] | None = None):
        n_d, v_d = float(n_d), float(v_d)
        if wavelength_range_nm is None:
            wavelength_range_nm = (0.0, math.inf) if math.isinf(v_d) else DEFAULT_RANGE_NM
        if math.isnan(v_d) or v_d <= 0:
            raise ValueError(f"model glass needs an Abbe number V_d > 0, got V_d = {v_d!r}")
        if not (math.isfinite(n_d) and (n_d >= 1.0 or (math.isinf(v_d) and n_d > 0.0))):
            raise ValueError(f"model glass needs a finite n_d >= 1 (or 0 < n_d < 1, a relative "
                             f"index, when non-dispersive: V_d = inf), got n_d = {n_d!r}"
                             + ("" if math.isinf(v_d) or not 0 < n_d < 1 else
                                f", V_d = {v_d!r}"))
        super().__init__(_model_spec(n_d, v_d) if name is None else name, wavelength_range_nm)
        self.n_d, self.v_d = n_d, v_d
        lf, lc, ld = LINE_F / _NM_PER_UM, LINE_C / _NM_PER_UM, LINE_D / _NM_PER_UM
        self.B = (n_d - 1.0) / (v_d * (1.0 / lf ** 2 - 1.0 / lc ** 2))   # µm²
        self.A = n_d - self.B / ld ** 2

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        return self.A + self.B / (w / _NM_PER_UM) ** 2

    def to_spec(self) -> str:
        """The catalogue name for a catalogue entry, else ``"n_d/V_d"``."""
        rec = GLASS_TABLE.get(self.name.upper())
        if rec is not None and rec.kind == "model" and rec.coefficients == (self.n_d, self.v_d):
            return rec.name
        return _model_spec(self.n_d, self.v_d)


def _model_spec(n_d: float, v_d: float) -> str:
    return f"{n_d!r}/{v_d!r}"


# --------------------------------------------------------------------------- catalogue
class GlassRecord(NamedTuple):
    """One catalogue entry.

    ``kind`` is ``"sellmeier"`` (coefficients ``B1, C1, B2, C2, B3, C3``, C in µm²), ``"schott"``
    (``a0..a5``) or ``"model"`` (``n_d, V_d``); ``range_nm`` the validity range in nm; ``nd`` and
    ``vd`` the published index and Abbe number the coefficients are checked against.
    """

    name: str
    kind: str
    coefficients: tuple[float, ...]
    range_nm: tuple[float, float]
    nd: float
    vd: float
    source: str


# SCHOTT glasses: refractiveindex.info database (public domain, CC0), files
# database/data/glass/schott/<NAME>.yml, which carry the "SCHOTT Zemax catalog 2017-01-20b"
# (schott_2017-01-20b.agf) Sellmeier coefficients (formula 2: B1 C1 B2 C2 B3 C3), the catalogue
# wavelength range and the data-sheet n_d / V_d (SPECS: nd, Vd).
_SCHOTT = "refractiveindex.info glass/schott/{}.yml (SCHOTT Zemax catalogue 2017-01-20b)"

_RECORDS: tuple[GlassRecord, ...] = tuple(
    GlassRecord(name, "sellmeier", coeffs, rng, nd, vd, _SCHOTT.format(name))
    for name, coeffs, rng, nd, vd in (
        ("N-BK7", (1.03961212, 0.00600069867, 0.231792344, 0.0200179144, 1.01046945, 103.560653),
         (300.0, 2500.0), 1.51680, 64.17),
        ("N-SF5", (1.52481889, 0.011254756, 0.187085527, 0.0588995392, 1.42729015, 129.141675),
         (370.0, 2500.0), 1.67271, 32.25),
        # SF5: the old lead-containing glass, a different glass from N-SF5.
        ("SF5", (1.46141885, 0.0111826126, 0.247713019, 0.0508594669, 0.949995832, 112.041888),
         (350.0, 2500.0), 1.67270, 32.21),
        ("N-SF6", (1.77931763, 0.0133714182, 0.338149866, 0.0617533621, 2.08734474, 174.01759),
         (370.0, 2500.0), 1.80518, 25.36),
        ("N-SF2", (1.47343127, 0.0109019098, 0.163681849, 0.0585683687, 1.36920899, 127.404933),
         (365.0, 2500.0), 1.64769, 33.82),
        ("N-SF10", (1.62153902, 0.0122241457, 0.256287842, 0.0595736775, 1.64447552, 147.468793),
         (380.0, 2500.0), 1.72828, 28.53),
        ("SF10", (1.61625977, 0.0127534559, 0.259229334, 0.0581983954, 1.07762317, 116.60768),
         (380.0, 2500.0), 1.72825, 28.41),
        ("N-SF11", (1.73759695, 0.013188707, 0.313747346, 0.0623068142, 1.89878101, 155.23629),
         (370.0, 2500.0), 1.78472, 25.68),
        ("N-BAF10", (1.5851495, 0.00926681282, 0.143559385, 0.0424489805, 1.08521269, 105.613573),
         (350.0, 2500.0), 1.67003, 47.11),
        ("N-BAK1", (1.12365662, 0.00644742752, 0.309276848, 0.0222284402, 0.881511957, 107.297751),
         (300.0, 2500.0), 1.57250, 57.55),
        ("N-BAK4", (1.28834642, 0.00779980626, 0.132817724, 0.0315631177, 0.945395373, 105.965875),
         (334.0, 2500.0), 1.56883, 55.98),
        ("N-SK16", (1.34317774, 0.00704687339, 0.241144399, 0.0229005, 0.994317969, 92.7508526),
         (310.0, 2500.0), 1.62041, 60.32),
        ("N-SSK8", (1.44857867, 0.00869310149, 0.117965926, 0.0421566593, 1.06937528, 111.300666),
         (350.0, 2500.0), 1.61773, 49.83),
        ("F2", (1.34533359, 0.00997743871, 0.209073176, 0.0470450767, 0.937357162, 111.886764),
         (320.0, 2500.0), 1.62004, 36.37),
        ("N-F2", (1.39757037, 0.00995906143, 0.159201403, 0.0546931752, 1.2686543, 119.248346),
         (365.0, 2500.0), 1.62005, 36.43),
        ("N-LAK9", (1.46231905, 0.00724270156, 0.344399589, 0.0243353131, 1.15508372, 85.4686868),
         (300.0, 2500.0), 1.69100, 54.71),
        ("N-LAK22", (1.14229781, 0.00585778594, 0.535138441, 0.0198546147, 1.04088385, 100.834017),
         (310.0, 2500.0), 1.65113, 55.89),
        ("N-LASF9", (2.00029547, 0.0121426017, 0.298926886, 0.0538736236, 1.80691843, 156.530829),
         (365.0, 2500.0), 1.85025, 32.17),
        ("N-LASF44", (1.78897105, 0.00872506277, 0.38675867, 0.0308085023, 1.30506243, 92.7743824),
         (334.0, 2500.0), 1.80420, 46.50),
        ("N-K5", (1.08511833, 0.00661099503, 0.199562005, 0.024110866, 0.930511663, 111.982777),
         (310.0, 2500.0), 1.52249, 59.48),
        ("N-PSK53A", (1.38121836, 0.00706416337, 0.196745645, 0.0233251345, 0.886089205,
                      97.4847345),
         (320.0, 2500.0), 1.61800, 63.39),
    )
) + (
    # Fused silica: I. H. Malitson, J. Opt. Soc. Am. 55, 1205 (1965), 20 °C, via refractiveindex.info
    # main/SiO2/Malitson.yml (formula 1, which gives sqrt(C_i): 0.0684043, 0.1162414, 9.896161 µm;
    # squared here).  Range 0.21-3.71 µm in Malitson, verified to 6.7 µm by C. Z. Tan, J. Non-Cryst.
    # Solids 223, 158 (1998).  n_d = 1.45846, V_d = 67.82 (Malitson's formula at d/F/C; the usual
    # catalogue values 1.4585 / 67.8).
    GlassRecord("FUSED_SILICA", "sellmeier",
                (0.6961663, 0.0684043 ** 2, 0.4079426, 0.1162414 ** 2, 0.8974794, 9.896161 ** 2),
                (210.0, 6700.0), 1.45846, 67.82,
                "Malitson 1965 via refractiveindex.info main/SiO2/Malitson.yml"),
    # B270 (SCHOTT B 270 Superwite): published by SCHOTT only as the power series (AGF formula 1),
    # NM record "NM B270 1 1 1.523080 58.571369" and CD a0..a5 below, from SCHOTT's free catalogue
    # "schott glasses preferred and special June-2025-B.AGF" (as quoted in public AGF-parser test
    # data).  SCHOTT/Thorlabs data sheets round it to n_d = 1.5230, V_d = 58.5; the Aug-1993 B 270
    # data sheet (refractiveindex.info specs/schott/misc/B270.yml) tabulates n_F = 1.5292,
    # n_d = 1.5230, n_C = 1.5203 (within 1e-4 of this formula).  No range in the source: default.
    GlassRecord("B270", "schott",
                (2.286575, -8.7334582e-3, 1.1742884e-2, 2.9041756e-4, -1.2506695e-5, 9.2646253e-7),
                DEFAULT_RANGE_NM, 1.52308, 58.57,
                "SCHOTT AGF June-2025-B (formula 1); data sheet n_d 1.5230, V_d 58.5"),
    # PMMA and polycarbonate: Zemax MISC.AGF (version 13 R2 SP1, 2013) records PMMA and POLYCARB,
    # formula 1; their NM records give n_d = 1.491756, V_d = 57.44 and n_d = 1.585470,
    # V_d = 29.91.  No range in the source: default range.
    GlassRecord("PMMA", "schott",
                (2.1864582, -2.4475348e-4, 1.4155787e-2, -4.4329781e-4, 7.7664259e-5,
                 -2.9936382e-6),
                DEFAULT_RANGE_NM, 1.491756, 57.44, "Zemax MISC.AGF PMMA (formula 1)"),
    GlassRecord("PC", "schott",
                (2.42838566, -3.86116645e-5, 2.87574474e-2, -1.97897366e-4, 1.48358968e-4,
                 1.38651935e-6),
                DEFAULT_RANGE_NM, 1.585470, 29.91, "Zemax MISC.AGF POLYCARB (formula 1)"),
) + tuple(
    # Old glasses without dispersion data found: Cauchy model from the n_d / V_d of the paper
    # authors' material table (exact at 587.56 nm only).  No old-SK16 Sellmeier data was found
    # (tables labelled "SK16" carry the N-SK16 coefficients), so SK16 is a model glass too.
    GlassRecord(name, "model", (nd, vd), DEFAULT_RANGE_NM, nd, vd,
                "paper authors' material table (n_d/V_d; Cauchy model)")
    for name, nd, vd in (
        ("SSK4", 1.61770, 55.116),
        ("SK1", 1.61030, 56.712),
        ("F15", 1.60570, 37.831),
        ("SK16", 1.62040, 60.306),
    )
)

GLASS_TABLE: "MappingProxyType[str, GlassRecord]" = MappingProxyType(
    {r.name: r for r in _RECORDS})
"""Read-only catalogue: canonical upper-case name → :class:`GlassRecord`."""

_ALIASES: "MappingProxyType[str, str]" = MappingProxyType({
    "SILICA": "FUSED_SILICA",
    "F_SILICA": "FUSED_SILICA",
    "POLYCARBONATE": "PC",
    "POLYCARB": "PC",     # Zemax MISC.AGF name
})


class UnknownMaterialError(ValueError):
    """:func:`get_material` was given a name that is not in the catalogue.

    Attributes:
        spec: the name as given.
        suggestions: the closest known names (at most 3).
    """

    def __init__(self, spec: str, suggestions: Sequence[str]):
        self.spec = spec
        self.suggestions = tuple(suggestions)
        close = ", ".join(self.suggestions) if self.suggestions else "none"
        super().__init__(f"unknown glass {spec!r}; closest known: {close} (or give 'n_d/V_d', "
                         f"e.g. '1.5168/64.17'; see deeplens.optics.materials.catalogue())")


def catalogue() -> list[str]:
    """All names :func:`get_material` knows (canonical names, aliases and the air media), sorted.

    ``n_d/V_d`` strings are accepted as well but are not listed.
    """
    return sorted(set(GLASS_TABLE) | set(_ALIASES) | set(Air.NAMES))


def _from_record(rec: GlassRecord) -> Material:
    if rec.kind == "sellmeier":
        c = rec.coefficients
        return SellmeierGlass(rec.name, c[0::2], c[1::2], rec.range_nm)
    if rec.kind == "schott":
        return SchottFormulaGlass(rec.name, rec.coefficients, rec.range_nm)
    if rec.kind == "model":
        return ModelGlass(rec.coefficients[0], rec.coefficients[1], rec.name, rec.range_nm)
    raise AssertionError(f"bad catalogue kind {rec.kind!r}")  # pragma: no cover


def _parse_model(spec: str) -> ModelGlass:
    expected = ("expected 'n_d/V_d' with n_d >= 1 (or 0 < n_d < 1 with V_d = inf) and "
                "V_d > 0, e.g. '1.5168/64.17'")
    parts = spec.split("/")
    if len(parts) != 2:
        raise ValueError(f"malformed material {spec!r}: {expected}")
    try:
        n_d, v_d = float(parts[0]), float(parts[1])
    except ValueError:
        raise ValueError(f"malformed material {spec!r}: {expected}") from None
    if not (math.isfinite(n_d) and (n_d >= 1.0 or (n_d > 0 and math.isinf(v_d)))):
        raise ValueError(f"malformed material {spec!r}: n_d = {parts[0].strip()} is not >= 1; "
                         f"{expected}")
    if math.isnan(v_d) or v_d <= 0:
        raise ValueError(f"malformed material {spec!r}: V_d = {parts[1].strip()} is not > 0; "
                         f"{expected}")
    return ModelGlass(n_d, v_d)


def get_material(spec: str) -> Material:
    """A new material module for ``spec``.

    Args:
        spec: a catalogue name, case-insensitive (``"N-BK7"``, ``"n-bk7"``, ``"fused_silica"``),
            ``"AIR"``, ``"VACUUM"`` or ``"OCCLUDER"`` (index 1), or ``"n_d/V_d"`` for a
            :class:`ModelGlass` (``"1.5168/64.17"``).

    Returns:
        A new :class:`Material` instance on every call.

    Raises:
        UnknownMaterialError: (a ``ValueError``) unknown name; the message lists the 3 closest
            catalogue names.
        ValueError: malformed ``"n_d/V_d"`` (not two numbers, ``n_d < 1`` with a finite
            ``V_d``, ``n_d <= 0`` or ``V_d <= 0``).
        TypeError: ``spec`` is not a string.
    """
    if not isinstance(spec, str):
        raise TypeError(f"material spec must be a string, got {type(spec).__name__}")
    s = spec.strip()
    if "/" in s:
        return _parse_model(s)
    key = re.sub(r"\s+", "_", s.upper())
    if key in Air.NAMES:
        return Air(key)
    key = _ALIASES.get(key, key)
    rec = GLASS_TABLE.get(key)
    if rec is None:
        names = catalogue()
        close = difflib.get_close_matches(key, names, n=3, cutoff=0.0)
        raise UnknownMaterialError(spec, close)
    return _from_record(rec)
