"""The reader: a parsed ``.zmx`` file (:mod:`.zmx_parse`) -> a :class:`~deeplens.optics.lens.Lens`.

Steps of :func:`read_zmx`, each a function here: the wavelengths and field type
(:func:`_wavelengths`); the surfaces in order, with dummies merged into gaps and coordinate
breaks turned into misalignments or :class:`~deeplens.optics.surfaces.CoordinateBreak` surfaces
(:func:`_sequence`, one block at a time by :func:`.zmx_surfaces.build_surface`, glasses by
:mod:`.zmx_glass`); the sensor (:func:`_sensor`); the elements (:func:`_elements`); the
system aperture (:func:`_aperture`); the lens itself, then apertures and fields given other than
as an EPD and angles (:mod:`.zmx_system`), automatic semi-diameters
(:func:`_auto_semi_diameters`) and the stop's clear aperture.  What the file format means and how
it maps onto deeplens is in :mod:`.zmx`.
"""

from __future__ import annotations

import dataclasses
import math
import re
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..errors import SurfacesCrossError, ZemaxFileError
from ..frames import mirrors_met_edge_on, travel_directions
from ..lens import Lens, LensSpec
from ..materials import Material, check_wavelength_nm
from ..paraxial import PupilAtInfinityError
from ..surfaces import Aperture, Asphere, CoordinateBreak, IdealLens, IdealLensXY, Plane
from .zmx_scbd import (check_scbd_on_break, image_scbd_note, refuse_object_scbd, scbd_breaks,
                       scbd_identity)
from .zmx_coordbrk import (coordinate_break, is_identity, misalignment_brackets,
                           stop_plane_of_break, y_fields_only)
from .zmx_glass import load_catalogues, range_refusal_source, surface_material
from .zmx_mconf import configuration
from .zmx_notes import Cause, literal
from .zmx_parse import UNITS, Locator, ZmxSurface, parse
from .surface_formats import QBFS_CONIC, refuse_unread
from .stop_clear import flat_stop_as_asphere, plain_circular_stop
from .zmx_glass_codes import GLASS_CODES
from .zmx_stop_size import STOP_SIZE, check_stop_size, limiting_stop_radius
from .zmx_surfaces import build_surface, is_air
from .zmx_system import aperture_to_epd, element_tilts, fields_to_angles

__all__ = ["read_zmx"]

# the sensor distance used when a file puts the image plane on the last (flat) vertex
_IMAGE_ON_VERTEX_MM = 1e-9


@dataclass
class _Sequence:
    """The surfaces kept from the file, in order (see :func:`_sequence`)."""

    obj_dist: float                 # object distance (mm), before the leading dummy gap
    obj_medium: Material
    obj_tilt: tuple = (0.0, 0.0)    # a TILTSURF object's (tan_x, tan_y): Lens.object_tilt
    kept: list = field(default_factory=list)     # (surface, material after, block, gap before)
    media: list = field(default_factory=list)    # object medium, then the medium after each
    groups: list = field(default_factory=list)   # (first, last, tilts, line) bracketed elements
    gap: float = 0.0               # from the last kept vertex to the image surface (mm)
    stop_idx: int | None = None
    autos: list = field(default_factory=list)    # kept indices with automatic semi-diameters
    mirrors: list = field(default_factory=list)  # kept indices of GLAS MIRROR surfaces
    folded: bool = False           # a fold or an off-axis section (an unpaired COORDBRK)


def read_zmx(path, *, glass_catalogs=(), glass_fallback=None, config=None,
             qbfs_conic="forbes", stop_size="limiting", glass_codes="refuse") -> Lens:
    """Read a sequential Zemax ``.zmx`` file into a :class:`~deeplens.optics.lens.Lens`.

    Args:
        path: the ``.zmx`` file (UTF-16 with or without byte-order mark, UTF-8 or Latin-1).
        glass_catalogs: ``.agf`` files (paths) or :class:`~.agf.GlassCatalogue` objects; each
            answers for the ``GCAT`` name equal to its file stem.  A catalogue the file names
            but the caller does not pass is looked for as ``<NAME>.agf`` next to the ``.zmx``.
        glass_fallback: ``None`` (default: a glass that is not found is an error), ``"model"``
            (use the ``n_d``/``V_d`` the ``GLAS`` line carries), or a material spec / material
            used for every missing glass.  Each use is reported in a :class:`ZemaxWarning`
            (one per file naming every such ``GLAS`` line).
        config: the configuration of a multi-configuration file (``MNUM``) to read, from 1;
            ``None`` (default): the active one, as saved (a :class:`ZemaxWarning` says the file
            has others).  Its operands (``THIC``, ``CRVT``, ``CONN``, ``GLSS``, ``PRAM``,
            ``APER``, ``YFIE``, ... the table of :mod:`.zmx_mconf`) replace the saved values
            (:func:`~.zmx_configs.read_zmx_configs` reads them all).
        qbfs_conic: how a ``QED_TYPE`` Qbfs surface on a conic base (``CONI`` != 0), which
            no OpticStudio page defines, is read: ``"forbes"`` (default) with Forbes' conic
            generalisation (optiland's; the departure times ``sqrt((1 − k c² r²) / (1 −
            (1+k) c² r²))``), with one located :class:`ZemaxWarning` at its ``TYPE`` line;
            ``"refuse"``: a located :class:`ZemaxFileError` there instead.
        stop_size: how a stop with no semi-diameter under ``FLOA`` (float by stop size), which
            the file alone does not size, is read: ``"limiting"`` (default) floats it to the
            largest on-axis beam the other surfaces' fixed apertures pass (paraxial marginal-ray
            scaling, :mod:`.zmx_stop_size`), with one located :class:`ZemaxWarning` at its
            ``SURF`` line naming the size and the limiting surface; ``"refuse"``: a located
            :class:`ZemaxFileError` there instead.
        glass_codes: how a ``GLAS`` name that is a six-digit ``n_d``/``V_d`` code (``847238``:
            n_d 1.847, V_d 23.8; CODE V's fictitious-glass convention) and in no catalogue
            searched is read: ``"refuse"`` (default; OpticStudio's catalogues hold no such
            name) a located :class:`ZemaxFileError` that names the code's reading;
            ``"model"``: ``ModelGlass(n_d, V_d)`` named by the code, with one located
            :class:`ZemaxWarning` per file naming every such ``GLAS`` line
            (:mod:`.zmx_glass_codes`).

    Returns:
        The lens (lengths in mm, wavelengths in nm).

    Raises:
        ZemaxFileError: (a :class:`~deeplens.optics.errors.LensFileError`) malformed or
            truncated lines, unknown surface types, unsupported apertures, coordinate breaks that do not bracket
            one element, unknown glasses, field types that cannot be converted, wavelengths
            outside a glass's range; the error's ``source``, ``line``, ``feature`` and
            ``surf`` say where (its message is formatted from them).

    Example::

        lens = read_zmx("US02532751-1.zmx")
        lens = read_zmx("vendor_lens.zmx", glass_catalogs=["OHARA.agf"])
    """
    path = Path(path)
    if qbfs_conic not in QBFS_CONIC:
        raise ValueError(f"qbfs_conic must be one of {QBFS_CONIC}, got {qbfs_conic!r}")
    if stop_size not in STOP_SIZE:
        raise ValueError(f"stop_size must be one of {STOP_SIZE}, got {stop_size!r}")
    if glass_codes not in GLASS_CODES:
        raise ValueError(f"glass_codes must be one of {GLASS_CODES}, got {glass_codes!r}")
    if not path.exists():
        raise FileNotFoundError(f"lens file not found: {path}")
    sysd, surfs, p = parse(path)
    sysd, surfs, n_cfg, k_cfg = configuration(sysd, surfs, p, config)
    if n_cfg > 1 and config is None:
        named = len(p.records[sysd["mnum"][2]].tokens) > 2   # MNUM n k; older files: MNUM n
        which = (f"the surface data as saved (configuration {k_cfg}, the active one)" if named
                 else f"configuration {k_cfg} (the MNUM line names no active configuration; "
                      f"the surface data as saved may hold another)")
        p.note(sysd["mnum"][2], f"multi-configuration file ({n_cfg} configurations): {which} "
                                f"is read; read_zmx(path, config=N) reads configuration N, "
                                f"read_zmx_configs(path) every one")
    cats = load_catalogues(path, sysd["gcat"][0], glass_catalogs, p)
    unit, _ = sysd["unit"]
    s_mm = UNITS[unit]
    gcat, _ = sysd["gcat"]
    ftyp, ftyp_line, n_fields, waves_nm, primary = _wavelengths(sysd, p)
    seq = _sequence(surfs, s_mm, gcat, cats, glass_fallback, p, qbfs_conic, glass_codes)
    _drop_drawn_plane_after_image(seq, primary, p)
    obj, img = surfs[0], surfs[-1]
    kept, stop_idx, autos = seq.kept, seq.stop_idx, seq.autos
    surfaces = [k_[0] for k_ in kept]
    distances = [0.0] + [k_[3] for k_ in kept[1:]]
    obj_dist = seq.obj_dist
    if not math.isinf(obj_dist):
        obj_dist += kept[0][3]   # dummy thickness in front of the first surface
        # (0 before a coordinate break: the object at its pivot, in the object's frame; the
        # break is no surface a ray meets, OpticStudio's "dummy surface", and turns only the
        # frame of what follows)
        if obj_dist == 0 and not isinstance(kept[0][0], CoordinateBreak):
            p.fail(obj.disz_line or obj.line,
                   f"the object lies on the first surface deeplens traces (SURF "
                   f"{surfs.index(kept[0][2])}): the object distance (DISZ of SURF 0, "
                   f"{obj.disz!r}) and the dummy gaps after it add up to 0; deeplens puts a "
                   f"finite object at a distance != 0 from the first vertex (> 0, or < 0 for a "
                   f"virtual object): insert a gap, or give the object a small distance")
    virtual = [False]
    d_sensor = _sensor(seq, img, p, virtual, primary)
    sensor_sd = img.diam * s_mm if img.diam > 0 else None

    # ---- elements: bracketed groups, then deeplens' default grouping for the rest
    elements = _elements(kept, seq.media, seq.groups, p)
    ap_type, ap_value, ap_line, convert = _aperture(sysd, seq, obj_dist, s_mm, p, stop_size)
    float_stop = ap_type == "stop" and stop_idx in autos   # FLOA, no stop size: the limit
    telecentric = _telecentric(ftyp, ftyp_line, obj_dist, convert, ap_line, p)

    # ---- glass wavelength ranges, before building (a clear error instead of a NaN)
    # (WAVM states µm: a wave beyond 100 µm is meant, and loads where every medium of the
    # lens is defined there, check_wavelength_nm's material range)
    for (surf, mat, s, _), i in zip(kept, range(len(kept))):
        for w in waves_nm:
            try:
                check_wavelength_nm(w, mat, stated_unit=True)
            except ValueError as e:
                where, give = range_refusal_source(mat)
                p.fail(s.glass_line or s.line, f"{e} (glass of SURF {surfs.index(s)}"
                                               f"{', ' + where if where else ''})"
                                               f"{_long_wave_hint(w)}"
                                               f"{'; ' + give if give and w <= 1e5 else ''}")
        _check_index(mat, waves_nm, s, surfs.index(s), p)
    for w in waves_nm:
        try:
            check_wavelength_nm(w, seq.obj_medium, stated_unit=True)
        except ValueError as e:
            p.fail(obj.glass_line or obj.line, f"{e}{_long_wave_hint(w)}")

    where_of = {i: kept[i][2].line for i in range(len(kept))}
    where_of["sensor"] = img.line
    propagated = _virtual_gaps(seq, surfaces, distances, primary, where_of, p)
    virtual_gaps = [q for q, _ in propagated]
    limited = {}   # (i, j) -> the radius where surfaces i and j meet (estimated diameters)
    original = {}  # surface -> its semi-diameter before it was first limited there
    try:
        spec = LensSpec(object_distance_mm=obj_dist, aperture_type=ap_type,
                        aperture_value=ap_value, fields_deg=[0.0], wavelengths_nm=waves_nm,
                        primary_wavelength_nm=primary,
                        wavelength_unit_stated=True)
        while True:
            try:
                lens = Lens(surfaces, seq.media, distances, d_sensor, stop_idx, sensor_sd, spec,
                            elements=[(a, b) for a, b, _, _ in elements],
                            name=sysd["name"] or path.stem, mirrors=seq.mirrors,
                            virtual_image=virtual[0], backward_gaps=virtual_gaps,
                            object_telecentric=telecentric)
                break
            except PupilAtInfinityError:
                if telecentric:
                    raise
                efl = None
                if ap_type == "fno" and convert is None:   # the message says what F/# fails
                    efl = _telecentric_efl(surfaces, seq, distances, d_sensor, stop_idx,
                                           sensor_sd, spec, primary)
                telecentric = _pupil_at_infinity(ftyp, ftyp_line, convert, ap_type, ap_line, p,
                                                 efl)
            except SurfacesCrossError as e:
                if not _limit_at_crossing(e, surfaces, lambda i: _limitable(kept, stop_idx, i),
                                          limited, original):
                    raise
    except (ValueError, TypeError) as e:
        if isinstance(e, ZemaxFileError):   # already located (a refusal while building)
            raise
        if getattr(e, "key", None) == "aperture":   # the ENPD/FNUM/FLOA line's value
            p.fail(ap_line, str(e))
        if (getattr(e, "key", None) == "sensor" and img.curv != 0
                and str(e).startswith("the last surface crosses the sensor plane")):
            _refuse_flat_sensor_cut(seq, img, surfs, d_sensor, s_mm, primary, p)
        raise _located(p, e, where_of) from e
    lens.object_telecentric = telecentric
    lens.object_tilt = seq.obj_tilt
    for i in mirrors_met_edge_on(surfaces, seq.mirrors, _axis_indices(seq, primary),
                                  primary):
        # (a sphere or conic mirror takes such rays at their first crossing ahead: intersect's
        # ``across``; an aspheric one intersects from its vertex plane, Newton's start)
        lost = ("" if getattr(surfaces[i], "is_quadric", False) else
                "; deeplens' real trace intersects this aspheric mirror from its vertex plane "
                "and loses the rays that run (nearly) parallel to it: spots and RMS of this "
                "lens miss part of the beam")
        edge_on = ("the beam's axis meets {} edge-on (it travels across the mirror's frame, "
                   "turned by the coordinate breaks before it, and never reaches the vertex: an "
                   "off-axis mirror lit across its axis); the thicknesses after it follow the "
                   "mirror parity, the paraxial data the local axis" + lost)
        p.note_each(kept[i][2].line,
                    Cause(one="{item}: " + literal(edge_on.format("this mirror")),
                          many="{n} mirrors ({items}): " + literal(edge_on.format("each"))),
                    f"SURF {surfs.index(kept[i][2])}")
    if float_stop:
        _float_stop_to_the_limit(lens, seq, surfs, where_of, p, original)
        autos = [i for i in autos if i != stop_idx]
    for e, (a, b, d, _) in enumerate(elements):
        if d is not None:
            m = lens.misalignments[e]
            dx, dy, tx, ty = d
            with torch.no_grad():
                m.dx.fill_(dx)
                m.dy.fill_(dy)
                m.tilt_x.fill_(math.radians(tx))
                m.tilt_y.fill_(math.radians(ty))
    _note_virtual_gaps(lens, propagated, where_of, p)
    _roof_gaps(lens, where_of, p)
    needs_efl = ftyp[0] in (2, 3) or (convert is not None and convert[0] == "wfno")
    if _afocal(lens) and needs_efl:
        # an afocal lens (flat folds only) has an infinite focal length: fields given as image
        # heights or a working F-number have no meaning there; object heights and an
        # object-space NA (a finite object) need only the entrance pupil, which the surfaces
        # before the stop place whatever the power after it
        p.fail(ftyp_line if convert is None or ftyp[0] in (2, 3) else convert[2],
               "the system is afocal (no paraxial power: flat mirrors and folds only), and "
               "this aperture or field type needs a finite focal length")
    if convert is not None:
        ap_value = aperture_to_epd(lens, *convert, p)
        try:
            lens.spec = LensSpec(object_distance_mm=obj_dist, aperture_type="epd",
                                 aperture_value=ap_value, fields_deg=[0.0],
                                 wavelengths_nm=waves_nm, primary_wavelength_nm=primary,
                                 wavelength_unit_stated=True)
            lens.apply_aperture_spec()
        except ValueError as e:
            p.fail(convert[2], str(e))
    if len(virtual) > 1:
        _refuse_image_before_vertex(lens, *virtual[1], p)

    # ---- fields
    lens.ray_aiming = sysd["raim"][0] != 0
    if seq.folded:
        sysd, n_fields = y_fields_only(sysd, n_fields, p)
    autos = [i for i in autos if not (i == stop_idx and ap_type != "stop")]
    with _unsized(lens, autos):   # (FTYP 3: the chief ray solved before they are sized)
        fields = fields_to_angles(sysd, ftyp, ftyp_line, n_fields, s_mm, lens, p,
                                  lambda i: f"SURF {surfs.index(kept[i][2])} (line "
                                            f"{kept[i][2].line})")
    if autos:
        _auto_semi_diameters(lens, autos, fields, where_of, p, limited, original)
    if limited:
        _cross_backwards_where_the_beam_passes(
            lens, limited, where_of, p, original,
            lambda: _auto_semi_diameters(lens, autos, fields, where_of, p, limited, original)
            if autos else None,
            fixed={i for i in range(len(kept)) if _fixed_diam(kept, stop_idx, i)})
    try:
        lens.spec = LensSpec(object_distance_mm=obj_dist, aperture_type=ap_type,
                             aperture_value=ap_value, fields_deg=fields, wavelengths_nm=waves_nm,
                             primary_wavelength_nm=primary, wavelength_unit_stated=True)
    except ValueError as e:
        p.fail(sysd["yfln"][1] if sysd["yfln"] else 0, str(e))
    _check_stop_clear_aperture(lens, kept[stop_idx][2], s_mm, p)
    p.warn_notes(stacklevel=3)
    return lens


@contextmanager
def _unsized(lens: Lens, idx):
    """Within the block, the surfaces ``idx`` (automatic semi-diameters, still at their
    provisional size) clip no ray: their semi-diameters are infinite, and restored after.  The
    fields are converted to angles before those semi-diameters are sized from them, and a real
    image height (``FTYP 3``) is solved by tracing chief rays: OpticStudio's default
    semi-diameter is "the radial distance to the aperture required to pass all real rays
    without clipping any of the rays", a floating aperture being applied only to a
    user-defined one (OpticStudio User Guide, *Semi-Diameters*), so an automatic one never
    stops a chief ray.  (Before, the provisional 1e-3 mm stopped every chief ray beyond a few
    hundredths of a degree, and such files were refused as "no chief ray reaches image height".)"""
    saved = [float(lens.surfaces[i].semi_diameter) for i in idx]
    with torch.no_grad():
        for i in idx:
            lens.surfaces[i].semi_diameter.fill_(math.inf)
    try:
        yield
    finally:
        with torch.no_grad():
            for i, v in zip(idx, saved):
                lens.surfaces[i].semi_diameter.fill_(v)


def _wavelengths(sysd: dict, p: Locator):
    """``(ftyp, ftyp_line, n_fields, wavelengths_nm, primary_nm)``: the ``FTYP`` values (field
    type, telecentric and afocal flags, numbers of fields and wavelengths), the active
    wavelengths (``WAVM``, or ``WAVL`` in older files; µm in the file) and the ``PWAV`` one."""
    ftyp, ftyp_line = sysd["ftyp"] if sysd["ftyp"] else ([0], 0)
    if len(ftyp) > 6 and ftyp[6] == 1:
        # OpticStudio's afocal image space changes how aberrations are reported (angles in
        # image space instead of positions on the image surface), not the prescription nor its
        # first-order data: the lens is read as written and images onto the image surface
        p.note(ftyp_line, "FTYP: afocal image space (seventh value 1): OpticStudio reports "
                          "this system's aberrations as angles in image space; deeplens reads "
                          "the same prescription and images onto the image surface at the "
                          "file's distance (spots in mm there, not angles), and writes it so")
    n_fields = ftyp[2] if len(ftyp) > 2 and ftyp[2] > 0 else None
    n_waves = ftyp[3] if len(ftyp) > 3 and ftyp[3] > 0 else None
    if sysd["waves"]:
        nums = sorted(sysd["waves"])
        if n_waves is not None:
            nums = [i for i in nums if i <= n_waves]
        waves = [(sysd["waves"][i][0], sysd["waves"][i][1]) for i in nums]
    elif sysd["wavl"]:
        vals, ln = sysd["wavl"]
        waves = [(v, ln) for v in vals]
        nums = list(range(1, len(vals) + 1))
    else:
        p.fail(0, "no wavelength (WAVM or WAVL line)")
    if not waves:
        p.fail(ftyp_line, "no active wavelength")
    waves_nm = []
    for v, ln in waves:
        try:   # WAVM is in µm by the format: no unit to guess (the media's ranges decide)
            check_wavelength_nm(v * 1000.0, stated_unit=True)
        except ValueError as e:
            p.fail(ln, f"wavelength {v!r} µm: {e}")
        waves_nm.append(v * 1000.0)
    pw, pw_line = sysd["pwav"]
    if pw not in nums:
        p.fail(pw_line, f"PWAV {pw}: the primary wavelength is not one of the active wavelengths "
                        f"{nums}")
    primary = waves_nm[nums.index(pw)]
    return ftyp, ftyp_line, n_fields, waves_nm, primary


def _long_wave_hint(w_nm: float) -> str:
    """What a refusal at a wavelength beyond 100 µm adds: the ``WAVM`` value in µm, what it is,
    what deeplens accepts there, and the nanometre slip when the value could be one."""
    if not w_nm > 1e5:
        return ""
    v = w_nm / 1000.0
    kind = f" ({v / 1000.0:g} mm: a millimetre or terahertz wave)" if v >= 1000.0 else ""
    slip = f"; if {v:g} is in nanometres, write {v / 1000.0:g}" if v < 3000.0 else ""
    return (f"; the wavelength is WAVM {v:g} µm{kind} (WAVM values are micrometres): a wave "
            f"beyond 100 µm loads where every medium of the lens is defined there (a constant "
            f"index, a model glass with V_d 0, or a catalogue glass whose range reaches it){slip}")


def _check_index(mat: Material, waves_nm, s: ZmxSurface, k: int, p: Locator) -> None:
    """The glass of ``SURF k`` has a finite index at every design wavelength, and one of at
    least 1 and at most 10 when it comes from a catalogue formula (an ``.agf`` glass): a formula
    with ``n² < 0`` there gives NaN indices (a report full of ``nan``), and ``n < 1`` or an index
    beyond any optical material's (germanium's is 4) a coefficient typed wrong.  (OpticStudio's model glasses may be below 1: indices relative to air.)"""
    from .agf import AGFGlass

    with torch.no_grad():
        n = mat.n(torch.tensor(waves_nm, dtype=torch.float64))
    bad = [(w, float(v)) for w, v in zip(waves_nm, n.reshape(-1).tolist())
           if not math.isfinite(v) or (isinstance(mat, AGFGlass) and not 1.0 <= v <= 10.0)]
    if not bad:
        return
    w, v = bad[0]
    where = getattr(mat, "source", None)
    what = (f"glass {mat.name!r}" + (f" ({where})" if where else "")
            + f" of SURF {k}: its dispersion formula gives ")
    what += (f"n = {v:g} at {w:g} nm" if math.isfinite(v) else
             f"no real index at {w:g} nm (n² < 0 or an overflow)")
    p.fail(s.glass_line or s.line, f"{what}; expected a finite index >= 1 (and <= 10 for a "
                                   f"catalogue glass) at every design wavelength (check the "
                                   f"formula number and the CD coefficients)")


def _telecentric(ftyp, ftyp_line: int, obj_dist: float, convert, ap_line: int,
                 p: Locator) -> bool:
    """Whether object space is telecentric (``FTYP`` second value 1: the entrance pupil at
    infinity, every chief ray parallel to the axis, ``Lens.object_telecentric``).  It needs an
    object at a finite distance, fields given as heights (``FTYP`` first value 1, 2 or 3) and
    an object-space NA or cone angle (``OBNA``): the cone of rays about each chief ray."""
    if not (len(ftyp) > 1 and ftyp[1] == 1):
        return False
    if math.isinf(obj_dist):
        p.fail(ftyp_line, "FTYP: object-space telecentric (second value 1) with the object at "
                          "infinity: the fields of a telecentric system are object heights")
    if ftyp[0] not in (1, 2, 3):
        names = {0: "angle", 4: "theodolite angle"}
        p.fail(ftyp_line, f"FTYP {ftyp[0]} ({names.get(ftyp[0], 'unknown field type')}) "
                          f"fields with object-space telecentric (second value 1): every chief "
                          f"ray is parallel to the axis, so fields must be heights (object, "
                          f"paraxial or real image height: FTYP 1, 2 or 3)")
    if convert is None or convert[0] not in ("obna", "cone"):
        p.fail(ap_line, "object-space telecentric (FTYP second value 1): deeplens takes the "
                        "aperture of a telecentric system as an object-space NA or cone angle "
                        "(OBNA), the cone of rays about each chief ray; this file gives another "
                        "system aperture")
    return True


def _telecentric_efl(surfaces, seq: _Sequence, distances, d_sensor: float, stop_idx: int,
                     sensor_sd, spec, primary: float) -> float | None:
    """The paraxial EFL (mm; ``inf`` afocal) of the lens built as object-space telecentric, for
    the refusal of an image-space F-number on an entrance pupil at infinity; ``None`` when that
    lens cannot be built."""
    from ..paraxial import paraxial

    try:
        trial = Lens(surfaces, seq.media, distances, d_sensor, stop_idx, sensor_sd,
                     dataclasses.replace(spec, aperture_type="epd", aperture_value=1.0),
                     mirrors=seq.mirrors, object_telecentric=True)
        with torch.no_grad():
            return float(paraxial(trial, primary).efl)
    except (ValueError, TypeError, RuntimeError):
        return None


def _pupil_at_infinity(ftyp, ftyp_line: int, convert, ap_type: str, ap_line: int,
                       p: Locator, efl: float | None = None) -> bool:
    """The file does not flag telecentric object space, but its ray parallel to the axis meets
    the stop at height 0 (to rounding: :func:`~deeplens.optics.paraxial.pupil_at_infinity`)
    and the object is finite: the entrance pupil is at infinity, object space is telecentric
    whatever the flag.  With an ``OBNA`` aperture (the cone about each chief ray, no entrance
    pupil needed) it is read as telecentric (``True``, one note at the aperture line); an
    ``ENPD`` or ``FNUM`` (a diameter or F-number of an entrance pupil at infinity) or ``FLOA``
    is refused there, angle fields at the ``FTYP`` line."""
    if ap_type == "fno" and convert is None and efl is not None:
        # OpticStudio's image-space F/# is the paraxial infinite-conjugate EFL over the paraxial
        # entrance-pupil diameter (User Guide, *Image Space F/#*)
        why = ("the lens is afocal (EFL infinite), so the image-space F/# (EFL over the "
               "entrance-pupil diameter) is inf/inf and sets no cone" if math.isinf(efl) else
               f"the image-space F/# (EFL {efl:.6g} mm over the entrance-pupil diameter) sets a "
               f"pupil of diameter EFL/F# at infinity, which subtends no cone from the object")
        p.fail(ap_line, f"FNUM: the entrance pupil is at infinity (the object is finite and the "
                        f"ray parallel to the axis meets the stop at height 0) and {why}; give "
                        f"the aperture as an object-space NA (OBNA)")
    if convert is None or convert[0] not in ("obna", "cone"):
        key = {"epd": "ENPD", "stop": "FLOA"}.get(ap_type, "FNUM")
        p.fail(ap_line, f"{key}: the entrance pupil is at infinity (the object is finite and "
                        f"the ray parallel to the axis meets the stop at height 0: object space "
                        f"is telecentric), so it has no diameter or F-number; give the "
                        f"aperture as an object-space NA (OBNA)")
    if ftyp[0] not in (1, 2, 3):
        p.fail(ftyp_line, f"FTYP {ftyp[0]}: the entrance pupil is at infinity (object space "
                          f"telecentric: the ray parallel to the axis meets the stop at height "
                          f"0), so every chief ray is parallel to the axis and fields must be "
                          f"heights (FTYP 1, 2 or 3)")
    p.note(ap_line, "the entrance pupil is at infinity (the ray parallel to the axis meets the "
                    "stop at height 0, to rounding) although FTYP does not flag telecentric "
                    "object space: read as object-space telecentric (Lens.object_telecentric), "
                    "every chief ray parallel to the axis, the OBNA the cone about it")
    return True


def _sequence(surfs: list[ZmxSurface], s_mm: float, gcat, cats, glass_fallback,
              p: Locator, qbfs_conic: str = "forbes",
              glass_codes: str = "refuse") -> _Sequence:
    """The object and the surfaces between it and the image, in order: dummies (flat, one medium
    on both sides) merged into the gaps, ``COORDBRK`` pairs that bracket one element read as its
    misalignment (``groups``), every other non-identity ``COORDBRK`` kept as a
    :class:`~deeplens.optics.surfaces.CoordinateBreak`, every other block built by
    :func:`.zmx_surfaces.build_surface`."""
    obj, img = surfs[0], surfs[-1]
    obj_tilt = _object_tilt(obj, p)
    obj_dist = obj.disz * (1 if math.isinf(obj.disz) else s_mm)
    if not (obj_dist >= 0 or math.isfinite(obj_dist)):   # NaN or -INFINITY
        # (0: the object on SURF 1; read_zmx adds the dummy gaps before the first surface
        # deeplens keeps and refuses a sum of 0)
        p.fail(obj.disz_line or obj.line, f"the object distance (DISZ of SURF 0) must be a "
                                          f"number of lens units (> 0; < 0, a virtual object; "
                                          f"0 before a dummy gap) or INFINITY, got "
                                          f"{obj.disz!r}")
    obj_medium = surface_material(obj, gcat, cats, glass_fallback, p, glass_codes)
    media = [obj_medium]
    kept = []            # (surface module, material after, zmx surf, gap before it in mm)
    groups = []          # [start, end] index ranges in kept for bracketed elements
    gap = 0.0            # axial distance from the last kept vertex to the current one (mm)
    bracket = None
    brackets = misalignment_brackets(surfs)   # COORDBRK pairs read as misalignments
    paired = set(brackets) | set(brackets.values())
    # a fold or an off-axis section: the beam leaves the local axes, and the file's automatic
    # semi-diameters (DIAM flag 0) are OpticStudio's footprints of its own (ray-aimed, all
    # fields) beam, which never vignette there: deeplens recomputes them from its rays
    folded = any(s.type == "COORDBRK" and not is_identity(s) and k not in paired
                 or s.type != "COORDBRK" and 0 < k < len(surfs) - 1 and not scbd_identity(s)
                 for k, s in enumerate(surfs))
    refuse_object_scbd(obj, p)
    image_scbd_note(img, len(surfs) - 1, p)
    stop_idx = None
    autos = []           # kept indices whose semi-diameter is automatic
    mirrors = []         # indices in kept of GLAS MIRROR surfaces
    for k in range(1, len(surfs) - 1):
        s = surfs[k]
        prev = media[-1]
        if s.type == "COORDBRK":
            if s.glass is not None:
                p.fail(s.line, "a COORDBRK surface cannot carry a glass")
            check_scbd_on_break(s, k, p)
            if s.stop:                   # a turn about z alone: a flat stop at its vertex
                plane = stop_plane_of_break(s, k, p)
                surf, auto = build_surface(plane, k, prev, prev, s_mm, folded, p, qbfs_conic)
                if auto:
                    autos.append(len(kept))
                stop_idx = len(kept)
                kept.append((surf, prev, s, gap))   # the block itself: its line, DIAM, CLAP
                media.append(prev)
                gap = 0.0                # the break's vertex is the stop's
            if is_identity(s):           # a dummy: its thickness only
                gap += s.disz * s_mm
                continue
            dx = s.parm.get(1, (0.0, 0))[0] * s_mm
            dy = s.parm.get(2, (0.0, 0))[0] * s_mm
            tx, ty, tz = (s.parm.get(i, (0.0, 0))[0] for i in (3, 4, 5))
            if k in brackets:            # opens an element's misalignment
                bracket = {"line": s.line, "d": (dx, dy, tx, ty, tz), "start": len(kept)}
            elif bracket is not None:    # closes it (misalignment_brackets checked the pair)
                if len(kept) > bracket["start"]:   # (around dummies only, the pair cancels)
                    groups.append((bracket["start"], len(kept) - 1,
                                   element_tilts(bracket["d"], kept[bracket["start"]:],
                                                 s.line, p), bracket["line"]))
                gap = gap + s.disz * s_mm   # gap: back at the pivot, + the thickness after
                bracket = None
            else:                        # a fold, an off-axis section: the frame turns
                kept.append((coordinate_break(s, s_mm), prev, s, gap))
                media.append(prev)
                gap = s.disz * s_mm
                if math.isinf(s.disz):
                    p.fail(s.disz_line, f"SURF {k}: an infinite thickness inside the lens")
            continue
        if s.spid is not None and bracket is not None:
            _turn_spider(s, k, bracket, p)
        mat = prev if s.mirror else surface_material(s, gcat, cats, glass_fallback, p,
                                                     glass_codes)
        built = build_surface(s, k, mat, prev, s_mm, folded, p, qbfs_conic)
        # SCBD: the surface's own tilt/decenter, a break before it and one after it (the
        # thickness after both); the breaks keep the block for its line
        before, after = scbd_breaks(s, k, s_mm, p)
        if before is not None:
            kept.append((before, prev, s, gap))
            media.append(prev)
            gap = 0.0
        if built is None:   # a dummy surface: its thickness only
            if after is not None:
                kept.append((after, prev, s, gap))
                media.append(prev)
                gap = 0.0
            gap += s.disz * s_mm
            continue
        surf, auto = built
        graded = getattr(surf, "medium", None)   # GRINSUR1: the surface names its medium
        if graded is not None:
            mat = graded
        if auto:
            autos.append(len(kept))
        if s.stop:
            stop_idx = len(kept)
        if s.mirror:
            mirrors.append(len(kept))
        kept.append((surf, mat, s, gap))
        media.append(mat)
        if after is not None:
            kept.append((after, mat, s, 0.0))
            media.append(mat)
        gap = s.disz * s_mm
        if math.isinf(s.disz):
            p.fail(s.disz_line, f"SURF {k}: an infinite thickness inside the lens")
    if not kept:
        p.fail(img.line, "no lens surface between the object and the image surface")
    if stop_idx is None:
        p.fail(0, "no STOP line: the lens has no aperture stop")
    img_tilt = tuple(img.parm.get(i, (0.0, 0))[0] for i in (1, 2))
    if img.type == "TILTSURF" and img.curv == 0 and img_tilt != (0.0, 0.0):
        p.note(img.line, f"the image surface is a tilted plane (TILTSURF, tangents "
                         f"{img_tilt[0]:g}, {img_tilt[1]:g}): deeplens' sensor is flat, normal "
                         f"to the axis at its vertex (a tilted sensor is not modelled), so "
                         f"off-axis spots are those of that plane")
    elif img.type != "STANDARD" or img.curv != 0:
        p.note(img.line, "the image surface is not flat: deeplens uses a flat sensor at its "
                         "vertex")
    seq = _Sequence(obj_dist=obj_dist, obj_medium=obj_medium, obj_tilt=obj_tilt, kept=kept,
                    media=media,
                    groups=groups, gap=gap, stop_idx=stop_idx, autos=autos, mirrors=mirrors,
                    folded=folded)
    return seq


def _object_tilt(obj: ZmxSurface, p: Locator) -> tuple[float, float]:
    """The object plane's slopes ``(tan_x, tan_y)`` (:attr:`Lens.object_tilt`): ``(0, 0)`` for a
    flat ``STANDARD`` object, ``PARM 1`` and ``PARM 2`` of a ``TILTSURF`` one (OpticStudio's
    *Tilted* surface, the plane ``z = x tan θ_x + y tan θ_y``, "useful for implementing tilted
    object and image surfaces": OpticStudio User Guide, *Tilted*).  Any other object surface
    is refused at its line."""
    if obj.type == "TILTSURF":
        refuse_unread(p, obj.parm, "SURF 0: TILTSURF", "PARM 1 and 2 are the x and y tangents of "
                      "the tilted object plane", (1, 2))
        tilt = (obj.parm.get(1, (0.0, 0))[0], obj.parm.get(2, (0.0, 0))[0])
        if not all(math.isfinite(v) for v in tilt):
            p.fail(obj.type_line or obj.line, f"SURF 0: the tilted object plane's tangents "
                                              f"(PARM 1, 2) must be finite, got {tilt}")
        if obj.curv == 0:
            if tilt != (0.0, 0.0) and math.isinf(obj.disz):
                p.fail(obj.disz_line or obj.line,
                       "SURF 0: a tilted object plane (TILTSURF) at infinity: an object at "
                       "infinity has no plane; give it a finite distance (or a STANDARD object)")
            return tilt
    if obj.type != "STANDARD" or obj.curv != 0:
        p.fail(obj.line, "the object surface (SURF 0) must be a flat STANDARD surface or a "
                         "tilted plane (TILTSURF)")
    return (0.0, 0.0)


def _turn_spider(s, k: int, bracket: dict, p: Locator) -> None:
    """A ``SPID`` inside a ``COORDBRK`` pair read as a misalignment: the pair's turn about z
    (``PARM 5``, degrees) turns the spider's arms, whose first lies along the turned frame's +x
    (OpticStudio's sample Schmidt-Cassegrain turns its three-armed spider by 30 degrees so that
    it is symmetric about the y-z plane); ``x_before = R_z(t) x_after``
    (:class:`~deeplens.optics.surfaces.CoordinateBreak`), so the first arm lies at ``+t`` in the
    lens's frame.  A pair that also decentres or tilts about x or y is refused.  Changes ``s``."""
    dx, dy, tx, ty, tz = bracket["d"]
    if any(v != 0 for v in (dx, dy, tx, ty)):
        p.fail(s.spid[2], f"SPID on SURF {k}: a spider inside a COORDBRK pair (line "
                          f"{bracket['line']}) that decentres or tilts about x or y is not "
                          f"supported (deeplens turns a spider by a pair's turn about z alone)")
    s.spid_angle += tz


def _axis_indices(seq: _Sequence, primary: float):
    """The media's indices at the primary wavelength (nm) for :func:`travel_directions`, or
    ``None`` when one cannot be evaluated there (the wavelength checks report it later)."""
    try:
        with torch.no_grad():
            w = torch.tensor(float(primary), dtype=torch.float64)
            return [float(m.n(w)) for m in seq.media]
    except (ValueError, TypeError):
        return None


def _sag_behind_vertex(surface, sign: float) -> float:
    """How far ``surface`` (a curved last surface) reaches behind its vertex plane along the
    direction of travel ``sign`` (mm, ``<= 0`` when it lies wholly before the plane): its sag
    at 65 radii up to its semi-diameter along 8 azimuths (where the Lens check samples it)."""
    r = torch.linspace(0.0, float(surface.semi_diameter), 65, dtype=torch.float64)
    a = torch.arange(8, dtype=torch.float64) * (math.pi / 8)
    x, y = r[None, :] * torch.cos(a)[:, None], r[None, :] * torch.sin(a)[:, None]
    with torch.no_grad():
        z = torch.cat([surface.sag(x, y), surface.sag(-x, -y)])
    z = sign * z.to(torch.float64)
    return math.inf if bool(z.isnan().any()) else float(z.max())


def _sensor(seq: _Sequence, img: ZmxSurface, p: Locator, virtual: list, primary: float) -> float:
    """The sensor distance (mm, signed along the direction of travel) from the gap between the
    last kept vertex and the image surface: an image plane on a flat last vertex moves
    :data:`_IMAGE_ON_VERTEX_MM` behind it, and so on a curved last vertex whose surface lies
    wholly before that plane (:func:`_sag_behind_vertex`); one reaching behind it is refused; an
    image plane before
    the last vertex (a virtual image: in an unfolded system, or after a flat mirror whose
    following thicknesses already run against the direction of travel, :func:`_virtual_gaps`)
    sets ``virtual[0]``."""
    kept, mirrors, surfaces = seq.kept, seq.mirrors, [k_[0] for k_ in seq.kept]
    d_sensor = seq.gap
    # the direction of travel in each medium, from the traced axis (Lens.directions: -z after
    # an odd number of mirrors unless breaks turn the beam round), so "behind" the last vertex
    # is sign * d > 0; a thickness of the wrong sign inside the lens is reported by Lens
    # (naming that surface)
    signs = [float(v) for v in travel_directions(surfaces, mirrors, _axis_indices(seq, primary),
                                                      primary)]
    sign = signs[-1]
    _note_reversed_ideal_lenses(kept, signs, p)
    inside_ok = all(kept[i][3] * signs[i] >= 0 for i in range(1, len(kept)))
    if d_sensor == 0 and isinstance(surfaces[-1], (Plane, CoordinateBreak)):
        # the image plane on the last (flat) vertex: deeplens' sensor must lie after the last
        # surface, so it sits _IMAGE_ON_VERTEX_MM behind it (image points move by that times
        # the ray slope: < 1e-8 mm)
        d_sensor = sign * _IMAGE_ON_VERTEX_MM
        p.note(img.line, f"the image plane lies on the last (flat) surface's vertex: the sensor "
                         f"is placed {_IMAGE_ON_VERTEX_MM:g} mm behind it")
    elif d_sensor == 0:
        behind = _sag_behind_vertex(surfaces[-1], sign)
        if behind > 0:
            p.fail(img.line, f"the image plane lies on the vertex of the last surface, which is "
                             f"curved and reaches {behind:.4g} mm behind its vertex plane within "
                             f"its semi-diameter: deeplens' flat sensor would cut through it "
                             f"(give the last surface a thickness)")
        # the whole surface lies before its vertex plane (a face concave towards the image,
        # sag against the direction of travel): the image plane through the vertex, where
        # OpticStudio's thickness 0 puts it (thicknesses are measured vertex to vertex), lies
        # behind all of it, so the sensor sits _IMAGE_ON_VERTEX_MM behind it, as for a flat one
        d_sensor = sign * _IMAGE_ON_VERTEX_MM
        p.note(img.line, f"the image plane lies on the last surface's vertex (a curved surface "
                         f"lying wholly before that plane): the sensor is placed "
                         f"{_IMAGE_ON_VERTEX_MM:g} mm behind it")
    elif sign * d_sensor < 0 and mirrors and _virtual_before_image(seq, signs):
        # OpticStudio's virtual propagation after a flat mirror (_virtual_gaps) continuing to
        # the image plane: a virtual image, reached along the rays' lines extended backwards
        p.note(img.line, f"the image plane lies {abs(d_sensor):g} mm against the direction of "
                         f"travel after the last (flat) mirror, as the thicknesses before it: a "
                         f"virtual image plane (OpticStudio's virtual propagation, rays "
                         f"extended backwards to it); analysis only, no camera can record it")
        virtual[0] = True
    elif sign * d_sensor < 0 and inside_ok and mirrors:
        # against the mirror parity after a curved mirror (OpticStudio's *Thicknesses*: virtual
        # propagation): refused once the lens is built as if the plane were virtual, which
        # lets the beam be traced to say whether it reaches the plane forwards (an off-axis
        # section met far from its vertex) or not (a slip of sign): _refuse_image_before_vertex
        virtual[0] = True
        virtual.append((img.line, abs(d_sensor), sign, len(mirrors)))
    elif sign * d_sensor < 0 and inside_ok:
        # a virtual image, as a negative lens's file puts it at its virtual focus: OpticStudio
        # extends the diverging rays backwards to that plane (Lens.virtual_image); analysis
        # only, the renderers refuse such a lens
        p.note(img.line, f"the image plane lies {abs(d_sensor):g} mm before the last surface's "
                         f"vertex: a virtual image plane (rays extended backwards to it); "
                         f"analysis only, no camera can record it")
        virtual[0] = True
    return d_sensor


def _refuse_image_before_vertex(lens, line: int, dist: float, sign: float, n_mirrors: int,
                                p: Locator) -> None:
    """Refuse, at ``line``, an image plane ``dist`` mm before the last vertex against the mirror
    parity (``sign``, the direction of travel there by :func:`~..frames.travel_directions`)
    after a curved mirror, saying whether the beam reaches it forwards (``lens``: the lens built
    with that plane as a virtual one, to trace).

    The beam: the on-axis field's chief ray and 48 rays on the rim of the paraxial entrance
    pupil, primary wavelength, apertures ignored.  Where each meets the plane ahead of where it
    leaves the last surface, the mirror is an off-axis section met far from its vertex at
    grazing incidence, which sends the beam on the way it came along its frame's axis
    (OpticStudio traces it there, moving rays along their lines; set 12's
    ``td_gracing_incidence_mirror_optimization``), while deeplens' direction of travel (and with
    it the paraxial data's signed indices) flips at every mirror: refused, saying so.  Otherwise (a slip
    of sign, a convex mirror's virtual image) the plane lies behind the beam: refused as
    before."""
    from ..intersect import propagate_distance
    from ..options import TraceOptions
    from ..paraxial import paraxial
    from ..sampling import field_rays

    what = (f"the image plane lies {dist:g} mm before the last surface's vertex (light travels "
            f"towards {'-' if sign < 0 else '+'}z there, after {n_mirrors} "
            f"mirror{'s' if n_mirrors != 1 else ''})")
    try:
        with torch.no_grad():
            par = paraxial(lens)
            half = 0.5 * float(par.entrance_pupil_diameter)
            phi = torch.arange(48, dtype=lens.dtype) * (2 * math.pi / 48)
            pts = torch.cat([torch.zeros(1, 2, dtype=lens.dtype),
                             torch.stack([torch.cos(phi), torch.sin(phi)], -1) * half])
            rays = field_rays(lens, 0.0, float(lens.spec.primary_wavelength_nm), pts,
                              float(par.entrance_pupil_z))
            out = lens.trace(rays, options=TraceOptions(clip_aperture=False))
            t, ok = propagate_distance(out.o[..., 2], out.d[..., 2], out.valid,
                                       lens.z_sensor().to(out.o), backwards=True)
    except (ValueError, RuntimeError):   # no pupil or beam to trace: the refusal as it was
        t, ok = torch.zeros(1), torch.zeros(1, dtype=torch.bool)
    if bool(ok[0]) and bool((t[ok] > 0).all()):
        p.fail(line, f"{what}, yet the beam reaches it forwards ({float(t[ok].min()):.6g} to "
                     f"{float(t[ok].max()):.6g} mm on): the last mirror is met far from its "
                     f"vertex (an off-axis section at grazing incidence) and keeps the beam's "
                     f"direction, which deeplens' mirror parity cannot express: not supported")
    p.fail(line, f"{what}: a virtual image plane after mirrors is read only where the "
                 f"thicknesses after the last mirror, a flat one, already run against the "
                 f"direction of travel (OpticStudio's virtual propagation)")


def _refuse_flat_sensor_cut(seq: _Sequence, img: ZmxSurface, surfs: list, d_sensor: float,
                            s_mm: float, primary: float, p: Locator) -> None:
    """Refuse, at the image surface's line, a curved image surface (``CURV`` != 0, read as
    deeplens' flat sensor at its vertex) whose vertex plane the last surface crosses, saying by
    how much and whether the file's own curved surface clears it.

    OpticStudio traces to the image surface as it is (a Petzval-curved focal surface, as in a
    Schmidt camera); deeplens' sensor is a plane, and the plane through that surface's vertex
    cuts the last surface where its rim runs beyond it (set 12's ``ob_HoO-V2C18Ex36``, a
    catadioptric camera whose field-flattener reaches 0.135 mm beyond the plane at its
    semi-diameter): rays meeting the rim there could not reach such a sensor.  The sag is
    sampled as :meth:`~deeplens.optics.lens.Lens.check` samples it (65 radii to the last
    surface's semi-diameter, 8 azimuths)."""
    from ..surfaces.base import in_closed_domain

    kept = seq.kept
    last = max((i for i, k_ in enumerate(kept) if k_[0].law != "stop"), default=len(kept) - 1)
    surf = kept[last][0]
    sign = float(travel_directions([k_[0] for k_ in kept], seq.mirrors,
                                   _axis_indices(seq, primary), primary)[-1])
    to_plane = sum(k_[3] for k_ in kept[last + 1:]) + d_sensor   # last vertex -> the plane
    sd = float(surf.semi_diameter)
    c = img.curv / s_mm
    k = float(getattr(img, "coni", 0.0) or 0.0)
    with torch.no_grad():
        r = torch.linspace(0.0, sd, 65, dtype=torch.float64)
        zs = torch.stack([surf.sag(r * math.cos(a), r * math.sin(a)).to(torch.float64)
                          for a in (i * math.pi / 4 for i in range(8))])
        ok = torch.stack([in_closed_domain(surf, r * math.cos(a), r * math.sin(a))
                          for a in (i * math.pi / 4 for i in range(8))])
    zs = torch.where(ok, zs, torch.zeros_like(zs))
    reach = float((sign * zs).max()) - sign * to_plane
    # the file's image surface (a conic of CURV, CONI) about the same vertex: where it is
    # defined, does the last surface stay before it?
    rr = r.unsqueeze(0).expand_as(zs)
    disc = 1.0 - (1.0 + k) * c * c * rr * rr
    img_sag = torch.where(disc >= 0, c * rr * rr / (1.0 + torch.sqrt(disc.clamp(min=0.0))),
                          torch.full_like(rr, float("nan")))
    gap = sign * (to_plane + img_sag - zs)
    clears = bool((torch.nan_to_num(gap, nan=1.0) >= -1e-9).all())
    p.fail(img.line, f"the image surface is curved (R {1.0 / c:.6g} mm) and deeplens' sensor is "
                     f"the plane at its vertex, which SURF {surfs.index(kept[last][2])} crosses: "
                     f"it reaches {reach:.4g} mm beyond that plane within its semi-diameter "
                     f"{sd:.4g} mm{', where the curved image surface clears it' if clears else ''}"
                     f"; a curved sensor is not supported")


def _note_reversed_ideal_lenses(kept: list, signs: list, p: Locator) -> None:
    """One located note per ``PARAXIAL`` / ``PARAX_XY`` surface met while the light travels
    towards ``-z`` (``signs``: :func:`~..frames.travel_directions` of the kept surfaces): deeplens
    takes its focal length (or power) along the direction of travel, a positive one converging
    the beam as it travels, in its real trace (:meth:`~..surfaces.IdealLens.deflect`) and its
    paraxial data alike, as rayoptics does and as a file's own thickness to the focus after it
    says (``PARM 1 f`` then ``DISZ -f`` after a mirror); optiland 0.6 makes such a lens diverge.
    OpticStudio's manual pages at hand do not say which, so the choice is named where it is made
    (docs/guide/zemax.md, A seventh unseen set)."""
    for i, (surf, _mat, block, _gap) in enumerate(kept):
        if isinstance(surf, (IdealLens, IdealLensXY)) and signs[i + 1] < 0:
            p.note(block.type_line or block.line,
                   f"{block.type}: the light travels towards -z here (after a mirror); deeplens "
                   f"takes the focal length (or power) along the direction of travel, so a "
                   f"positive one converges the beam as it travels (a collimated beam focuses "
                   f"f further on, at DISZ -f), as rayoptics reads it; optiland 0.6 makes it "
                   f"diverge, and its EFL and focus differ")


def _drop_drawn_plane_after_image(seq: _Sequence, primary: float, p: Locator) -> None:
    """Drop from ``seq`` a last flat surface in one medium kept only for its drawn fixed DIAM
    (:func:`_drawn_only_plane`) where the image plane lies before it (the gap to the image runs
    against the direction of travel there), merging its gap into the image gap, with one note
    at its line.  Such a surface bends and stops no ray, so OpticStudio's rays reach it and go
    back along their lines to the image plane (virtual propagation, User Guide *Thicknesses*),
    landing where rays running straight from the surface before it land (set 13's
    ``ob_Imaging_Optics_Figure_7_55b``: a focal-plane dummy 0.0008 mm beyond the image plane
    after three mirrors)."""
    kept = seq.kept
    if len(kept) < 2 or not _drawn_only_plane(seq, len(kept) - 1):
        return
    sign = float(travel_directions([k_[0] for k_ in kept], seq.mirrors,
                                   _axis_indices(seq, primary), primary)[-1])
    if not sign * seq.gap < 0:
        return
    last = kept.pop()
    seq.media.pop()
    seq.autos[:] = [i for i in seq.autos if i < len(kept)]
    p.note(last[2].line, f"the image plane lies {abs(seq.gap):g} mm before this flat surface "
                         f"in one medium, whose fixed DIAM never clips (no refractive power, "
                         f"no surface aperture): rays go back along their lines to the image "
                         f"plane (OpticStudio's virtual propagation), so it is dropped and its "
                         f"gap merged into the image's")
    seq.gap = last[3] + seq.gap


def _drawn_only_plane(seq: _Sequence, i: int) -> bool:
    """Whether kept surface ``i`` is a flat surface in one medium kept only for a fixed DIAM
    that never clips (:func:`.zmx_surfaces.build_surface`: no refractive power, no surface
    aperture, OpticStudio User Guide *Semi-Diameters*): not the stop, not a mirror, no
    bracketed element ending or starting there, nothing but an automatic semi-diameter."""
    if i <= 0 or i == seq.stop_idx or i in seq.mirrors or i not in seq.autos:
        return False
    surf, mat, s, _ = seq.kept[i]
    prev = seq.media[i]   # (media[0] is the object's medium: media[i] is the one before i)
    if type(surf) is not Aperture or getattr(surf, "spider", None) is not None:
        return False
    if any(getattr(s, a, None) is not None for a in ("clap", "sqap", "obsc", "elap", "elob",
                                                        "spid", "obsc_inner")):
        return False
    if any(a <= i <= b for a, b, _, _ in seq.groups):
        return False
    return type(mat) is type(prev) and mat.name == prev.name and s.curv == 0


def _virtual_before_image(seq: _Sequence, signs) -> bool:
    """Whether the last mirror is flat and the last non-zero thickness after it opposes the
    direction of travel there (the light after the mirror already propagates virtually)."""
    kept, last = seq.kept, max(seq.mirrors)
    if not getattr(kept[last][0], "is_flat", False):   # as _virtual_gaps: flat mirrors only
        return False
    for i in range(len(kept) - 1, last, -1):
        d = kept[i][3]
        if d != 0:
            return d * signs[i] < 0
    return False


def _aperture(sysd: dict, seq: _Sequence, obj_dist: float, s_mm: float, p: Locator,
              stop_size: str = "limiting"):
    """``(type, value, line, convert)`` of the system aperture: ``ENPD`` (scaled to mm),
    ``FNUM v 0`` or ``FLOA`` as deeplens' ``epd``/``fno``/``stop``; an aperture deeplens does not
    take directly (``FNUM v 1``, ``OBNA``) as a provisional ``epd`` of 1 with ``convert`` =
    ``(kind, value, line)``, turned into the EPD it defines once the lens is built.  A stop with
    no semi-diameter under ``FLOA`` is refused here with ``stop_size="refuse"`` or without a
    fixed aperture to limit the beam (:func:`~.zmx_stop_size.check_stop_size`)."""
    ap = sysd["aperture"]
    if ap is None:
        p.fail(0, "no system aperture (ENPD, FNUM or FLOA line)")
    ap_type, ap_value, ap_line = ap
    if ap_type in ("epd", "fno") and not ap_value > 0:
        # the aperture value sizes the pupil (an EPD in lens units, an F-number); 0 is the empty
        # value of a new or unfinished file (a short course's start file): no ray enters
        key, what, why = (("ENPD", "entrance-pupil diameter", "no ray enters") if ap_type == "epd"
                          else ("FNUM", "F-number", "a cone of no finite angle"))
        p.fail(ap_line, f"{key} {ap_value:g}: the system aperture's {what} must be > 0 (0 is an "
                        f"unset aperture, as in a new or unfinished file: {why})")
    if ap_type == "epd":
        ap_value *= s_mm
    convert = None     # an aperture given another way, turned into an EPD once the lens is built
    if ap_type in ("wfno", "obna", "cone"):
        if ap_type != "wfno" and math.isinf(obj_dist):
            p.fail(ap_line, "OBNA (object-space numerical aperture / cone angle) needs an object "
                            "at a finite distance")
        if not ap_value > 0:
            p.fail(ap_line, f"the aperture value must be > 0, got {ap_value!r}")
        convert = (ap_type, ap_value, ap_line)
        ap_type, ap_value = "epd", 1.0
    if ap_type == "stop" and seq.stop_idx in seq.autos:
        check_stop_size(seq, stop_size, p)   # refused, or floated to the limit once built
    if ap_type == "stop":
        s = seq.kept[seq.stop_idx][2]
        if s.clap is not None and s.diam > 0 and s.clap[0] != s.diam:
            # the file gives the stop two sizes; deeplens takes a CLAP as the surface's
            # semi-diameter (zmx_surfaces.build_surface), so the pupil floats on it
            p.note(s.clap[1], f"FLOA (float by stop size): the stop's CLAP radius {s.clap[0]:g} "
                              f"and its DIAM {s.diam:g} "
                              f"({'fixed' if s.diam_fixed else 'automatic'}) differ; the pupil "
                              f"floats on the CLAP's radius (EPD in proportion: "
                              f"x {s.clap[0] / s.diam:.6g} against the DIAM's); give both the "
                              f"same value to choose")
    return ap_type, ap_value, ap_line, convert


def _float_stop_to_the_limit(lens: Lens, seq: _Sequence, surfs, where_of: dict,
                             p: Locator, original: dict | None = None) -> None:
    """Under ``FLOA``, a stop with no semi-diameter: set it to the largest on-axis beam the
    fixed apertures pass (:func:`~.zmx_stop_size.limiting_stop_radius`), with one located note
    at its ``SURF`` line, and check the lens again (a lens surface as the stop may now cross
    its neighbour; ``original``: the file's semi-diameters of surfaces limited where they
    cross, which size the beam)."""
    r, i = limiting_stop_radius(lens, seq, p, original)
    k = seq.stop_idx
    blk, lim = seq.kept[k][2], seq.kept[i][2]
    with torch.no_grad():
        lens.surfaces[k].semi_diameter.fill_(r)
    try:
        lens.check()
    except ValueError as e:
        raise _located(p, e, where_of) from e
    p.note(blk.line, f"the stop (SURF {surfs.index(blk)}) has no semi-diameter under FLOA; it is "
                     f"set to {r:.6g} mm, the largest on-axis beam the surfaces' fixed apertures "
                     f"pass (paraxial marginal ray; SURF {surfs.index(lim)} limits, semi-diameter "
                     f"{(original or {}).get(i, float(lens.surfaces[i].semi_diameter)):.6g} "
                     f"mm); pass stop_size='refuse' "
                     f"(--stop-size refuse) to refuse instead")


def _check_stop_clear_aperture(lens: Lens, s: ZmxSurface, s_mm: float, p: Locator) -> None:
    """A ``CLAP`` on the stop surface narrower than the stop that the ``ENPD``/``FNUM``/``OBNA``
    aperture defines: in OpticStudio the pupil keeps the size the system aperture gives it (EPD,
    F-number, paraxial data) and the clear aperture vignettes its rim.  On a lens or mirror
    surface (:class:`~deeplens.optics.surfaces.Asphere`) the stop keeps its paraxial radius as
    its semi-diameter and the ``CLAP`` becomes its ``clear_radius`` (the opening is the smaller
    one); a flat stop in air (an :class:`Aperture` with a centred circular opening, with or
    without a central obscuration) is read the same way as a flat ``Asphere``
    (:func:`~.stop_clear.flat_stop_as_asphere`); other stops (a cylinder, a polynomial, a ring
    baffle) are refused.  (A ``SQAP`` on a lens or mirror stop is its rectangular opening within
    the stop's circle, set when the surface was built.)"""
    if s.clap is None or lens.spec.aperture_type == "stop":
        return
    clap = s.clap[0] * s_mm
    stop = lens.surfaces[lens.stop_index]
    sd = float(stop.semi_diameter)
    if not clap < sd * (1 - 1e-9):
        return
    if plain_circular_stop(stop):
        try:
            stop = flat_stop_as_asphere(lens)
        except ValueError as e:
            p.fail(s.clap[1], f"CLAP on the stop surface: its clear radius {clap:g} mm is "
                              f"smaller than the stop radius {sd:g} mm that the system "
                              f"aperture defines; deeplens reads such a flat stop as a flat "
                              f"surface whose clear aperture vignettes the pupil, which the "
                              f"rays land on, and here they cannot ({e}); give the system "
                              f"aperture as FLOA, or an ENPD/FNUM the CLAP does not cut")
    if type(stop) is Asphere:
        with torch.no_grad():
            stop.clear_radius.fill_(clap)
        try:
            stop.check()
        except ValueError as e:
            p.fail(s.clap[1], f"CLAP on the stop surface: {e}")
        return
    p.fail(s.clap[1], f"CLAP on the stop surface: its clear radius {clap:g} mm is smaller "
                      f"than the stop radius {sd:g} mm that the system aperture defines, so "
                      f"it cuts the entrance pupil; deeplens has such a clear aperture on a lens "
                      f"or mirror surface and on a flat stop in air with a circular opening, "
                      f"not on a {_stop_kind(stop)} stop (give the system aperture as FLOA, or "
                      f"an ENPD/FNUM the CLAP does not cut)")


def _stop_kind(stop) -> str:
    """How a refusal names the stop's type."""
    if type(stop) is not Aperture:
        return type(stop).__name__
    if stop.shape != "circle":
        return f"{stop.shape} Aperture"
    return ("ring-obscured" if float(stop.obscuration_inner) > 0 else "obscured") + " Aperture"


def _diam_only(kept, stop_idx: int, i: int) -> bool:
    """Whether kept surface ``i``'s semi-diameter comes from its ``DIAM`` alone: no surface
    aperture (``CLAP``, ``SQAP``, ``ELAP``) and not the stop (whose radius is the pupil's)."""
    s = kept[i][2]
    return i != stop_idx and s.clap is None and s.sqap is None and s.elap is None


def _estimated(kept, stop_idx: int, i: int) -> bool:
    """Whether kept surface ``i``'s semi-diameter is only an estimate of the beam's footprint:
    an automatic ``DIAM`` (flag 0, OpticStudio's own estimate written to the file, or none),
    not fixed (:func:`_diam_only`)."""
    return _diam_only(kept, stop_idx, i) and not kept[i][2].diam_fixed


def _fixed_diam(kept, stop_idx: int, i: int) -> bool:
    """Whether kept surface ``i``'s semi-diameter is a ``DIAM`` the file fixes (flag 1;
    :func:`_diam_only`)."""
    return _diam_only(kept, stop_idx, i) and kept[i][2].diam_fixed


def _limitable(kept, stop_idx: int, i: int) -> bool:
    """Whether kept surface ``i``'s semi-diameter may be limited where it crosses another's:
    an estimate (:func:`_estimated`) or a ``DIAM`` the file fixes (:func:`_fixed_diam`).

    OpticStudio's semi-diameters, fixed or automatic, size the drawing and do not vignette
    (only surface apertures do: ``CLAP``, ``SQAP``, ``ELAP``, which are never limited); where
    two of them cross, OpticStudio still traces every ray, those beyond the crossing backwards
    through the gap.  deeplens takes a semi-diameter as the surface's clear aperture, so it
    limits both to the crossing (:func:`_limit_at_crossing`) or, where the on-axis beam reaches
    past it, traces the gap backwards as OpticStudio does
    (:func:`_cross_backwards_where_the_beam_passes`), with a located warning either way."""
    return _estimated(kept, stop_idx, i) or _fixed_diam(kept, stop_idx, i)


def _limit_at_crossing(e: SurfacesCrossError, surfaces, estimated, limited: dict,
                       original: dict | None = None) -> bool:
    """Two surfaces whose *estimated* semi-diameters (:func:`_estimated`) overlap where they
    cross (``e``): both are limited to the radius where they meet and the pair is recorded in
    ``limited`` (``original``: each surface's semi-diameter before its first limit);
    ``False`` (nothing changed) when either semi-diameter is the file's own, or both already
    lie within that radius.

    OpticStudio's automatic semi-diameters are footprints of rays that it traces even where
    the next surface lies *behind* the ray (a negative propagation distance: rays beyond the
    radius where two surfaces meet travel backwards through the gap, a rim that cannot be
    made).  deeplens traces forwards only unless the gap is one of the lens's
    :attr:`~deeplens.optics.lens.Lens.backward_gaps`: limiting the estimates builds the lens,
    and :func:`_cross_backwards_where_the_beam_passes` opts the gap in (and restores the estimates)
    where the on-axis beam itself reaches past the crossing."""
    i, j = e.surfaces
    if not (estimated(i) and estimated(j)):
        return False
    changed = False
    with torch.no_grad():
        for k in (i, j):
            sd = surfaces[k].semi_diameter
            if float(sd) > e.radius:
                if original is not None:
                    original.setdefault(k, float(sd))
                sd.fill_(e.radius)
                changed = True
    if changed:
        limited[(i, j)] = e.radius
    return changed


def _virtual_gaps(seq: _Sequence, surfaces, distances, primary: float, where_of: dict,
                  p: Locator) -> list[tuple[int, tuple[str, str, str]]]:
    """Gaps after a mirror whose thickness opposes the direction of travel (the traced axis,
    :func:`travel_directions`): OpticStudio's *virtual propagation* (its thickness-sign rule:
    after an odd number of mirrors a positive thickness is virtual; the sequential trace takes
    the rays back along their lines, the optical path decreasing).  A beam-splitter cube
    written with the thickness after a flat mirror left positive is one.  Read so only after a
    *flat* mirror (the last one before the gap): after a curved mirror a thickness of the wrong
    sign is more likely a slip than a virtual system, and stays an error.  A gap runs from one
    real surface to the next (stops and coordinate breaks between them); its thicknesses are
    summed within each frame and each sum compared with the direction there.  Each such gap
    becomes one of the lens's :attr:`~deeplens.optics.lens.Lens.backward_gaps`, with a
    located warning (:func:`_note_virtual_gaps`, which first takes out a surface turned about
    a pivot); before the first mirror such a thickness is still an error (``Lens`` reports
    it).  Returns ``(q, (item, detail, shown))`` for each gap, ``q`` the surface after it and
    the rest :meth:`~.zmx_parse.Locator.note_each`'s arguments for its note."""
    if not seq.mirrors:
        return []
    signs = travel_directions(surfaces, seq.mirrors, _axis_indices(seq, primary), primary)
    first = min(seq.mirrors)
    out, prev = [], None
    for q, s in enumerate(surfaces):
        if s.law in ("frame", "stop"):
            continue
        last_mirror = max((m for m in seq.mirrors if m < q), default=None)
        if (prev is not None and q > first
                and getattr(surfaces[last_mirror], "is_flat", False)):
            against, seg = [], 0.0
            for k in range(prev + 1, q + 1):
                seg += distances[k]
                if k == q or surfaces[k].law == "frame":   # the end of a frame's stretch
                    if seg * signs[k] < 0:
                        against.append(seg)
                    seg = 0.0
            if against:
                mm = ", ".join(f"{v:g}" for v in against)
                out.append((q, (f"deeplens surface {q}",
                                f"{mm} mm, light travelling towards "
                                f"{'+' if signs[q] > 0 else '-'}z there",
                                f"surface {q}: {mm} mm")))
        prev = q
    return out


def _note_virtual_gaps(lens, gaps: list, where_of: dict, p: Locator) -> None:
    """The located note of each of :func:`_virtual_gaps`' gaps, once the lens is built; a gap
    into a surface right after coordinate breaks whose vertex, placed through them, lies
    *ahead* of the surface before the breaks along the traced axis
    (:meth:`~deeplens.optics.lens.Lens._ahead_across_breaks`) is no virtual propagation but a
    surface turned about a pivot (OpticStudio's scan-mirror idiom, read so before any mirror
    too: ``Lens.check``): only the frames between moved backwards, the rays meet it ahead of
    them, and the gap leaves the lens's backward gaps, without a note."""
    for q, (item, detail, shown) in gaps:
        ahead = lens._ahead_across_breaks(q)
        if ahead is not None and ahead[1] > 0:
            lens.backward_gaps = lens.backward_gaps - {q}
        else:
            p.note_each(where_of[q], _AGAINST, item, detail, shown)


def _roof_gaps(lens, where_of: dict, p: Locator) -> None:
    """Two mirrors at one vertex with only coordinate breaks between them (a roof written as
    OpticStudio's Amici prism files write it: each mirror tilted by its own break pair): half
    of the beam meets the second mirror's plane before the first, and OpticStudio's sequential
    trace takes it back to it (a negative propagation distance).  The gap becomes one of the
    lens's :attr:`~deeplens.optics.lens.Lens.backward_gaps`, with one located warning."""
    for i, j in lens._real_neighbours(across_breaks=True):
        if not (i in lens.mirrors and j in lens.mirrors and
                any(lens.surfaces[k].law == "frame" for k in range(i + 1, j)) and
                all(float(lens.distances[k]) == 0.0 for k in range(i + 1, j + 1))):
            continue
        lens.backward_gaps = lens.backward_gaps | {j}
        p.note_each(where_of[j], _ROOF, _pair_blocks(where_of, i, j))


def _cross_backwards_where_the_beam_passes(lens, limited: dict, where_of: dict, p: Locator,
                                 original: dict | None = None, redo_autos=None,
                                 fixed=frozenset()) -> None:
    """Each pair of surfaces limited at their crossing (:func:`_limit_at_crossing`): where the
    on-axis beam of the file's pupil (real rays at the primary wavelength over the paraxial
    entrance pupil's rim, apertures ignored) reaches past the crossing radius, OpticStudio
    traces the rays beyond it backwards through the gap (a negative propagation distance):
    the gap becomes one of the lens's :attr:`~deeplens.optics.lens.Lens.backward_gaps`, the
    two surfaces get their estimates back (``original``; ``redo_autos`` re-derives the
    automatic semi-diameters of surfaces without ``DIAM`` once rays may cross it backwards)
    and one located warning says so.  Pairs are taken in the light's order, and the beam is
    traced again after each (a ray lost at a surface keeps its last position in the later
    records, so only the first pair reached past its crossing is certain).  For the other
    pairs a located warning says which radius the rays of other fields are vignetted at
    (``fixed``: the surfaces whose semi-diameter the file fixes, named so in it)."""
    original = {} if original is None else original
    while True:
        reach, half = _beam_reach(lens, limited)
        over = [(i, j) for (i, j), r in sorted(limited.items())
                if j not in lens.backward_gaps and reach[(i, j)] > r * (1 + 1e-9)]
        if not over:
            break
        i, j = over[0]
        r = limited[(i, j)]
        lens.backward_gaps = lens.backward_gaps | {j}
        kept_limits = [(pair, rr) for pair, rr in limited.items()
                       if pair[1] not in lens.backward_gaps]
        with torch.no_grad():
            for k in (i, j):
                if k in original:   # the estimate, within the crossings still limited
                    sd = min([original[k]] + [rr for pair, rr in kept_limits if k in pair])
                    lens.surfaces[k].semi_diameter.fill_(sd)
        p.note_each(where_of[j], _BACKWARDS, _pair_blocks(where_of, i, j),
                    f"cross at r = {r:.6g} mm (a negative edge thickness beyond it), and the "
                    f"on-axis beam of the file's pupil (entrance-pupil diameter {2 * half:.6g} "
                    f"mm) reaches r = {reach[(i, j)]:.6g} mm there",
                    f"surfaces {i}/{j}: cross at r = {r:.6g} mm, beam to r = "
                    f"{reach[(i, j)]:.6g} mm")
        if redo_autos is not None:
            redo_autos()
        try:
            lens.check()
        except ValueError as e:
            raise _located(p, e, where_of) from e
    for (i, j), r in sorted(limited.items()):
        if j in lens.backward_gaps:
            continue
        kind = {0: "automatic", 1: "fixed (DIAM flag 1) and automatic",
                2: "fixed (DIAM flag 1)"}[(i in fixed) + (j in fixed)]
        why = ("OpticStudio's semi-diameters do not vignette and it traces rays beyond the "
               "crossing backwards through the gap (a negative propagation distance), deeplens "
               "vignettes them (the on-axis beam is not affected)")
        p.note_each(where_of[j],
                    Cause(one=f"the {kind} semi-diameters of the {{item}} overlap where the "
                              f"surfaces cross, at r = {{detail}}: both are limited to it; {why}",
                          many=f"the {kind} semi-diameters of {{n}} pairs of surfaces overlap "
                               f"where they cross ({{items}}): each is limited to the crossing; "
                               f"{why}"),
                    _pair_blocks(where_of, i, j),
                    f"{r:.6g} mm (the on-axis beam reaches r = {reach[(i, j)]:.6g} mm)",
                    f"surfaces {i}/{j} at r = {r:.6g} mm")


def _pair_blocks(where_of: dict, i: int, j: int) -> str:
    return f"deeplens surfaces {i} and {j} (SURF blocks on lines {where_of[i]} and {where_of[j]})"


#: one warning per file for each of these (``{item}``: a pair of surfaces, or one)
_BACKWARDS = Cause(
    one="the {item} {detail}: OpticStudio traces the rays beyond the crossing "
        "backwards through the gap (a negative propagation distance, the optical path "
        "decreasing), a lens that cannot be made as drawn; deeplens does the same for this gap "
        "(Lens.backward_gaps) and keeps the file's semi-diameters there",
    many="{n} pairs of surfaces cross where the on-axis beam of the file's pupil passes "
         "({items}): OpticStudio traces the rays beyond each crossing backwards through the gap "
         "(a negative propagation distance, the optical path decreasing), a lens that cannot be "
         "made as drawn; deeplens does the same for these gaps (Lens.backward_gaps) and keeps "
         "the file's semi-diameters there")
_ROOF = Cause(
    one="the mirrors, {item}, meet at one vertex, turned by coordinate breaks (a roof): rays "
        "that meet the second mirror's plane before the first are traced back to it, as "
        "OpticStudio's sequential trace does (Lens.backward_gaps)",
    many="{n} pairs of mirrors ({items}) meet at one vertex each, turned by coordinate breaks "
         "(roofs): rays that meet the second mirror's plane before the first are traced back to "
         "it, as OpticStudio's sequential trace does (Lens.backward_gaps)")
_AGAINST = Cause(
    one="the gap before {item} runs against the direction of travel after the mirror ({detail}): "
        "OpticStudio's virtual propagation, the rays taken back along their lines (the optical "
        "path decreasing); deeplens does the same for this gap (Lens.backward_gaps)",
    many="{n} gaps run against the direction of travel after a mirror (before {items}): "
         "OpticStudio's virtual propagation, the rays taken back along their lines (the optical "
         "path decreasing); deeplens does the same for these gaps (Lens.backward_gaps)")


def _beam_reach(lens, limited: dict):
    """``(reach, half)``: per pair of ``limited``, the largest radius (mm) the on-axis beam of
    the paraxial entrance pupil's rim (48 rays, primary wavelength, apertures ignored)
    reaches on either surface, and the pupil's radius (mm)."""
    from ..options import TraceOptions
    from ..paraxial import paraxial
    from ..sampling import field_rays

    with torch.no_grad():
        par = paraxial(lens)
        half = 0.5 * float(par.entrance_pupil_diameter)
        phi = torch.arange(48, dtype=lens.dtype) * (2 * math.pi / 48)
        pts = torch.stack([torch.cos(phi), torch.sin(phi)], -1) * half
        rays = field_rays(lens, 0.0, float(lens.spec.primary_wavelength_nm), pts,
                          float(par.entrance_pupil_z))
        _, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
    reach = {(i, j): max(float(torch.nan_to_num(torch.linalg.vector_norm(hits[k][:, :2], dim=-1),
                                                nan=0.0).max()) for k in (i, j))
             for (i, j) in limited}
    return reach, half


def _domain_cap(surf) -> float:
    """The largest automatic semi-diameter (mm) ``surf`` takes: a conic's domain edge ``0.999 /
    (|c| sqrt(1 + k))`` (its vertex curvature ``c``, conic ``k``), or, for a surface that states
    its own extent (``domain_radius()``: a :class:`~..surfaces.LensletArray`, whose lenslets'
    conics repeat across the array), that extent; ``inf`` otherwise."""
    own = getattr(surf, "domain_radius", None)
    if own is not None:
        return float(own())
    c = float(surf.paraxial_curvature())
    k = float(getattr(surf, "k", 0.0)) if hasattr(surf, "k") else 0.0
    if c != 0 and 1 + k > 0:
        return 0.999 / (abs(c) * math.sqrt(1 + k))
    return math.inf


def paraxial_semi_diameters(lens, idx, field_deg: float) -> None:
    """Semi-diameters ``1.05 (|y_marginal| + |y_chief|)`` of the surfaces ``idx`` (in place):
    the paraxial marginal ray's and the full field's chief ray's heights (``field_deg``, the
    chief ray parallel to the axis for an object-space telecentric lens), capped below a
    conic's domain edge ``0.999 / (|c| sqrt(1 + k))`` (a lenslet array: its own extent,
    :func:`_domain_cap`).  The first estimate of automatic
    semi-diameters of the ``.zmx`` and CODE V readers."""
    from ..paraxial import media_indices, paraxial, trace_paraxial_ray

    with torch.no_grad():
        par = paraxial(lens)
        n = media_indices(lens)
        half = 0.5 * float(par.entrance_pupil_diameter)
        pos = float(par.entrance_pupil_position)
        s = float(lens.spec.object_distance_mm)
        t = math.tan(math.radians(field_deg))
        if math.isinf(s):
            ym0, um0 = half, 0.0
        else:
            um0 = half / (s + pos)
            ym0 = um0 * s
        one = torch.ones_like(n[0])
        _, _, hm = trace_paraxial_ray(lens, ym0 * one, um0 * one, n)
        if getattr(lens, "object_telecentric", False):   # chief ray parallel to the axis
            _, _, hc = trace_paraxial_ray(lens, -s * t * one, 0.0 * one, n)
        else:
            _, _, hc = trace_paraxial_ray(lens, -pos * t * one, t * one, n)
        for i in idx:
            surf = lens.surfaces[i]
            sd = 1.05 * (abs(float(hm[i])) + abs(float(hc[i])))
            surf.semi_diameter.fill_(min(sd, _domain_cap(surf)))


def _auto_semi_diameters(lens, idx, fields, where_of, p: Locator, limited=None, original=None):
    """Automatic semi-diameters of the surfaces ``idx``, as OpticStudio's: the largest height of
    the real rays that fill the pupil, over every field and wavelength.  A first paraxial
    estimate ``1.05 (|y_marginal| + |y_chief|)`` (full field) lets the lens be built; then rays
    over the paraxial entrance pupil enlarged by 2 % (48 rim points and the chief ray per field
    and wavelength, apertures ignored) are traced and each surface gets its largest hit radius.
    OpticStudio does not vignette on automatic semi-diameters, and the 2 % keep rim rays (and
    the slightly larger pupils of ray aiming) from being clipped by them.  Capped to the
    surface's domain (:func:`real_ray_semi_diameters`); then estimates of surfaces that cross are
    limited to where they meet."""
    real_ray_semi_diameters(lens, idx, fields)
    limited = {} if limited is None else limited
    while True:
        try:
            lens.check()
            return
        except SurfacesCrossError as e:
            if _limit_at_crossing(e, lens.surfaces, lambda i: i in idx, limited, original):
                continue
            raise _located(p, e, where_of, "with automatic semi-diameters (no DIAM): ") from e
        except ValueError as e:
            raise _located(p, e, where_of, "with automatic semi-diameters (no DIAM): ") from e


def real_ray_semi_diameters(lens, idx, fields) -> None:
    """Semi-diameters (mm, in place) of the surfaces ``idx``: the largest hit radius of real
    rays over the paraxial entrance pupil enlarged by 2 % (48 rim points and the chief ray per
    field in ``fields`` (degrees) and wavelength, apertures ignored), after the paraxial
    estimate :func:`paraxial_semi_diameters` that lets the rays through; capped to a conic's
    domain (:func:`_domain_cap`).  The ``.zmx`` reader's automatic semi-diameters (:func:`_auto_semi_diameters`) and the
    CODE V reader's for a lens with coordinate breaks."""
    from ..options import TraceOptions
    from ..paraxial import paraxial
    from ..sampling import field_rays

    with torch.no_grad():
        par = paraxial(lens)   # before the estimate (a stop-sized aperture's pupil moves with it)
        half = 0.5 * float(par.entrance_pupil_diameter)
    paraxial_semi_diameters(lens, idx, max(abs(f) for f in fields))
    with torch.no_grad():
        # real rays
        phi = torch.arange(48, dtype=lens.dtype) * (2 * math.pi / 48)
        unit = torch.cat([torch.zeros(1, 2, dtype=lens.dtype),
                          torch.stack([torch.cos(phi), torch.sin(phi)], -1)])
        pts = unit * (1.02 * half)
        z_ep = float(par.entrance_pupil_z)
        top = {i: 0.0 for i in idx}
        for f in dict.fromkeys(fields):
            for w in lens.spec.wavelengths_nm:
                rays = field_rays(lens, float(f), float(w), pts, z_ep)
                out, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False),
                                       record=True)
                ok = out.valid
                for i in idx:
                    if bool(ok.any()):
                        r = torch.linalg.vector_norm(hits[i][ok][:, :2], dim=-1)
                        top[i] = max(top[i], float(r.max()))
        for i in idx:
            if top[i] > 0:
                surf = lens.surfaces[i]
                surf.semi_diameter.fill_(min(top[i], _domain_cap(surf)))


def _afocal(lens) -> bool:
    from ..paraxial import paraxial

    return math.isinf(float(paraxial(lens).efl))


def _located(p: Locator, e: Exception, where_of: dict, prefix: str = "") -> ZemaxFileError:
    """The error ``e`` of the lens built from the file, located at the ``SURF`` block of the last
    deeplens surface it concerns (``e.surfaces``, a :class:`~deeplens.optics.errors.LensError`'s
    attribute), with each of those surfaces' block line named in the message; an error about the
    sensor (``e.key == "sensor"``) at the image surface's block (``where_of["sensor"]``)."""
    idx = [i for i in dict.fromkeys(getattr(e, "surfaces", ())) if i in where_of]
    lines = [f"deeplens surface {i} is the SURF block on line {where_of[i]}" for i in idx]
    text = str(e)
    m = re.match(r"surface (\d+) \((\w+)\): ", text)
    if m and int(m.group(1)) in where_of:   # Lens.check's "surface i (Type): ": deeplens' index,
        # not the file's SURF number (SURF 0 is the object): name the block as written
        i = int(m.group(1))
        rec = p.records.get(where_of[i])
        surf = rec.tokens[1] if rec is not None and len(rec.tokens) > 1 else "?"
        text = f"SURF {surf} ({m.group(2)}, deeplens surface {i}): {text[m.end():]}"
    msg = f"{prefix}{text}" + (f" ({'; '.join(lines)})" if lines else "")
    line = where_of[idx[-1]] if idx else (
        where_of.get("sensor", 0) if getattr(e, "key", None) == "sensor" else 0)
    return p.error(line, msg, surfaces=getattr(e, "surfaces", ()))


def _elements(kept, media, groups, p):
    """``[(first, last, misalignment or None, line)]`` covering every kept surface."""
    out = []
    g = {a: (a, b, d, ln) for a, b, d, ln in groups}
    i, start = 0, 0
    n = len(kept)
    while i < n:
        if i in g:
            a, b, d, ln = g[i]
            if start < i:
                p.fail(ln, f"the COORDBRK on line {ln} starts inside an element (before it: "
                           f"SURF line {kept[start][2].line}); it must bracket whole elements")
            if not (is_air(media[a]) and is_air(media[b + 1])):
                p.fail(ln, f"the COORDBRK on line {ln} does not bracket a whole element (glass "
                           f"before its first or after its last surface)")
            out.append((a, b, d, ln))
            i = start = b + 1
            continue
        if is_air(media[i + 1]) or isinstance(kept[i][0], Aperture):
            out.append((start, i, None, 0))
            start = i + 1
        i += 1
    if start < n:
        out.append((start, n - 1, None, 0))
    return out

