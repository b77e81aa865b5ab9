"""Training and evaluation under manufacturing tolerances (the ``tolerance/`` config group).

Training (``model.tolerance_training: true``): step ``s`` renders through the lens drawn by
seed ``tolerance_seed(run seed, s)`` around the *current* nominal lens
(:func:`deeplens.design.tolerance_model.drawn`), so every batch sees another manufactured lens
and the optics' gradient is taken through the drawn lens to the nominal parameters.
With ``model.calibrate: distortion`` each step's drawn lens is also calibrated as a built unit
would be (:mod:`deeplens.render.calibration`): its distortion map against the current nominal
lens's is measured (no gradient: a measurement) and the restorer's output is registered with it
before the loss, so training scores the camera as the calibrated evaluation does.

Evaluation under tolerances: :mod:`.tolerance_eval`.
"""

from __future__ import annotations

import contextlib


from ..design.tolerance_model import ToleranceModel, drawn, load_group
from ..optics.errors import ConfigError

__all__ = ["check_tolerance_config", "load_group", "tolerance_seed", "TrainingDraws"]


def _needs_a_tolerance() -> ConfigError:
    return ConfigError("model.tolerance_training", "false, or a tolerance group with a non-zero "
                       "tolerance (e.g. tolerance=precision)", True)


def check_tolerance_config(cfg) -> None:
    """Start-up check of the composed tolerance group (``tolerance``, read by the module as
    ``model.tolerance``: parsed by :func:`load_group`, nothing drawn) and of
    ``model.tolerance_training`` (a bool; true needs a non-zero group); raises
    :class:`~deeplens.optics.errors.ConfigError` naming the key."""
    from omegaconf import OmegaConf

    node = OmegaConf.select(cfg, "model.tolerance", default=None)
    if node is None:
        node = OmegaConf.select(cfg, "tolerance", default=None)
    model = load_group(node, where="tolerance") if node is not None else None
    training = OmegaConf.select(cfg, "model.tolerance_training", default=False)
    if not isinstance(training, bool):
        raise ConfigError("model.tolerance_training", "true or false", training)
    if training and not model:
        raise _needs_a_tolerance()
    cal = OmegaConf.select(cfg, "model.calibrate", default=None)
    from .tolerance_eval import check_calibrate

    if check_calibrate(cal, "model.calibrate") is not None:
        if not training:
            raise ConfigError("model.calibrate", "null without model.tolerance_training (the "
                              "calibration registers drawn lenses)", cal)
        depths = OmegaConf.select(cfg, "model.depths_mm", default=None)
        if depths is None or len(depths) != 1:
            raise ConfigError("model.calibrate", "a single training depth (scene.depths_mm "
                              "[d]: the unit is calibrated at it)", cal)


def tolerance_seed(run_seed: int, step: int) -> int:
    """The seed of the lens drawn at training ``step`` (a new lens every step)."""
    return (int(run_seed) * 2_000_003 + 7 * int(step) + 104_729) % (2 ** 62)


class TrainingDraws:
    """Per-step drawn lenses for :class:`~deeplens.training.module.EndToEndModule`."""

    def __init__(self, model: ToleranceModel, run_seed: int, calibration=None):
        if not model:
            raise _needs_a_tolerance()
        self.model, self.run_seed = model, int(run_seed)
        self._active = None  # the step whose drawn lens is in place
        #: ``None`` or a :class:`~.tolerance_eval.DistortionCalibration`: the nominal lens is
        #: measured on entering a step's draw, the drawn lens inside it
        self.calibration = calibration
        #: while a draw with calibration is in place: its registration ``(pred, depth) -> pred``
        self.register = None

    @contextlib.contextmanager
    def at(self, lens, step: int):
        """The context in which ``lens`` (a lens, or a camera: then the centring traces run at
        its options) is the lens drawn for ``step``; re-entrant (an inner
        ``at`` inside an outer one for the same step is a no-op, not a second draw)."""
        if self._active is not None:
            if self._active != step:
                raise RuntimeError(f"tolerance draw for step {step} inside the one of step "
                                   f"{self._active}")
            yield lens
            return
        self._active = step
        try:
            if self.calibration is not None:  # the nominal lens, before it is replaced
                self.calibration.measure_nominal()
            base = getattr(lens, "lens", lens)  # a camera: its lens is drawn
            with drawn(lens, self.model.draw(base, tolerance_seed(self.run_seed, step))) as L:
                if self.calibration is not None:
                    self.register = self.calibration.unit()
                yield L
        finally:
            self._active = None
            self.register = None
