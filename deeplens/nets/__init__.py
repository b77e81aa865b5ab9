"""Image-restoration networks for end-to-end camera design: a U-Net and a DeblurGAN-v2-style
FPN generator (both: any input size, optional global residual that starts at the identity), a
pix2pix PatchGAN discriminator, and adversarial / VGG16 perceptual losses (opt-in; nothing is
downloaded).

All networks take and return ``(B, C, H, W)`` image tensors.
"""

from .discriminator import PatchGANDiscriminator
from .fpn import FPNGenerator
from .losses import PerceptualLoss, adversarial_loss, find_vgg16_weights, relativistic_adversarial_loss
from .unet import UNet, count_parameters

#: Restoration networks by name, for configuration files.
NETWORKS = {"unet": UNet, "fpn": FPNGenerator}


def build_network(name: str, **kwargs):
    """Construct a restoration network by name (``"unet"`` or ``"fpn"``) with ``kwargs``."""
    try:
        cls = NETWORKS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown network {name!r}; choose from {sorted(NETWORKS)}") from None
    return cls(**kwargs)


__all__ = [
    "UNet", "FPNGenerator", "PatchGANDiscriminator", "PerceptualLoss", "adversarial_loss",
    "relativistic_adversarial_loss", "find_vgg16_weights", "count_parameters", "NETWORKS",
    "build_network",
]
