"""Point-spread functions by forward tracing and bilinear splatting.

The PSF of an object point is the splatted irradiance of its rays on a ``K x K`` pixel grid
centred on the point's *ideal* image (:class:`~deeplens.render.scene.IdealCamera`), so that
shifts (distortion, lateral colour) stay in the kernel.  ``K`` is sized from the measured spot:
the smallest odd size holding 99.9 % of the rays (capped by ``max_kernel``), never a constant.
Kernels are normalised to sum 1 (the lost energy is reported by :func:`psf`'s
``return_energy``).  Index convention: the kernel is in image orientation (row = sensor row).

Every function takes a :class:`~deeplens.optics.camera.Camera` in place of ``lens`` (then
``sensor`` is ``None`` and the traces run with the camera's options), e.g.
``psf(camera, None, (0.0, 0.0), 5000.0, 587.6)``, or a lens with its ``sensor`` and ``options``.
"""

from __future__ import annotations

import math

import torch

from .scene import IdealCamera
from ..optics.camera import unpack
from ..optics.rays import Rays
from ..optics.sampling import entrance_pupil, point_source_rays
from .splat import splat_bilinear, trace_to_sensor_pixels

__all__ = ["psf", "psf_many", "psf_kernel_size", "psf_grid", "psf_grids"]


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
        lens, sensor: a :class:`~deeplens.optics.camera.Camera` and ``None``, or a lens and
            its sensor.
        point_xy_mm: ``(X, Y)`` object position (mm), or direction tangents for infinity.
        depth_mm: object distance from the first vertex (mm) or ``math.inf``.
        kernel_size: force ``K`` (odd); ``None`` sizes it from the spot.
        sampling: pupil sampling, ``"random"`` or a pattern (see
            :func:`~deeplens.render.splat.point_source_rays`).

    Raises:
        ValueError: if no ray of the point reaches the sensor (fully vignetted).
    """
    return psf_many(lens, sensor, [(point_xy_mm, depth_mm, wavelength_nm)], n_rays, kernel_size,
                    seed, options, max_kernel, return_energy, sampling)[0]


def psf_many(lens, sensor, jobs, n_rays: int = 4096, kernel_size=None, seed: int = 0,
             options=None, max_kernel: int = 129, return_energy: bool = False,
             sampling: str = "random"):
    """The PSFs of several object points, depths and wavelengths, traced together.

    Each job is :func:`psf` of ``(point_xy_mm, depth_mm, wavelength_nm)`` with the same rays and
    kernel (the rays of every job are one ``(J, n)`` batch, one trace instead of ``J``: an
    eager trace of a few thousand rays costs its operator count, not its arithmetic).

    Args:
        jobs: sequence of ``(point_xy_mm, depth_mm, wavelength_nm)``.
        kernel_size: ``None`` (each kernel sized from its own spot), one odd ``K`` for all, or
            a sequence of one per job.
        n_rays, seed, options, max_kernel, return_energy, sampling: as :func:`psf`.

    Returns:
        A list of ``(K_j, K_j)`` kernels (of ``(kernel, energy)`` with ``return_energy``).
    """
    lens, sensor, options = unpack(lens, sensor, options, "psf_many")
    jobs = [(tuple(float(v) for v in p), float(d), float(w)) for p, d, w in jobs]
    if not jobs:
        return []
    sizes = (list(kernel_size) if isinstance(kernel_size, (list, tuple))
             else [kernel_size] * len(jobs))
    if len(sizes) != len(jobs):
        raise ValueError(f"psf_many: {len(sizes)} kernel sizes for {len(jobs)} jobs")
    out = []
    for (p, d, w), K, (di, dj, valid) in zip(jobs, sizes, _job_offsets(
            lens, sensor, jobs, n_rays, seed, options, sampling)):
        if not bool(valid.any()):
            raise ValueError(f"no ray from the object point {p} at depth {d} mm reaches the "
                             f"sensor at {w:g} nm (fully vignetted)")
        K = K or psf_kernel_size(di, dj, valid, max_kernel)
        if K % 2 == 0:
            raise ValueError(f"kernel_size must be odd, got {K}")
        ker = splat_bilinear(di + K / 2, dj + K / 2, valid.to(di.dtype), (K, K))
        total = ker.sum()
        ker = ker / total.clamp_min(1e-30)
        out.append((ker, float(total) / max(int(valid.sum()), 1)) if return_energy else ker)
    return out


def _job_offsets(lens, sensor, jobs, n_rays: int, seed: int, options, sampling: str = "random"):
    """Trace every job's point-source rays as one ``(J, n)`` batch (the wavelength broadcast
    along each row, so the media's indices are evaluated once per job); returns per job the
    hits' offsets ``(di, dj)`` (pixels) from the point's ideal image and the valid mask."""
    camera = IdealCamera(lens, sensor)
    pupil = entrance_pupil(lens)
    rays = [point_source_rays(lens, p, d, w, n_rays, seed, sampling=sampling, pupil=pupil)
            for p, d, w in jobs]
    w = torch.tensor([w for _, _, w in jobs], dtype=lens.dtype, device=lens.device)[:, None]
    batch = Rays(torch.stack([r.o for r in rays]), torch.stack([r.d for r in rays]),
                 w.expand(len(rays), rays[0].o.shape[0]), normalize=False)
    i, j, valid = trace_to_sensor_pixels(lens, sensor, batch, options)
    out = []
    for b, (p, d, _) in enumerate(jobs):
        ci, cj = _ideal_pixel(camera, p[0], p[1], d)
        out.append((i[b] - float(ci), j[b] - float(cj), valid[b]))
    return out


def _grid_points(camera: IdealCamera, depth_mm: float, grid):
    """Object points ``[(X, Y)]`` imaged at the centres of a ``(gy, gx)`` grid of sensor
    patches (row-major) and the centres ``(gy, gx, 2)`` in fractional pixels."""
    sensor = camera.sensor
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
    centres = torch.tensor([[i, j] for i in ii for j in jj]).reshape(gy, gx, 2)
    return pts, centres


def psf_grid(lens, sensor, depth_mm: float, wavelength_nm: float, grid=(3, 3),
             n_rays: int = 4096, kernel_size: int | None = None, seed: int = 0, options=None):
    """PSFs at a ``(gy, gx)`` grid of sensor positions (patch centres) for one depth.

    Returns ``(kernels (gy, gx, K, K), centres (gy, gx, 2) in fractional pixels)``; all
    kernels share the largest measured size (:func:`psf_grids` for several depths and
    wavelengths at once).
    """
    return psf_grids(lens, sensor, [(depth_mm, wavelength_nm)], grid, n_rays, kernel_size, seed,
                     options)[0]


def psf_grids(lens, sensor, specs, grid=(3, 3), n_rays: int = 4096,
              kernel_size: int | None = None, seed: int = 0, options=None):
    """:func:`psf_grid` of each ``(depth_mm, wavelength_nm)`` in ``specs``, all traced together:
    one trace sizes every grid's kernel (``min(n_rays, 1024)`` rays per point; the grid's
    largest spot), one more traces every kernel (:func:`psf_many`).  Returns a list of
    ``(kernels (gy, gx, K, K), centres (gy, gx, 2))``, one per spec."""
    lens, sensor, options = unpack(lens, sensor, options, "psf_grids")
    camera = IdealCamera(lens, sensor)
    gy, gx = grid
    specs = [(float(d), float(w)) for d, w in specs]
    grids = [_grid_points(camera, d, grid) for d, _ in specs]
    jobs = [(P, d, w) for (d, w), (pts, _) in zip(specs, grids) for P in pts]
    per = gy * gx
    if kernel_size is None:
        probes = psf_many_sizes(lens, sensor, jobs, min(n_rays, 1024), seed, options)
        sizes = [max(probes[k * per:(k + 1) * per]) for k in range(len(specs))]
    else:
        sizes = [kernel_size] * len(specs)
    kers = psf_many(lens, sensor, jobs, n_rays, [K for K in sizes for _ in range(per)], seed,
                    options)
    return [(torch.stack(kers[k * per:(k + 1) * per]).reshape(gy, gx, K, K), centres)
            for k, (K, (_, centres)) in enumerate(zip(sizes, grids))]


def psf_many_sizes(lens, sensor, jobs, n_rays: int, seed: int = 0, options=None,
                   max_kernel: int = 129):
    """The kernel size :func:`psf_kernel_size` measures for each job of :func:`psf_many` from
    ``n_rays`` random rays, without autograd, in one trace."""
    lens, sensor, options = unpack(lens, sensor, options, "psf_many_sizes")
    with torch.no_grad():
        return [psf_kernel_size(di, dj, valid, max_kernel)
                for di, dj, valid in _job_offsets(lens, sensor, jobs, n_rays, seed, options)]
