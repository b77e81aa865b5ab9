"""Image-quality metrics: PSNR, SSIM (kornia), and radial field bands.

``PSNR = 10 log10(1 / MSE)`` for images in ``[0, 1]``; SSIM with an 11-pixel Gaussian window
(``kornia.metrics.ssim``).  Field bands split the image by normalised radius
``ρ = r / r_corner`` into ``[b_0, b_1), [b_1, b_2), ...``.
"""

from __future__ import annotations

import torch
from kornia.metrics import ssim as kornia_ssim

__all__ = ["psnr", "ssim", "band_masks", "image_metrics", "masked_psnr", "masked_ssim"]


def psnr(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean PSNR (dB) over a batch ``(B, C, H, W)`` of images in ``[0, 1]``."""
    mse = ((pred.clamp(0, 1) - target) ** 2).flatten(1).mean(1).clamp_min(1e-12)
    return (10 * torch.log10(1.0 / mse)).mean()


def ssim(pred: torch.Tensor, target: torch.Tensor, window: int = 11) -> torch.Tensor:
    """Mean SSIM over a batch (kornia, Gaussian window)."""
    return kornia_ssim(pred.clamp(0, 1), target, window).mean()


def band_masks(shape, edges) -> torch.Tensor:
    """Boolean masks ``(len(edges)-1, H, W)`` of radial bands ``edges[k] <= ρ < edges[k+1]``
    (the last band includes ``ρ = 1``)."""
    H, W = shape
    y = torch.arange(H, dtype=torch.float64) + 0.5 - H / 2
    x = torch.arange(W, dtype=torch.float64) + 0.5 - W / 2
    Y, X = torch.meshgrid(y, x, indexing="ij")
    rho = torch.sqrt(X ** 2 + Y ** 2) / (0.5 * (H ** 2 + W ** 2) ** 0.5)
    out = []
    for k in range(len(edges) - 1):
        lo, hi = edges[k], edges[k + 1]
        m = (rho >= lo) & ((rho < hi) if k < len(edges) - 2 else (rho <= hi + 1e-9))
        out.append(m)
    return torch.stack(out)


def masked_psnr(pred, target, mask) -> torch.Tensor:
    """PSNR (dB) over the pixels where ``mask`` ``(H, W)`` is true, averaged over the batch."""
    m = mask.to(pred.device)
    err = ((pred.clamp(0, 1) - target) ** 2).mean(1)[:, m]  # (B, n)
    return (10 * torch.log10(1.0 / err.mean(1).clamp_min(1e-12))).mean()


def masked_ssim(pred, target, mask, window: int = 11) -> torch.Tensor:
    """Mean of the SSIM map over the pixels of ``mask``."""
    smap = kornia_ssim(pred.clamp(0, 1), target, window).mean(1)  # (B, H, W)
    return smap[:, mask.to(pred.device)].mean()


def image_metrics(stage: str, tag: str, y, gt, pred, field_bands=None) -> dict:
    """The logged metrics of one depth of a ``stage`` (``val``/``test``) batch:
    ``{stage}/{psnr,ssim}_{sensor,restored}/{tag}`` of the sensor image ``y`` and the restored
    ``pred`` against ``gt`` (each ``(B, C, H, W)``), and the same per field band
    (``.../band<lo>-<hi>``) when ``field_bands`` are given."""
    log = {f"{stage}/psnr_sensor/{tag}": psnr(y, gt),
           f"{stage}/psnr_restored/{tag}": psnr(pred, gt),
           f"{stage}/ssim_sensor/{tag}": ssim(y, gt),
           f"{stage}/ssim_restored/{tag}": ssim(pred, gt)}
    if field_bands:
        for k, m in enumerate(band_masks(gt.shape[-2:], field_bands)):
            b = f"band{field_bands[k]:g}-{field_bands[k + 1]:g}"
            log[f"{stage}/psnr_sensor/{b}"] = masked_psnr(y, gt, m)
            log[f"{stage}/psnr_restored/{b}"] = masked_psnr(pred, gt, m)
            log[f"{stage}/ssim_sensor/{b}"] = masked_ssim(y, gt, m)
            log[f"{stage}/ssim_restored/{b}"] = masked_ssim(pred, gt, m)
    return log
