"""The soft maximum over depth bins (``model.worst_depth``, ``model.optics_worst_depth``).

The training depth range is cut into ``K`` bins uniform in 1/depth (:func:`depth_bin`); each
bin keeps a running mean ``E_b`` (momentum ``m``) of the per-image loss of its samples, and a
sample of bin ``b`` is weighted by ``K softmax_b(log E_b / T)`` (:func:`soft_max_weights`;
mean weight 1 over bins, so ``T -> inf`` is the plain mean and small ``T`` trains on the worst
bin).  The running means are float64 buffers ``(K,)`` of the module (``depth_loss_ema``,
``optics_depth_loss_ema``: checkpointed, names unchanged), -1 until a bin's first sample;
the functions here update them in place.
"""

from __future__ import annotations

import math

import torch

from ..optics.errors import ConfigError

__all__ = ["SOFT_MAX_DEFAULTS", "depth_bin", "soft_max_setting", "soft_max_weights"]

#: defaults of a soft maximum over depths (``model.worst_depth``, ``model.optics_worst_depth``)
SOFT_MAX_DEFAULTS = (("temperature", 0.5), ("bins", 4), ("momentum", 0.9))


def soft_max_setting(key: str, value) -> dict | None:
    """``model.<key>`` (``worst_depth``, ``optics_worst_depth``) checked, defaults filled:
    ``None`` or ``{"temperature": float > 0, "bins": int >= 1, "momentum": float in [0, 1)}``;
    else :class:`~deeplens.optics.errors.ConfigError` naming ``model.<key>.<field>``."""
    if value is None:
        return None
    if not isinstance(value, dict):
        try:
            value = dict(value)
        except (TypeError, ValueError):
            raise ConfigError(f"model.{key}", "null or a mapping {temperature, bins, "
                              "momentum}", value) from None
    wd = {**dict(SOFT_MAX_DEFAULTS), **value}
    unknown = set(wd) - set(dict(SOFT_MAX_DEFAULTS))
    if unknown:
        raise ConfigError.unknown(f"model.{key}", unknown, dict(SOFT_MAX_DEFAULTS))
    T, K, mom = wd["temperature"], wd["bins"], wd["momentum"]
    if not (isinstance(T, (int, float)) and not isinstance(T, bool) and math.isfinite(T)
            and T > 0):
        raise ConfigError(f"model.{key}.temperature", "a number > 0", T)
    if not (isinstance(K, int) and not isinstance(K, bool) and K >= 1):
        raise ConfigError(f"model.{key}.bins", "an integer >= 1", K)
    if not (isinstance(mom, (int, float)) and not isinstance(mom, bool) and 0 <= mom < 1):
        raise ConfigError(f"model.{key}.momentum", "a number in [0, 1)", mom)
    return {"temperature": float(T), "bins": K, "momentum": float(mom)}


def depth_bin(depths_mm, depths, bins: int) -> torch.Tensor:
    """Index ``(B,)`` (int64) of each of ``depths`` (mm) in ``bins`` equal intervals of
    1/depth over the training range ``[min(depths_mm), max(depths_mm)]`` (bin 0 the
    farthest; depths outside go to the end bins)."""
    lo, hi = min(depths_mm), max(depths_mm)
    K = bins
    inv = 1 / torch.as_tensor(depths, dtype=torch.float64)
    u = (inv - 1 / hi) / max(1 / lo - 1 / hi, 1e-300)
    return (u * K).floor().clamp(0, K - 1).long()


def soft_max_weights(buf: torch.Tensor, setting: dict, bins: torch.Tensor,
                     per_image: torch.Tensor) -> torch.Tensor:
    """Sample weights ``(B,)`` (``per_image``'s dtype) of the soft maximum over depth bins.

    Args:
        buf: the running mean loss of each bin ``(K,)`` float64, -1 where not seen yet;
            updated in place with ``per_image`` (detached) first.
        setting: the checked ``{"temperature", "bins", "momentum"}`` (:func:`soft_max_setting`).
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
                setting["momentum"] * e + (1 - setting["momentum"]) * x)
        ema = buf
        seen = ema >= 0
        logit = torch.where(seen, ema.clamp_min(1e-30).log(), torch.zeros_like(ema))
        # bins not seen yet take the largest seen value (no bin is favoured for being new)
        logit = torch.where(seen, logit, logit[seen].max())
        w = len(ema) * torch.softmax(logit / setting["temperature"], 0)
    return w[bins].to(per_image.dtype)
