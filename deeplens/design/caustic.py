"""Caustic design (paper Sec. V-A, Eq. 11): a refractive B-spline freeform whose irradiance on a
screen at distance ``D`` reproduces a target picture.

    min_θ  || E(θ) - T ||^2 ,        E(θ) = splat( trace(rays; θ) ) * res^2 / N

A collimated beam (wavelength 532.8 nm) fills the square ``[-a, a]^2`` of a flat glass plate
(index 1.5, non-dispersive), crosses it and leaves through the freeform back face
``z = sum C[p, q] N_p(x) N_q(y)`` (bicubic B-spline, :class:`~deeplens.optics.surfaces.BSpline`,
coefficients ``θ = C``).  The screen is the lens's sensor plane, ``D`` mm behind the freeform
vertex, a ``res x res`` pixel grid of the same ``2a x 2a`` size as the beam.  ``N`` rays on a
regular grid (``rays_per_pixel^2`` per screen pixel for the flat plate) are forward-traced and
splatted bilinearly (:func:`~deeplens.render.splat.splat_bilinear`), each with the weight
``res^2 / N``, so that an unchanged (flat) plate gives ``E = 1`` in every pixel; the target is
normalised to mean 1 (the same total power).  Both are smoothed by a Gaussian of ``sigma``
pixels, large during the first steps (coarse to fine): bilinear splatting moves a pixel's value
only by rays within one pixel, so without smoothing a ray far from where it belongs sees no
gradient.  The rays are re-jittered inside their grid cells at every step, and a curvature
penalty keeps neighbouring rays from crossing (see :func:`optimize_caustic`).

Lengths in mm, wavelength in nm.  The clear aperture of a B-spline surface is the disk of its
semi-diameter ``L``; the beam's square is inscribed in it (``L = a sqrt(2)`` plus a margin).
"""

from __future__ import annotations

import math
import time

import torch

from ..optics.camera import unpack
from ..optics.lens import Lens, LensSpec
from ..optics.materials import ModelGlass, get_material
from ..optics.rays import Rays
from ..optics.surfaces import BSpline, Plane
from ..render.sensor import Sensor
from ..render.splat import splat_bilinear

__all__ = ["CAUSTIC_WAVELENGTH_NM", "caustic_lens", "collimated_square_rays", "irradiance",
           "gaussian_blur", "load_target", "optimize_caustic", "sag_map"]

CAUSTIC_WAVELENGTH_NM = 532.8


def caustic_lens(half_width_mm: float, n_ctrl: int, distance_mm: float,
                 thickness_mm: float = 2.0, index: float = 1.5) -> Lens:
    """A flat entrance face, glass of ``index`` (non-dispersive), and a B-spline exit face.

    Args:
        half_width_mm: half-width ``a`` of the square beam and screen (mm).
        n_ctrl: control points per side of the B-spline (``>= 4``).
        distance_mm: freeform vertex to screen (the sensor distance), mm.
        thickness_mm: plate thickness on axis, mm.
        index: refractive index of the plate.

    Returns:
        A :class:`Lens` whose ``surfaces[1].coefficients`` (``(n_ctrl, n_ctrl)``, mm, zero:
        a flat plate) is the design variable.
    """
    if not (half_width_mm > 0 and distance_mm > 0 and thickness_mm > 0):
        raise ValueError(f"caustic lens: half-width, distance and thickness must be > 0 mm, got "
                         f"{half_width_mm}, {distance_mm}, {thickness_mm}")
    if int(n_ctrl) < 4:
        raise ValueError(f"caustic lens: need at least 4 control points per side, got {n_ctrl}")
    L = half_width_mm * math.sqrt(2.0) * 1.02
    glass = ModelGlass(index, math.inf, name=f"{index!r}/inf")
    surfaces = [Plane(L), BSpline(L, torch.zeros(int(n_ctrl), int(n_ctrl)))]
    spec = LensSpec(wavelengths_nm=[CAUSTIC_WAVELENGTH_NM])
    return Lens(surfaces, [get_material("AIR"), glass, get_material("AIR")],
                [0.0, thickness_mm], distance_mm, 0, spec=spec, name="caustic plate")


def collimated_square_rays(half_width_mm: float, n_side: int, z0_mm: float = -1.0,
                           wavelength_nm: float = CAUSTIC_WAVELENGTH_NM,
                           dtype=torch.float64, device=None,
                           generator: torch.Generator | None = None) -> Rays:
    """``n_side^2`` rays parallel to ``+z`` over the square ``[-a, a]^2`` at ``z = z0_mm``: one
    per cell of a regular ``n_side x n_side`` grid, at the cell centre, or uniformly jittered
    inside its cell when a ``generator`` is given (stratified sampling)."""
    h = 2 * half_width_mm / n_side
    u = -half_width_mm + h * (torch.arange(n_side, dtype=dtype, device=device) + 0.5)
    X, Y = torch.meshgrid(u, u, indexing="ij")
    X, Y = X.reshape(-1), Y.reshape(-1)
    if generator is not None:
        jit = torch.rand((2, X.numel()), generator=generator, dtype=dtype) - 0.5
        X, Y = X + h * jit[0].to(X.device), Y + h * jit[1].to(X.device)
    o = torch.stack([X, Y, torch.full_like(X, z0_mm)], -1)
    d = torch.zeros_like(o)
    d[:, 2] = 1.0
    return Rays(o, d, wavelength_nm)


def irradiance(lens: Lens, rays: Rays, res: int, half_width_mm: float,
               options=None) -> torch.Tensor:
    """Irradiance ``(res, res)`` on the sensor plane of ``lens``, normalised so that a beam that
    arrives undeflected and uniform reads 1 in every pixel.  Differentiable in the lens.

    Pixels follow :class:`~deeplens.render.sensor.Sensor` (row ``i`` along ``+y``, column ``j``
    along ``-x``), pitch ``2a / res``.  ``lens``: a Lens (traced with ``options``, ``None``:
    the defaults) or a :class:`~deeplens.optics.camera.Camera` (its options are used).
    """
    lens, _, options = unpack(lens, None, options, "irradiance")
    sensor = Sensor((res, res), 2 * half_width_mm / res, channels=[[CAUSTIC_WAVELENGTH_NM]])
    out = lens.trace_to_sensor(rays, options=options)
    i, j = sensor.xy_to_pixel(out.o[:, 0], out.o[:, 1])
    n = rays.shape[0]
    w = torch.where(out.valid, torch.full_like(i, res * res / n), torch.zeros_like(i))
    i = torch.where(out.valid, i, torch.zeros_like(i))
    j = torch.where(out.valid, j, torch.zeros_like(j))
    return splat_bilinear(i, j, w, (res, res))


def gaussian_blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of a ``(H, W)`` image (zero padding), ``sigma`` in pixels;
    ``sigma <= 0`` returns ``img``."""
    if sigma <= 0:
        return img
    r = max(1, int(math.ceil(3 * sigma)))
    x = torch.arange(-r, r + 1, dtype=img.dtype, device=img.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    im = img[None, None]
    im = torch.nn.functional.conv2d(im, k.view(1, 1, 1, -1), padding=(0, r))
    im = torch.nn.functional.conv2d(im, k.view(1, 1, -1, 1), padding=(r, 0))
    return im[0, 0]


def load_target(name: str, res: int, floor: float = 0.0, dtype=torch.float64) -> torch.Tensor:
    """A grey picture bundled with scikit-image (``camera``, ``moon``, ``brick``, ``grass``,
    ``gravel``, ``text``, ``coins``, ``page``, ...), centre-cropped square, resized to
    ``(res, res)``, mapped to ``floor + (1 - floor) * image`` and normalised to mean 1.

    Raises:
        ValueError: unknown name, a colour image, or ``res < 4``.
    """
    import numpy as np
    import skimage.data
    from skimage.transform import resize

    if res < 4:
        raise ValueError(f"--resolution must be >= 4 pixels, got {res}")
    fn = getattr(skimage.data, name, None)
    grey = ["camera", "moon", "brick", "grass", "gravel", "text", "coins", "page", "horse",
            "clock", "checkerboard"]
    if fn is None or not callable(fn) or name.startswith("_"):
        raise ValueError(f"--target: {name!r} is not an image bundled with scikit-image; grey "
                         f"ones include {', '.join(grey)}")
    img = np.asarray(fn(), dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"--target: {name!r} is not a grey image (shape {img.shape}); grey ones "
                         f"include {', '.join(grey)}")
    h, w = img.shape
    s = min(h, w)
    img = img[(h - s) // 2:(h - s) // 2 + s, (w - s) // 2:(w - s) // 2 + s]
    img = resize(img, (res, res), anti_aliasing=True)
    img = (img - img.min()) / max(img.max() - img.min(), 1e-12)
    img = floor + (1 - floor) * img
    t = torch.as_tensor(img, dtype=dtype)
    return t / t.mean()


def sag_map(lens: Lens, half_width_mm: float, n: int = 128) -> torch.Tensor:
    """Freeform height ``(n, n)`` in mm over the beam's square, in the screen's pixel layout."""
    s = lens.surfaces[1]
    sensor = Sensor((n, n), 2 * half_width_mm / n, channels=[[CAUSTIC_WAVELENGTH_NM]])
    with torch.no_grad():
        x, y = sensor.pixel_centers(dtype=s.coefficients.dtype)
        return s.sag(x, y)


def optimize_caustic(target: torch.Tensor, *, half_width_mm: float, distance_mm: float,
                     n_ctrl: int, rays_per_pixel: int = 2, steps: int = 300, lr_px: float = 1.0,
                     sigma0: float = 4.0, sigma1: float = 0.5, coarse_fraction: float = 0.6,
                     smooth: float = 0.01, snapshots=(), eval_rays_per_pixel: int = 6,
                     seed: int = 0, dtype=torch.float32, callback=None) -> dict:
    """Adam on the B-spline coefficients (Eq. 11) for one screen distance.

    Args:
        target: ``(res, res)`` target irradiance, mean 1 (:func:`load_target`).
        half_width_mm, distance_mm, n_ctrl: see :func:`caustic_lens`.
        rays_per_pixel: rays per screen pixel per side (``(res * k)^2`` rays in all), freshly
            jittered in their cells at every step (seeded by ``seed``): with fixed samples the
            optimiser fits the splat of those few rays, and a dense rendering of the same
            surface shows caustic folds between them.
        steps: Adam iterations.
        lr_px: Adam step expressed as the screen displacement (pixels) it causes: a change
            ``c`` of one coefficient tilts the surface by about ``c / h`` (``h`` the knot
            spacing) and moves rays by ``(n - 1) D c / h``, so the coefficient step is
            ``lr_px * pixel * h / ((n - 1) D)`` mm; decayed to a tenth along a cosine.
        sigma0, sigma1: smoothing of image and target (pixels), decreased linearly from
            ``sigma0`` to ``sigma1`` over the first ``coarse_fraction`` of the steps (the
            final ``sigma1`` suppresses the ray-sampling speckle the fit would chase).
        smooth: weight of a curvature penalty ``mean(g_xx^2 + g_yy^2)``, ``g = (n - 1) D
            Δ²C / h²`` the gradient of the ray displacement (dimensionless; ``g = -1`` is a
            fold, where rays cross and the irradiance has a caustic line).
        snapshots: step indices at which the irradiance (detached) is kept.
        eval_rays_per_pixel: rays per pixel per side for the snapshots and the returned final
            irradiance (forward only): the design is a smooth surface, and the speckle of the
            few rays the optimiser traces is a property of the sampling, not of the caustic.
        dtype: tracing precision (float32 by default: 3-4x faster on a CPU than float64, and
            the intersection tolerance of 1e-5 mm is far below a screen pixel).

    Returns:
        ``{"lens", "irradiance" (res, res) (final, with ``eval_rays_per_pixel``), "snapshots":
        {step: (res, res)}, "loss": [...] (per step, smoothed MSE + penalty), "seconds"}``.
    """
    t0 = time.perf_counter()
    res = int(target.shape[-1])
    lens = caustic_lens(half_width_mm, n_ctrl, distance_mm).to(dtype)
    target = target.to(dtype)
    gen = torch.Generator().manual_seed(seed)
    coef = lens.surfaces[1].coefficients
    coef.requires_grad_(True)
    h = 2 * float(lens.surfaces[1].semi_diameter) / (n_ctrl - 3)
    n_glass = float(lens.materials[1].n(CAUSTIC_WAVELENGTH_NM))
    lr = lr_px * (2 * half_width_mm / res) * h / ((n_glass - 1) * distance_mm)
    opt = torch.optim.Adam([coef], lr=lr)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda k: 0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(k / max(steps, 1), 1.0))))
    eval_rays = collimated_square_rays(half_width_mm, res * eval_rays_per_pixel, dtype=dtype)
    snaps, losses = {}, []
    n_coarse = max(1, int(coarse_fraction * steps))
    for k in range(steps + 1):
        if k in snapshots or k == steps:
            with torch.no_grad():
                E_eval = irradiance(lens, eval_rays, res, half_width_mm)
            snaps[k] = E_eval
        if k == steps:
            break
        sigma = sigma1 + (sigma0 - sigma1) * max(0.0, 1.0 - k / n_coarse)
        rays = collimated_square_rays(half_width_mm, res * rays_per_pixel, dtype=dtype,
                                      generator=gen)
        E = irradiance(lens, rays, res, half_width_mm)
        loss = ((gaussian_blur(E, sigma) - gaussian_blur(target, sigma)) ** 2).mean()
        if smooth > 0:
            k2 = (n_glass - 1) * distance_mm / h ** 2
            gxx = k2 * (coef[2:] - 2 * coef[1:-1] + coef[:-2])
            gyy = k2 * (coef[:, 2:] - 2 * coef[:, 1:-1] + coef[:, :-2])
            loss = loss + smooth * ((gxx ** 2).mean() + (gyy ** 2).mean())
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(float(loss.detach()))
        if callback is not None:
            callback(k, float(loss.detach()))
    coef.requires_grad_(False)
    return {"lens": lens, "irradiance": E_eval, "snapshots": snaps, "loss": losses,
            "seconds": time.perf_counter() - t0}
