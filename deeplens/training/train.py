"""``train(cfg)``: build everything from a composed Hydra config, fit, test; return results.

Data flow: experiment config -> Hydra composes -> :func:`train` builds lens, sensor, renderer,
restorer, data -> :class:`~deeplens.training.module.EndToEndModule` -> Lightning ``Trainer``.
The entry point ``train.py`` at the repository root only calls this function, so tests call it
directly with a composed, shrunk config.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
from pathlib import Path

import hydra
import lightning as L
import torch
from lightning.pytorch.utilities import rank_zero_info
from omegaconf import DictConfig, OmegaConf

from ..analysis.spot import find_pupil
from ..optics.camera import Camera, unpack
from ..optics.errors import ConfigError
from ..optics.limits import check_allocation
from ..optics.options import TraceOptions
from ..optics.sampling import RAY_BYTES
from ..render import MonteCarloRenderer, Sensor
from ..render.psf_conv import PSFConvRenderer
from ..render.psf_model import PSFModel, run_jobs
from ..render.scene import IdealCamera
from .callbacks import check_callbacks_config
from .checkpoint import AtomicCheckpointIO, read_checkpoint
from .lens_search import search_trainable, searched_lens
from .lens_search import check_lens_config
from .lens_setup import build_lens, set_trainable
from .machine import describe_machine
from .module_config import check_model_config
from .run_lock import held_by_hydra, hold_output_folder
from .stop_signals import stopped_by_signal
from .tolerance import check_tolerance_config

__all__ = ["STARTUP_CHECKS", "build_camera", "build_objects", "check_config", "check_sizes",
           "log_every_n_steps", "preflight", "summary", "train"]

# leaf keys whose type is checked at start-up (Hydra already rejects unknown keys)
_TYPES = {
    "seed": int,
    "lens.path": str, "lens.dtype": str, "lens.trainable": list,
    "sensor.resolution": list, "sensor.pixel_size_mm": float, "sensor.full_well": float,
    "sensor.read_noise": float,
    "scene.depths_mm": list, "scene.val_depths_mm": list, "scene.margin": float,
    "render.kind": str, "render.spp": int, "render.vignetting": bool, "render.adjoint": bool,
    "render.decorrelate": bool, "render.chunk_rays": int, "render.max_iter": int,
    "render.psf_rays": int, "render.psf_model": str,
    "model.net_lr": float, "model.optics_lr_mm": float, "model.disc_lr": float,
    "data.image_size": int, "data.batch_size": int, "data.train_steps_per_epoch": int,
    "data.val_size": int, "data.test_size": int,
}
#: keys that must hold a value (``null`` would fail deep inside seeding or rendering)
_NOT_NULL = ("seed", "sensor.resolution", "sensor.pixel_size_mm", "scene.depths_mm",
             "scene.val_depths_mm", "render.kind", "render.spp", "data.image_size",
             "data.batch_size", "data.train_steps_per_epoch", "data.val_size", "data.test_size")
#: Lightning trainer keys checked when present (Lightning itself only asserts, without the key)
_TRAINER_TYPES = {"trainer.max_epochs": (int,), "trainer.max_steps": (int,),
                  "trainer.min_epochs": (int,), "trainer.min_steps": (int,),
                  "trainer.log_every_n_steps": (int,), "trainer.check_val_every_n_epoch": (int,),
                  "trainer.val_check_interval": (int, float),
                  "trainer.limit_train_batches": (int, float),
                  "trainer.limit_val_batches": (int, float),
                  "trainer.limit_test_batches": (int, float)}


def check_config(cfg: DictConfig, extra=()) -> None:
    """The one start-up check of a composed config, run before anything is built (dataset,
    lens, renderer, model): the types of the known keys, the meaning of the values of the
    keys no room owns (:data:`_RULES`: a depth of 0 mm, a negative seed, ...), then each
    room's own validator (:data:`STARTUP_CHECKS`: ``lens.*``, ``model.*`` with the depth soft
    maxima and the Wiener front end, the tolerance group, the callbacks), then the validators
    ``extra`` of a floor above (the evaluation's ``eval.*``:
    :func:`deeplens.evaluation.evaluate.check_config`), then the sizes (:func:`check_sizes`).

    Raises:
        ConfigError: the first bad key (:class:`~deeplens.optics.errors.ConfigError`:
            ``"{key}: expected {expected}, got {got!r}"``, attributes ``key``, ``expected``,
            ``got``).
        MemoryBudgetError: a size whose first allocation cannot fit in memory.
    """
    for key, typ in _TYPES.items():
        val = OmegaConf.select(cfg, key, default="__missing__")
        if isinstance(val, str) and val == "__missing__":
            raise ConfigError.missing(key, typ.__name__)
        if val is None:
            if key in _NOT_NULL:
                raise ConfigError(key, typ.__name__, None)
            continue
        if OmegaConf.is_list(val):
            val = list(val)
        ok = isinstance(val, typ) and not (typ in (int, float) and isinstance(val, bool))
        if typ is float and isinstance(val, int) and not isinstance(val, bool):
            ok = True
        if not ok:
            raise ConfigError(key, typ.__name__, val)
    for key, types in _TRAINER_TYPES.items():
        val = OmegaConf.select(cfg, key, default=None)
        if val is not None and (isinstance(val, bool) or not isinstance(val, types)):
            raise ConfigError(key, " or ".join(t.__name__ for t in types), val)
    for key, rule in _RULES.items():
        val = OmegaConf.select(cfg, key, default=None)
        if val is None:
            continue
        val = OmegaConf.to_container(val) if OmegaConf.is_config(val) else val
        problem = rule(val)
        if problem:
            raise ConfigError(key, problem, val)
    for check in (*STARTUP_CHECKS, *extra):
        check(cfg)
    check_sizes(cfg)


#: the values of ``render.compile`` (:class:`~deeplens.optics.options.TraceOptions`)
_COMPILE_VALUES = "'default', false, true ('auto'), 'surface' or 'lens'"


def _check_render(cfg: DictConfig) -> None:
    """``render.compile`` (a setting of :class:`~deeplens.optics.options.TraceOptions`) and
    the PSF model's settings (``render.psf_model``, ``psf_error_budget``, ``psf_remeasure``:
    :class:`~deeplens.render.psf_model.PSFModel`'s own checks; ``diffraction`` needs
    ``render.kind=psf``)."""
    c = OmegaConf.select(cfg, "render.compile", default="default")
    try:
        TraceOptions(compile=c)
    except ValueError:
        raise ConfigError("render.compile", _COMPILE_VALUES, c) from None
    r = cfg.render
    PSFModel(r.get("psf_model", "geometric"), r.get("psf_error_budget", 0.05),
             r.get("psf_remeasure", 0.1))
    if r.get("psf_model") == "diffraction" and r.get("kind") != "psf":
        raise ConfigError("render.psf_model", f"geometric or auto with render.kind="
                          f"{r.get('kind')} (rays: geometric optics only; diffraction needs "
                          f"render=psf)", "diffraction")


def _check_channels(cfg: DictConfig) -> None:
    """``sensor.channels``: 1 or 3 channels (the textures are RGB); the networks' channel
    arguments null or the sensor's count (:func:`_image_channels`)."""
    ch = OmegaConf.select(cfg, "sensor.channels", default=None)
    n_ch = 3 if ch is None else len(ch)
    if n_ch not in (1, 3):
        raise ConfigError("sensor.channels", "1 channel (monochrome: textures are converted "
                          "to grey) or 3 (the training textures are RGB)",
                          OmegaConf.to_container(ch) if OmegaConf.is_config(ch) else ch)
    if cfg.get("net") is not None:
        _image_channels(cfg.net, "net", n_ch)
    disc = OmegaConf.select(cfg, "model.discriminator", default=None)
    if disc:
        _image_channels(disc, "model.discriminator", n_ch, ("in_channels",))


def check_sizes(cfg: DictConfig) -> None:
    """Refuse sizes whose first allocation cannot fit in memory (a typo such as
    ``data.image_size=1000000``), naming the key and the bytes it would need
    (:func:`~deeplens.optics.limits.check_allocation`)."""
    b = cfg.data.batch_size
    h, w = cfg.sensor.resolution
    n_ch = 3 if cfg.sensor.get("channels") is None else len(cfg.sensor.channels)
    check_allocation("data.image_size (with data.batch_size)", b * 3 * cfg.data.image_size ** 2,
                     4, "float32 values of one batch of textures (batch x 3 x size^2)")
    check_allocation("sensor.resolution (with data.batch_size)", b * n_ch * h * w, 4 * 4,
                     "pixels of one batch (sensor image, target, restored, gradient; float32)")
    if cfg.render.kind == "mc":
        # one render chunk holds at least one pixel's spp rays per wavelength
        check_allocation("render.spp", cfg.render.spp, RAY_BYTES, "rays of one pixel")
        check_allocation("render.chunk_rays", cfg.render.chunk_rays, RAY_BYTES,
                         "rays of one render chunk")
    else:
        check_allocation("render.psf_rays", cfg.render.psf_rays, RAY_BYTES, "rays of one PSF")


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _positive(v) -> bool:
    return _number(v) and math.isfinite(v) and v > 0


def _rule_int(lo: int, hi: int | None = None):
    what = f"an int in [{lo}, {hi}]" if hi is not None else f"an int >= {lo}"
    return lambda v: (None if isinstance(v, int) and not isinstance(v, bool) and v >= lo
                      and (hi is None or v <= hi) else what)


def _rule_real(lo: float | None = None, hi: float | None = None, lo_open: bool = True):
    if lo is None:
        what = "a finite number"
    else:
        what = f"a finite number {'>' if lo_open else '>='} {lo:g}"
    what += f" and <= {hi:g}" if hi is not None else ""

    def rule(v):
        if not (_number(v) and math.isfinite(v)):
            return what
        if lo is not None and (v <= lo if lo_open else v < lo):
            return what
        if hi is not None and v > hi:
            return what
        return None
    return rule


def _rule_list(item, what: str, n: tuple[int, int] = (1, 1_000_000)):
    def rule(v):
        ok = (isinstance(v, list) and n[0] <= len(v) <= n[1]
              and all(item(x) for x in v))
        return None if ok else what
    return rule


def _bands(v):
    ok = (isinstance(v, list) and len(v) >= 2 and all(_number(x) and 0 <= x <= 1 for x in v)
          and all(a < b for a, b in itertools.pairwise(v)))
    return None if ok else "at least 2 increasing band edges in [0, 1] (normalised radius)"


_POS_INT = _rule_int(1)
# meaning of the values (after the type checks): key -> rule(value) -> None or what was expected
_RULES = {
    # numpy's and Lightning's seeding take 0 <= seed < 2^32
    "seed": _rule_int(0, 2 ** 32 - 1),
    # SSIM's 11-pixel window (reflect-padded by 5) needs 6 pixels per side
    "sensor.resolution": _rule_list(lambda x: _rule_int(6)(x) is None,
                                    "[H, W] pixels, both >= 6 (SSIM's 11-pixel window)", (2, 2)),
    "sensor.pixel_size_mm": _rule_real(0),
    "sensor.full_well": _rule_real(0, lo_open=False),
    "sensor.read_noise": _rule_real(0, lo_open=False),
    "scene.depths_mm": _rule_list(_positive, "one depth or a [min, max] range, distances > 0 mm "
                                  "(finite)", (1, 2)),
    "scene.val_depths_mm": _rule_list(_positive, "a non-empty list of distances > 0 mm (finite)"),
    "scene.field_bands": _bands,
    "scene.psf_fields_deg": _rule_list(lambda x: _number(x) and 0 <= x < 90,
                                       "field angles in [0, 90) deg"),
    "render.kind": lambda v: None if v in ("mc", "psf") else "'mc' or 'psf'",
    "render.spp": _POS_INT, "render.chunk_rays": _POS_INT, "render.max_iter": _POS_INT,
    "render.psf_rays": _POS_INT,
    "render.psf_error_budget": _rule_real(0, 1),
    "render.psf_remeasure": _rule_real(0),
    "render.psf_memory_gb": _rule_real(0),
    "render.newton_tol": _rule_real(0),
    "render.psf_patches": _rule_list(lambda x: _POS_INT(x) is None, "[rows, cols], both > 0",
                                     (2, 2)),
    # lens.*: lens_search.check_lens_config; model.* learning rates and loss weights:
    # module_config.check_model_config (STARTUP_CHECKS)
    # stricter than the constraint itself (which takes 0 for none): a config says null
    "model.max_sag_mm": _rule_real(0),
    # the dead-leaves texture draws discs of radius 2 px to size / 2: at least 4 pixels
    "data.image_size": _rule_int(4), "data.batch_size": _POS_INT,
    "data.train_steps_per_epoch": _POS_INT, "data.val_size": _POS_INT,
    "data.test_size": _POS_INT, "data.num_workers": _rule_int(0),
}

#: each room's validator of its own keys, run in this order by :func:`check_config` (after
#: the types and :data:`_RULES`); each takes the composed config and raises
#: :class:`~deeplens.optics.errors.ConfigError`.  ``eval.*`` is the evaluation's
#: (:data:`deeplens.evaluation.evaluate.EVAL_CHECKS`, run after these by its ``check_config``)
STARTUP_CHECKS = (check_lens_config, _check_channels, _check_render, check_model_config,
                  check_tolerance_config, check_callbacks_config)


def build_camera(cfg, lens, sensor) -> Camera:
    """The run's one :class:`~deeplens.optics.camera.Camera`: ``lens``, ``sensor`` and the
    trace options of ``render.newton_tol``, ``render.max_iter`` and ``render.compile``, which
    every trace of a training step reads (renderer, Wiener front end, PSF model)."""
    r = cfg.render
    try:
        opts = TraceOptions(tol=r.newton_tol, max_iter=r.max_iter,
                            compile=r.get("compile", "default"))
    except ValueError:
        raise ConfigError("render.compile", _COMPILE_VALUES, r.get("compile", "default")) from None
    return Camera(lens, sensor, opts)


def build_renderer(cfg, lens, sensor=None):
    """The renderer of ``render.kind`` through ``lens`` (a camera, or a lens and ``sensor``:
    the camera of :func:`build_camera` is built)."""
    camera = lens if isinstance(lens, Camera) else build_camera(cfg, lens, sensor)
    return _build_renderer(cfg, camera)


def build_psf_model(cfg, lens, sensor=None, opts=None):
    """``render.psf_model`` (geometric | diffraction | auto), measured on the run's pixels,
    depths, wavelengths and field patches through ``lens`` (the run's camera, ``sensor`` and
    ``opts`` then ``None``; or a lens, its sensor and trace options); its choice is printed
    (``auto``: with the measured error and the budget).  The Monte Carlo renderer traces rays:
    diffraction needs ``render.kind=psf``."""
    lens, sensor, opts = unpack(lens, sensor, opts, "build_psf_model")

    r = cfg.render
    pm = PSFModel(r.get("psf_model", "geometric"), r.get("psf_error_budget", 0.05),
                  r.get("psf_remeasure", 0.1), r.get("psf_memory_gb", 2.0),
                  n_rays=r.psf_rays)
    if pm.model == "geometric":  # nothing to measure
        pm.message = "PSF model: geometric (render.psf_model=geometric, not measured)"
        rank_zero_info("deeplens: " + pm.message)
        return pm
    grid = tuple(r.psf_patches) if r.kind == "psf" else (3, 3)
    jobs = run_jobs(lens, sensor, list(cfg.scene.depths_mm), grid)
    rank_zero_info("deeplens: " + pm.measure(lens, sensor, jobs, opts))
    if pm.choice == "diffraction" and r.kind != "psf":
        raise ValueError(f"render.psf_model={pm.model} chose diffraction ({pm.message}), but "
                         f"render.kind={r.kind} traces rays (geometric optics only): use "
                         f"render=psf, or render.psf_model=geometric")
    return pm


def _log_psf_model(trainer, renderer) -> None:
    """The PSF model's choice as TensorBoard text (``psf_model``) where the logger has it."""
    pm = getattr(renderer, "psf_model", None)
    exp = getattr(trainer.logger, "experiment", None) if trainer.logger else None
    if pm is not None and hasattr(exp, "add_text"):
        exp.add_text("psf_model", pm.message)


def _build_renderer(cfg, camera: Camera):
    r = cfg.render
    if r.kind == "mc":
        return MonteCarloRenderer(camera, spp=r.spp, vignetting=r.vignetting,
                                  adjoint=r.adjoint, decorrelate=r.decorrelate and r.adjoint,
                                  chunk_rays=r.chunk_rays, seed=cfg.seed)
    if r.kind == "psf":
        return PSFConvRenderer(camera, n_rays=r.psf_rays, patches=tuple(r.psf_patches),
                               seed=cfg.seed)
    raise ConfigError("render.kind", "'mc' or 'psf'", r.kind)


def preflight(lens, sensor) -> None:
    """Fail before training when the lens passes no light: checks the on-axis field and the
    sensor's corner field at every sensor wavelength (the message names field and numbers)."""
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
            raise ConfigError(f"{where}.{k}", f"{n_ch} or null (the sensor's channel count, "
                              f"sensor.channels)", v)
        out[k] = n_ch
    return out


def build_objects(cfg: DictConfig) -> dict:
    """Instantiate lens, sensor, renderer, restorer, data module, Lightning module, trainer."""
    check_config(cfg)
    L.seed_everything(cfg.seed, workers=True)
    sc = cfg.sensor
    sensor = Sensor(tuple(sc.resolution), sc.pixel_size_mm,
                    channels=None if sc.channels is None else [list(c) for c in sc.channels],
                    full_well=sc.full_well, read_noise=sc.read_noise)
    lc = cfg.lens
    path, trainable = lc.path, list(lc.trainable)
    if lc.get("start") == "search":   # the design search's lens (lens_search.py)

        path, trainable = str(searched_lens(cfg)), []
    lens = build_lens(path, trainable=trainable, dtype=lc.dtype,
                      plate=lc.plate, plate_surface=lc.plate_surface,
                      plate_alpha_mm=lc.plate_alpha_mm,
                      table_options=OmegaConf.to_container(lc.table_options),
                      focus_mm=lc.focus_mm,
                      learned_start_alpha_mm=lc.get("learned_start_alpha_mm"),
                      plate_order=lc.get("plate_order"),
                      focus_wavelengths_nm=[w for ch in sensor.channels for w in ch])
    if lc.get("start") == "search":   # globs over the searched lens's parameter names
        set_trainable(lens, search_trainable(cfg), "lens.search.trainable")
    n_ch = len(sensor.channels)
    camera = build_camera(cfg, lens, sensor)  # one camera: every trace of a step reads it
    renderer = build_renderer(cfg, camera)
    preflight(lens, sensor)
    renderer.psf_model = build_psf_model(cfg, camera)
    restorer = hydra.utils.instantiate(cfg.net, **_image_channels(cfg.net, "net", n_ch))
    mc = cfg.model
    discriminator = (hydra.utils.instantiate(
        mc.discriminator, **_image_channels(mc.discriminator, "model.discriminator", n_ch,
                                            ("in_channels",)))
        if mc.discriminator else None)
    # the module and its optimisers come from cfg.model (a Hydra partial); the objects built
    # here are what the config cannot describe
    make_module = hydra.utils.instantiate(cfg.model, discriminator=discriminator,
                                          _convert_="all")
    module = make_module(lens=camera, sensor=None, renderer=renderer, restorer=restorer)
    datamodule = hydra.utils.instantiate(cfg.data)
    callbacks = [hydra.utils.instantiate(c) for c in (cfg.callbacks or {}).values() if c]
    logger = hydra.utils.instantiate(cfg.logger) if cfg.get("logger") else False
    trainer = hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=logger,
                                      plugins=[AtomicCheckpointIO()],
                                      log_every_n_steps=log_every_n_steps(cfg))
    return {"lens": lens, "sensor": sensor, "camera": camera, "renderer": renderer,
            "restorer": restorer,
            "datamodule": datamodule, "module": module, "trainer": trainer, "cfg": cfg}


def log_every_n_steps(cfg: DictConfig) -> int:
    """``trainer.log_every_n_steps`` (Lightning's default 50 when absent), lowered to the
    training batches of one epoch (``data.train_steps_per_epoch``, or an integer
    ``trainer.limit_train_batches`` / ``overfit_batches`` below it) and to a positive
    ``trainer.max_steps``: a short run (the README's two steps) still logs its ``train/*``
    scalars once, at its last step, instead of none."""
    t = cfg.trainer
    n = t.get("log_every_n_steps")
    n = 50 if n is None else int(n)
    caps = [int(cfg.data.train_steps_per_epoch)]
    for key in ("limit_train_batches", "overfit_batches", "max_steps"):
        v = t.get(key)
        if isinstance(v, int) and not isinstance(v, bool) and v >= 1:
            caps.append(v)
    return max(1, min(n, *caps))


def _test_checkpoint(cfg: DictConfig, trainer, trained: bool) -> str | None:
    """What ``test`` scores: after training, this run's own best checkpoint (never a path
    carried over from the run it resumed); without training, ``ckpt_path`` (or the weights as
    built)."""
    if not trained:
        return cfg.get("ckpt_path")
    cb = trainer.checkpoint_callback
    best = Path(cb.best_model_path) if cb is not None and cb.best_model_path else None
    if best is not None and best.is_file() and cb.dirpath and best.parent == Path(cb.dirpath):
        return str(best)
    rank_zero_info("deeplens: this run wrote no best checkpoint; testing the final weights")
    return None


def summary(cfg: DictConfig, metrics: dict, trainer, tested: str | None) -> str:
    """A few lines closing a run: test PSNR / SSIM per depth (or field band), where the
    checkpoint and the exported lens are, and the TensorBoard command."""
    lines = [(f"deeplens: {cfg.get('task_name', 'train')} finished after "
              f"{trainer.current_epoch} epoch(s), {trainer.global_step} step(s) "
              f"({describe_machine()})")]
    tags = [k[len("test/psnr_restored/"):] for k in metrics
            if k.startswith("test/psnr_restored/")]
    if tags:
        lines.append("  test (restored | sensor), PSNR dB / SSIM:")
        def cell(img, t):
            ps, ss = metrics.get(f"test/psnr_{img}/{t}"), metrics.get(f"test/ssim_{img}/{t}")
            return f"{ps:6.2f} / {ss:.3f}" if ps is not None and ss is not None else "n/a"

        for t in tags:
            is_depth = t.startswith("d") and t.endswith("mm")
            name = f"{float(t[1:-2]) / 1000:g} m" if is_depth else t
            lines.append(f"    {name:>16}  {cell('restored', t)} | {cell('sensor', t)}")
    if tested:
        lines.append(f"  tested checkpoint: {tested}")
        lens = Path(tested).with_suffix(".lens.json")
        if lens.exists():
            lines.append(f"  exported lens:     {lens}")
    cb = trainer.checkpoint_callback
    if cb is not None and cb.last_model_path:
        lines.append(f"  last checkpoint:   {cb.last_model_path}  (resume: "
                     f"ckpt_path={cb.last_model_path})")
    logdir = OmegaConf.select(cfg, "logger.save_dir", default=None)
    if logdir:
        lines.append(f"  TensorBoard:       tensorboard --logdir {logdir}")
    return "\n".join(lines)


def train(cfg: DictConfig):
    """Fit (and optionally test) the end-to-end model described by ``cfg``; print a summary.

    Returns:
        ``(metrics, objects)``: the callback metrics as floats, and the built objects (plus
        ``"tested"``, the checkpoint the test scored or ``None``, and ``"summary"``, the text
        printed at the end).

    Raises:
        FolderInUseError: another live run holds ``paths.output_dir`` (:mod:`.run_lock`).
        StoppedBySignal: SIGTERM or SIGINT stopped training (exit status 143 / 130); the
            state after the last step is in ``last.ckpt`` (:mod:`.stop_signals`).
    """
    # the ranks a DDP launcher starts (LOCAL_RANK / NODE_RANK > 0) share rank 0's folder
    child = any(os.environ.get(k, "0") != "0" for k in ("LOCAL_RANK", "NODE_RANK"))
    # `deeplens train` holds the folder already, from before Hydra wrote into it (run_lock)
    held = child or held_by_hydra(cfg.paths.output_dir)
    with contextlib.nullcontext() if held else hold_output_folder(cfg.paths.output_dir):
        return _train(cfg)


def _train(cfg: DictConfig):
    objs = build_objects(cfg)
    trainer, module, dm = objs["trainer"], objs["module"], objs["datamodule"]
    ckpt = cfg.get("ckpt_path")
    if ckpt is not None and not Path(ckpt).exists():
        raise FileNotFoundError(f"ckpt_path: no checkpoint at {ckpt}")
    trained = bool(cfg.get("train", True))
    if ckpt is not None:  # verified, a training checkpoint, with what resuming needs
        read_checkpoint(ckpt, resume=trained)
    _log_psf_model(trainer, objs["renderer"])
    if trained:
        with stopped_by_signal(trainer):
            trainer.fit(module, datamodule=dm, ckpt_path=ckpt)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    tested = None
    if cfg.get("test", False):
        tested = _test_checkpoint(cfg, trainer, trained)
        trainer.test(module, datamodule=dm, ckpt_path=tested, verbose=False)
        metrics.update({k: float(v) for k, v in trainer.callback_metrics.items()})
    objs["tested"] = tested
    objs["summary"] = summary(cfg, metrics, trainer, tested)
    pm = getattr(objs["renderer"], "psf_model", None)
    if pm is not None:  # the measurement's sentence was printed at start-up
        objs["summary"] += (f"\n  PSF model:         {pm.choice} (render.psf_model="
                            f"{pm.model})")
    if trainer.is_global_zero:
        print(objs["summary"])
    return metrics, objs
