"""The end-to-end LightningModule: differentiable camera + restoration network (paper V-B).

One step::

    sharp textures x ──► scene planes at depths D ──► renderer (backward Monte Carlo, adjoint
    gradients) ──► sensor image y (+ noise) ──► restorer f ──► x̂ = f(y)
    loss = w_mse |x̂ - x*|^2 + w_l1 |x̂ - x*| + w_ssim (1 - SSIM) + w_vgg VGG(x̂, x*)
           + w_adv adversarial + w_c constraints(lens)

``x*`` is the ideal camera's sharp image of the same scene (the framing the lens should reach).
Optics and network have separate parameter groups and learning rates (the optics rate is in mm
of sag, see :mod:`.lens_setup`); the optimisers are factories (``model.optimizer``, a Hydra
``_partial_``) filled with those groups.  Training uses manual optimisation so that the optional
discriminator gets its own optimiser, and so that a non-finite loss or gradient stops training
*before* the optimiser step, with the state just before it saved under ``checkpoints/``.

Parts kept in their own files: the checks of the module's arguments and its camera
(:mod:`.module_config`), its dict settings (:mod:`.settings`: frozen dataclasses), the soft
maximum over depth bins and the invariance penalty (:mod:`.depth_weighting`: modules owning
their buffers, saved under the checkpoint names :data:`CHECKPOINT_NAMES`), the image loss
terms (:mod:`.image_loss`), the per-depth metrics (:func:`.metrics.image_metrics`), the
non-finite guard (:mod:`.nonfinite`) and the checks of a loaded checkpoint
(:func:`.checkpoint.check_on_load`); ``NonFiniteLossError``, ``check_learning_rate`` and
``MAX_LR`` are still importable from here.
"""

from __future__ import annotations

import contextlib
import functools

import lightning as L
import torch
from kornia.color import rgb_to_grayscale

from ..nets.losses import PerceptualLoss, adversarial_loss
from ..optics.camera import Camera
from ..optics.errors import ConfigError
from ..render import IdealCamera, Scene
from . import compile_choice, image_loss
from .checkpoint import LOADED_FROM, check_on_load
from .constraints import SagDepartureConstraint
from .depth_weighting import DepthSoftMax, InvariancePenalty
from .lens_setup import optics_param_groups
from .metrics import image_metrics, psnr
from .module_config import MAX_LR, check_learning_rate, check_module_settings, module_camera
from .nonfinite import (NonFiniteLossError, nonfinite_grad, nonfinite_param, stop,
                        trained_parameters)
from .psf_energy import PsfEnergy, psf_energy_loss
from .scalars import training_scalars
from .tolerance import TrainingDraws
from .wiener import DepthWienerFilter

# moved to module_config.py / nonfinite.py, still importable from here
__all__ = ["EndToEndModule", "MAX_LR", "NonFiniteLossError", "check_learning_rate"]

#: the checkpoint names of the buffers the settings' modules own (the names checkpoints have
#: always had): ``{name in the module: name in a checkpoint}``
CHECKPOINT_NAMES = {"depth_softmax.loss_ema": "depth_loss_ema",
                    "optics_depth_softmax.loss_ema": "optics_depth_loss_ema",
                    "invariance.ref": "invariance_ref"}


def _to_checkpoint_names(module, state_dict, prefix, local_metadata):
    for ours, theirs in CHECKPOINT_NAMES.items():
        if prefix + ours in state_dict:
            state_dict[prefix + theirs] = state_dict.pop(prefix + ours)


def _from_checkpoint_names(state_dict, prefix, *args):
    for ours, theirs in CHECKPOINT_NAMES.items():
        if prefix + theirs in state_dict:
            state_dict[prefix + ours] = state_dict.pop(prefix + theirs)


class EndToEndModule(L.LightningModule):
    """Joint lens + restorer training.

    The module holds one :class:`~deeplens.optics.camera.Camera` (``module.camera``): the
    renderer renders through it and the Wiener front end traces its PSFs through it, so one
    ``camera.options`` reaches every trace of a training step.  The camera owns the lens
    (:mod:`deeplens.optics.camera`): the module optimises the parameters the camera lets
    train and fixes them (``optics_warmup_steps``) through :meth:`Camera.lens_fixed
    <deeplens.optics.camera.Camera.lens_fixed>`.

    Args:
        lens: the :class:`~deeplens.optics.camera.Camera`, or (the older form) the
            :class:`~deeplens.optics.lens.Lens` with ``sensor``: the module then takes the
            renderer's camera (a renderer built on this lens and sensor), else builds one with
            the renderer's ``options``.
        sensor: the :class:`~deeplens.render.sensor.Sensor` (with its noise model); with a
            camera, ``None`` or the camera's.
        renderer: a renderer ``(scene, seed=) -> (B, C, H, W)`` rendering through the camera
            (a renderer with a ``camera`` attribute must hold the module's).
        restorer: the network ``(B, C, H, W) -> (B, C, H, W)``.
        depths_mm: ``[min, max]`` training depth range (sampled uniformly in 1/depth) or one depth.
        val_depths_mm: depths evaluated (and logged) separately in validation.
        field_bands: radial band edges for per-field-band metrics (``None``: whole image only).
        loss: weights ``{"mse", "l1", "ssim", "perceptual", "adversarial", "constraint"}``
            (finite, >= 0).
        net_lr, optics_lr_mm, disc_lr: learning rates (finite, > 0, at most :data:`MAX_LR`).
        perceptual: an optional perceptual-loss module (``(x̂, x*) -> scalar``); if ``None`` and
            ``loss["perceptual"] > 0``, a VGG16 :class:`~deeplens.nets.PerceptualLoss` is built
            from ``perceptual_weights`` (a local file; nothing is downloaded).
        discriminator: an optional PatchGAN (enables the adversarial term).
        max_sag_mm: constraint: every surface with trainable parameters keeps its departure from
            its initial shape within ``max_sag_mm`` over the aperture (quadratic penalty, weight
            ``loss["constraint"]``; :mod:`.constraints`).
        seed: the run's seed (training depths and render/noise seeds derive from it and the step).
        worst_depth: ``None`` (the image loss is the plain mean over the batch) or the mapping
            of a :class:`~.settings.SoftMax`: the MSE, L1 and SSIM terms weighted per sample
            by a soft maximum over depth bins (running means: a checkpointed buffer).
        deconvolution: ``None`` (the restorer sees the sensor image) or the mapping of a
            :class:`~.wiener.Deconvolution`: the sensor image is first deconvolved with the
            depth-averaged Wiener filter of the current lens (:class:`~.wiener.DepthWienerFilter`;
            its noise-to-signal ratio trains with the network), and the restorer refines that.
        optics_warmup_steps: ``None``/0, or the optics stay fixed for this many first steps (their gradients
            are dropped), so that the restorer learns to decode the starting optics before
            the optics' gradient is trusted (e.g. a learned plate started from a cubic one).
        optics_invariance: ``None`` or the mapping of a :class:`~.settings.Invariance` (needs
            ``deconvolution``): while the optics move, the loss gains the penalty of
            :class:`~.depth_weighting.InvariancePenalty` (logged as ``train/loss_invariance``
            and ``train/psf_depth_change``).
        optics_worst_depth: ``None`` or a :class:`~.settings.SoftMax` mapping as for
            ``worst_depth``, applied to the optics' gradient only: the loss stays the plain
            mean, and each sample's gradient flowing back into the optics (and the
            deconvolution front end) is scaled by its bin's weight.
        tolerance, tolerance_training: the tolerance group (a mapping, group name or file;
            :mod:`.tolerance`) and whether every training batch renders through its own lens
            drawn from it around the current nominal lens (gradients reach the nominal values).
        calibrate: ``None`` or ``"distortion"`` (needs ``tolerance_training`` and one training
            depth): each step's drawn lens is calibrated (its distortion map against the
            nominal lens's, :mod:`deeplens.render.calibration`) and the restored image is
            registered with it before the loss.
        optics_psf_energy: ``None`` or the mapping of a :class:`~.psf_energy.PsfEnergy`:
            while the optics move, the loss gains ``weight * mean(1 - E)``, ``E`` the share of
            each edge field's light in its own pixel (:mod:`.psf_energy`; an optics-only term,
            logged as ``train/loss_psf_energy``).
        optimizer, disc_optimizer: factories ``(param_groups) -> torch.optim.Optimizer``
            (config: Hydra ``_partial_``); default Adam, and Adam with ``betas=(0.5, 0.999)``.
    """

    def __init__(self, lens, sensor, renderer, restorer, depths_mm, val_depths_mm,
                 field_bands=None, loss=None, net_lr: float = 1e-3, optics_lr_mm: float = 1e-4,
                 disc_lr: float = 1e-4, perceptual=None, discriminator=None,
                 max_sag_mm: float | None = None, seed: int = 0, perceptual_weights=None,
                 optimizer=None, disc_optimizer=None, scene_margin: float = 0.0,
                 worst_depth: dict | None = None, deconvolution: dict | None = None,
                 optics_warmup_steps: int | None = None,
                 optics_worst_depth: dict | None = None, tolerance=None,
                 tolerance_training: bool = False, calibrate: str | None = None,
                 optics_invariance: dict | None = None,
                 optics_psf_energy: dict | None = None):
        super().__init__()
        camera = module_camera(lens, sensor, renderer)
        self._held = (camera,)  # held, not registered: state-dict keys lens.*, as before
        lens, sensor = camera.lens, camera.sensor
        self.lens, self.sensor, self.renderer, self.restorer = lens, sensor, renderer, restorer
        self.perceptual = perceptual
        self.discriminator = discriminator
        self.depths_mm = [float(d) for d in depths_mm]
        self.val_depths_mm = [float(d) for d in val_depths_mm]
        self.field_bands = list(field_bands) if field_bands else None
        cfg = check_module_settings(  # module_config.py: every argument checked first
            loss=loss, has_discriminator=discriminator is not None, net_lr=net_lr,
            optics_lr_mm=optics_lr_mm, disc_lr=disc_lr, optics_warmup_steps=optics_warmup_steps,
            scene_margin=scene_margin, worst_depth=worst_depth,
            optics_worst_depth=optics_worst_depth, deconvolution=deconvolution,
            optics_invariance=optics_invariance)
        self.loss_w = cfg["loss"]
        if self.loss_w["perceptual"] > 0 and perceptual is None:
            perceptual = PerceptualLoss(weights_path=perceptual_weights)
            self.perceptual = perceptual
        self.net_lr = cfg["net_lr"]
        self.optics_lr_mm = cfg["optics_lr_mm"]
        self.disc_lr = cfg["disc_lr"]
        self.seed = int(seed)
        self.optics_warmup_steps = cfg["optics_warmup_steps"]
        self.optimizer = optimizer or torch.optim.Adam
        self.disc_optimizer = disc_optimizer or functools.partial(torch.optim.Adam,
                                                                  betas=(0.5, 0.999))
        self.scene_margin = cfg["scene_margin"]
        self.automatic_optimization = False
        self.ideal = IdealCamera(lens, sensor)  # the ground truth's framing
        self.constraint = SagDepartureConstraint(lens, max_sag_mm)
        # the soft maxima over depth (their running means: buffers of their own modules)
        self.worst_depth = cfg["worst_depth"]
        self.depth_softmax = (None if self.worst_depth is None
                              else DepthSoftMax(self.worst_depth, self.depths_mm))
        # frozen optics: no gradient to weigh (optics_worst_depth), nothing to constrain
        # (optics_invariance)
        optics_frozen = not any(p.requires_grad for p in lens.parameters())
        self.optics_worst_depth = None if optics_frozen else cfg["optics_worst_depth"]
        self.optics_depth_softmax = (None if self.optics_worst_depth is None
                                     else DepthSoftMax(self.optics_worst_depth, self.depths_mm))
        self._register_state_dict_hook(_to_checkpoint_names)
        self._register_load_state_dict_pre_hook(_from_checkpoint_names)
        self.deconv = None
        if cfg["deconvolution"] is not None:
            self.deconv = DepthWienerFilter(camera, None, self.depths_mm, **cfg["deconvolution"],
                                            psf_model=getattr(renderer, "psf_model", None))
        self.optics_invariance = None if optics_frozen else cfg["optics_invariance"]
        psf_energy = PsfEnergy.from_config(optics_psf_energy)
        self.optics_psf_energy = None if optics_frozen else psf_energy
        if self.optics_invariance is not None and len(set(self.depths_mm)) < 2:
            raise ConfigError("model.optics_invariance", "null with one training depth (no PSF "
                              "change over depth to hold)", optics_invariance)
        # its reference R_0 is a buffer of its own (checkpointed: a resumed run keeps it)
        self.invariance = (None if self.optics_invariance is None
                           else InvariancePenalty(self.optics_invariance))
        # model.tolerance_training: every training batch through its own drawn lens (tolerance.py)
        self.tolerance_draws = TrainingDraws.of_module(self, tolerance, tolerance_training,
                                                       calibrate)
        self.val_vis = None  # (gt, sensor, restored) of the first validation batch, for callbacks
        # per-unit calibration under test: None, or (restored (B, C, H, W), depth_mm) -> the
        # restored image registered to the nominal lens's mapping (tolerance.DistortionCalibration)
        self.calibration = None

    # ------------------------------------------------------------------ the camera
    @property
    def camera(self) -> Camera:
        """The :class:`~deeplens.optics.camera.Camera` of every trace of a step (renderer and
        Wiener front end); ``module.camera.options = ...`` changes them all."""
        return self._held[0]

    def sample_depths(self, n: int, step: int) -> list[float]:
        """Training depths: uniform in inverse depth over ``[min, max]`` (seeded by step)."""
        if len(self.depths_mm) == 1:
            return self.depths_mm * n
        lo, hi = min(self.depths_mm), max(self.depths_mm)
        g = torch.Generator().manual_seed(self.seed * 7919 + step)
        u = torch.rand(n, generator=g, dtype=torch.float64)
        inv = 1 / hi + u * (1 / lo - 1 / hi)
        return (1 / inv).tolist()

    def capture(self, images: torch.Tensor, depths, seed: int, noise: bool = True):
        """Render sharp ``images`` ``(B, 3, H, W)`` at ``depths``; returns ``(sensor, gt)`` as
        float32 ``(B, C, H, W)``, ``C`` the sensor's channels (RGB textures are converted to
        grey for a one-channel sensor)."""
        dtype = self.lens.dtype
        if len(self.sensor.channels) == 1 and images.shape[1] == 3:
            images = rgb_to_grayscale(images)  # a monochrome camera sees (and learns) grey
        # each texture covers the field of view plus ``scene_margin`` of it on every side, so
        # light blurred in from beyond the frame's edge is scene content, not a black surround
        sizes = torch.stack([self.ideal.fov_size_mm(float(d)) for d in depths])
        scene = Scene(images.to(dtype), depths, sizes * (1 + 2 * self.scene_margin))
        y = self.renderer(scene, seed=seed)
        gt = self.ideal.render(scene).to(y.dtype)
        if noise:
            g = torch.Generator(device=y.device).manual_seed(seed + 17)
            y = self.sensor.add_noise(y, generator=g)
        return y.float(), gt.float()

    def forward(self, sensor_image: torch.Tensor) -> torch.Tensor:
        """The restored image ``(B, C, H, W)`` of a sensor image (deconvolved first when the
        module has a ``deconvolution`` front end)."""
        x = sensor_image
        if self.deconv is not None:
            x = self.deconv(x)
        return self.restorer(x)

    # ------------------------------------------------------------------ losses
    def constraint_loss(self) -> torch.Tensor:
        """The lens constraint (:class:`~.constraints.SagDepartureConstraint`) now."""
        return self.constraint(self.lens)

    def per_image_loss(self, pred, gt) -> torch.Tensor:
        """The weighted MSE + L1 + SSIM loss of each image ``(B,)``, detached."""
        return image_loss.per_image(self.loss_w, pred, gt)

    def image_loss(self, pred, gt, depths=None) -> dict:
        """Loss terms (:func:`.image_loss.terms`); with ``worst_depth`` and ``depths`` given,
        the MSE, L1 and SSIM terms are weighted per sample by the soft maximum over depth."""
        return image_loss.terms(self.loss_w, pred, gt, depths, self.depth_softmax,
                                self.perceptual)

    # ------------------------------------------------------------------ training
    def training_step(self, batch, batch_idx):
        opts = self.optimizers()
        opt_g = opts[0] if isinstance(opts, (list, tuple)) else opts
        step = int(self.global_step)
        # buffers the forward pass updates (batch-norm running statistics): kept so that a
        # stop at this step saves the state it started from, not one its forward pass changed
        self._buffers_before = {n: b.detach().clone() for n, b in self.named_buffers()
                                if not n.startswith("lens.")}
        images = batch["image"]
        # the optics are fixed (warm-up) *before* the drawn lens replaces their tensors (the
        # freeze acts on the nominal parameters; the drawn values then carry no graph), and the
        # drawn lens stays in place until after backward (tolerance training)
        with self.optics_fixed(step < self.optics_warmup_steps), self.drawn_lens(step):
            loss, terms, y, gt, pred = self.step_loss(images, step)
            finite = bool(torch.isfinite(loss))
            if finite:
                opt_g.zero_grad(set_to_none=True)
                self.manual_backward(loss)
        if not finite:  # (outside the drawn lens: the stop saves the nominal one)
            detail = ", ".join(f"{k}={float(v.detach()):.4g}" for k, v in terms.items())
            stop(self, step, f"non-finite loss {float(loss)} at step {step} ({detail})")
        bad = nonfinite_grad(trained_parameters(self))
        if bad:
            opt_g.zero_grad(set_to_none=True)
            stop(self, step, f"non-finite gradient of {bad} at step {step}")
        if step < self.optics_warmup_steps:  # optics fixed: Adam skips parameters without grad
            for p in self.lens.parameters():
                p.grad = None
        opt_g.step()
        bad = nonfinite_param(trained_parameters(self))
        if bad:  # cannot happen with finite gradients and a bounded Adam rate; say so if it does
            raise NonFiniteLossError(f"{bad} became non-finite in the optimiser step at step "
                                     f"{step} (learning rate too large?); the last good state "
                                     f"is the last checkpoint")
        if self.discriminator is not None and self.loss_w["adversarial"]:
            opt_d = opts[1]
            d_loss = 0.5 * (adversarial_loss(self.discriminator(gt), True)
                            + adversarial_loss(self.discriminator(pred.detach()), False))
            opt_d.zero_grad(set_to_none=True)
            self.manual_backward(d_loss)
            opt_d.step()
            self.log("train/loss_discriminator", d_loss, batch_size=images.shape[0])
        n = images.shape[0]
        self.log("train/loss", loss, prog_bar=True, batch_size=n)
        # the terms as minimised (train/loss_ssim is 1 - SSIM; val/ssim_* is SSIM itself)
        self.log_dict({f"train/loss_{k}": v for k, v in terms.items()}, batch_size=n)
        self.log_dict(training_scalars(opt_g, self.deconv), batch_size=n)
        if self.invariance is not None and self.invariance.last is not None:
            self.log("train/psf_depth_change", self.invariance.last, batch_size=n)
            self.invariance.last = None
        self.log("train/psnr_restored", psnr(pred.detach(), gt), batch_size=n)
        self.log("train/psnr_sensor", psnr(y, gt), batch_size=n)
        return loss.detach()

    def step_loss(self, images: torch.Tensor, step: int):
        """The training loss of one batch of sharp ``images`` at ``step`` (depths, render and
        noise seeded by the step): ``(loss, terms, sensor, gt, restored)``.  With
        ``optics_worst_depth`` the gradient flowing back into the optics is scaled per sample
        (a hook on the restorer's input)."""
        depths = self.sample_depths(images.shape[0], step)
        with self.optics_fixed(step < self.optics_warmup_steps):
            with self.drawn_lens(step):
                y, gt = self.capture(images, depths, seed=self.seed * 1_000_003 + step)
            moments = None
            if self.deconv is None:
                x = y
            elif self.optics_invariance is not None and self._optics_moving():
                x, moments = self.deconv(y, return_moments=True)
            else:
                x = self.deconv(y)
        loss, terms, y, gt, pred = self.restore_loss(depths, y, gt, x)
        if moments is not None:
            pen = self.invariance(*moments)
            terms["invariance"] = pen
            loss = loss + self.optics_invariance.weight * pen
        if (self.optics_psf_energy is not None and step >= self.optics_warmup_steps
                and self._optics_moving()):   # psf_energy.py: the weight is inside the term
            terms["psf_energy"] = psf_energy_loss(self.camera, self.ideal,
                                                  self.optics_psf_energy, self.val_depths_mm)
            loss = loss + terms["psf_energy"]
        return loss, terms, y, gt, pred

    def _optics_moving(self) -> bool:
        return torch.is_grad_enabled() and any(p.requires_grad for p in self.lens.parameters())

    def drawn_lens(self, step: int):
        """The context in which ``self.lens`` is the lens drawn for ``step`` under
        ``model.tolerance_training`` (re-entrant; a no-op without it).  The adjoint render
        re-traces in the backward pass, so the context must span the backward as well.  The
        centring traces of a draw run at the camera's options, as every trace of the step."""
        if self.tolerance_draws is None:
            return contextlib.nullcontext()
        return self.tolerance_draws.at(self.camera, step)

    def optics_fixed(self, fixed: bool = True):
        """While ``fixed``: the lens parameters do not require gradients, so the render and
        the Wiener filter trace without autograd (the same values; the filter's PSFs come
        from its cache), as during ``optics_warmup_steps``, whose lens gradients were
        discarded anyway.  Restored on exit (:meth:`Camera.lens_fixed
        <deeplens.optics.camera.Camera.lens_fixed>`: the camera owns the lens)."""
        return self.camera.lens_fixed(fixed)

    def restore_loss(self, depths: torch.Tensor, y: torch.Tensor, gt: torch.Tensor,
                     x: torch.Tensor):
        """The second half of :meth:`step_loss`: restore ``x`` (the capture ``y``, deconvolved
        where ``model.deconvolution`` is set) and the loss against ``gt``; returns ``(loss,
        terms, y, gt, restored)``."""
        scale = None
        if self.optics_worst_depth is not None and torch.is_grad_enabled():
            scale = {}  # filled below, once this step's losses are known (running means too)
            if x.requires_grad:  # not while the optics are fixed and no Wiener nsr is learned
                x.register_hook(lambda g: g * scale["w"].to(g.dtype)[:, None, None, None])
        pred = self.restorer(x)
        register = None if self.tolerance_draws is None else self.tolerance_draws.register
        if register is not None:  # model.calibrate: the drawn unit's output registered
            pred = register(pred, self.depths_mm[0])
        terms = self.image_loss(pred, gt, depths)
        if scale is not None:
            scale["w"] = self.optics_depth_softmax(self.per_image_loss(pred, gt), depths)
        if self.discriminator is not None and self.loss_w["adversarial"]:
            terms["adversarial"] = adversarial_loss(self.discriminator(pred), True)
        terms["constraint"] = self.constraint_loss()
        loss = sum(self.loss_w[k] * v for k, v in terms.items())
        return loss, terms, y, gt, pred

    def on_train_batch_start(self, batch, batch_idx):
        compile_choice.begin_step(self)

    def on_train_batch_end(self, outputs, batch, batch_idx):
        compile_choice.end_step(self)

    def on_save_checkpoint(self, checkpoint):
        """Also store the run's choice of tracer (:mod:`.compile_choice`), so that a resumed
        run traces as the uninterrupted one did."""
        compile_choice.store(self, checkpoint)

    def on_load_checkpoint(self, checkpoint):
        """Refuse a checkpoint of another experiment with a message naming its file (resuming:
        this run's learning rates apply; :func:`.checkpoint.check_on_load`); apply the choice
        of tracer it stored (:mod:`.compile_choice`)."""
        path = checkpoint.pop(LOADED_FROM, None)
        compile_choice.restore(self, checkpoint)
        resuming = self._trainer is not None and self.trainer.state.fn == "fit"
        check_on_load(checkpoint, self, path, [
            self._param_groups(), [{"name": "discriminator", "lr": self.disc_lr}]]
            if resuming else None)

    # ------------------------------------------------------------------ validation / test
    def _eval_step(self, batch, batch_idx, stage: str):
        images = batch["image"]
        B, nd = images.shape[0], len(self.val_depths_mm)
        # all depths in one render: the lens is traced once for every depth of the batch
        depths = [d for d in self.val_depths_mm for _ in range(B)]
        y_all, gt_all = self.capture(images.repeat(nd, 1, 1, 1), depths,
                                     seed=10_000_019 + batch_idx * 101, noise=True)
        with torch.no_grad():
            pred_all = self(y_all)
            if self.calibration is not None:  # eval.calibrate: the unit's registration
                pred_all = torch.cat([self.calibration(pred_all[k * B:(k + 1) * B], d)
                                      for k, d in enumerate(self.val_depths_mm)])
        out = {}
        for k, d in enumerate(self.val_depths_mm):
            sl = slice(k * B, (k + 1) * B)
            y, gt, pred = y_all[sl], gt_all[sl], pred_all[sl]
            tag = f"d{d:g}mm"
            out[tag] = (gt, y, pred)
            self.log_dict(image_metrics(stage, tag, y, gt, pred, self.field_bands), batch_size=B)
        self.log(f"{stage}/psnr_restored", torch.stack(
            [psnr(v[2], v[0]) for v in out.values()]).mean(), prog_bar=stage == "val",
            batch_size=B)
        self.log(f"{stage}/psnr_sensor", torch.stack(
            [psnr(v[1], v[0]) for v in out.values()]).mean(), batch_size=B)
        if batch_idx == 0 and stage == "val":
            self.val_vis = {k: tuple(t[:4].detach().cpu() for t in v) for k, v in out.items()}

    def validation_step(self, batch, batch_idx):
        self._eval_step(batch, batch_idx, "val")

    def test_step(self, batch, batch_idx):
        self._eval_step(batch, batch_idx, "test")

    # ------------------------------------------------------------------ optimisers
    def _param_groups(self) -> list[dict]:
        net = list(self.restorer.parameters())
        if self.deconv is not None:
            net += list(self.deconv.parameters())
        groups = [{"params": net, "lr": self.net_lr, "name": "net"}]
        return groups + optics_param_groups(self.camera.lens, self.optics_lr_mm)

    def configure_optimizers(self):
        opt_g = self.optimizer(self._param_groups())
        if self.discriminator is not None and self.loss_w["adversarial"]:
            opt_d = self.disc_optimizer([{"params": list(self.discriminator.parameters()),
                                          "lr": self.disc_lr, "name": "discriminator"}])
            return [opt_g, opt_d]
        return opt_g
