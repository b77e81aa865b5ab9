"""A sequential lens: surfaces, media, stop, sensor and per-element misalignment.

Geometry (global frame, mm): the optical axis is ``z``; vertex ``i`` sits at
``z_i = sum_{j<=i} distances[j]`` (``distances[0]`` is normally 0, placing the first vertex at the
origin) and the sensor at ``z_N-1 + d_sensor``.  ``materials[0]`` is the object-space medium and
``materials[i+1]`` the medium after surface ``i``.  A lens flagged ``virtual_image`` has a
virtual image plane instead: ``d_sensor`` lies *before* the last vertex (a negative lens's
virtual focus, as OpticStudio allows) and the move to it extends the rays backwards along their
lines; it is for analysis only (no camera can record it, :meth:`Lens.require_real_image`).
Light travels towards ``+z`` in forward (object-to-sensor) tracing and towards ``-z`` in
backward (sensor-to-object) tracing; the same module serves both, and tracing never modifies
the lens or its input rays.

Mirrors and folds (``docs/guide/mirrors.md``): a mirror (``mirrors=``) reflects (:mod:`.reflect`)
instead of refracting and reverses the direction of travel along the axis, so after an odd
number of mirrors the distances are negative (Zemax's convention; in general the sign of the
traced axis's local z component, :meth:`Lens.directions`, which mirrors tilted inside
coordinate-break pairs, as in a roof prism, can turn round without the count changing); a
:class:`~.surfaces.CoordinateBreak` changes the frame of every following surface (folds,
off-axis sections) and ray coordinates after it are in the new frame (:mod:`.frames`).

Each surface is intersected in its element's frame (:mod:`.misalignment`) by Newton's method with
one differentiable step (:mod:`.intersect`) and refracted by vector Snell's law (:mod:`.refract`).
An aperture stop is crossed, not landed on (:meth:`Lens._cross_stop`): it may lie inside a lens's
sag, so :meth:`Lens.check` orders and overlaps only the real surfaces around it.
How a whole trace runs (eager, checkpointed, or with ``TraceOptions(compile=...)`` through fused
``torch.compile`` kernels on a component-major ray state) is the tracer's business
(:mod:`.tracer`, :mod:`.compiled`); the lens describes the system and one surface's physics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import nn

from . import grin_trace, tracer
from .errors import LensError, SurfacesCrossError
from .frames import local_frames, traced_axes, travel_directions
from .intersect import (_safe_div, intersect, propagate_distance, stop_crossing_xyz,
                        trace_quadric)
from .materials import Air, Material, check_wavelength_nm
from .misalignment import Misalignment
from .options import TraceOptions
from .paraxial import epd_from_image_space_fno, paraxial
from .rays import Rays, compact_broadcast as _compact
from .surfaces import Surface
from .surfaces.base import in_closed_domain, make_param

__all__ = ["Lens", "LensSpec"]


@dataclass
class LensSpec:
    """How the lens is used: object distance, aperture, fields and wavelengths.

    Attributes:
        object_distance_mm: distance from the object plane to the first vertex (``inf``); a
            negative distance is a virtual object, ``|s|`` behind the first vertex (as in a
            relay fed by a converging beam): object-space rays are aimed at it and start before
            the first surface.  ``0`` puts the object at the first vertex, which a
            :class:`Lens` accepts only where its first surface is a coordinate break (the
            object at the break's pivot, in the frame before it: OpticStudio's object at
            ``DISZ 0`` before a ``COORDBRK``, which no ray meets).
        aperture_type: ``"stop"`` (the stop's own semi-diameter), ``"epd"`` (entrance-pupil
            diameter, mm) or ``"fno"`` (image-space F-number at infinity).
        aperture_value: the value for ``"epd"``/``"fno"`` (ignored for ``"stop"``).
        fields_deg: field angles in degrees (object-space chief-ray angle, in the y-z plane;
            for an object-space telecentric lens, ``Lens.object_telecentric``, whose chief rays
            are parallel to the axis: the object point's direction from the first vertex, object
            height ``-s tan θ``).
        wavelengths_nm: wavelengths in nm.
        primary_wavelength_nm: the wavelength of paraxial quantities (default: the first).
        wavelength_unit_stated: the wavelengths were read with their unit stated (a ``.zmx``
            file's ``WAVM``, µm by the format): the unit guards for bare numbers
            (:func:`~.materials.check_wavelength_nm`: above 100 µm looks like ångström or
            picometres) are not applied; every medium's range still is (:meth:`Lens.check`),
            so a millimetre-wave lens of constant-index media loads.
    """

    object_distance_mm: float = math.inf
    aperture_type: str = "stop"
    aperture_value: float | None = None
    fields_deg: list = field(default_factory=lambda: [0.0])
    wavelengths_nm: list = field(default_factory=lambda: [587.5618])
    primary_wavelength_nm: float | None = None
    wavelength_unit_stated: bool = False

    def __post_init__(self):
        if self.aperture_type not in ("stop", "epd", "fno"):
            raise LensError(f"aperture type must be 'stop', 'epd' or 'fno', got "
                            f"{self.aperture_type!r}", key="aperture")
        if self.aperture_type != "stop":
            v = self.aperture_value
            if v is None or not (float(v) > 0 and math.isfinite(float(v))):
                raise LensError(f"aperture {self.aperture_type}: value must be a positive number, "
                                f"got {v!r}", key="aperture")
        s = self.object_distance_mm
        if not (s >= 0 or (s < 0 and math.isfinite(s))):
            raise LensError(f"object distance must be > 0 mm (a real object; or inf), < 0 mm "
                            f"(a virtual object behind the first vertex) or 0 (at a first "
                            f"coordinate break's pivot), got {s!r}", key="object_distance_mm")
        if not len(self.fields_deg):
            raise LensError("at least one field angle is needed", key="fields_deg")
        for f in self.fields_deg:
            if not (math.isfinite(float(f)) and abs(float(f)) < 90.0):
                raise LensError(f"field angles must be finite and within (-90, 90) degrees, "
                                f"got {f!r}", key="fields_deg")
        if not len(self.wavelengths_nm):
            raise LensError("at least one wavelength is needed", key="wavelengths_nm")
        try:
            check_wavelength_nm(list(self.wavelengths_nm), where="lens wavelengths: ",
                                stated_unit=self.wavelength_unit_stated)
        except ValueError as e:
            raise LensError(str(e), key="wavelengths_nm") from None
        if self.primary_wavelength_nm is None:
            self.primary_wavelength_nm = float(self.wavelengths_nm[0])
        try:
            check_wavelength_nm(self.primary_wavelength_nm, where="primary wavelength: ",
                                stated_unit=self.wavelength_unit_stated)
        except ValueError as e:
            raise LensError(str(e), key="primary_wavelength_nm") from None


_DIR = {1: "+", -1: "-"}
# azimuths (degrees from +x) along which Lens.check samples surfaces for crossings: the y
# section first (where a crossing of rotationally symmetric surfaces is reported), then x, then
# every 22.5 degrees round the circle (surfaces without rotational symmetry, issue 38)
_CHECK_AZIMUTHS_DEG = (90.0, 0.0) + tuple(22.5 * k for k in range(16) if k not in (0, 4))


def _check_directions() -> tuple[torch.Tensor, torch.Tensor]:
    """``(cos φ, sin φ)`` of :data:`_CHECK_AZIMUTHS_DEG`, float64, shape ``(A, 1)`` each, exact
    0 and ±1 on the axes (so that the y section samples ``x = 0`` exactly)."""
    phi = torch.deg2rad(torch.tensor(_CHECK_AZIMUTHS_DEG, dtype=torch.float64)).unsqueeze(-1)
    cos_a, sin_a = torch.cos(phi), torch.sin(phi)
    snap = lambda t: torch.where(t.abs() < 1e-12, torch.zeros_like(t), t)  # noqa: E731
    return snap(cos_a), snap(sin_a)


def against_travel(surfaces, distances, sign) -> list[tuple[int, float, str]]:
    """The gaps whose distance opposes the direction of travel: ``(q, d, what)`` for each real
    surface ``q`` whose distance ``d`` (mm) from the surface before it (from the previous real
    surface across stops) has the sign opposite to ``sign[q]`` (:meth:`Lens.directions`);
    ``distances``: the ``N`` distances (floats, mm, ``Lens.distances``); ``what`` names the
    distance for a message.  A stop is crossed, not landed on (:meth:`Lens._cross_stop`): it
    may lie inside a lens's sag (a negative distance before or after it), so order is checked
    between consecutive *real* surfaces, the stops between them skipped; the distance before
    a coordinate break is not checked (the break is not a surface the light meets)."""
    pairs, prev = [], None
    for i, s in enumerate(surfaces):
        if s.law == "frame":
            prev = None
        elif s.law != "stop":
            if prev is not None and i > prev + 1:
                pairs.append((prev, i))   # across stops
            prev = i
    spans = [(i - 1, i) for i in range(1, len(surfaces))
             if surfaces[i].interaction.lands and surfaces[i - 1].law != "stop"] + pairs
    out = []
    for p, q in spans:
        d = distances[q] if q == p + 1 else math.fsum(distances[p + 1:q + 1])
        what = f"distance before surface {q}" if q == p + 1 else \
            f"distance from surface {p} to surface {q} (across the stop between them)"
        if (d < 0 and sign[q] > 0) or (d > 0 and sign[q] < 0):
            out.append((q, d, what))
    return out


def _after_mirrors(mirrors, i: int) -> str:
    """`` (after k mirrors)`` for a message about the space before surface ``i`` ('' if none)."""
    k = sum(1 for j in mirrors if j < i)
    return f" (after {k} mirror{'s' if k != 1 else ''})" if k else ""


def _check_mirrors(mirrors, surfaces, materials) -> frozenset:
    """Validated mirror indices: surfaces that can reflect, with the same medium on both
    sides (a mirror does not change the medium; its sign is in the distances)."""
    out = set()
    for i in mirrors:
        if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < len(surfaces):
            raise LensError(f"mirror index {i!r} is not a surface index (0..{len(surfaces) - 1})",
                            key="mirrors")
        s = surfaces[i]
        if not s.interaction.reflects:   # a stop, a frame change, an ideal lens
            raise LensError(f"surface {i} ({type(s).__name__}) cannot be a mirror",
                            surfaces=(i,), key="mirrors")
        if materials[i + 1] is not materials[i] and materials[i + 1].to_spec() != \
                materials[i].to_spec():
            raise LensError(f"mirror surface {i}: the medium after it must be the medium before "
                            f"it ({materials[i].to_spec()}), got {materials[i + 1].to_spec()}",
                            surfaces=(i,), key="mirrors")
        out.add(int(i))
    return frozenset(out)


def _default_elements(surfaces, materials) -> list[tuple[int, int]]:
    """Group surfaces into rigid elements: a run of surfaces enclosing non-air media; a stop
    (or any surface with air on both sides) is an element of its own."""
    groups, start = [], 0
    for i in range(len(surfaces)):
        if isinstance(materials[i + 1], Air) or surfaces[i].law == "stop":
            groups.append((start, i))
            start = i + 1
    if start < len(surfaces):
        groups.append((start, len(surfaces) - 1))
    return groups


class Lens(nn.Module):
    """A sequential lens system (see the module docstring for geometry and conventions).

    Args:
        surfaces: ``N`` surfaces in order from object to image.
        materials: ``N + 1`` media: object space, then the medium after each surface.
        distances: ``N`` axial gaps in mm (``distances[i]`` from vertex ``i-1`` to vertex ``i``).
        d_sensor: gap from the last vertex to the sensor plane, mm.
        stop_index: index of the aperture-stop surface.
        sensor_semi_diameter: half the sensor diagonal, mm (``None``: unbounded).
        spec: :class:`LensSpec` (object distance, aperture, fields, wavelengths).
        elements: ``[(first, last), ...]`` surface-index ranges that move rigidly under
            misalignment (default: glass elements and the stop, from the media).
        name: a title.
        mirrors: indices of reflecting surfaces (their medium after is the medium before;
            see :meth:`directions` for the sign of the distances after them).
        virtual_image: the image plane is virtual: ``d_sensor`` must then lie *before* the
            last vertex (``< 0`` along the direction of travel), and :meth:`trace_to_sensor`
            extends the rays backwards to it (a negative distance: the optical path decreases,
            as in OpticStudio); analysis only, renderers and cameras with a sensor refuse it.
        backward_gaps: indices ``j`` of real surfaces (not stops or coordinate breaks) whose gap
            from the previous real surface may be crossed *backwards*: see :attr:`backward_gaps`.
        object_telecentric: the initial ``object_telecentric`` (below), set before the aperture
            is sized (a lens whose entrance pupil is at infinity needs it then).

    Attribute ``object_telecentric`` (default ``False``): the entrance pupil is at infinity
    (OpticStudio's telecentric object space, ``FTYP`` second value 1): every field's chief ray
    is parallel to the axis in object space and its pupil is a cone about it
    (:func:`~deeplens.optics.sampling.field_rays`); the object must be at a finite distance.

    Attribute ``object_tilt`` (default ``(0.0, 0.0)``): ``(tan_x, tan_y)``, the finite object
    plane's slopes: the object point at ``(x, y)`` lies at ``z = z_obj + tan_x x + tan_y y`` (in the
    object-space frame, before any coordinate break; ``z_obj`` the object vertex,
    ``object_distance_mm`` before the first vertex), as OpticStudio's *Tilted* surface is the plane
    ``z = x tan θ_x + y tan θ_y``.  Field points lie on it
    (:func:`~deeplens.optics.sampling.field_rays`); first-order data (about the axis, from the
    object vertex) do not depend on it.  Plain floats, not trained.

    Trainable values: each surface's prescription, ``distances[i]``, ``d_sensor`` and each
    element's :class:`Misalignment` are ``nn.Parameter`` objects created frozen; call
    ``requires_grad_(True)`` on the ones to optimise.

    Raises:
        ValueError: no or a bad stop, mismatched list lengths, surfaces that cross, or a
            semi-diameter beyond a surface's domain (each message names the surface).
    """

    def __init__(self, surfaces, materials, distances, d_sensor: float, stop_index: int | None,
                 sensor_semi_diameter: float | None = None, spec: LensSpec | None = None,
                 elements=None, name: str = "", mirrors=(), virtual_image: bool = False,
                 backward_gaps=(), object_telecentric: bool = False):
        super().__init__()
        surfaces, materials, distances = list(surfaces), list(materials), list(distances)
        n = len(surfaces)
        if n == 0:
            raise ValueError("a lens needs at least one surface")
        if len(materials) != n + 1:
            raise ValueError(f"a lens with {n} surfaces needs {n + 1} materials (object space "
                             f"first), got {len(materials)}")
        if len(distances) != n:
            raise ValueError(f"a lens with {n} surfaces needs {n} distances, got {len(distances)}")
        if stop_index is None:
            raise LensError("the lens has no aperture stop: give stop_index (an 'A' row in a "
                            "table file, or \"stop\" in a JSON lens file)", key="stop")
        if not 0 <= int(stop_index) < n:
            raise LensError(f"stop_index {stop_index} is not a surface index (0..{n - 1})",
                            key="stop")
        for i, s in enumerate(surfaces):
            if not isinstance(s, Surface):
                raise TypeError(f"surface {i} is a {type(s).__name__}, not a Surface")
        for i, m in enumerate(materials):
            if not isinstance(m, Material):
                raise TypeError(f"material {i} is a {type(m).__name__}, not a Material")
        self.name = name
        self.object_telecentric = bool(object_telecentric)   # before the aperture is sized
        self._object_tilt = (0.0, 0.0)
        self.surfaces = nn.ModuleList(surfaces)
        self.materials = nn.ModuleList(materials)
        self.distances = nn.ParameterList([make_param(v, f"distance {i}")
                                           for i, v in enumerate(distances)])
        self.d_sensor = make_param(d_sensor, "sensor distance")
        self.stop_index = int(stop_index)
        self.virtual_image = bool(virtual_image)
        self.mirrors = _check_mirrors(mirrors, surfaces, materials)
        if sensor_semi_diameter is not None and not (float(sensor_semi_diameter) > 0 and
                                                     math.isfinite(float(sensor_semi_diameter))):
            raise LensError(f"sensor semi-diameter must be a positive number of mm (or None), "
                            f"got {sensor_semi_diameter!r}", key="sensor")
        self.sensor_semi_diameter = (None if sensor_semi_diameter is None
                                     else float(sensor_semi_diameter))
        self.spec = spec if spec is not None else LensSpec()
        self.elements = [tuple(map(int, e)) for e in
                         (elements if elements is not None else _default_elements(surfaces,
                                                                                   materials))]
        for a, b in self.elements:  # before any range is built: a typo such as 10**12 in a
            if not 0 <= a <= b < n:  # lens file would otherwise allocate all memory
                raise LensError(f"the pair [{a}, {b}] must be surface indices with "
                                f"0 <= first <= last <= {n - 1}", key="elements")
        covered = sorted(i for a, b in self.elements for i in range(a, b + 1))
        if covered != list(range(n)):
            raise LensError(f"elements {self.elements} must cover surfaces 0..{n - 1} exactly "
                            f"once", key="elements")
        self.misalignments = nn.ModuleList([Misalignment() for _ in self.elements])
        self._element_of = {i: e for e, (a, b) in enumerate(self.elements) for i in range(a, b + 1)}
        self._backward = frozenset()
        self._backward_hit = (frozenset(), frozenset())
        self.backward_gaps = backward_gaps   # validated (no check yet: that follows)
        self.check()
        if self.spec.aperture_type != "stop":
            self.apply_aperture_spec()

    # ------------------------------------------------------------------ geometry
    @property
    def spec(self) -> LensSpec:
        """How the lens is used (:class:`LensSpec`).  Assigning one checks its object distance
        against the surfaces: ``0`` (the object at the first vertex) only before a first
        coordinate break, which no ray meets."""
        return self._spec

    @spec.setter
    def spec(self, spec: LensSpec) -> None:
        if spec.object_distance_mm == 0 and self.surfaces[0].law != "frame":
            raise LensError(f"object distance 0 puts the object on surface 0 (a "
                            f"{type(self.surfaces[0]).__name__}); the object may lie at the "
                            f"first vertex only when that is a coordinate break's pivot: give a "
                            f"distance > 0 (or < 0 for a virtual object)",
                            key="object_distance_mm")
        self._spec = spec

    @property
    def object_tilt(self) -> tuple[float, float]:
        """``(tan_x, tan_y)``: the object plane ``z = z_obj + tan_x x + tan_y y`` (class
        docstring); ``(0.0, 0.0)`` for a plane normal to the axis."""
        return self._object_tilt

    @object_tilt.setter
    def object_tilt(self, tangents) -> None:
        try:
            tx, ty = (float(v) for v in tangents)
        except (TypeError, ValueError):
            raise LensError(f"object tilt: expected two slopes (tan_x, tan_y), got "
                            f"{tangents!r}", key="object_tilt") from None
        if not (math.isfinite(tx) and math.isfinite(ty)):
            raise LensError(f"object tilt: the slopes (tan_x, tan_y) must be finite, got "
                            f"{tangents!r}", key="object_tilt")
        self._object_tilt = (tx, ty)

    @property
    def dtype(self) -> torch.dtype:
        """The floating-point type of the lens's values (``.to(dtype)`` changes it)."""
        return self.distances[0].dtype

    @property
    def device(self) -> torch.device:
        """The device the lens's values live on."""
        return self.distances[0].device

    @property
    def stop(self) -> Surface:
        return self.surfaces[self.stop_index]

    def z_vertices(self) -> torch.Tensor:
        """Vertex positions ``(N,)`` in mm (differentiable in ``distances``)."""
        return torch.cumsum(torch.stack(list(self.distances)), 0)

    def directions(self) -> list[int]:
        """The direction of travel along the local axis in each of the ``N + 1`` media: ``+1``
        (``+z``) in object space, then the sign of the traced axis's local ``z`` component
        after each surface (:func:`~.frames.travel_directions`: coordinate breaks turn it,
        mirrors reflect it about their vertex normals, refracting surfaces refract it and
        gratings diffract it in their order, at the primary wavelength).  Distances into a medium carry its sign.  Without coordinate
        breaks, and with folds written as ``break, mirror, break``, this is the mirror count's
        parity (negative after an odd number of mirrors, Zemax's convention); mirrors tilted
        inside break pairs that return the frame (a roof prism) can turn the beam round
        without the parity changing, and the traced axis follows them."""
        indices = None
        w = float(self.spec.primary_wavelength_nm)
        if any(s.interaction.changes_frame for s in self.surfaces):
            with torch.no_grad():
                indices = [float(m.n(torch.tensor(w, dtype=torch.float64)))
                           for m in self.materials]
        return travel_directions(list(self.surfaces), self.mirrors, indices, w)

    def folded(self) -> bool:
        """True when the lens has a mirror or a coordinate break (it then traces eagerly)."""
        return bool(self.mirrors) or any(s.interaction.changes_frame for s in self.surfaces)

    @property
    def backward_gaps(self) -> frozenset:
        """Gaps that rays may cross backwards, as OpticStudio's sequential trace does: the
        indices ``j`` of real surfaces whose gap from the previous real surface ``p`` (stops
        and coordinate breaks between them skipped) is opted in.  Empty by default: every gap
        is traced forwards only
        (a hit must lie ahead of the ray, ``t >= 0``) and surfaces that cross within their
        semi-diameters are an error (:meth:`check`).

        For a gap in the set, a ray reaches surface ``j`` (surface ``p`` when tracing in
        reverse) along its line whatever the sign of the distance: where two surfaces cross
        (a negative edge thickness beyond radius ``r``), rays beyond ``r`` travel back through
        the gap (``t < 0``) and their optical path *decreases* by ``n |t|``, which is what
        OpticStudio computes for such a file (the lens cannot be made as drawn).  The crossing
        check is waived for those pairs only.  Across coordinate breaks: the two mirrors of a
        roof written at one vertex (breaks tilting each, OpticStudio's Amici prism files): the
        half of the beam that meets the second mirror's plane first is traced back to it
        (``t < 0``, as OpticStudio's sequential trace does; both orders end on the same ray,
        the two reflections composing a 180-degree rotation about the ridge).  The root is the
        same one as forwards (the
        crossing in the direction of travel on the surface's own branch, ``h > 0``), so the far
        side of a sphere is never taken.

        A set of gap indices rather than one switch for the whole lens: only the gaps that
        need it accept backward hits; everywhere else a hit behind the ray still invalidates it
        and a crossing is still an error, so a typo elsewhere in a prescription is not hidden.
        The compiled trace (``TraceOptions(compile=...)``) runs the two surfaces of each such
        gap eagerly (:func:`~.tracer.fused_kind`) and the rest compiled, as before.
        Assigning a new set validates it (not the rest of the lens: call :meth:`check`).
        """
        return self._backward

    @backward_gaps.setter
    def backward_gaps(self, gaps) -> None:
        pairs = dict((q, p) for p, q in self._real_neighbours(across_breaks=True))
        out = set()
        for j in gaps:
            if isinstance(j, bool) or not isinstance(j, int) or j not in pairs:
                raise LensError(f"backward gap {j!r}: expected the index of a real surface "
                                f"after another one (not a stop, a coordinate break or the "
                                f"first surface); allowed: {sorted(pairs)}",
                                key="backward_gaps")
            out.add(int(j))
        self._backward = frozenset(out)
        # the surfaces hit through such a gap: forwards (j) and in reverse (p)
        self._backward_hit = (frozenset(out), frozenset(pairs[j] for j in out))

    def hit_backwards(self, i: int, reverse: bool = False) -> bool:
        """Whether surface ``i``, traced forwards (or in reverse), is reached through a gap of
        :attr:`backward_gaps` (a hit behind the ray is then accepted)."""
        return i in self._backward_hit[1 if reverse else 0]

    def z_sensor(self) -> torch.Tensor:
        return self.z_vertices()[-1] + self.d_sensor

    def check(self) -> None:
        """Validate the prescription; raises :class:`~.errors.LensError` (a ``ValueError``)
        naming the surface in its message and in ``surfaces``/``key``."""
        waves = [float(w) for w in self.spec.wavelengths_nm] + [
            float(self.spec.primary_wavelength_nm)]
        for i, m in enumerate(self.materials):
            medium = "object space" if i == 0 else f"the medium after surface {i - 1}"
            try:
                check_wavelength_nm(waves, m)
            except ValueError as e:
                raise LensError(f"lens wavelengths: {e} ({medium})",
                                surfaces=() if i == 0 else (i - 1,),
                                key="wavelengths_nm") from None
        for i, s in enumerate(self.surfaces):
            try:
                s.check(where=f"surface {i} ({type(s).__name__}): ")
            except ValueError as e:
                raise LensError(str(e), surfaces=(i,)) from None
            if s.interaction.same_medium:  # a stop does not refract: one medium on both sides
                with torch.no_grad():
                    w = torch.tensor(waves, dtype=torch.float64)
                    n1, n2 = self.materials[i].n(w), self.materials[i + 1].n(w)
                if not torch.allclose(n1, n2, rtol=0.0, atol=1e-9):
                    raise LensError(
                        f"surface {i} is an aperture stop between two different media (index "
                        f"{float(n1[0]):.6g} before, {float(n2[0]):.6g} after at "
                        f"{waves[0]:g} nm); a stop does not refract, so the medium must be the "
                        f"same on both sides: put the stop in a gap, or give the interface its "
                        f"own surface", surfaces=(i,))
        grin_trace.check_graded(self)
        sign = self.directions()
        z = self.z_vertices().detach()
        pairs = self._real_neighbours()
        for q, d, what in against_travel(list(self.surfaces),
                                         [float(v) for v in self.distances], sign):
            if q in self._backward:   # crossed backwards (OpticStudio's virtual propagation)
                continue
            ahead = self._ahead_across_breaks(q)
            if ahead is not None and ahead[1] > 0:
                continue   # a pivot: only the frames between moved backwards
            where = "" if ahead is None else (
                f"; its vertex, placed through the coordinate breaks before it, lies "
                f"{-ahead[1]:g} mm behind surface {ahead[0]} along the beam")
            if d < 0:
                raise LensError(f"{what} is negative ({d:g} mm){where}: sequential surfaces "
                                f"must be ordered along +z{_after_mirrors(self.mirrors, q)}",
                                surfaces=(q,))
            raise LensError(f"{what} is positive ({d:g} mm){where}: sequential surfaces must be "
                            f"ordered along -z, the direction of travel there"
                            f"{_after_mirrors(self.mirrors, q)}", surfaces=(q,))
        if self.virtual_image:
            if sign[-1] * float(self.d_sensor) >= 0:
                raise LensError(f"a virtual image plane (virtual_image) must lie before the "
                                f"last surface: the sensor distance must be "
                                f"{'<' if sign[-1] > 0 else '>'} 0 mm"
                                f"{_after_mirrors(self.mirrors, len(self.surfaces))}, got "
                                f"{float(self.d_sensor):g}", key="sensor")
        elif sign[-1] * float(self.d_sensor) <= 0:
            raise LensError(f"sensor distance must be {'>' if sign[-1] > 0 else '<'} 0 mm"
                            f"{_after_mirrors(self.mirrors, len(self.surfaces))}, got "
                            f"{float(self.d_sensor):g}", key="sensor")
        with torch.no_grad():
            for i, j in pairs:
                if j in self._backward:   # crossing surfaces traced backwards: allowed
                    continue
                a, b = self.surfaces[i], self.surfaces[j]
                r_max = min(float(a.semi_diameter), float(b.semi_diameter))
                # along several azimuths, not the y section only (issue 38: a biconic or any
                # surface without rotational symmetry may cross its neighbour along x while
                # the y sections stay apart); y first, so a crossing of rotationally symmetric
                # surfaces is reported where it was before
                cos_a, sin_a = _check_directions()                       # (A, 1) each
                r = torch.linspace(0, r_max, 65, dtype=torch.float64)    # (R,)
                x, y = r * cos_a, r * sin_a                              # (A, R)
                gap = (z[j] + b.sag(x, y) - z[i] - a.sag(x, y)) * sign[j]
                # only where both surfaces exist for the rays: inside both openings' outlines
                # (a rectangle's corners, not its circumscribed circle: a cube's diagonal
                # touches its faces at the edges; an obscuration's disc is still glass)
                # (a conic's rim included: two hemispheres of a ball meet there, and surfaces
                # that pass each other there cross, in_closed_domain)
                bad = ((gap < -1e-9) & in_closed_domain(a, x, y) & in_closed_domain(b, x, y)
                       & a.opening.outer.contains(x, y) & b.opening.outer.contains(x, y))
                if bool(bad.any()):
                    # the azimuth whose first crossing comes first (ties: the earlier azimuth)
                    first = torch.where(bad.any(-1), bad.int().argmax(-1), bad.shape[-1])
                    m = int(torch.argmin(first))
                    k = int(first[m])
                    deg = _CHECK_AZIMUTHS_DEG[m]
                    along = "" if deg == 90.0 else " along x" if deg == 0.0 else \
                        f" at azimuth {deg:g} deg from +x"
                    raise SurfacesCrossError(
                        f"surfaces {i} and {j} cross: at r = {float(r[k]):.4g} mm{along} surface "
                        f"{j} lies {float(-gap[m, k]):.4g} mm before surface {i} (distance "
                        f"between them {float(z[j] - z[i]):g} mm); increase the "
                        f"thickness or reduce the semi-diameters", surfaces=(i, j),
                        radius=self._crossing_radius(i, j, float(r[k - 1]) if k else 0.0,
                                                     float(r[k]), z, sign[j],
                                                     math.radians(deg)))
            last = max([i for i, s in enumerate(self.surfaces)
                        if s.law != "stop"], default=len(self.surfaces) - 1)
            s = self.surfaces[last]
            centre, radius = s.opening.bounds()
            if centre != (0.0, 0.0):
                # an off-axis segment (a decentred clear aperture: an off-axis parabola): only
                # its opening, sampled along the radius through its centre (a rotationally
                # symmetric sag is extreme there), and of it only what lies within the sensor's
                # semi-diameter when that is known (an OAP's focus lies beside its segment)
                c = torch.tensor(centre, dtype=torch.float64)
                u = c / torch.linalg.vector_norm(c)
                t = torch.linspace(-1.0, 1.0, 65, dtype=torch.float64)
                xy = c + (t * radius).unsqueeze(-1) * u
                if self.sensor_semi_diameter is not None:
                    xy = xy[torch.linalg.vector_norm(xy, dim=-1) <= self.sensor_semi_diameter]
                zl = z[last] + s.sag(xy[:, 0], xy[:, 1])
            else:   # along the same azimuths as the pairs above
                r = torch.linspace(0, float(s.semi_diameter), 65, dtype=torch.float64)
                cos_a, sin_a = _check_directions()
                zl = z[last] + s.sag(r * cos_a, r * sin_a)
            if (not self.virtual_image   # a virtual plane may cut the lens: nothing is there
                    and bool((sign[-1] * (zl - self.z_sensor().detach()) > 1e-9).any())):
                raise LensError(f"the last surface crosses the sensor plane (sensor distance "
                                f"{float(self.d_sensor):g} mm)", key="sensor")

    def _crossing_radius(self, i: int, j: int, lo: float, hi: float, z, sign: int,
                         azimuth: float = math.pi / 2) -> float:
        """The radius in ``[lo, hi]`` (mm) where surfaces ``i`` and ``j`` meet (their gap, along
        the direction of travel ``sign`` between them, changes sign) along the ``azimuth``
        (radians from +x; the default is the +y section), by bisection."""
        a, b = self.surfaces[i], self.surfaces[j]
        cos_a, sin_a = math.cos(azimuth), math.sin(azimuth)

        def gap(r: float) -> float:
            x = torch.tensor([r * cos_a], dtype=torch.float64)
            y = torch.tensor([r * sin_a], dtype=torch.float64)
            return float((z[j] + b.sag(x, y) - z[i] - a.sag(x, y)) * sign)

        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if gap(mid) < 0:
                hi = mid
            else:
                lo = mid
        return lo

    def _ahead_across_breaks(self, q: int) -> tuple[int, float] | None:
        """For a surface ``q`` right after a coordinate break: ``(p, h)``, ``p`` the nearest
        surface before it that is not a break (a stop counts: the beam crosses its plane) and
        ``h`` (mm) how far ``q``'s vertex lies *ahead* of ``p``'s along the traced axis between
        them (:func:`~.frames.traced_axes`; both vertices placed by the composed frames,
        :func:`~.frames.local_frames`); ``None`` when ``q`` does not follow a break or no such
        ``p`` exists.

        A thickness is an offset along the local z axis from the previous vertex, and a
        coordinate break is a dummy surface that cannot bend rays, only define the next frame
        (OpticStudio User Guide, *Thicknesses*; Zemax knowledge base, *How to tilt and decenter
        a sequential optical component*): rays move along their lines from ``p`` to ``q``, so
        only where ``q`` lies against the beam does the trace go backwards.  A mirror turned
        about a pivot (break, ``+d``, break with the tilt, ``-d``, mirror) has a negative
        distance into the mirror while the mirror lies ahead: ``h > 0``."""
        if q == 0 or not self.surfaces[q - 1].interaction.changes_frame:
            return None
        p = next((i for i in range(q - 1, -1, -1)
                  if not self.surfaces[i].interaction.changes_frame), None)
        if p is None:
            return None
        indices, w = None, float(self.spec.primary_wavelength_nm)
        with torch.no_grad():
            indices = [float(m.n(torch.tensor(w, dtype=torch.float64))) for m in self.materials]
            axis = torch.tensor(traced_axes(list(self.surfaces), self.mirrors, indices, w)[p + 1],
                                dtype=torch.float64)
            frames = local_frames(self)
            z = self.z_vertices().detach().to(torch.float64)
            zero = torch.zeros((), dtype=torch.float64)

            def vertex(i):
                A, b = (t.detach().to(torch.float64) for t in frames[i])
                return b + A @ torch.stack([zero, zero, z[i]])

            A_p = frames[p][0].detach().to(torch.float64)
            h = float(torch.dot(vertex(q) - vertex(p), A_p @ axis))
        return p, h

    def _real_neighbours(self, across_breaks: bool = False) -> list[tuple[int, int]]:
        """Pairs ``(p, q)`` of consecutive surfaces that are neither stops (:class:`Aperture`)
        nor coordinate breaks, with only stops between them (a coordinate break changes the
        frame: the pairs across it are not compared); ``across_breaks``: with stops and
        coordinate breaks between them (the gaps :attr:`backward_gaps` may name)."""
        pairs, prev = [], None
        for i, s in enumerate(self.surfaces):
            if s.law == "frame":
                if not across_breaks:
                    prev = None
            elif s.law != "stop":
                if prev is not None:
                    pairs.append((prev, i))
                prev = i
        return pairs

    def apply_aperture_spec(self) -> None:
        """Size the stop so that the paraxial entrance pupil matches ``spec`` (EPD or F-number).

        The stop may be an :class:`Aperture` or a lens surface (as in most vendor files): its
        semi-diameter becomes the paraxial stop radius, ``EPD/2 · |y_stop / y_EP|``.  A
        rectangular :class:`Aperture` keeps its rectangle, which clips the rays outside it
        (OpticStudio's surface apertures vignette whatever the system aperture: User Guide,
        *Aperture (surface properties)*); its nominal semi-diameter, which the paraxial pupil
        is computed from, becomes that radius."""

        stop = self.stop
        if stop.law == "stop" and stop.opening.outer.kind == "ellipse":
            raise LensError("an EPD or F-number aperture needs a circular or rectangular stop "
                            "(this Aperture is elliptical)", key="aperture")
        p = paraxial(self)
        if self.spec.aperture_type == "epd":
            epd = float(self.spec.aperture_value)
        else:
            if not (float(p.efl) != 0 and math.isfinite(float(p.efl))):
                raise LensError(f"an F-number aperture needs a finite focal length (an afocal "
                                f"system has none); the paraxial EFL is {float(p.efl):.6g} mm "
                                f"(give the aperture as 'epd' or 'stop' instead)", key="aperture")
            epd = epd_from_image_space_fno(float(p.efl), float(self.spec.aperture_value))
        sd = 0.5 * epd * abs(float(p.stop_height_per_ep_height))
        if not (sd > 0 and math.isfinite(sd)):
            raise LensError(f"aperture {self.spec.aperture_type} {self.spec.aperture_value!r} "
                            f"gives a stop semi-diameter of {sd!r} mm", key="aperture")
        with torch.no_grad():
            stop.semi_diameter.fill_(sd)

    # ------------------------------------------------------------------ media
    def indices(self, wavelength: torch.Tensor) -> list[torch.Tensor]:
        """Refractive indices of the ``N + 1`` media at ``wavelength`` (nm), each of its shape.

        A wavelength tensor broadcast along some dimensions (stride 0, e.g. one wavelength for
        every ray) is evaluated once per distinct element and expanded back (a view: later
        arithmetic on it, such as ``n1 / n2``, also runs on the distinct elements only)."""
        w = _compact(wavelength)
        return [m.n(w).expand(wavelength.shape) for m in self.materials]

    # ------------------------------------------------------------------ tracing
    def _frame(self, i: int, z: torch.Tensor, like: torch.Tensor):
        """``(misalignment or None, pivot (3,), vertex offset in the element frame (3,))``."""
        e = self._element_of[i]
        first = self.elements[e][0]
        m = self.misalignments[e]
        zero = torch.zeros((), dtype=like.dtype, device=like.device)
        pivot = torch.stack([zero, zero, z[first].to(like)])
        vertex = torch.stack([zero, zero, (z[i] - z[first]).to(like)])
        return (None if m.is_identity() else m), pivot, vertex

    def trace_surface(self, i: int, rays: Rays, n1, n2, z, options=None,
                      refract_: bool = True, reverse: bool = False) -> Rays:
        """Intersect surface ``i`` and apply its interaction (:meth:`_trace_surface`); where a
        graded medium (:mod:`.grin`) lies on either side, the rays first follow their curved
        path through it and refract with the local index (:func:`.grin_trace.graded_surface`)."""
        if self.materials[i].graded or self.materials[i + 1].graded:
            return grin_trace.graded_surface(self, i, rays, n1, n2, z, options, refract_,
                                             reverse)
        return self._trace_surface(i, rays, n1, n2, z, options, refract_, reverse)

    def _trace_surface(self, i: int, rays: Rays, n1, n2, z, options=None,
                       refract_: bool = True, reverse: bool = False) -> Rays:
        """Intersect surface ``i`` and apply its interaction (``surface.interaction``,
        :mod:`.interactions`: refraction from medium index ``n1`` into ``n2``, reflection at a
        mirror, a grating's order, an ideal lens's deflection), in the surface's element frame.
        A frame change (a coordinate break) re-expresses the rays in the next frame (the
        previous one when ``reverse``); a stop clips where the ray's line crosses it and leaves
        the rays where they were (:meth:`_cross_stop`).  ``refract_=False`` moves the rays onto
        any surface, a stop's plane included, and applies no law.  ``reverse`` also says which
        way a gap of :attr:`backward_gaps` is crossed."""
        s, law = self.surfaces[i], self.surfaces[i].interaction
        if law.changes_frame:
            o, d = (s.to_previous if reverse else s.to_next)(rays.o, rays.d, z[i])
            return Rays(o, d, rays.wavelength, rays.valid, rays.opl, normalize=False)
        m, pivot, vertex = self._frame(i, z, rays.o)
        opt, mirror, back = options or TraceOptions(), i in self.mirrors, self.hit_backwards(i, reverse)
        n1, n2 = _compact(n1), _compact(n2)
        if (m is None and refract_ and not mirror and opt.closed_form and opt.mode == "implicit"
                and s.closed_form):
            x, d, valid, opl = trace_quadric(s, rays.o, rays.d, rays.valid, rays.opl,
                                             (pivot + vertex)[2], n1, n2, opt, backward=back)
            return Rays(x, d, rays.wavelength, valid, opl, normalize=False)
        shift = pivot + vertex   # aligned: one pass over the rays instead of two
        o, d = (rays.o - shift, rays.d) if m is None else m.to_element(rays.o, rays.d, pivot)
        if m is not None:
            o = o - vertex
        if not law.lands:
            return self._cross_stop(s, rays, o, d, m, pivot, vertex, n1, opt, refract_)
        t, x, valid = intersect(s, o, d, rays.valid, options, backward=back, across=mirror)
        opl = rays.opl + n1 * t
        if refract_:
            d, valid, opl = law(s, x, d, n1, n2, rays.wavelength, valid, opl, mirror)
        x, d = (x + shift, d) if m is None else m.to_global(x + vertex, d, pivot)
        return Rays(x, d, rays.wavelength, valid, opl, normalize=False)

    @staticmethod
    def _cross_stop(s, rays: Rays, o, d, m, pivot, vertex, n1, opt, virtual: bool) -> Rays:
        """A stop is *crossed, not landed on* (``virtual``): the ray's line meets the plane
        (``o``, ``d`` in the stop's frame) at ``t`` of either sign, rays crossing outside the
        opening go invalid, and origin, direction and optical path stay as they were, so the
        next surface is intersected from where the ray was (as OpticStudio traces a stop
        inside a lens's sag: a negative distance after or before it).  ``virtual=False``
        (``refract_=False``: ray aiming, the chief ray, recorded hits) moves the rays onto the
        plane instead, backwards where ``t < 0``."""
        X, Y, _, ok = stop_crossing_xyz(*o.unbind(-1), *d.unbind(-1), rays.valid)
        if opt.clip_aperture:
            ok = ok & s.in_aperture(X, Y)
        if virtual:
            return Rays(rays.o, rays.d, rays.wavelength, ok, rays.opl, normalize=False)
        t = _safe_div(-o[..., 2], d[..., 2], ok)  # with autograd through o and d
        t = torch.where(ok, t, torch.zeros_like(t))
        x = o + t.unsqueeze(-1) * d
        x = x + pivot + vertex if m is None else m.to_global(x + vertex, d, pivot)[0]
        return Rays(torch.where(ok.unsqueeze(-1), x, rays.o), rays.d, rays.wavelength, ok,
                    rays.opl + n1 * t, normalize=False)

    def _check_rays(self, rays: Rays) -> None:
        # wavelengths are checked against every medium's range by Material.n in indices()
        if not isinstance(rays, Rays):
            raise TypeError(f"expected Rays, got {type(rays).__name__}")

    def trace(self, rays: Rays, *, reverse: bool = False, options: TraceOptions | None = None,
              record: bool = False, propagate_to=None):
        """Trace through every surface.

        Args:
            rays: input rays; forward rays start before the first surface and travel to ``+z``;
                ``reverse=True`` rays start behind the last surface and travel to ``-z``.
            reverse: backward (sensor-to-object) tracing.
            options: :class:`~.options.TraceOptions` (Newton settings; ``compile=...`` selects
                the fused kernels of :mod:`.compiled`, except when ``record`` is set); the
                schedule is :mod:`.tracer`'s.
            record: also return the list of per-surface hit points ``(*B, 3)``.
            propagate_to: ``(z_plane, medium_index)``: then move the rays to that plane, as
                :meth:`propagate_to_z` (with ``compile=...`` inside the last kernel).

        Returns:
            Rays just after the last surface traced (``(rays, hits)`` when ``record``).
        """
        self._check_rays(rays)
        return tracer.trace(self, rays, reverse=reverse, options=options, record=record,
                            propagate_to=propagate_to)

    def propagate_to_z(self, rays: Rays, z_plane, medium_index=None,
                       backwards: bool = False) -> Rays:
        """Move rays to the plane ``z = z_plane`` (mm); rays that cannot reach it go invalid.
        ``backwards``: a plane behind the rays is reached along their lines extended backwards
        (a negative distance, the optical path decreasing by ``n |t|``)."""
        z_plane = torch.as_tensor(z_plane, dtype=rays.dtype, device=rays.device)
        t, ok = propagate_distance(rays.o[..., 2], rays.d[..., 2], rays.valid, z_plane,
                                   backwards)
        n = 1.0 if medium_index is None else medium_index
        return Rays(rays.at(t), rays.d, rays.wavelength, ok, rays.opl + n * t, normalize=False)

    def trace_to_sensor(self, rays: Rays, *, z_image=None, options=None) -> Rays:
        """Forward trace and propagate to the sensor plane (or to ``z_image`` when given).
        With :attr:`virtual_image` the image side is virtual: the rays reach the plane along
        their lines extended backwards where it lies behind them."""
        z = self.z_sensor() if z_image is None else z_image
        n_img = self.materials[-1].n(_compact(rays.wavelength))
        z = torch.as_tensor(z, dtype=rays.dtype, device=rays.device)
        if self.virtual_image:
            return self.propagate_to_z(self.trace(rays, options=options), z, n_img,
                                       backwards=True)
        return self.trace(rays, options=options, propagate_to=(z, n_img))

    def require_real_image(self, what: str) -> None:
        """Raise a :class:`~.errors.LensError` naming ``what`` when the image plane is virtual
        (:attr:`virtual_image`): a renderer, a PSF or a camera with a sensor needs light that
        reaches a physical sensor."""
        if self.virtual_image:
            raise LensError(f"{what}: the lens {self.name!r} has a virtual image plane "
                            f"({float(self.d_sensor):g} mm from its last surface, before it): "
                            f"a camera cannot record a virtual image; only analysis (paraxial "
                            f"data, spots, report) works on it; add the optics that image it "
                            f"onto a real sensor", key="sensor")

    def info(self, extra: bool = True) -> None:
        """Print the prescription as a lens-data-editor table (surface, type, radius, thickness,
        material, semi-diameter, conic; :mod:`.prescription`, whose ``prescription(lens)``
        gives the rows as dictionaries)."""
        from .prescription import prescription_table

        print(prescription_table(self, extra=extra))

    def extra_repr(self) -> str:
        return (f"name={self.name!r}, surfaces={len(self.surfaces)}, stop={self.stop_index}, "
                f"d_sensor={float(self.d_sensor.detach()):.6g} mm"
                + (", virtual_image=True" if self.virtual_image else "")
                + (f", backward_gaps={sorted(self._backward)}" if self._backward else ""))
