"""Training callbacks: checkpoints with lens files, TensorBoard image logging.

Image logging runs on rank zero only, after validation, and never changes training state.
Checkpoint files themselves (atomic writes, digests, verified loading) are
:mod:`deeplens.training.checkpoint`.
"""

from __future__ import annotations

import inspect
import math
import warnings
from collections.abc import Sequence
from pathlib import Path

import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from lightning.pytorch.utilities import rank_zero_only
from lightning.pytorch.utilities.exceptions import SIGTERMException
from omegaconf import OmegaConf

from ..analysis.plot import layout_figure
from ..optics.errors import ConfigError
from ..optics.io import save_lens
from ..render.psf import psf
from .checkpoint import AtomicCheckpointIO, CheckpointError
from .lens_setup import surface_height_map
from .psf_panels import psf_panels_figure

__all__ = ["AtomicCheckpointIO", "LensCheckpoint", "ImageLogger", "check_callbacks_config",
           "check_image_logger"]

#: the config key of :class:`ImageLogger`'s settings (errors name it)
_LOGGER_KEY = "callbacks.image_logger"


def _count(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 1


def check_image_logger(every_n_epochs=1, psf_rays=4096, depths_mm=(10_000.0,),
                       fields_deg=(0.0,), plate_surface=None, key: str = _LOGGER_KEY) -> None:
    """:class:`ImageLogger`'s arguments checked; raises
    :class:`~deeplens.optics.errors.ConfigError` naming ``<key>.<argument>``."""
    if not _count(every_n_epochs):
        raise ConfigError(f"{key}.every_n_epochs", "an int >= 1", every_n_epochs)
    if not _count(psf_rays):
        raise ConfigError(f"{key}.psf_rays", "an int >= 1", psf_rays)
    num = (lambda x: isinstance(x, (int, float)) and not isinstance(x, bool)  # noqa: E731
           and math.isfinite(x))
    def seq(v):
        return list(v) if isinstance(v, Sequence) and not isinstance(v, str) else [v]

    depths, fields = seq(depths_mm), seq(fields_deg)
    if not depths or not all(num(d) and d > 0 for d in depths):
        raise ConfigError(f"{key}.depths_mm", "distances > 0 mm (a non-empty list)", depths)
    if not fields or not all(num(f) and 0 <= f < 90 for f in fields):
        raise ConfigError(f"{key}.fields_deg", "angles in [0, 90) deg (a non-empty list)",
                          fields)
    if plate_surface is not None and not (isinstance(plate_surface, int)
                                          and not isinstance(plate_surface, bool)
                                          and plate_surface >= 0):
        raise ConfigError(f"{key}.plate_surface", "an int >= 0 (a surface index) or null",
                          plate_surface)


def check_callbacks_config(cfg) -> None:
    """Start-up check of the callbacks' settings in a composed config (``callbacks.*``):
    those of every :class:`ImageLogger` (:func:`check_image_logger`)."""
    for name, node in (OmegaConf.select(cfg, "callbacks", default=None) or {}).items():
        if not node or node.get("_target_") != f"{__name__}.ImageLogger":
            continue
        args = {k: (OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v)
                for k, v in node.items() if k != "_target_"}
        known = [p for p in inspect.signature(check_image_logger).parameters if p != "key"]
        if set(args) - set(known):
            raise ConfigError.unknown(f"callbacks.{name}", set(args) - set(known), known)
        check_image_logger(**args, key=f"callbacks.{name}")


class LensCheckpoint(ModelCheckpoint):
    """A ModelCheckpoint that also exports the lens beside every checkpoint it writes
    (``last.ckpt`` -> ``last.lens.json``), so the trained lens is usable without the code.

    A run resumed into a new folder keeps its checkpoints to itself: the best checkpoint it
    reports (and tests) is one it wrote, never the old folder's ``best.ckpt`` (Lightning would
    carry that path over even though it no longer tracks that file's score).
    """

    def _save_checkpoint(self, trainer, filepath):
        super()._save_checkpoint(trainer, filepath)
        if trainer.is_global_zero:
            out = Path(filepath).with_suffix(".lens.json")
            try:
                save_lens(trainer.lightning_module.lens, out)
            except Exception as e:  # save_lens removes its own temporary file
                raise CheckpointError(f"could not write the lens file {out}: "
                                      f"{type(e).__name__}: {e}") from e

    # Lightning (2.5+) writes last.ckpt only when it also writes a top-k checkpoint, so after an
    # epoch that does not improve the monitored metric last.ckpt would hold an older state and a
    # resume would silently repeat epochs: write it at every save point.
    def on_validation_end(self, trainer, pl_module):
        skip = (self._should_skip_saving_checkpoint(trainer)
                or self._should_save_on_train_epoch_end(trainer))
        super().on_validation_end(trainer, pl_module)
        self._save_last_if_missed(trainer, skip)

    def on_train_epoch_end(self, trainer, pl_module):
        skip = (self._should_skip_saving_checkpoint(trainer)
                or not self._should_save_on_train_epoch_end(trainer))
        super().on_train_epoch_end(trainer, pl_module)
        self._save_last_if_missed(trainer, skip)

    def _save_last_if_missed(self, trainer, skip: bool):
        if not skip and self.save_last and self._last_global_step_saved != trainer.global_step:
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))

    # the final steps (after the last validation, e.g. with trainer.val_check_interval) belong in
    # last.ckpt too: Lightning writes it at train end only if it never wrote one
    def on_train_end(self, trainer, pl_module):
        super().on_train_end(trainer, pl_module)
        if (self.save_last and not trainer.fast_dev_run
                and self._last_global_step_saved != trainer.global_step):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))

    # stopped by SIGTERM / SIGINT (deeplens.training.stop_signals): Lightning stops between
    # steps; the state there is saved to last.ckpt, which resumes exactly
    def on_exception(self, trainer, pl_module, exception):
        super().on_exception(trainer, pl_module, exception)
        if (isinstance(exception, SIGTERMException) and self.save_last
                and not trainer.fast_dev_run
                and self._last_global_step_saved != trainer.global_step):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))

    def load_state_dict(self, state_dict):
        if state_dict.get("dirpath", self.dirpath) == self.dirpath:
            return super().load_state_dict(state_dict)
        with warnings.catch_warnings():  # Lightning's note says it keeps best_model_path
            warnings.simplefilter("ignore")
            super().load_state_dict(state_dict)
        self.best_model_path = ""


def _to_image(t: torch.Tensor) -> torch.Tensor:
    """``(C, H, W)`` in [0, 1], 3 channels."""
    t = t.detach().float().clamp(0, 1).cpu()
    return t.expand(3, -1, -1) if t.shape[0] == 1 else t


class ImageLogger(Callback):
    """Logs, after each validation: image grids (ground truth | sensor | restored) per depth,
    PSFs across depths and fields (a labelled figure: :mod:`.psf_panels`), the phase plate's height map, the lens layout and the
    trainable lens parameters.

    What it reads off the module is runtime state only (the lens, sensor and ideal camera, and
    ``val_vis``: the first validation batch's images); what to draw comes from its own
    arguments (config ``callbacks.image_logger``).

    Args:
        every_n_epochs: log every n validations (> 0).
        psf_rays: rays per logged PSF (> 0).
        depths_mm: object distances of the PSF rows (mm, > 0).
        fields_deg: field angles of the PSF columns (degrees, on the +y axis).
        plate_surface: index of a phase-plate surface whose height map is logged, or ``None``.
    """

    def __init__(self, every_n_epochs: int = 1, psf_rays: int = 4096, depths_mm=(10_000.0,),
                 fields_deg=(0.0,), plate_surface: int | None = None):
        super().__init__()
        check_image_logger(every_n_epochs, psf_rays, depths_mm, fields_deg, plate_surface)
        self.every_n_epochs = int(every_n_epochs)
        self.psf_rays = int(psf_rays)
        self.depths_mm = [float(d) for d in depths_mm]
        self.fields_deg = [float(f) for f in fields_deg]
        self.plate_surface = None if plate_surface is None else int(plate_surface)

    @rank_zero_only
    def on_validation_end(self, trainer, pl_module):
        if trainer.sanity_checking or trainer.logger is None:
            return
        if trainer.current_epoch % self.every_n_epochs:
            return
        exp = getattr(trainer.logger, "experiment", None)
        if exp is None or not hasattr(exp, "add_image"):
            return
        step = trainer.global_step
        was_training = pl_module.training
        pl_module.eval()
        try:
            self._log_images(exp, pl_module, step)
            self._log_psfs(exp, pl_module, step)
            self._log_lens(exp, pl_module, step)
        finally:
            pl_module.train(was_training)

    def _log_images(self, exp, m, step):
        from torchvision.utils import make_grid

        if not m.val_vis:
            return
        for tag, (gt, y, pred) in m.val_vis.items():
            rows = []
            for b in range(gt.shape[0]):
                rows += [_to_image(gt[b]), _to_image(y[b]), _to_image(pred[b])]
            exp.add_image(f"images/{tag}", make_grid(rows, nrow=3, padding=2), step)

    def _log_psfs(self, exp, m, step):
        lens, sensor = m.lens, m.sensor
        w = sensor.mono_wavelength_nm
        kmax = 0
        with torch.no_grad():
            ks = []
            for d in self.depths_mm:
                for f in self.fields_deg:
                    t = math.tan(math.radians(f))
                    X = 0.0
                    Y = t * (d + m.ideal.z_ep - m.ideal.z0)
                    try:  # traced with the run's trace options (the module's camera)
                        ks.append(psf(lens, sensor, (X, Y), d, w, self.psf_rays, seed=0,
                                      options=m.camera.options))
                    except ValueError:
                        ks.append(torch.zeros(3, 3))
            kmax = max(k.shape[-1] for k in ks)
        if ks:
            fig = psf_panels_figure([torch.nn.functional.pad(k, ((kmax - k.shape[-1]) // 2,) * 4)
                                     for k in ks], self.depths_mm, self.fields_deg, w,
                                    sensor.pixel_size_mm)
            exp.add_figure("psf/depth_rows_field_cols", fig, step, close=True)

    def _log_lens(self, exp, m, step):
        lens = m.lens
        if self.plate_surface is not None:
            h = surface_height_map(lens.surfaces[self.plate_surface])
            exp.add_scalar("lens/plate_peak_to_valley_um", float(h.max() - h.min()) * 1e3, step)
            rng = (h.max() - h.min()).clamp_min(1e-12)
            exp.add_image("lens/phase_plate_height", ((h - h.min()) / rng)[None].float(), step)
        try:
            fig = layout_figure(lens)
            exp.add_figure("lens/layout", fig, step, close=True)
        except Exception as e:  # plotting must never stop training
            exp.add_text("lens/layout_error", repr(e), step)
        lines = []
        for n, p in lens.named_parameters():
            if p.requires_grad:
                v = float(p) if p.numel() == 1 else float(p.detach().norm())
                exp.add_scalar(f"lens_params/{n}", v, step)
                lines.append(f"{n} = {v:.6g}" + ("" if p.numel() == 1 else " (norm)"))
        if lines:
            exp.add_text("lens/trainable", "  \n".join(lines), step)
