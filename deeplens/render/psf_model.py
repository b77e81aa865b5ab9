"""Which PSF a run renders with: ``geometric`` (rays), ``diffraction`` (wave optics) or ``auto``.

``auto`` measures, on the run's own pixels, depths, wavelengths and fields, the energy the
geometric PSF puts in the wrong pixels relative to the diffraction PSF: the total-variation
distance ``TV = ½ Σ |P_geo - P_diff|`` of the two kernels on the sensor's pixels (both around
the ideal image point and integrated over each pixel; the geometric one counts ``n_rays``
rays of a pupil grid per pixel, :func:`binned_geometric_psf`), its mean
over the jobs (the fraction of the image's energy misplaced; the worst job is reported too),
and takes the cheaper model (geometric) when that is within ``error_budget``
(default 0.05: 5 % of the energy), else diffraction.  A job whose wavefront is too steep to
sample (:class:`~.diffraction.PupilSamplingError`) is in the geometric regime and counts as 0,
and so does one much sharper than a pixel whose pupil grid would be too large
(:class:`~.diffraction.PixelSamplingError`; the message says which).
It measures again when a group of lens parameters (one tensor, or one list such as a plate's
coefficients) has moved by more than ``remeasure`` of its own norm since the last measurement.

:class:`PSFModel` also keeps the diffraction sampling (:func:`~.diffraction.choose_sampling`)
of the run's jobs and widens it when a later trace finds it too coarse.
"""

from __future__ import annotations

import logging
import math

import torch

from .diffraction import (DiffractionSampling, PixelSamplingError, PupilSamplingError,
                          choose_sampling, diffraction_psf_many)
from ..optics.camera import unpack
from ..optics.errors import ConfigError
from .psf import _job_offsets

__all__ = ["PSFModel", "MODELS", "tv_distance", "run_jobs"]

MODELS = ("geometric", "diffraction", "auto")
log = logging.getLogger(__name__)


def tv_distance(a: torch.Tensor, b: torch.Tensor) -> float:
    """``½ Σ |a - b|`` of two centred kernels, the smaller zero-padded to the larger."""
    K = max(a.shape[-1], b.shape[-1])
    pa, pb = (K - a.shape[-1]) // 2, (K - b.shape[-1]) // 2
    a = torch.nn.functional.pad(a.detach(), (pa, pa, pa, pa))
    b = torch.nn.functional.pad(b.detach(), (pb, pb, pb, pb))
    return 0.5 * float((a - b).abs().sum())


def _groups(lens) -> dict:
    """The lens's parameters grouped by owner (``surfaces.4.a.0``, ``surfaces.4.a.1``, ... ->
    ``surfaces.4.a``), each group one detached vector: a coefficient that starts at zero moves
    relative to its group, not to itself."""
    out = {}
    for name, p in lens.named_parameters():
        parts = name.split(".")
        key = ".".join(parts[:-1]) if parts[-1].isdigit() else name
        out.setdefault(key, []).append(p.detach().reshape(-1).double().clone())
    return {k: torch.cat(v) for k, v in out.items()}


def binned_geometric_psf(lens, sensor, job, n: int, K: int, options=None) -> torch.Tensor:
    """The geometric PSF ``(K, K)`` with the same pixel filter as the diffraction kernel (the
    rays of an ``n x n`` pupil grid counted in the pixel they land in, not splatted
    bilinearly), summing to 1: the comparison measures diffraction, not the splat."""
    di, dj, valid = _job_offsets(lens, sensor, [job], n * n, 0, options, f"grid:{n}")[0]
    i = torch.floor(di + K / 2).long()
    j = torch.floor(dj + K / 2).long()
    ok = valid & (i >= 0) & (i < K) & (j >= 0) & (j < K)
    h = torch.bincount((i * K + j)[ok], minlength=K * K).to(torch.float64)
    return (h / max(int(valid.sum()), 1)).reshape(K, K)


def run_jobs(lens, sensor, depths_mm, grid=(1, 1), depths: int = 5):
    """The PSF jobs of a run: ``depths`` depths uniform in 1/depth over ``[min, max]`` of
    ``depths_mm`` (both ends), every sensor wavelength, the centres of a ``grid`` of field
    patches (:func:`~deeplens.render.psf.psf_grids`)."""
    from .psf import _grid_points
    from .scene import IdealCamera

    lo, hi = min(depths_mm), max(depths_mm)
    ds = ([lo] if lo == hi or depths == 1 else
          [1 / (1 / hi + k / (depths - 1) * (1 / lo - 1 / hi)) for k in range(depths)])
    camera = IdealCamera(lens, sensor)
    waves = sorted({w for ch in sensor.channels for w in ch})
    return [(P, d, w) for d in ds for w in waves for P in _grid_points(camera, d, grid)[0]]


class PSFModel:
    """The PSF model of a run (config ``render.psf_model``, ``render.psf_error_budget``, ...).

    Args:
        model: ``"geometric"``, ``"diffraction"`` or ``"auto"``.
        error_budget: the largest misplaced energy fraction ``auto`` accepts from the geometric
            model (0 < budget < 1).
        remeasure: relative parameter change that triggers a new measurement (``auto``).
        memory_gb: memory the diffraction PSFs of one call may take (error beyond).
        max_kernel: largest kernel (odd).
        n_rays: rays per geometric PSF in the measurement (a square pupil grid).
    """

    def __init__(self, model: str = "auto", error_budget: float = 0.05, remeasure: float = 0.1,
                 memory_gb: float = 2.0, max_kernel: int = 129, n_rays: int = 16384):
        if model not in MODELS:
            raise ConfigError("render.psf_model", f"one of {', '.join(MODELS)}", model)
        if not (0 < float(error_budget) < 1):
            raise ConfigError("render.psf_error_budget", "a fraction in (0, 1)", error_budget)
        if not float(remeasure) > 0:
            raise ConfigError("render.psf_remeasure", "a number > 0", remeasure)
        self.model, self.error_budget = model, float(error_budget)
        self.remeasure, self.memory_gb = float(remeasure), float(memory_gb)
        self.max_kernel, self.n_rays = int(max_kernel), int(n_rays)
        self.choice = None if model == "auto" else model
        self.error = None          # measured mean TV over the jobs
        self.worst = None          # and its maximum
        self.sampling = None       # DiffractionSampling of the run's jobs
        self.jobs = None           # the measured jobs
        self._params = None        # lens parameters where it measured
        self.cache = {}            # diffraction_psf_many's cache (the OPD fit per pupil mask)
        self.message = f"PSF model: {model} (not measured)"

    # ------------------------------------------------------------------ measurement
    def measure(self, lens, sensor, jobs, options=None) -> str:
        """Measure the geometric model's error on ``jobs`` and (``auto``) choose; returns the
        sentence stating the choice, the measured error and the budget.  ``lens`` may be a
        :class:`~deeplens.optics.camera.Camera` (``sensor`` ``None``: its options trace)."""
        lens, sensor, options = unpack(lens, sensor, options, "PSFModel.measure")
        jobs = [(tuple(float(v) for v in p), float(d), float(w)) for p, d, w in jobs]
        self.jobs = jobs
        errs, steep, sharp = [], 0, 0
        n = max(int(round(math.sqrt(self.n_rays))), 8)
        with torch.no_grad():
            for job in jobs:
                try:
                    smp = choose_sampling(lens, sensor, [job], options,
                                          max_kernel=self.max_kernel,
                                          memory_limit_gb=self.memory_gb, cache=self.cache)
                except PixelSamplingError:   # sharper than a pixel: a sampling limit
                    sharp += 1
                    errs.append(0.0)
                    continue
                except PupilSamplingError:
                    steep += 1
                    errs.append(0.0)
                    continue
                self._widen(smp)
                d = diffraction_psf_many(lens, sensor, [job], smp, options=options,
                                         cache=self.cache)[0]
                g = binned_geometric_psf(lens, sensor, job, n, smp.kernel, options)
                errs.append(tv_distance(g, d))
        self.error = sum(errs) / len(errs)
        self.worst = max(errs)
        self._params = _groups(lens)
        if self.model == "auto":
            self.choice = "geometric" if self.error <= self.error_budget else "diffraction"
        msg = (f"PSF model: {self.choice} ({'auto: ' if self.model == 'auto' else ''}the "
               f"geometric PSF misplaces {100 * self.error:.1f} % of the energy on average "
               f"(worst {100 * self.worst:.1f} %) over {len(jobs)} PSFs at "
               f"{sensor.pixel_size_mm * 1e3:.3g} um pixels; budget "
               f"{100 * self.error_budget:.1f} %"
               + (f"; {steep} too aberrated to sample, geometric" if steep else "")
               + (f"; {sharp} much sharper than a pixel, geometric" if sharp else "") + ")")
        self.message = msg     # printed once by the caller (train.build_psf_model)
        return msg

    def _widen(self, smp: DiffractionSampling):
        s = self.sampling
        self.sampling = smp if s is None else DiffractionSampling(
            max(s.pupil, smp.pupil), max(s.kernel, smp.kernel), max(s.sub, smp.sub))

    def moved(self, lens) -> bool:
        """Whether a lens parameter moved by more than ``remeasure`` since the measurement."""
        if self._params is None:
            return False
        now = _groups(lens)
        for name, p0 in self._params.items():
            ref = float(p0.norm())
            # the snapshot stays where it was taken (set-up runs before the module moves to
            # its device): compare on the lens's device
            if ref > 0 and float((now[name] - p0.to(now[name].device)).norm()) > \
                    self.remeasure * ref:
                return True
        return False

    def resolve(self, lens, sensor, options=None) -> str:
        """The model to use now (re-measuring ``auto`` when the lens moved far); ``lens`` as
        for :meth:`measure`."""
        lens, sensor, options = unpack(lens, sensor, options, "PSFModel.resolve")
        if self.model == "auto" and self.jobs is not None and self.moved(lens):
            before = self.choice
            self.measure(lens, sensor, self.jobs, options)
            log.info(f"PSF model re-measured (the lens moved): {before} -> {self.choice}")
        if self.choice is None:
            raise RuntimeError("render.psf_model=auto: measure() was not called at set-up")
        return self.choice

    # ------------------------------------------------------------------ kernels
    def diffraction(self, lens, sensor, jobs, options=None, max_kernel: int | None = None):
        """Diffraction kernels of ``jobs`` (one shared size), widening the sampling when this
        trace finds it too coarse; ``lens`` as for :meth:`measure`."""
        lens, sensor, options = unpack(lens, sensor, options, "PSFModel.diffraction")
        mk = self.max_kernel if max_kernel is None else min(self.max_kernel, max_kernel)
        if self.sampling is None:
            self.sampling = choose_sampling(lens, sensor, jobs, options, max_kernel=mk,
                                            memory_limit_gb=self.memory_gb, cache=self.cache)
        smp = self.sampling
        if smp.kernel > (mk | 1):
            smp = DiffractionSampling(smp.pupil, mk | 1 if mk % 2 else mk - 1, smp.sub)
        kers, info = diffraction_psf_many(lens, sensor, jobs, smp, options=options,
                                          return_info=True, cache=self.cache)
        if info["max_step_waves"] > 0.5 or (info["energy"] < 0.99 and smp.kernel < (mk | 1)):
            with torch.no_grad():
                self._widen(choose_sampling(lens, sensor, jobs, options, max_kernel=mk,
                                            memory_limit_gb=self.memory_gb, cache=self.cache))
            log.info(f"diffraction sampling widened to {self.sampling}")
            return self.diffraction(lens, sensor, jobs, options, max_kernel)
        return kers
