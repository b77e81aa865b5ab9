"""Per-unit distortion calibration: measure where a built lens images a grid of object points
against where the nominal lens images them, and register an image with that map.

A camera maker calibrates every unit: the image mapping of the lens as built differs from the
design's by a smooth, field-dependent displacement (a decentred element moves the image, a
radius or index error changes the distortion), which is measured once per unit with a target
and removed by resampling every image.  A tolerance test that scores the camera as it is used
scores after that correction (docs/results/doublet_tolerance.md).

The map (:func:`image_points`): object points at depth ``depth_mm`` on an ``nodes x nodes``
grid whose ideal images (:class:`~deeplens.render.scene.IdealCamera` framing, the ground
truth's) span the sensor from the first to the last pixel centre in both directions, so the map
is not assumed rotationally symmetric (decenters and tilts).  Each point's image is the
energy centroid of its PSF on the sensor: a deterministic ``grid:48`` bundle that *overfills*
the paraxial entrance pupil by 30 %, so that the lens's own stop and rims cut the bundle, as
they cut the light of a render.  (A bundle inside the paraxial pupil, as the centring
compensator's, does not follow a decentred stop: for the doublet moved rigidly by 35 µm it
misplaces the centroid by up to 8 µm off axis, against 0.5 µm for this one; the doublet's
off-axis spots are 30–85 µm RMS, so which rays are kept moves the centroid.)  Centroids are taken
**per sensor channel**: the channel's wavelengths weighted as the renderer weights them
(:meth:`Sensor.wavelengths_for <deeplens.render.sensor.Sensor.wavelengths_for>`), rays that do
not reach the sensor carrying no energy.  Per channel, because the errors also change the
lateral colour (index and Abbe number; the doublet's on-axis residual after centring, 0.8 µm, is
lateral colour), and a camera pipeline corrects lateral colour per channel anyway.

The displacement of a unit (:func:`displacement_px`) is its points minus the nominal lens's
points, converted to pixels (rows ``i``, columns ``j``) and interpolated (bicubic) from the
grid nodes to every pixel centre.  Content the nominal lens puts at pixel ``u`` lands at ``u +
d(u)`` on the unit's sensor; the restorer, which is locally shift-equivariant at this
sub-pixel scale, puts it at ``u + d(u)`` of its output too, so :func:`warp` registers an image
with ``out(u) = img(u + d(u))`` (Keys' cubic convolution, exact on linear and quadratic images,
edges clamped).  On the doublet's six worst calibrated lenses, Keys' cubic, Lanczos-3 and
bilinear (:func:`torch.nn.functional.grid_sample`) registrations score within 0.2 dB of each
other; PyTorch's own bicubic (a = -3/4) scores up to 0.35 dB more, by sharpening (it misplaces
a linear ramp by up to 0.04 px), so it is not used.  An identically zero map returns the image itself (bit for bit), so a unit that is
the nominal lens scores exactly as the nominal lens.

Units: positions in mm on the sensor, displacements in pixels; the sensor's pixel convention
(:meth:`Sensor.pixel_to_xy <deeplens.render.sensor.Sensor.pixel_to_xy>`: ``x = -(j - W/2) p``,
``y = (i - H/2) p``, pixel centres at ``+0.5``).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..optics.camera import unpack
from ..optics.sampling import entrance_pupil, pupil_pattern, rays_from_tangents, start_plane_z

__all__ = ["CALIBRATIONS", "image_points", "displacement_px", "warp", "node_pixels"]

#: the values ``eval.calibrate`` / ``model.calibrate`` take (``None``: no calibration)
CALIBRATIONS = ("distortion",)


def node_pixels(resolution, nodes: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Fractional pixel positions ``(i, j)`` (each ``(nodes,)``, float64) of the grid nodes:
    from the first to the last pixel centre (``0.5`` to ``H - 0.5``)."""
    if isinstance(nodes, bool) or not isinstance(nodes, int) or nodes < 2:
        raise ValueError(f"calibration grid: nodes must be an integer >= 2, got {nodes!r}")
    H, W = (int(v) for v in resolution)
    t = torch.linspace(0.0, 1.0, nodes, dtype=torch.float64)
    return 0.5 + t * (H - 1), 0.5 + t * (W - 1)


def image_points(lens, sensor, depth_mm: float, object_scale: float, n_channels: int,
                 nodes: int = 9, sampling: str = "grid:48", pupil_fill: float = 1.3,
                 options=None) -> torch.Tensor:
    """Where ``lens`` images the calibration grid: ``(n_channels, nodes, nodes, 2)`` (mm, sensor
    ``(x, y)``), the per-channel energy centroid of each grid point's bundle (module docstring).

    Args:
        lens: a :class:`~deeplens.optics.lens.Lens` (traced with ``options``) or a
            :class:`~deeplens.optics.camera.Camera` (its sensor and options; ``sensor`` None).
        sensor: the :class:`~deeplens.render.sensor.Sensor` (resolution, pixel pitch, channels).
        depth_mm: the calibration target's distance from the first vertex (finite, mm).
        object_scale: object-plane mm per sensor mm at ``depth_mm`` (the ideal framing:
            :meth:`IdealCamera.object_scale <deeplens.render.scene.IdealCamera.object_scale>`).
        n_channels: the image's channels (a monochrome scene on an RGB sensor: 1).
        nodes: grid nodes per side (>= 2).
        sampling, pupil_fill: the pupil pattern and its radius in paraxial entrance-pupil radii
            (over 1: the lens's apertures select the rays, module docstring).

    Returns a detached float64 tensor (a measurement, not a differentiable quantity).

    Raises:
        ValueError: an infinite or non-positive depth; a grid point none of whose rays reach
            the sensor at some wavelength of a channel.
    """
    lens, cam_sensor, options = unpack(lens, None, options, "image_points")
    sensor = sensor if sensor is not None else cam_sensor
    if sensor is None:
        raise ValueError("image_points: give the sensor (or a camera)")
    if not (math.isfinite(float(depth_mm)) and float(depth_mm) > 0):
        raise ValueError(f"distortion calibration needs a finite target depth > 0 mm, got "
                         f"{depth_mm}")
    ii, jj = node_pixels(sensor.resolution, nodes)
    I, J = torch.meshgrid(ii, jj, indexing="ij")
    x, y = sensor.pixel_to_xy(I, J)                       # ideal image positions (mm)
    K = nodes * nodes
    Q = torch.stack([float(object_scale) * x.reshape(-1), float(object_scale) * y.reshape(-1)],
                    -1)                                   # object points (K, 2), mm
    with torch.no_grad():
        z_ep, r_ep, z0 = entrance_pupil(lens)
        unit = pupil_pattern(sampling) * (r_ep * pupil_fill)           # (M, 2)
        M = unit.shape[0]
        E = torch.cat([unit, torch.full_like(unit[:, :1], z_ep)], -1)  # pupil points (M, 3)
        z_obj = z0 - float(depth_mm)
        P = E.unsqueeze(0).expand(K, M, 3).reshape(-1, 3)
        t = ((E[None, :, :2] - Q[:, None, :]) / (E[None, :, 2:] - z_obj)).reshape(-1, 2)
        z_start = max(start_plane_z(lens), z_obj)
        num = torch.zeros(n_channels, K, 2, dtype=torch.float64)
        den = torch.zeros(n_channels, K, dtype=torch.float64)
        for c, w, wt in sensor.wavelengths_for(n_channels):
            rays = rays_from_tangents(P.to(lens.device), t.to(lens.device), z_start, w,
                                      lens.dtype)
            out = lens.trace_to_sensor(rays, options=options)
            ok = out.valid.reshape(K, M).to(torch.float64).cpu()
            xy = torch.nan_to_num(out.o[:, :2].to(torch.float64).cpu()).reshape(K, M, 2)
            if bool((ok.sum(1) == 0).any()):
                k = int((ok.sum(1) == 0).nonzero()[0])
                raise ValueError(f"distortion calibration: no ray from the grid point at sensor "
                                 f"({float(x.reshape(-1)[k]):.3f}, {float(y.reshape(-1)[k]):.3f})"
                                 f" mm reaches the sensor at {w:g} nm")
            num[c] += float(wt) * (xy * ok[..., None]).sum(1)
            den[c] += float(wt) * ok.sum(1)
    return (num / den[..., None]).reshape(n_channels, nodes, nodes, 2)


def displacement_px(points: torch.Tensor, nominal: torch.Tensor, sensor) -> torch.Tensor:
    """``(C, H, W, 2)`` float64: the unit's displacement ``(di, dj)`` in pixels (rows,
    columns) at every pixel centre, from its grid points ``points`` and the nominal lens's
    ``nominal`` (both ``(C, n, n, 2)`` mm, :func:`image_points`), interpolated bicubically
    from the nodes (which lie on the first and last pixel centres) to the pixel grid."""
    if points.shape != nominal.shape or points.dim() != 4 or points.shape[-1] != 2:
        raise ValueError(f"displacement_px: points {tuple(points.shape)} and nominal "
                         f"{tuple(nominal.shape)} must both be (C, n, n, 2)")
    d = (points - nominal).to(torch.float64)
    p = float(sensor.pixel_size_mm)
    dij = torch.stack([d[..., 1] / p, -d[..., 0] / p], 1)            # (C, 2, n, n) pixels
    H, W = (int(v) for v in sensor.resolution)
    if not bool(dij.any()):
        return torch.zeros(d.shape[0], H, W, 2, dtype=torch.float64)
    up = F.interpolate(dij, size=(H, W), mode="bicubic", align_corners=True)
    return up.permute(0, 2, 3, 1).contiguous()


def _lanczos_weights(t: torch.Tensor, n: int = 3) -> list[torch.Tensor]:
    """Lanczos-``n`` weights of the samples at offsets ``1 - n .. n`` for a fractional position
    ``t`` in [0, 1) (a windowed sinc: nearly the ideal band-limited interpolation), normalised
    to sum to 1."""
    ks = [t - k for k in range(1 - n, n + 1)]            # distance of each sample from t

    def lanczos(u):
        pu = math.pi * u
        safe = torch.where(u.abs() < 1e-12, torch.ones_like(u), pu)
        val = n * torch.sin(safe) * torch.sin(safe / n) / (safe * safe)
        return torch.where(u.abs() < 1e-12, torch.ones_like(u), val)

    w = [lanczos(u) for u in ks]
    total = sum(w)
    return [x / total for x in w]


def _keys_weights(t: torch.Tensor) -> list[torch.Tensor]:
    """Keys' cubic convolution weights (a = -1/2) of the samples at offsets -1, 0, 1, 2 for a
    fractional position ``t`` in [0, 1): they sum to 1 and reproduce polynomials up to degree
    2, so a linear image is shifted exactly (PyTorch's bicubic uses a = -3/4, which does not:
    it misplaces a ramp by up to 0.04 px)."""
    t2, t3 = t * t, t * t * t
    return [(-t3 + 2 * t2 - t) / 2, (3 * t3 - 5 * t2 + 2) / 2, (-3 * t3 + 4 * t2 + t) / 2,
            (t3 - t2) / 2]


def _separable(image: torch.Tensor, y: torch.Tensor, x: torch.Tensor, mode: str) -> torch.Tensor:
    """``image`` ``(B, C, H, W)`` sampled at fractional pixel indices ``y``, ``x`` (each ``(C,
    H, W)``, float64; integer = a pixel centre) with a separable kernel (``"cubic"``: Keys,
    offsets -1..2; ``"lanczos3"``: offsets -2..3), indices clamped to the image (edges
    repeated)."""
    B, C, H, W = image.shape
    y0, x0 = torch.floor(y), torch.floor(x)
    weights = _keys_weights if mode == "cubic" else _lanczos_weights
    first = -1 if mode == "cubic" else -2
    wy = [w.to(image.dtype) for w in weights(y - y0)]
    wx = [w.to(image.dtype) for w in weights(x - x0)]
    y0, x0 = y0.long(), x0.long()
    cc = torch.arange(C, device=image.device)[:, None, None].expand(C, H, W)
    out = torch.zeros_like(image)
    for m, wym in enumerate(wy):
        iy = (y0 + (m + first)).clamp(0, H - 1)
        row = torch.zeros_like(image)
        for n, wxn in enumerate(wx):
            ix = (x0 + (n + first)).clamp(0, W - 1)
            row = row + wxn * image[:, cc, iy, ix]
        out = out + wym * row
    return out


def warp(image: torch.Tensor, disp_px: torch.Tensor, mode: str = "cubic") -> torch.Tensor:
    """Register ``image`` ``(B, C, H, W)`` with a unit's displacement ``disp_px`` ``(C, H, W,
    2)`` or ``(1, H, W, 2)`` (pixels, ``(di, dj)``): ``out[b, c, i, j] = image[b, c, i + di, j +
    dj]``; ``mode``: ``"cubic"`` (Keys' cubic convolution, a = -1/2, exact on quadratics) or
    ``"bilinear"`` (:func:`torch.nn.functional.grid_sample`); positions beyond the edge take
    the edge pixel.  Differentiable in ``image``; an all-zero ``disp_px`` returns ``image``
    itself."""
    if image.dim() != 4:
        raise ValueError(f"warp: image must be (B, C, H, W), got {tuple(image.shape)}")
    B, C, H, W = image.shape
    if disp_px.dim() != 4 or disp_px.shape[1:] != (H, W, 2) or disp_px.shape[0] not in (1, C):
        raise ValueError(f"warp: displacement must be (C or 1, {H}, {W}, 2) for an image "
                         f"{tuple(image.shape)}, got {tuple(disp_px.shape)}")
    if mode not in ("lanczos3", "cubic", "bilinear"):
        raise ValueError(f"warp: mode must be 'lanczos3', 'cubic' or 'bilinear', got {mode!r}")
    if not bool(disp_px.any()):
        return image
    d = disp_px.to(device=image.device, dtype=torch.float64).expand(C, H, W, 2)
    i = torch.arange(H, dtype=torch.float64, device=image.device)[:, None]
    j = torch.arange(W, dtype=torch.float64, device=image.device)[None, :]
    if mode != "bilinear":
        return _separable(image, i + d[..., 0], j + d[..., 1], mode)
    # grid_sample, align_corners=False: -1 / +1 are the outer edges, pixel k's centre is
    # (2k + 1) / W - 1; the grid's last axis is (column, row)
    gx = (2.0 * (j + d[..., 1]) + 1.0) / W - 1.0
    gy = (2.0 * (i + d[..., 0]) + 1.0) / H - 1.0
    grid = torch.stack([gx, gy], -1).to(image.dtype)                 # (C, H, W, 2)
    # the channels become grid_sample's batch (each its own map), the batch its channels
    out = F.grid_sample(image.transpose(0, 1), grid, mode="bilinear", padding_mode="border",
                        align_corners=False)
    return out.transpose(0, 1)
