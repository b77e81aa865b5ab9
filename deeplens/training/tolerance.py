"""Training and evaluation under manufacturing tolerances (the ``tolerance/`` config group).

Training (``model.tolerance_training: true``): step ``s`` renders through the lens drawn by
seed ``tolerance_seed(run seed, s)`` around the *current* nominal lens
(:func:`deeplens.optics.tolerance_model.drawn`), so every batch sees another manufactured lens
and the optics' gradient is taken through the drawn lens to the nominal parameters.
With ``model.calibrate: distortion`` each step's drawn lens is also calibrated as a built unit
would be (:mod:`deeplens.render.calibration`): its distortion map against the current nominal
lens's is measured (no gradient: a measurement) and the restorer's output is registered with it
before the loss, so training scores the camera as the calibrated evaluation does.

Evaluation under tolerances: :mod:`deeplens.evaluation.tolerance`.
"""

from __future__ import annotations

import contextlib

import torch
from omegaconf import OmegaConf

from ..design.tolerance_groups import load_group
from ..optics.tolerance_model import ToleranceModel, drawn
from ..optics.errors import ConfigError
from ..render.calibration import CALIBRATIONS, displacement_px, image_points, warp

__all__ = ["DistortionCalibration", "check_calibrate", "check_tolerance_config", "load_group",
           "tolerance_seed", "TrainingDraws"]


def check_calibrate(value, key: str) -> str | None:
    """``None`` or one of :data:`~deeplens.render.calibration.CALIBRATIONS`; else a
    :class:`ConfigError` naming ``key``."""
    if value is None or (isinstance(value, str) and value in CALIBRATIONS):
        return value
    raise ConfigError(key, f"null (no calibration) or one of {', '.join(CALIBRATIONS)}", value)


class DistortionCalibration:
    """Per-unit distortion calibration of ``module``'s camera at its test depths
    (:mod:`deeplens.render.calibration`): :meth:`measure_nominal` on the nominal lens, then,
    with a drawn lens in place, :meth:`unit` gives the registration ``(pred, depth_mm) ->
    pred`` of that unit (the module's ``calibration`` hook, applied to the restored image
    before its metrics).

    Args:
        module: the :class:`~.module.EndToEndModule` (its camera, ideal framing and sensor).
        depths_mm: the depths the map is measured at (one map per depth).
        nodes: grid nodes per side of the sensor.
        sampling: the pupil pattern of each point's bundle (:func:`~deeplens.render.calibration.image_points`).
    """

    def __init__(self, module, depths_mm, nodes: int = 9, sampling: str = "grid:48"):
        self.camera, self.ideal = module.camera, module.ideal
        self.depths = [float(d) for d in depths_mm]
        self.nodes, self.sampling = int(nodes), str(sampling)
        self.channels = len(self.camera.sensor.channels)
        self.nominal: dict[float, torch.Tensor] | None = None

    def _points(self) -> dict[float, torch.Tensor]:
        return {d: image_points(self.camera, None, d, self.ideal.object_scale(d), self.channels,
                                nodes=self.nodes, sampling=self.sampling) for d in self.depths}

    def measure_nominal(self) -> None:
        """Measure the nominal lens's grid (call with no drawn lens in place)."""
        self.nominal = self._points()

    def maps(self) -> dict[float, torch.Tensor]:
        """``{depth: (C, H, W, 2)}`` pixel displacements of the lens now in place."""
        if self.nominal is None:
            raise RuntimeError("DistortionCalibration: measure_nominal() first")
        sensor = self.camera.sensor
        return {d: displacement_px(p, self.nominal[d], sensor) for d, p in self._points().items()}

    def unit(self):
        """The registration of the lens now in place: ``(pred (B, C, H, W), depth_mm) ->
        pred`` registered to the nominal lens's image mapping."""
        maps = self.maps()

        def register(pred, depth_mm):
            return warp(pred, maps[float(depth_mm)])

        register.maps = maps
        return register


def _needs_a_tolerance() -> ConfigError:
    return ConfigError("model.tolerance_training", "false, or a tolerance group with a non-zero "
                       "tolerance (e.g. tolerance=precision)", True)


def check_tolerance_config(cfg) -> None:
    """Start-up check of the composed tolerance group (``tolerance``, read by the module as
    ``model.tolerance``: parsed by :func:`load_group`, nothing drawn) and of
    ``model.tolerance_training`` (a bool; true needs a non-zero group); raises
    :class:`~deeplens.optics.errors.ConfigError` naming the key."""
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

    @classmethod
    def of_module(cls, module, tolerance, training: bool, calibrate) -> TrainingDraws | None:
        """The draws of ``module`` (an ``EndToEndModule``: its seed, training depths, camera
        and ideal framing): ``None`` unless ``training`` (``model.tolerance_training``); the
        group ``tolerance`` (checked at start-up) is read either way; with ``calibrate``
        (``"distortion"``, one training depth) each step's drawn lens is calibrated
        (:class:`DistortionCalibration` on a 5 x 5 grid, ``grid:32``: coarser than the
        evaluation's 9 x 9, ``grid:48``, measured twice every step)."""
        tol = load_group(tolerance) if tolerance is not None else None
        draws = cls(tol, module.seed) if training else None
        if check_calibrate(calibrate, "model.calibrate") is not None:
            if draws is None or len(module.depths_mm) != 1:
                raise ValueError("model.calibrate: needs model.tolerance_training and a single "
                                 "training depth")
            draws.calibration = DistortionCalibration(module, module.depths_mm, nodes=5,
                                                      sampling="grid:32")
        return draws

    def __init__(self, model: ToleranceModel, run_seed: int, calibration=None):
        if not model:
            raise _needs_a_tolerance()
        self.model, self.run_seed = model, int(run_seed)
        self._active = None  # the step whose drawn lens is in place
        #: ``None`` or a :class:`DistortionCalibration`: the nominal lens is
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
