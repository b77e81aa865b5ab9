"""Transverse aberrations: ray fans, field curvature, distortion, colour and vignetting.

Pupil coordinates ``p`` are normalised on the paraxial entrance pupil of the primary wavelength
(as in :mod:`.wavefront`).  With the image plane at ``z_I``:

* ray fan: ``e_y(p_y) = y(0, p_y) - y_chief`` (tangential) and ``e_x(p_x) = x(p_x, 0) - x_chief``
  (sagittal), both referred to the chief ray of the *primary* wavelength, so lateral colour
  shows as an offset of the other wavelengths' fans;
* field curvature: two parabasal rays ``p = p_c ± δ`` around the chief ray cross at
  ``z_T`` (pair along ``p_y``, meridional section) and ``z_S`` (pair along ``p_x``); reported as
  ``z_T - z_I`` and ``z_S - z_I`` (mm);
* distortion: ``D = 100 (y_real - y_par) / y_par`` (%), ``y_real`` the real chief ray's height
  on the image plane and ``y_par = κ tan θ`` the paraxial chief ray's there
  (:func:`~deeplens.optics.paraxial.chief_ray_scale`), the "f-tan" convention;
* lateral colour: ``y_chief(λ_short) - y_chief(λ_long)`` (mm) per field; longitudinal colour:
  the paraxial image position of each wavelength minus the primary's (mm);
* vignetting: ``1 - T(θ)/T(0)`` with ``T`` the fraction of a uniform grid over the paraxial
  entrance pupil that reaches the image.

``aim="real"`` (default) takes the chief ray through the stop centre (aimed by iteration),
``aim="paraxial"`` the ray through the paraxial entrance-pupil centre (no ray aiming).

Every function takes a lens (traced with ``options``, a
:class:`~deeplens.optics.options.TraceOptions`; ``None``: the defaults) or a
:class:`~deeplens.optics.camera.Camera` in its place (its options are used, and giving
``options`` as well is refused); the aiming traces run at the same options without clear
apertures (:func:`~deeplens.optics.chief.aiming_options`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..optics.camera import unpack
from ..optics.chief import aiming_options
from ..optics.sampling import field_rays
from .checks import AnalysisError, check_field, check_wavelength
from ..optics.paraxial import chief_ray_scale, paraxial
from .spot import chief_ray, image_plane_z
from .wavefront import launch, pupil_grid, trace_pupil

__all__ = ["RayFan", "ray_fan", "field_curvature", "distortion", "lateral_color",
           "longitudinal_color", "vignetting", "real_chief_ray", "chief_heights"]


def _waves(lens, wavelengths_nm):
    ws = list(lens.spec.wavelengths_nm if wavelengths_nm is None else wavelengths_nm)
    check_wavelength(lens, ws)
    return [float(w) for w in ws]


def _fields(lens, fields_deg):
    return [float(f) for f in (lens.spec.fields_deg if fields_deg is None else fields_deg)]


def _aim(aim):
    if aim not in ("real", "paraxial"):
        raise ValueError(f"aim must be 'real' or 'paraxial', got {aim!r}")


def real_chief_ray(lens, field_deg: float, wavelength_nm: float | None = None, image_plane="sensor",
                   options=None):
    """Height ``(,)`` mm on the image plane of the real chief ray (through the stop centre) and
    its entrance-pupil-plane height ``y_p`` (mm), both differentiable.

    ``y_p`` is found without gradients (:func:`~deeplens.analysis.spot.chief_ray`), then one
    differentiable Newton step ``y_p - h(y_p)/h'`` on the stop height ``h`` (``h = 0`` at the
    solution, ``h'`` detached) carries the implicit derivative ``-∂h/∂θ / h'`` to the lens.
    ``lens``: a Lens or a Camera (its options are used; module docstring)."""
    lens, _, options = unpack(lens, None, options, "real_chief_ray")
    if wavelength_nm is None:   # the lens's primary wavelength, as the other analysis functions
        wavelength_nm = float(lens.spec.primary_wavelength_nm)
    dtype = lens.dtype
    _, y1 = chief_ray(lens, field_deg, wavelength_nm, image_plane, options=options)
    p = paraxial(lens)
    z = lens.z_vertices()
    dev = lens.device
    n = lens.indices(torch.tensor(wavelength_nm, dtype=dtype, device=dev))
    aim = aiming_options(options)

    def stop_h(yp):
        rays = launch(lens, field_deg, wavelength_nm,
                      torch.stack([torch.zeros_like(yp), yp])[None], p.entrance_pupil_z)
        for i in range(lens.stop_index + 1):
            rays = lens.trace_surface(i, rays, n[i], n[i + 1], z, aim,
                                      refract_=i < lens.stop_index)
        return rays.o[0, 1]

    eps = 1e-6 * max(float(p.entrance_pupil_diameter), 1e-3)
    y0 = torch.tensor(y1, dtype=dtype, device=dev)
    with torch.no_grad():
        slope = (stop_h(y0 + eps) - stop_h(y0 - eps)) / (2 * eps)
    yp = y0 - stop_h(y0) / slope
    rays = launch(lens, field_deg, wavelength_nm, torch.stack([torch.zeros_like(yp), yp])[None],
                  p.entrance_pupil_z)
    out = lens.trace_to_sensor(rays, z_image=image_plane_z(lens, image_plane), options=options)
    if not bool(out.valid[0]):
        raise AnalysisError(f"the real chief ray of field {field_deg:g} deg at "
                            f"{wavelength_nm:g} nm does not reach the image")
    return out.o[0, 1], yp


def _chief_pupil(lens, field_deg, wavelength_nm, aim, options=None):
    """Normalised pupil ``p_y`` of the chief ray."""
    if aim == "paraxial":
        return 0.0
    _, yp = chief_ray(lens, field_deg, wavelength_nm, options=options)
    return float(yp) / (0.5 * float(paraxial(lens).entrance_pupil_diameter))


@dataclass
class RayFan:
    """Fans of one field: ``p`` (K,) pupil coordinate; per wavelength ``ey``/``ex`` (K,) in mm
    (NaN where vignetted), keyed by wavelength in nm."""

    field_deg: float
    p: torch.Tensor
    ey: dict
    ex: dict


def ray_fan(lens, field_deg: float, wavelengths_nm=None, n: int = 41,
            image_plane="sensor", options=None) -> RayFan:
    """Tangential and sagittal ray fans of one field (see the module docstring); ``lens``: a
    Lens or a Camera (its options are used)."""
    lens, _, options = unpack(lens, None, options, "ray_fan")
    waves = _waves(lens, wavelengths_nm)
    dtype = lens.dtype
    p = torch.linspace(-1.0, 1.0, n, dtype=dtype, device=lens.device)
    zero = torch.zeros_like(p)
    tang = torch.stack([zero, p], -1)
    sag = torch.stack([p, zero], -1)
    prim = float(lens.spec.primary_wavelength_nm)
    ref = trace_pupil(lens, field_deg, prim, tang[:1], image_plane,
                      options=options).chief_point
    ey, ex = {}, {}
    for w in waves:
        t = trace_pupil(lens, field_deg, w, tang, image_plane, options=options)
        s = trace_pupil(lens, field_deg, w, sag, image_plane, options=options)
        nan = torch.full_like(p, math.nan)
        ey[w] = torch.where(t.mask, t.points[:, 1] - ref[1], nan)
        ex[w] = torch.where(s.mask, s.points[:, 0] - ref[0], nan)
    return RayFan(float(field_deg), p, ey, ex)


def _cross(P1, D1, P2, D2, a):
    """Axial distance from ``P1`` to where two rays meet in the (``a``, z) section."""
    t1 = (D2[a] * (P1[2] - P2[2]) - D2[2] * (P1[a] - P2[a])) / (D1[a] * D2[2] - D2[a] * D1[2])
    return t1 * D1[2]


def field_curvature(lens, fields_deg=None, wavelength_nm: float | None = None,
                    image_plane="sensor", aim: str = "real", delta: float = 1e-5, options=None):
    """Tangential and sagittal focus relative to the image plane, ``(z_T - z_I, z_S - z_I)``,
    each ``(F,)`` in mm, for the fields ``fields_deg`` (default the lens file's); ``lens``: a
    Lens or a Camera (its options are used)."""
    _aim(aim)
    lens, _, options = unpack(lens, None, options, "field_curvature")
    w = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    check_wavelength(lens, w)
    dtype = lens.dtype
    zt, zs = [], []
    for f in _fields(lens, fields_deg):
        pc = _chief_pupil(lens, f, w, aim, options)
        pts = torch.tensor([[0.0, pc - delta], [0.0, pc + delta], [-delta, pc], [delta, pc]],
                           dtype=dtype, device=lens.device)
        tr = trace_pupil(lens, f, w, pts, image_plane, options=options)
        if not bool(tr.mask.all()):
            raise AnalysisError(f"the parabasal rays of field {f:g} deg are vignetted")
        X, D = tr.points, tr.directions
        zt.append(_cross(X[0], D[0], X[1], D[1], 1))
        zs.append(_cross(X[2], D[2], X[3], D[3], 0))
    return torch.stack(zt), torch.stack(zs)


def distortion(lens, fields_deg=None, wavelength_nm: float | None = None,
               image_plane="sensor", aim: str = "real", options=None) -> torch.Tensor:
    """Distortion in percent ``(F,)`` (module docstring); field 0 gives 0.  Differentiable.
    ``lens``: a Lens or a Camera (its options are used)."""
    _aim(aim)
    lens, _, options = unpack(lens, None, options, "distortion")
    w = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    check_wavelength(lens, w)
    z = image_plane_z(lens, image_plane)
    kappa = chief_ray_scale(lens, z, w)
    out = []
    for f in _fields(lens, fields_deg):
        if f == 0.0:
            out.append(torch.zeros_like(kappa))
            continue
        if aim == "real":
            p = paraxial(lens)
            check_field(lens, f, w, float(p.entrance_pupil_z),
                        0.5 * float(p.entrance_pupil_diameter), options)
            y, _ = real_chief_ray(lens, f, w, image_plane, options)
        else:
            y = trace_pupil(lens, f, w, torch.zeros(1, 2, dtype=kappa.dtype, device=kappa.device),
                            image_plane, options=options).chief_point[1]
        ypar = kappa * math.tan(math.radians(f))
        out.append(100.0 * (y - ypar) / ypar)
    return torch.stack(out)


def chief_heights(lens, fields_deg=None, wavelength_nm=None, image_plane="sensor",
                  aim: str = "real", options=None) -> torch.Tensor:
    """Chief-ray heights on the image plane ``(F,)`` (mm); ``lens``: a Lens or a Camera (its
    options are used)."""
    _aim(aim)
    lens, _, options = unpack(lens, None, options, "chief_heights")
    w = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    check_wavelength(lens, w)
    dtype = lens.dtype
    out = []
    for f in _fields(lens, fields_deg):
        if aim == "real":
            y, _ = real_chief_ray(lens, f, w, image_plane, options)
        else:
            zero = torch.zeros(1, 2, dtype=dtype, device=lens.device)
            y = trace_pupil(lens, f, w, zero, image_plane, options=options).chief_point[1]
        out.append(y)
    return torch.stack(out)


def lateral_color(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor",
                  aim: str = "real", options=None) -> torch.Tensor:
    """``y_chief(shortest λ) - y_chief(longest λ)`` per field ``(F,)`` in mm; ``lens``: a Lens
    or a Camera (its options are used)."""
    lens, _, options = unpack(lens, None, options, "lateral_color")
    waves = _waves(lens, wavelengths_nm)
    if len(waves) < 2:
        raise AnalysisError("lateral colour needs at least two wavelengths")
    lo, hi = min(waves), max(waves)
    return (chief_heights(lens, fields_deg, lo, image_plane, aim, options)
            - chief_heights(lens, fields_deg, hi, image_plane, aim, options))


def longitudinal_color(lens, wavelengths_nm=None) -> tuple[list, torch.Tensor]:
    """Paraxial focus shift of each wavelength from the primary's, ``(W,)`` mm (+ = further
    from the lens); returns ``(wavelengths, shifts)``.  Paraxial (no ray is traced); ``lens``
    may be a Camera."""
    lens, _, _ = unpack(lens, None, None, "longitudinal_color")
    waves = _waves(lens, wavelengths_nm)
    z0 = paraxial(lens).image_z
    return waves, torch.stack([paraxial(lens, w).image_z - z0 for w in waves])


def vignetting(lens, fields_deg=None, wavelength_nm: float | None = None, n: int = 41,
               image_plane="sensor", options=None) -> torch.Tensor:
    """Vignetting ``1 - T(θ)/T(0)`` per field ``(F,)`` (module docstring); 0 = none, 1 = fully
    vignetted (a field whose chief ray is lost counts as fully vignetted).  ``lens``: a Lens or
    a Camera (its options are used)."""
    lens, _, options = unpack(lens, None, options, "vignetting")
    w = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    check_wavelength(lens, w)
    dtype = lens.dtype
    g = pupil_grid(n, dtype, lens.device)
    g = g[(g ** 2).sum(-1) <= 1.0 + 1e-12]
    p = paraxial(lens)
    z_ep, r_ep = float(p.entrance_pupil_z), 0.5 * float(p.entrance_pupil_diameter)
    z = image_plane_z(lens, image_plane)

    def transmitted(f):
        with torch.no_grad():
            out = lens.trace_to_sensor(field_rays(lens, f, w, g * r_ep, z_ep), z_image=z,
                                       options=options)
        return float(out.valid.to(dtype).mean())

    t0 = transmitted(0.0)
    if t0 == 0.0:
        raise AnalysisError(f"no on-axis ray at {w:g} nm reaches the image")
    return torch.tensor([1.0 - transmitted(f) / t0 for f in _fields(lens, fields_deg)],
                        dtype=dtype, device=lens.device)
