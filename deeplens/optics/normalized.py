"""Rays from normalised field and pupil coordinates ``(Hx, Hy, Px, Py)``, as Zemax defines them.

Field: ``(Hx, Hy)`` scale the largest field angle ``θ_max`` (default the lens spec's largest
``|field|``): the ray bundle's object-space angles are ``θ_x = Hx θ_max``, ``θ_y = Hy θ_max``,
its direction ``∝ (tan θ_x, tan θ_y, 1)`` for an object at infinity, or from the object point
``-(tan θ_x, tan θ_y) (z_EP - z_obj)`` (seen from the entrance-pupil centre under those
angles) for a finite one (on the object plane, tilted where ``lens.object_tilt`` says so:
:func:`~.sampling.object_points`).  ``Hy = 1`` is the lens's ``+θ_max`` field of
:func:`~.sampling.field_rays`.

Pupil: ``(Px, Py)`` on the unit disk.

* ``aim="stop"`` (*ray aiming*): the ray crosses the stop surface at ``(Px, Py) r_stop`` about
  the axis, ``r_stop`` its semi-diameter.  The entrance-pupil-plane point ``u`` of each ray is
  found by Newton's method on ``g(u) = y_stop(u) - P r_stop`` with a ``2 × 2`` forward-difference
  Jacobian per ray (``h = 10^-7 r_EP``); all rays are traced in one bundle (three traces per
  iteration), to ``|g| < tol · r_stop``.  ``P = (0, 0)`` is the real chief ray, solved first;
  the target is then moved from the stop centre to ``P r_stop`` in four stages (a
  continuation: far off axis the paraxial pupil's rim rays can miss the lens), and a step whose
  ray would miss a surface is halved.
* ``aim="paraxial"``: the ray crosses the paraxial entrance-pupil plane at ``(Px, Py) r_EP``
  (lens-design programs without ray aiming).

Rays start before the first surface (:func:`~.sampling.start_plane_z`).
"""

from __future__ import annotations

import math

import torch

from .options import TraceOptions
from .paraxial import paraxial
from .rays import Rays
from .sampling import object_points, rays_from_tangents, start_plane_z

__all__ = ["normalized_rays", "pupil_to_stop"]


def _pairs(v, what: str) -> torch.Tensor:
    t = torch.as_tensor(v, dtype=torch.float64)
    if t.dim() == 1:
        t = t[None]
    if t.dim() != 2 or t.shape[-1] != 2:
        raise ValueError(f"{what} must be (2,) or (M, 2) pairs, got shape {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{what} must be finite, got {t.tolist()}")
    return t


def _launch(lens, H, u, z_ep, theta_max):
    """Object-space rays ``(M,)`` (float64) of normalised fields ``H`` through the points ``u``
    ``(M, 2)`` of the plane ``z_ep``."""
    tan = torch.tan(torch.deg2rad(H * theta_max))
    P = torch.cat([u, torch.full_like(u[:, :1], z_ep)], -1)
    s = float(lens.spec.object_distance_mm)
    z0 = start_plane_z(lens)
    if math.isinf(s):
        return P, tan, z0
    q = object_points(lens, tan, z_ep, s)        # object points, (M, 3): on a tilted plane too
    z_near = float(q[:, 2].min())
    real = z_near <= float(lens.z_vertices()[0])   # s < 0 (or a tilted plane beyond): virtual
    return P, (u - q[:, :2]) / (z_ep - q[:, 2:]), (max(z0, z_near) if real else z0)


def _stop_xy(lens, P, tangents, z0, wavelength_nm):
    """Where the rays cross the stop surface (apertures ignored), ``(M, 2)`` and valid."""
    rays = rays_from_tangents(P, tangents, z0, wavelength_nm, torch.float64)
    z = lens.z_vertices()
    n = lens.indices(torch.tensor(float(wavelength_nm), dtype=torch.float64))
    aim = TraceOptions(clip_aperture=False)
    for i in range(lens.stop_index + 1):
        rays = lens.trace_surface(i, rays, n[i], n[i + 1], z, aim, refract_=i < lens.stop_index)
    return rays.o[:, :2], rays.valid


def pupil_to_stop(lens, H, P, wavelength_nm: float, *, max_field_deg: float | None = None,
                  iterations: int = 30, tol: float = 1e-10):
    """``(u, z_EP, stop_xy, valid)``: the entrance-pupil-plane points ``u`` ``(M, 2)`` (mm)
    whose rays cross the stop at ``P r_stop`` (module docstring, ``aim="stop"``), the plane's
    position, where they do cross it, and which converged.  Computed in float64, no gradient."""
    lens64 = lens if lens.dtype == torch.float64 else None
    if lens64 is None:
        raise ValueError("pupil_to_stop: ray aiming runs on a float64 lens "
                         "(lens.to(torch.float64))")
    H, P = torch.broadcast_tensors(_pairs(H, "H"), _pairs(P, "P"))
    theta = _theta_max(lens, max_field_deg)
    with torch.no_grad():
        p = paraxial(lens)
        z_ep, r_ep = float(p.entrance_pupil_z), 0.5 * float(p.entrance_pupil_diameter)
        r_stop = float(lens.stop.semi_diameter)
        h = 1e-7 * max(r_ep, 1e-6)
        M = H.shape[0]
        eye = torch.eye(2, dtype=torch.float64)

        def stop_of(u):
            Pt, tan, z0 = _launch(lens, H, u, z_ep, theta)
            return _stop_xy(lens, Pt, tan, z0, wavelength_nm)

        def newton(u, target, n_iter):
            for _ in range(n_iter):
                Pt, tan, z0 = _launch(lens, torch.cat([H, H, H]),
                                      torch.cat([u, u + h * eye[0], u + h * eye[1]]), z_ep, theta)
                xy, ok = _stop_xy(lens, Pt, tan, z0, wavelength_nm)
                g = xy[:M] - target
                J = torch.stack([(xy[M:2 * M] - xy[:M]) / h, (xy[2 * M:] - xy[:M]) / h], -1)
                valid = ok[:M] & ok[M:2 * M] & ok[2 * M:]
                err = torch.where(valid[:, None], g, torch.zeros_like(g)).abs().max()
                if float(err) < tol * r_stop and bool(valid.all()):
                    break
                J = torch.where(valid[:, None, None], J, eye)
                step = torch.linalg.solve(J, -g[..., None])[..., 0]
                step = torch.where(valid[:, None], step, torch.zeros_like(step))
                for _ in range(30):   # halve the steps whose rays would miss a surface
                    _, ok_new = stop_of(u + step)
                    bad = valid & ~ok_new
                    if not bool(bad.any()):
                        break
                    step = torch.where(bad[:, None], 0.5 * step, step)
                u = u + step
            return u

        # the chief ray first, then the pupil coordinates in stages from it (a continuation:
        # far off axis the paraxial pupil's rim rays can miss the lens altogether)
        u = newton(torch.zeros_like(P), torch.zeros_like(P), iterations)
        for stage in (0.25, 0.5, 0.75):
            u = newton(u, stage * P * r_stop, 6)
        u = newton(u, P * r_stop, iterations)
        xy, ok = stop_of(u)
        done = ok & ((xy - P * r_stop).abs().amax(-1) < 1e3 * tol * r_stop)
    return u, z_ep, xy, done


def _theta_max(lens, max_field_deg):
    t = (max(abs(float(f)) for f in lens.spec.fields_deg) if max_field_deg is None
         else float(max_field_deg))
    if not (math.isfinite(t) and 0 <= t < 90):
        raise ValueError(f"max_field_deg must lie in [0, 90) degrees, got {t!r}")
    return t


def normalized_rays(lens, H, P, wavelength_nm: float | None = None, *, aim: str = "stop",
                    max_field_deg: float | None = None) -> Rays:
    """Object-space rays of normalised field ``H`` and pupil ``P`` coordinates.

    Args:
        lens: the :class:`~.lens.Lens` (``aim="stop"`` needs it in float64).
        H: ``(Hx, Hy)`` or ``(M, 2)``: field in units of ``max_field_deg``.
        P: ``(Px, Py)`` or ``(M, 2)``: pupil in units of the stop (``aim="stop"``) or paraxial
            entrance-pupil (``aim="paraxial"``) radius; broadcast against ``H``.
        wavelength_nm: default the lens's primary wavelength.
        aim: ``"stop"`` (ray aiming) or ``"paraxial"`` (module docstring).
        max_field_deg: the field angle of ``|H| = 1`` (default the spec's largest).

    Returns:
        :class:`~.rays.Rays` ``(M,)`` in the lens's dtype, starting before the first surface;
        rays that could not be aimed (they miss a surface on the way to the stop) are invalid.

    Example:
        >>> from deeplens.optics import load_lens
        >>> lens = load_lens("double_gauss").to(torch.float64)
        >>> rays = normalized_rays(lens, (0, 0.7), [(0, 0), (0, 1), (0, -1)])
        >>> out = lens.trace_to_sensor(rays)   # chief, upper and lower marginal rays at 0.7 field
        >>> out.valid.tolist(), [round(y, 2) for y in out.o[:, 1].tolist()]
        ([True, True, True], [7.14, 7.15, 7.14])
    """
    if aim not in ("stop", "paraxial"):
        raise ValueError(f"aim must be 'stop' or 'paraxial', got {aim!r}")
    wl = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    if aim == "stop":
        u, z_ep, _, ok = pupil_to_stop(lens, H, P, wl, max_field_deg=max_field_deg)
        Hb = torch.broadcast_tensors(_pairs(H, "H"), _pairs(P, "P"))[0]
    else:
        Hb, Pb = torch.broadcast_tensors(_pairs(H, "H"), _pairs(P, "P"))
        with torch.no_grad():
            p = paraxial(lens)
            z_ep, r_ep = float(p.entrance_pupil_z), 0.5 * float(p.entrance_pupil_diameter)
        u, ok = Pb * r_ep, None
    Pt, tan, z0 = _launch(lens, Hb, u, z_ep, _theta_max(lens, max_field_deg))
    rays = rays_from_tangents(Pt, tan, z0, wl, lens.dtype)
    return rays if ok is None else rays.replace(valid=rays.valid & ok.to(rays.device))
