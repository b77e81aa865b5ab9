"""Human labels of lens parameters for figures and tables: ``misalignments.0.tilt_x`` ->
``element 1 tilt x`` in mrad.

Each parameter kind is shown in the unit a tolerance is written in: decenters and spacings
in µm, tilts in mrad, curvatures in 1/m (``surfaces.i.c`` is in 1/mm).  Each display unit is
10^-3 of the parameter's own unit (mm, rad, 1/mm), so a sensitivity in mm of RMS spot per unit
of the parameter equals, number for number, µm of RMS spot per display unit:

    ∂ε/∂θ [µm per display unit] = 10^3 µm/mm × 10^-3 × ∂ε/∂θ [mm per unit] = ∂ε/∂θ [mm per unit]

Elements and surfaces are numbered from 1 (the optical designer's habit); only glass elements
are counted (the stop, an element of :attr:`Lens.elements` too, is skipped).
"""

from __future__ import annotations

__all__ = ["DISPLAY_PER_UNIT", "parameter_label"]

#: display unit per kind, and how many display units one parameter unit is
DISPLAY_PER_UNIT = {"decenter": ("µm", 1e3), "tilt": ("mrad", 1e3), "spacing": ("µm", 1e3),
                    "curvature": ("1/m", 1e3), "other": ("unit", 1.0)}


def _glass_ordinal(lens, e: int) -> int:
    """1-based number of element ``e`` among the lens's glass elements."""
    from ..optics.materials import Air

    k = 0
    for i, (a, b) in enumerate(lens.elements):
        if any(not isinstance(lens.materials[j + 1], Air) for j in range(a, b + 1)):
            k += 1
        if i == e:
            return max(k, 1)
    return e + 1


def parameter_label(lens, name: str) -> tuple[str, str, str]:
    """``(label, unit, kind)`` of the parameter ``name``: e.g. ``("element 1 tilt x", "mrad",
    "tilt")``, ``("spacing surface 2 to 3", "µm", "spacing")``, ``("surface 3 curvature", "1/m",
    "curvature")``; an unknown name is its own label (kind ``"other"``).  ``kind`` keys
    :data:`DISPLAY_PER_UNIT` (a value in the parameter's unit times its factor is in ``unit``).
    """
    p = name.split(".")
    if p[0] == "misalignments" and len(p) == 3 and p[1].isdigit():
        el = f"element {_glass_ordinal(lens, int(p[1]))}"
        if p[2] in ("dx", "dy"):
            return f"{el} decenter {p[2][1]}", "µm", "decenter"
        if p[2].startswith("tilt_"):
            return f"{el} tilt {p[2][5:]}", "mrad", "tilt"
    if p[0] == "distances" and len(p) == 2 and p[1].isdigit():
        i = int(p[1])
        return f"spacing surface {i} to {i + 1}", "µm", "spacing"
    if p[0] == "surfaces" and len(p) == 3 and p[1].isdigit() and p[2] == "c":
        return f"surface {int(p[1]) + 1} curvature", "1/m", "curvature"
    return name, "unit", "other"
