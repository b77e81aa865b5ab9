"""Diffraction PSFs on the sensor's own pixels, from traced rays (for rendering; differentiable).

For each job (object point, depth, wavelength) an ``N x N`` grid of rays from the object point
fills the (1.1x enlarged) paraxial entrance pupil and is traced to the sensor.  The pupil
function is ``P = A exp(2πi L / λ)``: ``A = 1`` for rays that reach the sensor inside the
pupil disk (vignetting included), 0 otherwise; ``L`` the optical path from the object point
(a finite depth: a spherical wave; infinity: the plane wave through the first ray) to the
*reference sphere* centred on the ideal image ``C`` of the object point at that depth on the
sensor plane (:class:`~deeplens.render.scene.IdealCamera`) through the paraxial exit pupil's
centre.  Defocus of a depth that the sensor is not focused on, distortion and lateral colour
are therefore in ``L``, and the kernel is centred on the ideal image like the geometric one
(:mod:`.psf`).

Propagation (Debye): ``U(x) = Σ_k P_k exp(2πi n' u_k·(x - C) / λ)`` with ``u_k`` the reference
sphere's normal at ray ``k``; its transverse part is fitted as affine in the grid indices
(least squares over the valid rays), so the sum is a *matrix Fourier transform*
``U = E_y P E_x^T`` evaluated directly at ``S x S`` points inside each of the ``K x K``
sensor pixels (pixel integration by the ``S``-point Gauss-Legendre rule per side,
``S = ceil(5 NA pitch / λ)``; beyond ``MAX_SUB_POINTS`` = 64, a PSF much sharper than the
pixel, exactly: the pupil's autocorrelation times the pixel's sinc, :func:`_kernel_exact`),
not on the FFT's native grid.  Energy: by Parseval the whole PSF (one
period ``1 / Δν`` of the sampled pupil's transform) holds ``Σ A² / (Δν_x Δν_y)``; kernels are
divided by it, so a kernel sums to the fraction of the light the lens transmits that falls in
it (>= ``energy``, 99.5 % by default, when ``K`` is chosen automatically).

Sampling (:func:`choose_sampling`): ``N`` so that the wavefront changes by less than
``max_step_waves`` (1/4 wave) between neighbouring samples and the transform's period holds
the kernel with a margin; ``K`` from the rays' spread plus the diffraction halo, grown until
the kernel holds ``energy``.  Memory is estimated before tracing
(:class:`PSFMemoryError` names the setting to change).

Index convention as :mod:`.psf`: row = sensor row, pixel ``K // 2`` centred on the ideal image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..optics.camera import unpack
from ..optics.paraxial import exit_pupil
from ..optics.rays import Rays
from .scene import IdealCamera
from ..optics.sampling import entrance_pupil

__all__ = ["DiffractionSampling", "PSFMemoryError", "diffraction_psf_many",
           "choose_sampling", "PUPIL_MARGIN", "PixelSamplingError", "PupilSamplingError"]

PUPIL_MARGIN = 1.1        # the traced grid spans 1.1x the paraxial entrance pupil
MAX_PUPIL_SAMPLES = 1024
FIT_DEGREE = 12          # the traced OPD's polynomial fit (see _smooth)
TRACE_SAMPLES = 64       # rays per side traced when the fit holds (finer grids: the fit)
FIT_MAX_RESIDUAL = 0.1   # waves RMS: a larger fit residual is the wavefront's own structure
MAX_SUB_POINTS = 64      # more points per pixel side than this: the exact pixel integral instead


class PupilSamplingError(ValueError):
    """The wavefront is too steep to sample (more than ``MAX_PUPIL_SAMPLES`` per side): the
    lens is far from the diffraction limit at this pixel pitch (its PSF is geometric)."""


class PixelSamplingError(PupilSamplingError):
    """The PSF is much sharper than a pixel (rays and diffraction halo within one pixel) and
    the pupil grid that keeps the sampled PSF's periodic copies off the kernel would exceed
    ``MAX_PUPIL_SAMPLES``: a sampling limit, not aberrations (the geometric PSF is close)."""


class PSFMemoryError(MemoryError):
    """The diffraction PSF would need more memory than allowed (message: how much, which
    setting to change)."""


@dataclass
class DiffractionSampling:
    """``pupil`` samples per side, kernel size ``kernel`` (odd), ``sub`` points per pixel side
    (above :data:`MAX_SUB_POINTS`: the exact pixel integral, :func:`_kernel_exact`, whatever
    the number)."""

    pupil: int
    kernel: int
    sub: int


def _grid(n: int, dtype, device):
    v = torch.linspace(-PUPIL_MARGIN, PUPIL_MARGIN, n, dtype=dtype, device=device)
    gy, gx = torch.meshgrid(v, v, indexing="ij")
    return gx, gy


def _ideal_xy(camera: IdealCamera, X: float, Y: float, depth_mm: float):
    if math.isinf(depth_mm):
        return camera.kappa * X, camera.kappa * Y
    s = camera.object_scale(depth_mm)
    return X / s, Y / s


def _trace(lens, sensor, jobs, n: int, options=None):
    """Trace an ``n x n`` pupil grid per job; returns the pupil data per job (see
    :func:`_pupil_function`)."""
    dtype, device = lens.dtype, lens.device
    z_ep, r_ep, z0 = entrance_pupil(lens)
    gx, gy = _grid(n, dtype, device)
    inside = (gx ** 2 + gy ** 2) <= PUPIL_MARGIN ** 2
    E = torch.stack([gx * r_ep, gy * r_ep, torch.full_like(gx, z_ep)], -1).reshape(-1, 3)
    E = E.double()
    zs = _start_plane(lens)
    os_, ds, ls = [], [], []
    for (X, Y), depth, wl in jobs:
        n0 = float(lens.materials[0].n(torch.tensor([wl], dtype=torch.float64)).reshape(-1)[0])
        if math.isinf(depth):
            d = torch.tensor([X, Y, 1.0], dtype=torch.float64, device=E.device)
            d = (d / d.norm()).expand_as(E)
            o = E + ((zs - z_ep) / float(d[0, 2])) * d
            # from the plane wavefront through the axis point of the start plane
            L = n0 * (o * d).sum(-1)
        else:
            if not depth > 0:
                raise ValueError(f"point source depth must be > 0 mm, got {depth}")
            P = torch.tensor([X, Y, z0 - depth], dtype=torch.float64, device=E.device)
            d = E - P
            d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
            t = (zs - float(P[2])) / d[:, 2]
            o = P + t[:, None] * d
            # the path from the object point to the start plane, less a constant (the axial
            # distance), in float64: a float32 path of metres would be quantised to ~1 wave
            L = n0 * (t - (zs - float(P[2])))
        os_.append(o)
        ds.append(d)
        ls.append(L)
    w = torch.tensor([wl for _, _, wl in jobs], dtype=dtype, device=device)[:, None]
    cast = dict(dtype=dtype, device=device)
    rays = Rays(torch.stack(os_).to(**cast), torch.stack(ds).to(**cast),
                w.expand(len(jobs), n * n), opl=torch.stack(ls).to(**cast), normalize=False)
    out = lens.trace_to_sensor(rays, options=options)
    return out, inside.reshape(-1), (gx, gy)


def _start_plane(lens) -> float:
    from ..optics.sampling import start_plane_z
    return start_plane_z(lens)


def _pupil_function(lens, sensor, jobs, n, options=None, degree: int = FIT_DEGREE,
                    cache: dict | None = None):
    """Per job: ``(A (n, n), phase (n, n) radians, bx, by (direction-cosine slope per grid
    unit, tensors), n_image, max neighbour step (waves), ray spread (pixels))``.

    With the polynomial fit (``degree >= 0``) a grid finer than ``TRACE_SAMPLES`` per side is
    not traced: the fit of a ``TRACE_SAMPLES`` grid is evaluated on it and the vignetting mask
    interpolated (bilinear, threshold 1/2); a wavefront the fit does not hold is traced at
    ``n`` after all."""
    fit = degree is not None and degree >= 0
    nt = min(n, TRACE_SAMPLES) if fit else n
    if nt < n:
        try:
            return _pupil_function_traced(lens, sensor, jobs, nt, options, degree, n, cache)
        except _FitFailed:
            pass
    return _pupil_function_traced(lens, sensor, jobs, n, options, degree if fit else None, n,
                                  cache)


class _FitFailed(Exception):
    pass


def _pupil_function_traced(lens, sensor, jobs, n, options, degree, n_out, cache=None):
    out, inside, (gx, gy) = _trace(lens, sensor, jobs, n, options)
    camera = IdealCamera(lens, sensor)
    z_xp, _ = exit_pupil(lens)
    z_s = lens.z_sensor()
    w = torch.tensor([wl for _, _, wl in jobs], dtype=lens.dtype, device=lens.device)
    n_img = lens.materials[-1].n(w)
    if degree is not None and degree < 0:
        degree = None
    res = []
    for b, ((X, Y), depth, wl) in enumerate(jobs):
        cx, cy = _ideal_xy(camera, X, Y, depth)
        C = torch.stack([torch.as_tensor(cx, dtype=lens.dtype, device=lens.device),
                         torch.as_tensor(cy, dtype=lens.dtype, device=lens.device),
                         z_s.to(lens.dtype)])
        Exp = torch.stack([torch.zeros_like(z_s), torch.zeros_like(z_s), z_xp.to(z_s)])
        R = torch.linalg.vector_norm(C - Exp)
        o, d, opl = out.o[b], out.d[b], out.opl[b]
        valid = out.valid[b] & inside
        if not bool(valid.any()):
            raise ValueError(f"no ray from the object point {(X, Y)} at depth {depth} mm "
                             f"reaches the sensor at {wl:g} nm (fully vignetted)")
        safe = lambda t: torch.where(valid.reshape(-1, *([1] * (t.dim() - 1))), t,  # noqa
                                     torch.zeros_like(t))
        o, d, opl = safe(o), safe(d), safe(opl)
        v = o - C
        bq = (v * d).sum(-1)
        cq = (v * v).sum(-1) - R * R
        s = bq + torch.sqrt((bq * bq - cq).clamp_min(0.0))
        path = opl - n_img[b] * s
        lam = wl * 1e-6
        ref = (path * valid).sum() / valid.sum()
        W = torch.where(valid, (path - ref) / lam, torch.zeros_like(path)).reshape(n, n)
        if n_out != n:
            vm = valid.reshape(n, n)
            c = _fit(W, vm, degree, cache)
            with torch.no_grad():
                r = ((_evaluate(c, n, degree).to(W.dtype) - W) * vm).pow(2).sum() / vm.sum()
            if float(r.sqrt()) > FIT_MAX_RESIDUAL:
                raise _FitFailed
            mf = torch.nn.functional.interpolate(vm.to(torch.float64)[None, None], (n_out, n_out),
                                                 mode="bilinear", align_corners=True)[0, 0] >= 0.5
            Wf = _evaluate(c, n_out, degree).to(W.dtype)
            Wf = torch.where(mf, Wf, torch.zeros_like(Wf))
        else:
            W = _smooth(W, valid.reshape(n, n), degree, cache)
        S = o - s[:, None] * d
        u = (C - S) / R
        # affine fit of the sphere normal's transverse part in the grid coordinates
        m = valid.to(lens.dtype)
        bx = _slope(u[:, 0], gx.reshape(-1), m)
        by = _slope(u[:, 1], gy.reshape(-1), m)
        if n_out != n:
            W, Am = Wf, mf.to(lens.dtype)
            vm = mf
        else:
            Am, vm = m.reshape(n, n), valid.reshape(n, n)
        st = _step(W.detach(), vm)
        hx = (o[:, 0].detach() - float(cx))[valid].abs().max() / sensor.pixel_size_mm
        hy = (o[:, 1].detach() - float(cy))[valid].abs().max() / sensor.pixel_size_mm
        res.append((Am, 2 * math.pi * W, bx, by, n_img[b], st,
                    float(torch.maximum(hx, hy)), lam))
    return res


def _cheb(n: int, degree: int, device=None) -> torch.Tensor:
    """Chebyshev polynomials ``T_k(v)``, ``k <= degree``, at ``v = linspace(-1, 1, n)`` (the
    grid's ``g / 1.1``): ``(n, degree + 1)`` float64."""
    v = torch.linspace(-1.0, 1.0, n, dtype=torch.float64, device=device)
    T = [torch.ones_like(v), v]
    for _ in range(degree - 1):
        T.append(2 * v * T[-1] - T[-2])
    return torch.stack(T[:degree + 1], -1)


def _terms(degree: int):
    """``(i, j)`` of the basis terms ``T_i(x) T_j(y)``, ``i + j <= degree``, in basis order."""
    return [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]


def _basis(n: int, degree: int, device=None) -> torch.Tensor:
    """Chebyshev products ``T_i(x / 1.1) T_j(y / 1.1)``, ``i + j <= degree``, on the
    ``n x n`` grid: ``(n * n, terms)`` float64 (rows y, columns x)."""
    T = _cheb(n, degree, device)
    return torch.stack([T[:, j][:, None] * T[:, i][None, :] for i, j in _terms(degree)],
                       -1).reshape(n * n, -1)


def _evaluate(c: torch.Tensor, n: int, degree: int) -> torch.Tensor:
    """The fit ``Σ c_ij T_i(x) T_j(y)`` on the ``n x n`` grid, ``(n, n)`` float64, as the
    separable product ``T C Tᵀ`` (``C[j, i] = c_ij``): ``n² (degree + 1)`` operations instead of
    the full basis's ``n² terms`` (and none of its ``n² x terms`` memory)."""
    T = _cheb(n, degree, c.device)
    ij = torch.tensor(_terms(degree), device=c.device)
    C = torch.zeros(degree + 1, degree + 1, dtype=c.dtype, device=c.device)
    C = C.index_put((ij[:, 1], ij[:, 0]), c)
    return T @ C @ T.transpose(0, 1)


def _projector(m, degree: int, cache: dict | None):
    """``(sel, Π)``: the fit's samples (flat indices into the ``n x n`` grid: every
    ``n // 64``-th per side, valid under ``m``) and the least-squares map ``Π = (BᵀB + ε)⁻¹ Bᵀ``
    (``(terms, len(sel))`` float64) from their values to the coefficients.  It depends only on
    the mask, so ``cache`` (a dict, e.g. :class:`~.psf_model.PSFModel`'s) keeps it per mask
    across jobs and calls; ``Π`` carries no gradient (the fit stays linear in ``W``)."""
    n = m.shape[0]
    step = max(1, n // 64)
    sel = torch.zeros(n, n, dtype=torch.bool, device=m.device)
    sel[::step, ::step] = True
    sel = (sel & m).reshape(-1)
    key = None
    if cache is not None:
        key = ("fit", n, degree, str(m.device), sel.cpu().numpy().tobytes())
        if key in cache:
            return cache[key]
    Bs = _basis(n, degree, m.device)[sel]
    G = Bs.T @ Bs
    G = G + 1e-12 * torch.eye(G.shape[0], dtype=G.dtype, device=G.device) * G.diagonal().mean()
    out = (sel.nonzero()[:, 0], torch.linalg.solve(G, Bs.T))
    if cache is not None:
        if len(cache) >= 256:  # masks that drift with the lens: keep the cache bounded
            cache.clear()
        cache[key] = out
    return out


def _fit(W, m, degree, cache=None):
    """Least-squares coefficients (float64) of ``W`` (n, n) over the valid samples ``m`` in
    the basis of ``degree`` (:func:`_basis`), from every ``n // 64``-th sample per side."""
    sel, P = _projector(m, degree, cache)
    return P @ W.reshape(-1)[sel].to(torch.float64)


def _smooth(W, m, degree, cache=None):
    """The least-squares fit of ``W`` (n, n) over the valid samples ``m`` by the Chebyshev
    basis of ``degree`` (:func:`_basis`; ``None``: no fit), solved in float64 from every
    ``n // 64``-th sample per side (linear in ``W``, so gradients pass).  Removes the traced
    path's rounding noise (float32: ~0.05 waves per sample, which scatters a few % of the light
    into a halo).  When the fit leaves more than ``FIT_MAX_RESIDUAL`` waves RMS (a wavefront
    with structure beyond the degree, e.g. a wide field's high orders) the traced values are
    kept as they are."""
    if degree is None:
        return W
    n = W.shape[0]
    out = _evaluate(_fit(W, m, degree, cache), n, degree).to(W.dtype)
    with torch.no_grad():  # real structure beyond the fit's degree: keep the traced values
        res = ((out - W) * m).pow(2).sum() / m.sum().clamp_min(1)
    if float(res.sqrt()) > FIT_MAX_RESIDUAL:
        return W
    return torch.where(m, out, torch.zeros_like(out))


def _step(W, m, k: int = 4):
    """Largest wavefront change (waves) between neighbouring samples, as the change over ``k``
    samples divided by ``k`` (the traced path's rounding noise, ~0.05 waves in float32, would
    otherwise dominate a fine grid's neighbour differences)."""
    k = min(k, W.shape[0] - 1)
    dy = ((W[k:] - W[:-k]).abs() * (m[k:] & m[:-k])).max()
    dx = ((W[:, k:] - W[:, :-k]).abs() * (m[:, k:] & m[:, :-k])).max()
    return float(torch.maximum(dx, dy)) / k


def _slope(u, g, m):
    gm = (g * m).sum() / m.sum()
    um = (u * m).sum() / m.sum()
    return ((g - gm) * (u - um) * m).sum() / (((g - gm) ** 2) * m).sum()


def _kernel(A, phase, bx, by, n_img, lam, n, K, sub, pitch):
    """``(..., K, K)`` pixel-integrated kernels (Parseval-normalised) of pupil functions
    ``A, phase (..., n, n)`` with slopes ``bx, by``, index ``n_img`` and wavelength ``lam`` (mm)
    of shape ``(...)`` (or scalars): one batched matrix Fourier transform."""
    if sub > MAX_SUB_POINTS:
        return _kernel_exact(A, phase, bx, by, n_img, lam, n, K, pitch)
    dtype, device = A.dtype, A.device
    as_t = lambda v: torch.as_tensor(v, dtype=dtype, device=device)  # noqa: E731
    bx, by, n_img, lam = as_t(bx), as_t(by), as_t(n_img), as_t(lam)
    dg = 2 * PUPIL_MARGIN / (n - 1)
    g = torch.linspace(-PUPIL_MARGIN, PUPIL_MARGIN, n, dtype=dtype, device=device)
    # only the rows and columns where some pupil is non-zero (the 1.1x margin and the
    # vignetted edge add nothing to the sum: exact, and 10-20 % fewer operations)
    with torch.no_grad():
        on = (A != 0).reshape(-1, n, n).any(0)
        rows, cols = on.any(1).nonzero()[:, 0], on.any(0).nonzero()[:, 0]
    if len(rows) and len(cols):
        r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        A, phase = A[..., r0:r1, c0:c1], phase[..., r0:r1, c0:c1]
        gy, gx = g[r0:r1], g[c0:c1]
    else:
        gy = gx = g
    # sub-pixel points (pixels from the ideal image point): kernel pixel m spans
    # [m - K//2 - 1/2, m - K//2 + 1/2]
    # Gauss-Legendre points and weights inside each pixel (exact for polynomials of degree
    # 2 sub - 1 across the pixel; 1 point: the pixel centre)
    x, w = _gauss_legendre(sub)
    x = torch.as_tensor(x, dtype=dtype, device=device)
    w = torch.as_tensor(w, dtype=dtype, device=device)
    t = (torch.arange(K, dtype=dtype, device=device)[:, None] - K // 2 + x[None, :]).reshape(-1)
    yi = t * pitch           # rows: +y
    xj = -t * pitch          # columns: -x
    ky = (2 * math.pi * n_img * by / lam)[..., None, None]
    kx = (2 * math.pi * n_img * bx / lam)[..., None, None]
    ay = ky * (yi[:, None] * gy[None, :])   # (..., K sub, n)
    ax = kx * (xj[:, None] * gx[None, :])
    Ey = torch.complex(torch.cos(ay), torch.sin(ay))
    Ex = torch.complex(torch.cos(ax), torch.sin(ax))
    P = torch.complex(A * torch.cos(phase), A * torch.sin(phase))
    U = Ey @ P @ Ex.transpose(-1, -2)       # (..., K sub, K sub)
    I = U.real ** 2 + U.imag ** 2
    lead = I.shape[:-2]
    I = (I.reshape(*lead, K, sub, K, sub) * w[:, None, None] * w).sum((-3, -1))
    dnx = (n_img * bx * dg / lam).abs()
    dny = (n_img * by * dg / lam).abs()
    return I * (pitch * pitch) * (dnx * dny / (A * A).sum((-1, -2)))[..., None, None]


def _kernel_exact(A, phase, bx, by, n_img, lam, n, K, pitch):
    """:func:`_kernel` with the pixel integral done exactly (issue 38: a PSF much sharper than
    a pixel slipped between a capped number of sub-pixel points).  The sampled pupil makes the
    intensity a trigonometric polynomial, ``I(y, x) = Σ_{m,l} C_ml exp(i k_y m Δg y)
    exp(i k_x l Δg x)`` with ``C`` the pupil's autocorrelation (the OTF on the pupil grid,
    ``C_ml = Σ P_{r+m,c+l} conj(P_rc)``, by FFT), so its mean over a pixel multiplies each term
    by the pixel's transfer function ``sinc(k m Δg p / 2)`` (``sin u / u``): the kernel is
    ``Re(M_y C M_x^T)`` with ``M (K, 2n)`` the phase factors at the pixel centres times that
    sinc.  Exact for every pitch; cost ``O(n² log n + K n²)`` whatever the pitch."""
    dtype, device = A.dtype, A.device
    as_t = lambda v: torch.as_tensor(v, dtype=dtype, device=device)  # noqa: E731
    bx, by, n_img, lam = as_t(bx), as_t(by), as_t(n_img), as_t(lam)
    dg = 2 * PUPIL_MARGIN / (n - 1)
    with torch.no_grad():   # crop the rows and columns where no pupil is non-zero (exact)
        on = (A != 0).reshape(-1, n, n).any(0)
        rows, cols = on.any(1).nonzero()[:, 0], on.any(0).nonzero()[:, 0]
    if len(rows) and len(cols):
        r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        A, phase = A[..., r0:r1, c0:c1], phase[..., r0:r1, c0:c1]
    R, C = A.shape[-2:]
    P = torch.complex(A * torch.cos(phase), A * torch.sin(phase))
    F = torch.fft.fft2(P, s=(2 * R, 2 * C))
    corr = torch.fft.ifft2(torch.complex(F.real ** 2 + F.imag ** 2, torch.zeros_like(F.real)))
    # lag of each index (0 .. R-1, then -R .. -1), and the pixel centres (rows +y, columns -x)
    my = torch.fft.fftfreq(2 * R, 1.0 / (2 * R), dtype=dtype, device=device)
    mx = torch.fft.fftfreq(2 * C, 1.0 / (2 * C), dtype=dtype, device=device)
    t = torch.arange(K, dtype=dtype, device=device) - K // 2
    ky = (2 * math.pi * n_img * by / lam)[..., None, None]
    kx = (2 * math.pi * n_img * bx / lam)[..., None, None]
    wy = ky * dg * my            # (..., 1, 2R) angular frequency of each lag, rad/mm
    wx = kx * dg * mx

    def factors(w, centre):      # (..., K, 2R): exp(i w c) sinc(w p / 2)
        a = w * centre[:, None]
        sinc = torch.sinc(w * (pitch / (2 * math.pi)))
        return torch.complex(torch.cos(a) * sinc, torch.sin(a) * sinc)

    My, Mx = factors(wy, t * pitch), factors(wx, -t * pitch)
    I = (My @ corr @ Mx.transpose(-1, -2)).real
    dnx = (n_img * bx * dg / lam).abs()
    dny = (n_img * by * dg / lam).abs()
    return I * (pitch * pitch) * (dnx * dny / (A * A).sum((-1, -2)))[..., None, None]


def _kernels(pf, n, K, sub, pitch, chunk_elements: int = 2 ** 23):
    """The kernels of :func:`_pupil_function`'s results ``pf``, batched (in chunks of at most
    ``chunk_elements`` transform outputs)."""
    per = max(1, chunk_elements // (K * sub) ** 2)
    out = []
    for k in range(0, len(pf), per):
        ch = pf[k:k + per]
        stack = lambda i: torch.stack([torch.as_tensor(p[i]) for p in ch])  # noqa: E731
        A, ph = stack(0), stack(1)
        out.extend(_kernel(A, ph, stack(2).to(A), stack(3).to(A), stack(4).to(A),
                           torch.tensor([p[7] for p in ch], dtype=A.dtype, device=A.device),
                           n, K, sub, pitch).unbind(0))
    return out


def _gauss_legendre(n: int):
    """Nodes in ``[-1/2, 1/2]`` and weights summing to 1 of the ``n``-point Gauss-Legendre rule."""
    import numpy as np

    x, w = np.polynomial.legendre.leggauss(int(n))
    return (0.5 * x).tolist(), (0.5 * w).tolist()


def _halo_px(lam_mm, n_img, bx, pitch):
    """A generous diffraction halo (pixels): 2 Airy radii of the pupil's numerical aperture."""
    na = abs(float(n_img * bx)) * 1.0  # direction cosine at the unit pupil radius
    airy = 0.61 * lam_mm / max(na, 1e-9)
    return 2 * airy / pitch


def choose_sampling(lens, sensor, jobs, options=None, max_step_waves: float = 0.25,
                    energy: float = 0.995, max_kernel: int = 129, start: int = 64,
                    memory_limit_gb: float = 2.0, cache: dict | None = None
                    ) -> DiffractionSampling:
    """Pupil samples, kernel size and sub-pixel points for ``jobs`` (module docstring), from a
    trace of ``start`` samples per side without autograd (``cache``: as for
    :func:`diffraction_psf_many`; ``lens``: a lens or a
    :class:`~deeplens.optics.camera.Camera`, ``sensor`` then ``None``).  Raises
    :class:`PSFMemoryError`."""
    lens, sensor, options = unpack(lens, sensor, options, "choose_sampling")
    with torch.no_grad():
        n = start
        for _ in range(6):
            pf = _pupil_function(lens, sensor, jobs, n, options, cache=cache)
            step = max(p[5] for p in pf)
            need = int(math.ceil(n * step / max_step_waves)) if step > 0 else n
            if need <= n:
                break
            n = need + (need % 2)
            if n > MAX_PUPIL_SAMPLES:
                raise PupilSamplingError(
                    f"diffraction PSF: the wavefront changes by {step:.3g} waves between "
                    f"neighbouring pupil samples and would need {n} per side (at most "
                    f"{MAX_PUPIL_SAMPLES}): the lens is far from the diffraction limit at this "
                    f"pixel pitch: use render.psf_model=geometric")
            check_memory(len(jobs), n, max_kernel, 1, memory_limit_gb, lens.dtype)
        pitch = sensor.pixel_size_mm
        K = 3
        for p in pf:
            A, ph, bx, by, n_img, _, spread, lam = p
            K = max(K, 2 * int(math.ceil(spread + _halo_px(lam, n_img, bx, pitch))) + 1)
        K = min(K, max_kernel | 1)
        # Gauss-Legendre points per pixel side: pitch * 5 NA / λ (measured against the closed-form
        # pixel-integrated Airy pattern: <= 0.1 % of the peak at 1-4 λN pixels)
        sub = 1
        for p in pf:
            A, ph, bx, by, n_img, _, spread, lam = p
            na = max(abs(float(n_img * bx)), abs(float(n_img * by))) * PUPIL_MARGIN
            sub = max(sub, int(math.ceil(pitch * 5 * na / lam)))
        # no cap: beyond MAX_SUB_POINTS the transform integrates the pixel exactly (issue 38)
        n = _period_samples(pf, n, K, pitch)
        check_memory(len(jobs), n, K, sub, memory_limit_gb, lens.dtype)
        # grow K until it holds `energy` of the light (the period growing with it)
        for _ in range(12):
            pf = _pupil_function(lens, sensor, jobs, n, options, cache=cache)
            kers = _kernels(pf, n, K, sub, pitch)
            least = min(float(k.sum()) for k in kers)
            if least >= energy or K >= (max_kernel | 1):
                break
            K = min(K + 2 * max(2, K // 4), max_kernel | 1)
            n = _period_samples(pf, n, K, pitch)
            check_memory(len(jobs), n, K, sub, memory_limit_gb, lens.dtype)
        return DiffractionSampling(n, K, sub)


def _period_samples(pf, n, K, pitch):
    """Pupil samples so that the transform's period ``λ / (n' b Δg)`` is >= 1.5 K pixels."""
    for p in pf:
        b = max(abs(float(p[2])), abs(float(p[3])))
        period_px = p[7] / (float(p[4]) * b * 2 * PUPIL_MARGIN / (n - 1)) / pitch
        if period_px < 1.5 * K:
            n = int(math.ceil((n - 1) * 1.5 * K / period_px)) + 1
            n += n % 2
    if n > MAX_PUPIL_SAMPLES:
        # which limit: the rays' spread (aberrations) or the pixel being much wider than the
        # diffraction pattern of a sharp PSF (issue 38: a perfect lens was told it was
        # aberrated)
        spread = max(float(p[6]) for p in pf)
        halo = max(_halo_px(p[7], p[4], max(abs(float(p[2])), abs(float(p[3]))), pitch)
                   for p in pf)
        head = (f"diffraction PSF: {n} pupil samples per side needed (at most "
                f"{MAX_PUPIL_SAMPLES}) for a {K}-pixel kernel")
        if spread + halo <= 1.0:
            raise PixelSamplingError(
                f"{head}: the PSF is much sharper than a pixel at this pitch ({pitch * 1e3:.3g} "
                f"um pixels, the rays within {spread:.2g} pixels, the diffraction halo within "
                f"{halo:.2g} pixels): a pupil grid fine enough to keep the sampled PSF's "
                f"periodic copies off the kernel is too large, and the geometric PSF is then "
                f"close to the diffraction one: use render.psf_model=geometric")
        raise PupilSamplingError(
            f"{head}: the lens is far from the diffraction limit at this pixel pitch (the rays "
            f"spread over {spread:.3g} pixels): use render.psf_model=geometric")
    return n


def check_memory(jobs: int, n: int, K: int, sub: int, limit_gb: float, dtype):
    """Raise :class:`PSFMemoryError` when the PSFs' trace and transforms would exceed
    ``limit_gb`` (estimate: ~60 tensors of the traced rays kept for the backward pass, and the
    complex transform matrices)."""
    b = torch.finfo(dtype).bits // 8
    if sub > MAX_SUB_POINTS:   # the exact pixel integral: FFTs of 2n x 2n, (K, 2n) factors
        transforms = 4 * (2 * n) ** 2 * 2 * b + 4 * K * 2 * n * 2 * b + 4 * K * K * 2 * b
    else:
        transforms = 4 * K * sub * n * 2 * b + 4 * (K * sub) ** 2 * 2 * b
    need = jobs * (n * n * 60 * b + transforms)
    if need > limit_gb * 2 ** 30:
        raise PSFMemoryError(
            f"diffraction PSF: {jobs} PSFs of {n}x{n} pupil samples and {K}x{K} pixels "
            f"({sub}x{sub} points each) need about {need / 2 ** 30:.2f} GiB, more than "
            f"render.psf_memory_gb = {limit_gb:g}: raise render.psf_memory_gb, use fewer depths "
            f"or wavelengths, a smaller render.psf_max_kernel, or render.psf_model=geometric")


def diffraction_psf_many(lens, sensor, jobs, sampling: DiffractionSampling | None = None,
                         kernel_size=None, options=None, return_info: bool = False,
                         cache: dict | None = None, **choose):
    """Diffraction PSFs ``(K, K)`` of ``jobs = [(point_xy_mm, depth_mm, wavelength_nm)]``, all
    traced together (one ``(J, N²)`` batch); differentiable in every lens parameter.

    Args:
        lens, sensor: a :class:`~deeplens.optics.camera.Camera` and ``None`` (its options are
            the traces'), or a lens and its sensor (with ``options``).
        sampling: fixed :class:`DiffractionSampling` (``None``: :func:`choose_sampling`).
        kernel_size: force ``K`` (odd) for every job (overrides ``sampling.kernel``).
        return_info: also return ``{"max_step_waves", "energy"}`` measured on this trace (the
            caller checks the sampling still holds).
        cache: a dict kept between calls (e.g. :class:`~.psf_model.PSFModel`'s): the OPD fit's
            least-squares map per vignetting mask (no gradient is cached).
        choose: keyword arguments of :func:`choose_sampling`.

    Returns:
        A list of kernels (and the info dict with ``return_info``).
    """
    lens, sensor, options = unpack(lens, sensor, options, "diffraction_psf_many")
    jobs = [(tuple(float(v) for v in p), float(d), float(w)) for p, d, w in jobs]
    if not jobs:
        return ([], {}) if return_info else []
    if sampling is None:
        sampling = choose_sampling(lens, sensor, jobs, options, **choose)
    K = int(kernel_size or sampling.kernel)
    if K % 2 == 0:
        raise ValueError(f"kernel_size must be odd, got {K}")
    n = sampling.pupil
    pf = _pupil_function(lens, sensor, jobs, n, options, cache=cache)
    kers = _kernels(pf, n, K, sampling.sub, sensor.pixel_size_mm)
    if return_info:
        return kers, {"max_step_waves": max(p[5] for p in pf),
                      "energy": min(float(k.detach().sum()) for k in kers)}
    return kers
