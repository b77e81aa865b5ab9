"""A lens specification: what design search is asked for (first order, fields, colour, limits).

First order: the focal length ``f`` (``efl_mm``) and the aperture, either the F-number ``N``
(``fno``) or the entrance-pupil diameter ``D`` (``epd_mm``), related by ``N = f / D``; the field
is the half field of view ``θ_max`` (``hfov_deg``), sampled at ``field_fractions`` of it (the
usual 0, 0.7, 1).  Colour: ``wavelengths_nm`` with relative ``wavelength_weights``; the primary
wavelength (first-order quantities) is ``primary_wavelength_nm`` or else the middle of the sorted
list.  Form: ``elements`` singlets (air-spaced), ``aspheres`` of their surfaces allowed a conic
and ``a4, a6`` (0: all spherical), the stop ``"front"``, ``"back"``, ``"middle"``, an air gap
index ``k`` (after element ``k``, 0-based), or ``"search"`` (the search tries each position).
Glass: ``glass_mode`` ``"catalogue"`` (the default) picks each element's glass from a set
and keeps it; ``glasses`` names the set (``"SCHOTT"``: the SCHOTT glasses of
:data:`~deeplens.optics.materials.GLASS_TABLE`; ``"model"``: a small grid of ``n_d/V_d`` model
glasses) or lists glasses by name (``"N-SK16,N-SF2"``).  ``glass_mode`` ``"model"`` makes every
element's glass a model glass whose ``n_d`` and ``V_d`` are design variables held inside the
glass region of the vendor catalogues ``glasses`` names (``"SCHOTT"``, ``"SCHOTT,OHARA"``:
:data:`~.glass_region.CATALOGUES`), substituted at the end by the nearest real glasses of those
catalogues (:mod:`.glass`, :func:`~.multistart.search`).  Limits (mm; ``None`` = none):
``max_track_mm`` (first vertex to image), ``min/max_center_glass_mm``, ``min_edge_glass_mm``,
``min_air_mm`` (centre and edge of every air gap), ``min_bfl_mm``, ``max_diameter_mm`` (every
clear aperture); ``max_distortion_pct`` (percent, ``None`` = none: the largest ``|distortion|``
over the non-zero fields, :mod:`.imaging`, for a lens a camera scores against the ideal
``f tan θ`` image).  ``object_distance_mm`` (``inf``) places the object.

A spec comes from a YAML/JSON mapping (:meth:`DesignSpec.from_file`, keys as the field names),
from command-line flags, or from Python; every bad value raises :class:`SpecError` naming the
field (and the file), what was expected and what was given.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
from dataclasses import dataclass
from pathlib import Path

from ...optics.materials import GLASS_TABLE, ModelGlass, check_wavelength_nm, get_material

__all__ = ["DesignSpec", "SpecError", "glass_set", "GLASS_SETS", "STOP_CHOICES", "GLASS_MODES",
           "catalogue_start_glasses"]

STOP_CHOICES = ("front", "middle", "back", "search")
GLASS_MODES = ("catalogue", "model")

#: model glasses (n_d, V_d) of the ``"model"`` set: crowns and flints along the glass line
_MODEL_SET = ((1.5168, 64.17), (1.62041, 60.32), (1.69100, 54.71), (1.62004, 36.37),
              (1.67271, 32.25), (1.80518, 25.36))


def _schott_names() -> tuple[str, ...]:
    return tuple(n for n, r in GLASS_TABLE.items() if r.source.startswith("refractiveindex.info")
                 and "schott" in r.source.lower())


#: glass set name -> function returning the glass specs of the set
GLASS_SETS = {"SCHOTT": _schott_names,
              "MODEL": lambda: tuple(f"{nd!r}/{vd!r}" for nd, vd in _MODEL_SET)}


class SpecError(ValueError):
    """A bad specification: ``field`` names the offending entry, ``source`` the file (if any)."""

    def __init__(self, message: str, field: str = "", source: str = ""):
        where = ", ".join(x for x in (source, f"field {field!r}" if field else "") if x)
        super().__init__(f"{where}: {message}" if where else message)
        self.field, self.source = field, source


def glass_set(glasses: str) -> list[str]:
    """The glass specs (names or ``n_d/V_d``) of a set name or a comma-separated list.

    Raises:
        SpecError: an unknown set or glass (the message lists the sets / closest names).
    """
    text = str(glasses).strip()
    if text.upper() in GLASS_SETS:
        return list(GLASS_SETS[text.upper()]())
    names = [g.strip() for g in text.split(",") if g.strip()]
    if not names:
        raise SpecError(f"expected a glass set ({', '.join(GLASS_SETS)}) or glass names, got "
                        f"{glasses!r}", field="glasses")
    for g in names:
        try:
            get_material(g)
        except ValueError as e:
            raise SpecError(f"{e} (sets: {', '.join(GLASS_SETS)})", field="glasses") from None
    return names


def catalogue_start_glasses(catalogues) -> list[str]:
    """The ``"n_d/V_d"`` specs of the glasses of vendor ``catalogues`` (each point once, in
    catalogue order): the glasses a ``glass_mode="model"`` search starts from.

    Raises:
        SpecError: an unknown catalogue (the message lists the valid names).
    """
    from .glass_region import glasses

    try:
        pool = glasses(catalogues)
    except ValueError as e:
        raise SpecError(str(e), field="glasses") from None
    return list(dict.fromkeys(f"{g.n_d:.6f}/{g.v_d:.4f}" for g in pool))


def _pos(v, name, allow_none=False, allow_inf=False):
    if v is None and allow_none:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise SpecError(f"expected a positive number, got {v!r}", field=name) from None
    if not (x > 0 and (math.isfinite(x) or (allow_inf and x == math.inf))):
        raise SpecError(f"expected a positive {'number (or inf)' if allow_inf else 'finite number'}"
                        f", got {v!r}", field=name)
    return x


def _floats(v, name):
    if isinstance(v, str):
        v = [t for t in v.replace(" ", "").split(",") if t]
    try:
        return tuple(float(x) for x in v)
    except (TypeError, ValueError):
        raise SpecError(f"expected a list of numbers, got {v!r}", field=name) from None


@dataclass
class DesignSpec:
    """What to design (module docstring).  Lengths in mm, angles in degrees, wavelengths in nm.

    Example:
        >>> spec = DesignSpec(efl_mm=50, fno=5, hfov_deg=20, elements=3)
        >>> spec.fields_deg
        [0.0, 14.0, 20.0]
    """

    efl_mm: float
    hfov_deg: float
    fno: float | None = None
    epd_mm: float | None = None
    wavelengths_nm: tuple = (486.1327, 587.5618, 656.2725)
    wavelength_weights: tuple | None = None
    primary_wavelength_nm: float | None = None
    field_fractions: tuple = (0.0, 0.7, 1.0)
    field_weights: tuple | None = None
    elements: int = 3
    aspheres: int = 0
    stop: object = "search"
    glasses: str = "SCHOTT"
    glass_mode: str = "catalogue"
    object_distance_mm: float = math.inf
    max_track_mm: float | None = None
    min_center_glass_mm: float | None = 1.0
    max_center_glass_mm: float | None = None
    min_edge_glass_mm: float | None = 0.5
    min_air_mm: float | None = 0.2
    min_bfl_mm: float | None = None
    max_diameter_mm: float | None = None
    max_distortion_pct: float | None = None
    name: str = ""

    def __post_init__(self):
        self.efl_mm = _pos(self.efl_mm, "efl_mm")
        self.hfov_deg = float(_floats([self.hfov_deg], "hfov_deg")[0])
        if not 0 <= self.hfov_deg < 60:
            raise SpecError(f"expected a half field of view in [0, 60) degrees, got "
                            f"{self.hfov_deg!r}", field="hfov_deg")
        if (self.fno is None) == (self.epd_mm is None):
            raise SpecError(f"give exactly one of fno and epd_mm, got fno={self.fno!r}, "
                            f"epd_mm={self.epd_mm!r}", field="fno")
        self.fno = _pos(self.fno, "fno", allow_none=True)
        self.epd_mm = _pos(self.epd_mm, "epd_mm", allow_none=True)
        if self.fno is not None and self.fno < 0.5:
            raise SpecError(f"an F-number below 0.5 is not a lens, got {self.fno!r}", field="fno")
        self.wavelengths_nm = _floats(self.wavelengths_nm, "wavelengths_nm")
        if not self.wavelengths_nm:
            raise SpecError("at least one wavelength is needed", field="wavelengths_nm")
        try:
            check_wavelength_nm(list(self.wavelengths_nm))
        except ValueError as e:
            raise SpecError(str(e), field="wavelengths_nm") from None
        self.wavelength_weights = self._weights(self.wavelength_weights, len(self.wavelengths_nm),
                                                "wavelength_weights")
        if self.primary_wavelength_nm is None:
            srt = sorted(self.wavelengths_nm)
            self.primary_wavelength_nm = srt[(len(srt) - 1) // 2]
        self.primary_wavelength_nm = _pos(self.primary_wavelength_nm, "primary_wavelength_nm")
        self.field_fractions = _floats(self.field_fractions, "field_fractions")
        if not self.field_fractions or any(not 0 <= x <= 1 for x in self.field_fractions):
            raise SpecError(f"expected fractions of the half field in [0, 1], got "
                            f"{list(self.field_fractions)}", field="field_fractions")
        self.field_weights = self._weights(self.field_weights, len(self.field_fractions),
                                           "field_weights")
        if isinstance(self.elements, bool) or not isinstance(self.elements, int) or \
                not 1 <= self.elements <= 8:
            raise SpecError(f"expected an integer number of elements in 1..8, got "
                            f"{self.elements!r}", field="elements")
        if isinstance(self.aspheres, bool) or not isinstance(self.aspheres, int) or \
                not 0 <= self.aspheres <= 2 * self.elements:
            raise SpecError(f"expected an integer in 0..{2 * self.elements} (surfaces), got "
                            f"{self.aspheres!r}", field="aspheres")
        self.stop = self._stop(self.stop)
        mode = str(self.glass_mode).strip().lower()
        if mode not in GLASS_MODES:
            raise SpecError(f"expected one of {', '.join(GLASS_MODES)}, got {self.glass_mode!r}",
                            field="glass_mode")
        self.glass_mode = mode
        if mode == "model":
            from .glass_region import check_catalogues

            try:
                self.glasses = ",".join(check_catalogues(self.glasses))
            except ValueError as e:
                raise SpecError(f"glass_mode 'model' needs vendor catalogue names: {e}",
                                field="glasses") from None
        else:
            glass_set(self.glasses)
        self.object_distance_mm = _pos(self.object_distance_mm, "object_distance_mm",
                                       allow_inf=True)
        for name in ("max_track_mm", "min_center_glass_mm", "max_center_glass_mm",
                     "min_edge_glass_mm", "min_bfl_mm", "max_diameter_mm", "max_distortion_pct"):
            setattr(self, name, _pos(getattr(self, name), name, allow_none=True))
        if self.min_air_mm is not None:
            self.min_air_mm = float(self.min_air_mm)
            if not (math.isfinite(self.min_air_mm) and self.min_air_mm >= 0):
                raise SpecError(f"expected a number >= 0, got {self.min_air_mm!r}",
                                field="min_air_mm")
        if (self.min_center_glass_mm and self.max_center_glass_mm
                and self.min_center_glass_mm > self.max_center_glass_mm):
            raise SpecError("min_center_glass_mm exceeds max_center_glass_mm",
                            field="min_center_glass_mm")

    @staticmethod
    def _weights(w, n, name):
        if w is None:
            return (1.0,) * n
        w = _floats(w, name)
        if len(w) != n or any(not (math.isfinite(x) and x >= 0) for x in w) or sum(w) <= 0:
            raise SpecError(f"expected {n} non-negative weights (not all 0), got {list(w)}",
                            field=name)
        return w

    def _stop(self, s):
        if isinstance(s, str) and s.strip().lower() in STOP_CHOICES:
            return s.strip().lower()
        try:
            k = int(s)
            if isinstance(s, bool) or float(s) != k:
                raise ValueError
        except (TypeError, ValueError):
            raise SpecError(f"expected one of {', '.join(STOP_CHOICES)} or the index of an air "
                            f"gap (stop after element k, 0..{self.elements - 2}), got {s!r}",
                            field="stop") from None
        if not 0 <= k <= self.elements - 2:
            raise SpecError(f"an air gap index must lie in 0..{self.elements - 2} (between "
                            f"elements), got {k}", field="stop")
        return k

    # ------------------------------------------------------------------ derived values
    @property
    def epd(self) -> float:
        """Entrance-pupil diameter (mm)."""
        return self.epd_mm if self.epd_mm is not None else self.efl_mm / self.fno

    @property
    def f_number(self) -> float:
        """``f / D``."""
        return self.fno if self.fno is not None else self.efl_mm / self.epd_mm

    @property
    def fields_deg(self) -> list[float]:
        """The field angles (deg), each once (fractions that coincide, as every fraction of a
        zero field does, are one field whose weight is their sum: :attr:`weights_of_fields`)."""
        out = []
        for x in self.field_fractions:
            f = round(x * self.hfov_deg, 12)
            if f not in out:
                out.append(f)
        return out

    @property
    def weights_of_fields(self) -> list[float]:
        """The weight of each of :attr:`fields_deg`."""
        fields = self.fields_deg
        w = [0.0] * len(fields)
        for x, wx in zip(self.field_fractions, self.field_weights):
            w[fields.index(round(x * self.hfov_deg, 12))] += wx
        return w

    @property
    def glass_list(self) -> list[str]:
        """The glass specs the starts choose from: the set's glasses, or with ``glass_mode``
        ``"model"`` the ``n_d/V_d`` points of the catalogues' glasses."""
        if self.glass_mode == "model":
            return catalogue_start_glasses(self.glasses)
        return glass_set(self.glasses)

    @property
    def catalogues(self) -> tuple[str, ...]:
        """The vendor catalogues of a ``glass_mode="model"`` spec (empty otherwise)."""
        return tuple(self.glasses.split(",")) if self.glass_mode == "model" else ()

    def stop_positions(self) -> list:
        """The stop positions the search tries: ``"front"``, ``0 .. elements-2`` (air gaps)
        and ``"back"`` for ``"search"``, else the one asked for (``"middle"``: gap
        ``N // 2 - 1 + N % 2``: after the middle element of three, between the middle two of
        four; a singlet's middle is its front)."""
        gaps = list(range(self.elements - 1))
        if self.stop == "search":
            return ["front", *gaps, "back"]
        if self.stop == "middle":
            return [self.elements // 2 - 1 + self.elements % 2] if self.elements > 1 \
                else ["front"]
        return [self.stop]

    # ------------------------------------------------------------------ IO
    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        for k, v in d.items():
            if isinstance(v, tuple):
                d[k] = list(v)
            if isinstance(v, float) and math.isinf(v):
                d[k] = "inf"
        return d

    @classmethod
    def from_dict(cls, data: dict, source: str = "") -> "DesignSpec":
        """A spec from a mapping with the field names as keys (``"inf"`` allowed for the
        object distance).

        Raises:
            SpecError: an unknown key (with the closest known one), a missing required key,
                or any bad value.
        """
        if not isinstance(data, dict):
            raise SpecError(f"expected a mapping of spec fields, got {type(data).__name__}",
                            source=source)
        known = [f.name for f in dataclasses.fields(cls)]
        for k in data:
            if k not in known:
                close = difflib.get_close_matches(str(k), known, n=1)
                raise SpecError(f"unknown spec field{f'; did you mean {close[0]!r}' if close else ''}"
                                f" (known: {', '.join(known)})", field=str(k), source=source)
        for k in ("efl_mm", "hfov_deg"):
            if k not in data:
                raise SpecError("this field is required", field=k, source=source)
        try:
            return cls(**data)
        except SpecError as e:
            raise SpecError(str(e).split(": ", 1)[-1], field=e.field, source=source) from None
        except TypeError as e:
            raise SpecError(str(e), source=source) from None

    @classmethod
    def from_file(cls, path) -> "DesignSpec":
        """Read a ``.yaml``/``.yml`` (needs PyYAML) or ``.json`` spec file."""
        path = Path(path)
        text = path.read_text(encoding="utf-8")
        if path.suffix.lower() in (".yaml", ".yml"):
            try:
                import yaml
            except ImportError:  # pragma: no cover - pyyaml is in the plot extra
                raise SpecError("reading YAML needs PyYAML (pip install pyyaml), or give the "
                                "spec as JSON", source=str(path)) from None
            try:
                data = yaml.safe_load(text)
            except yaml.YAMLError as e:
                raise SpecError(f"not valid YAML: {e}", source=str(path)) from None
        elif path.suffix.lower() == ".json":
            try:
                data = json.loads(text)
            except json.JSONDecodeError as e:
                raise SpecError(f"not valid JSON: {e}", source=str(path)) from None
        else:
            raise SpecError(f"expected a .yaml, .yml or .json file, got {path.suffix!r}",
                            source=str(path))
        return cls.from_dict(data or {}, source=str(path))


def model_glass_of(spec: str) -> ModelGlass:
    """The ``n_d/V_d`` model glass matching a glass spec (for the thin-lens solve)."""
    m = get_material(spec)
    return m if isinstance(m, ModelGlass) else ModelGlass(m.nd, m.vd)

