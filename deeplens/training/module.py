"""The end-to-end LightningModule: differentiable camera + restoration network (paper V-B).

One step::

    sharp textures x ──► scene planes at depths D ──► renderer (backward Monte Carlo, adjoint
    gradients) ──► sensor image y (+ noise) ──► restorer f ──► x̂ = f(y)
    loss = w_mse |x̂ - x*|^2 + w_l1 |x̂ - x*| + w_ssim (1 - SSIM) + w_vgg VGG(x̂, x*)
           + w_adv adversarial + w_c constraints(lens)

``x*`` is the ideal camera's sharp image of the same scene (the framing the lens should reach).
Optics and network have separate parameter groups and learning rates (the optics rate is in mm
of sag, see :mod:`.lens_setup`).  Training uses manual optimisation so that the optional
discriminator gets its own optimiser and a non-finite loss can save the state before stopping.
"""

from __future__ import annotations

import math
from pathlib import Path

import lightning as L
import torch
import torch.nn.functional as F
from kornia.color import rgb_to_grayscale

from ..render import IdealCamera, Scene
from .lens_setup import optics_param_groups
from .metrics import band_masks, masked_psnr, masked_ssim, psnr, ssim

__all__ = ["EndToEndModule", "NonFiniteLossError"]


class NonFiniteLossError(FloatingPointError):
    """Raised when the training loss is NaN or infinite; the message names the step and the
    checkpoint holding the state just before it."""


class EndToEndModule(L.LightningModule):
    """Joint lens + restorer training.

    Args:
        lens: the :class:`~deeplens.optics.lens.Lens` (its trainable parameters are optimised).
        sensor: the :class:`~deeplens.render.sensor.Sensor` (with its noise model).
        renderer: a renderer ``(scene, seed=) -> (B, C, H, W)`` holding ``lens`` and ``sensor``.
        restorer: the network ``(B, C, H, W) -> (B, C, H, W)``.
        depths_mm: ``[min, max]`` training depth range (sampled uniformly in 1/depth) or one depth.
        val_depths_mm: depths evaluated (and logged) separately in validation.
        field_bands: radial band edges for per-field-band metrics (``None``: whole image only).
        loss: weights ``{"mse", "l1", "ssim", "perceptual", "adversarial"}``.
        net_lr, optics_lr_mm, disc_lr: learning rates.
        perceptual: an optional perceptual-loss module (``(x̂, x*) -> scalar``).
        discriminator: an optional PatchGAN (enables the adversarial term).
        max_sag_mm: constraint: every surface with trainable parameters keeps its departure from
            its initial shape within ``max_sag_mm`` over the aperture (quadratic penalty, weight
            ``loss["constraint"]``).
        plate_surface: index of the phase-plate surface (for logging its height map).
    """

    def __init__(self, lens, sensor, renderer, restorer, depths_mm, val_depths_mm,
                 field_bands=None, loss=None, net_lr: float = 1e-3, optics_lr_mm: float = 1e-4,
                 disc_lr: float = 1e-4, perceptual=None, discriminator=None,
                 max_sag_mm: float | None = None, plate_surface: int | None = None,
                 seed: int = 0, psf_fields_deg=None):
        super().__init__()
        self.lens, self.sensor, self.renderer, self.restorer = lens, sensor, renderer, restorer
        self.perceptual = perceptual
        self.discriminator = discriminator
        self.depths_mm = [float(d) for d in depths_mm]
        self.val_depths_mm = [float(d) for d in val_depths_mm]
        self.field_bands = list(field_bands) if field_bands else None
        self.loss_w = {"mse": 1.0, "l1": 0.0, "ssim": 0.0, "perceptual": 0.0,
                       "adversarial": 0.0, "constraint": 1.0}
        unknown = set(loss or {}) - set(self.loss_w)
        if unknown:
            raise ValueError(f"model.loss: unknown terms {sorted(unknown)}; expected "
                             f"{sorted(self.loss_w)}")
        self.loss_w.update({k: float(v) for k, v in (loss or {}).items()})
        if self.loss_w["perceptual"] > 0 and perceptual is None:
            raise ValueError("model.loss.perceptual > 0 needs a perceptual loss module")
        if self.loss_w["adversarial"] > 0 and discriminator is None:
            raise ValueError("model.loss.adversarial > 0 needs a discriminator")
        self.net_lr, self.optics_lr_mm, self.disc_lr = net_lr, optics_lr_mm, disc_lr
        self.max_sag_mm = max_sag_mm
        self.plate_surface = plate_surface
        self.seed = int(seed)
        self.psf_fields_deg = list(psf_fields_deg or [0.0])
        self.automatic_optimization = False
        self.camera = IdealCamera(lens, sensor)
        self._init_constraints()
        self.val_vis = None  # (gt, sensor, restored) of the first validation batch, for callbacks

    # ------------------------------------------------------------------ the camera
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
        scene = Scene(images.to(dtype), depths)
        y = self.renderer(scene, seed=seed)
        gt = self.camera.render(scene).to(y.dtype)
        if noise:
            g = torch.Generator(device=y.device).manual_seed(seed + 17)
            y = self.sensor.add_noise(y, generator=g)
        return y.float(), gt.float()

    def forward(self, sensor_image: torch.Tensor) -> torch.Tensor:
        return self.restorer(sensor_image)

    # ------------------------------------------------------------------ losses
    def _constraint_grid(self, surface):
        R = float(surface.semi_diameter)
        v = torch.linspace(-R, R, 17, dtype=torch.float64) / math.sqrt(2)
        Y, X = torch.meshgrid(v, v, indexing="ij")
        return X, Y

    def _init_constraints(self):
        """Record the initial sag of every surface with trainable parameters."""
        self._sag0 = {}
        with torch.no_grad():
            for i, s in enumerate(self.lens.surfaces):
                if any(p.requires_grad for p in s.parameters()) and hasattr(s, "sag"):
                    X, Y = self._constraint_grid(s)
                    dt = self.lens.dtype
                    self._sag0[i] = s.sag(X.to(dt), Y.to(dt)).detach().clone()

    def constraint_loss(self) -> torch.Tensor:
        """``mean(relu(|sag - sag_0| / m - 1)^2)`` over each trainable surface: its departure
        from the initial shape stays within ``max_sag_mm`` (e.g. a phase plate's thickness)."""
        zero = torch.zeros((), device=self.device)
        if not self.max_sag_mm:
            return zero
        total = zero
        for i, sag0 in self._sag0.items():
            s = self.lens.surfaces[i]
            dt = self.lens.dtype
            X, Y = (g.to(device=self.device, dtype=dt) for g in self._constraint_grid(s))
            dep = s.sag(X, Y) - sag0.to(device=self.device, dtype=dt)
            excess = F.relu(dep.abs() / self.max_sag_mm - 1)
            total = total + (excess ** 2).mean().float()
        return total

    def image_loss(self, pred, gt) -> dict:
        w = self.loss_w
        terms = {}
        if w["mse"]:
            terms["mse"] = F.mse_loss(pred, gt)
        if w["l1"]:
            terms["l1"] = F.l1_loss(pred, gt)
        if w["ssim"]:
            terms["ssim"] = 1 - ssim(pred, gt)
        if w["perceptual"]:
            if pred.shape[1] == 1:  # VGG16 takes RGB: a grey image is its own three channels
                pred, gt = pred.expand(-1, 3, -1, -1), gt.expand(-1, 3, -1, -1)
            terms["perceptual"] = self.perceptual(pred, gt)
        return terms

    # ------------------------------------------------------------------ training
    def training_step(self, batch, batch_idx):
        opts = self.optimizers()
        opt_g = opts[0] if isinstance(opts, (list, tuple)) else opts
        step = int(self.global_step)
        images = batch["image"]
        depths = self.sample_depths(images.shape[0], step)
        y, gt = self.capture(images, depths, seed=self.seed * 1_000_003 + step)
        pred = self.restorer(y)
        terms = self.image_loss(pred, gt)
        if self.discriminator is not None and self.loss_w["adversarial"]:
            from ..nets.losses import adversarial_loss

            terms["adversarial"] = adversarial_loss(self.discriminator(pred), True)
        terms["constraint"] = self.constraint_loss()
        loss = sum(self.loss_w[k] * v for k, v in terms.items())
        if not torch.isfinite(loss):
            self._stop_on_nonfinite(step, loss, terms)
        opt_g.zero_grad(set_to_none=True)
        self.manual_backward(loss)
        self._check_grads(step)
        opt_g.step()
        if self.discriminator is not None and self.loss_w["adversarial"]:
            from ..nets.losses import adversarial_loss

            opt_d = opts[1]
            d_loss = 0.5 * (adversarial_loss(self.discriminator(gt), True)
                            + adversarial_loss(self.discriminator(pred.detach()), False))
            opt_d.zero_grad(set_to_none=True)
            self.manual_backward(d_loss)
            opt_d.step()
            self.log("train/d_loss", d_loss, batch_size=images.shape[0])
        n = images.shape[0]
        self.log("train/loss", loss, prog_bar=True, batch_size=n)
        self.log_dict({f"train/{k}": v for k, v in terms.items()}, batch_size=n)
        self.log("train/psnr_restored", psnr(pred.detach(), gt), batch_size=n)
        self.log("train/psnr_sensor", psnr(y, gt), batch_size=n)
        return loss.detach()

    def _stop_on_nonfinite(self, step, loss, terms):
        path = None
        if self.trainer is not None and self.trainer.log_dir:
            path = Path(self.trainer.log_dir) / "checkpoints" / f"nonfinite_step{step}.ckpt"
            self.trainer.save_checkpoint(str(path))
        detail = ", ".join(f"{k}={float(v):.4g}" for k, v in terms.items())
        raise NonFiniteLossError(f"non-finite loss {float(loss)} at step {step} ({detail}); "
                                 f"training stopped, state saved to {path}")

    def _check_grads(self, step):
        for n, p in self.lens.named_parameters():
            if p.grad is not None and not torch.isfinite(p.grad).all():
                raise NonFiniteLossError(f"non-finite gradient of lens.{n} at step {step}")

    # ------------------------------------------------------------------ validation / test
    def _eval_step(self, batch, batch_idx, stage: str):
        images = batch["image"]
        B, nd = images.shape[0], len(self.val_depths_mm)
        # all depths in one render: the lens is traced once for every depth of the batch
        depths = [d for d in self.val_depths_mm for _ in range(B)]
        y_all, gt_all = self.capture(images.repeat(nd, 1, 1, 1), depths,
                                     seed=10_000_019 + batch_idx * 101, noise=True)
        with torch.no_grad():
            pred_all = self.restorer(y_all)
        out = {}
        for k, d in enumerate(self.val_depths_mm):
            sl = slice(k * B, (k + 1) * B)
            y, gt, pred = y_all[sl], gt_all[sl], pred_all[sl]
            tag = f"d{d:g}mm"
            out[tag] = (gt, y, pred)
            log = {f"{stage}/psnr_sensor/{tag}": psnr(y, gt),
                   f"{stage}/psnr_restored/{tag}": psnr(pred, gt),
                   f"{stage}/ssim_sensor/{tag}": ssim(y, gt),
                   f"{stage}/ssim_restored/{tag}": ssim(pred, gt)}
            if self.field_bands:
                masks = band_masks(gt.shape[-2:], self.field_bands)
                for k, m in enumerate(masks):
                    b = f"band{self.field_bands[k]:g}-{self.field_bands[k + 1]:g}"
                    log[f"{stage}/psnr_sensor/{b}"] = masked_psnr(y, gt, m)
                    log[f"{stage}/psnr_restored/{b}"] = masked_psnr(pred, gt, m)
                    log[f"{stage}/ssim_sensor/{b}"] = masked_ssim(y, gt, m)
                    log[f"{stage}/ssim_restored/{b}"] = masked_ssim(pred, gt, m)
            self.log_dict(log, batch_size=B)
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
    def configure_optimizers(self):
        groups = [{"params": list(self.restorer.parameters()), "lr": self.net_lr, "name": "net"}]
        groups += optics_param_groups(self.lens, self.optics_lr_mm)
        opt_g = torch.optim.Adam(groups)
        if self.discriminator is not None and self.loss_w["adversarial"]:
            opt_d = torch.optim.Adam(self.discriminator.parameters(), lr=self.disc_lr,
                                     betas=(0.5, 0.999))
            return [opt_g, opt_d]
        return opt_g
