"""The prescription as a lens-data-editor table: one row per surface, object to image.

Columns follow the lens-design programs' editors:

* ``surface``: ``OBJ``, ``0 .. N-1`` (``STO`` marked beside the stop) and ``IMA``;
* ``type``: the lens-file type (``asphere``, ``aperture``, ``xy_polynomial`` ...);
* ``radius`` (mm): the paraxial radius of curvature ``R = 1 / c`` (``inf`` for a flat vertex;
  ``surface.radius``), ``c`` the vertex curvature (``curvature`` column, 1/mm);
* ``thickness`` (mm): the axial gap from this vertex to the next (to the sensor for the last
  surface; the object distance on the ``OBJ`` row);
* ``material``: the medium after the surface (``AIR``, a catalogue glass, ``n_d/V_d``);
* ``semi_diameter`` (mm): the clear semi-aperture; ``conic``: ``k`` where the type has one;
* ``extra``: what else the type's lens-file entry holds (aspheric coefficients, polynomial
  terms ...), ``key=value`` with long lists shortened; on the ``OBJ`` row, a tilted object
  plane's slopes (``Lens.object_tilt``).

Nothing here changes the lens; the values are read without gradient.
"""

from __future__ import annotations

import math

import torch

__all__ = ["prescription", "prescription_table"]


def _num(v):
    return None if v is None else float(v.detach() if torch.is_tensor(v) else v)


_COLUMNS = {"type", "semi_diameter_mm", "curvature_per_mm", "conic", "distance_mm", "material"}


def _extra(entry: dict, keep: int = 6) -> str:
    def short(v):
        if isinstance(v, (list, tuple)):
            body = ", ".join(short(x) for x in v[:keep])
            return f"[{body}{', ...' if len(v) > keep else ''}]" + (
                f"({len(v)})" if len(v) > keep else "")
        return f"{v:.6g}" if isinstance(v, float) else str(v)
    return ", ".join(f"{k}={short(v)}" for k, v in entry.items() if k not in _COLUMNS)


def prescription(lens) -> list[dict]:
    """The rows of the table (module docstring) as dictionaries, ``OBJ`` first, ``IMA`` last."""
    rows = [{"surface": "OBJ", "type": "object", "radius": math.inf, "curvature": 0.0,
             "thickness": float(lens.spec.object_distance_mm),
             "material": lens.materials[0].name, "semi_diameter": None, "conic": None,
             "extra": ""}]
    tilt = getattr(lens, "object_tilt", (0.0, 0.0))
    if tilt != (0.0, 0.0):   # a tilted object plane, z = z_obj + tan_x x + tan_y y
        rows[0]["extra"] = f"tan_x={tilt[0]:.6g}, tan_y={tilt[1]:.6g}"
    n = len(lens.surfaces)
    with torch.no_grad():
        for i, s in enumerate(lens.surfaces):
            c = float(s.paraxial_curvature())
            gap = lens.distances[i + 1] if i + 1 < n else lens.d_sensor
            k = getattr(s, "k", None)
            extra = _extra(s.to_dict())
            rows.append({"surface": f"{i}" + (" STO" if i == lens.stop_index else ""),
                         "type": s.type_name, "radius": s.radius, "curvature": c,
                         "thickness": _num(gap), "material": lens.materials[i + 1].name,
                         "semi_diameter": _num(s.semi_diameter),
                         "conic": _num(k) if isinstance(k, torch.Tensor) else None,
                         "extra": extra})
    rows.append({"surface": "IMA", "type": "sensor", "radius": math.inf, "curvature": 0.0,
                 "thickness": None, "material": "", "semi_diameter": lens.sensor_semi_diameter,
                 "conic": None, "extra": ""})
    return rows


def _fmt(v, width: int) -> str:
    if v is None:
        return " " * (width - 1) + "-"
    if isinstance(v, str):
        return f"{v:>{width}}"
    if math.isinf(v):
        return f"{'Infinity' if v > 0 else '-Infinity':>{width}}"
    return f"{v:>{width}.6g}"


def prescription_table(lens, extra: bool = True) -> str:
    """The table as text: a title line, then one line per row (module docstring)."""
    head = (f"{'surf':>7} {'type':>14} {'radius':>12} {'thickness':>12} {'material':>16} "
            f"{'semi-diam':>10} {'conic':>10}")
    lines = [f"{lens.name or 'lens'}", f"  lengths in mm; stop = surface {lens.stop_index}; "
             f"radius = 1/curvature; thickness = gap to the next vertex", head]
    for r in prescription(lens):
        line = (f"{r['surface']:>7} {r['type']:>14} {_fmt(r['radius'], 12)} "
                f"{_fmt(r['thickness'], 12)} {r['material'][:16]:>16} "
                f"{_fmt(r['semi_diameter'], 10)} {_fmt(r['conic'], 10)}")
        if extra and r["extra"]:
            line += f"   {r['extra']}"
        lines.append(line)
    return "\n".join(lines)
