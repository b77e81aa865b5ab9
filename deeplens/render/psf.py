"""Point-spread functions by forward tracing and bilinear splatting.

The PSF of an object point is the splatted irradiance of its rays on a ``K x K`` pixel grid
centred on the point's *ideal* image (:class:`~deeplens.render.scene.IdealCamera`), so that
shifts (distortion, lateral colour) stay in the kernel.  ``K`` is sized from the measured spot:
the smallest odd size holding 99.9 % of the rays (capped by ``max_kernel``), never a constant.
Kernels are normalised to sum 1 (the lost energy is reported by :func:`psf`'s
``return_energy``).  Index convention: the kernel is in image orientation (row = sensor row).
"""

from __future__ import annotations

import math

import torch

from .scene import IdealCamera
from .splat import point_source_rays, splat_bilinear, trace_to_sensor_pixels

__all__ = ["psf", "psf_kernel_size", "psf_grid"]


def _ideal_pixel(camera: IdealCamera, X: float, Y: float, depth_mm: float):
    """Fractional pixel position of the ideal image of an object point."""
    if math.isinf(depth_mm):
        x, y = camera.kappa * X, camera.kappa * Y
    else:
        s = camera.object_scale(depth_mm)
        x, y = X / s, Y / s
    return camera.sensor.xy_to_pixel(torch.tensor(x), torch.tensor(y))


def psf_kernel_size(di: torch.Tensor, dj: torch.Tensor, valid: torch.Tensor,
                    max_kernel: int = 129, quantile: float = 0.999) -> int:
    """Odd kernel size holding ``quantile`` of the valid rays' offsets (pixels)."""
    r = torch.maximum(di.detach().abs(), dj.detach().abs())[valid]
    if r.numel() == 0:
        return 3
    q = float(torch.quantile(r.double(), quantile)) if r.numel() > 1 else float(r.max())
    k = 2 * int(math.ceil(q + 1.0)) + 1
    return int(min(max(k, 3), max_kernel | 1))


def psf(lens, sensor, point_xy_mm, depth_mm: float, wavelength_nm: float, n_rays: int = 4096,
        kernel_size: int | None = None, seed: int = 0, options=None, max_kernel: int = 129,
        return_energy: bool = False, sampling: str = "random"):
    """PSF ``(K, K)`` of an object point (see module docstring); differentiable in the lens.

    Args:
        point_xy_mm: ``(X, Y)`` object position (mm), or direction tangents for infinity.
        depth_mm: object distance from the first vertex (mm) or ``math.inf``.
        kernel_size: force ``K`` (odd); ``None`` sizes it from the spot.
        sampling: pupil sampling, ``"random"`` or a pattern (see
            :func:`~deeplens.render.splat.point_source_rays`).

    Raises:
        ValueError: if no ray of the point reaches the sensor (fully vignetted).
    """
    camera = IdealCamera(lens, sensor)
    rays = point_source_rays(lens, point_xy_mm, depth_mm, wavelength_nm, n_rays, seed,
                             sampling=sampling)
    i, j, valid = trace_to_sensor_pixels(lens, sensor, rays, options)
    if not bool(valid.any()):
        raise ValueError(f"no ray from the object point {tuple(point_xy_mm)} at depth "
                         f"{depth_mm} mm reaches the sensor at {wavelength_nm:g} nm (fully "
                         f"vignetted)")
    ci, cj = _ideal_pixel(camera, float(point_xy_mm[0]), float(point_xy_mm[1]), depth_mm)
    di, dj = i - float(ci), j - float(cj)
    K = kernel_size or psf_kernel_size(di, dj, valid, max_kernel)
    if K % 2 == 0:
        raise ValueError(f"kernel_size must be odd, got {K}")
    w = valid.to(i.dtype)
    ker = splat_bilinear(di + K / 2, dj + K / 2, w, (K, K))
    total = ker.sum()
    ker = ker / total.clamp_min(1e-30)
    if return_energy:
        return ker, float(total) / max(int(valid.sum()), 1)
    return ker


def psf_grid(lens, sensor, depth_mm: float, wavelength_nm: float, grid=(3, 3),
             n_rays: int = 4096, kernel_size: int | None = None, seed: int = 0, options=None):
    """PSFs at a ``(gy, gx)`` grid of sensor positions (patch centres) for one depth.

    Returns ``(kernels (gy, gx, K, K), centres (gy, gx, 2) in fractional pixels)``; all
    kernels share the largest measured size.
    """
    camera = IdealCamera(lens, sensor)
    H, W = sensor.resolution
    gy, gx = grid
    ii = [(k + 0.5) * H / gy for k in range(gy)]
    jj = [(k + 0.5) * W / gx for k in range(gx)]
    pts = []
    for i in ii:
        for j in jj:
            x, y = sensor.pixel_to_xy(torch.tensor(i), torch.tensor(j))
            if math.isinf(depth_mm):
                pts.append((float(x) / camera.kappa, float(y) / camera.kappa))
            else:
                s = camera.object_scale(depth_mm)
                pts.append((float(x) * s, float(y) * s))
    if kernel_size is None:
        sizes = []
        for P in pts:
            rays = point_source_rays(lens, P, depth_mm, wavelength_nm, min(n_rays, 1024), seed)
            i_, j_, v_ = trace_to_sensor_pixels(lens, sensor, rays, options)
            ci, cj = _ideal_pixel(camera, P[0], P[1], depth_mm)
            sizes.append(psf_kernel_size(i_ - float(ci), j_ - float(cj), v_))
        kernel_size = max(sizes)
    kers = [psf(lens, sensor, P, depth_mm, wavelength_nm, n_rays, kernel_size, seed, options)
            for P in pts]
    K = kernel_size
    centres = torch.tensor([[i, j] for i in ii for j in jj]).reshape(gy, gx, 2)
    return torch.stack(kers).reshape(gy, gx, K, K), centres

