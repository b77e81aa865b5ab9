"""A configurable U-Net image restorer (Ronneberger et al. 2015), plus the padding helpers that
all restoration networks in :mod:`deeplens.nets` share.

Tensors are ``(B, C, H, W)`` images; any ``H, W`` is accepted: the input is padded (replicate)
to a multiple of the network's total down-sampling factor and the output is cropped back.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

NORMS = ("batch", "instance", "none")


# --------------------------------------------------------------------------------------------
# shared helpers
# --------------------------------------------------------------------------------------------
def make_norm(norm: str, channels: int) -> nn.Module:
    """A 2-D normalisation layer by name: ``"batch"`` (BatchNorm2d), ``"instance"`` (affine
    InstanceNorm2d without running statistics) or ``"none"`` (Identity)."""
    if norm == "batch":
        return nn.BatchNorm2d(channels)
    if norm == "instance":
        return nn.InstanceNorm2d(channels, affine=True, track_running_stats=False)
    if norm == "none":
        return nn.Identity()
    raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")


def conv_norm_act(c_in: int, c_out: int, norm: str, *, kernel_size: int = 3, stride: int = 1,
                  act: bool = True) -> nn.Sequential:
    """``Conv2d -> norm -> ReLU``; the convolution has a bias only when ``norm == "none"``
    (a bias in front of a normalisation is cancelled by the mean subtraction and would get an
    identically zero gradient)."""
    layers: list[nn.Module] = [
        nn.Conv2d(c_in, c_out, kernel_size, stride=stride, padding=kernel_size // 2,
                  bias=(norm == "none")),
        make_norm(norm, c_out),
    ]
    if act:
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


def pad_to_multiple(x: torch.Tensor, multiple: int, min_size: int = 0):
    """Pad ``x`` ``(B, C, H, W)`` with edge replication so that ``H`` and ``W`` become multiples
    of ``multiple`` and at least ``min_size``.  The padding is split evenly between the two
    sides of each axis.

    Returns ``(x_padded, (top, bottom, left, right))``; :func:`crop_padding` undoes it.
    """
    h, w = x.shape[-2:]

    def _target(n: int) -> int:
        t = -(-n // multiple) * multiple
        if t < min_size:
            t = -(-min_size // multiple) * multiple
        return t

    dh, dw = _target(h) - h, _target(w) - w
    pads = (dh // 2, dh - dh // 2, dw // 2, dw - dw // 2)
    if dh == 0 and dw == 0:
        return x, pads
    top, bottom, left, right = pads
    return F.pad(x, (left, right, top, bottom), mode="replicate"), pads


def crop_padding(x: torch.Tensor, pads) -> torch.Tensor:
    """Remove the ``(top, bottom, left, right)`` padding added by :func:`pad_to_multiple`."""
    top, bottom, left, right = pads
    h, w = x.shape[-2:]
    return x[..., top:h - bottom, left:w - right]


def count_parameters(module: nn.Module, trainable_only: bool = True) -> int:
    """Number of (trainable) scalar parameters of ``module``."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad or not trainable_only)


# --------------------------------------------------------------------------------------------
# U-Net
# --------------------------------------------------------------------------------------------
class DoubleConv(nn.Sequential):
    """``(conv3x3 -> norm -> ReLU) x 2``: ``(B, c_in, H, W) -> (B, c_out, H, W)``."""

    def __init__(self, c_in: int, c_out: int, norm: str):
        super().__init__(conv_norm_act(c_in, c_out, norm), conv_norm_act(c_out, c_out, norm))


class _Up(nn.Module):
    """Bilinear x2 upsampling, 1x1 channel reduction, concatenation with the skip, DoubleConv.

    ``forward(x (B, c_in, h, w), skip (B, c_out, 2h, 2w)) -> (B, c_out, 2h, 2w)``.
    """

    def __init__(self, c_in: int, c_out: int, norm: str):
        super().__init__()
        self.reduce = nn.Conv2d(c_in, c_out, 1)
        self.conv = DoubleConv(2 * c_out, c_out, norm)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        return self.conv(torch.cat([skip, self.reduce(x)], dim=1))


class UNet(nn.Module):
    """U-Net image restorer.

    Encoder: ``DoubleConv`` at full resolution, then ``depth`` times ``MaxPool2d(2) ->
    DoubleConv`` with channels ``base_channels * 2**level`` (level ``0..depth``).  Decoder:
    ``depth`` times bilinear x2 upsampling, 1x1 reduction, concatenation with the encoder skip
    and ``DoubleConv``.  Head: a 1x1 convolution to ``out_channels``.

    Args:
        in_channels, out_channels: image channels of input and output.
        base_channels: width of the first level (the width doubles at every level down).
        depth: number of 2x down-samplings (the total factor is ``2**depth``).
        residual: predict a correction that is added to the input, ``y = x + head(...)``
            (needs ``in_channels == out_channels``).  The restorer then starts near the
            identity, which suits deblurring.
        norm: ``"batch"``, ``"instance"`` or ``"none"``.
        zero_init_head: zero the head's weight and bias, so that with ``residual=True`` the
            network is *exactly* the identity at initialisation (in train and eval mode).
            Note the zero head blocks gradients to the body for the very first step only.

    Shapes: ``forward(x (B, in_channels, H, W)) -> (B, out_channels, H, W)`` for any ``H, W``:
    the input is replicate-padded to a multiple of ``2**depth`` (and at least ``2**(depth+1)``,
    so the bottleneck has >= 2x2 pixels, as instance/batch norm need) and the output is cropped
    back.  No output clamping.
    """

    def __init__(self, in_channels: int = 3, out_channels: int = 3, base_channels: int = 32,
                 depth: int = 4, residual: bool = True, norm: str = "batch",
                 zero_init_head: bool = True):
        super().__init__()
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}")
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")
        if residual and in_channels != out_channels:
            raise ValueError("residual=True needs in_channels == out_channels "
                             f"(got {in_channels} and {out_channels})")
        self.in_channels, self.out_channels = in_channels, out_channels
        self.base_channels, self.depth = base_channels, depth
        self.residual, self.norm = residual, norm

        ch = [base_channels * 2 ** i for i in range(depth + 1)]
        self.inc = DoubleConv(in_channels, ch[0], norm)
        self.downs = nn.ModuleList(
            nn.Sequential(nn.MaxPool2d(2), DoubleConv(ch[i], ch[i + 1], norm)) for i in range(depth))
        self.ups = nn.ModuleList(_Up(ch[i + 1], ch[i], norm) for i in reversed(range(depth)))
        self.head = nn.Conv2d(ch[0], out_channels, 1)
        if zero_init_head:
            nn.init.zeros_(self.head.weight)
            nn.init.zeros_(self.head.bias)

    @property
    def multiple(self) -> int:
        """Total down-sampling factor ``2**depth``."""
        return 2 ** self.depth

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, in_channels, H, W) -> (B, out_channels, H, W)``."""
        if x.ndim != 4 or x.shape[1] != self.in_channels:
            raise ValueError(f"expected (B, {self.in_channels}, H, W), got {tuple(x.shape)}")
        xp, pads = pad_to_multiple(x, self.multiple, min_size=2 * self.multiple)
        feats = [self.inc(xp)]
        for down in self.downs:
            feats.append(down(feats[-1]))
        y = feats.pop()
        for up in self.ups:
            y = up(y, feats.pop())
        y = crop_padding(self.head(y), pads)
        return x + y if self.residual else y
