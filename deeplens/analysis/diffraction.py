"""Diffraction: PSF from the pupil function (FFT and Huygens), Strehl ratio, MTF, encircled energy.

Pupil function on an ``N x N`` grid of normalised entrance-pupil coordinates (the wavefront of
:mod:`.wavefront`, ``W`` in waves): ``P(p) = A(p) exp(-2πi W(p))``, ``A = 1`` for rays that reach
the image and 0 otherwise.  In the Fraunhofer (Debye) approximation the image-plane amplitude
is the Fourier transform of ``P`` over the image-space direction cosines, so

    PSF = |FFT_M(P)|^2 / (Σ A)^2          (zero-padded to ``M x M``, ``M = 2N`` by default),

normalised so that the aberration-free pupil of the same shape peaks at 1: the Strehl ratio
is the peak of this PSF.  One pupil sample spans ``δ = |Δd_⊥| / (N - 1)`` in direction
cosine, where ``Δd_⊥`` is the difference of the image-plane components of the directions of
the opposite marginal rays (``p_y = ±1`` tangential, ``p_x = ±1`` sagittal), so one step of
the optical transfer function is ``Δν = n' δ / λ`` (cycles/mm) and one PSF pixel is
``1 / (M Δν)`` mm.  The same calibration as optiland and Zemax; it assumes the map from pupil
coordinates to direction cosines is close to affine.

MTF (diffraction): ``|FFT(PSF)| / FFT(PSF)(0)``, sampled at ``k Δν``; tangential along ``y``
(the meridional plane of a field on the ``y`` axis), sagittal along ``x``.  At one frequency
``ν`` (:func:`mtf_at`, differentiable): ``|Σ_x PSF(x) e^{-2πi ν·x}| / Σ_x PSF(x)``, a direct
transform of the sampled PSF.  MTF (geometric): the same transform of the spot diagram,
``|mean_k e^{-2πi ν (y_k - ȳ)}|``.

Huygens PSF: the wavefront on the reference sphere (points ``S_k``) as secondary sources,
``U(x) = Σ_k A_k e^{-2πi W_k} e^{2πi n' |x - S_k| / λ} R / |x - S_k|`` on an image-plane grid
around the chief-ray point, normalised the same way.  Slower (``N² K²`` terms) but free of the
affine assumption and of the FFT's fixed pixel size.

Encircled energy: the fraction of the PSF (or of the spot's rays) within radius ``r`` of its
centroid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..optics.camera import unpack
from ..optics.options import TraceOptions
from .checks import AnalysisError
from .spot import spot_diagram
from .wavefront import Wavefront, pupil_grid, trace_pupil, wavefront

__all__ = ["PSF", "psf_fft", "sampled_wavefront", "psf_huygens", "strehl", "MTF", "mtf", "mtf_at", "geometric_mtf",
           "encircled_energy", "frequency_steps"]


def _aim(options) -> TraceOptions:
    """The options of an aiming trace: ``options`` (``None``: the defaults) without clear
    apertures."""
    return (options or TraceOptions()).replace(clip_aperture=False)


def frequency_steps(lens, field_deg: float, wavelength_nm: float, n: int,
                    image_plane="sensor", options=None) -> tuple[torch.Tensor, torch.Tensor]:
    """``(Δν_t, Δν_s)`` in cycles/mm: one pupil-sample lag of an ``n``-point pupil grid.

    ``Δν = n' |Δd_⊥| / ((n - 1) λ)`` from the directions of the four marginal rays on the image
    plane (normal ``+z``), traced through every surface regardless of clear apertures (as
    optiland does: a vignetted pupil still has a direction-cosine scale); raises
    :class:`AnalysisError` when a marginal ray misses a surface.  ``lens``: a lens (with
    ``options``) or a :class:`~deeplens.optics.camera.Camera`, as for every function here."""
    lens, _, options = unpack(lens, None, options, "frequency_steps")
    dtype = lens.dtype
    m = torch.tensor([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0]], dtype=dtype,
                     device=lens.device)
    tr = trace_pupil(lens, field_deg, wavelength_nm, m, image_plane, options=_aim(options))
    if not bool(tr.mask.all()):
        raise AnalysisError(f"a marginal ray of field {field_deg:g} deg at {wavelength_nm:g} nm "
                            f"misses a surface: the pupil-to-frequency scale is undefined")
    d = tr.directions[..., :2]
    lam = wavelength_nm * 1e-6
    dt = torch.linalg.vector_norm(d[0] - d[1])
    ds = torch.linalg.vector_norm(d[2] - d[3])
    return tr.n_image * dt / ((n - 1) * lam), tr.n_image * ds / ((n - 1) * lam)


@dataclass
class PSF:
    """A sampled PSF ``psf`` (K, K) (rows along ``y``), Strehl-normalised (perfect peak = 1).

    ``x``/``y`` (K,) are pixel positions in mm relative to the chief-ray image point ``center``
    (3,); ``strehl`` the peak value; ``wavefront`` the pupil data it came from."""

    psf: torch.Tensor
    x: torch.Tensor
    y: torch.Tensor
    center: torch.Tensor
    strehl: torch.Tensor
    wavefront: Wavefront
    method: str


MAX_STEP_WAVES = 0.5  # Nyquist for the pupil phase: < π between neighbouring samples
AUTO_STEP_WAVES = 0.4
MAX_AUTO_SAMPLES = 512


def _max_step(wf: Wavefront) -> float:
    """Largest change of the wavefront (waves) between neighbouring valid pupil samples."""
    with torch.no_grad():
        W, m = wf.opd, wf.mask
        dy = ((W[1:] - W[:-1]).abs() * (m[1:] & m[:-1])).max()
        dx = ((W[:, 1:] - W[:, :-1]).abs() * (m[:, 1:] & m[:, :-1])).max()
    return float(torch.maximum(dx, dy))


def sampled_wavefront(lens, field_deg: float, wavelength_nm: float, n: int | None = None,
                      image_plane="sensor", options=None) -> Wavefront:
    """The wavefront on a pupil grid fine enough for an FFT PSF.

    The pupil phase must change by less than half a wave between neighbouring samples, or light
    from the steep parts of the pupil wraps around the PSF grid (aliasing).  ``n=None`` picks
    the samples per side from a 64-sample trial (neighbour steps below 0.4 waves, at most 512);
    an explicit ``n`` is checked.

    Raises:
        AnalysisError: the wavefront is too steep for ``n`` (or for 512 samples), with the
            measured step and the sampling it would need.
    """
    lens, _, options = unpack(lens, None, options, "sampled_wavefront")
    if n is not None:
        if n < 8:
            raise ValueError(f"pupil sampling n must be >= 8, got {n}")
        wf = wavefront(lens, field_deg, wavelength_nm, n=n, image_plane=image_plane,
                       options=options)
        step = _max_step(wf)
        if step > MAX_STEP_WAVES:
            need = int(math.ceil(n * step / AUTO_STEP_WAVES))
            raise AnalysisError(
                f"field {field_deg:g} deg at {wavelength_nm:g} nm: the wavefront changes by "
                f"{step:.3g} waves between neighbouring pupil samples (n = {n}); the FFT PSF "
                f"aliases above {MAX_STEP_WAVES} waves: use n >= {need} (or n=None)")
        return wf
    wf = wavefront(lens, field_deg, wavelength_nm, n=64, image_plane=image_plane,
                   options=options)
    step = _max_step(wf)
    if step <= AUTO_STEP_WAVES:
        return wf
    need = 2 * int(math.ceil(64 * step / AUTO_STEP_WAVES / 2))
    if need > MAX_AUTO_SAMPLES:
        raise AnalysisError(
            f"field {field_deg:g} deg at {wavelength_nm:g} nm: the wavefront ({float(wf.rms):.4g} "
            f"waves RMS) would need {need} pupil samples per side for an FFT PSF (at most "
            f"{MAX_AUTO_SAMPLES}); the lens is far from the diffraction limit here: use the "
            f"geometric MTF / spot, or pass n explicitly")
    return wavefront(lens, field_deg, wavelength_nm, n=need, image_plane=image_plane,
                     options=options)


def psf_fft(lens, field_deg: float, wavelength_nm: float | None = None, n: int | None = None,
            grid: int | None = None, image_plane="sensor", options=None) -> PSF:
    """FFT PSF of one field and wavelength (see the module docstring); differentiable.

    Args:
        n: pupil samples per side (``None``: chosen by :func:`sampled_wavefront`).
        grid: FFT size (default ``2n``).

    Raises:
        AnalysisError: a field beyond reach, a wavelength out of range, or a pupil too coarse
            for the wavefront (:func:`sampled_wavefront`).
    """
    lens, _, options = unpack(lens, None, options, "psf_fft")
    wl = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    wf = sampled_wavefront(lens, field_deg, wl, n, image_plane, options)
    n = wf.opd.shape[0]
    grid = 2 * n if grid is None else int(grid)
    if grid < 2 * n - 1:
        raise ValueError(f"FFT grid {grid} is too small for a pupil of {n} samples: use at least "
                         f"2n ({2 * n}) or the MTF aliases")
    A = wf.mask.to(wf.opd.dtype)
    phase = -2 * math.pi * wf.opd
    P = torch.complex(A * torch.cos(phase), A * torch.sin(phase))
    before = (grid - n) // 2
    after = grid - n - before
    P = torch.nn.functional.pad(P, (before, after, before, after))
    U = torch.fft.fftshift(torch.fft.fft2(P))
    psf = (U.real ** 2 + U.imag ** 2) / A.sum() ** 2
    dnt, dns = frequency_steps(lens, field_deg, wl, n, image_plane, options)
    # orientation: the FFT axis runs along +x (+y) when the direction cosine falls across the
    # pupil (an imaging lens); otherwise the image is mirrored
    tr = trace_pupil(lens, field_deg, wl, torch.tensor([[0.0, 1.0], [1.0, 0.0]]).to(A),
                     image_plane, check=False, options=_aim(options))
    sy = -1.0 if float(tr.directions[0, 1] - tr.chief_direction[1]) > 0 else 1.0
    sx = -1.0 if float(tr.directions[1, 0] - tr.chief_direction[0]) > 0 else 1.0
    if sy < 0:
        psf = torch.flip(psf, (0,))
    if sx < 0:
        psf = torch.flip(psf, (1,))
    k = torch.arange(grid, dtype=A.dtype, device=A.device) - grid // 2
    if sy < 0 and grid % 2 == 0:
        k_y = k + 1
    else:
        k_y = k
    k_x = k + 1 if (sx < 0 and grid % 2 == 0) else k
    x = k_x / (grid * dns)
    y = k_y / (grid * dnt)
    return PSF(psf, x, y, wf.trace.chief_point, psf.max(), wf, "fft")


def psf_huygens(lens, field_deg: float, wavelength_nm: float | None = None, n: int = 48,
                size: int = 64, pixel_mm: float | None = None, image_plane="sensor",
                center=None, options=None) -> PSF:
    """Huygens PSF on a ``size x size`` grid of ``pixel_mm`` pixels (default: the FFT pixel of
    an ``n``-sample pupil at ``2n`` padding) centred on the chief-ray image point (or on
    ``center = (x, y)`` mm of the image plane, e.g. another model's pixel grid)."""
    lens, _, options = unpack(lens, None, options, "psf_huygens")
    wl = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    wf = wavefront(lens, field_deg, wl, n=n, image_plane=image_plane, options=options)
    if pixel_mm is None:
        dnt, dns = frequency_steps(lens, field_deg, wl, n, image_plane, options)
        pixel_mm = float(1.0 / (2 * n * torch.maximum(dnt, dns)))
    if not (pixel_mm > 0 and math.isfinite(pixel_mm)):
        raise ValueError(f"pixel_mm must be a positive number of mm, got {pixel_mm!r}")
    C = wf.reference_center
    if center is not None:
        C = torch.stack([torch.as_tensor(float(v), dtype=C.dtype, device=C.device)
                         for v in center[:2]] + [C[2]])
    k = (torch.arange(size, dtype=C.dtype, device=C.device) - size // 2) * pixel_mm
    Y, X = torch.meshgrid(k, k, indexing="ij")
    pts = torch.stack([X + C[0], Y + C[1], torch.zeros_like(X) + C[2]], -1).reshape(-1, 3)
    S = wf.sphere_points[wf.mask]  # (Q, 3)
    W = wf.opd[wf.mask]
    lam = wl * 1e-6
    n_img = wf.trace.n_image
    R = wf.reference_radius
    out = torch.zeros(pts.shape[0], dtype=C.dtype, device=C.device)
    for chunk in torch.split(torch.arange(pts.shape[0], device=C.device), 1024):
        r = torch.linalg.vector_norm(pts[chunk, None, :] - S[None], dim=-1)  # (c, Q)
        ph = 2 * math.pi * (n_img * (r - R) / lam - W[None])
        amp = R / r
        re = (amp * torch.cos(ph)).sum(-1)
        im = (amp * torch.sin(ph)).sum(-1)
        out[chunk] = re ** 2 + im ** 2
    psf = out.reshape(size, size) / S.shape[0] ** 2
    return PSF(psf, k, k, C, psf.max(), wf, "huygens")


def strehl(lens, field_deg: float, wavelength_nm: float | None = None, n: int | None = None,
           image_plane="sensor", options=None) -> torch.Tensor:
    """Strehl ratio: the FFT PSF's peak over the aberration-free peak (differentiable)."""
    return psf_fft(lens, field_deg, wavelength_nm, n=n, image_plane=image_plane,
                   options=options).strehl


@dataclass
class MTF:
    """Tangential and sagittal MTF (K,) at frequencies ``freq_t``/``freq_s`` (cycles/mm)."""

    freq_t: torch.Tensor
    mtf_t: torch.Tensor
    freq_s: torch.Tensor
    mtf_s: torch.Tensor
    field_deg: float
    wavelength_nm: float
    method: str

    def at(self, freq: float) -> tuple[float, float]:
        """Linear interpolation ``(tangential, sagittal)`` at ``freq`` cycles/mm."""
        def interp(f, m):
            f, m = f.detach().double(), m.detach().double()
            if freq > float(f[-1]):
                return 0.0
            i = int(torch.searchsorted(f, torch.tensor([freq], dtype=f.dtype))[0])
            i = min(max(i, 1), len(f) - 1)
            a = (freq - float(f[i - 1])) / float(f[i] - f[i - 1])
            return float(m[i - 1] * (1 - a) + m[i] * a)
        return interp(self.freq_t, self.mtf_t), interp(self.freq_s, self.mtf_s)


def mtf(lens, field_deg: float, wavelength_nm: float | None = None, n: int | None = None,
        grid: int | None = None, image_plane="sensor", options=None) -> MTF:
    """Diffraction MTF by FFT of the FFT PSF, tangential (``y``) and sagittal (``x``) slices
    from zero to ``grid/2`` steps (the cut-off lies at ``N - 1`` steps)."""
    lens, _, options = unpack(lens, None, options, "mtf")
    p = psf_fft(lens, field_deg, wavelength_nm, n=n, grid=grid, image_plane=image_plane,
                options=options)
    n = p.wavefront.opd.shape[0]
    g = p.psf.shape[0]
    O = torch.fft.fftshift(torch.fft.fft2(torch.fft.ifftshift(p.psf))).abs()
    c = g // 2
    dc = O[c, c]
    t = (O[c:, c][:c] / dc).clamp(0.0, 1.0)
    s = (O[c, c:][:c] / dc).clamp(0.0, 1.0)
    dnt, dns = frequency_steps(lens, field_deg, p.wavefront.trace.wavelength_nm, n, image_plane,
                               options)
    k = torch.arange(c, dtype=t.dtype, device=t.device)
    return MTF(k * dnt, t, k * dns, s, float(field_deg), p.wavefront.trace.wavelength_nm,
               "diffraction")


def mtf_at(lens, field_deg: float, freq: float, wavelength_nm: float | None = None,
           direction: str = "tangential", n: int | None = None,
           image_plane="sensor", options=None) -> torch.Tensor:
    """Diffraction MTF at one frequency (cycles/mm), differentiable: a direct transform of
    the FFT PSF (module docstring).  ``direction``: ``"tangential"`` or ``"sagittal"``."""
    lens, _, options = unpack(lens, None, options, "mtf_at")
    if direction not in ("tangential", "sagittal"):
        raise ValueError(f"direction must be 'tangential' or 'sagittal', got {direction!r}")
    if not (freq >= 0 and math.isfinite(freq)):
        raise ValueError(f"frequency must be >= 0 cycles/mm, got {freq!r}")
    p = psf_fft(lens, field_deg, wavelength_nm, n=n, image_plane=image_plane, options=options)
    n = p.wavefront.opd.shape[0]
    grid = p.psf.shape[0]
    dnt, dns = frequency_steps(lens, field_deg, p.wavefront.trace.wavelength_nm, n, image_plane,
                               options)
    k = torch.arange(grid, dtype=p.psf.dtype, device=p.psf.device) - grid // 2
    if direction == "tangential":
        line = p.psf.sum(1)  # line spread along y
        pos = k / (grid * dnt)
    else:
        line = p.psf.sum(0)
        pos = k / (grid * dns)
    ph = -2 * math.pi * freq * pos
    re = (line * torch.cos(ph)).sum()
    im = (line * torch.sin(ph)).sum()
    return torch.sqrt(re ** 2 + im ** 2) / line.sum()


def geometric_mtf(lens, field_deg: float, freqs, wavelength_nm: float | None = None,
                  n: int = 64, image_plane="sensor", options=None) -> MTF:
    """Geometric MTF from the rays of an ``n x n`` pupil grid (module docstring)."""
    lens, _, options = unpack(lens, None, options, "geometric_mtf")
    wl = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    dtype = lens.dtype
    g = pupil_grid(n, dtype, lens.device)
    g = g[(g ** 2).sum(-1) <= 1.0 + 1e-12]
    tr = trace_pupil(lens, field_deg, wl, g, image_plane, options=options)
    pts = tr.points[tr.mask][:, :2]
    pts = pts - pts.mean(0)
    f = torch.as_tensor(freqs, dtype=dtype, device=pts.device).reshape(-1)

    def one(c):
        ph = -2 * math.pi * f[:, None] * c[None]
        return torch.sqrt(torch.cos(ph).mean(-1) ** 2 + torch.sin(ph).mean(-1) ** 2)

    return MTF(f, one(pts[:, 1]), f, one(pts[:, 0]), float(field_deg), wl, "geometric")


def encircled_energy(lens, field_deg: float, radii_mm, wavelength_nm: float | None = None,
                     method: str = "diffraction", n: int | None = None,
                     image_plane="sensor", options=None) -> torch.Tensor:
    """Fraction of energy within each radius (mm) of the centroid, ``(R,)``.

    ``method="diffraction"`` integrates the FFT PSF (pixels counted by their centres, the PSF
    grid must be large enough to hold the energy: ``grid = 4n`` here); ``"geometric"`` counts
    the rays of a ``hexapolar`` spot."""
    lens, _, options = unpack(lens, None, options, "encircled_energy")
    r = torch.as_tensor(radii_mm, dtype=lens.dtype,
                        device=lens.device).reshape(-1)
    if method == "geometric":
        wl = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
        s = spot_diagram(lens, field_deg, wl, "hexapolar:30", pupil="paraxial",
                         image_plane=image_plane, options=options)
        d = torch.linalg.vector_norm(s.points - s.centroid, dim=-1)
        return (d[None] <= r[:, None]).to(r.dtype).mean(-1)
    if method != "diffraction":
        raise ValueError(f"encircled-energy method must be 'diffraction' or 'geometric', got "
                         f"{method!r}")
    p = psf_fft(lens, field_deg, wavelength_nm, n=n, grid=None if n is None else 4 * n,
                image_plane=image_plane, options=options)
    if n is None:  # finer PSF pixels for the radii: pad the chosen pupil 4x
        m = p.wavefront.opd.shape[0]
        p = psf_fft(lens, field_deg, wavelength_nm, n=m, grid=4 * m, image_plane=image_plane,
                    options=options)
    Y, X = torch.meshgrid(p.y, p.x, indexing="ij")
    tot = p.psf.sum()
    cx = (p.psf * X).sum() / tot
    cy = (p.psf * Y).sum() / tot
    d = torch.sqrt((X - cx) ** 2 + (Y - cy) ** 2)
    return ((d[None] <= r[:, None, None]).to(r.dtype) * p.psf[None]).sum((-1, -2)) / tot
