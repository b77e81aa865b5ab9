"""Pupil sampling patterns and object-space ray bundles.

Patterns return points ``(M, 2)`` in the unit disk (normalised pupil coordinates ``(p_x, p_y)``):

* ``hexapolar:R``  the centre plus rings ``k = 1..R`` of ``6k`` points at radius ``k/R``
  (as lens-design programs do; ``1 + 3R(R+1)`` points)
* ``grid:N``       an ``N x N`` square grid over ``[-1, 1]^2`` clipped to the disk
* ``random:N``     ``N`` uniform points in the disk (seeded; ``random:N:SEED``)

Field rays for an object at infinity travel along ``(0, sin θ, cos θ)`` (positive field angle
= ray rising towards ``+y``); for a finite object the object point sits at
``y = -tan θ (z_EP - z_obj)`` so that its chief ray crosses the entrance-pupil centre at ``θ``.
For an object-space telecentric lens (``lens.object_telecentric``: the entrance pupil at
infinity) every chief ray is parallel to the axis: the object point of field ``θ`` sits at
``y = -s tan θ`` (``s`` the object distance: the field angle is the object point's direction
seen from the first vertex) and a pupil point ``(x, y)`` of the plane ``z_P`` is the ray of
slopes ``(x, y) / |z_P - z_obj|`` about it, a cone of rays about the chief ray, uniform in slope
as optiland samples it (on the paraxial entrance pupil of an ``OBNA`` lens, ``r_EP / |z_EP -
z_obj| = tan θ_NA``: the rim rays have direction cosines ``sin θ_NA``; on the axis these are
the rays of the non-telecentric construction).
A tilted object plane (``lens.object_tilt = (tan_x, tan_y)``: ``z = z_obj + tan_x x + tan_y
y``, OpticStudio's *Tilted* object surface) moves each field's object point along its chief
line onto the plane: ``y = -tan θ (z_P - z_obj) / (1 - tan_y tan θ)``, ``z = z_obj + tan_y y``
(telecentric: ``y = -s tan θ`` on the plane).
Either way the rays start on a plane just before the first surface (or at the object point when
it is nearer), launch point and direction computed in float64 from the pupil points and the
direction tangents and only then rounded to the lens's dtype, so that float32 rays from an
object 1e9 mm away keep their pupil positions (:func:`rays_from_tangents`).

Point sources (:func:`point_source_rays`, for PSFs and rendering): rays leave an object point
(or arrive as a parallel beam from infinity) towards points sampled on the paraxial entrance
pupil (:func:`entrance_pupil`) enlarged by ``pupil_margin``.
"""

from __future__ import annotations

import math

import torch

from .limits import check_allocation
from .paraxial import paraxial
from .rays import Rays

__all__ = ["pupil_pattern", "parse_sampling", "hexapolar", "square_grid", "random_disk",
           "field_rays", "object_point", "object_points", "start_plane_z", "rays_from_tangents",
           "rays_from_point", "entrance_pupil", "point_source_rays", "DEFAULT_SAMPLING"]

#: the pupil sampling of every RMS spot the command line prints (``deeplens report``, ``plot
#: --kind spot``, ``optimize``, ``tolerance``), so one lens has one on-axis RMS: 1027 rays per
#: field and wavelength, within 2-7 % of a 64-ring reference on the shipped lenses, where 6
#: rings are 9-26 % off (docs/guide/cli.md, "One pupil sampling")
DEFAULT_SAMPLING = "hexapolar:18"


#: bytes one traced ray takes at least (the peak of ``deeplens report`` tracing 1.5 million rays
#: through an 8-surface lens was ~340 bytes per ray above the baseline); sizes the memory check
RAY_BYTES = 256


def hexapolar(rings: int, dtype=torch.float64, device=None) -> torch.Tensor:
    """Hexapolar pattern with ``rings`` rings, ``(1 + 3R(R+1), 2)``."""
    if rings < 0:
        raise ValueError(f"hexapolar: rings must be >= 0, got {rings}")
    pts = [torch.zeros(1, 2, dtype=dtype, device=device)]
    for k in range(1, rings + 1):
        phi = torch.arange(6 * k, dtype=dtype, device=device) * (2 * math.pi / (6 * k))
        r = k / rings
        pts.append(torch.stack([r * torch.sin(phi), r * torch.cos(phi)], -1))
    return torch.cat(pts)


def square_grid(n: int, dtype=torch.float64, device=None) -> torch.Tensor:
    """``n x n`` grid over ``[-1, 1]^2``, points inside the unit disk."""
    if n < 1:
        raise ValueError(f"grid: n must be >= 1, got {n}")
    v = torch.linspace(-1, 1, n, dtype=dtype, device=device) if n > 1 else \
        torch.zeros(1, dtype=dtype, device=device)
    x, y = torch.meshgrid(v, v, indexing="xy")
    p = torch.stack([x.reshape(-1), y.reshape(-1)], -1)
    return p[(p * p).sum(-1) <= 1 + 1e-12]


def random_disk(n: int, seed: int = 0, dtype=torch.float64, device=None) -> torch.Tensor:
    """``n`` uniform points in the unit disk from a seeded generator."""
    if n < 1:
        raise ValueError(f"random: n must be >= 1, got {n}")
    g = torch.Generator().manual_seed(seed)
    r = torch.sqrt(torch.rand(n, generator=g, dtype=torch.float64))
    phi = torch.rand(n, generator=g, dtype=torch.float64) * 2 * math.pi
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi)], -1).to(dtype=dtype, device=device)


def parse_sampling(text: str) -> tuple[str, int, int]:
    """``"hexapolar:18"`` -> ``("hexapolar", 18, 0)``; ``"random:500:3"`` -> seed 3."""
    parts = str(text).split(":")
    kinds = ("hexapolar", "grid", "random")
    if parts[0] not in kinds or len(parts) not in (2, 3) or (len(parts) == 3 and
                                                             parts[0] != "random"):
        raise ValueError(f"pupil sampling must be one of hexapolar:RINGS, grid:N, random:N[:SEED]; "
                         f"got {text!r}")
    try:
        n = int(parts[1])
        seed = int(parts[2]) if len(parts) == 3 else 0
    except ValueError:
        raise ValueError(f"pupil sampling {text!r}: the count must be an integer") from None
    if n < (0 if parts[0] == "hexapolar" else 1):
        raise ValueError(f"pupil sampling {text!r}: the count must be positive")
    points = {"hexapolar": 1 + 3 * n * (n + 1), "grid": n * n, "random": n}[parts[0]]
    check_allocation(f"pupil sampling {text!r}", points, RAY_BYTES, "rays per field and "
                     "wavelength")
    return parts[0], n, seed


def pupil_pattern(text: str, dtype=torch.float64, device=None) -> torch.Tensor:
    """Unit-disk points ``(M, 2)`` for a sampling string (see the module docstring)."""
    kind, n, seed = parse_sampling(text)
    if kind == "hexapolar":
        return hexapolar(n, dtype, device)
    if kind == "grid":
        return square_grid(n, dtype, device)
    return random_disk(n, seed, dtype, device)


def _lowest_sag(s) -> float:
    """The most negative sag of surface ``s`` along a radius to its semi-diameter (mm; points
    outside its domain count as 0)."""
    with torch.no_grad():
        r = torch.linspace(0, float(s.semi_diameter), 33, dtype=torch.float64)
        zero = torch.zeros_like(r)
        sag = torch.where(s.in_domain(zero, r), s.sag(zero, r), torch.zeros_like(r))
        return float(sag.min())


def start_plane_z(lens) -> float:
    """An axial position safely before the first surface (its sag and tilt included), mm.

    Behind leading coordinate breaks (an off-axis mirror tilted by a ``COORDBRK``) the first
    surface may be tilted: its rim can then reach a whole semi-diameter towards the object.
    Behind leading stops the first lens surface may reach through their planes (a stop inside
    its sag): the plane is then also 1 mm before that surface."""
    k = 0
    while k < len(lens.surfaces) - 1 and lens.surfaces[k].law == "frame":
        k += 1
    s0 = lens.surfaces[k]
    low = _lowest_sag(s0)
    z = lens.z_vertices().detach()
    margin = 0.1 if k == 0 else 1.0
    z_start = float(z[:k + 1].min()) - abs(low if k else min(0.0, low)) - 1.0 \
        - margin * float(s0.semi_diameter)
    j = k
    while j < len(lens.surfaces) - 1 and lens.surfaces[j].law == "stop":
        j += 1
    if j > k and lens.surfaces[j].law != "frame":
        front = float(z[j]) + min(0.0, _lowest_sag(lens.surfaces[j]))
        z_start = min(z_start, front - 1.0)   # unchanged unless it reaches before the stop
    return z_start


def field_rays(lens, field_deg: float, wavelength_nm: float, pupil_xy: torch.Tensor,
               z_pupil: float, *, object_distance_mm: float | None = None) -> Rays:
    """Object-space rays of one field through points of a pupil plane.

    Args:
        lens: the :class:`~deeplens.optics.lens.Lens` (for the object distance and start plane).
        field_deg: field angle (deg).
        wavelength_nm: wavelength (nm).
        pupil_xy: ``(M, 2)`` *physical* pupil-plane coordinates in mm.
        z_pupil: axial position of the pupil plane (mm).
        object_distance_mm: overrides ``lens.spec.object_distance_mm``.

    Returns:
        :class:`Rays` of shape ``(M,)``, starting before the first surface.

    Raises:
        ValueError: an object-space telecentric lens with the object at infinity or the pupil
            plane on the object plane.
    """
    dtype, device = pupil_xy.dtype, pupil_xy.device
    s = lens.spec.object_distance_mm if object_distance_mm is None else object_distance_mm
    th = math.radians(field_deg)
    if getattr(lens, "object_telecentric", False):
        return _telecentric_rays(lens, th, wavelength_nm, pupil_xy, float(z_pupil), float(s))
    P = torch.cat([pupil_xy.to(torch.float64),
                   torch.full((pupil_xy.shape[0], 1), float(z_pupil), dtype=torch.float64,
                              device=device)], -1)
    if math.isinf(s):
        tangents = torch.tensor([0.0, math.tan(th)], dtype=torch.float64, device=device)
        return rays_from_tangents(P, tangents, start_plane_z(lens), wavelength_nm, dtype)
    z0 = float(lens.z_vertices()[0])
    Q = object_point(lens, th, float(z_pupil), s, device)
    return rays_from_point(P, Q, start_plane_z(lens), wavelength_nm, dtype,
                           virtual=float(Q[2]) > z0)


def object_point(lens, th: float, z_pupil: float, s: float, device=None) -> torch.Tensor:
    """The object point ``(0, y, z)`` (float64, mm) of the field of angle ``th`` (radians, in
    the y-z plane) for a finite object ``s`` mm before the first vertex: :func:`object_points`
    of the tangents ``(0, tan th)``."""
    tan = torch.tensor([[0.0, math.tan(th)]], dtype=torch.float64, device=device)
    return object_points(lens, tan, z_pupil, s)[0]


def object_points(lens, tangents: torch.Tensor, z_pupil: float, s: float) -> torch.Tensor:
    """Object points ``(M, 3)`` (float64, mm) of fields of direction tangents ``(tan θ_x, tan
    θ_y)`` ``(M, 2)`` for a finite object ``s`` mm before the first vertex: each on its chief
    line through the pupil plane's centre ``(0, 0, z_pupil)``, ``(x, y) = -(tan θ_x, tan θ_y)
    D``, and on the object plane ``z = z_obj + tan_x x + tan_y y`` (``lens.object_tilt``;
    untilted: ``z = z_obj``), which puts it ``D = (z_pupil - z_obj) / (1 - tan_x tan θ_x -
    tan_y tan θ_y)`` before the pupil plane.

    Raises:
        ValueError: a chief line runs parallel to a tilted object plane."""
    tan = tangents.to(torch.float64)
    z_obj = float(lens.z_vertices()[0]) - s
    tx, ty = getattr(lens, "object_tilt", (0.0, 0.0))
    den = 1.0 - tx * tan[:, 0] - ty * tan[:, 1]
    if not bool((den.abs() > 1e-12).all()):
        raise ValueError(f"a field's chief line (direction tangents "
                         f"{tan[den.abs() <= 1e-12][0].tolist()}) runs parallel to the tilted "
                         f"object plane (tan_x {tx:g}, tan_y {ty:g}) and never meets it")
    xy = -tan * ((z_pupil - z_obj) / den)[:, None]
    z = z_obj + tx * xy[:, 0] + ty * xy[:, 1]   # on the plane (untilted: z_obj exactly)
    return torch.cat([xy, z[:, None]], -1)


def _telecentric_rays(lens, th: float, wavelength_nm, pupil_xy: torch.Tensor, z_pupil: float,
                      s: float) -> Rays:
    """:func:`field_rays` of an object-space telecentric lens (see the module docstring): from
    the object point ``(0, -s tan θ, z_obj)``, slopes ``pupil_xy / |z_pupil - z_obj|``."""
    if math.isinf(s):
        raise ValueError("an object-space telecentric lens needs an object at a finite "
                         "distance (its fields are object heights)")
    z_obj = float(lens.z_vertices()[0]) - s
    dz = abs(z_pupil - z_obj)
    if not dz > 0:
        raise ValueError(f"object-space telecentric rays: the pupil plane (z = {z_pupil:g} mm) "
                         f"lies on the object plane")
    t = pupil_xy.to(torch.float64) / dz
    y = -math.tan(th) * s
    z_q = z_obj + getattr(lens, "object_tilt", (0.0, 0.0))[1] * y   # on a tilted object plane
    Q = torch.tensor([0.0, y, z_q], dtype=torch.float64,
                     device=pupil_xy.device).expand(pupil_xy.shape[0], 3)
    return rays_from_tangents(Q, t, max(start_plane_z(lens), z_q), wavelength_nm,
                              pupil_xy.dtype)


def rays_from_tangents(P: torch.Tensor, tangents: torch.Tensor, z_start: float,
                       wavelength_nm, dtype) -> Rays:
    """Rays through the points ``P`` ``(M, 3)`` (mm) along ``(t_x, t_y, 1)``, started on the
    plane ``z = z_start``.

    ``P`` and ``tangents`` (``(2,)`` or ``(M, 2)``) are float64; the launch point and direction
    are computed there and only then rounded to ``dtype``, so the rays' precision does not
    depend on how far away their source is (issue 25, item 8: a float32 object point 1e9 mm
    away rounds the pupil coordinates to 64 mm).  ``opl`` starts at 0 on the start plane.
    """
    t = tangents.expand(P.shape[0], 2)
    ones = torch.ones_like(t[:, :1])
    o = torch.cat([P[:, :2] + (z_start - P[:, 2:]) * t, torch.full_like(ones, z_start)], -1)
    d = torch.cat([t, ones], -1)
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    return Rays(o.to(dtype), d.to(dtype), wavelength_nm, normalize=False)


def rays_from_point(P: torch.Tensor, Q: torch.Tensor, z_start: float, wavelength_nm,
                    dtype, virtual: bool = False) -> Rays:
    """Rays from the object point ``Q`` ``(3,)`` through the points ``P`` ``(M, 3)`` (float64,
    mm), started on the plane ``z = max(z_start, Q_z)`` (see :func:`rays_from_tangents`).
    ``virtual``: ``Q`` is a virtual object behind the lens's first vertex; the rays travel
    towards it along the same lines and start on ``z = z_start``."""
    z_obj = float(Q[2])
    tangents = (P[:, :2] - Q[:2]) / (P[:, 2:] - z_obj)
    z0 = float(z_start) if virtual else max(float(z_start), z_obj)
    return rays_from_tangents(P, tangents, z0, wavelength_nm, dtype)


def entrance_pupil(lens):
    """``(z_ep, r_ep, z0)``: the paraxial entrance pupil's position and radius and the first
    vertex (mm), as :func:`point_source_rays` aims at them (one paraxial trace; pass the result
    as its ``pupil`` to aim many point sources with one)."""
    with torch.no_grad():
        p = paraxial(lens)
        return (float(p.entrance_pupil_z), 0.5 * float(p.entrance_pupil_diameter),
                float(lens.z_vertices()[0]))


def point_source_rays(lens, point_xy_mm, depth_mm: float, wavelength_nm: float, n_rays: int,
                      seed: int = 0, pupil_margin: float = 1.1, sampling: str = "random",
                      pupil=None) -> Rays:
    """Rays from an object point towards the entrance pupil (for an object-space telecentric
    lens: towards that pupil's disk moved across to the point, a cone about the ray parallel to
    the axis).

    Args:
        point_xy_mm: ``(X, Y)`` of the object point (mm) for a finite ``depth_mm``; for
            ``depth_mm = inf`` the object-space direction tangents ``(tan θx, tan θy)``.
        depth_mm: distance from the first vertex (mm), or ``math.inf``.
        n_rays: number of pupil samples (uniform on the enlarged paraxial entrance pupil).
        sampling: ``"random"`` (``n_rays`` seeded samples) or a deterministic pattern such as
            ``"grid:64"`` or ``"hexapolar:20"`` (:func:`~deeplens.optics.sampling.pupil_pattern`;
            ``n_rays`` is then ignored).
        pupil: :func:`entrance_pupil` of ``lens`` if already known (else computed here).
    """
    dtype, device = lens.dtype, lens.device
    z_ep, r_ep, z0 = pupil if pupil is not None else entrance_pupil(lens)
    r_ep = r_ep * pupil_margin
    if sampling == "random":
        unit = random_disk(n_rays, seed)
    else:
        unit = pupil_pattern(sampling)
    unit = unit * r_ep
    E = torch.cat([unit, torch.full_like(unit[:, :1], z_ep)], -1).to(device=device)
    X, Y = float(point_xy_mm[0]), float(point_xy_mm[1])
    if math.isinf(depth_mm):
        if getattr(lens, "object_telecentric", False):
            raise ValueError("an object-space telecentric lens needs point sources at a "
                             "finite depth")
        t = torch.tensor([X, Y], dtype=torch.float64, device=device)
        return rays_from_tangents(E, t, start_plane_z(lens), wavelength_nm, dtype)
    if not depth_mm > 0:
        raise ValueError(f"point source depth must be > 0 mm (in front of the lens), got "
                         f"{depth_mm}")
    P = torch.tensor([X, Y, z0 - depth_mm], dtype=torch.float64, device=device)
    if getattr(lens, "object_telecentric", False):
        E[:, :2] = E[:, :2] + P[:2]   # a cone about the ray parallel to the axis
    return rays_from_point(E, P, start_plane_z(lens), wavelength_nm, dtype)
