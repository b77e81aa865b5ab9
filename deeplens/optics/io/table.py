"""Reader for the paper authors' lens table format (vccimaging/DiffOptics ``.txt``).

Line 1 is a title, line 2 the header ``type distance roc diameter material``; then one row per
surface ``TYPE DISTANCE ROC DIAMETER MATERIAL [extra ...]`` with types

* ``O`` object side (distance ignored: the object is at infinity unless ``object_distance_mm``)
* ``S`` sphere / conic / even asphere; extras ``conic a4 a6 ...``
* ``A`` aperture stop plane (material ``OCCLUDER`` = air)
* ``X`` XY polynomial; extras ``b a0 a1 ...`` (``b`` the z^2 coefficient, then 1, y, x, y^2, ...)
* ``B`` B-spline on deeplens' fixed uniform knots; extras ``nx ny c_00 c_01 ... c_(nx-1)(ny-1)``
  (knots in the authors' own B rows are not supported and are reported as such)
* ``I`` image plane: its distance is the sensor distance, its diameter the sensor diagonal

``DISTANCE`` is the axial gap from the previous row's vertex, ``DIAMETER`` the full clear
diameter, ``MATERIAL`` the medium after the surface.  ``scale`` multiplies every length (for
prescriptions in normalised units).  Each error names the file and line.
"""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import LensFileError
from ..materials import get_material
from ..surfaces.xy_polynomial import xy_terms
from .filecheck import read_file_bytes
from .lensfile import lens_from_dict

__all__ = ["read_table", "table_to_dict"]

_TYPES = {"O", "S", "A", "X", "B", "I"}


def _at(path, line, key=None):
    """An error factory for ``path`` (and ``line``): ``raise _at(path, 3)("message")``."""
    return lambda message: LensFileError(message, source=path, line=line, key=key)


def _num(tok, at, what):
    try:
        v = float(tok)
    except ValueError:
        raise at(f"column {what!r} must be a number, got {tok!r}") from None
    if not math.isfinite(v):
        raise at(f"column {what!r} must be finite, got {tok!r}")
    return v


def table_to_dict(path, *, scale: float = 1.0, stop_index: int | None = None,
                  object_distance_mm: float = math.inf, fields_deg=(0.0,),
                  wavelengths_nm=(587.5618,), name: str | None = None) -> dict:
    """Parse a table file into a lens-file dictionary (see :mod:`.lensfile`).

    Args:
        path: the ``.txt`` file.
        scale: multiply all lengths (and divide curvatures) by this factor.
        stop_index: surface index to use as the stop when the file has no ``A`` row.
        object_distance_mm, fields_deg, wavelengths_nm: the system data the format lacks.
        name: title (default: line 1).
    """
    return _parse(path, scale=scale, stop_index=stop_index,
                  object_distance_mm=object_distance_mm, fields_deg=fields_deg,
                  wavelengths_nm=wavelengths_nm, name=name)[0]


def _parse(path, *, scale, stop_index, object_distance_mm, fields_deg, wavelengths_nm, name):
    """``(lens-file dict, {"surfaces[i]": line number, "sensor": line number})``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"lens file not found: {path}")
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise LensFileError(f"scale must be a positive number, got {scale!r}", source=path,
                            key="scale")
    raw = read_file_bytes(path)
    try:
        if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
            text = raw.decode("utf-16")
        else:
            text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise _at(path, None)(f"not a UTF-8 or UTF-16 text file ({e.reason} at byte "
                              f"{e.start})") from None
    lines = text.splitlines()
    if len(lines) < 3:
        raise _at(path, None)(f"expected a title line, a header line and surface rows, got "
                              f"{len(lines)} line(s)")
    header = lines[1].split()
    if not header or header[0].lower() != "type":
        raise _at(path, 2)(f"expected the header 'type distance roc diameter "
                           f"material' on line 2, got {lines[1].strip()!r}")
    surfaces, obj_medium, sensor, stop = [], "AIR", None, None
    where_of = {}
    for ln, line in enumerate(lines[2:], start=3):
        toks = line.split()
        if not toks or toks[0].startswith("#"):
            continue
        at = _at(path, ln)
        kind = toks[0].upper()
        if kind not in _TYPES:
            raise at(f"unknown surface type {toks[0]!r}; expected one of "
                     f"O, S, A, X, B, I")
        if len(toks) < 5:
            names = ["type", "distance", "roc", "diameter", "material"]
            raise at(f"expected 5 columns (type distance roc diameter "
                     f"material), got {len(toks)}; missing {names[len(toks):]}")
        dist = _num(toks[1], at, "distance") * scale
        roc = _num(toks[2], at, "roc") * scale
        diam = _num(toks[3], at, "diameter") * scale
        mat = toks[4]
        extra = [_num(t, at, f"extra {j + 1}") for j, t in enumerate(toks[5:])]
        if kind != "I":
            try:
                get_material(mat)
            except ValueError as e:
                raise at(f"{e}") from None
        if kind == "O":
            obj_medium = mat
            continue
        if kind == "I":
            if sensor is not None:
                raise at("a second image (I) row")
            if diam < 0:
                raise at(f"diameter must be >= 0 mm (0: unbounded sensor), "
                         f"got {toks[3]!r}")
            sensor = {"distance_mm": dist}
            if diam > 0:
                sensor["semi_diameter_mm"] = diam / 2
            where_of["sensor"] = ln
            continue
        if sensor is not None:
            raise at("a surface row after the image (I) row")
        if not diam > 0:
            raise at(f"diameter must be > 0 mm, got {toks[3]!r}")
        s = {"distance_mm": dist, "semi_diameter_mm": diam / 2, "material": mat.upper()
             if "/" not in mat else mat}
        if kind == "S":
            s["type"] = "asphere"
            s["curvature_per_mm"] = 0.0 if roc == 0 else 1.0 / roc
            if extra:
                s["conic"] = extra[0]
                # a_{2i} multiplies r^{2i}: scale lengths by (scale)^(1-2i)
                s["aspheric"] = [a * scale ** (1 - 2 * (i + 2)) for i, a in enumerate(extra[1:])]
            if roc == 0 and not extra:
                s["type"] = "plane"
                del s["curvature_per_mm"]
        elif kind == "A":
            if stop is not None:
                raise at("a second aperture stop (A row)")
            stop = len(surfaces)
            s["type"] = "aperture"
            if mat.upper() == "OCCLUDER":
                s["material"] = "AIR"
        elif kind == "X":
            if len(extra) < 2:
                raise at("an X row needs 'b a0 [a1 ...]' after the material")
            n = len(extra) - 1
            J = (math.isqrt(8 * n + 1) - 3) // 2
            if (J + 1) * (J + 2) // 2 != n:
                raise at(f"an X row needs b and (J+1)(J+2)/2 coefficients "
                         f"(1, 3, 6, 10, ...), got {n}")
            s["type"] = "xy_polynomial"
            s["b"] = extra[0] / scale
            s["coefficients"] = [a * scale ** (1 - (i + j)) for a, (i, j) in
                                 zip(extra[1:], xy_terms(J))]
        elif kind == "B":
            if len(extra) < 2 or extra[0] != int(extra[0]) or extra[1] != int(extra[1]):
                raise at("a B row needs 'nx ny c_00 ... ' (deeplens' uniform "
                         "knots); knot vectors are not supported")
            nx, ny = int(extra[0]), int(extra[1])
            if len(extra) - 2 != nx * ny:
                raise at(f"a B row with nx={nx}, ny={ny} needs {nx * ny} "
                         f"coefficients, got {len(extra) - 2}")
            c = [v * scale for v in extra[2:]]
            s["type"] = "bspline"
            s["coefficients"] = [c[i * ny:(i + 1) * ny] for i in range(nx)]
        where_of[f"surfaces[{len(surfaces)}]"] = ln
        surfaces.append(s)
    if not surfaces:
        raise _at(path, None)("no surface rows")
    if sensor is None:
        raise _at(path, None)("no image (I) row: the sensor distance is unknown")
    if stop is None:
        if stop_index is None:
            raise _at(path, None, "stop_index")("no aperture stop (no 'A' row); pass stop_index "
                                                "to use a surface's clear aperture as the stop")
        if isinstance(stop_index, bool) or not isinstance(stop_index, int) or not (
                0 <= stop_index < len(surfaces)):
            raise _at(path, None, "stop_index")(
                f"{stop_index!r} is not a surface index (0..{len(surfaces) - 1}: the rows after "
                f"O, not counting I)")
        stop = stop_index
    elif stop_index is not None and stop_index != stop:
        raise _at(path, where_of[f"surfaces[{stop}]"], "stop_index")(
            f"the file's A row is surface {stop}, but stop_index={stop_index} was passed")
    return {
        "format": "deeplens-lens", "version": 1,
        "name": name if name is not None else lines[0].strip(),
        "object": {"distance_mm": object_distance_mm, "medium": obj_medium.upper()},
        "aperture": {"type": "stop"},
        "fields_deg": list(fields_deg), "wavelengths_nm": list(wavelengths_nm),
        "stop": stop, "surfaces": surfaces, "sensor": sensor,
    }, where_of


def read_table(path, *, scale: float = 1.0, stop_index: int | None = None,
               object_distance_mm: float = math.inf, fields_deg=(0.0,),
               wavelengths_nm=(587.5618,), name: str | None = None):
    """Read a table file into a :class:`~deeplens.optics.lens.Lens` (options: see
    :func:`table_to_dict`).  Errors about a surface name the file and the surface's line."""
    d, where_of = _parse(path, scale=scale, stop_index=stop_index,
                         object_distance_mm=object_distance_mm, fields_deg=fields_deg,
                         wavelengths_nm=wavelengths_nm, name=name)
    try:
        return lens_from_dict(d, source=str(path))
    except LensFileError as e:
        raise _locate(e, path, where_of) from e


def _locate(e: LensFileError, path, where_of: dict) -> LensFileError:
    """The error ``e`` of the lens built from the table, placed at the line of the surfaces it
    concerns (``e.surfaces``), or of the I row for a sensor field, plus the rows it names."""
    keys = [f"surfaces[{i}]" for i in dict.fromkeys(e.surfaces) if f"surfaces[{i}]" in where_of]
    if not keys and e.key is not None and e.key.split(".")[0] == "sensor" and "sensor" in where_of:
        keys = ["sensor"]
    if not keys:
        return e
    rows = ", ".join(f"{k.replace('surfaces[', 'surface ').rstrip(']')} is line {where_of[k]}"
                     for k in keys)
    body = f"{e.key}: {e.message}" if e.key else e.message
    return LensFileError(f"{body} ({rows})", source=path, line=where_of[keys[-1]],
                         surfaces=e.surfaces)
