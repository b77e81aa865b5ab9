"""Scenes: textured planes at given depths, point sources, and the ideal reference camera.

A :class:`Scene` is a batch of ``B`` textured planes perpendicular to the axis: textures
``(B, C, Ht, Wt)`` and depths ``(B,)`` in mm measured from the lens's first vertex towards the
object (``z = z_0 - depth``).  Each texture covers a physical ``(height, width)`` in mm centred
on the axis; ``None`` sizes it to fill the sensor's field of view at its depth through the ideal
camera.  Texture row 0 is the top (``+y``) and column 0 the left of the rendered image: renders
come out upright, like a camera's read-out (see :mod:`.sensor` for the pixel mapping).

Ideal camera (the ground truth's framing): the paraxial chief ray of object-space slope ``u``
through the entrance-pupil centre reaches height ``κ u`` on the sensor
(:func:`~deeplens.optics.paraxial.chief_ray_scale`).  A sensor point ``(x, y)`` therefore sees
the object point ``-(z_EP - z_obj) (x, y) / κ``: a distortion-free pinhole at the entrance pupil
with the lens's framing.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..optics.paraxial import chief_ray_scale, paraxial

__all__ = ["Scene", "sample_texture", "IdealCamera"]


class Scene:
    """A batch of textured planes.

    Args:
        textures: ``(B, C, Ht, Wt)`` or ``(C, Ht, Wt)`` (one plane), values in ``[0, 1]`` (linear).
        depths_mm: ``(B,)`` or a float: distance from the first vertex to each plane (> 0).
        sizes_mm: ``(B, 2)`` physical ``(height, width)`` in mm, or ``None`` to fill the field
            of view at each depth.

    Raises:
        ValueError: wrong texture rank, depth count or a depth that is not in front of the lens.
    """

    def __init__(self, textures: torch.Tensor, depths_mm, sizes_mm=None):
        if not torch.is_tensor(textures):
            raise ValueError(f"Scene: textures must be a tensor (B, C, H, W), got "
                             f"{type(textures).__name__}")
        if textures.ndim == 3:
            textures = textures.unsqueeze(0)
        if textures.ndim != 4 or min(textures.shape[-2:]) < 2:
            raise ValueError(f"Scene: textures must have shape (B, C, H, W) or (C, H, W) with "
                             f"H, W >= 2, got {tuple(textures.shape)}")
        B = textures.shape[0]
        depths = torch.as_tensor(depths_mm, dtype=torch.float64).reshape(-1)
        if depths.numel() == 1 and B > 1:
            depths = depths.expand(B)
        if depths.numel() != B:
            raise ValueError(f"Scene: {B} textures need {B} depths, got {depths.numel()}")
        if not bool(torch.isfinite(depths).all()) or bool((depths <= 0).any()):
            raise ValueError(f"Scene: depths must be finite and > 0 mm (in front of the first "
                             f"vertex), got {depths.tolist()}")
        if sizes_mm is not None:
            sizes_mm = torch.as_tensor(sizes_mm, dtype=torch.float64).reshape(-1, 2)
            if sizes_mm.shape[0] == 1 and B > 1:
                sizes_mm = sizes_mm.expand(B, 2)
            if sizes_mm.shape[0] != B or bool((sizes_mm <= 0).any()):
                raise ValueError(f"Scene: sizes_mm must be (B, 2) positive (height, width) mm, "
                                 f"got {tuple(sizes_mm.shape)}")
        self.textures = textures
        self.depths_mm = depths
        self.sizes_mm = sizes_mm

    @property
    def batch(self) -> int:
        return self.textures.shape[0]

    @property
    def channels(self) -> int:
        return self.textures.shape[1]

    def resolved_sizes(self, camera: "IdealCamera") -> torch.Tensor:
        """``(B, 2)`` physical sizes, filling the field of view where none was given."""
        if self.sizes_mm is not None:
            return self.sizes_mm
        return torch.stack([camera.fov_size_mm(float(d)) for d in self.depths_mm])


def sample_texture(textures: torch.Tensor, X: torch.Tensor, Y: torch.Tensor,
                   sizes_mm: torch.Tensor) -> torch.Tensor:
    """Bilinear texture lookup at physical plane positions, differentiable in ``X, Y``.

    Args:
        textures: ``(B, C, Ht, Wt)``.
        X, Y: ``(B, N)`` positions on each plane (mm).
        sizes_mm: ``(B, 2)`` ``(height, width)`` of each texture (mm).

    Returns:
        ``(B, C, N)``; positions outside a texture read 0 (a black surround).
    """
    sz = sizes_mm.to(X)
    gx = X / (0.5 * sz[:, 1:2])
    gy = -Y / (0.5 * sz[:, 0:1])
    grid = torch.stack([gx, gy], -1).unsqueeze(1).to(textures.dtype)  # (B, 1, N, 2)
    out = F.grid_sample(textures, grid, mode="bilinear", padding_mode="zeros",
                        align_corners=False)
    return out[:, :, 0, :]


class IdealCamera:
    """The distortion-free reference camera with the lens's framing (module docstring).

    Args:
        lens: the lens (its entrance pupil and paraxial chief-ray scale are used).
        sensor: the :class:`~deeplens.render.sensor.Sensor`.
    """

    def __init__(self, lens, sensor):
        if getattr(lens, "virtual_image", False):
            lens.require_real_image("IdealCamera")
        with torch.no_grad():
            p = paraxial(lens)
            self.z0 = float(lens.z_vertices()[0])
            self.z_ep = float(p.entrance_pupil_z)
            self.kappa = float(chief_ray_scale(lens, lens.z_sensor()))
        if abs(self.kappa) < 1e-12:
            raise ValueError("IdealCamera: the lens does not image the field onto the sensor "
                             "(chief-ray scale is zero)")
        self.sensor = sensor

    def object_scale(self, depth_mm: float) -> float:
        """Object-plane mm per sensor-plane mm at ``depth_mm`` (the inverse magnification)."""
        return -(self.z_ep - (self.z0 - depth_mm)) / self.kappa

    def fov_size_mm(self, depth_mm: float) -> torch.Tensor:
        h, w = self.sensor.size_mm
        s = abs(self.object_scale(depth_mm))
        return torch.tensor([h * s, w * s], dtype=torch.float64)

    def field_angle_deg(self, r_sensor_mm: float) -> float:
        """Object-space field angle imaged to sensor radius ``r_sensor_mm``."""
        return math.degrees(math.atan(abs(r_sensor_mm / self.kappa)))

    def render(self, scene: Scene, supersample: int = 2, pad: int = 0) -> torch.Tensor:
        """The sharp ground truth ``(B, C, H + 2 pad, W + 2 pad)`` with the lens's framing
        (box-filtered ``supersample^2`` samples per pixel); ``pad`` pixels beyond every edge of
        the sensor (the scene that a blur brings into the frame)."""
        H, W = self.sensor.resolution
        s, pad = supersample, int(pad)
        if pad < 0:
            raise ValueError(f"pad must be >= 0, got {pad}")
        dtype, device = scene.textures.dtype, scene.textures.device
        i = (torch.arange(-pad * s, (H + pad) * s, dtype=torch.float64, device=device) + 0.5) / s
        j = (torch.arange(-pad * s, (W + pad) * s, dtype=torch.float64, device=device) + 0.5) / s
        H, W = H + 2 * pad, W + 2 * pad
        I, J = torch.meshgrid(i, j, indexing="ij")
        x, y = self.sensor.pixel_to_xy(I, J)
        sizes = scene.resolved_sizes(self)
        B = scene.batch
        scale = torch.tensor([self.object_scale(float(d)) for d in scene.depths_mm],
                             dtype=torch.float64, device=device)[:, None]
        X = scale * x.reshape(1, -1)
        Y = scale * y.reshape(1, -1)
        img = sample_texture(scene.textures, X.to(dtype), Y.to(dtype), sizes.to(device))
        img = img.reshape(B, scene.channels, H, s, W, s).mean(dim=(3, 5))
        return img
