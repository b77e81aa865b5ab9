"""Wavefront: optical path difference over the exit pupil relative to the reference sphere.

A ray of the field, launched through normalised entrance-pupil coordinates ``(p_x, p_y)`` (the
paraxial entrance pupil of the primary wavelength, radius ``r_EP``: "paraxial ray aiming"), is
traced to the image plane, where it lands at ``X`` with direction ``d`` and optical path ``L``.
The reference sphere is centred on the chief ray's (``p = 0``) image point ``C`` and passes
through the paraxial exit-pupil point ``E = (0, 0, z_XP)``: ``R = |C - E|``.  Going back along
the ray from ``X`` by ``s > 0`` with ``|X - s d - C| = R`` reaches the sphere, so the optical
path to the sphere is ``L - n' s`` and, in waves,

    W(p) = [ (L - n' s)_chief - (L - n' s)(p) ] / λ .

A positive ``W`` is a ray that arrives early (shorter path), the convention of optiland and
Zemax.  For an object at infinity the rays start on a plane ``z = z_0`` that is not a wavefront
of the tilted beam, so each ray's path is counted from the plane wavefront through the chief
ray's start: ``L += n_0 d · (o - o_chief)``.  A finite object emits a spherical wave: each ray
starts on the same plane with its path from the object point relative to the pupil centre's
(:func:`launch`; the two agree in the limit).  Rays that are vignetted are dropped (``mask`` False).

Zernike polynomials on the unit disk (``ρ = |p|``, ``θ = atan2(p_y, p_x)``):
``Z_n^m = N_n^m R_n^|m|(ρ) cos(mθ)`` (``m ≥ 0``) or ``sin(|m|θ)`` (``m < 0``) with
``R_n^m(ρ) = Σ_k (-1)^k (n-k)! / (k! ((n+m)/2-k)! ((n-m)/2-k)!) ρ^(n-2k)``;
"standard" is the OSA/ANSI order ``j = (n(n+2)+m)/2`` (from 0) with ``N = sqrt(2(n+1)/(1+δ_m0))``
(unit RMS over the disk); "fringe" is the Fringe/University-of-Arizona order (terms 1..37) with
``N = 1``.  The fit is least squares over the valid samples.

RMS and peak-to-valley are in waves, piston removed:
``rms = sqrt(mean (W - mean W)^2)`` over the valid samples of a uniform pupil grid (area
weighting), ``pv = max W - min W``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..optics.camera import unpack
from ..optics.rays import Rays
from ..optics.sampling import start_plane_z
from .checks import AnalysisError, check_field, check_wavelength
from ..optics.paraxial import exit_pupil, paraxial
from .spot import image_plane_z

__all__ = ["PupilTrace", "trace_pupil", "launch", "pupil_grid", "Wavefront", "wavefront",
           "zernike_basis", "zernike_fit", "zernike_nm", "ZernikeFit"]


def pupil_grid(n: int, dtype=torch.float64, device=None) -> torch.Tensor:
    """``n x n`` points over ``[-1, 1]^2`` (rows = ``p_y``), shape ``(n, n, 2)``."""
    if n < 2:
        raise ValueError(f"pupil grid needs at least 2 points per side, got {n}")
    v = torch.linspace(-1.0, 1.0, n, dtype=dtype, device=device)
    py, px = torch.meshgrid(v, v, indexing="ij")
    return torch.stack([px, py], -1)


@dataclass
class PupilTrace:
    """Rays of one field and wavelength on the image plane (leading shape of ``pupil``).

    ``points``/``directions`` (..., 3), ``opl`` (...,) mm, ``mask`` (...,) valid rays;
    ``chief_*`` the ray through the pupil centre; ``start`` the launch points."""

    pupil: torch.Tensor
    points: torch.Tensor
    directions: torch.Tensor
    opl: torch.Tensor
    mask: torch.Tensor
    chief_point: torch.Tensor
    chief_direction: torch.Tensor
    chief_opl: torch.Tensor
    n_image: torch.Tensor
    z_image: torch.Tensor
    field_deg: float
    wavelength_nm: float


def trace_pupil(lens, field_deg: float, wavelength_nm: float, pupil: torch.Tensor,
                image_plane="sensor", check: bool = True, options=None) -> PupilTrace:
    """Trace normalised entrance-pupil points ``pupil`` (..., 2) of one field to the image plane.

    The optical paths include the plane-wave launch correction of the module docstring, so
    differences of ``opl`` are optical path differences.  Gradients flow to the lens.
    ``options`` (:class:`~deeplens.optics.options.TraceOptions`) e.g. to ignore clear
    apertures; ``lens`` may be a :class:`~deeplens.optics.camera.Camera` (its options).

    Raises:
        AnalysisError: a wavelength outside a medium's range or a field beyond the lens's reach.
    """
    lens, _, options = unpack(lens, None, options, "trace_pupil")
    w = float(wavelength_nm)
    if check:
        check_wavelength(lens, w)
    p = paraxial(lens)
    z_ep = p.entrance_pupil_z
    r_ep = 0.5 * p.entrance_pupil_diameter
    if check:
        check_field(lens, field_deg, w, float(z_ep), float(r_ep), options)
    shape = pupil.shape[:-1]
    flat = pupil.reshape(-1, 2).to(dtype=lens.dtype, device=lens.device)
    zero = torch.zeros(1, 2, dtype=flat.dtype, device=flat.device)
    xy = torch.cat([zero, flat], 0) * r_ep
    rays = launch(lens, field_deg, w, xy, z_ep)
    z_img = image_plane_z(lens, image_plane)
    n_img = lens.materials[-1].n(rays.wavelength[:1])[0]
    out = lens.trace_to_sensor(rays, z_image=z_img, options=options)
    if not bool(out.valid[0]):
        raise AnalysisError(f"the chief ray of field {field_deg:g} deg at {w:g} nm does not reach "
                            f"the image plane")
    opl = out.opl  # launch() starts each ray at its path relative to the pupil centre's
    return PupilTrace(pupil=pupil, points=out.o[1:].reshape(*shape, 3),
                      directions=out.d[1:].reshape(*shape, 3), opl=opl[1:].reshape(shape),
                      mask=out.valid[1:].reshape(shape), chief_point=out.o[0],
                      chief_direction=out.d[0], chief_opl=opl[0], n_image=n_img,
                      z_image=torch.as_tensor(z_img), field_deg=float(field_deg), wavelength_nm=w)


def launch(lens, field_deg: float, wavelength_nm: float, xy: torch.Tensor,
           z_pupil: torch.Tensor) -> Rays:
    """Object-space rays of one field through points ``xy`` (M, 2) mm of the plane ``z_pupil``.

    The geometry of :func:`deeplens.optics.sampling.field_rays`, written with tensors so that
    gradients also flow through the pupil plane's position and size (which move with the lens).
    Each ray's ``opl`` starts at ``n_0 (L - L_0)``: its path from the object point (for an object
    at infinity, from the plane wavefront) minus that of the ray through the pupil centre.  The
    launch is computed in float64 from the direction tangents ``t = t_0 + xy / D`` (``D`` the
    object's distance from the pupil plane) with ``L - L_0`` written without cancellation, so
    float32 rays keep their precision for any object distance (issue 25, item 8).
    """
    dtype, device = xy.dtype, xy.device
    f64 = torch.float64
    s = float(lens.spec.object_distance_mm)
    th = math.radians(field_deg)
    xy64 = xy.to(f64)
    zp = torch.as_tensor(z_pupil, device=device).to(f64)
    z_start = torch.as_tensor(start_plane_z(lens), dtype=f64, device=device)
    t0 = torch.tensor([0.0, math.tan(th)], dtype=f64, device=device)
    if math.isinf(s):
        t, ratio = t0.expand_as(xy64), 1.0
    else:
        # the object point on the chief line through the pupil centre, on the object plane
        # (tilted: lens.object_tilt, sampling.object_points), ``depth`` before the pupil plane
        ty = getattr(lens, "object_tilt", (0.0, 0.0))[1]
        z_obj = lens.z_vertices()[0].to(f64) - s
        depth = (zp - z_obj) / (1.0 - ty * math.tan(th))
        z_obj = z_obj - ty * math.tan(th) * depth   # the point's z (untilted: z_obj exactly)
        t = t0 + xy64 / depth
        # a real object point (before the first vertex; at it: a first coordinate break's pivot,
        # s = 0) starts the rays no earlier than itself; a virtual one (behind the first
        # vertex: s < 0, or a tilted plane's far point) lies behind the start plane: path < 0
        if float(z_obj) <= float(lens.z_vertices()[0]):
            z_start = torch.maximum(z_start, z_obj)
        ratio = (z_start - z_obj) / depth
    ones = torch.ones_like(xy64[:, :1])
    o = torch.cat([xy64 + (z_start - zp) * t, z_start * ones], -1)
    d = torch.cat([t, ones], -1)
    norm = torch.linalg.vector_norm(d, dim=-1)
    # L - L_0 = D' (sqrt(1 + |t|^2) - sqrt(1 + |t_0|^2)), |t|^2 - |t_0|^2 = (xy / D).(t + t_0)
    path = ratio * (xy64 * (t + t0)).sum(-1) / (norm + torch.sqrt(1.0 + (t0 * t0).sum()))
    w = torch.as_tensor(wavelength_nm, dtype=dtype, device=device)
    n0 = lens.materials[0].n(w.reshape(1))[0]
    return Rays(o.to(dtype), (d / norm[:, None]).to(dtype), wavelength_nm,
                opl=n0 * path.to(dtype), normalize=False)


def _back_to_sphere(X, d, C, R):
    """``s >= 0`` with ``|X - s d - C| = R`` (the root on the pupil side)."""
    v = X - C
    b = (v * d).sum(-1)
    c = (v * v).sum(-1) - R * R
    disc = (b * b - c).clamp_min(0.0)
    return b + torch.sqrt(disc)


@dataclass
class Wavefront:
    """OPD of one field and wavelength; ``opd`` in waves over ``pupil`` (normalised EP).

    ``rms``/``pv`` in waves (piston removed), ``reference_center`` (3,) and
    ``reference_radius`` (mm) the reference sphere; ``sphere_points`` (..., 3) where each ray
    meets it."""

    pupil: torch.Tensor
    opd: torch.Tensor
    mask: torch.Tensor
    rms: torch.Tensor
    pv: torch.Tensor
    reference_center: torch.Tensor
    reference_radius: torch.Tensor
    sphere_points: torch.Tensor
    trace: PupilTrace


def _rms_pv(opd, mask):
    m = mask.to(opd.dtype)
    k = m.sum().clamp_min(1.0)
    mean = (opd * m).sum() / k
    rms = torch.sqrt((((opd - mean) ** 2) * m).sum() / k)
    big = torch.where(mask, opd, torch.full_like(opd, -math.inf)).max()
    small = torch.where(mask, opd, torch.full_like(opd, math.inf)).min()
    return rms, big - small


def wavefront(lens, field_deg: float, wavelength_nm: float | None = None, n: int = 64,
              image_plane="sensor", pupil: torch.Tensor | None = None,
              options=None) -> Wavefront:
    """OPD map (waves) over an ``n x n`` pupil grid clipped to the unit disk (or over the given
    normalised ``pupil`` points (..., 2)); see the module docstring.  Differentiable.
    ``lens`` may be a :class:`~deeplens.optics.camera.Camera` (traced with its options), or a
    lens traced with ``options`` (:class:`~deeplens.optics.options.TraceOptions`).

    Example:
        >>> from deeplens.optics import load_lens
        >>> lens = load_lens("double_gauss")
        >>> w = wavefront(lens, 14.0, 587.56, n=32)
        >>> round(float(w.rms), 2)                     # waves
        0.42
    """
    lens, _, options = unpack(lens, None, options, "wavefront")
    wl = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    dtype = lens.dtype
    if pupil is None:
        pupil = pupil_grid(n, dtype, lens.device)
    inside = (pupil ** 2).sum(-1) <= 1.0 + 1e-12
    tr = trace_pupil(lens, field_deg, wl, pupil, image_plane, options=options)
    z_xp, _ = exit_pupil(lens)
    C = tr.chief_point
    E = torch.stack([torch.zeros_like(z_xp), torch.zeros_like(z_xp), z_xp.to(C)])
    R = torch.linalg.vector_norm(C - E)
    s = _back_to_sphere(tr.points, tr.directions, C, R)
    s_chief = _back_to_sphere(C, tr.chief_direction, C, R)
    ref = tr.chief_opl - tr.n_image * s_chief
    opd = (ref - (tr.opl - tr.n_image * s)) / (wl * 1e-6)
    mask = tr.mask & inside
    opd = torch.where(mask, opd, torch.zeros_like(opd))
    if not bool(mask.any()):
        raise AnalysisError(f"no ray of field {field_deg:g} deg at {wl:g} nm reaches the image")
    rms, pv = _rms_pv(opd, mask)
    pts = tr.points - s.unsqueeze(-1) * tr.directions
    return Wavefront(pupil, opd, mask, rms, pv, C, R, pts, tr)


# ----------------------------------------------------------------------------- Zernike
def zernike_nm(j: int, ordering: str = "fringe") -> tuple[int, int]:
    """``(n, m)`` of term ``j``: fringe counts from 1, standard (OSA/ANSI) from 0."""
    if ordering == "standard":
        if j < 0:
            raise ValueError(f"standard (OSA/ANSI) Zernike indices start at 0, got {j}")
        n = int((math.sqrt(8 * j + 1) - 1) // 2)
        m = 2 * j - n * (n + 2)
        return n, m
    if ordering == "fringe":
        if not 1 <= j <= 37:
            raise ValueError(f"fringe Zernike indices run from 1 to 37, got {j}")
        if j == 37:
            return 12, 0  # the set's extra term after the complete shells 1..36
        # fringe index of (n, m): (N+1)^2 - 2|m| + (m < 0), N = (n + |m|)/2; search the shell
        N = int(math.ceil(math.sqrt(j))) - 1
        for am in range(N + 1):
            for sign in ((1,) if am == 0 else (1, -1)):
                if (N + 1) ** 2 - 2 * am + (sign < 0) == j:
                    return 2 * N - am, sign * am
        raise AssertionError(j)
    raise ValueError(f"Zernike ordering must be 'fringe' or 'standard', got {ordering!r}")


def _radial(n, m, rho):
    m = abs(m)
    out = torch.zeros_like(rho)
    for k in range((n - m) // 2 + 1):
        c = (-1) ** k * math.factorial(n - k) / (math.factorial(k) *
                                                 math.factorial((n + m) // 2 - k) *
                                                 math.factorial((n - m) // 2 - k))
        out = out + c * rho ** (n - 2 * k)
    return out


def zernike_basis(pupil: torch.Tensor, num_terms: int, ordering: str = "fringe") -> torch.Tensor:
    """Zernike values ``(..., num_terms)`` at unit-disk points ``pupil`` (..., 2)."""
    x, y = pupil[..., 0], pupil[..., 1]
    rho = torch.sqrt(x * x + y * y)
    th = torch.atan2(y, x)
    first = 1 if ordering == "fringe" else 0
    cols = []
    for j in range(first, first + num_terms):
        n, m = zernike_nm(j, ordering)
        z = _radial(n, m, rho)
        if m > 0:
            z = z * torch.cos(m * th)
        elif m < 0:
            z = z * torch.sin(-m * th)
        if ordering == "standard":
            z = z * math.sqrt(2 * (n + 1) / (1 + (m == 0)))
        cols.append(z)
    return torch.stack(cols, -1)


@dataclass
class ZernikeFit:
    """Coefficients (waves) in the given ordering, the first index (1 fringe, 0 standard), the
    RMS of the fit residual (waves) and the indices ``(n, m)`` of each term."""

    coefficients: torch.Tensor
    ordering: str
    first_index: int
    residual_rms: torch.Tensor
    nm: list


def zernike_fit(wf: Wavefront, num_terms: int = 37, ordering: str = "fringe") -> ZernikeFit:
    """Least-squares Zernike fit of a :class:`Wavefront` over its valid samples."""
    if num_terms < 1:
        raise ValueError(f"num_terms must be >= 1, got {num_terms}")
    zernike_nm(1 if ordering == "fringe" else 0, ordering)  # validates the ordering
    P = wf.pupil[wf.mask]
    Z = zernike_basis(P, num_terms, ordering)
    y = wf.opd[wf.mask]
    if Z.shape[0] < num_terms:
        raise AnalysisError(f"{Z.shape[0]} valid pupil samples cannot fit {num_terms} Zernike "
                            f"terms; sample the pupil more densely")
    coef = torch.linalg.lstsq(Z, y.unsqueeze(-1)).solution.squeeze(-1)
    res = y - Z @ coef
    first = 1 if ordering == "fringe" else 0
    return ZernikeFit(coef, ordering, first, torch.sqrt((res ** 2).mean()),
                      [zernike_nm(j, ordering) for j in range(first, first + num_terms)])
