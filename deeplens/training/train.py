"""``train(cfg)``: build everything from a composed Hydra config, fit, test; return results.

Data flow: experiment config -> Hydra composes -> :func:`train` builds lens, sensor, renderer,
restorer, data -> :class:`~deeplens.training.module.EndToEndModule` -> Lightning ``Trainer``.
The entry point ``train.py`` at the repository root only calls this function, so tests call it
directly with a composed, shrunk config.
"""

from __future__ import annotations

from pathlib import Path

import hydra
import lightning as L
import torch
from omegaconf import DictConfig, OmegaConf

from ..optics.intersect import IntersectOptions
from ..render import MonteCarloRenderer, Sensor
from ..render.psf_conv import PSFConvRenderer
from .callbacks import AtomicCheckpointIO
from .lens_setup import build_lens
from .module import EndToEndModule

__all__ = ["train", "build_objects", "check_config", "preflight"]

# leaf keys whose type is checked at start-up (Hydra already rejects unknown keys)
_TYPES = {
    "seed": int,
    "lens.path": str, "lens.dtype": str, "lens.trainable": list,
    "sensor.resolution": list, "sensor.pixel_size_mm": float, "sensor.full_well": float,
    "sensor.read_noise": float,
    "scene.depths_mm": list, "scene.val_depths_mm": list,
    "render.kind": str, "render.spp": int, "render.vignetting": bool, "render.adjoint": bool,
    "render.decorrelate": bool, "render.chunk_rays": int, "render.max_iter": int,
    "render.psf_rays": int,
    "model.net_lr": float, "model.optics_lr_mm": float,
    "data.image_size": int, "data.batch_size": int, "data.train_steps_per_epoch": int,
    "data.val_size": int, "data.test_size": int,
}


def check_config(cfg: DictConfig) -> None:
    """Type-check the known keys; raises ``ValueError`` naming the key, the expected type and
    the value received."""
    for key, typ in _TYPES.items():
        val = OmegaConf.select(cfg, key, default="__missing__")
        if isinstance(val, str) and val == "__missing__":
            raise ValueError(f"config key {key!r} is missing")
        if val is None:
            continue
        if OmegaConf.is_list(val):
            val = list(val)
        ok = isinstance(val, typ) and not (typ in (int, float) and isinstance(val, bool))
        if typ is float and isinstance(val, int) and not isinstance(val, bool):
            ok = True
        if not ok:
            raise ValueError(f"config key {key!r}: expected {typ.__name__}, got {val!r} "
                             f"({type(val).__name__})")


def build_renderer(cfg, lens, sensor):
    r = cfg.render
    opts = IntersectOptions(tol=r.newton_tol, max_iter=r.max_iter)
    if r.kind == "mc":
        return MonteCarloRenderer(lens, sensor, spp=r.spp, vignetting=r.vignetting,
                                  adjoint=r.adjoint, decorrelate=r.decorrelate and r.adjoint,
                                  chunk_rays=r.chunk_rays, options=opts,
                                  seed=cfg.seed)
    if r.kind == "psf":
        return PSFConvRenderer(lens, sensor, n_rays=r.psf_rays, patches=tuple(r.psf_patches),
                               options=opts, seed=cfg.seed)
    raise ValueError(f"render.kind must be 'mc' or 'psf', got {r.kind!r}")


def preflight(lens, sensor, renderer) -> None:
    """Fail before training when the lens passes no light: checks the on-axis field and the
    sensor's corner field at every sensor wavelength (the message names field and numbers)."""
    from ..analysis.spot import find_pupil
    from ..render.scene import IdealCamera

    cam = IdealCamera(lens, sensor)
    corner = cam.field_angle_deg(sensor.half_diagonal_mm)
    waves = sorted({w for ch in sensor.channels for w in ch} | {sensor.mono_wavelength_nm})
    with torch.no_grad():
        for w in waves:
            for f in (0.0, corner):
                try:
                    find_pupil(lens, f, w, "traced", grid=33, bisections=2)
                except ValueError as e:
                    raise ValueError(f"lens check before training: {e} (sensor corner field "
                                     f"{corner:.3g} deg, half-diagonal "
                                     f"{sensor.half_diagonal_mm:.4g} mm)") from None


def _image_channels(node, where: str, n_ch: int, keys=("in_channels", "out_channels")) -> dict:
    """Channel arguments of a network config: ``null`` (or absent) takes the sensor's channel
    count; an explicit different value is an error naming the key."""
    out = {}
    for k in keys:
        v = node.get(k)
        if v is not None and int(v) != n_ch:
            raise ValueError(f"{where}.{k}={v}, but the sensor has {n_ch} channel(s) "
                             f"(sensor.channels); set it to {n_ch} or null")
        out[k] = n_ch
    return out


def build_objects(cfg: DictConfig) -> dict:
    """Instantiate lens, sensor, renderer, restorer, data module, Lightning module, trainer."""
    check_config(cfg)
    L.seed_everything(cfg.seed, workers=True)
    lc = cfg.lens
    lens = build_lens(lc.path, trainable=list(lc.trainable), dtype=lc.dtype,
                      plate=lc.plate, plate_surface=lc.plate_surface,
                      plate_alpha_mm=lc.plate_alpha_mm,
                      table_options=OmegaConf.to_container(lc.table_options))
    sc = cfg.sensor
    sensor = Sensor(tuple(sc.resolution), sc.pixel_size_mm,
                    channels=None if sc.channels is None else [list(c) for c in sc.channels],
                    full_well=sc.full_well, read_noise=sc.read_noise)
    n_ch = len(sensor.channels)
    if n_ch not in (1, 3):
        raise ValueError(f"sensor.channels: {n_ch} channels, but the training textures are RGB: "
                         f"use 1 (monochrome: textures are converted to grey) or 3 channels")
    renderer = build_renderer(cfg, lens, sensor)
    preflight(lens, sensor, renderer)
    restorer = hydra.utils.instantiate(cfg.net, **_image_channels(cfg.net, "net", n_ch))
    mc = cfg.model
    discriminator = (hydra.utils.instantiate(
        mc.discriminator, **_image_channels(mc.discriminator, "model.discriminator", n_ch,
                                            ("in_channels",)))
        if mc.discriminator else None)
    perceptual = None
    if mc.loss.get("perceptual", 0):
        from ..nets.losses import PerceptualLoss

        perceptual = PerceptualLoss(weights_path=mc.perceptual_weights)
    module = EndToEndModule(
        lens, sensor, renderer, restorer,
        depths_mm=list(cfg.scene.depths_mm), val_depths_mm=list(cfg.scene.val_depths_mm),
        field_bands=None if cfg.scene.field_bands is None else list(cfg.scene.field_bands),
        loss=OmegaConf.to_container(mc.loss), net_lr=mc.net_lr, optics_lr_mm=mc.optics_lr_mm,
        disc_lr=mc.disc_lr, perceptual=perceptual, discriminator=discriminator,
        max_sag_mm=mc.max_sag_mm, plate_surface=lc.plate_surface, seed=cfg.seed,
        psf_fields_deg=list(cfg.scene.psf_fields_deg))
    datamodule = hydra.utils.instantiate(cfg.data)
    callbacks = [hydra.utils.instantiate(c) for c in (cfg.callbacks or {}).values() if c]
    logger = hydra.utils.instantiate(cfg.logger) if cfg.get("logger") else False
    trainer = hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=logger,
                                      plugins=[AtomicCheckpointIO()])
    return {"lens": lens, "sensor": sensor, "renderer": renderer, "restorer": restorer,
            "datamodule": datamodule, "module": module, "trainer": trainer, "cfg": cfg}


def train(cfg: DictConfig):
    """Fit (and optionally test) the end-to-end model described by ``cfg``.

    Returns:
        ``(metrics, objects)``: the callback metrics as floats, and the built objects.
    """
    objs = build_objects(cfg)
    trainer, module, dm = objs["trainer"], objs["module"], objs["datamodule"]
    ckpt = cfg.get("ckpt_path")
    if ckpt is not None and not Path(ckpt).exists():
        raise FileNotFoundError(f"ckpt_path: no checkpoint at {ckpt}")
    if cfg.get("train", True):
        trainer.fit(module, datamodule=dm, ckpt_path=ckpt)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    if cfg.get("test", False):
        cb = trainer.checkpoint_callback
        best = cb.best_model_path if (cfg.get("train", True) and cb is not None) else ""
        trainer.test(module, datamodule=dm, ckpt_path=best or None, verbose=False)
        metrics.update({k: float(v) for k, v in trainer.callback_metrics.items()})
    return metrics, objs
