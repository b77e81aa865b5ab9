"""The soft maximum over depth bins (``model.worst_depth``, ``model.optics_worst_depth``).

The training depth range is cut into ``K`` bins uniform in 1/depth (:func:`depth_bin`); each
bin keeps a running mean ``E_b`` (momentum ``m``) of the per-image loss of its samples, and a
sample of bin ``b`` is weighted by ``K softmax_b(log E_b / T)`` (:func:`soft_max_weights`;
mean weight 1 over bins, so ``T -> inf`` is the plain mean and small ``T`` trains on the worst
bin).  The running means are float64 buffers ``(K,)`` of the module (``depth_loss_ema``,
``optics_depth_loss_ema``: checkpointed, names unchanged), -1 until a bin's first sample;
the functions here update them in place.  :class:`DepthSoftMax` is one soft maximum as a
module owning its running means, :class:`InvariancePenalty` the depth-invariance penalty
(``model.optics_invariance``) owning its reference ``R_0``; the module keeps their buffers'
checkpoint names (``depth_loss_ema``, ``optics_depth_loss_ema``, ``invariance_ref``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .settings import Invariance, SoftMax
from .wiener import depth_change

__all__ = ["DepthSoftMax", "InvariancePenalty", "depth_bin", "soft_max_weights"]


def depth_bin(depths_mm, depths, bins: int) -> torch.Tensor:
    """Index ``(B,)`` (int64) of each of ``depths`` (mm) in ``bins`` equal intervals of
    1/depth over the training range ``[min(depths_mm), max(depths_mm)]`` (bin 0 the
    farthest; depths outside go to the end bins)."""
    lo, hi = min(depths_mm), max(depths_mm)
    K = bins
    inv = 1 / torch.as_tensor(depths, dtype=torch.float64)
    u = (inv - 1 / hi) / max(1 / lo - 1 / hi, 1e-300)
    return (u * K).floor().clamp(0, K - 1).long()


def soft_max_weights(buf: torch.Tensor, setting: SoftMax, bins: torch.Tensor,
                     per_image: torch.Tensor) -> torch.Tensor:
    """Sample weights ``(B,)`` (``per_image``'s dtype) of the soft maximum over depth bins.

    Args:
        buf: the running mean loss of each bin ``(K,)`` float64, -1 where not seen yet;
            updated in place with ``per_image`` (detached) first.
        setting: the checked :class:`~.settings.SoftMax`.
        bins: each sample's bin ``(B,)`` (:func:`depth_bin`), on ``buf``'s device.
        per_image: each sample's loss ``(B,)``.
    """
    v = per_image.detach().to(torch.float64)
    with torch.no_grad():
        for b in bins.unique().tolist():
            x = v[bins == b].mean()
            e = buf[b]
            # not seen yet: -1 (NaN in checkpoints written before 2026-11-23)
            buf[b] = x if not bool(e >= 0) else (
                setting.momentum * e + (1 - setting.momentum) * x)
        ema = buf
        seen = ema >= 0
        logit = torch.where(seen, ema.clamp_min(1e-30).log(), torch.zeros_like(ema))
        # bins not seen yet take the largest seen value (no bin is favoured for being new)
        logit = torch.where(seen, logit, logit[seen].max())
        w = len(ema) * torch.softmax(logit / setting.temperature, 0)
    return w[bins].to(per_image.dtype)


class DepthSoftMax(nn.Module):
    """The soft maximum over depth bins of one setting, owning its running means (the float64
    buffer ``loss_ema`` ``(K,)``, -1 until a bin's first sample).

    Args:
        setting: the checked :class:`~.settings.SoftMax`.
        depths_mm: the training depth range ``[min, max]`` (mm) the bins cut.
    """

    def __init__(self, setting: SoftMax, depths_mm):
        super().__init__()
        self.setting = setting
        self.depths_mm = [float(d) for d in depths_mm]
        self.register_buffer("loss_ema", torch.full((setting.bins,), -1.0, dtype=torch.float64))

    def bin(self, depths, bins: int | None = None) -> torch.Tensor:
        """Each depth's bin ``(B,)`` (:func:`depth_bin`; ``bins`` default the setting's)."""
        return depth_bin(self.depths_mm, depths, self.setting.bins if bins is None else bins)

    def forward(self, per_image: torch.Tensor, depths) -> torch.Tensor:
        """Sample weights ``(B,)`` of ``per_image`` ``(B,)`` at ``depths``, after updating the
        running means with it (:func:`soft_max_weights`)."""
        bins = self.bin(depths).to(self.loss_ema.device)
        return soft_max_weights(self.loss_ema, self.setting, bins, per_image)


class InvariancePenalty(nn.Module):
    """``relu(R / R_0 - 1 - slack)^2`` (``model.optics_invariance``), ``R`` the PSF change over
    depth of this step's OTF moments (:func:`~.wiener.depth_change`) and ``R_0`` its value at
    the first call (the float64 buffer ``ref``, -1 until then: a resumed run keeps it).
    ``last`` is the latest ``R`` (a float, for the log; ``None`` once read by the module)."""

    def __init__(self, setting: Invariance):
        super().__init__()
        self.setting = setting
        self.register_buffer("ref", torch.tensor(-1.0, dtype=torch.float64))
        self.last = None

    def forward(self, ch: torch.Tensor, h2: torch.Tensor) -> torch.Tensor:
        R = depth_change(ch, h2)
        self.last = float(R.detach())
        if float(self.ref) < 0:
            self.ref.fill_(float(R.detach()))
        ref = self.ref.to(R.dtype).clamp_min(1e-12)
        return F.relu(R / ref - 1 - self.setting.slack) ** 2
