"""Cardinal points, pupils at any conjugate and magnification, from the paraxial system matrix.

With reduced angles ``ν = n u`` a paraxial ray ``(y, ν)`` is refracted at surface ``i`` by
``R_i = [[1, 0], [-φ_i, 1]]`` (``φ_i = c_i (n' - n)``) and carried over a gap ``t`` in a medium
``n`` by ``T = [[1, t/n], [0, 1]]``.  The matrix from the first to the last vertex,
``M = [[A, B], [C, D]]`` (``det M = 1``), gives, with object index ``n`` and image index ``n'``:

    power φ = -C,   f' = n'/φ (rear),   f = -n/φ (front),
    F' = z_last + A n'/φ,      P' = F' - n'/φ = z_last + (A - 1) n'/φ,
    F  = z_first - D n/φ,      P  = F + n/φ  = z_first + (1 - D) n/φ,
    N  = P + (n' - n)/φ,       N' = P' + (n' - n)/φ        (nodal points).

Pupils are images of the stop (at any conjugate the same planes); the marginal ray from the axial
object point to the rim of the stop fixes the object- and image-space numerical apertures, the
paraxial working F-number ``1 / (2 n' u')`` and, with a chief ray, the paraxial magnification
``m = y'/y``.
Every value is a differentiable torch scalar (mm, or dimensionless), at one wavelength (nm;
``None``: the lens spec's primary wavelength).  Each function takes a lens or a
:class:`~deeplens.optics.camera.Camera` in its place (paraxial: the camera's options do not
apply), as the other analysis functions do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .checks import check_wavelength
from ..optics.camera import unpack
from ..optics.paraxial import surface_power
from ..optics.paraxial import exit_pupil, paraxial

__all__ = ["CardinalPoints", "cardinal_points", "system_matrix", "Pupils", "pupils",
           "magnification"]


def _indices(lens, wavelength_nm):
    w = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    check_wavelength(lens, w)
    p0 = torch.zeros((), dtype=lens.dtype, device=lens.device)   # dtype and device
    wt = torch.tensor(w, dtype=p0.dtype, device=p0.device)
    return [m.n(wt).to(p0) for m in lens.materials], w


def system_matrix(lens, wavelength_nm: float | None = None, first: int = 0,
                  last: int | None = None) -> torch.Tensor:
    """The ``(2, 2)`` paraxial matrix acting on ``(y, n u)`` from vertex ``first`` (before its
    refraction) to vertex ``last`` (after it); default the whole lens."""
    lens = unpack(lens, where="system_matrix")[0]
    n, w = _indices(lens, wavelength_nm)
    last = len(lens.surfaces) - 1 if last is None else last
    dist = list(lens.distances)
    one = torch.ones_like(dist[0])
    zero = torch.zeros_like(one)
    M = torch.stack([torch.stack([one, zero]), torch.stack([zero, one])])
    for i in range(first, last + 1):
        if i > first:   # the medium's transfer: (1, t / n, 0, 1), or a graded medium's own
            A, B, C, D = (v.to(one) for v in lens.materials[i].paraxial_transfer(dist[i], n[i]))
            M = torch.stack([torch.stack([A, B]), torch.stack([C, D])]) @ M
        phi = surface_power(lens.surfaces[i], n[i], n[i + 1], w).to(one)
        M = torch.stack([torch.stack([one, zero]), torch.stack([-phi, one])]) @ M
    return M


@dataclass
class CardinalPoints:
    """Absolute axial positions (mm, lens frame) of the cardinal points and the focal lengths.

    ``efl`` is the rear focal length ``f' = n'/φ``; ``front_focal_length`` is ``f = -n/φ``."""

    efl: torch.Tensor
    front_focal_length: torch.Tensor
    power: torch.Tensor  # 1/mm
    front_focal_z: torch.Tensor
    rear_focal_z: torch.Tensor
    front_principal_z: torch.Tensor
    rear_principal_z: torch.Tensor
    front_nodal_z: torch.Tensor
    rear_nodal_z: torch.Tensor
    n_object: torch.Tensor
    n_image: torch.Tensor
    wavelength_nm: float

    def as_dict(self) -> dict:
        return {k: (float(v) if torch.is_tensor(v) else v) for k, v in self.__dict__.items()}


def cardinal_points(lens, wavelength_nm: float | None = None) -> CardinalPoints:
    """Focal, principal and nodal points of ``lens`` (see the module docstring).

    Raises:
        ValueError: for an afocal system (zero power) or an unusable wavelength.
    """
    lens = unpack(lens, where="cardinal_points")[0]
    n, w = _indices(lens, wavelength_nm)
    M = system_matrix(lens, w)
    A, C, D = M[0, 0], M[1, 0], M[1, 1]
    phi = -C
    if abs(float(phi)) < 1e-15:
        raise ValueError("the system is afocal (zero paraxial power): no cardinal points")
    z = lens.z_vertices()
    n0, n1 = n[0], n[-1]
    F2 = z[-1] + A * n1 / phi
    P2 = F2 - n1 / phi
    F1 = z[0] - D * n0 / phi
    P1 = F1 + n0 / phi
    shift = (n1 - n0) / phi
    return CardinalPoints(efl=n1 / phi, front_focal_length=-n0 / phi, power=phi,
                          front_focal_z=F1, rear_focal_z=F2, front_principal_z=P1,
                          rear_principal_z=P2, front_nodal_z=P1 + shift,
                          rear_nodal_z=P2 + shift, n_object=n0, n_image=n1, wavelength_nm=w)


@dataclass
class Pupils:
    """Entrance and exit pupils and the conjugate-dependent apertures.

    Positions are absolute ``z`` (mm); diameters in mm.  ``object_na`` is ``n sin U`` of the
    paraxial marginal ray (0 for an object at infinity), ``image_na`` the image-space one,
    ``working_fno = 1 / (2 n' |u'|)`` the paraxial working F-number (``EFL / EPD`` at infinity;
    Zemax's "paraxial working F/#") and ``pupil_magnification = D_xp / D_ep``."""

    entrance_z: torch.Tensor
    entrance_diameter: torch.Tensor
    exit_z: torch.Tensor
    exit_diameter: torch.Tensor
    pupil_magnification: torch.Tensor
    object_na: torch.Tensor
    image_na: torch.Tensor
    working_fno: torch.Tensor
    image_z: torch.Tensor
    object_distance_mm: float
    wavelength_nm: float

    def as_dict(self) -> dict:
        return {k: (float(v) if torch.is_tensor(v) else v) for k, v in self.__dict__.items()}


def _object_distance(lens, object_distance_mm):
    s = float(lens.spec.object_distance_mm if object_distance_mm is None else object_distance_mm)
    if not (s > 0):
        raise ValueError(f"object distance must be > 0 mm (or inf), got {s!r}")
    return s


def pupils(lens, wavelength_nm: float | None = None,
           object_distance_mm: float | None = None) -> Pupils:
    """Pupils and apertures for an object ``object_distance_mm`` before the first vertex
    (default the lens spec's; ``inf`` for a distant object).

    The marginal ray starts at the axial object point and passes the rim of the entrance pupil;
    it is traced with the system matrix to the paraxial image, where its slope gives the
    image-space NA.  Raises ``ValueError`` for an object at a focal point (image at infinity).
    """
    lens = unpack(lens, where="pupils")[0]
    n, w = _indices(lens, wavelength_nm)
    s = _object_distance(lens, object_distance_mm)
    p = paraxial(lens, w)
    z_xp, r_xp = exit_pupil(lens, w)
    r_ep = 0.5 * p.entrance_pupil_diameter
    z = lens.z_vertices()
    M = system_matrix(lens, w)
    if math.isinf(s):
        y0, nu0 = r_ep, torch.zeros_like(r_ep)
        na_obj = torch.zeros_like(r_ep)
    else:
        # from the object point (z0 - s) to the EP rim (z_ep, r_ep): slope u, height at vertex 0
        u = r_ep / (p.entrance_pupil_z - (z[0] - s))
        y0, nu0 = u * s, n[0] * u
        na_obj = n[0] * torch.sin(torch.atan(u))
    y1 = M[0, 0] * y0 + M[0, 1] * nu0
    nu1 = M[1, 0] * y0 + M[1, 1] * nu0
    if abs(float(nu1)) < 1e-15:
        raise ValueError(f"the object at {s:g} mm is imaged at infinity: no image-space NA")
    image_z = z[-1] - y1 * n[-1] / nu1
    na_img = n[-1] * torch.sin(torch.atan((nu1 / n[-1]).abs()))
    return Pupils(entrance_z=p.entrance_pupil_z, entrance_diameter=2 * r_ep, exit_z=z_xp,
                  exit_diameter=2 * r_xp, pupil_magnification=r_xp / r_ep, object_na=na_obj,
                  image_na=na_img, working_fno=1.0 / (2.0 * nu1.abs()), image_z=image_z,
                  object_distance_mm=s, wavelength_nm=w)


def magnification(lens, wavelength_nm: float | None = None,
                  object_distance_mm: float | None = None) -> torch.Tensor:
    """Paraxial lateral magnification ``m = y'/y`` for a finite object distance (mm).

    The matrix from the object plane (transfer ``s`` in object space, then the lens) is
    ``[[A, B], [C, D]]``; the image lies ``t' = -B n'/D`` after the last vertex, where ``B``
    vanishes, and there the matrix is ``[[m, 0], [C, 1/m]]`` with ``m = A + t' C / n'``.

    Raises:
        ValueError: for an object at infinity (use the EFL and the field angle instead).
    """
    lens = unpack(lens, where="magnification")[0]
    n, w = _indices(lens, wavelength_nm)
    s = _object_distance(lens, object_distance_mm)
    if math.isinf(s):
        raise ValueError("magnification is zero for an object at infinity; the image height is "
                         "EFL * tan(field angle)")
    M = system_matrix(lens, w)
    # object plane -> first vertex: transfer by s in n[0]
    A = M[0, 0]
    B = M[0, 0] * s / n[0] + M[0, 1]
    C = M[1, 0]
    D = M[1, 0] * s / n[0] + M[1, 1]
    if abs(float(D)) < 1e-15:
        raise ValueError(f"the object at {s:g} mm is at the front focal point: image at infinity")
    t_img = -B * n[-1] / D  # image distance from the last vertex (B' = 0)
    return A + t_img * C / n[-1]
