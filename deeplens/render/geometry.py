"""The lens geometry a backward render needs, measured once per lens state (paper Sec. III-C).

* exit pupil: the paraxial exit pupil ``(z_xp, r_xp)`` (:func:`~deeplens.optics.paraxial.exit_pupil`);
  rays are aimed at a disk of radius ``pupil_margin · r_xp`` there;
* image circle: the largest sensor radius from which a ray still passes the lens, found by
  tracing ``96`` radii x ``64`` pupil points along the ``+y`` and ``-x`` half-axes per
  wavelength (misalignment breaks the rotational symmetry), plus one radial step of margin;
  pixels whose nearest point lies outside it receive no light and are not traced;
* reference weight ``w̄_0 = mean(v |d_z|^4)`` over pupil samples at the sensor centre: with
  vignetting on, a uniform scene renders 1 at the centre.

:class:`LensGeometry` holds the results (a frozen dataclass: nothing in it changes after it is
measured).  It is measured without gradient: the renderer treats it as a constant of the
current lens state and caches it under :func:`geometry_key`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch

from ..optics.paraxial import exit_pupil
from ..optics.rays import Rays
from .scene import IdealCamera

__all__ = ["LensGeometry", "measure_geometry", "geometry_key", "lens_structure", "sensor_rays",
           "image_circle_radius", "pixels_inside", "reference_weight", "exit_pupil"]


@dataclass(frozen=True)
class LensGeometry:
    """What a render takes from the lens as constants (mm).

    Attributes:
        camera: the :class:`~deeplens.render.scene.IdealCamera` (object-to-sensor mapping).
        z_xp: axial position of the paraxial exit pupil.
        r_xp: radius of the exit-pupil disk that rays are aimed at (margin included).
        pixels: ``(P,)`` indices into ``H*W`` of the pixels inside the image circle.
        image_circle_mm: radius of the image circle on the sensor (``None`` when the pixels
            were chosen without measuring it).
        w_ref: reference weight ``w̄_0`` per wavelength job (empty without vignetting).
    """

    camera: IdealCamera
    z_xp: float
    r_xp: float
    pixels: torch.Tensor
    image_circle_mm: float | None
    w_ref: tuple[float, ...] = ()


def lens_structure(lens) -> tuple:
    """What a lens is made of, apart from its tensor values: module types in order, media, stop,
    elements and aperture shapes.  Plain python values (never ``repr``, which reads trainable
    tensors as floats and warns)."""
    return (tuple((name, type(m).__name__) for name, m in lens.named_modules()),
            tuple(m.to_spec() for m in lens.materials), lens.stop_index, tuple(lens.elements),
            tuple(getattr(s, "shape", None) for s in lens.surfaces), lens.sensor_semi_diameter)


def geometry_key(lens, sensor, jobs, settings: tuple) -> tuple[tuple, torch.Tensor]:
    """``(meta, values)``: what the geometry depends on.  ``meta`` (hashable, compared with
    ``==``): the lens's structure, its state names, the wavelength jobs, the sensor and the
    renderer ``settings``; ``values``: every tensor of the lens's state (parameters and buffers,
    by value, so in-place and ``.data`` writes both count), compared with ``torch.equal``."""
    sd = lens.state_dict()
    values = torch.cat([t.detach().reshape(-1).to(torch.float64) for t in sd.values()])
    meta = (lens_structure(lens), tuple(sd), tuple(jobs), tuple(sensor.resolution),
            float(sensor.pixel_size_mm), tuple(settings), str(values.device))
    return meta, values


def sensor_rays(lens, x, y, ex, ey, z_xp: float, wavelength) -> Rays:
    """Rays from sensor points ``(x, y)`` (mm, any shape) towards exit-pupil points
    ``(ex, ey, z_xp)``, travelling towards the object (``-z``)."""
    zs = lens.z_sensor().to(x)
    o = torch.stack([x, y, zs.expand_as(x)], -1)
    p = torch.stack([ex, ey, torch.full_like(ex, z_xp)], -1)
    d = p - o
    d = torch.where((d[..., 2:3] > 0), -d, d)  # always travel towards the object (-z)
    return Rays(o, d, wavelength)


#: below this share of the aiming disk's area the paraxial exit pupil (the "core") gets half the
#: probe and reference rays (``pupil_margin`` above sqrt 2; the default 1.05 samples uniformly)
CORE_SHARE = 0.5


def _core_share(r_xp: float, r_core: float | None) -> float:
    return 1.0 if r_core is None else min(1.0, (float(r_core) / float(r_xp)) ** 2)


def image_circle_radius(lens, sensor, jobs, z_xp: float, r_xp: float, options=None,
                        r_core: float | None = None) -> float:
    """Radius (mm) of the image circle: the largest traced sensor radius with a passing ray,
    plus one radial step (module docstring); at most the sensor's half-diagonal.  ``r_xp`` is
    the aiming radius (margin included); ``r_core`` the paraxial exit pupil's radius: when it
    covers less than :data:`CORE_SHARE` of the aiming disk half the probe rays aim inside it, so that a large ``pupil_margin`` (most of the aiming disk
    dark) cannot make every probe miss the light (issue 25, item 12)."""
    dtype, device = lens.dtype, lens.device
    r_max = sensor.half_diagonal_mm
    n_r, n_p = 96, 64
    with torch.no_grad():
        r = torch.linspace(0, r_max, n_r, dtype=dtype, device=device)
        g = torch.Generator().manual_seed(1234)
        rad = torch.sqrt(torch.rand(n_p, generator=g, dtype=torch.float64))
        phi = torch.rand(n_p, generator=g, dtype=torch.float64) * 2 * math.pi
        rad, phi = rad.to(dtype=dtype, device=device), phi.to(dtype=dtype, device=device)
        radius = torch.full_like(rad, float(r_xp))
        if _core_share(r_xp, r_core) < CORE_SHARE:
            radius[n_p // 2:] = float(r_core)
        ex = (radius * rad * torch.cos(phi))[None].expand(n_r, n_p)
        ey = (radius * rad * torch.sin(phi))[None].expand(n_r, n_p)
        r_ic = 0.0
        for _, w, _ in jobs:
            for sgn in (1.0, -1.0):  # the +y and -x half-axes (misalignment breaks symmetry)
                x = (r[:, None] * (0.0 if sgn > 0 else -1.0)).expand(n_r, n_p)
                y = (r[:, None] * (1.0 if sgn > 0 else 0.0)).expand(n_r, n_p)
                rays = sensor_rays(lens, x.contiguous(), y.contiguous(), ex, ey, float(z_xp), w)
                ok = lens.trace(rays, reverse=True, options=options).valid.any(-1)
                if bool(ok.any()):
                    r_ic = max(r_ic, float(r[ok].max()))
    step = r_max / (n_r - 1)
    return min(r_ic + step, r_max) if r_ic < r_max else r_max


def pixels_inside(sensor, r_ic: float, dtype=torch.float64, device=None) -> torch.Tensor:
    """Indices (into ``H*W``) of the pixels that overlap the circle of radius ``r_ic`` mm; warns
    when some do not (they receive no light and are not traced)."""
    H, W = sensor.resolution
    x, y = sensor.pixel_centers(dtype, device)
    half_pix = sensor.pixel_size_mm / math.sqrt(2)
    inside = (torch.sqrt(x * x + y * y) - half_pix <= r_ic).reshape(-1)
    if bool((~inside).any()):  # not on r_ic < r_max alone: float32 rounding of r_ic
        warnings.warn(
            f"the sensor (half-diagonal {sensor.half_diagonal_mm:.4g} mm) is larger than the "
            f"lens's image circle (radius {r_ic:.4g} mm): {int((~inside).sum())} of {H * W} "
            f"pixels receive no light and are not traced", stacklevel=4)
    return torch.nonzero(inside).reshape(-1)


def reference_weight(lens, z_xp: float, r_xp: float, wavelength: float, options=None,
                     n: int = 4096, r_core: float | None = None) -> float:
    """``w̄_0``: mean of ``v |d_z|^4`` over the aiming disk (radius ``r_xp``) at the sensor
    centre, from ``n`` samples.  With ``r_core`` (the paraxial exit pupil's radius) covering
    less than :data:`CORE_SHARE` of the aiming disk, that disk and the annulus outside it get ``n / 2`` samples each, weighted by
    their areas (the same mean, stratified): with a large ``pupil_margin`` a uniform sample
    leaves only a few dozen passing rays, and the image, divided by this, inherited their
    noise as a bias of its brightness (issue 25, item 12).

    Raises:
        ValueError: no ray from the sensor centre passes the lens.
    """
    dtype, device = lens.dtype, lens.device
    f = _core_share(r_xp, r_core)
    strata = [(0.0, 1.0, n, 1.0)] if f >= CORE_SHARE else [(0.0, f, n // 2, f),
                                                     (f, 1.0, n - n // 2, 1.0 - f)]
    val = 0.0
    with torch.no_grad():
        g = torch.Generator().manual_seed(4321)
        for lo, hi, m, share in strata:
            u = lo + (hi - lo) * torch.rand(m, generator=g, dtype=torch.float64)
            rad = torch.sqrt(u) * r_xp
            phi = torch.rand(m, generator=g, dtype=torch.float64) * 2 * math.pi
            ex = (rad * torch.cos(phi)).to(dtype=dtype, device=device)
            ey = (rad * torch.sin(phi)).to(dtype=dtype, device=device)
            zero = torch.zeros_like(ex)
            rays = sensor_rays(lens, zero, zero, ex, ey, z_xp, wavelength)
            out = lens.trace(rays, reverse=True, options=options)
            val += share * float((out.valid.to(dtype) * rays.d[..., 2] ** 4).mean())
    if val <= 0:
        raise ValueError(f"no ray from the sensor centre passes the lens at {wavelength:g} nm: "
                         f"the lens vignettes the on-axis field completely")
    return val


def measure_geometry(lens, sensor, jobs, *, options=None, pupil_margin: float = 1.05,
                     vignetting: bool = True, pupil=None, pixels=None,
                     image_circle_mm: float | None = None) -> LensGeometry:
    """Measure the :class:`LensGeometry` of ``lens`` for the wavelength ``jobs``
    (``[(channel, wavelength_nm, weight), ...]``), without gradient.

    ``pupil`` (the paraxial ``(z_xp, r_xp)``), ``pixels`` and ``image_circle_mm`` may be given
    when already known (the renderer measures the pixels through its own, overridable
    ``active_pixels``); the rest is measured here.
    """
    if pupil is None:
        with torch.no_grad():
            pupil = exit_pupil(lens)
    z_xp, r_xp = float(pupil[0]), float(pupil[1])
    r_aim = r_xp * pupil_margin
    if pixels is None:
        image_circle_mm = image_circle_radius(lens, sensor, jobs, z_xp, r_aim, options, r_xp)
        pixels = pixels_inside(sensor, image_circle_mm, lens.dtype, lens.device)
    w_ref = tuple(reference_weight(lens, z_xp, r_aim, w, options, r_core=r_xp)
                  for _, w, _ in jobs) \
        if vignetting else ()
    return LensGeometry(camera=IdealCamera(lens, sensor), z_xp=z_xp, r_xp=r_aim, pixels=pixels,
                        image_circle_mm=image_circle_mm, w_ref=w_ref)
