"""Quick focus: the sensor distance that minimises the RMS spot, in closed form.

Behind the last surface a ray travels in a straight line, so on the plane ``z = z_0 + t`` the
ray ``m`` of a (field, wavelength) block lands at ``p_m(t) = a_m + t s_m`` with ``a_m`` its
point on the plane ``z_0`` and ``s_m = (d_x, d_y) / d_z`` its slopes.  Referenced to the
block's centroid (``ã = a - mean a``, ``s̃ = s - mean s``) the mean squared spot radius of the
blocks, each weighted by ``1/M`` (its ray count),

    E(t) = sum_b (1/M_b) sum_m |ã_m + t s̃_m|^2,

is a quadratic in ``t`` with its minimum at

    t* = - sum_b (1/M_b) sum_m ã_m·s̃_m  /  sum_b (1/M_b) sum_m |s̃_m|^2 .

This is what lens-design programs call *quick focus* (the thickness before the image adjusted
for the smallest RMS spot, centroid-referenced): one trace, no iteration, exact for the rays
traced (the pupil regions are found once on the lens as it is).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..analysis.spot import find_pupil
from ..optics.camera import unpack
from ..optics.sampling import field_rays, pupil_pattern

__all__ = ["FocusResult", "quick_focus_shift", "quick_focus"]


@dataclass
class FocusResult:
    """``shift_mm`` (the sensor move, + away from the lens), the root-mean-square over blocks of
    the RMS spot radius before and after (mm), and the sensor distances before/after (mm)."""

    shift_mm: float
    rms_before_mm: float
    rms_after_mm: float
    d_sensor_before: float
    d_sensor_after: float


def _blocks(lens, fields, waves, sampling, options=None):
    """Per (field, wavelength) the valid rays' points on the sensor plane and their slopes."""
    unit = pupil_pattern(sampling, dtype=lens.dtype)
    primary = float(lens.spec.primary_wavelength_nm)
    out = []
    for f in fields:
        region = find_pupil(lens, f, primary, "traced", grid=65, bisections=24, options=options)
        for wl in waves:
            rays = lens.trace_to_sensor(field_rays(lens, f, wl, region.points(unit), region.z),
                                        options=options)
            ok = rays.valid
            if int(ok.sum()) < 2:
                continue
            a = rays.o[ok][:, :2]
            s = rays.d[ok][:, :2] / rays.d[ok][:, 2:]
            out.append((a, s))
    if not out:
        raise ValueError("quick focus: no field reaches the sensor with two rays or more")
    return out


def quick_focus_shift(lens, fields=None, waves=None, sampling: str = "hexapolar:6",
                      options=None) -> tuple[float, float, float]:
    """``(t*, E(0) / B, E(t*) / B)``: the sensor shift (mm) and the mean over the ``B`` blocks
    of the squared RMS radius before and after it (mm^2), by the module docstring's formula.
    ``lens``: a Lens (traced with ``options``, ``None``: the defaults) or a
    :class:`~deeplens.optics.camera.Camera` (its options reach the pupil search and the
    spots)."""
    lens, _, options = unpack(lens, None, options, "quick_focus_shift")
    fields = list(lens.spec.fields_deg) if fields is None else list(fields)
    waves = list(lens.spec.wavelengths_nm) if waves is None else list(waves)
    with torch.no_grad():
        num = den = e0 = 0.0
        blocks = _blocks(lens, fields, waves, sampling, options)
        for a, s in blocks:
            at, st = a - a.mean(0), s - s.mean(0)
            m = a.shape[0]
            num += float((at * st).sum()) / m
            den += float((st * st).sum()) / m
            e0 += float((at * at).sum()) / m
        t = -num / den if den > 0 else 0.0
        e2 = e0 + 2 * t * num + t * t * den
    return t, e0 / len(blocks), max(e2, 0.0) / len(blocks)


def quick_focus(lens, fields=None, waves=None, sampling: str = "hexapolar:6",
                apply: bool = True, options=None) -> FocusResult:
    """Move the sensor to the quick-focus plane (module docstring); with ``apply=False`` only
    report where it would go.  ``lens``: a Lens (traced with ``options``) or a
    :class:`~deeplens.optics.camera.Camera` (its options are used; its lens's sensor moves).

    Raises:
        ValueError: no field reaches the sensor, or the focus lies at or before the last
            vertex (the message gives the distance).
    """
    lens, _, options = unpack(lens, None, options, "quick_focus")
    fields = list(lens.spec.fields_deg) if fields is None else list(fields)
    waves = list(lens.spec.wavelengths_nm) if waves is None else list(waves)
    t, e0, e1 = quick_focus_shift(lens, fields, waves, sampling, options)
    d0 = float(lens.d_sensor.detach())
    d1 = d0 + t
    if not d1 > 0:
        raise ValueError(f"quick focus: the best-focus plane lies {d1:.6g} mm from the last "
                         f"vertex (at or before it); the lens does not form an image there")
    if apply:
        with torch.no_grad():
            lens.d_sensor.fill_(d1)
    return FocusResult(t, e0 ** 0.5, e1 ** 0.5, d0, d1)
