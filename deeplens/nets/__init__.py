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

__all__ = [
    "UNet", "FPNGenerator", "PatchGANDiscriminator", "PerceptualLoss", "adversarial_loss",
    "relativistic_adversarial_loss", "find_vgg16_weights", "count_parameters",
]
