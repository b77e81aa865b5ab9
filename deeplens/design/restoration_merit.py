"""A merit for an EDOF phase plate that asks what the camera asks: how well a linear front end
restores the image at the worst depth (issue 36).

The depth-invariance merit (:mod:`.depth_invariance`) matches the PSF's OTF across depths at a
fixed blur size; it does not ask that the OTF stay away from zero, which is what a
deconvolution needs, and it ranked three plates opposite to the camera
(docs/results/edof_search_3seeds.md).  This merit scores a plate by the expected error of the
camera's own kind of front end, the depth-averaged Wiener filter
(:class:`deeplens.training.wiener.DepthWienerFilter`), on the experiment's textures and noise.

For the on-axis PSFs ``h_{d,c}`` at depths ``d = 1..D`` (uniform in 1/depth over the training
range, as training samples them) and sensor channels ``c`` (each its wavelengths' weighted
mean, as the Wiener filter forms them), with OTFs ``H_{d,c}(f)`` on an ``N x N`` FFT grid
(cycles per pixel), an object power spectrum ``S(f)`` and white sensor noise of variance
``σ²`` per pixel, the linear filter of least mean square error when the depth is unknown
(uniform over the ``D`` depths) is

    G_c(f) = E_d[conj H_{d,c}(f)] S(f) / (E_d[|H_{d,c}(f)|²] S(f) + σ²),

the training filter's form with its learned noise-to-signal ratio replaced by ``σ² / S(f)``
(training learns one ``nsr`` per channel; this merit lets every plate have its best filter, so
that it scores the plate, not a filter setting).  Its expected squared error at depth ``d``,
per pixel, averaged over the channels and the frequency grid (Parseval), is

    MSE_d = mean_{c,f} [ |G_c H_{d,c} - 1|² S + |G_c|² σ² ]

(blur left after the filter, including a PSF that differs from the average one, plus noise
amplified by the filter), and its expected PSNR ``-10 log10 MSE_d`` (signal range 1).  The
residuals for :func:`~.lensopt.optimize_lens` are ``(MSE_d / mse_ref)^(p/2)``: their sum of
squares is the ``p``-th power of the ``p``-norm of the per-depth errors, a soft maximum that
weights the worst depth (``p = 4``: a depth 2 dB worse counts 6.3 times as much).

The object spectrum ``S(f) = c / (|f|² + f0²)`` (``S(0) = 0``: the image mean is not a
deconvolution's problem) is the 1/f² law of natural images and of the dead-leaves textures
the camera trains on; ``c = 1e-3`` is their measured level (96 training textures, 128 px,
Hann-windowed periodogram: ``P(f) |f|²`` of 0.5e-3 to 1.4e-3 over 0.01-0.7 cycles per pixel,
pixel variance 0.0245 against ``c 2π ln(N/2) = 0.026`` for this law), and the law is invariant
under the texture-to-sensor rescaling.  ``σ² = m / full_well + read_noise²`` is the sensor's
noise (:class:`~deeplens.render.sensor.Sensor`: shot noise at the textures' mean level
``m = 0.36``, plus read noise).

PSFs: ``"diffraction"`` (:func:`~deeplens.render.diffraction.diffraction_psf_many`, the model
``render.psf_model=auto`` picks for the EDOF experiment at 6.9 µm pixels) on a sampling chosen
by :meth:`RestorationMerit.prepare` for the lens as it is then (with finer pupil steps and a
larger energy fraction than rendering's, so that a nearby plate is still well sampled), or
``"geometric"`` (:func:`~deeplens.render.psf.psf_many`, a square pupil grid).  Both are
differentiable in the lens parameters, with a sampling fixed between calls.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..optics.camera import unpack
from ..render.diffraction import DiffractionSampling, choose_sampling, diffraction_psf_many
from ..render.psf import psf_many

__all__ = ["RestorationMerit", "object_spectrum", "SPECTRUM_LEVEL", "TEXTURE_MEAN"]

#: ``c`` of the object spectrum ``c / (|f|² + f0²)`` (per pixel, f in cycles per pixel):
#: the training textures' measured level (module docstring)
SPECTRUM_LEVEL = 1e-3
#: the training textures' mean level (signal units, 1 = full well): the shot noise's
TEXTURE_MEAN = 0.36
MODELS = ("diffraction", "geometric")


def object_spectrum(n: int, level: float = SPECTRUM_LEVEL, f0: float | None = None,
                    dtype=torch.float64) -> torch.Tensor:
    """``(n, n)`` power spectrum ``level / (|f|² + f0²)`` on the ``fft2`` grid of an ``n x n``
    image (``f`` in cycles per pixel), 0 at ``f = 0``; ``f0`` defaults to ``1 / n``."""
    if not (isinstance(n, int) and n >= 2):
        raise ValueError(f"restoration merit: the FFT size must be an integer >= 2, got {n!r}")
    f0 = 1.0 / n if f0 is None else float(f0)
    f = torch.fft.fftfreq(n, dtype=dtype)
    r2 = f[:, None] ** 2 + f[None, :] ** 2
    S = level / (r2 + f0 * f0)
    S[0, 0] = 0.0
    return S


class RestorationMerit:
    """Expected restoration error of the depth-averaged Wiener filter (module docstring).

    Args:
        depths_mm: object depths (mm from the first vertex), at least one; the filter averages
            over them and every depth gets its own error.
        sensor: the :class:`~deeplens.render.sensor.Sensor` (channels, wavelengths, pixel pitch,
            noise); or pass a :class:`~deeplens.optics.camera.Camera` to the methods and
            ``None`` here.
        psf_model: ``"diffraction"`` or ``"geometric"``.
        size: FFT grid side ``N`` (pixels); kernels are padded to it (``K < N``).
        noise_var: white noise variance per pixel (signal units); ``None``: the sensor's,
            ``mean_level / full_well + read_noise²``.
        mean_level: the scene's mean signal for the shot noise (``noise_var=None``).
        spectrum_level: ``c`` of :func:`object_spectrum`.
        power: ``p`` of the soft maximum over depths (``>= 1``; 1: the mean error).
        mse_ref: error scale of the residuals (30 dB: 1e-3).
        rays: rays per geometric PSF (a square grid).
        max_step_waves, energy: the diffraction sampling's (:func:`choose_sampling`), finer
            than rendering's (0.25 wave, 99.5 %) for a margin as the plate moves.
        max_kernel: largest kernel (odd, ``< size``).
    """

    def __init__(self, depths_mm, sensor=None, psf_model: str = "diffraction", size: int = 128,
                 noise_var: float | None = None, mean_level: float = TEXTURE_MEAN,
                 spectrum_level: float = SPECTRUM_LEVEL, power: float = 4.0,
                 mse_ref: float = 1e-3, rays: int = 4096, max_step_waves: float = 0.125,
                 energy: float = 0.999, max_kernel: int = 63):
        self.depths = [float(d) for d in depths_mm]
        if not self.depths or not all(d > 0 and math.isfinite(d) for d in self.depths):
            raise ValueError(f"restoration merit: need finite depths > 0 mm, got "
                             f"{list(depths_mm)}")
        if psf_model not in MODELS:
            raise ValueError(f"restoration merit: psf_model must be one of {', '.join(MODELS)}, "
                             f"got {psf_model!r}")
        if not (isinstance(size, int) and size >= 8):
            raise ValueError(f"restoration merit: size must be an integer >= 8, got {size!r}")
        if not (isinstance(max_kernel, int) and max_kernel % 2 == 1 and max_kernel < size):
            raise ValueError(f"restoration merit: max_kernel must be odd and < size ({size}), "
                             f"got {max_kernel!r}")
        for name, v in (("power", power), ("mse_ref", mse_ref), ("spectrum_level",
                                                                 spectrum_level)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"restoration merit: {name} must be > 0, got {v!r}")
        if power < 1:
            raise ValueError(f"restoration merit: power must be >= 1, got {power!r}")
        if noise_var is not None and not (math.isfinite(noise_var) and noise_var >= 0):
            raise ValueError(f"restoration merit: noise_var must be >= 0, got {noise_var!r}")
        self.sensor, self.psf_model, self.size = sensor, psf_model, int(size)
        self.noise_var_given, self.mean_level = noise_var, float(mean_level)
        self.spectrum_level, self.power, self.mse_ref = (float(spectrum_level), float(power),
                                                         float(mse_ref))
        self.rays, self.max_step_waves, self.energy = int(rays), max_step_waves, energy
        self.max_kernel = max_kernel
        self.sampling: DiffractionSampling | None = None
        self.kernel: int | None = None

    # ------------------------------------------------------------------ set-up
    def noise_var(self, sensor) -> float:
        """``σ²`` per pixel (module docstring)."""
        if self.noise_var_given is not None:
            return float(self.noise_var_given)
        shot = self.mean_level / sensor.full_well if sensor.full_well > 0 else 0.0
        return shot + sensor.read_noise ** 2

    def _unpack(self, lens):
        lens, sensor, options = unpack(lens, self.sensor, None, "RestorationMerit")
        if sensor is None:
            raise ValueError("RestorationMerit: needs a sensor (given here or by a Camera)")
        return lens, sensor, options

    def _specs(self, sensor):
        jobs = sensor.wavelengths_for(len(sensor.channels))
        return [(d, c, wl, w) for d in self.depths for c, wl, w in jobs]

    def prepare(self, lens) -> "RestorationMerit":
        """Fix the PSFs' sampling (diffraction: pupil samples, kernel, pixel points; geometric:
        the kernel size) for ``lens`` as it is now."""
        lens_, sensor, options = self._unpack(lens)
        specs = self._specs(sensor)
        pts = [((0.0, 0.0), d, wl) for d, _, wl, _ in specs]
        with torch.no_grad():
            if self.psf_model == "diffraction":
                self.sampling = choose_sampling(lens_, sensor, pts, options,
                                                max_step_waves=self.max_step_waves,
                                                energy=self.energy, max_kernel=self.max_kernel)
                self.kernel = self.sampling.kernel
            else:
                n = max(int(round(math.sqrt(self.rays))), 8)
                kers = psf_many(lens_, sensor, pts, n_rays=n * n, sampling=f"grid:{n}",
                                max_kernel=self.max_kernel, options=options)
                self.kernel = max(k.shape[-1] for k in kers)
        return self

    # ------------------------------------------------------------------ the merit
    def psfs(self, lens) -> torch.Tensor:
        """On-axis PSFs ``(D, C, K, K)`` per depth and sensor channel (each channel the weighted
        mean of its wavelengths' kernels), differentiable in the lens."""
        if self.kernel is None:
            raise RuntimeError("RestorationMerit.prepare(lens) must be called first")
        lens_, sensor, options = self._unpack(lens)
        specs = self._specs(sensor)
        pts = [((0.0, 0.0), d, wl) for d, _, wl, _ in specs]
        if self.psf_model == "diffraction":
            kers = diffraction_psf_many(lens_, sensor, pts, self.sampling, options=options)
        else:
            n = max(int(round(math.sqrt(self.rays))), 8)
            kers = psf_many(lens_, sensor, pts, n_rays=n * n, sampling=f"grid:{n}",
                            kernel_size=self.kernel, options=options)
        C = len(sensor.channels)
        rows = []
        for di in range(len(self.depths)):
            acc = [0.0] * C
            wsum = [0.0] * C
            for (d, c, _, w), k in zip(specs, kers):
                if d != self.depths[di]:
                    continue
                acc[c] = acc[c] + w * k
                wsum[c] += w
            rows.append(torch.stack([a / s for a, s in zip(acc, wsum)]))
        return torch.stack(rows)

    def otfs(self, lens) -> torch.Tensor:
        """OTFs ``(D, C, N, N)`` (complex) of :meth:`psfs`, the kernel centre at the origin."""
        k = self.psfs(lens)
        K, N = k.shape[-1], self.size
        if K >= N:
            raise ValueError(f"restoration merit: kernel of {K} px does not fit the FFT grid of "
                             f"{N} px (raise size)")
        pad = F.pad(k, (0, N - K, 0, N - K))
        pad = torch.roll(pad, shifts=(-(K // 2), -(K // 2)), dims=(-2, -1))
        return torch.fft.fft2(pad)

    def mse(self, lens) -> torch.Tensor:
        """Expected squared error per pixel ``(D,)`` of the MMSE depth-averaged Wiener filter at
        each depth (module docstring), averaged over channels; differentiable."""
        _, sensor, _ = self._unpack(lens)
        H = self.otfs(lens)
        S = object_spectrum(self.size, self.spectrum_level, dtype=H.real.dtype).to(H.real.device)
        s2 = self.noise_var(sensor)
        h2 = (H.real ** 2 + H.imag ** 2)
        # S = 0 at f = 0: without noise the ratio is 0 / 0 there; the filter passes 0 (nothing
        # to restore), and the clamp keeps the gradient finite (its numerator's is 0 too)
        den = (h2.mean(0) * S + s2).clamp_min(torch.finfo(S.dtype).tiny)
        G = H.conj().mean(0) * S / den                              # (C, N, N)
        E = G[None] * H - 1
        err = (E.real ** 2 + E.imag ** 2) * S + (G.real ** 2 + G.imag ** 2)[None] * s2
        return err.mean(dim=(1, 2, 3))

    def psnr(self, lens) -> torch.Tensor:
        """Expected PSNR (dB, signal range 1) ``(D,)`` per depth."""
        return -10 * torch.log10(self.mse(lens))

    def residuals(self, lens) -> torch.Tensor:
        """``(MSE_d / mse_ref)^(p/2)``, ``(D,)``."""
        return (self.mse(lens) / self.mse_ref) ** (self.power / 2)

    def score(self, lens) -> tuple[float, float]:
        """``(sum of squared residuals, worst-depth expected PSNR in dB)`` of ``lens``, no
        gradient."""
        with torch.no_grad():
            m = self.mse(lens)
            r = (m / self.mse_ref) ** (self.power / 2)
            return float((r * r).sum()), float(-10 * torch.log10(m.max()))
