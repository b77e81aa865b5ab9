"""``F.conv2d`` of one-channel images with many kernels, by FFT (same result, "valid" part).

    y[b, p, i, j] = Σ_{u,v} x[b, 0, i + u, j + v] k[p, 0, u, v]

is the circular correlation of ``x`` (``L_h x L_w``) with ``k`` zero-padded to the same size,
read at ``i <= L_h - K_h``: there the window does not wrap, so
``y = irfft2(rfft2(x) · rfft2(flip(k)))[K_h - 1:, K_w - 1:]`` exactly (up to rounding: measured
2e-6 to 5e-6 of the largest value in float32, K = 25-85 on a 64-pixel frame).  Direct
correlation costs ``H W K²`` per kernel and its backward as much again; the FFT costs
``L² log L``: at one thread, forward and backward of a 64 x 64 frame, 8.0 ms against 0.37 ms
at K = 37 (the EDOF geometric kernel) and 38.5 ms against 1.9 ms at K = 85 (the diffraction
kernel), ``benchmarks/bench_diffraction_step.py``'s notes in docs/guide/diffraction.md.
"""

from __future__ import annotations

import torch

__all__ = ["correlate_valid"]


def correlate_valid(x: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """``F.conv2d(x, k)`` for ``x (B, 1, Lh, Lw)`` and ``k (P, 1, Kh, Kw)`` -> ``(B, P, Lh - Kh
    + 1, Lw - Kw + 1)``, by FFT; differentiable in both."""
    if x.dim() != 4 or k.dim() != 4 or x.shape[1] != 1 or k.shape[1] != 1:
        raise ValueError(f"correlate_valid: expected x (B, 1, H, W) and k (P, 1, K, K), got "
                         f"{tuple(x.shape)} and {tuple(k.shape)}")
    Lh, Lw = x.shape[-2:]
    Kh, Kw = k.shape[-2:]
    if Kh > Lh or Kw > Lw:
        raise ValueError(f"correlate_valid: kernel {Kh}x{Kw} larger than the image {Lh}x{Lw}")
    X = torch.fft.rfft2(x, s=(Lh, Lw))                          # (B, 1, Lh, Lw/2+1)
    Kf = torch.fft.rfft2(k.flip(-1, -2)[:, 0], s=(Lh, Lw))      # (P, Lh, Lw/2+1)
    y = torch.fft.irfft2(X * Kf[None], s=(Lh, Lw))              # (B, P, Lh, Lw)
    return y[..., Kh - 1:, Kw - 1:]
