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
from ..optics.errors import ConfigError
from ..optics.parameters import parameter_scale
from ..optics.io import load_lens
from ..optics.io.lensfile import LensFileError
from ..optics.io.table import read_table
from ..optics.surfaces import XYPolynomial

__all__ = ["build_lens", "check_lens_settings", "set_trainable", "parameter_scale", "optics_param_groups",
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
    s.set_cubic(alpha_mm)


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
        ConfigError: ``order`` is not an int in ``[plate's order, MAX_PLATE_ORDER]``, or the
            surface is not an XY polynomial (config key ``lens.plate_order``).
    """
    n = len(lens.surfaces)
    if not (isinstance(surface_index, int) and not isinstance(surface_index, bool)
            and 0 <= surface_index < n):
        raise ConfigError("lens.plate_surface", f"a surface index in [0, {n - 1}]",
                          surface_index)
    s = lens.surfaces[surface_index]
    if not isinstance(s, XYPolynomial):
        raise ConfigError("lens.plate_surface", f"the index of an XY-polynomial surface (to use "
                          f"lens.plate_order; surface {surface_index} is a "
                          f"{type(s).__name__})", surface_index)
    if not (isinstance(order, int) and not isinstance(order, bool)
            and s.order <= order <= MAX_PLATE_ORDER):
        raise ConfigError("lens.plate_order", f"an int in [{s.order}, {MAX_PLATE_ORDER}] (from "
                          f"the plate's own order, {s.order}, whose terms cannot be dropped, to "
                          f"the diffraction renderer's wavefront fit degree), or null", order)
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
    check_lens_settings(path, plate=plate, plate_surface=plate_surface,
                        plate_alpha_mm=plate_alpha_mm, table_options=table_options,
                        focus_mm=focus_mm, learned_start_alpha_mm=learned_start_alpha_mm,
                        plate_order=plate_order, dtype=dtype)
    opts = {k: v for k, v in (table_options or {}).items() if v is not None}
    try:
        lens = load_lens(path, **opts)
    except LensFileError as e:
        if e.key == "stop_index":
            raise LensFileError(f"{e} (config: lens.table_options.stop_index=N)") from None
        raise
    added = []
    if plate_order is not None:
        added = extend_plate(lens, plate_surface, plate_order)
    if focus_mm is not None:
        bare = copy.deepcopy(lens)
        if plate_surface is not None:  # focus the lens without its plate (any variant)
            cubic_phase_plate(bare, plate_surface, 0.0)
        d = best_focus_distance(bare, float(focus_mm), focus_wavelengths_nm)
        with torch.no_grad():
            lens.d_sensor.fill_(d)
        lens.check()
    if plate in ("none", "cubic"):
        cubic_phase_plate(lens, plate_surface, plate_alpha_mm if plate == "cubic" else 0.0)
    elif learned_start_alpha_mm is not None:
        cubic_phase_plate(lens, plate_surface, float(learned_start_alpha_mm))
    chosen = set_trainable(lens, list(trainable))
    if added and any(n.startswith(f"surfaces.{plate_surface}.a.") for n in chosen):
        set_trainable(lens, chosen + added)
    return lens.to(getattr(torch, dtype))


def _real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def check_lens_settings(path, *, plate=None, plate_surface=None, plate_alpha_mm=0.0,
                        table_options=None, focus_mm=None, learned_start_alpha_mm=None,
                        plate_order=None, dtype="float32") -> None:
    """The ``lens.*`` settings of :func:`build_lens` checked without reading the file (the
    checks that need the lens, a plate index within its surfaces and a plate order from its
    own, run in :func:`extend_plate`); raises :class:`~deeplens.optics.errors.ConfigError`
    naming ``lens.<key>``."""
    if dtype not in ("float32", "float64"):
        raise ConfigError("lens.dtype", "'float32' or 'float64'", dtype)
    if plate not in (None, "learned", "none", "cubic"):
        raise ConfigError("lens.plate", "null, 'learned', 'none' or 'cubic'", plate)
    if plate_surface is not None and not (isinstance(plate_surface, int)
                                          and not isinstance(plate_surface, bool)
                                          and plate_surface >= 0):
        raise ConfigError("lens.plate_surface", "an int >= 0 (a surface index) or null",
                          plate_surface)
    if plate_alpha_mm is not None and not _real(plate_alpha_mm):
        raise ConfigError("lens.plate_alpha_mm", "a finite number (mm)", plate_alpha_mm)
    if learned_start_alpha_mm is not None and not _real(learned_start_alpha_mm):
        raise ConfigError("lens.learned_start_alpha_mm", "a finite number (mm) or null",
                          learned_start_alpha_mm)
    if plate_order is not None and not (isinstance(plate_order, int)
                                        and not isinstance(plate_order, bool)
                                        and 1 <= plate_order <= MAX_PLATE_ORDER):
        raise ConfigError("lens.plate_order", f"an int in [1, {MAX_PLATE_ORDER}] (at least the "
                          f"plate's own order), or null", plate_order)
    if focus_mm is not None and not (_real(focus_mm) and focus_mm > 0):
        raise ConfigError("lens.focus_mm", "a depth > 0 mm, or null", focus_mm)
    # what needs the plate's surface: lens.plate none/cubic, plate_order, a learned plate's start
    needs = [k for k, v in (("lens.plate_order", plate_order is not None),
                            ("lens.plate", plate in ("none", "cubic")),
                            ("lens.learned_start_alpha_mm", plate in (None, "learned")
                             and learned_start_alpha_mm is not None)) if v]
    if needs and plate_surface is None:
        raise ConfigError.missing("lens.plate_surface", f"the plate's surface index (to use "
                                  f"{needs[0]})")
    opts = {k: v for k, v in (table_options or {}).items() if v is not None}
    if opts and Path(path).suffix.lower() != ".txt":
        raise ConfigError("lens.table_options", f"null options for a "
                          f"{Path(path).suffix or 'suffix-less'} lens file (they apply to the "
                          f"authors' .txt tables only)", opts)
    known = [n for n in inspect.signature(read_table).parameters if n != "path"]
    unknown = set(opts) - set(known)
    if unknown:
        raise ConfigError.unknown("lens.table_options", unknown, known)


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
