r"""CODE V zoom lenses (``ZOO``): one :class:`~deeplens.optics.lens.Lens` per zoom position.

A zoomed ``.seq`` file gives the number of positions and, for each zoomed parameter, its value
in every position::

    ZOO 3                          ! three zoom positions
    ZOO THI S2 10.0 20.0 30.0      ! surface 2's thickness in positions 1, 2, 3
    ZOO EPD 10.0 8.0 6.0           ! the entrance pupil diameter
    ZOO YAN F2 5.0 3.0 2.0         ! the second field's angle (degrees)

Read: ``ZOO n`` (the count; once, before or after the zoomed parameters) and ``ZOO P [Sk|Fk]
v1 ... vn`` for the surface parameters ``THI``, ``RDY``, ``CUY`` (``Sk``: CODE V's surface
number, ``SO`` the object, ``SI`` the image, whose thickness is its defocus), the system aperture
``EPD`` or ``FNO`` (the kind the file's own aperture line gives), and the fields ``YAN``, ``YOB``,
``YIM`` (``Fk``: the k-th field, from 1; without it the file must have one field), each with
exactly ``n`` values.  Position ``N`` is the file with each zoomed parameter's ``N``-th value in
place of the one the file's own commands give (those are CODE V's values of the current
position, a parameter not zoomed has the same value in every position).  Lengths are in the
file's ``DIM`` unit, as everywhere.

Sources: neither reader deeplens checks its CODE V files against reads ``ZOO`` (rayoptics 0.9.8's
``rayoptics/codev/cmdproc.py`` has no ``ZOO`` command in its ``tla_mapping.csv``; optiland's
``fileio/codev`` neither), and no CODE V manual page on ``ZOO`` was found in the searched
corpora: the syntax above is the one real CODE V zoom files are written in per the issue this
reader answers (``ZOO THI S5 10 20 30``, ``ZOO n``), with its surface and field qualifiers in the
form CODE V's other commands use (``PIK THI S3 ...``; ``Z1`` position qualifiers of ``PIK``).
Each position is checked against the same file with that position's values typed in by hand,
which rayoptics does read (``tests/optics/io/test_codev_zoom.py``).

Refused, each with the file and line: any other zoomed parameter (glasses, decenters, aspheric
terms, wavelengths, apertures of surfaces, ...), a count other than ``n`` values, ``ZOO`` lines
without ``ZOO n``, a surface or field that does not exist, a zoomed ``EPD`` in a file whose
aperture is ``FNO`` (or the reverse).
"""

from __future__ import annotations

import re

__all__ = ["ZOOM_PARAMETERS", "zoom_command", "apply_zoom", "zoom_count", "surface_value",
           "set_surface_value"]

_SURFACE = ("THI", "RDY", "CUY")
_PUPIL = ("EPD", "FNO")
_FIELD = ("YAN", "YOB", "YIM")
#: the parameters a ``ZOO`` line may zoom
ZOOM_PARAMETERS = _SURFACE + _PUPIL + _FIELD


def surface_value(s: dict, code: str) -> float:
    """A surface record's value under its command ``code``: ``THI`` the thickness, ``CUY`` the
    curvature, ``RDY`` the radius (0 for a flat surface); lens units."""
    if code == "THI":
        return s["t"]
    if code == "CUY":
        return s["c"]
    return 0.0 if s["c"] == 0 else 1.0 / s["c"]


def set_surface_value(s: dict, code: str, v: float) -> None:
    """Set a surface record's ``THI``, ``CUY`` or ``RDY`` (a radius 0: flat) to ``v``
    (:func:`surface_value`'s inverse)."""
    if code == "THI":
        s["t"] = v
    elif code == "CUY":
        s["c"] = v
    else:
        s["c"] = 0.0 if v == 0 else 1.0 / v


def zoom_command(zoom: dict, args: list[str], line: int, nums, fail) -> None:
    """Record one ``ZOO`` command in ``zoom`` (``{"n": (count, line) | None, "params": [...]}``).

    Args:
        zoom: the reader's zoom record (updated).
        args: the tokens after ``ZOO``.
        line: the file line (1-based).
        nums: the reader's ``nums(args, line, what, n)``.
        fail: the reader's ``fail(line, message)``.
    """
    if len(args) == 1 and re.fullmatch(r"\d+", args[0]):
        n = int(args[0])
        if n < 1:
            fail(line, f"ZOO {args[0]}: expected a number of zoom positions >= 1")
        if zoom["n"] is not None and zoom["n"][0] != n:
            fail(line, f"ZOO {n}: the number of zoom positions is already {zoom['n'][0]} (line "
                       f"{zoom['n'][1]})")
        zoom["n"] = (n, line)
        return
    if not args:
        fail(line, "ZOO: expected 'ZOO n' (the number of positions) or 'ZOO P [Sk|Fk] v1 ... vn'")
    p = args[0].upper()
    if p not in ZOOM_PARAMETERS:
        fail(line, f"ZOO {args[0]}: zooming {args[0]} is not supported (deeplens applies zoomed "
                   f"{', '.join(ZOOM_PARAMETERS)}); expected one of them")
    rest = args[1:]
    target = None
    if p in _SURFACE:
        q = rest[0].upper() if rest else ""
        m = re.fullmatch(r"S(\d+|O|I)", q)
        if m is None:
            fail(line, f"ZOO {p}: expected a surface (Sk, SO or SI) before the values, got "
                       f"{' '.join(rest[:1]) or 'none'}")
        target = {"O": 0, "I": -1}.get(m.group(1), None)
        target = int(m.group(1)) if target is None else target
        rest = rest[1:]
    elif p in _FIELD and rest and re.fullmatch(r"F\d+", rest[0].upper()):
        target = int(rest[0][1:])
        rest = rest[1:]
    vals = nums(rest, line, f"ZOO {p} (one value per zoom position)")
    zoom["params"].append((p, target, vals, line))


def zoom_count(zoom: dict) -> int:
    """The number of zoom positions (1 for a file without ``ZOO n``)."""
    return zoom["n"][0] if zoom["n"] is not None else 1


def apply_zoom(rd, position: int) -> None:
    """Put zoom position ``position`` (from 1) of the reader ``rd``'s ``ZOO`` lines in place of
    the file's own values: surface records' ``t``/``c``, ``rd.pupil``, ``rd.fields``.  Checks every
    ``ZOO`` line (counts, surfaces, fields) whatever the position."""
    zoom, fail = rd.zoom, rd.fail
    if not zoom["params"] and zoom["n"] is None:
        return
    if zoom["n"] is None:
        fail(zoom["params"][0][3], "ZOO values with no 'ZOO n' line (the number of zoom "
                                   "positions)")
    n, n_line = zoom["n"]
    if not 1 <= position <= n:
        fail(n_line, f"zoom position {position} requested: the file has {n} (ZOO {n}); "
                     f"expected 1 .. {n}")
    surfs = rd.surfs
    for p, target, vals, line in zoom["params"]:
        if len(vals) != n:
            fail(line, f"ZOO {p}: {len(vals)} values for the {n} zoom positions of line {n_line}; "
                       f"expected one per position")
        v = vals[position - 1]
        if p in _SURFACE:
            if not -len(surfs) <= target < len(surfs) or (target == -1 and
                                                            surfs[-1]["kind"] != "SI"):
                fail(line, f"ZOO {p}: surface S{target if target >= 0 else 'I'} does not exist "
                           f"(SO .. S{len(surfs) - 2}, SI)")
            set_surface_value(surfs[target], p, v)
        elif p in _PUPIL:
            if rd.pupil is None or rd.pupil[0] != p:
                have = rd.pupil[0] if rd.pupil is not None else "no system aperture"
                fail(line, f"ZOO {p}: the file's aperture is {have}; expected ZOO of that kind")
            rd.pupil = (p, v, rd.pupil[2])
        else:
            if p not in rd.fields:
                fail(line, f"ZOO {p}: the file gives no {p} fields; expected ZOO of the file's "
                           f"field kind ({', '.join(sorted(rd.fields)) or 'none'})")
            fv, f_line = rd.fields[p]
            k = target
            if k is None:
                if len(fv) != 1:
                    fail(line, f"ZOO {p} without Fk: the file has {len(fv)} fields; expected "
                               f"'ZOO {p} Fk v1 ... v{n}'")
                k = 1
            if not 1 <= k <= len(fv):
                fail(line, f"ZOO {p} F{k}: the file has {len(fv)} fields (F1 .. F{len(fv)})")
            fv = list(fv)
            fv[k - 1] = v
            rd.fields[p] = (fv, f_line)
