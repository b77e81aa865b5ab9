"""Forward tracing and bilinear splatting (paper Sec. III-D, "reconstruction filter").

A ray landing at fractional pixel position ``(i, j)`` (pixel centres at ``k + 1/2``) adds its
weight to the four nearest pixel centres with bilinear weights
``(1 - a)(1 - b), (1 - a) b, a (1 - b), a b`` where ``a, b`` are the fractional offsets from the
lower-left centre.  The weights sum to one (energy is conserved except for rays splatting
outside the grid) and are continuous in the hit position, so gradients flow to the lens.

Point sources (:func:`~deeplens.optics.sampling.point_source_rays`, re-exported here): rays leave
an object point (or arrive as a parallel beam from infinity) towards points sampled uniformly on
the paraxial entrance pupil enlarged by ``pupil_margin``; rays the lens vignettes are dropped.
"""

from __future__ import annotations


import torch

from ..optics.rays import Rays
from ..optics.sampling import entrance_pupil, point_source_rays  # noqa: F401  (re-exported)

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


def trace_to_sensor_pixels(lens, sensor, rays: Rays, options=None):
    """Forward-trace to the sensor plane; returns fractional ``(i, j)`` and the valid mask."""
    out = lens.trace_to_sensor(rays, options=options)
    i, j = sensor.xy_to_pixel(out.o[..., 0], out.o[..., 1])
    return i, j, out.valid
