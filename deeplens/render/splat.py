"""Forward tracing and bilinear splatting (paper Sec. III-D, "reconstruction filter").

A ray landing at fractional pixel position ``(i, j)`` (pixel centres at ``k + 1/2``) adds its
weight to the four nearest pixel centres with bilinear weights
``(1 - a)(1 - b), (1 - a) b, a (1 - b), a b`` where ``a, b`` are the fractional offsets from the
lower-left centre.  The weights sum to one (energy is conserved except for rays splatting
outside the grid) and are continuous in the hit position, so gradients flow to the lens.

Point sources: rays leave an object point (or arrive as a parallel beam from infinity) towards
points sampled uniformly on the paraxial entrance pupil enlarged by ``pupil_margin``; rays the
lens vignettes are dropped.
"""

from __future__ import annotations

import math

import torch

from ..optics.paraxial import paraxial
from ..optics.rays import Rays
from ..optics.sampling import (pupil_pattern, random_disk, rays_from_point, rays_from_tangents,
                               start_plane_z)

__all__ = ["splat_bilinear", "entrance_pupil", "point_source_rays", "trace_to_sensor_pixels"]


def splat_bilinear(i: torch.Tensor, j: torch.Tensor, weights: torch.Tensor, shape) -> torch.Tensor:
    """Splat ``N`` weighted points at fractional pixel positions into an ``(H, W)`` image.

    Args:
        i, j: ``(N,)`` fractional row/column positions (pixel centres at ``k + 0.5``).
        weights: ``(N,)`` (0 for invalid rays).
        shape: ``(H, W)``.

    Returns:
        ``(H, W)`` image, differentiable in ``i, j`` and ``weights``.
    """
    H, W = int(shape[0]), int(shape[1])
    u, v = i - 0.5, j - 0.5
    i0, j0 = torch.floor(u.detach()), torch.floor(v.detach())
    a, b = u - i0, v - j0
    i0, j0 = i0.long(), j0.long()
    img = torch.zeros(H * W, dtype=weights.dtype, device=weights.device)
    for di, wi in ((0, 1 - a), (1, a)):
        for dj, wj in ((0, 1 - b), (1, b)):
            ii, jj = i0 + di, j0 + dj
            ok = (ii >= 0) & (ii < H) & (jj >= 0) & (jj < W)
            idx = torch.where(ok, ii * W + jj, torch.zeros_like(ii))
            img = img.index_add(0, idx, torch.where(ok, weights * wi * wj,
                                                    torch.zeros_like(weights)))
    return img.reshape(H, W)


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
    """Rays from an object point towards the entrance pupil.

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
        t = torch.tensor([X, Y], dtype=torch.float64, device=device)
        return rays_from_tangents(E, t, start_plane_z(lens), wavelength_nm, dtype)
    if not depth_mm > 0:
        raise ValueError(f"point source depth must be > 0 mm (in front of the lens), got "
                         f"{depth_mm}")
    P = torch.tensor([X, Y, z0 - depth_mm], dtype=torch.float64, device=device)
    return rays_from_point(E, P, start_plane_z(lens), wavelength_nm, dtype)


def trace_to_sensor_pixels(lens, sensor, rays: Rays, options=None):
    """Forward-trace to the sensor plane; returns fractional ``(i, j)`` and the valid mask."""
    out = lens.trace_to_sensor(rays, options=options)
    i, j = sensor.xy_to_pixel(out.o[..., 0], out.o[..., 1])
    return i, j, out.valid
