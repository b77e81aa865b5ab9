"""The image terms of the end-to-end loss (:class:`~.module.EndToEndModule`): MSE, L1,
``1 - SSIM`` and the perceptual term, each with its weight of ``model.loss``, optionally
weighted per sample by a soft maximum over depth (:class:`~.depth_weighting.DepthSoftMax`).

Images are ``(B, C, H, W)`` float tensors in ``[0, 1]`` (``pred`` the restored image, ``gt`` the
ideal camera's).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from kornia.metrics import ssim as kornia_ssim

from .metrics import ssim

__all__ = ["per_image", "per_image_terms", "terms"]


def per_image_terms(weights: dict, pred, gt) -> dict:
    """The MSE, L1 and (1 - SSIM) terms with a non-zero weight, per image ``(B,)``."""
    per = {}
    if weights["mse"]:
        per["mse"] = ((pred - gt) ** 2).flatten(1).mean(1)
    if weights["l1"]:
        per["l1"] = (pred - gt).abs().flatten(1).mean(1)
    if weights["ssim"]:
        per["ssim"] = 1 - kornia_ssim(pred.clamp(0, 1), gt, 11).flatten(1).mean(1)
    return per


def per_image(weights: dict, pred, gt) -> torch.Tensor:
    """The weighted MSE + L1 + SSIM loss of each image ``(B,)``, detached."""
    with torch.no_grad():
        total = torch.zeros(pred.shape[0], dtype=pred.dtype, device=pred.device)
        for k, v in per_image_terms(weights, pred, gt).items():
            total = total + weights[k] * v
    return total


def terms(weights: dict, pred, gt, depths=None, softmax=None, perceptual=None) -> dict:
    """The loss terms ``{name: scalar}`` (unweighted; ``weights`` says which are on).  With a
    ``softmax`` (:class:`~.depth_weighting.DepthSoftMax`) and ``depths`` given, the MSE, L1
    and SSIM terms are weighted per sample (from their weighted per-image sum; the soft
    maximum's running means are updated); else they are the batch means.  ``perceptual``:
    ``(pred, gt) -> scalar`` for the perceptual term (a grey image is given as its own three
    channels)."""
    out = {}
    if softmax is not None and depths is not None:
        per = per_image_terms(weights, pred, gt)
        if per:
            total = sum(weights[k] * v for k, v in per.items())
            sw = softmax(total, depths)
            out.update({k: (sw * v).mean() for k, v in per.items()})
    else:
        if weights["mse"]:
            out["mse"] = F.mse_loss(pred, gt)
        if weights["l1"]:
            out["l1"] = F.l1_loss(pred, gt)
        if weights["ssim"]:
            out["ssim"] = 1 - ssim(pred, gt)
    if weights["perceptual"]:
        if pred.shape[1] == 1:  # VGG16 takes RGB: a grey image is its own three channels
            pred, gt = pred.expand(-1, 3, -1, -1), gt.expand(-1, 3, -1, -1)
        out["perceptual"] = perceptual(pred, gt)
    return out
