"""A DeblurGAN-v2-style feature-pyramid generator (Kupyn et al., "DeblurGAN-v2: Deblurring
(Orders-of-Magnitude) Faster and Better", ICCV 2019) on a small backbone built here.

Structure (``L = num_levels``; resolutions relative to the padded input)::

    x ─ stem (conv + residual block, 1/1) ─ f0 ─────────────────────────────────┐ lateral0
          └ enc1 (strided conv + res. block, 1/2) ─ e1 ─ lateral1 ─(+)─ td1 ─ p1 ─ head1 ─┐
               └ enc2 (1/4) ─ e2 ─ lateral2 ─(+)─ td2 ─ p2 ─ head2 ─ up to 1/2 ─────────┤ concat
                    ...                         ↑ (nearest x2 from the level below)       │
                    └ encL (1/2**L) ─ eL ─ lateralL ─ pL ─ headL ─ up to 1/2 ─────────────┘
    concat ─ smooth1 (1/2) ─ bilinear x2 ─ (+ lateral0(f0)) ─ smooth2 ─ final conv ─ tanh ─ (+ x)

The random-initialised backbone replaces DeblurGAN-v2's ImageNet MobileNet/Inception backbone:
nothing is downloaded.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .unet import NORMS, conv_norm_act, crop_padding, pad_to_multiple


class ResBlock(nn.Module):
    """``x + conv_norm(ReLU(conv_norm(x)))`` followed by ReLU: ``(B, C, H, W) -> (B, C, H, W)``."""

    def __init__(self, channels: int, norm: str):
        super().__init__()
        self.body = nn.Sequential(conv_norm_act(channels, channels, norm),
                                  conv_norm_act(channels, channels, norm, act=False))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.body(x))


class FPNHead(nn.Sequential):
    """DeblurGAN-v2's per-level head: ``conv3x3 -> ReLU -> conv3x3 -> ReLU`` (no norm)."""

    def __init__(self, c_in: int, c_mid: int, c_out: int):
        super().__init__(nn.Conv2d(c_in, c_mid, 3, padding=1), nn.ReLU(inplace=True),
                         nn.Conv2d(c_mid, c_out, 3, padding=1), nn.ReLU(inplace=True))


class FPNGenerator(nn.Module):
    """Feature-pyramid deblurring generator in the style of DeblurGAN-v2.

    Args:
        in_channels, out_channels: image channels.
        base_channels: width of the stem; encoder level ``i`` (``1..num_levels``) has
            ``min(base_channels * 2**i, 8 * base_channels)`` channels at resolution ``1/2**i``.
        fpn_channels: width of the lateral / top-down pyramid; the per-level heads output
            ``fpn_channels // 2`` channels each, the full-resolution tail ``fpn_channels // 2``.
        num_levels: number of pyramid levels (strided stages of the backbone), >= 2.
        residual: global residual ``y = x + tanh(final)`` (DeblurGAN-v2); needs
            ``in_channels == out_channels``.  Otherwise ``y = final`` (linear output).
        norm: ``"instance"`` (DeblurGAN-v2's default), ``"batch"`` or ``"none"``.
        clamp_range: optional ``(lo, hi)`` to clamp the output to, e.g. ``(-1, 1)`` as in
            DeblurGAN-v2 for images in ``[-1, 1]``, or ``(0, 1)``.  ``None`` (default): no clamp.
        zero_init_head: zero the final convolution, so that with ``residual=True`` (and no
            clamp, or inputs inside ``clamp_range``) the generator is exactly the identity at
            initialisation.

    Shapes: ``forward(x (B, in_channels, H, W)) -> (B, out_channels, H, W)`` for any ``H, W``
    (replicate-padded to a multiple of ``2**num_levels``, at least ``2**(num_levels+1)``, and
    cropped back).
    """

    def __init__(self, in_channels: int = 3, out_channels: int = 3, base_channels: int = 32,
                 fpn_channels: int = 64, num_levels: int = 4, residual: bool = True,
                 norm: str = "instance", clamp_range: tuple[float, float] | None = None,
                 zero_init_head: bool = True):
        super().__init__()
        if num_levels < 2:
            raise ValueError(f"num_levels must be >= 2, got {num_levels}")
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")
        if residual and in_channels != out_channels:
            raise ValueError("residual=True needs in_channels == out_channels "
                             f"(got {in_channels} and {out_channels})")
        if fpn_channels < 2:
            raise ValueError("fpn_channels must be >= 2")
        self.in_channels, self.out_channels = in_channels, out_channels
        self.num_levels, self.residual, self.norm = num_levels, residual, norm
        self.clamp_range = None if clamp_range is None else (float(clamp_range[0]),
                                                             float(clamp_range[1]))
        head_ch = fpn_channels // 2
        ch = [base_channels] + [min(base_channels * 2 ** i, 8 * base_channels)
                                for i in range(1, num_levels + 1)]
        self.encoder_channels = tuple(ch)

        # backbone
        self.stem = nn.Sequential(conv_norm_act(in_channels, ch[0], norm), ResBlock(ch[0], norm))
        self.encoders = nn.ModuleList(
            nn.Sequential(conv_norm_act(ch[i], ch[i + 1], norm, stride=2), ResBlock(ch[i + 1], norm))
            for i in range(num_levels))
        # pyramid: laterals for levels 1..L, top-down smoothing for levels 1..L-1
        self.laterals = nn.ModuleList(nn.Conv2d(ch[i + 1], fpn_channels, 1)
                                      for i in range(num_levels))
        self.td = nn.ModuleList(conv_norm_act(fpn_channels, fpn_channels, norm)
                                for _ in range(num_levels - 1))
        self.heads = nn.ModuleList(FPNHead(fpn_channels, head_ch, head_ch)
                                   for _ in range(num_levels))
        # fusion and full-resolution tail
        self.smooth1 = conv_norm_act(num_levels * head_ch, head_ch, norm)
        self.lateral0 = nn.Conv2d(ch[0], head_ch, 1)
        self.smooth2 = conv_norm_act(head_ch, head_ch, norm)
        self.final = nn.Conv2d(head_ch, out_channels, 3, padding=1)
        if zero_init_head:
            nn.init.zeros_(self.final.weight)
            nn.init.zeros_(self.final.bias)

    @property
    def multiple(self) -> int:
        """Total down-sampling factor ``2**num_levels``."""
        return 2 ** self.num_levels

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, in_channels, H, W) -> (B, out_channels, H, W)``."""
        if x.ndim != 4 or x.shape[1] != self.in_channels:
            raise ValueError(f"expected (B, {self.in_channels}, H, W), got {tuple(x.shape)}")
        xp, pads = pad_to_multiple(x, self.multiple, min_size=2 * self.multiple)
        f0 = self.stem(xp)
        enc, e = [], f0
        for stage in self.encoders:
            e = stage(e)
            enc.append(e)                                   # level i+1 at 1/2**(i+1)
        # top-down pathway
        p = self.laterals[-1](enc[-1])
        pyramid = [p]
        for i in reversed(range(self.num_levels - 1)):
            p = self.td[i](self.laterals[i](enc[i]) + F.interpolate(p, scale_factor=2.0,
                                                                     mode="nearest"))
            pyramid.append(p)
        pyramid.reverse()                                   # pyramid[i]: level i+1
        size = pyramid[0].shape[-2:]
        maps = [self.heads[0](pyramid[0])] + [
            F.interpolate(self.heads[i](pyramid[i]), size=size, mode="nearest")
            for i in range(1, self.num_levels)]
        y = self.smooth1(torch.cat(maps, dim=1))
        y = F.interpolate(y, size=f0.shape[-2:], mode="bilinear", align_corners=False)
        y = self.final(self.smooth2(y + self.lateral0(f0)))
        y = crop_padding(y, pads)
        if self.residual:
            y = x + torch.tanh(y)
        if self.clamp_range is not None:
            y = y.clamp(*self.clamp_range)
        return y
