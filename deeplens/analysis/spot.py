"""Real-ray analysis: entrance pupils found by tracing, spot diagrams, RMS spot, chief ray.

RMS spot radius (centroid-referenced) of the ``M`` valid rays landing at ``p_m`` on the image
plane:  ``sqrt( (1/M) sum_m |p_m - p̄|^2 )``, ``p̄`` their centroid.

Pupils (paper Sec. III-E).  ``pupil="paraxial"`` samples the paraxial entrance pupil (a disk of
diameter EPD at the paraxial EP position) as lens-design programs do without ray aiming.  When
the aperture is given as an EPD or F-number, the stop's size is derived from that paraxial pupil
and does not clip these rays (clipping them dropped rim rays by round-off and pupil aberration:
18 of 469 on a Thorlabs asphere, RMS 4.5 % low); a stop of its own size (``"stop"``) and other
apertures do clip.  ``pupil="traced"`` first traces a dense grid over that plane, keeps the
rays that reach the image, bisects the edges of the passing region along x and y through its
centroid, and samples the ellipse inscribed in those edges, so that a vignetted field spends its
rays where light passes.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import torch

from ..optics.camera import unpack
from ..optics.chief import chief_ray, image_plane_z  # noqa: F401  (re-exported)
from ..optics.paraxial import paraxial
from ..optics.sampling import field_rays, pupil_pattern

__all__ = ["PupilRegion", "find_pupil", "spot_diagram", "chief_ray", "SpotResult",
           "image_plane_z"]


@dataclass
class PupilRegion:
    """An elliptical sampling region in the plane ``z`` (mm): centre ``(cx, cy)``, semi-axes."""

    cx: float
    cy: float
    rx: float
    ry: float
    z: float

    def points(self, unit_xy: torch.Tensor) -> torch.Tensor:
        """Map unit-disk points ``(M, 2)`` into this region (mm)."""
        out = unit_xy.clone()
        out[:, 0] = self.cx + self.rx * unit_xy[:, 0]
        out[:, 1] = self.cy + self.ry * unit_xy[:, 1]
        return out


def _passes(lens, field_deg, wavelength_nm, xy, z, options=None):
    rays = field_rays(lens, field_deg, wavelength_nm, xy, z)
    out = lens.trace_to_sensor(rays, options=options)
    return out.valid


def find_pupil(lens, field_deg: float, wavelength_nm: float | None = None, method: str = "traced",
               grid: int = 129, bisections: int = 40, options=None) -> PupilRegion:
    """The region of the entrance-pupil plane to sample for one field (see module docstring).

    ``lens``: a Lens (its search traces run with ``options``, ``None``: the defaults) or a
    :class:`~deeplens.optics.camera.Camera` (its options are used).

    Raises:
        ValueError: for an unknown ``method``, or when no ray of the field reaches the image
            (a fully vignetted field): the message gives the field and the search region.
    """
    if method not in ("paraxial", "traced"):
        raise ValueError(f"pupil method must be 'paraxial' or 'traced', got {method!r}")
    lens, _, options = unpack(lens, None, options, "find_pupil")
    if wavelength_nm is None:   # the lens's primary wavelength, as the other analysis functions
        wavelength_nm = float(lens.spec.primary_wavelength_nm)
    dtype = lens.dtype
    with torch.no_grad():
        p = paraxial(lens)
        z = float(p.entrance_pupil_z)
        r = 0.5 * float(p.entrance_pupil_diameter)
        if method == "paraxial":
            # shrunk by 1e-12: rim points must not straddle a stop that
            # is exactly the pupil's image by rounding
            r = r * (1.0 - 1e-12)
            return PupilRegion(0.0, 0.0, r, r, z)
        for scale in (2.0, 4.0):
            W = scale * r
            v = torch.linspace(-W, W, grid, dtype=dtype)
            X, Y = torch.meshgrid(v, v, indexing="xy")
            xy = torch.stack([X.reshape(-1), Y.reshape(-1)], -1)
            ok = _passes(lens, field_deg, wavelength_nm, xy, z, options)
            if bool(ok.any()):
                break
        else:
            raise ValueError(f"field {field_deg:g} deg at {wavelength_nm:g} nm is fully "
                             f"vignetted: none of {grid * grid} rays over a {2 * W:.4g} mm square "
                             f"in the entrance-pupil plane (z = {z:.4g} mm) reaches the image")
        c = xy[ok].mean(0)
        if not bool(_passes(lens, field_deg, wavelength_nm, c[None], z, options)[0]):
            c = xy[ok][((xy[ok] - c) ** 2).sum(-1).argmin()]
        # bisect the edge along +x, -x, +y, -y from the centre
        dirs = torch.tensor([[1.0, 0], [-1, 0], [0, 1], [0, -1]], dtype=dtype)
        lo = torch.zeros(4, dtype=dtype)
        hi = torch.full((4,), 2 * scale * r, dtype=dtype)
        for _ in range(bisections):
            mid = 0.5 * (lo + hi)
            okm = _passes(lens, field_deg, wavelength_nm, c + mid[:, None] * dirs, z, options)
            lo = torch.where(okm, mid, lo)
            hi = torch.where(okm, hi, mid)
        xp, xm, yp, ym = lo.tolist()
        cx, cy = float(c[0]), float(c[1])
        # shrink by 1e-9 so that pattern points on the rim do not straddle the edge by rounding
        shrink = 1.0 - 1e-9
        return PupilRegion(cx + 0.5 * (xp - xm), cy + 0.5 * (yp - ym), 0.5 * (xp + xm) * shrink,
                           0.5 * (yp + ym) * shrink, z)


@contextlib.contextmanager
def _stop_not_clipping(lens):
    """Rays aimed at the paraxial entrance pupil are not clipped by a stop sized from that pupil
    (its semi-diameter is restored afterwards; it is a buffer, so no gradient is involved)."""
    sd = lens.stop.semi_diameter
    saved = sd.clone()
    with torch.no_grad():
        sd.fill_(float("inf"))
    try:
        yield
    finally:
        with torch.no_grad():
            sd.copy_(saved)


def _safe_sqrt(v: torch.Tensor) -> torch.Tensor:
    """``sqrt(v)`` whose derivative at ``v = 0`` is 0 (a subgradient of the RMS radius, a norm)
    rather than ``inf``: a spot of one ray, or of coincident rays, has ``v = 0`` and
    ``dv/dθ = 0``, and ``inf * 0`` made every gradient NaN."""
    pos = v > 0
    return torch.where(pos, torch.sqrt(torch.where(pos, v, torch.ones_like(v))),
                       torch.zeros_like(v))


@dataclass
class SpotResult:
    """Spot of one field and wavelength; positions in mm on the image plane."""

    field_deg: float
    wavelength_nm: float
    points: torch.Tensor  # (M_valid, 2) mm
    centroid: torch.Tensor  # (2,) mm
    rms_radius: torch.Tensor  # mm (differentiable)
    n_rays: int
    n_launched: int


def spot_diagram(lens, field_deg: float, wavelength_nm: float | None = None,
                 sampling: str = "hexapolar:18",
                 pupil: str = "traced", image_plane="sensor", options=None,
                 region: PupilRegion | None = None) -> SpotResult:
    """Trace a pupil pattern of one field to the image plane; gradients flow to the lens.
    ``lens``: a Lens (traced with ``options``) or a :class:`~deeplens.optics.camera.Camera`
    (its options are used); the pupil search (:func:`find_pupil`) runs at the same options.

    Raises:
        ValueError: when no ray reaches the image (names the field).
    """
    lens, _, options = unpack(lens, None, options, "spot_diagram")
    if wavelength_nm is None:   # the lens's primary wavelength, as the other analysis functions
        wavelength_nm = float(lens.spec.primary_wavelength_nm)
    dtype = lens.dtype
    if region is None:
        region = find_pupil(lens, field_deg, wavelength_nm, pupil, options=options)
    unit = pupil_pattern(sampling, dtype=dtype)
    rays = field_rays(lens, field_deg, wavelength_nm, region.points(unit), region.z)
    z_img = image_plane_z(lens, image_plane)
    if pupil == "paraxial" and lens.spec.aperture_type != "stop":
        with _stop_not_clipping(lens):
            out = lens.trace_to_sensor(rays, z_image=z_img, options=options)
    else:
        out = lens.trace_to_sensor(rays, z_image=z_img, options=options)
    ok = out.valid
    n = int(ok.sum())
    if n == 0:
        raise ValueError(f"no ray of field {field_deg:g} deg at {wavelength_nm:g} nm reaches "
                         f"the image plane")
    pts = out.o[..., :2][ok]
    cen = pts.mean(0)
    rms = _safe_sqrt(((pts - cen) ** 2).sum(-1).mean())
    return SpotResult(field_deg, wavelength_nm, pts, cen, rms, n, rays.shape[0])
