"""The checks of :class:`~.module.EndToEndModule`'s arguments (``model.*`` of the config).

:func:`check_module_settings` checks them all and returns the checked settings; each bad value
raises :class:`~deeplens.optics.errors.ConfigError` naming its ``model.<key>`` (or
``scene.margin``), what was expected and the value.  :func:`check_model_config` runs the same
checks on a composed config at start-up (called by :func:`~.train.check_config`, before
anything is built); the module calls :func:`check_module_settings` again (for API users).
"""

from __future__ import annotations

import math

import torch
from omegaconf import OmegaConf

from ..optics.camera import Camera, as_camera
from ..optics.errors import ConfigError
from .psf_energy import PsfEnergy
from .settings import Invariance, SoftMax
from .wiener import check_deconvolution

__all__ = ["LOSS_DEFAULTS", "MAX_LR", "check_learning_rate", "check_model_config",
           "check_module_settings", "module_camera"]

#: largest accepted learning rates: Adam moves each weight by about ``lr`` per step, so a
#: network rate above 1, or an optics step above 1 mm of sag, can only run away
MAX_LR = {"net_lr": 1.0, "optics_lr_mm": 1.0, "disc_lr": 1.0}

#: the loss terms and their default weights (``model.loss``)
LOSS_DEFAULTS = (("mse", 1.0), ("l1", 0.0), ("ssim", 0.0), ("perceptual", 0.0),
                 ("adversarial", 0.0), ("constraint", 1.0))


def check_learning_rate(key: str, value) -> float:
    """``value`` as a float in ``(0, MAX_LR[key]]``, else :class:`ConfigError` naming
    ``model.key``."""
    what = (f"a finite learning rate in (0, {MAX_LR[key]:g}]"
            f"{' mm of sag per step' if key == 'optics_lr_mm' else ''}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"model.{key}", what, value) from None
    if not (math.isfinite(v) and 0 < v <= MAX_LR[key]):
        raise ConfigError(f"model.{key}", what, value)
    return v


def check_module_settings(*, loss, has_discriminator: bool, net_lr, optics_lr_mm, disc_lr,
                          optics_warmup_steps, scene_margin, worst_depth, optics_worst_depth,
                          deconvolution, optics_invariance=None) -> dict:
    """The module's settings checked (in this order), as a dict:

    * ``loss``: the weights of every term (:data:`LOSS_DEFAULTS` updated with ``loss``; known
      terms only, finite and >= 0; an adversarial weight > 0 needs a discriminator);
    * ``net_lr``, ``optics_lr_mm``, ``disc_lr``: floats (:func:`check_learning_rate`);
    * ``optics_warmup_steps``: an int >= 0 (``None`` -> 0);
    * ``scene_margin``: a float in ``[0, 4]`` (fraction of the field of view);
    * ``worst_depth``, ``optics_worst_depth``: ``None`` or the checked
      :class:`~.settings.SoftMax`;
    * ``deconvolution``: ``None`` or a dict of :class:`~.wiener.DepthWienerFilter` keywords
      (known keys only: :class:`~.wiener.Deconvolution`);
    * ``optics_invariance``: ``None`` or the checked :class:`~.settings.Invariance`.
    """
    loss_w = dict(LOSS_DEFAULTS)
    unknown = set(loss or {}) - set(loss_w)
    if unknown:
        raise ConfigError.unknown("model.loss", unknown, loss_w)
    for k, v in (loss or {}).items():
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) \
            and v >= 0
        if not ok:
            raise ConfigError(f"model.loss.{k}", "a finite weight >= 0", v)
        loss_w[k] = float(v)
    if loss_w["adversarial"] > 0 and not has_discriminator:
        raise ConfigError("model.loss.adversarial", "0 without a discriminator "
                          "(model.discriminator is null)", loss_w["adversarial"])
    out = {"loss": loss_w,
           "net_lr": check_learning_rate("net_lr", net_lr),
           "optics_lr_mm": check_learning_rate("optics_lr_mm", optics_lr_mm),
           "disc_lr": check_learning_rate("disc_lr", disc_lr)}
    optics_warmup_steps = optics_warmup_steps or 0
    if not (isinstance(optics_warmup_steps, int) and not isinstance(optics_warmup_steps, bool)
            and optics_warmup_steps >= 0):
        raise ConfigError("model.optics_warmup_steps", "an integer >= 0 (or null)",
                          optics_warmup_steps)
    out["optics_warmup_steps"] = optics_warmup_steps
    if not (isinstance(scene_margin, (int, float)) and not isinstance(scene_margin, bool)
            and 0 <= scene_margin <= 4):
        raise ConfigError("scene.margin", "a fraction of the field of view in [0, 4]",
                          scene_margin)
    out["scene_margin"] = float(scene_margin)
    out["worst_depth"] = SoftMax.from_config("worst_depth", worst_depth)
    out["optics_worst_depth"] = SoftMax.from_config("optics_worst_depth", optics_worst_depth)
    dc = None
    if deconvolution is not None:
        dc = dict(deconvolution)
        check_deconvolution(dc)
    out["deconvolution"] = dc
    out["optics_invariance"] = Invariance.from_config(optics_invariance, dc)
    return out


def check_model_config(cfg) -> None:
    """Start-up check of ``model.*`` (and ``scene.margin``) in a composed config: the
    module's own checks (:func:`check_module_settings`, the depth soft maxima of
    :mod:`.settings`, the Wiener front end's settings of :mod:`.wiener` for the
    run's ``lens.dtype``), without building anything."""

    def plain(key):
        v = OmegaConf.select(cfg, key, default=None)
        return OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v

    m = cfg.model
    s = check_module_settings(
        loss=plain("model.loss"), has_discriminator=plain("model.discriminator") is not None,
        net_lr=m.get("net_lr", 1e-3), optics_lr_mm=m.get("optics_lr_mm", 1e-4),
        disc_lr=m.get("disc_lr", 1e-4), optics_warmup_steps=m.get("optics_warmup_steps"),
        scene_margin=m.get("scene_margin", 0.0), worst_depth=plain("model.worst_depth"),
        optics_worst_depth=plain("model.optics_worst_depth"),
        deconvolution=plain("model.deconvolution"),
        optics_invariance=plain("model.optics_invariance"))
    PsfEnergy.from_config(plain("model.optics_psf_energy"))
    dtype = OmegaConf.select(cfg, "lens.dtype", default=None)
    if s["deconvolution"] is not None and dtype in ("float32", "float64"):
        check_deconvolution(s["deconvolution"], getattr(torch, dtype))


def module_camera(lens, sensor, renderer) -> Camera:
    """The camera of an :class:`~.module.EndToEndModule`: ``lens`` if it is one, else the
    renderer's camera when it holds this lens and sensor, else a new camera with the
    renderer's options.

    Raises:
        ValueError: the renderer renders through another camera, or the camera has no sensor.
    """
    held = getattr(renderer, "camera", None)
    if not isinstance(lens, Camera):
        if isinstance(held, Camera) and held.lens is lens and held.sensor is sensor:
            return held
        lens = as_camera(lens, sensor, getattr(renderer, "options", None))
    camera = as_camera(lens, sensor, where="EndToEndModule")
    if isinstance(held, Camera) and held is not camera:
        raise ValueError("EndToEndModule: the renderer renders through another camera than "
                         "the module's; build the renderer with the module's camera")
    if camera.sensor is None:
        raise ValueError("EndToEndModule: the camera has no sensor (Camera(lens, sensor))")
    return camera
