"""The deeplens JSON lens format (version 1): read, write, validate.

A lens file is a JSON object::

    {
      "format": "deeplens-lens", "version": 1, "name": "double Gauss",
      "units": {"length": "mm", "wavelength": "nm"},
      "object": {"distance_mm": "inf", "medium": "AIR"},
      "aperture": {"type": "stop"} | {"type": "epd", "value": 10.0} | {"type": "fno", "value": 2.8},
      "fields_deg": [0, 7, 14, 21],
      "wavelengths_nm": [587.5618], "primary_wavelength_nm": 587.5618,
      "stop": 5,
      "surfaces": [
        {"type": "asphere", "distance_mm": 0.0, "semi_diameter_mm": 8.7, "material": "SSK4",
         "curvature_per_mm": 0.0749, "conic": 0.005, "aspheric": [1e-6, 1e-8]},
        {"type": "aperture", "distance_mm": 3.86, "semi_diameter_mm": 2.443, "material": "AIR"},
        {"type": "plane" | "xy_polynomial" | "bspline", ...}
      ],
      "sensor": {"distance_mm": 17.43, "semi_diameter_mm": 10.33},
      "elements": [[0, 1], [2, 4], ...],                      (optional)
      "misalignment": [{"dx_mm": 0, "dy_mm": 0, "tilt_x_rad": 0, "tilt_y_rad": 0}, ...],  (optional)
      "backward_gaps": [32]                                   (optional)
    }

``backward_gaps``: surface indices whose gap from the previous surface rays may cross
backwards, as OpticStudio traces crossing surfaces (:attr:`Lens.backward_gaps
<deeplens.optics.lens.Lens.backward_gaps>`; written only when not empty).

``distance_mm`` is the axial gap from the previous vertex; ``material`` is the medium *after*
the surface (a catalogue glass, ``AIR``, a model glass ``"n_d/V_d"``, or a glass given by its
dispersion formula, below), or ``"MIRROR"`` for a
reflecting surface (the medium after it is the one before it; distances after an odd number of
mirrors are negative, and so is the sensor distance then).  A ``coordinate_break`` entry
(``dx_mm``, ``dy_mm``, ``tilt_x_rad``, ``tilt_y_rad``, ``tilt_z_rad``) changes the frame of every
following surface (folds, off-axis sections; see ``docs/guide/mirrors.md``).  Per type:
``asphere`` takes ``curvature_per_mm`` (or ``roc_mm``, 0 = flat), optional ``conic`` and
``aspheric`` (``[a4, a6, ...]``); ``xy_polynomial`` takes ``coefficients`` and ``b``;
``extended_polynomial`` (OpticStudio's ``XPOLYNOM`` on a conic) ``curvature_per_mm``, ``conic``,
``norm_radius_mm`` and ``polynomial_coefficients`` (in OpticStudio's term order);
``extended_odd_asphere`` (OpticStudio's ``XOSPHERE``) ``curvature_per_mm``, ``conic``,
``norm_radius_mm`` and ``rho_coefficients_mm`` (``[A_1, A_2, ...]`` on ``(r / R_n)^i``); ``bspline``
takes a 2-D ``coefficients`` grid; ``aperture`` optionally ``shape: "rect"`` (or ``"ellipse"``)
with ``half_width_x_mm``/``half_width_y_mm`` (an ellipse's half-axes); ``ideal_lens`` takes
``focal_length_mm``.  Any lens or mirror surface may carry ``clear_rect_mm`` ``[h_x, h_y]``,
``clear_ellipse_mm`` ``[a, b]`` (an elliptical clear aperture, half-axes along x and y, about
``clear_decenter_mm``) or ``obscuration_ellipse_mm`` ``[a, b]`` (an elliptical obscuration about
the vertex).  The surface
types are those registered in :data:`~deeplens.optics.surfaces.SURFACE_TYPES`; each type reads
and writes its own fields (``from_dict``/``to_dict``), so whatever is written can be read.
A glass that :func:`~deeplens.optics.materials.get_material` does not know by name (a vendor
glass read from a ``.zmx`` file: OHARA's ``S-LAH64``, an archived or fitted catalogue's glass, a
user's ``.agf``) is written with its formula, so the file reads back the same indices without
the catalogue: ``{"glass": "S-LAH64", "catalogue": "OHARA", "agf_formula": 2,
"coefficients": [...], "wavelength_range_nm": [lo, hi]}`` (the Zemax AGF formula numbers,
:data:`~deeplens.optics.io.agf.FORMULAS`, λ in µm) or, for a glass of the previous catalogues,
``{"glass": "BK7", "catalogue": "SCHOTT", "buchdahl": [n0, nu1, nu2], "lambda0_um": 0.574}``;
a formula of the absolute index taken relative to OpticStudio's air (``MISC``'s ``WATER``:
:class:`~deeplens.optics.io.misc_glass.AirRelativeGlass`) adds
``"absolute_relative_to_air_c": 20.0``, the air's temperature in °C.
``object.telecentric: true`` (optional, a finite object only) makes object space telecentric:
every chief ray parallel to the axis, ``fields_deg`` the object points' directions from the
first vertex (``Lens.object_telecentric``).  ``object.tilt_tangents: [tan_x, tan_y]``
(optional, a finite object only) tilts the object plane, ``z = z_obj + tan_x x + tan_y y``
(``Lens.object_tilt``); ``object.distance_mm`` may be 0 only when the first surface is a
``coordinate_break`` (the object at its pivot).  Numbers are written with ``repr`` so a file round-trips
exactly.  Every error names the file and the JSON path of the offending field.
"""

from __future__ import annotations

import contextlib
import copy
import difflib
import json
import math
import os
from pathlib import Path

import torch

from ..errors import LensError, LensFileError
from ..frames import travel_directions
from ..lens import Lens, LensSpec
from ..materials import check_wavelength_nm, get_material
from ..surfaces import SURFACE_TYPES, Aperture, Cylinder, IdealLens
from ..surfaces.base import (clear_ellipse_of, clear_rect_of, obscuration_ellipse_of,
                            obscuration_spider_of, set_obscuration_spider,
                            set_clear_ellipse, set_clear_rect, set_obscuration_ellipse,
                            takes_clear_rect)
from .atomic import replace, temp_path
from .file_limits import MAX_CURVATURE_PER_MM, MAX_LENGTH_MM
from .filecheck import read_file_bytes

__all__ = ["read_json", "save_lens", "lens_to_dict", "lens_from_dict", "LensFileError",
           "FORMAT_NAME", "FORMAT_VERSION"]

FORMAT_NAME = "deeplens-lens"
FORMAT_VERSION = 1


#: LensSpec / Lens error keys -> the lens-file field they come from
_SPEC_FIELDS = {"aperture": "aperture", "object_distance_mm": "object.distance_mm",
                "fields_deg": "fields_deg", "wavelengths_nm": "wavelengths_nm",
                "primary_wavelength_nm": "primary_wavelength_nm", "stop": "stop",
                "sensor": "sensor", "elements": "elements", "backward_gaps": "backward_gaps"}


class _Reader:
    def __init__(self, source: str):
        self.source = source

    def fail(self, path: str, msg: str, surfaces=()):
        if not surfaces and path.startswith("surfaces["):
            surfaces = (int(path[len("surfaces["):path.index("]")]),)
        raise LensFileError(msg, source=self.source, key=path, surfaces=surfaces)

    def get(self, obj, key, path, kind="number", default=...):
        if not isinstance(obj, dict):
            self.fail(path, f"expected an object, got {type(obj).__name__}")
        if key not in obj:
            if default is ...:
                self.fail(f"{path}.{key}" if path else key, "missing required field")
            return default
        return self.check(obj[key], f"{path}.{key}" if path else key, kind)

    def check(self, v, path, kind):
        if kind == "number":
            if isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 1023:
                self.fail(path, f"expected a finite number, got an integer of {len(str(v))} "
                                f"digits (too large for a float)")
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                self.fail(path, f"expected a finite number, got {v!r}")
            if path.endswith("_mm") and not path.endswith("_per_mm") and abs(v) > MAX_LENGTH_MM:
                self.fail(path, f"expected a length of at most {MAX_LENGTH_MM:g} mm in "
                                f"magnitude, got {v!r} (paraxial data would overflow or round "
                                f"to nonsense; an object at infinity is \"inf\")")
            if path.endswith("curvature_per_mm") or path.endswith("curvature_x_per_mm"):
                if abs(v) > MAX_CURVATURE_PER_MM:
                    self.fail(path, f"expected a curvature of at most {MAX_CURVATURE_PER_MM:g} "
                                    f"per mm in magnitude (a radius of at least "
                                    f"{1 / MAX_CURVATURE_PER_MM:g} mm), got {v!r}")
            if path.endswith("roc_mm") and v != 0 and abs(v) < 1 / MAX_CURVATURE_PER_MM:
                self.fail(path, f"expected a radius of at least {1 / MAX_CURVATURE_PER_MM:g} mm "
                                f"in magnitude (0 for a flat surface), got {v!r}")
            return float(v)
        if kind == "number_or_inf":
            if isinstance(v, str) and v.strip().lower() in ("inf", "infinity"):
                return math.inf
            if isinstance(v, float) and v == math.inf:
                return v
            if isinstance(v, str):
                self.fail(path, f"expected a finite number or \"inf\", got {v!r}")
            return self.check(v, path, "number")
        if kind == "int":
            if isinstance(v, bool) or not isinstance(v, int):
                self.fail(path, f"expected an integer, got {v!r}")
            return v
        if kind == "str":
            if not isinstance(v, str):
                self.fail(path, f"expected a string, got {v!r}")
            return v
        if kind == "numbers":
            if not isinstance(v, list):
                self.fail(path, f"expected a list of numbers, got {v!r}")
            return [self.check(x, f"{path}[{i}]", "number") for i, x in enumerate(v)]
        if kind == "grid":
            if not isinstance(v, list) or not v or not all(isinstance(r, list) for r in v):
                self.fail(path, f"expected a 2-D list of numbers, got {type(v).__name__}")
            rows = [self.check(r, f"{path}[{i}]", "numbers") for i, r in enumerate(v)]
            if len({len(r) for r in rows}) != 1:
                self.fail(path, "rows of the coefficient grid differ in length")
            return rows
        if kind == "object":
            if not isinstance(v, dict):
                self.fail(path, f"expected an object, got {type(v).__name__} {v!r}")
            return v
        raise AssertionError(kind)

    def keys(self, obj: dict, allowed, path: str) -> None:
        """Reject unknown fields (a misspelt optional field would otherwise be ignored)."""
        for key in obj:
            if key in allowed or key == "comment" or key.startswith("_"):
                continue
            close = difflib.get_close_matches(key, sorted(allowed), n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            self.fail(f"{path}.{key}" if path else key,
                      f"unknown field{hint} (known: {', '.join(sorted(allowed))})")



_COMMON_KEYS = {"type", "distance_mm", "semi_diameter_mm", "material"}
_TOP_KEYS = {"format", "version", "name", "units", "object", "aperture", "fields_deg",
             "wavelengths_nm", "primary_wavelength_nm", "stop", "surfaces", "sensor", "elements",
             "misalignment", "backward_gaps"}


class _Entry:
    """The reader interface a surface type's ``from_dict`` sees: typed, checked fields of one
    ``surfaces[i]`` entry, with errors naming the file and the field."""

    def __init__(self, reader: _Reader, obj: dict, path: str):
        self._r, self._obj, self._path = reader, obj, path

    def has(self, key: str) -> bool:
        return key in self._obj

    def get(self, key: str, kind: str = "number", default=...):
        """The field ``key`` checked as ``kind`` (``number``, ``numbers``, ``grid``, ``str``)."""
        return self._r.get(self._obj, key, self._path, kind, default)

    def fail(self, key: str, message: str):
        self._r.fail(f"{self._path}.{key}", message)


def _surface_from_dict(r: _Reader, s: dict, path: str):
    r.check(s, path, "object")
    kind = r.get(s, "type", path, "str")
    cls = SURFACE_TYPES.get(kind)
    if cls is None:
        close = difflib.get_close_matches(kind, sorted(SURFACE_TYPES), n=1, cutoff=0.5)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        r.fail(f"{path}.type", f"unknown surface type {kind!r}{hint} (known: "
                               f"{', '.join(sorted(SURFACE_TYPES))})")
    # a surface the rays land on, other than an aperture, a cylinder or an ideal lens
    landed = takes_clear_rect(cls) and not issubclass(cls, (Aperture, Cylinder, IdealLens))
    # a rectangular clear aperture (clear_rect_mm) on any such surface whose type does not read
    # it itself (set_clear_rect)
    generic_rect = landed and "clear_rect_mm" not in cls.file_fields
    # an elliptical clear aperture or obscuration (clear_ellipse_mm, obscuration_ellipse_mm)
    # on any such surface, an asphere's included (set_clear_ellipse, set_obscuration_ellipse)
    ellipses = {"clear_ellipse_mm", "obscuration_ellipse_mm", "spider_width_mm", "spider_arms",
                "spider_angle_deg"} if landed else set()
    r.keys(s, _COMMON_KEYS | set(cls.file_fields) | ({"clear_rect_mm"} if generic_rect else set())
           | ellipses, path)
    sd = r.get(s, "semi_diameter_mm", path)
    if not sd > 0:
        r.fail(f"{path}.semi_diameter_mm", f"must be > 0 mm, got {sd!r}")
    surf = cls.from_dict(_Entry(r, s, path), sd)
    if generic_rect and "clear_rect_mm" in s:
        rect = r.get(s, "clear_rect_mm", path, "numbers")
        try:
            if len(rect) != 2:
                raise ValueError(f"expected two half-widths (mm), got {rect!r}")
            set_clear_rect(surf, rect)
        except ValueError as e:
            r.fail(f"{path}.clear_rect_mm", str(e))
    for key, setter in (("clear_ellipse_mm", set_clear_ellipse),
                        ("obscuration_ellipse_mm", set_obscuration_ellipse)):
        if key in ellipses and key in s:
            ab = r.get(s, key, path, "numbers")
            try:
                if len(ab) != 2:
                    raise ValueError(f"expected two half-axes [a, b] (mm, along x and y), got "
                                     f"{ab!r}")
                setter(surf, ab)
            except ValueError as e:
                r.fail(f"{path}.{key}", str(e))
            with torch.no_grad():   # the file's semi-diameter stands (a stop's pupil radius)
                surf.semi_diameter.fill_(sd)
    if "spider_width_mm" in ellipses and ("spider_width_mm" in s or "spider_arms" in s):
        # a spider obscuration about the vertex (set_obscuration_spider)
        w = r.get(s, "spider_width_mm", path)
        n = r.get(s, "spider_arms", path)
        ang = r.get(s, "spider_angle_deg", path, default=0.0)
        try:
            set_obscuration_spider(surf, (w, n, math.radians(ang)))
        except ValueError as e:
            r.fail(f"{path}.spider_arms" if "arms" in str(e) else f"{path}.spider_width_mm",
                   str(e))
    return surf


def lens_from_dict(data: dict, source: str = "<dict>") -> Lens:
    """Build a :class:`Lens` from a lens-file dictionary; errors name ``source`` and the field."""
    r = _Reader(source)
    if not isinstance(data, dict):
        r.fail("(top level)", f"expected a JSON object, got {type(data).__name__}")
    r.keys(data, _TOP_KEYS, "")
    fmt = data.get("format", FORMAT_NAME)
    if fmt != FORMAT_NAME:
        r.fail("format", f"expected {FORMAT_NAME!r}, got {fmt!r}")
    version = r.get(data, "version", "", "int", default=FORMAT_VERSION)
    if not 1 <= version <= FORMAT_VERSION:
        r.fail("version", f"unsupported lens-file version {version}: this deeplens reads "
                          f"versions 1 to {FORMAT_VERSION}")
    name = r.get(data, "name", "", "str", default="")
    units = r.check(data.get("units", {}), "units", "object")
    r.keys(units, {"length", "wavelength"}, "units")
    for key, want in (("length", "mm"), ("wavelength", "nm")):
        got = units.get(key, want)
        if got != want:
            r.fail(f"units.{key}", f"unsupported unit {got!r}: deeplens lens files give "
                                   f"lengths in mm and wavelengths in nm (convert the values "
                                   f"and write {want!r})")
    obj = r.check(data.get("object", {}), "object", "object")
    r.keys(obj, {"distance_mm", "medium", "telecentric", "tilt_tangents"}, "object")
    obj_dist = r.get(obj, "distance_mm", "object", "number_or_inf", default=math.inf)
    first = data.get("surfaces")
    first = first[0] if isinstance(first, list) and first else None
    at_break = isinstance(first, dict) and first.get("type") == "coordinate_break"
    if not (obj_dist > 0 or obj_dist < 0 or (obj_dist == 0 and at_break)):
        r.fail("object.distance_mm", f"the object distance must be > 0 mm (or \"inf\"), or < 0 "
                                     f"mm for a virtual object (0: only before a first "
                                     f"coordinate break, at its pivot), got {obj_dist!r}")
    tilt = r.get(obj, "tilt_tangents", "object", "numbers", default=[0.0, 0.0])
    if len(tilt) != 2 or not all(math.isfinite(v) for v in tilt):
        r.fail("object.tilt_tangents", f"expected [tan_x, tan_y], two finite slopes of the "
                                       f"object plane, got {tilt!r}")
    if tilt != [0.0, 0.0] and math.isinf(obj_dist):
        r.fail("object.tilt_tangents", "a tilted object plane needs an object at a finite "
                                       "distance (object.distance_mm)")
    obj_medium = obj.get("medium", "AIR") if isinstance(obj, dict) else "AIR"
    if not isinstance(obj_medium, dict):
        obj_medium = r.get(obj, "medium", "object", "str", default="AIR")
    telecentric = obj.get("telecentric", False)
    if not isinstance(telecentric, bool):
        r.fail("object.telecentric", f"expected true or false, got {telecentric!r}")
    if telecentric and math.isinf(obj_dist):
        r.fail("object.telecentric", "an object-space telecentric lens needs an object at a "
                                     "finite distance (object.distance_mm)")
    ap = r.check(data.get("aperture", {"type": "stop"}), "aperture", "object")
    r.keys(ap, {"type", "value"}, "aperture")
    ap_type = r.get(ap, "type", "aperture", "str")
    if ap_type not in ("stop", "epd", "fno"):
        r.fail("aperture.type", f"expected 'stop', 'epd' (entrance-pupil diameter, mm) or 'fno' "
                                f"(F-number), got {ap_type!r}")
    ap_value = None if ap_type == "stop" else r.get(ap, "value", "aperture")
    if ap_value is not None and not ap_value > 0:
        r.fail("aperture.value", f"the {ap_type} must be > 0, got {ap_value!r}")
    fields = r.get(data, "fields_deg", "", "numbers", default=[0.0])
    wavelengths = r.get(data, "wavelengths_nm", "", "numbers", default=[587.5618])
    if not wavelengths:
        r.fail("wavelengths_nm", "expected at least one wavelength (nm)")
    primary = r.get(data, "primary_wavelength_nm", "", "number", default=None)
    for key, value in (("wavelengths_nm", wavelengths), ("primary_wavelength_nm", primary)):
        if value is not None:
            try:
                check_wavelength_nm(value)
            except ValueError as e:
                r.fail(key, str(e))
    try:
        spec = LensSpec(object_distance_mm=obj_dist, aperture_type=ap_type,
                        aperture_value=ap_value, fields_deg=fields, wavelengths_nm=wavelengths,
                        primary_wavelength_nm=primary)
    except LensError as e:
        r.fail(_SPEC_FIELDS.get(e.key, "(system)"), e.message)
    surf_list = data.get("surfaces")
    if not isinstance(surf_list, list) or not surf_list:
        r.fail("surfaces", "expected a non-empty list of surfaces")
    surfaces, materials, distances, mirrors = [], [], [], []

    def material(spec_str, path, surfaces=()):
        if isinstance(spec_str, dict):
            m = _formula_glass(r, spec_str, path, surfaces)
        else:
            try:
                m = get_material(spec_str)
            except ValueError as e:
                r.fail(path, str(e), surfaces)
        for key, w in (("wavelengths_nm", spec.wavelengths_nm),
                       ("primary_wavelength_nm", spec.primary_wavelength_nm)):
            try:
                check_wavelength_nm(w, m)
            except ValueError as e:
                r.fail(key, f"{e} (used at {path})", surfaces)
        return m

    materials.append(material(obj_medium, "object.medium"))
    for i, s in enumerate(surf_list):
        path = f"surfaces[{i}]"
        try:
            surfaces.append(_surface_from_dict(r, s, path))
        except LensFileError:
            raise
        except ValueError as e:
            r.fail(path, str(e), surfaces=(i,))
        distances.append(r.get(s, "distance_mm", path))
        medium = s.get("material", "AIR") if isinstance(s, dict) else "AIR"
        if not isinstance(medium, dict):
            medium = r.get(s, "material", path, "str", default="AIR")
        if isinstance(medium, str) and medium.strip().upper() == "MIRROR":
            mirrors.append(i)
            materials.append(materials[-1])
        else:
            materials.append(material(medium, f"{path}.material", (i,)))
    stop = data.get("stop")
    if stop is None:
        r.fail("stop", "missing: the lens has no aperture stop (give the index of the stop "
                       "surface)")
    stop = r.check(stop, "stop", "int")
    if not 0 <= stop < len(surfaces):
        r.fail("stop", f"{stop} is not a surface index (0..{len(surfaces) - 1})")
    sensor = data.get("sensor")
    if not isinstance(sensor, dict):
        r.fail("sensor", "missing: expected {\"distance_mm\": ..., \"semi_diameter_mm\": ...}")
    r.keys(sensor, {"distance_mm", "semi_diameter_mm", "virtual_image"}, "sensor")
    d_sensor = r.get(sensor, "distance_mm", "sensor")
    virtual = sensor.get("virtual_image", False)
    if not isinstance(virtual, bool):
        r.fail("sensor.virtual_image", f"expected true or false, got {virtual!r}")
    # the direction of travel after the last surface (Lens.directions: the traced axis; the
    # mirror count's parity unless coordinate breaks turn the beam round)
    with torch.no_grad():
        w = torch.tensor(float(spec.primary_wavelength_nm), dtype=torch.float64)
        forward = travel_directions(surfaces, mirrors, [float(m.n(w)) for m in materials],
                                    float(w))[-1] > 0
    ahead = d_sensor > 0 if forward else d_sensor < 0
    if virtual and (ahead or d_sensor == 0):
        r.fail("sensor.distance_mm", f"a virtual image plane (virtual_image: true) must lie "
                                     f"before the last surface: the distance must be "
                                     f"{'< 0' if forward else '> 0'} mm, got "
                                     f"{d_sensor!r}")
    if not virtual and not ahead:
        after = f" after {len(mirrors)} mirrors" if mirrors else ""
        r.fail("sensor.distance_mm", f"the sensor distance must be "
                                     f"{'> 0' if forward else '< 0'} mm{after}, "
                                     f"got {d_sensor!r}" + ("" if mirrors else
                                     " (a virtual image plane before the last surface needs "
                                     "\"virtual_image\": true in a JSON lens file)"))
    sensor_sd = r.get(sensor, "semi_diameter_mm", "sensor", default=None)
    if sensor_sd is not None and not sensor_sd > 0:
        r.fail("sensor.semi_diameter_mm", f"must be > 0 mm (or left out), got {sensor_sd!r}")
    elements = data.get("elements")
    if elements is not None:
        if not isinstance(elements, list):
            r.fail("elements", f"expected a list of [first, last] surface-index pairs, got "
                               f"{elements!r}")
        for e, pair in enumerate(elements):
            if (not isinstance(pair, list) or len(pair) != 2
                    or any(isinstance(v, bool) or not isinstance(v, int) for v in pair)):
                r.fail(f"elements[{e}]", f"expected [first, last] surface indices, got {pair!r}")
    backward = data.get("backward_gaps", [])
    if not isinstance(backward, list) or any(isinstance(v, bool) or not isinstance(v, int)
                                             for v in backward):
        r.fail("backward_gaps", f"expected a list of surface indices, got {backward!r}")
    try:
        lens = Lens(surfaces, materials, distances, d_sensor, stop, sensor_sd, spec,
                    elements=elements, name=name, mirrors=mirrors, virtual_image=virtual,
                    backward_gaps=backward)
    except LensError as e:
        raise LensFileError(e.message, source=source, key=_SPEC_FIELDS.get(e.key),
                            surfaces=e.surfaces) from e
    except (ValueError, TypeError) as e:
        raise LensFileError(str(e), source=source) from e
    lens.object_telecentric = telecentric
    lens.object_tilt = tilt
    mis = data.get("misalignment")
    if mis is not None:
        if not isinstance(mis, list) or len(mis) != len(lens.elements):
            r.fail("misalignment", f"expected a list of {len(lens.elements)} entries (one per "
                                   f"element), got {mis!r}")
        for e, m in enumerate(mis):
            path = f"misalignment[{e}]"
            r.check(m, path, "object")
            r.keys(m, {"dx_mm", "dy_mm", "tilt_x_rad", "tilt_y_rad"}, path)
            ma = lens.misalignments[e]
            for key, p in (("dx_mm", ma.dx), ("dy_mm", ma.dy), ("tilt_x_rad", ma.tilt_x),
                           ("tilt_y_rad", ma.tilt_y)):
                p.data.fill_(r.get(m, key, path, default=0.0))
    return lens


def lens_to_dict(lens: Lens) -> dict:
    """The lens-file dictionary of ``lens`` (current parameter values, exact floats)."""
    lens = copy.deepcopy(lens).requires_grad_(False)  # plain values, also for trainable lenses
    spec = lens.spec
    ap = {"type": spec.aperture_type}
    if spec.aperture_type != "stop":
        ap["value"] = float(spec.aperture_value)
    surfaces = []
    for i, s in enumerate(lens.surfaces):
        d = s.to_dict()
        rect = clear_rect_of(s)
        if rect is not None and "clear_rect_mm" not in d:
            d["clear_rect_mm"] = list(rect)
        for key, ab in (("clear_ellipse_mm", clear_ellipse_of(s)),
                        ("obscuration_ellipse_mm", obscuration_ellipse_of(s))):
            if ab is not None:
                d[key] = list(ab)
        spi = obscuration_spider_of(s)
        if spi is not None:
            d.update(spider_width_mm=spi[0], spider_arms=spi[1])
            if spi[2] != 0.0:
                d["spider_angle_deg"] = math.degrees(spi[2])
        d["distance_mm"] = float(lens.distances[i])
        d["material"] = "MIRROR" if i in lens.mirrors else _material_json(lens.materials[i + 1],
                                                                           spec)
        surfaces.append(d)
    out = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "name": lens.name,
        "units": {"length": "mm", "wavelength": "nm"},
        "object": {"distance_mm": ("inf" if math.isinf(spec.object_distance_mm)
                                   else float(spec.object_distance_mm)),
                   "medium": _material_json(lens.materials[0], spec)},
        "aperture": ap,
        "fields_deg": [float(f) for f in spec.fields_deg],
        "wavelengths_nm": [float(w) for w in spec.wavelengths_nm],
        "primary_wavelength_nm": float(spec.primary_wavelength_nm),
        "stop": lens.stop_index,
        "surfaces": surfaces,
        "sensor": {"distance_mm": float(lens.d_sensor)},
        "elements": [list(e) for e in lens.elements],
    }
    if getattr(lens, "object_telecentric", False):
        out["object"]["telecentric"] = True
    if getattr(lens, "object_tilt", (0.0, 0.0)) != (0.0, 0.0):
        out["object"]["tilt_tangents"] = list(lens.object_tilt)
    if lens.sensor_semi_diameter is not None:
        out["sensor"]["semi_diameter_mm"] = float(lens.sensor_semi_diameter)
    if lens.virtual_image:
        out["sensor"]["virtual_image"] = True
    if not all(m.is_identity() for m in lens.misalignments):
        out["misalignment"] = [m.to_dict() for m in lens.misalignments]
    if lens.backward_gaps:
        out["backward_gaps"] = sorted(lens.backward_gaps)
    return out


def _material_json(m, spec):
    """``m`` as a lens file writes it: its spec string where :func:`get_material` gives back the
    same indices at the lens's wavelengths (to 1e-12), else its formula (module docstring)."""
    from .agf import AGFGlass
    from .vendor_glass import BuchdahlGlass

    name = m.to_spec()
    if not isinstance(m, (AGFGlass, BuchdahlGlass)):
        return name
    waves = sorted({float(w) for w in spec.wavelengths_nm} | {float(spec.primary_wavelength_nm)})
    try:
        same = get_material(name)
        w = torch.tensor(waves, dtype=torch.float64)
        if bool(((same.n(w).double() - m.n(w).double()).abs() <= 1e-12).all()):
            return name
    except ValueError:
        pass
    out = {"glass": m.name, "catalogue": str(getattr(m, "catalogue", "") or "")}
    if isinstance(m, AGFGlass):
        out["agf_formula"] = int(m.formula)
        out["coefficients"] = [float(c) for c in m.coefficients]
        if hasattr(m, "air_temperature_c"):   # an absolute index taken relative to air
            out["absolute_relative_to_air_c"] = float(m.air_temperature_c)
    else:
        out["buchdahl"] = [float(m.n0), float(m.nu1), float(m.nu2)]
        out["lambda0_um"] = float(m.lambda0_um)
    lo, hi = m.wavelength_range_nm
    out["wavelength_range_nm"] = [float(lo), float(hi)]
    return out


def _formula_glass(r: _Reader, d: dict, path: str, surfaces=()):
    """The glass of a ``{"glass": ..., "agf_formula" | "buchdahl": ...}`` material entry."""
    from .agf import AGFGlass
    from .vendor_glass import BuchdahlGlass

    r.keys(d, {"glass", "catalogue", "agf_formula", "coefficients", "buchdahl", "lambda0_um",
               "wavelength_range_nm", "absolute_relative_to_air_c"}, path)
    name = r.get(d, "glass", path, "str")
    cat = r.get(d, "catalogue", path, "str", default="")
    rng = r.get(d, "wavelength_range_nm", path, "numbers")
    if len(rng) != 2 or not 0 < rng[0] < rng[1]:
        r.fail(f"{path}.wavelength_range_nm", f"expected [lo, hi] in nm with 0 < lo < hi, got "
                                              f"{rng!r}", surfaces)
    has_agf, has_b = "agf_formula" in d, "buchdahl" in d
    if has_agf == has_b:
        r.fail(path, "expected exactly one of 'agf_formula' (with 'coefficients') or "
                     "'buchdahl' for a glass given by its formula", surfaces)
    try:
        if has_agf and "absolute_relative_to_air_c" in d:
            from .misc_glass import AirRelativeGlass

            m = AirRelativeGlass(name, r.get(d, "agf_formula", path, "int"),
                                 r.get(d, "coefficients", path, "numbers"), tuple(rng),
                                 catalogue=cat, air_temperature_c=r.get(
                                     d, "absolute_relative_to_air_c", path))
        elif has_agf:
            m = AGFGlass(name, r.get(d, "agf_formula", path, "int"),
                         r.get(d, "coefficients", path, "numbers"), tuple(rng), catalogue=cat)
        else:
            b = r.get(d, "buchdahl", path, "numbers")
            if len(b) != 3:
                r.fail(f"{path}.buchdahl", f"expected [n0, nu1, nu2], got {b!r}", surfaces)
            m = BuchdahlGlass(name, *b, catalogue=cat,
                              lambda0_um=r.get(d, "lambda0_um", path, default=0.574))
            m.wavelength_range_nm = tuple(rng)
    except ValueError as e:
        r.fail(path, str(e), surfaces)
    w = torch.tensor([float(rng[0]), 0.5 * (rng[0] + rng[1]), float(rng[1])],
                     dtype=torch.float64)
    n = m.n(w)
    if not bool(torch.isfinite(n).all()) or not bool((n >= 1.0).all()):
        r.fail(path, f"glass {name!r}: its formula gives indices {n.tolist()} over "
                     f"{rng[0]:g}-{rng[1]:g} nm; expected finite indices >= 1", surfaces)
    return m


def save_lens(lens: Lens, path) -> None:
    """Write ``lens`` as JSON, atomically (write to a temporary file, then rename); a path
    ending in ``.zmx`` writes a Zemax file (:func:`~.zmx.write_zmx`), one in ``.seq`` a CODE V
    file (:func:`~.codev.write_seq`)."""
    path = Path(path)
    if path.suffix.lower() == ".zmx":
        from .zmx import write_zmx

        return write_zmx(lens, path)
    if path.suffix.lower() == ".seq":
        from .codev import write_seq

        return write_seq(lens, path)
    tmp = temp_path(path)
    try:  # a name of its own: two writers of one lens file never share a temporary file
        with open(tmp, "w") as f:
            json.dump(lens_to_dict(lens), f, indent=1)
            f.write("\n")
        replace(tmp, path)   # the umask's mode, not mkstemp's 0600
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def read_json(path) -> Lens:
    """Read a deeplens JSON lens file (errors name the file and the field, or line and column
    for invalid JSON)."""
    path = Path(path)
    try:
        data = json.loads(read_file_bytes(path).decode("utf-8"))
    except UnicodeDecodeError as e:
        raise LensFileError(f"not a UTF-8 text file ({e.reason} at byte {e.start})",
                            source=path) from e
    except json.JSONDecodeError as e:
        raise LensFileError(f"invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}",
                            source=path, line=e.lineno, column=e.colno) from e
    except RecursionError:
        raise LensFileError("the JSON is nested too deeply to read (a lens file is a few "
                            "levels deep)", source=path) from None
    except ValueError as e:  # e.g. an integer literal with more than 4300 digits
        raise LensFileError(f"unreadable JSON number: {e}", source=path) from None
    return lens_from_dict(data, source=str(path))
