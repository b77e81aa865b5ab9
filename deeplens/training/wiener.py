"""A PSF-aware front end for the restorer: the depth-averaged Wiener filter of the lens.

The restorer of an end-to-end camera does not know the optics.  A coded PSF (a cubic phase
plate spreads light over 3-11 pixels) is a large, known blur that a small U-Net trained for a
few hundred steps undoes only partly.  This module deconvolves the sensor image with the
optics' own PSFs first, and the network restores what is left (Sitzmann et al. 2018, the
paper's ref. [10], feed the restorer a Wiener-deconvolved image in the same way)::

    x̃ = F⁻¹[ G · F[y] ],   G(f) = E_d[conj H_d(f)] / (E_d[|H_d(f)|²] + nsr_c)

``H_d`` is the optical transfer function of the on-axis PSF at depth ``d``, for ``depths``
depths spaced uniformly in 1/depth over the training range (the depth distribution training
samples from), and ``E_d`` their mean.  ``G`` is the linear filter of least mean square error
when the depth is unknown and uniform in 1/depth and the noise-to-signal power ratio is
``nsr_c``: for a depth-invariant PSF (a strong cubic plate) it is the ordinary Wiener filter of
that PSF, for a PSF that changes with depth (no plate) it restores only the frequencies every
depth passes.  The filter is a function of the lens, so a learned plate's gradient includes
how it changes the deconvolution (the PSFs are traced with gradients), and ``nsr`` (one per
sensor channel) is learned with the network.

The image is extended by mirroring by half its size on every side before the FFT and cropped
back, so the filter's circular boundary does not wrap one edge's content onto the other.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ..optics.camera import Camera, HoldsCamera, as_camera
from ..optics.errors import ConfigError
from ..render.psf import psf_many

__all__ = ["Deconvolution", "DepthWienerFilter", "check_deconvolution", "depth_change",
           "nsr_range"]


@dataclass(frozen=True)
class Deconvolution:
    """The settings of :class:`DepthWienerFilter` (``model.deconvolution``) and their defaults,
    the filter's own: checked by :func:`check_deconvolution`; the run key completes a setting
    given in part with them (:mod:`deeplens.training.settings`)."""

    depths: int = 5
    rays: int = 16384
    nsr: float = 1e-2
    learn_nsr: bool = True


def nsr_range(dtype: torch.dtype) -> tuple[float, float]:
    """The noise-to-signal ratios ``(lo, hi)`` the filter can hold in ``dtype``:
    ``sqrt(tiny) .. sqrt(max)`` (float32: 1.1e-19 .. 1.8e19), so that ``nsr`` itself and the
    square ``(|H|^2 + nsr)^2`` of its derivative stay finite normal numbers (outside, float32's
    ``exp(log_nsr)`` is 0 or inf and the gradient 0 or NaN; issue 25, item 11)."""
    fi = torch.finfo(dtype)
    return math.sqrt(fi.tiny), math.sqrt(fi.max)


class DepthWienerFilter(HoldsCamera, nn.Module):
    """``(B, C, H, W) -> (B, C, H, W)``: the depth-averaged Wiener deconvolution of the lens.

    Args:
        lens: the :class:`~deeplens.optics.camera.Camera` (held by reference, not registered:
            the end-to-end module owns it), whose ``options`` every PSF trace reads when it
            runs; or, the older form, a lens with ``sensor`` and ``options``.
        sensor: with a lens, the sensor; with a camera, ``None``.
        depths_mm: ``[near, far]`` depth range (mm) or one depth.
        depths: number of depths averaged (uniform in 1/depth, both ends included; >= 1).
        rays: rays per PSF (a square grid over the entrance pupil, deterministic).
        nsr: initial noise-to-signal power ratio (> 0), one per channel, learned in log space.
        learn_nsr: whether ``nsr`` is a trainable parameter.
        psf_model: the run's :class:`~deeplens.render.psf_model.PSFModel` (``None``:
            geometric PSFs), shared with the renderer.
        options: with a lens, the :class:`~deeplens.optics.options.TraceOptions` of the
            camera built (``None``: the defaults); with a camera, ``None`` (the camera's).
    """

    def __init__(self, lens: Camera, sensor=None, depths_mm=None,
                 depths: int = Deconvolution.depths, rays: int = Deconvolution.rays,
                 nsr: float = Deconvolution.nsr, learn_nsr: bool = Deconvolution.learn_nsr,
                 psf_model=None,
                 options=None):
        super().__init__()
        camera = as_camera(lens, sensor, options, "DepthWienerFilter")
        if camera.sensor is None or depths_mm is None:
            raise ValueError("DepthWienerFilter: needs a camera with a sensor and depths_mm")
        lens, sensor = camera.lens, camera.sensor
        self.psf_model = psf_model
        check_deconvolution({"depths": depths, "rays": rays, "nsr": nsr}, lens.dtype)
        self._held = (camera,)  # a tuple: not registered (the end-to-end module owns it)
        lo, hi = min(depths_mm), max(depths_mm)
        if depths == 1 or lo == hi:  # the dioptric middle of the range
            self.depths_mm = [2 / (1 / lo + 1 / hi)]
        else:  # uniform in 1/depth, far to near
            self.depths_mm = [1 / (1 / hi + k / (depths - 1) * (1 / lo - 1 / hi))
                              for k in range(depths)]
        self.rays = int(rays)
        C = len(sensor.channels)
        # float32 for a float32 lens (the training default), float64 for a float64 lens
        log_nsr = torch.full((C,), math.log(nsr), dtype=lens.dtype)
        if learn_nsr:
            self.log_nsr = nn.Parameter(log_nsr)
        else:
            self.register_buffer("log_nsr", log_nsr)
        self._cache = None  # (key, (mean conj H, mean |H|^2)) of a lens that is not training


    # ------------------------------------------------------------------ the optics
    def psfs(self, size) -> torch.Tensor:
        """On-axis PSFs ``(D, C, K, K)`` per depth and sensor channel (``K`` odd, smaller than
        both sides of ``size = (Hs, Ws)``), differentiable in the lens."""
        cam = self.camera
        lens, sensor, options = cam.lens, cam.sensor, cam.options
        n = max(int(round(math.sqrt(self.rays))), 8)
        jobs = sensor.wavelengths_for(len(sensor.channels))
        specs = [(d, c, wl, w) for d in self.depths_mm for c, wl, w in jobs]
        pts = [((0.0, 0.0), d, wl) for d, _, wl, _ in specs]
        model = ("geometric" if self.psf_model is None
                 else self.psf_model.resolve(lens, sensor, options))
        if model == "diffraction":
            kers = self.psf_model.diffraction(lens, sensor, pts, options,
                                              max_kernel=min(size) - 1)
        else:
            kers = psf_many(lens, sensor, pts, n_rays=n * n, sampling=f"grid:{n}",
                            max_kernel=min(size) - 1, options=options)
        out = []
        for k0 in range(0, len(specs), len(jobs)):
            per = {}
            for (_, c, _, w), k in zip(specs[k0:k0 + len(jobs)], kers[k0:k0 + len(jobs)]):
                per.setdefault(c, []).append((k, w))
            out.append(per)
        K = max(k.shape[-1] for per in out for ks in per.values() for k, _ in ks)
        rows = []
        for per in out:
            chans = []
            for c in range(len(sensor.channels)):
                acc, wsum = 0, 0.0
                for k, w in per[c]:
                    p = (K - k.shape[-1]) // 2
                    acc = acc + w * F.pad(k, (p, p, p, p))
                    wsum += w
                chans.append(acc / wsum)
            rows.append(torch.stack(chans))
        return torch.stack(rows)

    def otf_moments(self, size):
        """``(E_d conj H, E_d |H|^2)``, each ``(C, Hs, Ws // 2 + 1)``, for an FFT of
        ``size = (Hs, Ws)``; cached while no lens parameter changes or trains."""
        lens = self.camera.lens
        params = list(lens.parameters())
        training = torch.is_grad_enabled() and any(p.requires_grad for p in params)
        key = (tuple(size), tuple((p.data_ptr(), p._version) for p in params))
        if not training and self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        k = self.psfs(size)  # (D, C, K, K)
        K = k.shape[-1]
        Hs, Ws = size
        pad = F.pad(k, (0, Ws - K, 0, Hs - K))
        # the kernel's centre (index K // 2) to the origin
        pad = torch.roll(pad, shifts=(-(K // 2), -(K // 2)), dims=(-2, -1))
        H = torch.fft.rfft2(pad)
        moments = (H.conj().mean(0), (H.abs() ** 2).mean(0))
        if not training:
            self._cache = (key, tuple(m.detach() for m in moments))
        return moments

    def nsr(self) -> torch.Tensor:
        """The noise-to-signal power ratio ``(C,)`` per channel, kept inside
        :func:`nsr_range` of its dtype (a learned value that drifts out stops there)."""
        lo, hi = nsr_range(self.log_nsr.dtype)
        return self.log_nsr.clamp(math.log(lo), math.log(hi)).exp()

    # ------------------------------------------------------------------ the filter
    def forward(self, y: torch.Tensor, return_moments: bool = False):
        """The deconvolved image ``(B, C, H, W)`` of the sensor image ``y``; with
        ``return_moments`` also the OTF moments it used (:meth:`otf_moments`), e.g. for
        :func:`depth_change` in the same graph."""
        B, C, Hh, Ww = y.shape
        ph, pw = Hh // 2, Ww // 2
        ext = F.pad(y, (pw, pw, ph, ph), mode="reflect" if min(Hh, Ww) > 1 else "replicate")
        size = (Hh + 2 * ph, Ww + 2 * pw)
        ch, h2 = self.otf_moments(size)
        G = ch / (h2 + self.nsr().to(h2.dtype)[:, None, None])
        x = torch.fft.irfft2(torch.fft.rfft2(ext.to(h2.dtype)) * G, s=size)
        x = x[..., ph:ph + Hh, pw:pw + Ww].to(y.dtype)
        return (x, (ch, h2)) if return_moments else x


def depth_change(ch: torch.Tensor, h2: torch.Tensor) -> torch.Tensor:
    """The fraction of the OTF's power that changes with depth, from the moments of
    :meth:`DepthWienerFilter.otf_moments` (``ch = E_d conj H_d``, ``h2 = E_d |H_d|^2``, each
    ``(C, Hs, Ws // 2 + 1)``):

        R = Σ_{c,f} (E_d |H_d(f)|^2 - |E_d H_d(f)|^2) / Σ_{c,f} E_d |H_d(f)|^2,

    the depth variance of the OTF summed over channels and the rfft half-plane of
    frequencies, over its power.  ``R`` is in ``[0, 1]``: 0 when the PSF is the same at every
    depth (a depth-invariant camera), and it does not fall merely because the PSF widens (both
    sums shrink with the OTF).  Differentiable in the lens through the moments; a scalar."""
    var = (h2 - ch.abs() ** 2).sum()
    return var / h2.sum()


def check_deconvolution(settings: dict, dtype: torch.dtype | None = None) -> None:
    """``model.deconvolution`` (the keywords of :class:`DepthWienerFilter`) checked: known keys
    only (the fields of :class:`Deconvolution`), ``depths`` an int >= 1, ``rays`` an int >= 64, ``nsr`` a number
    > 0 (within :func:`nsr_range` of ``dtype``, the lens's, when given), ``learn_nsr`` a bool;
    else
    :class:`~deeplens.optics.errors.ConfigError` naming ``model.deconvolution.<key>``."""
    known = {f.name: f.default for f in dataclasses.fields(Deconvolution)}
    unknown = set(settings) - set(known)
    if unknown:
        raise ConfigError.unknown("model.deconvolution", unknown, known)
    s = {**known, **settings}
    depths, rays, nsr = s["depths"], s["rays"], s["nsr"]
    if not (isinstance(depths, int) and not isinstance(depths, bool) and depths >= 1):
        raise ConfigError("model.deconvolution.depths", "an integer >= 1", depths)
    if not (isinstance(rays, int) and not isinstance(rays, bool) and rays >= 64):
        raise ConfigError("model.deconvolution.rays", "an integer >= 64", rays)
    if not (isinstance(nsr, (int, float)) and not isinstance(nsr, bool) and math.isfinite(nsr)
            and nsr > 0):
        raise ConfigError("model.deconvolution.nsr", "a number > 0", nsr)
    if not isinstance(s["learn_nsr"], bool):
        raise ConfigError("model.deconvolution.learn_nsr", "true or false", s["learn_nsr"])
    if dtype is not None:
        lo, hi = nsr_range(dtype)
        if not lo <= nsr <= hi:
            raise ConfigError("model.deconvolution.nsr", f"a number in the range a "
                              f"{str(dtype).removeprefix('torch.')} lens can hold "
                              f"({lo:.3g} .. {hi:.3g})", nsr)
