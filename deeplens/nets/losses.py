"""Losses for training restoration networks: adversarial losses (LSGAN, BCE and their
relativistic-average variants) and a VGG16 perceptual loss.

Everything here is opt-in: nothing is constructed at import time and nothing is ever
downloaded.  :class:`PerceptualLoss` needs the torchvision ImageNet VGG16 weights as a local file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

ADV_KINDS = ("lsgan", "bce")


# --------------------------------------------------------------------------------------------
# adversarial losses
# --------------------------------------------------------------------------------------------
def adversarial_loss(logits: torch.Tensor, target_is_real: bool, kind: str = "lsgan") -> torch.Tensor:
    """GAN loss of discriminator ``logits`` (any shape, e.g. a PatchGAN map ``(B, 1, H', W')``)
    against an all-real or all-fake target, averaged over all elements.

    * ``"lsgan"`` (Mao et al. 2017; DeblurGAN-v2's default): ``mean((logits - t)**2)`` with
      ``t = 1`` for real and ``t = 0`` for fake.
    * ``"bce"`` (the original GAN): ``mean(BCEWithLogits(logits, t))``
      ``= mean(softplus(-logits))`` for real, ``mean(softplus(logits))`` for fake.

    Discriminator step: ``adversarial_loss(D(real), True) + adversarial_loss(D(fake.detach()),
    False)``; generator step: ``adversarial_loss(D(fake), True)``.  Returns a scalar tensor.
    """
    if kind == "lsgan":
        target = 1.0 if target_is_real else 0.0
        return ((logits - target) ** 2).mean()
    if kind == "bce":
        target = torch.ones_like(logits) if target_is_real else torch.zeros_like(logits)
        return F.binary_cross_entropy_with_logits(logits, target)
    raise ValueError(f"kind must be one of {ADV_KINDS}, got {kind!r}")


def relativistic_adversarial_loss(real_logits: torch.Tensor, fake_logits: torch.Tensor,
                                  for_discriminator: bool, kind: str = "lsgan") -> torch.Tensor:
    """Relativistic-average GAN loss (Jolicoeur-Martineau 2019); ``kind="lsgan"`` is the
    RaGAN-LS loss of DeblurGAN-v2.

    With ``Dr = real_logits - mean(fake_logits)`` and ``Df = fake_logits - mean(real_logits)``:

    * discriminator: ``(L(Dr, real) + L(Df, fake)) / 2``
    * generator:     ``(L(Df, real) + L(Dr, fake)) / 2``

    where ``L`` is :func:`adversarial_loss` of ``kind`` (so for LSGAN the fake target is
    ``0``: ``mean((Dr - 1)**2) + mean(Df**2)`` for the discriminator).  For the discriminator
    step pass logits of *detached* fakes; for the generator step both logit tensors may carry
    gradients (the real ones through ``D`` only).  Returns a scalar tensor.
    """
    dr = real_logits - fake_logits.mean()
    df = fake_logits - real_logits.mean()
    if for_discriminator:
        return 0.5 * (adversarial_loss(dr, True, kind) + adversarial_loss(df, False, kind))
    return 0.5 * (adversarial_loss(df, True, kind) + adversarial_loss(dr, False, kind))


# --------------------------------------------------------------------------------------------
# perceptual loss
# --------------------------------------------------------------------------------------------
#: ``torchvision.models.vgg16().features`` index of each named layer output.
VGG16_LAYERS = {
    "conv1_1": 0, "relu1_1": 1, "conv1_2": 2, "relu1_2": 3, "pool1": 4,
    "conv2_1": 5, "relu2_1": 6, "conv2_2": 7, "relu2_2": 8, "pool2": 9,
    "conv3_1": 10, "relu3_1": 11, "conv3_2": 12, "relu3_2": 13, "conv3_3": 14, "relu3_3": 15,
    "pool3": 16,
    "conv4_1": 17, "relu4_1": 18, "conv4_2": 19, "relu4_2": 20, "conv4_3": 21, "relu4_3": 22,
    "pool4": 23,
    "conv5_1": 24, "relu5_1": 25, "conv5_2": 26, "relu5_2": 27, "conv5_3": 28, "relu5_3": 29,
    "pool5": 30,
}
#: File name torchvision uses for the ImageNet VGG16 weights (``VGG16_Weights.IMAGENET1K_V1``).
VGG16_WEIGHTS_FILE = "vgg16-397923af.pth"
#: Environment variable that may point at a local VGG16 weights file.
VGG16_WEIGHTS_ENV = "DEEPLENS_VGG16_WEIGHTS"
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def _hub_checkpoint_dir() -> Path:
    """``<torch hub dir>/checkpoints`` (honours ``$TORCH_HOME``); computed without downloading."""
    return Path(torch.hub.get_dir()) / "checkpoints"


def find_vgg16_weights(weights_path: str | os.PathLike | None = None) -> Path:
    """Locate a local VGG16 ImageNet weights file, never downloading.

    Looks at, in order: ``weights_path`` (if given, only there), ``$DEEPLENS_VGG16_WEIGHTS``,
    then torchvision's cache ``<torch hub dir>/checkpoints/vgg16-397923af.pth`` (by default
    ``~/.cache/torch/hub/checkpoints``).  Raises ``FileNotFoundError`` naming every place looked
    at and how to provide the file.
    """
    if weights_path is not None:
        candidates = [Path(weights_path).expanduser()]
    else:
        candidates = []
        env = os.environ.get(VGG16_WEIGHTS_ENV)
        if env:
            candidates.append(Path(env).expanduser())
        candidates.append(_hub_checkpoint_dir() / VGG16_WEIGHTS_FILE)
    for c in candidates:
        if c.is_file():
            return c
    looked = "\n".join(f"  - {c}" for c in candidates)
    raise FileNotFoundError(
        "PerceptualLoss needs the ImageNet VGG16 weights as a local file (deeplens never "
        f"downloads them at run time); not found at:\n{looked}\n"
        "Provide them by either\n"
        "  * passing weights_path='/path/to/vgg16-397923af.pth' (a torchvision VGG16 state "
        "dict; a features-only dict is also accepted), or\n"
        f"  * setting ${VGG16_WEIGHTS_ENV}=/path/to/vgg16-397923af.pth, or\n"
        f"  * placing the file in torchvision's cache {_hub_checkpoint_dir() / VGG16_WEIGHTS_FILE}"
        " (on a machine with internet access: python -c \"import torchvision; "
        "torchvision.models.vgg16(weights='IMAGENET1K_V1')\", or download "
        f"https://download.pytorch.org/models/{VGG16_WEIGHTS_FILE}).")


class PerceptualLoss(nn.Module):
    """Perceptual (feature) loss on frozen VGG16 features (Johnson et al. 2016), as used by
    DeblurGAN / DeblurGAN-v2 (which take ``conv3_3``-level features).

    Args:
        layers: names from :data:`VGG16_LAYERS` (e.g. ``"relu1_2"``, ``"relu2_2"``,
            ``"relu3_3"``, ``"relu4_3"``) whose feature maps are compared.
        weights_path: local torchvision VGG16 state dict (``.pth``); default: look up
            ``$DEEPLENS_VGG16_WEIGHTS`` then torchvision's hub cache (see
            :func:`find_vgg16_weights`).  Missing weights raise ``FileNotFoundError``
            immediately, before anything is built; nothing is ever downloaded.
        layer_weights: per-layer multipliers (default all 1).
        distance: ``"mse"`` (DeblurGAN) or ``"l1"`` between feature maps (mean over elements).
        input_range: value range ``(lo, hi)`` of the images, mapped to ``[0, 1]`` before the
            ImageNet mean/std normalisation; use ``(-1, 1)`` for tanh-range images.

    ``forward(pred (B, 3, H, W), target (B, 3, H, W)) -> scalar``: ``sum_l w_l d(phi_l(pred),
    phi_l(target))``.  Gradients flow to ``pred`` (and ``target`` if it requires grad); the VGG
    parameters are frozen (``requires_grad=False``) and the network stays in eval mode.
    Note the VGG weights are part of this module's ``state_dict``.
    """

    def __init__(self, layers: Sequence[str] = ("relu3_3",), weights_path=None,
                 layer_weights: Sequence[float] | None = None, distance: str = "mse",
                 input_range: tuple[float, float] = (0.0, 1.0)):
        super().__init__()
        layers = (layers,) if isinstance(layers, str) else tuple(layers)
        if not layers:
            raise ValueError("layers must name at least one VGG16 layer")
        unknown = [name for name in layers if name not in VGG16_LAYERS]
        if unknown:
            raise ValueError(f"unknown VGG16 layer(s) {unknown}; choose from {list(VGG16_LAYERS)}")
        if distance not in ("mse", "l1"):
            raise ValueError(f"distance must be 'mse' or 'l1', got {distance!r}")
        if layer_weights is None:
            layer_weights = [1.0] * len(layers)
        if len(layer_weights) != len(layers):
            raise ValueError("layer_weights must have one entry per layer")
        # fail fast, before importing/building anything that could try to download
        path = find_vgg16_weights(weights_path)

        import torchvision  # optional dependency (the "train" extra)

        self.layers = layers
        self.layer_weights = [float(w) for w in layer_weights]
        self.distance = distance
        self.input_range = (float(input_range[0]), float(input_range[1]))
        self.weights_path = path
        self._indices = [VGG16_LAYERS[name] for name in layers]
        last = max(self._indices)

        # Build the architecture on the meta device (weights=None: torchvision downloads
        # nothing, and no memory/time goes to the unused classifier), keep the needed prefix
        # of `features`, then materialise it from the local state dict.
        with torch.device("meta"):
            vgg = torchvision.models.vgg16(weights=None)
        features = vgg.features[: last + 1]
        for m in features:
            if isinstance(m, nn.ReLU):
                m.inplace = False          # intermediate outputs are kept; no in-place edits
        try:   # tensors and containers only: a pickled object is refused, never run
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as e:  # noqa: BLE001 - torch raises many kinds; all mean "not weights"
            first = str(e).strip().splitlines()[0] if str(e).strip() else ""
            raise ValueError(f"{path}: cannot be read as VGG16 weights: torch.load(weights_only="
                             f"True) refused it ({type(e).__name__}: {first[:200]}); deeplens "
                             f"loads tensors only, never arbitrary pickled objects: expected "
                             f"torchvision's VGG16 state dict ({VGG16_WEIGHTS_FILE}, or a "
                             f"features-only dict)") from None
        if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
            state = state["state_dict"]
        if not isinstance(state, dict):
            raise ValueError(f"{path} is not a VGG16 state dict: it holds a "
                             f"{type(state).__name__}, expected a dict of parameter names to "
                             f"tensors (torchvision's {VGG16_WEIGHTS_FILE})")
        if any(isinstance(k, str) and k.startswith("features.") for k in state):
            state = {k[len("features."):]: v for k, v in state.items() if k.startswith("features.")}
        wanted = features.state_dict().keys()
        missing = [k for k in wanted if not torch.is_tensor(state.get(k))]
        if missing:
            raise ValueError(f"{path} is not a VGG16 state dict: missing features keys {missing}")
        features.load_state_dict({k: state[k].float() for k in wanted}, strict=True, assign=True)
        features.requires_grad_(False)
        self.features = features.eval()

        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True):
        """Keep the frozen VGG in eval mode whatever the parent module does."""
        super().train(mode)
        self.features.eval()
        return self

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        """Map ``x`` from ``input_range`` to ``[0, 1]`` and apply the ImageNet mean/std."""
        lo, hi = self.input_range
        x = (x - lo) / (hi - lo)
        return (x - self.mean) / self.std

    def extract(self, x: torch.Tensor) -> list[torch.Tensor]:
        """VGG16 feature maps of ``x`` ``(B, 3, H, W)`` at ``self.layers`` (in that order)."""
        if x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(f"PerceptualLoss expects (B, 3, H, W) images, got {tuple(x.shape)}")
        h = self.normalize(x)
        out = {}
        wanted = set(self._indices)
        for i, layer in enumerate(self.features):
            h = layer(h)
            if i in wanted:
                out[i] = h
        return [out[i] for i in self._indices]

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """``(B, 3, H, W), (B, 3, H, W) -> scalar`` weighted sum of feature distances."""
        if pred.shape != target.shape:
            raise ValueError(f"shape mismatch: {tuple(pred.shape)} vs {tuple(target.shape)}")
        fp = self.extract(pred)
        with torch.set_grad_enabled(target.requires_grad and torch.is_grad_enabled()):
            ft = self.extract(target)
        dist = F.mse_loss if self.distance == "mse" else F.l1_loss
        total = pred.new_zeros(())
        for w, a, b in zip(self.layer_weights, fp, ft):
            total = total + w * dist(a, b)
        return total
