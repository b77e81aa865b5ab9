"""Backward (sensor-to-scene) Monte Carlo rendering (paper Sec. III-C/D).

For pixel ``q`` and a sample ``i`` (jittered position ``s_i`` in the pixel, point ``e_i``
uniform on the exit pupil, paraxial, enlarged by ``pupil_margin``) the ray from ``s_i`` towards
``e_i`` is traced backwards through the lens to each scene plane, where the texture is fetched
bilinearly (so gradients reach the hit positions).  With ``w_i = |d_z|^4`` (the ``cos θ cos θ'
/ r^2`` geometry of sensor and pupil planes):

    vignetting on:   I_q = sum_i v_i w_i L_i / (S · w̄_0)     (S samples, w̄_0 the on-axis mean
                                                             of v w: the centre of a uniform
                                                             scene renders 1)
    vignetting off:  I_q = sum_i v_i w_i L_i / sum_i v_i w_i

``v_i`` is 1 for a ray that passes the lens and reaches the plane.  *On* models relative
illumination: rays lost in the lens darken the image, and the gradient sees that loss (through
the texture values of the rays still passing, not through the discrete mask).  *Off* normalises
each pixel by its own passing rays: a uniform scene renders uniform, and the gradient ignores
vignetting.  ``w̄_0`` is measured once per render without gradient.

Only what the scene needs is traced: one wavelength for a monochrome texture (else the sensor
channels' wavelengths), one lens trace shared by all depths of the batch, pixels inside the
image circle only, rays aimed at the exit pupil only.  The exit pupil, image circle and ``w̄_0``
are the lens geometry (:mod:`.geometry`), measured once per lens state and cached.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
from torch import nn

from ..optics.camera import Camera, HoldsCamera, as_camera
from ..optics.options import TraceOptions
from .geometry import (LensGeometry, exit_pupil, geometry_key, image_circle_radius,
                       measure_geometry, pixels_inside, sensor_rays)
from .geometry import reference_weight as _reference_weight
from .scene import Scene, sample_texture

__all__ = ["MonteCarloRenderer", "RenderPlan"]


@dataclass(frozen=True)
class RenderPlan:
    """Everything a render needs that does not depend on gradients, built by
    :meth:`MonteCarloRenderer.plan`: the seed, the wavelength jobs
    ``((channel, wavelength_nm, weight), ...)``, the lens geometry (:class:`~.geometry.LensGeometry`:
    camera, exit pupil, traced pixels, vignetting normalisation) and the scene planes' physical
    sizes ``(B, 2)`` (mm)."""

    seed: int
    jobs: tuple
    geometry: LensGeometry
    sizes: torch.Tensor

    camera = property(lambda self: self.geometry.camera)
    z_xp = property(lambda self: self.geometry.z_xp)
    r_xp = property(lambda self: self.geometry.r_xp)
    pixels = property(lambda self: self.geometry.pixels)
    w_ref = property(lambda self: self.geometry.w_ref)

    def with_seed(self, seed: int) -> "RenderPlan":
        """The same plan (pupil, pixels, normalisation) drawing other random samples."""
        return dataclasses.replace(self, seed=int(seed))


class MonteCarloRenderer(HoldsCamera, nn.Module):
    """Renders a :class:`~deeplens.render.scene.Scene` through a camera's lens onto its sensor.

    Args:
        lens: the :class:`~deeplens.optics.camera.Camera` (lens, sensor, trace options: every
            trace reads ``camera.options`` when it runs), or, the older form, the
            :class:`~deeplens.optics.lens.Lens` (its trainable parameters get gradients) with
            ``sensor`` and ``options``, from which the renderer builds its camera.
        sensor: the :class:`~deeplens.render.sensor.Sensor` (with a lens; with a camera:
            ``None``).
        spp: rays per pixel per wavelength (>= 1).
        vignetting: relative illumination on/off (module docstring).
        adjoint: back-propagate with the adjoint method (memory flat in the ray count) instead of
            plain autograd.
        decorrelate: (adjoint only) the backward pass re-traces *independent* samples, so the
            gradient is ``J_B^T dL/dI(I_A)``: image ``I_A`` and Jacobian ``J_B`` from different
            rays.  With shared samples (off) the estimate's noise and its Jacobian's noise are
            correlated and the gradient of a loss non-linear in the image is biased by about
            ``1/spp`` (it does not average out over steps); decorrelated it is unbiased for a
            loss quadratic in the image, at no extra cost (the adjoint traces twice anyway).
            Measured in ``benchmarks/README.md``.  Off keeps gradient = d(image)/dθ exactly,
            which finite-difference checks need.
        chunk_rays: rays traced at once (peak memory of the adjoint pass is about 1.1 kB per
            ray of one chunk; 262144 is as fast as larger chunks on CPU).
        options: (with a lens) the :class:`~deeplens.optics.options.TraceOptions` of the
            camera built; ``renderer.options`` reads and sets ``renderer.camera.options``.
        pupil_margin: exit-pupil sampling radius relative to the paraxial exit pupil.
        seed: base seed; each call uses ``seed + call index`` unless ``seed=`` is passed.

    Example:
        >>> import torch
        >>> from deeplens.optics import load_lens
        >>> from deeplens.render import Scene, Sensor
        >>> lens, sensor = load_lens("edof_achromat"), Sensor((16, 16), 0.0069)
        >>> texture = torch.rand(1, 3, 32, 32)                   # (B, C, H, W)
        >>> img = MonteCarloRenderer(lens, sensor, spp=16)(Scene(texture, [5000.0]))
        >>> img.shape                                            # (B, C, H, W) of the sensor
        torch.Size([1, 3, 16, 16])
    """

    def __init__(self, lens: Camera, sensor=None, spp: int = 16, vignetting: bool = True,
                 adjoint: bool = True, chunk_rays: int = 262144, decorrelate: bool = False,
                 options: TraceOptions | None = None, pupil_margin: float = 1.05,
                 seed: int = 0):
        super().__init__()
        if int(spp) < 1:
            raise ValueError(f"MonteCarloRenderer: spp (rays per pixel) must be >= 1, got {spp}")
        if int(chunk_rays) < 1:
            raise ValueError(f"MonteCarloRenderer: chunk_rays must be >= 1, got {chunk_rays}")
        if not pupil_margin >= 1.0:
            raise ValueError(f"MonteCarloRenderer: pupil_margin must be >= 1, got {pupil_margin}")
        if decorrelate and not adjoint:
            raise ValueError("MonteCarloRenderer: decorrelate=True needs adjoint=True (the "
                             "independent Jacobian samples are drawn in the adjoint pass)")
        camera = as_camera(lens, sensor, options, "MonteCarloRenderer")
        if camera.sensor is None:
            raise ValueError("MonteCarloRenderer: the camera has no sensor (Camera(lens, sensor))")
        self._held = (camera,)  # held, not registered: the module that built it owns it
        # registered as before (state-dict keys ``lens.*``, ``sensor.*``): the camera's own
        self.lens, self.sensor = camera.lens, camera.sensor
        self.spp = int(spp)
        self.decorrelate = bool(decorrelate)
        self.vignetting = bool(vignetting)
        self.adjoint = bool(adjoint)
        self.chunk_rays = int(chunk_rays)
        self.pupil_margin = float(pupil_margin)
        self.seed = int(seed)
        self._calls = 0
        self._geometry_cache = None  # (key, lens values, geometry): see geometry()
        self.image_circle_mm = None  # measured by active_pixels()


    # ------------------------------------------------------------ lens geometry
    def geometry(self, jobs) -> LensGeometry:
        """The :class:`~.geometry.LensGeometry` for the wavelength ``jobs``, measured without
        gradient and cached until the lens (any parameter or buffer value, or its structure),
        the sensor, the wavelengths or the settings change: frozen optics pay for it once,
        trained optics once per step."""
        meta, values = geometry_key(self.lens, self.sensor, jobs,
                                    (self.vignetting, self.pupil_margin, repr(self.options)))
        c = self._geometry_cache
        if c is not None and c[0] == meta and torch.equal(c[1], values):
            return c[2]
        with torch.no_grad():
            z_xp, r_xp = exit_pupil(self.lens)
        pupil = (float(z_xp), float(r_xp))
        self.image_circle_mm = None
        pixels = self.active_pixels(jobs, pupil)
        geo = measure_geometry(self.lens, self.sensor, jobs, options=self.options,
                               pupil_margin=self.pupil_margin, vignetting=self.vignetting,
                               pupil=pupil, pixels=pixels, image_circle_mm=self.image_circle_mm)
        self._geometry_cache = (meta, values, geo)
        return geo

    def active_pixels(self, jobs, pupil=None) -> torch.Tensor:
        """Indices (into ``H*W``) of the pixels inside the image circle (measured by tracing,
        :func:`~.geometry.image_circle_radius`; its radius is kept in ``image_circle_mm``).
        ``pupil``: the paraxial exit pupil ``(z_xp, r_xp)`` if already known."""
        if pupil is None:
            with torch.no_grad():
                pupil = exit_pupil(self.lens)
        z_xp, r_xp = float(pupil[0]), float(pupil[1])
        r_ic = image_circle_radius(self.lens, self.sensor, jobs, z_xp,
                                   r_xp * self.pupil_margin, self.options, r_xp)
        self.image_circle_mm = r_ic
        return pixels_inside(self.sensor, r_ic, self._dtype(), self._device())

    def reference_weight(self, plan, wavelength: float, n: int = 4096) -> float:
        """``w̄_0`` (:func:`~.geometry.reference_weight`; ``plan``: anything with the exit
        pupil ``z_xp`` and sampling radius ``r_xp``)."""
        return _reference_weight(self.lens, plan.z_xp, plan.r_xp, wavelength, self.options, n,
                                 r_core=plan.r_xp / self.pupil_margin)

    def _dtype(self):
        return self.lens.dtype

    def _device(self):
        return self.lens.device

    def _sensor_rays(self, x, y, ex, ey, z_xp, wavelength):
        return sensor_rays(self.lens, x, y, ex, ey, z_xp, wavelength)

    # ------------------------------------------------------------ the functional core
    def n_chunks(self, plan: RenderPlan) -> int:
        per = max(1, self.chunk_rays // self.spp)
        return max(1, math.ceil(plan.pixels.numel() / per))

    def chunk_pixels(self, plan: RenderPlan, k: int) -> torch.Tensor:
        per = max(1, self.chunk_rays // self.spp)
        return plan.pixels[k * per:(k + 1) * per]

    def render_chunk(self, plan: RenderPlan, scene: Scene, job: int, k: int) -> torch.Tensor:
        """Contribution ``(B, n)`` of wavelength job ``job`` to chunk ``k``'s pixels (its
        channel and weight applied).  Deterministic given ``plan.seed``: the adjoint pass
        re-traces exactly the same rays."""
        dtype, device = self._dtype(), self._device()
        channel, wavelength, weight = plan.jobs[job]
        pix = self.chunk_pixels(plan, k)
        n, S = pix.numel(), self.spp
        g = torch.Generator(device=device).manual_seed(
            (plan.seed * 1_000_003 + job * 10_007 + k) % (2 ** 63))
        u = torch.rand((n, S, 4), generator=g, dtype=dtype, device=device)
        W = self.sensor.resolution[1]
        i = (pix // W).to(dtype)[:, None] + u[..., 0]
        j = (pix % W).to(dtype)[:, None] + u[..., 1]
        x, y = self.sensor.pixel_to_xy(i, j)
        rad = torch.sqrt(u[..., 2]) * plan.r_xp
        phi = u[..., 3] * (2 * math.pi)
        rays = self._sensor_rays(x, y, rad * torch.cos(phi), rad * torch.sin(phi), plan.z_xp,
                                 wavelength)
        w = rays.d[..., 2] ** 4
        out = self.lens.trace(rays, reverse=True, options=self.options)
        z0 = self.lens.z_vertices()[0]
        values = []
        valid_all = []
        for b in range(scene.batch):
            hit = self.lens.propagate_to_z(out, z0 - float(scene.depths_mm[b]))
            values.append(hit.o[..., :2])
            valid_all.append(hit.valid)
        XY = torch.stack(values)  # (B, n, S, 2)
        valid = torch.stack(valid_all)  # (B, n, S)
        tex = sample_texture(scene.textures, XY[..., 0].reshape(scene.batch, -1),
                             XY[..., 1].reshape(scene.batch, -1), plan.sizes.to(device))
        tex_c = tex[:, channel if scene.channels > 1 else 0].reshape(scene.batch, n, S)
        vw = valid.to(dtype) * w
        num = (vw * tex_c.to(dtype)).sum(-1)
        if self.vignetting:
            val = num / (S * plan.w_ref[job])
        else:
            den = vw.sum(-1)
            val = num / torch.where(den > 0, den, torch.ones_like(den))
        return weight * val

    def render_plain(self, plan: RenderPlan, scene: Scene) -> torch.Tensor:
        """The image ``(B, C, H, W)`` with every chunk recorded by autograd."""
        H, W = self.sensor.resolution
        B, C = scene.batch, (scene.channels if scene.channels > 1 else 1)
        dtype, device = self._dtype(), self._device()
        chans = [torch.zeros(B, H * W, dtype=dtype, device=device) for _ in range(C)]
        for job, (channel, _, _) in enumerate(plan.jobs):
            for k in range(self.n_chunks(plan)):
                pix = self.chunk_pixels(plan, k)
                chans[channel] = chans[channel].index_add(1, pix,
                                                          self.render_chunk(plan, scene, job, k))
        return torch.stack(chans, 1).reshape(B, C, H, W)

    def plan(self, scene: Scene, seed: int | None = None) -> RenderPlan:
        """The sampling plan of a render (pupil, pixels, normalisation, seed).  Re-using one plan
        renders with identical samples, e.g. for finite differences."""
        if not isinstance(scene, Scene):
            raise TypeError(f"MonteCarloRenderer expects a Scene, got {type(scene).__name__}")
        if seed is None:
            seed = self.seed + self._calls
            self._calls += 1
        jobs = tuple(self.sensor.wavelengths_for(scene.channels))
        geo = self.geometry(jobs)
        return RenderPlan(int(seed), jobs, geo, scene.resolved_sizes(geo.camera))

    def forward(self, scene: Scene, seed: int | None = None,
                plan: RenderPlan | None = None) -> torch.Tensor:
        """Render ``scene``; returns ``(B, C, H, W)`` in the lens's dtype (C = 1 for a
        monochrome scene).  ``plan`` (from :meth:`plan`) fixes the samples; the pupil and
        normalisation it holds are then constants for the gradient."""
        if plan is None:
            plan = self.plan(scene, seed)
        if self.adjoint:
            from .adjoint import adjoint_render

            return adjoint_render(self, plan, scene)
        return self.render_plain(plan, scene)
