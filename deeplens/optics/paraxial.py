"""Paraxial (first-order) analysis by y-u ray tracing.

At surface ``i`` with vertex curvature ``c_i`` between indices ``n`` and ``n'``:

    refraction:  n' u' = n u - y c_i (n' - n)        transfer:  y <- y + t u'

Two rays are traced from the first vertex: ``A = (y=1, u=0)`` and ``B = (y=0, u=1)``.  Then
``EFL = -1 / u_A'`` (image space), ``BFL = -y_A / u_A'`` at the last vertex; the entrance pupil
(the stop's image in object space) lies ``y_B,stop / y_A,stop`` behind the first vertex and has
diameter ``2 r_stop / |y_A,stop|``; ``F/# = |EFL| / EPD`` (:func:`image_space_fno`).  For an object at distance ``s`` the
paraxial image lies ``-y/u'`` behind the last vertex for the ray ``s A + B``.

Mirrors: the classic trick.  Indices carry the direction of travel, ``n -> σ n`` with ``σ = ±1``
flipped by every mirror (:meth:`Lens.directions <deeplens.optics.lens.Lens.directions>`), so a
mirror is a surface with ``n' = -n`` and power ``φ = -2 n c``; distances after an odd number of
mirrors are negative, slopes ``u = dy/dz`` are real slopes along the local axis, and the
transfer ``y <- y + t u'`` is unchanged.  ``EFL = -σ_img / u_A'`` is then positive for a
converging system whichever way the light leaves (a concave mirror of radius ``R`` has
``EFL = |R| / 2``), while ``BFL``, ``image_distance`` and ``*_z`` stay positions along the local
``z`` (``BFL = R / 2`` for that mirror).  A coordinate break has no power and paraxial rays
follow the local axes through it (as in Zemax): a fold is exact, a tilted or decentered
section is paraxial about its own vertex.
A graded medium (:mod:`.grin`) transfers the ray with its own matrix (a radial quadratic
rod: ``cos gL``, ``sin(gL) / (n0 g)``, ...; :meth:`~.materials.Material.paraxial_transfer`)
instead of ``y <- y + t u``.
A diffractive phase (:class:`~.surfaces.Binary2`) adds its paraxial power ``-M A_1 λ / (π R_n²)``
to its base's ``c (n' - n)``, at the wavelength of the trace.
All quantities are differentiable torch scalars in mm, at the primary wavelength.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = ["paraxial", "ParaxialData", "exit_pupil", "chief_ray_scale", "media_indices",
           "trace_paraxial_ray", "surface_power", "image_space_fno", "epd_from_image_space_fno"]


@dataclass
class ParaxialData:
    """First-order data (mm); ``*_z`` are absolute axial positions in the lens frame."""

    efl: torch.Tensor
    bfl: torch.Tensor
    image_distance: torch.Tensor  # from the last vertex to the paraxial image of the object
    image_z: torch.Tensor
    entrance_pupil_z: torch.Tensor
    entrance_pupil_position: torch.Tensor  # relative to the first vertex
    entrance_pupil_diameter: torch.Tensor
    fno: torch.Tensor
    stop_height_per_ep_height: torch.Tensor
    wavelength_nm: float


def image_space_fno(efl, epd):
    """Image-space F-number ``|EFL| / EPD`` (EFL and EPD in mm; tensors or floats).

    The one place where the sign of the focal length meets the F-number: OpticStudio's
    *Image Space F/#* is "the ratio of the paraxial infinite conjugate effective focal length to
    the paraxial entrance pupil diameter", and an F-number is a positive ratio; a negative EFL
    (a diverging system, or a converging one with an odd number of intermediate images) has the
    F-number of its magnitude, as OpticStudio's own stored semi-diameters show (Zemax guide,
    *What is read*).  :func:`epd_from_image_space_fno` is its inverse."""
    return abs(efl) / epd


def epd_from_image_space_fno(efl, fno):
    """Entrance-pupil diameter (mm) of an image-space F-number ``fno`` > 0: ``|EFL| / fno``
    (the inverse of :func:`image_space_fno`)."""
    return abs(efl) / fno


def surface_power(surface, n1, n2, wavelength_nm: float):
    """Paraxial power (1/mm) of ``surface`` between media of indices ``n1``, ``n2``:
    ``φ = c (n2 - n1)``; an ideal lens supplies its own ``1/f`` (times ``|n2|``: ``n1``, ``n2``
    carry the direction of travel, and a positive ``f`` converges along the light's way whichever
    way it travels, as :meth:`~.surfaces.IdealLens.deflect` traces it); a diffractive
    phase (:class:`~.surfaces.Binary2`) adds its own power at ``wavelength_nm`` (nm).  The
    paraxial traces here and the system matrices of :mod:`deeplens.analysis.cardinal` use it."""
    if hasattr(surface, "paraxial_power"):
        return surface.paraxial_power() * abs(n2)
    phi = surface.paraxial_curvature() * (n2 - n1)
    if hasattr(surface, "paraxial_phase_power"):
        phi = phi + surface.paraxial_phase_power(wavelength_nm).to(phi)
    return phi


def _signed_indices(lens, wt):
    """The ``N + 1`` media indices at wavelength tensor ``wt``, times the direction of travel."""
    return [m.n(wt).to(wt) * sign for m, sign in zip(lens.materials, lens.directions())]


def _trace(lens, y, u, n, wavelength_nm=None):
    """Trace a paraxial ray (y, u at the first vertex, in object space) to the last vertex, at
    ``wavelength_nm`` (nm; ``None``: the primary one; only a diffractive surface's power needs
    it, the indices ``n`` are given).

    Returns the ray after the last surface and the height at every vertex."""
    w = _wavelength(lens, wavelength_nm)
    heights = []
    dist = list(lens.distances)
    for i, s in enumerate(lens.surfaces):
        if i > 0:
            y, u = _transfer(lens.materials[i], dist[i], y, u, n[i])
        heights.append(y)
        u = (n[i] * u - y * surface_power(s, n[i], n[i + 1], w).to(y)) / n[i + 1]
    return y, u, heights


def _transfer(medium, t, y, u, n):
    """The ray ``(y, u)`` across ``t`` mm of ``medium`` (signed axial index ``n``): ``y + t u``
    in a homogeneous medium, the medium's own matrix in a graded one
    (:meth:`~.materials.Material.paraxial_transfer`, :mod:`.grin`)."""
    if not medium.graded:
        return y + t * u, u
    A, B, C, D = medium.paraxial_transfer(t, n)
    nu = n * u
    return A * y + B * nu, (C * y + D * nu) / n


def _wavelength(lens, wavelength_nm) -> float:
    return float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)


class PupilAtInfinityError(ValueError):
    """The ray parallel to the axis meets the stop at height 0 while the object is finite: the
    entrance pupil is at infinity (object space telecentric) and the lens is not flagged so
    (``Lens.object_telecentric``)."""


def pupil_at_infinity(heights, k: int) -> bool:
    """Whether the ray parallel to the axis (``heights``: its height at each vertex, mm, from
    height 1 at the first) meets surface ``k`` at height 0 to the rounding of its float trace.

    Each surface's transfer and refraction round ``y`` and ``u`` by a few ulps of the heights
    involved (``|t u| = |y_i - y_{i-1}| <= 2 max |y|``), so after ``k + 1`` surfaces the
    height at ``k`` carries an error of at most about ``4 (k + 1) eps max_{i<=k} |y_i|`` (first
    order, ``eps`` the dtype's unit roundoff); a height within that of 0 is 0."""
    y = heights[k]
    eps = torch.finfo(y.dtype).eps
    scale = max(abs(float(h.detach())) for h in heights[:k + 1])
    return abs(float(y.detach())) <= 4.0 * (k + 1) * eps * scale


def paraxial(lens, wavelength_nm: float | None = None) -> ParaxialData:
    """Paraxial data of ``lens`` at ``wavelength_nm`` (default: the spec's primary wavelength).

    An afocal system (no paraxial power, e.g. flat fold mirrors only) has ``efl``, ``bfl``, ``fno``
    and, for an object at infinity, ``image_distance`` / ``image_z`` equal to ``+inf`` (its
    pupils are finite).

    For an object-space telecentric lens (``lens.object_telecentric``) whose ray parallel to the
    axis meets the stop at height 0 (the entrance pupil at infinity, :func:`pupil_at_infinity`)
    the "entrance pupil" is the plane of the stop's vertex (``entrance_pupil_position`` its
    distance from the first vertex, ``p``) with the radius ``(s + p) tan θ`` of the axial
    object's cone that fills the stop (``s`` the object distance), the pupil that
    :mod:`.sampling` builds each field's cone on.

    Raises:
        ValueError: the stop is at the image of an object at infinity (``y_A = 0``);
            :class:`PupilAtInfinityError` for a finite object and a lens not flagged
            ``object_telecentric``.
    """
    w = _wavelength(lens, wavelength_nm)
    n, p0 = _indices(lens, w)
    one, zero = torch.ones_like(p0), torch.zeros_like(p0)
    yA, uA, hA = _trace(lens, one, zero, n, w)
    _, _, hB = _trace(lens, zero, one, n, w)
    if abs(float(uA.detach())) < 1e-15:   # afocal (flat folds only): no focus
        efl = bfl = torch.full_like(uA, math.inf)
    else:
        efl = -n[-1].sign() / uA
        bfl = -yA / uA
    k = lens.stop_index
    ya_s, yb_s = hA[k], hB[k]
    s = float(lens.spec.object_distance_mm)
    z0 = lens.z_vertices()[0]
    if pupil_at_infinity(hA, k):
        if math.isinf(s):
            raise ValueError("the stop is at the image of the object at infinity (the ray "
                             "parallel to the axis meets it at height 0): no entrance pupil")
        if not getattr(lens, "object_telecentric", False):
            raise PupilAtInfinityError(
                "the entrance pupil is at infinity (the ray parallel to the axis meets the stop "
                "at height 0): object space is telecentric; set Lens.object_telecentric and "
                "give the aperture as an object-space NA")
        # telecentric object space, the pupil at infinity: the cone about each chief ray is
        # sampled on the plane of the stop's vertex (ep_pos = z_stop - z_0), whose radius r
        # subtends tan θ = r / (s + ep_pos) from the axial object point; that ray (height
        # s tan θ at the first vertex) meets the stop at r (s y_A + y_B) / (s + ep_pos)
        ep_pos = (lens.z_vertices()[k] - z0).to(ya_s)
        L = s + ep_pos
        if float(L.detach()) == 0.0:
            raise ValueError("object-space telecentric lens with its stop's vertex on the "
                             "object plane: no cone from the object to sample the pupil on")
        ya_s = (s * ya_s + yb_s) / L
        if abs(float(ya_s.detach())) == 0.0:
            raise ValueError("the stop is at an image of the object: no ray from the axial "
                             "object point reaches its rim")
    else:
        ep_pos = yb_s / ya_s
    epd = 2.0 * lens.stop.semi_diameter.to(p0) / ya_s.abs()
    if math.isinf(s):
        img = bfl
    else:
        y, u, _ = _trace(lens, s * one, one, n, w)
        img = -y / u
    z_last = lens.z_vertices()[-1]
    return ParaxialData(efl=efl, bfl=bfl, image_distance=img, image_z=z_last + img,
                        entrance_pupil_z=z0 + ep_pos, entrance_pupil_position=ep_pos,
                        entrance_pupil_diameter=epd, fno=image_space_fno(efl, epd),
                        stop_height_per_ep_height=ya_s, wavelength_nm=w)


def _indices(lens, wavelength_nm):
    w = _wavelength(lens, wavelength_nm)
    p0 = torch.zeros((), dtype=lens.dtype, device=lens.device)   # dtype and device
    wt = torch.tensor(w, dtype=p0.dtype, device=p0.device)
    return _signed_indices(lens, wt), p0


def media_indices(lens, wavelength_nm: float | None = None) -> torch.Tensor:
    """The media's refractive indices ``(S + 1,)`` at ``wavelength_nm`` (nm; ``None``: the
    lens's primary wavelength), object space first, each signed by the direction of travel
    there (negative after an odd number of mirrors), on the lens's dtype and device: the
    ``n`` that :func:`trace_paraxial_ray` takes."""
    return torch.stack(list(_indices(lens, wavelength_nm)[0]))


def trace_paraxial_ray(lens, y: torch.Tensor, u: torch.Tensor, n: torch.Tensor,
                       wavelength_nm: float | None = None):
    """Trace a paraxial ray of height ``y`` (mm) and slope ``u`` at the first vertex (in
    object space) through every surface, in media of signed indices ``n``
    (:func:`media_indices`).  Returns ``(y, u, heights)``: the ray after the last surface (at
    the last vertex) and its height at each vertex (a list of ``S`` 0-d tensors, mm).
    ``wavelength_nm`` (``None``: the primary one) is the wavelength of ``n``, which a
    diffractive surface's power depends on."""
    return _trace(lens, y, u, n, wavelength_nm)


def _trace_from(lens, start: int, y, u, n, wavelength_nm=None):
    """Trace a paraxial ray that sits at vertex ``start`` (before refracting there)."""
    w = _wavelength(lens, wavelength_nm)
    dist = list(lens.distances)
    for i in range(start, len(lens.surfaces)):
        if i > start:
            y, u = _transfer(lens.materials[i], dist[i], y, u, n[i])
        u = (n[i] * u - y * surface_power(lens.surfaces[i], n[i], n[i + 1], w).to(y)) / n[i + 1]
    return y, u


def exit_pupil(lens, wavelength_nm: float | None = None):
    """Paraxial exit pupil ``(z_xp, radius)`` in mm: the image of the stop in image space.

    A ray leaving the stop centre with unit slope crosses the axis in image space at ``z_xp``;
    a ray leaving the stop at height 1 reaches height ``m`` there, so the radius is
    ``|m| r_stop``.
    """
    n, p0 = _indices(lens, wavelength_nm)
    one, zero = torch.ones_like(p0), torch.zeros_like(p0)
    k = lens.stop_index
    z_last = lens.z_vertices()[-1]
    yc, uc = _trace_from(lens, k, zero, one, n, wavelength_nm)
    if abs(float(uc.detach())) < 1e-15:
        raise ValueError("the exit pupil is at infinity (image-space telecentric lens)")
    dz = -yc / uc  # from the last vertex
    ye, ue = _trace_from(lens, k, one, zero, n, wavelength_nm)
    m = ye + ue * dz
    return z_last + dz, m.abs() * lens.stop.semi_diameter.to(p0)


def chief_ray_scale(lens, z_image, wavelength_nm: float | None = None):
    """``κ`` (mm): the paraxial chief ray of object-space slope ``u`` reaches height ``κ u`` on
    the plane ``z_image``.  An ideal camera images the field angle ``θ`` to ``κ tan θ``."""
    n, p0 = _indices(lens, wavelength_nm)
    one = torch.ones_like(p0)
    z0 = lens.z_vertices()[0]
    p = paraxial(lens, wavelength_nm)
    y0 = -(p.entrance_pupil_z - z0) * one  # passes the EP centre with slope 1
    y, u = _trace_from(lens, 0, y0, one, n, wavelength_nm)
    return y + u * (torch.as_tensor(z_image).to(p0) - lens.z_vertices()[-1])
