"""The pix2pix PatchGAN discriminator (Isola et al. 2017, "NLayerDiscriminator"): a fully
convolutional classifier whose every output logit judges one ``70 x 70`` input patch (for
``n_layers=3``).  Used (opt-in) for adversarial training of the restorer, as in DeblurGAN-v2.
"""

from __future__ import annotations

import torch
from torch import nn

from .unet import NORMS, make_norm


class PatchGANDiscriminator(nn.Module):
    """pix2pix PatchGAN.

    Layers (kernel 4, padding 1, LeakyReLU(0.2))::

        conv s2 (in -> nf)                                         (no norm)
        conv s2 (nf*min(2**(n-1), 8) -> nf*min(2**n, 8)) + norm    for n = 1 .. n_layers-1
        conv s1 (.. -> nf*min(2**n_layers, 8)) + norm
        conv s1 (.. -> 1)                                          (logits, no activation)

    Args:
        in_channels: image channels (use ``2 * C`` to condition on the blurred input by
            concatenation, as pix2pix does).
        base_channels: ``nf``, width of the first layer.
        n_layers: number of stride-2 layers; ``n_layers=3`` gives the 70x70 receptive field.
        norm: ``"batch"`` (pix2pix's default), ``"instance"`` or ``"none"``.

    Shapes: ``forward(x (B, in_channels, H, W)) -> (B, 1, H', W')`` raw logits with
    ``H' = floor(...floor(H/2).../2) - 2`` (``n_layers`` halvings, then two stride-1 4x4 convs
    each shrinking by 1), e.g. ``256 -> 30``; see :meth:`output_size` and
    :meth:`receptive_field`.  Inputs need ``H, W >= 2**n_layers * 3``.
    """

    def __init__(self, in_channels: int = 3, base_channels: int = 64, n_layers: int = 3,
                 norm: str = "batch"):
        super().__init__()
        if n_layers < 1:
            raise ValueError(f"n_layers must be >= 1, got {n_layers}")
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")
        self.n_layers = n_layers
        bias = norm == "none"
        nf = base_channels
        layers: list[nn.Module] = [nn.Conv2d(in_channels, nf, 4, stride=2, padding=1),
                                   nn.LeakyReLU(0.2, inplace=True)]
        mult = 1
        for n in range(1, n_layers + 1):
            prev, mult = mult, min(2 ** n, 8)
            stride = 2 if n < n_layers else 1
            layers += [nn.Conv2d(nf * prev, nf * mult, 4, stride=stride, padding=1, bias=bias),
                       make_norm(norm, nf * mult), nn.LeakyReLU(0.2, inplace=True)]
        layers.append(nn.Conv2d(nf * mult, 1, 4, stride=1, padding=1))
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, in_channels, H, W) -> (B, 1, H', W')`` logits (see :meth:`output_size`)."""
        return self.model(x)

    def output_size(self, h: int, w: int) -> tuple[int, int]:
        """Spatial size ``(H', W')`` of the logit map for an ``h x w`` input."""
        def _one(n: int) -> int:
            for _ in range(self.n_layers):
                n = (n + 2 - 4) // 2 + 1
            return n - 2
        return _one(h), _one(w)

    def receptive_field(self) -> int:
        """Side in pixels of the input patch seen by one output logit (70 for n_layers=3)."""
        rf = 1
        for _ in range(2):                      # the two stride-1 convs (from the output back)
            rf += 3
        for _ in range(self.n_layers):          # the stride-2 convs
            rf = 2 * rf + 2
        return rf
