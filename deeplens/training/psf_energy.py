"""An optics-only loss term: the share of each field's light that lands in its own pixel
(``model.optics_psf_energy``).

For an object point whose *ideal* image (:class:`~deeplens.render.scene.IdealCamera`: the
framing the restored image is scored against) lies at fractional pixel ``(i0, j0)``, the
point-source rays are traced to the sensor by the same forward trace as the PSFs of
:mod:`deeplens.render.psf`, and their hits ``(i, j)`` are weighted with the bilinear splat's
tent about the ideal image::

    E = sum_rays valid * relu(1 - |i - i0|) * relu(1 - |j - j0|) / sum_rays valid

``E`` is the centre value of the bilinear-splatted PSF kernel centred on the ideal image (a
perfect lens: ``E = 1``; light spread over a pixel or more, shifted by distortion or lateral
colour: ``E -> 0``), differentiable in the lens almost everywhere (the tent is piecewise linear;
a ray farther than a pixel from ``(i0, j0)`` carries no gradient).  The loss is
``weight * mean(1 - E)`` over the points and the sensor's wavelengths (every wavelength of every
channel, equally weighted).  The points lie on the sensor's diagonal at ``fields`` (fractions of
the half-diagonal: the radius ``rho`` of :func:`~deeplens.training.metrics.band_masks`, so
``[0.7, 0.85, 1.0]`` samples the edge band 0.66-1), at the module's validation depths.

It sees only the optics: the restorer's parameters do not enter it, so adding it to the joint
loss changes the lens's gradient and nothing of the restorer's (a run with frozen optics is
unchanged).  Settings: :class:`PsfEnergy`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..optics.camera import unpack
from ..optics.errors import ConfigError
from ..optics.rays import Rays
from ..optics.sampling import entrance_pupil, parse_sampling, point_source_rays
from ..render.splat import trace_to_sensor_pixels

__all__ = ["PsfEnergy", "pixel_energy", "psf_energy_loss"]


@dataclass(frozen=True)
class PsfEnergy:
    """``model.optics_psf_energy``: ``weight * mean(1 - E)`` added to the loss while the
    optics train (module docstring).

    Attributes:
        weight: a finite number > 0.
        fields: fractions of the sensor's half-diagonal in ``[0, 1]`` (points on the diagonal).
        sampling: the pupil sampling of each point's rays (a pattern such as
            ``"hexapolar:8"``; deterministic, so the term is a smooth function of the lens).
    """

    weight: float = 1.0
    fields: tuple = (0.7, 0.85, 1.0)
    sampling: str = "hexapolar:8"

    @classmethod
    def from_config(cls, value) -> PsfEnergy | None:
        """``model.optics_psf_energy`` checked: ``None``, or a mapping of known keys completed
        with the defaults; else :class:`ConfigError` naming ``model.optics_psf_energy[.<key>]``."""
        if value is None:
            return None
        key = "model.optics_psf_energy"
        if not isinstance(value, dict):
            raise ConfigError(key, "null or a mapping {weight, fields, sampling}", value)
        known = {"weight": cls.weight, "fields": cls.fields, "sampling": cls.sampling}
        unknown = set(value) - set(known)
        if unknown:
            raise ConfigError.unknown(key, unknown, known)
        s = {**known, **value}
        w = s["weight"]
        if not (isinstance(w, (int, float)) and not isinstance(w, bool) and math.isfinite(w)
                and w > 0):
            raise ConfigError(f"{key}.weight", "a finite number > 0", w)
        f = s["fields"]
        ok = (isinstance(f, (list, tuple)) and len(f) > 0
              and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                      and 0 <= v <= 1 for v in f))
        if not ok:
            raise ConfigError(f"{key}.fields", "a non-empty list of fractions of the sensor's "
                              "half-diagonal in [0, 1]", f)
        smp = s["sampling"]
        try:
            kind = parse_sampling(smp)[0] if isinstance(smp, str) else None
        except ValueError:
            kind = None
        if kind is None or kind == "random":
            raise ConfigError(f"{key}.sampling", "a deterministic pupil pattern such as "
                              "'hexapolar:8' or 'grid:16'", smp)
        return cls(float(w), tuple(float(v) for v in f), smp)


def _points(ideal, sensor, fields, depth_mm: float):
    """Object points ``[(X, Y)]`` (mm) at ``depth_mm`` whose ideal images lie on the sensor's
    diagonal at the fractions ``fields`` of its half-diagonal."""
    h, w = (float(v) for v in sensor.size_mm)
    s = ideal.object_scale(depth_mm)
    return [(s * f * 0.5 * w, s * f * 0.5 * h) for f in fields]


def pixel_energy(lens, sensor, ideal, fields, depths_mm, sampling: str = "hexapolar:8",
                 options=None) -> torch.Tensor:
    """``E`` of the module docstring per job, ``(len(depths) * len(fields) * W,)`` (depth-,
    then field-, then wavelength-major; ``W`` the sensor's wavelengths, every channel's in
    order), differentiable in the lens.

    Args:
        lens, sensor: a :class:`~deeplens.optics.camera.Camera` and ``None``, or a lens and its
            sensor (its channels give the wavelengths, nm).
        ideal: the :class:`~deeplens.render.scene.IdealCamera` whose image is the target (the
            module's ``ideal``: fixed when training starts).
        fields: fractions of the sensor's half-diagonal (points on the diagonal).
        depths_mm: object distances from the first vertex (mm, finite).
        sampling: a deterministic pupil pattern (:func:`~deeplens.optics.sampling.pupil_pattern`).
    """
    lens, sensor, options = unpack(lens, sensor, options, "pixel_energy")
    waves = [float(w) for ch in sensor.channels for w in ch]
    pupil = entrance_pupil(lens)
    jobs, rays = [], []
    for d in depths_mm:
        for p in _points(ideal, sensor, fields, float(d)):
            for w in waves:
                jobs.append((p, float(d)))
                rays.append(point_source_rays(lens, p, float(d), w, 0, sampling=sampling,
                                              pupil=pupil))
    wl = torch.tensor([w for _ in range(len(jobs) // len(waves)) for w in waves],
                      dtype=lens.dtype, device=lens.device)[:, None]
    batch = Rays(torch.stack([r.o for r in rays]), torch.stack([r.d for r in rays]),
                 wl.expand(len(rays), rays[0].o.shape[0]), normalize=False)
    i, j, valid = trace_to_sensor_pixels(lens, sensor, batch, options)
    out = []
    for b, ((X, Y), d) in enumerate(jobs):
        s = ideal.object_scale(d)
        i0, j0 = sensor.xy_to_pixel(torch.tensor(X / s), torch.tensor(Y / s))
        v = valid[b].to(i.dtype)
        tent = (torch.relu(1 - (i[b] - float(i0)).abs())
                * torch.relu(1 - (j[b] - float(j0)).abs()))
        out.append((v * tent).sum() / v.sum().clamp_min(1.0))
    return torch.stack(out)


def psf_energy_loss(camera, ideal, setting: PsfEnergy, depths_mm) -> torch.Tensor:
    """``weight * mean(1 - E)`` of :func:`pixel_energy` (a float32 scalar)."""
    e = pixel_energy(camera, None, ideal, setting.fields, depths_mm, setting.sampling)
    return (setting.weight * (1 - e).mean()).float()
