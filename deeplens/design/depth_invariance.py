"""A merit for extended depth of field: the change of the PSF over a depth range, at a fixed
blur size (the classical route to an EDOF plate: design the optics for depth invariance, then
restore).

The PSF of an on-axis point at depth ``d`` is represented by its *geometric OTF*: with ``M``
rays landing at ``p_k`` (pixels, about a reference point ``c``),

    H_d(f) = (1 / M) Σ_k exp(-2πi f · (p_k - c)),        f in cycles per pixel,

the Fourier transform of the ray histogram, smooth in the ray positions (no binning, so the
merit has exact gradients).  ``c`` is the centroid averaged over all depths and wavelengths (a
PSF that moves with depth counts as a change; a shift common to every depth does not).  The
residuals are

* invariance: ``Re, Im (H_d(f) - H̄(f)) / sqrt(D F)`` for every depth ``d``, wavelength and
  frequency ``f`` of a half-plane grid up to Nyquist (``H̄`` the mean over depths);
* blur size: ``blur_weight · (mean_d rms_d - blur_px)``, the rms radius (pixels) averaged over
  depths and wavelengths held at ``blur_px``; without it the trivial optimum is an infinitely
  wide PSF (every OTF zero).

``invariance(lens)`` is the first part's sum of squares (the figure of merit reported and
tested); ``residuals(lens)`` both, for :func:`~deeplens.design.lensopt.optimize_lens`.
"""

from __future__ import annotations

import math

import torch

from ..optics.camera import unpack
from ..optics.sampling import point_source_rays
from .optimizers import Infeasible

__all__ = ["DepthInvarianceMerit", "geometric_otf", "frequency_grid"]


def frequency_grid(n: int, dtype=torch.float64) -> torch.Tensor:
    """``(K, 2)`` frequencies (cycles per pixel) of a half-plane grid: ``fx`` in ``[0, 0.5]``,
    ``fy`` in ``[-0.5, 0.5]``, ``n`` steps to Nyquist, the zero frequency left out (``H(0) = 1``)
    and ``fx = 0, fy < 0`` too (``H(-f) = conj H(f)``)."""
    if n < 1:
        raise ValueError(f"frequencies: need n >= 1 steps to Nyquist, got {n}")
    s = torch.arange(-n, n + 1, dtype=dtype) * (0.5 / n)
    fx, fy = torch.meshgrid(s[n:], s, indexing="ij")
    f = torch.stack([fx.reshape(-1), fy.reshape(-1)], -1)
    keep = (f[:, 0] > 0) | (f[:, 1] > 0)
    return f[keep]


def geometric_otf(p: torch.Tensor, weights: torch.Tensor, freqs: torch.Tensor):
    """``(Re, Im)`` of ``Σ_k w_k exp(-2πi f·p_k) / Σ_k w_k``; ``p (M, 2)`` pixels, ``weights (M,)``
    (0 for lost rays), ``freqs (K, 2)`` cycles per pixel; returns two ``(K,)`` tensors."""
    ph = -2 * math.pi * (p @ freqs.to(p).T)  # (M, K)
    w = weights.to(p)[:, None]
    n = w.sum()
    return (w * torch.cos(ph)).sum(0) / n, (w * torch.sin(ph)).sum(0) / n


class DepthInvarianceMerit:
    """Depth-invariance residuals of the on-axis PSF (module docstring).

    Args:
        depths_mm: object depths (mm from the first vertex), at least two.
        wavelengths_nm: wavelengths (nm).
        pixel_mm: sensor pixel pitch (mm): positions and frequencies are in pixels.
        blur_px: target rms radius (pixels) averaged over depths and wavelengths; ``None``:
            the value of the lens given to :meth:`prepare` (keep the start's blur size).
        blur_weight: weight of the blur-size residual (per pixel of error).
        n_freq: frequency steps to Nyquist (:func:`frequency_grid`).
        sampling: pupil pattern of :func:`~deeplens.render.splat.point_source_rays`.
    """

    def __init__(self, depths_mm, wavelengths_nm, pixel_mm: float, blur_px: float | None = None,
                 blur_weight: float = 1.0, n_freq: int = 6, sampling: str = "grid:48"):
        self.depths = [float(d) for d in depths_mm]
        self.waves = [float(w) for w in wavelengths_nm]
        if len(self.depths) < 2 or not all(d > 0 and math.isfinite(d) for d in self.depths):
            raise ValueError(f"depth invariance: need at least two finite depths > 0 mm, got "
                             f"{list(depths_mm)}")
        if not self.waves or not all(w > 0 and math.isfinite(w) for w in self.waves):
            raise ValueError(f"depth invariance: wavelengths must be > 0 nm, got "
                             f"{list(wavelengths_nm)}")
        if not (pixel_mm > 0 and math.isfinite(pixel_mm)):
            raise ValueError(f"depth invariance: pixel_mm must be > 0, got {pixel_mm}")
        if blur_px is not None and not blur_px > 0:
            raise ValueError(f"depth invariance: blur_px must be > 0 pixels, got {blur_px}")
        self.pixel_mm, self.blur_px, self.blur_weight = float(pixel_mm), blur_px, float(blur_weight)
        self.freqs = frequency_grid(n_freq)
        self.sampling = sampling
        self.masks = None

    def _positions(self, lens):
        """``{(depth, λ): (p (M, 2) pixels, valid (M,))}`` from one trace per key; ``lens``:
        a Lens (default trace options) or a :class:`~deeplens.optics.camera.Camera` (its
        options; so for :meth:`prepare`, :meth:`residuals`, :meth:`invariance`, :meth:`blur`)."""
        lens, _, options = unpack(lens, None, None, "DepthInvarianceMerit")
        out = {}
        for d in self.depths:
            for w in self.waves:
                rays = point_source_rays(lens, (0.0, 0.0), d, w, 0, sampling=self.sampling)
                r = lens.trace_to_sensor(rays, options=options)
                out[(d, w)] = (r.o[:, :2] / self.pixel_mm, r.valid)
        return out

    def prepare(self, lens) -> "DepthInvarianceMerit":
        """Fix the rays that reach the sensor on ``lens`` as it is now, and the blur target."""
        with torch.no_grad():
            pos = self._positions(lens)
            self.masks = {k: v.clone() for k, (_, v) in pos.items()}
            for k, m in self.masks.items():
                if int(m.sum()) < 3:
                    raise ValueError(f"depth invariance: fewer than 3 rays reach the sensor at "
                                     f"{k[0]:g} mm, {k[1]:g} nm")
            if self.blur_px is None:
                self.blur_px = float(self._blur(pos))
        return self

    def _blur(self, pos):
        rms = []
        for k, (p, _) in pos.items():
            m = (self.masks[k] if self.masks is not None else pos[k][1]).to(p.dtype)[:, None]
            c = (p * m).sum(0) / m.sum()
            rms.append(torch.sqrt((((p - c) ** 2) * m).sum() / m.sum()))
        return torch.stack(rms).mean()

    def _terms(self, lens):
        if self.masks is None:
            raise RuntimeError("DepthInvarianceMerit.prepare(lens) must be called first")
        pos = self._positions(lens)
        for k, (_, v) in pos.items():
            lost = self.masks[k] & ~v
            if bool(lost.any()):
                raise Infeasible(f"{int(lost.sum())} rays of the point at {k[0]:g} mm, "
                                 f"{k[1]:g} nm no longer reach the sensor")
        ws = {k: self.masks[k].to(p.dtype) for k, (p, _) in pos.items()}
        c = torch.stack([(p * ws[k][:, None]).sum(0) / ws[k].sum()
                         for k, (p, _) in pos.items()]).mean(0)
        inv = []
        for w in self.waves:
            H = [geometric_otf(pos[(d, w)][0] - c, ws[(d, w)], self.freqs) for d in self.depths]
            re = torch.stack([h[0] for h in H])
            im = torch.stack([h[1] for h in H])
            inv += [re - re.mean(0), im - im.mean(0)]
        scale = 1.0 / math.sqrt(len(self.depths) * self.freqs.shape[0])
        inv_r = torch.cat([t.reshape(-1) for t in inv]) * scale
        return inv_r, self._blur(pos)

    def invariance(self, lens) -> torch.Tensor:
        """Sum of squares of the invariance residuals (0: the same PSF at every depth)."""
        r, _ = self._terms(lens)
        return (r * r).sum()

    def blur(self, lens) -> torch.Tensor:
        """rms radius (pixels) averaged over depths and wavelengths."""
        return self._terms(lens)[1]

    def residuals(self, lens) -> torch.Tensor:
        r, b = self._terms(lens)
        return torch.cat([r, (self.blur_weight * (b - self.blur_px)).reshape(1).to(r)])
