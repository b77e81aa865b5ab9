"""The checks of :class:`~.module.EndToEndModule`'s arguments (``model.*`` of the config).

:func:`check_module_settings` checks them all and returns the checked settings; each bad value
raises ``ValueError`` naming its ``model.<key>`` (or ``scene.margin``) and what was expected.
"""

from __future__ import annotations

import math

from .depth_weighting import soft_max_setting

__all__ = ["LOSS_DEFAULTS", "MAX_LR", "check_learning_rate", "check_module_settings"]

#: largest accepted learning rates: Adam moves each weight by about ``lr`` per step, so a
#: network rate above 1, or an optics step above 1 mm of sag, can only run away
MAX_LR = {"net_lr": 1.0, "optics_lr_mm": 1.0, "disc_lr": 1.0}

#: the loss terms and their default weights (``model.loss``)
LOSS_DEFAULTS = (("mse", 1.0), ("l1", 0.0), ("ssim", 0.0), ("perceptual", 0.0),
                 ("adversarial", 0.0), ("constraint", 1.0))


def check_learning_rate(key: str, value) -> float:
    """``value`` as a float in ``(0, MAX_LR[key]]``, else ``ValueError`` naming ``model.key``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"model.{key}: expected a number, got {value!r}") from None
    if not (math.isfinite(v) and 0 < v <= MAX_LR[key]):
        raise ValueError(f"model.{key}: expected a finite learning rate in (0, {MAX_LR[key]:g}]"
                         f"{' mm of sag per step' if key == 'optics_lr_mm' else ''}, got {value}")
    return v


def check_module_settings(*, loss, has_discriminator: bool, net_lr, optics_lr_mm, disc_lr,
                          optics_warmup_steps, scene_margin, worst_depth, optics_worst_depth,
                          deconvolution) -> dict:
    """The module's settings checked (in this order), as a dict:

    * ``loss``: the weights of every term (:data:`LOSS_DEFAULTS` updated with ``loss``; known
      terms only, finite and >= 0; an adversarial weight > 0 needs a discriminator);
    * ``net_lr``, ``optics_lr_mm``, ``disc_lr``: floats (:func:`check_learning_rate`);
    * ``optics_warmup_steps``: an int >= 0 (``None`` -> 0);
    * ``scene_margin``: a float in ``[0, 4]`` (fraction of the field of view);
    * ``worst_depth``, ``optics_worst_depth``: ``None`` or the checked soft-maximum settings
      (:func:`~.depth_weighting.soft_max_setting`);
    * ``deconvolution``: ``None`` or a dict of :class:`~.wiener.DepthWienerFilter` keywords
      (known keys only).
    """
    loss_w = dict(LOSS_DEFAULTS)
    unknown = set(loss or {}) - set(loss_w)
    if unknown:
        raise ValueError(f"model.loss: unknown terms {sorted(unknown)}; expected "
                         f"{sorted(loss_w)}")
    loss_w.update({k: float(v) for k, v in (loss or {}).items()})
    bad = {k: v for k, v in loss_w.items() if not (math.isfinite(v) and v >= 0)}
    if bad:
        raise ValueError(f"model.loss: weights must be finite and >= 0, got {bad}")
    if loss_w["adversarial"] > 0 and not has_discriminator:
        raise ValueError("model.loss.adversarial > 0 needs a discriminator "
                         "(model.discriminator)")
    out = {"loss": loss_w,
           "net_lr": check_learning_rate("net_lr", net_lr),
           "optics_lr_mm": check_learning_rate("optics_lr_mm", optics_lr_mm),
           "disc_lr": check_learning_rate("disc_lr", disc_lr)}
    optics_warmup_steps = optics_warmup_steps or 0
    if not (isinstance(optics_warmup_steps, int) and optics_warmup_steps >= 0):
        raise ValueError(f"model.optics_warmup_steps: expected an integer >= 0, got "
                         f"{optics_warmup_steps!r}")
    out["optics_warmup_steps"] = optics_warmup_steps
    if not (isinstance(scene_margin, (int, float)) and 0 <= scene_margin <= 4):
        raise ValueError(f"scene.margin: expected a fraction of the field of view in "
                         f"[0, 4], got {scene_margin!r}")
    out["scene_margin"] = float(scene_margin)
    out["worst_depth"] = soft_max_setting("worst_depth", worst_depth)
    out["optics_worst_depth"] = soft_max_setting("optics_worst_depth", optics_worst_depth)
    dc = None
    if deconvolution is not None:
        from .wiener import DEFAULTS

        dc = dict(deconvolution)
        unknown = set(dc) - set(dict(DEFAULTS))
        if unknown:
            raise ValueError(f"model.deconvolution: unknown keys {sorted(unknown)}; expected "
                             f"{', '.join(dict(DEFAULTS))}")
    out["deconvolution"] = dc
    return out
