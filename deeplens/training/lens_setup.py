"""Building the trainable lens from configuration: which parameters train, and their scales.

Parameters are addressed by their ``named_parameters`` names, e.g. ``surfaces.4.a.6`` (the
``x^3``... coefficient of an XY polynomial), ``surfaces.1.a.0`` (a4), ``d_sensor``.  Glob
patterns are allowed (``surfaces.4.a.*``).

Learning rates are given in *millimetres of sag* and converted per parameter, so that one Adam
step of size ``lr`` changes the surface by about ``lr`` mm at its rim whatever the parameter's
units: a coefficient of ``x^i y^j`` scales by ``R^-(i+j)``, an even asphere ``a_2k`` by
``R^-2k``, a curvature by ``2 / R^2`` (``R`` the semi-diameter); distances and misalignment
are already in mm (tilts: 1/R rad).  ``parameter_scale`` and the glob rule live in
:mod:`deeplens.optics.parameters` (shared with the design engine and the tolerances) and
``parameter_scale`` is re-exported here.
"""

from __future__ import annotations

import copy
import math
import inspect
from pathlib import Path

import torch

from ..optics.camera import set_trainable  # the one rule (re-exported)
from ..optics.parameters import parameter_scale
from ..optics.io import load_lens
from ..optics.io.lensfile import LensFileError
from ..optics.io.table import read_table
from ..optics.surfaces import XYPolynomial

__all__ = ["build_lens", "set_trainable", "parameter_scale", "optics_param_groups",
           "cubic_phase_plate", "extend_plate", "surface_height_map", "MAX_PLATE_ORDER"]

#: the highest ``lens.plate_order``: the diffraction renderer fits the traced wavefront with
#: polynomials of total degree 12 (:data:`deeplens.render.diffraction.FIT_DEGREE`), so a plate
#: of higher order would not be rendered as it is
MAX_PLATE_ORDER = 12




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


def extend_plate(lens, surface_index: int, order: int) -> list[str]:
    """Raise the XY-polynomial plate ``lens.surfaces[surface_index]`` to polynomial ``order``:
    the surface is replaced by an :class:`XYPolynomial` of that order with the same ``b``, the
    same coefficients (in :func:`~deeplens.optics.surfaces.xy_polynomial.xy_terms` order a
    higher order only appends terms, so every existing coefficient keeps its index) and zeros
    for the added terms, so the sag is unchanged.  Order ``J`` has ``(J+1)(J+2)/2`` terms;
    ``order`` equal to the plate's own leaves the lens untouched.

    Returns:
        The ``named_parameters`` names of the added coefficients (``surfaces.<i>.a.<m>``), in
        coefficient order (empty when nothing was added).  They are frozen (as every freshly
        made parameter); :func:`build_lens` unfreezes them when the plate trains.

    Raises:
        ValueError: ``order`` is not an int in ``[plate's order, MAX_PLATE_ORDER]``, or the
            surface is not an XY polynomial (config key ``lens.plate_order``).
    """
    n = len(lens.surfaces)
    if not (isinstance(surface_index, int) and not isinstance(surface_index, bool)
            and 0 <= surface_index < n):
        raise ValueError(f"lens.plate_surface: expected a surface index in [0, {n - 1}], got "
                         f"{surface_index!r}")
    s = lens.surfaces[surface_index]
    if not isinstance(s, XYPolynomial):
        raise ValueError(f"lens.plate_order: surface {surface_index} (lens.plate_surface) is a "
                         f"{type(s).__name__}, not an XY polynomial")
    if not (isinstance(order, int) and not isinstance(order, bool)
            and s.order <= order <= MAX_PLATE_ORDER):
        raise ValueError(f"lens.plate_order: expected an int in [{s.order}, {MAX_PLATE_ORDER}] "
                         f"(from the plate's own order, {s.order}, whose terms cannot be "
                         f"dropped, to the diffraction renderer's wavefront fit degree), or "
                         f"null; got {order!r}")
    if order == s.order:
        return []
    old = [float(a) for a in s.a]  # the parameters are float64: exact
    extended = XYPolynomial(float(s.semi_diameter), old + [0.0] * ((order + 1) * (order + 2) // 2
                                                                    - len(old)),
                            b=float(s.b))
    extended.to(dtype=s.b.dtype, device=s.b.device)
    lens.surfaces[surface_index] = extended
    lens.check()
    return [f"surfaces.{surface_index}.a.{m}" for m in range(len(old), len(extended.a))]


def best_focus_distance(lens, depth_mm: float, wavelengths_nm, n_rays: int = 4096) -> float:
    """Sensor distance ``d_sensor`` (mm after the last vertex) that minimises the on-axis RMS
    spot of a point at ``depth_mm`` over ``wavelengths_nm`` (rays weighted equally).

    Closed form: after the last surface a ray is ``x(z) = x_0 + (z - z_0) u`` with ``u = d_xy /
    d_z``, so the squared spot size about the centroid, ``Σ |x(z) - x̄(z)|²``, is a quadratic in
    ``z``, minimal at ``z* = -Σ (a - ā)·(u - ū) / Σ |u - ū|²`` with ``a = x_0 - z_0 u``.
    """
    from ..optics.sampling import point_source_rays

    a_all, u_all = [], []
    with torch.no_grad():
        L = copy.deepcopy(lens).double()
        for w in wavelengths_nm:
            rays = point_source_rays(L, (0.0, 0.0), depth_mm, float(w), n_rays, seed=0)
            out = L.trace(rays)
            v = out.valid
            if int(v.sum()) < 3:
                raise ValueError(f"best focus: fewer than 3 rays from {depth_mm:g} mm on axis "
                                 f"pass the lens at {float(w):g} nm")
            o, d = out.o[v], out.d[v]
            u = d[:, :2] / d[:, 2:3]
            a_all.append(o[:, :2] - o[:, 2:3] * u)
            u_all.append(u)
        a, u = torch.cat(a_all), torch.cat(u_all)
        da, du = a - a.mean(0), u - u.mean(0)
        z = float(-(da * du).sum() / (du * du).sum())
        return z - float(L.z_vertices()[-1])


def build_lens(path: str, trainable=(), dtype: str = "float32", plate: str | None = None,
               plate_surface: int | None = None, plate_alpha_mm: float = 0.0,
               table_options: dict | None = None, focus_mm: float | None = None,
               focus_wavelengths_nm=(587.5618,), learned_start_alpha_mm: float | None = None,
               plate_order: int | None = None):
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
        focus_mm: if given, move the sensor to the best focus (smallest on-axis RMS spot over
            ``focus_wavelengths_nm``, see :func:`best_focus_distance`) of a point at this
            depth (mm), computed with the plate flattened, so every plate variant shares one
            sensor position; config ``lens.focus_mm``.
        learned_start_alpha_mm: for ``plate="learned"``: ``None`` starts from the plate in the
            file; a number starts from the cubic plate of this ``α`` (mm of sag at the rim), e.g.
            to learn a refinement of a Dowski-Cathey plate; config
            ``lens.learned_start_alpha_mm``.
        plate_order: ``None`` keeps the plate's order in the file; an int raises the plate
            (``plate_surface``) to that polynomial order with zeros for the added terms
            (:func:`extend_plate`), for every ``plate`` kind (``none`` and ``cubic`` set the
            added terms to zero as well).  The added terms train when any coefficient of the
            plate is in ``trainable``; config ``lens.plate_order``.

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
    added = []
    if plate_order is not None:
        if plate_surface is None:
            raise ValueError("lens.plate_surface must be set to use lens.plate_order")
        added = extend_plate(lens, plate_surface, plate_order)
    if focus_mm is not None:
        if not (isinstance(focus_mm, (int, float)) and math.isfinite(focus_mm) and focus_mm > 0):
            raise ValueError(f"lens.focus_mm: expected a depth > 0 mm, got {focus_mm!r}")
        bare = copy.deepcopy(lens)
        if plate_surface is not None:  # focus the lens without its plate (any variant)
            cubic_phase_plate(bare, plate_surface, 0.0)
        d = best_focus_distance(bare, float(focus_mm), focus_wavelengths_nm)
        with torch.no_grad():
            lens.d_sensor.fill_(d)
        lens.check()
    if plate in ("none", "cubic"):
        if plate_surface is None:
            raise ValueError("lens.plate_surface must be set to use lens.plate")
        cubic_phase_plate(lens, plate_surface, plate_alpha_mm if plate == "cubic" else 0.0)
    elif plate not in (None, "learned"):
        raise ValueError(f"lens.plate must be learned, none or cubic; got {plate!r}")
    elif learned_start_alpha_mm is not None:
        a = learned_start_alpha_mm
        if not (isinstance(a, (int, float)) and math.isfinite(a)):
            raise ValueError(f"lens.learned_start_alpha_mm: expected a number (mm) or null, "
                             f"got {a!r}")
        if plate_surface is None:
            raise ValueError("lens.plate_surface must be set to use lens.learned_start_alpha_mm")
        cubic_phase_plate(lens, plate_surface, float(a))
    chosen = set_trainable(lens, list(trainable))
    if added and any(n.startswith(f"surfaces.{plate_surface}.a.") for n in chosen):
        set_trainable(lens, chosen + added)
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
