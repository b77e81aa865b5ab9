"""Building the trainable lens from configuration: which parameters train, and their scales.

Parameters are addressed by their ``named_parameters`` names, e.g. ``surfaces.4.a.6`` (the
``x^3``... coefficient of an XY polynomial), ``surfaces.1.a.0`` (a4), ``d_sensor``.  Glob
patterns are allowed (``surfaces.4.a.*``).

Learning rates are given in *millimetres of sag* and converted per parameter, so that one Adam
step of size ``lr`` changes the surface by about ``lr`` mm at its rim whatever the parameter's
units: a coefficient of ``x^i y^j`` scales by ``R^-(i+j)``, an even asphere ``a_2k`` by
``R^-2k``, a curvature by ``2 / R^2`` (``R`` the semi-diameter); distances and misalignment
are already in mm (tilts: 1/R rad).
"""

from __future__ import annotations

import copy
import fnmatch
import inspect
from pathlib import Path

import torch

from ..optics.io import load_lens
from ..optics.io.lensfile import LensFileError
from ..optics.io.table import read_table
from ..optics.surfaces import Asphere, BSpline, XYPolynomial

__all__ = ["build_lens", "set_trainable", "parameter_scale", "optics_param_groups",
           "cubic_phase_plate", "surface_height_map"]


def set_trainable(lens, patterns) -> list[str]:
    """Unfreeze the parameters matching ``patterns``; returns their names.

    Raises:
        ValueError: a pattern matches no parameter (the message lists the available names).
    """
    names = [n for n, _ in lens.named_parameters()]
    chosen = []
    for pat in patterns or []:
        hits = [n for n in names if fnmatch.fnmatchcase(n, pat)]
        if not hits:
            raise ValueError(f"lens.trainable: {pat!r} matches no lens parameter; available: "
                             f"{', '.join(names)}")
        chosen += [h for h in hits if h not in chosen]
    params = dict(lens.named_parameters())
    for n in names:
        params[n].requires_grad_(n in chosen)
    return chosen


def parameter_scale(lens, name: str) -> float:
    """mm of sag per unit of the parameter ``name`` (module docstring)."""
    parts = name.split(".")
    if parts[0] == "surfaces":
        s = lens.surfaces[int(parts[1])]
        R = float(s.semi_diameter)
        if isinstance(s, XYPolynomial) and parts[2] == "a":
            i, j = s.terms[int(parts[3])]
            return R ** (i + j)
        if isinstance(s, Asphere) and parts[2] == "a":
            return R ** (2 * int(parts[3]) + 4)
        if isinstance(s, Asphere) and parts[2] == "c":
            return R * R / 2
        if isinstance(s, BSpline):
            return 1.0
        return 1.0
    if parts[0] == "misalignments" and parts[-1].startswith("tilt"):
        return float(max(s.semi_diameter for s in lens.surfaces))
    return 1.0


def optics_param_groups(lens, lr_mm: float) -> list[dict]:
    """One Adam parameter group per trainable lens parameter, ``lr = lr_mm / scale``."""
    return [{"params": [p], "lr": lr_mm / parameter_scale(lens, n), "name": f"lens.{n}"}
            for n, p in lens.named_parameters() if p.requires_grad]


def cubic_phase_plate(lens, surface_index: int, alpha_mm: float) -> None:
    """Set an XY-polynomial surface to the Dowski-Cathey cubic phase plate
    ``z = α ((x/R)^3 + (y/R)^3)``, ``α`` the sag in mm at the rim (on the x and y axes)."""
    s = lens.surfaces[surface_index]
    if not isinstance(s, XYPolynomial) or s.order < 3:
        raise ValueError(f"surface {surface_index} is not an XY polynomial of order >= 3")
    R = float(s.semi_diameter)
    with torch.no_grad():
        for k, (i, j) in enumerate(s.terms):
            s.a[k].zero_()
            if (i, j) in ((3, 0), (0, 3)):
                s.a[k].fill_(alpha_mm / R ** 3)


def build_lens(path: str, trainable=(), dtype: str = "float32", plate: str | None = None,
               plate_surface: int | None = None, plate_alpha_mm: float = 0.0,
               table_options: dict | None = None):
    """Load a lens file, optionally set a phase plate, choose what trains, cast to ``dtype``.

    Args:
        path: lens file (.json or the authors' .txt).
        trainable: parameter names or globs to optimise.
        dtype: ``"float32"`` or ``"float64"``.
        plate: ``None``/``"learned"`` (as in the file), ``"none"`` (flatten the plate: all its
            coefficients zero) or ``"cubic"`` (the analytic Dowski-Cathey plate of
            ``plate_alpha_mm``).
        plate_surface: index of the XY-polynomial plate surface.
        table_options: options of the authors' ``.txt`` reader
            (:func:`~deeplens.optics.io.table.read_table`: ``stop_index``, ``scale``,
            ``object_distance_mm``, ``fields_deg``, ``wavelengths_nm``; ``None`` values are
            left out); config ``lens.table_options``.

    Raises:
        LensFileError: the file cannot be read; the message names the file and, where an option
            would help, the ``lens.table_options`` key.
    """
    opts = {k: v for k, v in (table_options or {}).items() if v is not None}
    if opts and Path(path).suffix.lower() != ".txt":
        raise ValueError(f"lens.table_options {sorted(opts)} apply to the authors' .txt tables "
                         f"only, but lens.path is {path}")
    known = [n for n in inspect.signature(read_table).parameters if n != "path"]
    unknown = sorted(set(opts) - set(known))
    if unknown:
        raise ValueError(f"lens.table_options: unknown option(s) {unknown}; expected some of "
                         f"{', '.join(known)}")
    try:
        lens = load_lens(path, **opts)
    except LensFileError as e:
        if e.key == "stop_index":
            raise LensFileError(f"{e} (config: lens.table_options.stop_index=N)") from None
        raise
    if plate in ("none", "cubic"):
        if plate_surface is None:
            raise ValueError("lens.plate_surface must be set to use lens.plate")
        cubic_phase_plate(lens, plate_surface, plate_alpha_mm if plate == "cubic" else 0.0)
    elif plate not in (None, "learned"):
        raise ValueError(f"lens.plate must be learned, none or cubic; got {plate!r}")
    set_trainable(lens, list(trainable))
    if dtype not in ("float32", "float64"):
        raise ValueError(f"lens.dtype must be float32 or float64, got {dtype!r}")
    return lens.to(getattr(torch, dtype))


def surface_height_map(surface, n: int = 64) -> torch.Tensor:
    """Sag ``(n, n)`` in mm over the surface's clear aperture, row 0 at ``+y`` (0 outside)."""
    s = copy.deepcopy(surface).double()
    R = float(s.semi_diameter)
    v = torch.linspace(-R, R, n, dtype=torch.float64)
    Y, X = torch.meshgrid(v, v, indexing="ij")
    with torch.no_grad():
        z = s.sag(X, Y)
    inside = (X ** 2 + Y ** 2 <= R * R) & s.in_domain(X, Y)
    return torch.where(inside, z, torch.zeros_like(z)).flip(0)
