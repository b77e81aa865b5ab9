"""The sensor: a pixel grid on the lens's sensor plane, spectral channels and a noise model.

Pixel ``(i, j)`` (row ``i`` from the top, column ``j`` from the left) of an ``H x W`` sensor with
pitch ``p`` (mm) sits at

    x = -(j + 1/2 - W/2) p,    y = (i + 1/2 - H/2) p

on the sensor plane.  The 180-degree rotation undoes the lens's image inversion, so an upright
scene renders upright (as a camera's read-out does).

Channels: each channel integrates a list of wavelengths (nm) with weights (default R, G, B at
656.3, 587.6 and 486.1 nm, one wavelength each).  A monochrome scene on a sensor of several
channels uses only ``mono_wavelength_nm``; on a one-channel sensor it integrates that channel.

Noise (applied after rendering, seeded): ``I_noisy = I + sqrt(I / full_well) * N1 + read * N2``
with ``N1, N2 ~ N(0, 1)``: Gaussian approximation of shot noise for a signal of ``I * full_well``
electrons (``I = 1`` is full well) plus read noise in units of full well.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..optics.materials import check_wavelength_nm

__all__ = ["Sensor", "RGB_WAVELENGTHS_NM"]

RGB_WAVELENGTHS_NM = (656.2725, 587.5618, 486.1327)


class Sensor(nn.Module):
    """A pixel sensor.

    Args:
        resolution: ``(H, W)`` pixels.
        pixel_size_mm: pixel pitch (mm).
        channels: per channel a list of wavelengths (nm); default R, G, B lines.
        channel_weights: per channel a list of weights (default uniform, normalised to sum 1).
        mono_wavelength_nm: wavelength for monochrome scenes (default: the middle channel's
            first wavelength).
        full_well: electrons at signal 1 (shot noise); ``0`` disables shot noise.
        read_noise: read-noise standard deviation in units of full well; ``0`` disables it.

    Raises:
        ValueError: non-positive sizes, empty channels, wavelengths not in nm.
    """

    def __init__(self, resolution, pixel_size_mm: float, channels=None, channel_weights=None,
                 mono_wavelength_nm: float | None = None, full_well: float = 0.0,
                 read_noise: float = 0.0):
        super().__init__()
        if len(resolution) != 2 or min(int(r) for r in resolution) < 1:
            raise ValueError(f"Sensor: resolution must be (H, W) positive integers, got "
                             f"{resolution!r}")
        if not pixel_size_mm > 0:
            raise ValueError(f"Sensor: pixel_size_mm must be > 0, got {pixel_size_mm!r}")
        self.resolution = (int(resolution[0]), int(resolution[1]))
        self.pixel_size_mm = float(pixel_size_mm)
        if channels is None:
            channels = [[w] for w in RGB_WAVELENGTHS_NM]
        channels = [[float(w) for w in ch] for ch in channels]
        if not channels or any(len(ch) == 0 for ch in channels):
            raise ValueError("Sensor: every channel needs at least one wavelength (nm)")
        for c, ch in enumerate(channels):
            check_wavelength_nm(ch, where=f"Sensor channel {c}: ")
        if channel_weights is None:
            channel_weights = [[1.0] * len(ch) for ch in channels]
        if [len(w) for w in channel_weights] != [len(ch) for ch in channels]:
            raise ValueError("Sensor: channel_weights must match channels in shape")
        self.channels = channels
        self.channel_weights = [[w / sum(ws) for w in ws] for ws in channel_weights]
        self.mono_wavelength_nm = float(mono_wavelength_nm if mono_wavelength_nm is not None
                                        else channels[len(channels) // 2][0])
        check_wavelength_nm(self.mono_wavelength_nm, where="Sensor mono wavelength: ")
        if full_well < 0 or read_noise < 0:
            raise ValueError("Sensor: full_well and read_noise must be >= 0")
        self.full_well = float(full_well)
        self.read_noise = float(read_noise)

    @property
    def size_mm(self) -> tuple[float, float]:
        """``(height, width)`` of the active area in mm."""
        return self.resolution[0] * self.pixel_size_mm, self.resolution[1] * self.pixel_size_mm

    @property
    def half_diagonal_mm(self) -> float:
        h, w = self.size_mm
        return 0.5 * math.hypot(h, w)

    def pixel_to_xy(self, i: torch.Tensor, j: torch.Tensor):
        """Sensor-plane coordinates (mm) of fractional pixel positions (row ``i``, column ``j``;
        pixel centres at ``+0.5``)."""
        H, W = self.resolution
        p = self.pixel_size_mm
        return -(j - W / 2) * p, (i - H / 2) * p

    def xy_to_pixel(self, x: torch.Tensor, y: torch.Tensor):
        """Inverse of :meth:`pixel_to_xy`: fractional ``(i, j)`` (centre of pixel 0 at 0.5)."""
        H, W = self.resolution
        p = self.pixel_size_mm
        return y / p + H / 2, -x / p + W / 2

    def pixel_centers(self, dtype=torch.float64, device=None):
        """``(x, y)`` of all pixel centres, each ``(H, W)`` in mm."""
        H, W = self.resolution
        i = torch.arange(H, dtype=dtype, device=device) + 0.5
        j = torch.arange(W, dtype=dtype, device=device) + 0.5
        I, J = torch.meshgrid(i, j, indexing="ij")
        return self.pixel_to_xy(I, J)

    def wavelengths_for(self, n_channels: int):
        """The ``[(channel, wavelength_nm, weight), ...]`` a scene with ``n_channels`` needs.

        A monochrome scene on a one-channel sensor integrates that channel's wavelengths; on a
        sensor of several channels it uses ``mono_wavelength_nm`` only (the scene carries no
        colour to split).
        """
        if n_channels == 1 and len(self.channels) > 1:
            return [(0, self.mono_wavelength_nm, 1.0)]
        if n_channels != len(self.channels):
            ok = "1" if len(self.channels) == 1 else f"1 (monochrome) or {len(self.channels)}"
            raise ValueError(f"a scene with {n_channels} channels on a sensor with "
                             f"{len(self.channels)} channel(s); use {ok}")
        return [(c, w, wt) for c, (ch, ws) in enumerate(zip(self.channels, self.channel_weights))
                for w, wt in zip(ch, ws)]

    def add_noise(self, image: torch.Tensor, generator: torch.Generator | None = None):
        """Shot + read noise (see module docstring); the noise itself is not differentiated."""
        if self.full_well == 0 and self.read_noise == 0:
            return image
        noise = torch.zeros_like(image)
        if self.full_well > 0:
            std = torch.sqrt(image.detach().clamp_min(0) / self.full_well)
            noise = noise + std * torch.randn(image.shape, generator=generator,
                                              dtype=image.dtype, device=image.device)
        if self.read_noise > 0:
            noise = noise + self.read_noise * torch.randn(image.shape, generator=generator,
                                                          dtype=image.dtype, device=image.device)
        return image + noise

    def extra_repr(self) -> str:
        return (f"resolution={self.resolution}, pixel_size_mm={self.pixel_size_mm}, "
                f"channels={self.channels}")
