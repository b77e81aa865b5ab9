"""Polychromatic, through-focus and field-dependent diffraction MTF.

Polychromatic MTF, as lens-design programs define it: the modulus of the weighted sum of the
wavelengths' optical transfer functions, each normalised to 1 at zero frequency and placed on
one physical axis (the lateral colour between the wavelengths' images lowers it):

    MTF(ν) = | Σ_λ w_λ Σ_k L_λ(x_k) e^{-2πi ν x_k} | / Σ_λ w_λ,        Σ_k L_λ(x_k) = 1,

with ``L_λ`` the line spread function of the FFT PSF (:func:`~.diffraction.psf_fft`: the PSF
summed across the direction of the bars; ``x`` along ``y`` for tangential, ``x`` for sagittal)
at its pixel positions ``x_k`` about the wavelength's own chief-ray image point, shifted by that
point's position.  With one wavelength this is :func:`~.diffraction.mtf_at`'s direct transform.

Through focus: the same at image planes ``z_image + δ``; versus field: the same per field.

Each function takes a lens (traced with ``options``, ``None``: the defaults) or a
:class:`~deeplens.optics.camera.Camera` in its place (its options reach every PSF trace).
"""

from __future__ import annotations

import math

import torch

from ..optics.camera import unpack
from .diffraction import psf_fft
from .spot import image_plane_z

__all__ = ["combine_otf", "polychromatic_mtf", "through_focus_mtf", "mtf_vs_field"]


def combine_otf(lsfs, positions, freqs, weights=None) -> torch.Tensor:
    """``MTF(ν)`` ``(F,)`` from per-wavelength line spread functions (module docstring).

    Args:
        lsfs: per wavelength a ``(K_λ,)`` tensor (any scale: each is normalised to sum 1).
        positions: per wavelength the ``(K_λ,)`` positions in mm on a common axis.
        freqs: ``(F,)`` frequencies in cycles/mm.
        weights: per wavelength (default equal).
    """
    freqs = torch.as_tensor(freqs, dtype=torch.float64)
    w = [1.0] * len(lsfs) if weights is None else [float(v) for v in weights]
    if len(w) != len(lsfs) or not all(v >= 0 for v in w) or sum(w) <= 0:
        raise ValueError(f"weights must be {len(lsfs)} non-negative numbers, not all 0, got {w}")
    re = torch.zeros_like(freqs)
    im = torch.zeros_like(freqs)
    for L, x, wt in zip(lsfs, positions, w):
        L = L.double() / L.double().sum()
        ph = -2 * math.pi * freqs[:, None] * x.double()[None, :]
        re = re + wt * (L * torch.cos(ph)).sum(-1)
        im = im + wt * (L * torch.sin(ph)).sum(-1)
    return torch.sqrt(re * re + im * im) / sum(w)


def _lsf(lens, field_deg, wavelength_nm, n, image_plane, options=None):
    """``{"tangential": (L, x), "sagittal": (L, x)}`` of one FFT PSF."""
    p = psf_fft(lens, field_deg, wavelength_nm, n=n, image_plane=image_plane, options=options)
    return {"tangential": (p.psf.sum(1), p.y + p.center[1]),
            "sagittal": (p.psf.sum(0), p.x + p.center[0])}


def _check(direction, freqs):
    if direction not in ("tangential", "sagittal", "both"):
        raise ValueError(f"direction must be 'tangential', 'sagittal' or 'both', got "
                         f"{direction!r}")
    f = torch.as_tensor(freqs, dtype=torch.float64).reshape(-1)
    if not bool(torch.isfinite(f).all()) or bool((f < 0).any()):
        raise ValueError(f"frequencies must be finite and >= 0 cycles/mm, got {f.tolist()}")
    return f


def polychromatic_mtf(lens, field_deg: float, freqs, wavelengths_nm=None, weights=None,
                      direction: str = "tangential", n: int | None = None,
                      image_plane="sensor", options=None) -> torch.Tensor:
    """Polychromatic diffraction MTF ``(F,)`` at ``freqs`` (cycles/mm) of one field (module
    docstring), ``(2, F)`` (tangential, sagittal) for ``direction="both"``; wavelengths
    default to the lens's, weights to equal.  ``lens``: a Lens or a Camera (its options are
    used)."""
    lens, _, options = unpack(lens, None, options, "polychromatic_mtf")
    f = _check(direction, freqs)
    waves = list(lens.spec.wavelengths_nm if wavelengths_nm is None else wavelengths_nm)
    with torch.no_grad():
        parts = [_lsf(lens, field_deg, float(w), n, image_plane, options) for w in waves]
    out = [combine_otf([p[d][0] for p in parts], [p[d][1] for p in parts], f, weights)
           for d in ("tangential", "sagittal")]
    if direction == "both":
        return torch.stack(out)
    return out[0] if direction == "tangential" else out[1]


def through_focus_mtf(lens, field_deg: float, freqs, defocus_mm, wavelengths_nm=None,
                      weights=None, direction: str = "tangential", n: int | None = None,
                      image_plane="sensor", options=None) -> torch.Tensor:
    """``(D, F)`` (``(D, 2, F)`` for ``"both"``): :func:`polychromatic_mtf` on the planes
    ``z_image + δ`` for each ``δ`` of ``defocus_mm`` (mm, + away from the lens).  ``lens``: a
    Lens or a Camera (its options are used)."""
    lens, _, options = unpack(lens, None, options, "through_focus_mtf")
    z0 = float(image_plane_z(lens, image_plane))
    return torch.stack([polychromatic_mtf(lens, field_deg, freqs, wavelengths_nm, weights,
                                          direction, n, z0 + float(d), options)
                        for d in defocus_mm])


def mtf_vs_field(lens, fields_deg, freqs, wavelengths_nm=None, weights=None,
                 direction: str = "tangential", n: int | None = None,
                 image_plane="sensor", options=None) -> torch.Tensor:
    """``(P, F)`` (``(P, 2, F)`` for ``"both"``): :func:`polychromatic_mtf` per field;
    ``lens``: a Lens or a Camera (its options are used)."""
    lens, _, options = unpack(lens, None, options, "mtf_vs_field")
    return torch.stack([polychromatic_mtf(lens, float(f), freqs, wavelengths_nm, weights,
                                          direction, n, image_plane, options)
                        for f in fields_deg])
