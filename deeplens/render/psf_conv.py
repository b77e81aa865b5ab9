"""PSF-convolution rendering: the fast, shift-invariant approximation.

    I_c = sum_k w_k (GT_c ⊛ PSF_{c,k})

``GT`` is the ideal camera's sharp image (:class:`~deeplens.render.scene.IdealCamera`),
``PSF_{c,k}`` the PSF of the plane's depth at patch centre ``k`` for channel ``c`` (its
wavelengths weighted, :func:`~deeplens.render.psf.psf_grid`) and ``w_k`` bilinear blending
weights between patch centres (one patch: a single convolution).  ``GT`` is rendered beyond the
frame's edges by the largest kernel's half width, so the blur brings the scene's content
(``scene.margin``) into the edge pixels, as the ray tracer does, not a black surround.  Exact
only where the system is shift-invariant over a patch; relative illumination is not modelled
(PSFs sum to one).  Same call interface as
:class:`~deeplens.render.monte_carlo.MonteCarloRenderer`.
"""

from __future__ import annotations

import torch
from torch import nn

from ..optics.camera import Camera, HoldsCamera, as_camera
from .fftconv import correlate_valid
from .psf import _grid_points, psf_grids
from .scene import IdealCamera, Scene

__all__ = ["PSFConvRenderer", "blend_weights"]


def blend_weights(shape, grid, dtype=torch.float64, device=None) -> torch.Tensor:
    """Bilinear (tent) weights ``(gy*gx, H, W)`` between patch centres; they sum to one."""
    H, W = shape
    gy, gx = grid

    def tents(n, g):
        c = (torch.arange(g, dtype=dtype, device=device) + 0.5) * n / g
        x = torch.arange(n, dtype=dtype, device=device) + 0.5
        if g == 1:
            return torch.ones(1, n, dtype=dtype, device=device)
        step = n / g
        w = (1 - (x[None] - c[:, None]).abs() / step).clamp_min(0)
        w[0, x <= c[0]] = 1.0
        w[-1, x >= c[-1]] = 1.0
        return w / w.sum(0, keepdim=True)

    wy, wx = tents(H, gy), tents(W, gx)
    return (wy[:, None, :, None] * wx[None, :, None, :]).reshape(gy * gx, H, W)


class PSFConvRenderer(HoldsCamera, nn.Module):
    """Renders a scene as the ideal image convolved with the lens's PSFs.

    Args:
        lens, sensor, options: as for :class:`~deeplens.render.monte_carlo.MonteCarloRenderer`
            (a :class:`~deeplens.optics.camera.Camera`, or a lens with its sensor and trace
            options).
        n_rays: rays per PSF.
        patches: ``(gy, gx)`` PSF grid over the field (``(1, 1)``: one on-axis PSF).
        kernel_size: force the kernel size (odd); ``None`` sizes it from the spots.
        supersample: ground-truth supersampling.
        seed: base seed of the PSF ray samples.
        psf_model: a :class:`~deeplens.render.psf_model.PSFModel` (``None``: geometric).
    """

    def __init__(self, lens: Camera, sensor=None, n_rays: int = 4096, patches=(1, 1),
                 kernel_size: int | None = None, supersample: int = 2, options=None,
                 seed: int = 0, psf_model=None):
        super().__init__()
        self.psf_model = psf_model
        if int(n_rays) < 1:
            raise ValueError(f"PSFConvRenderer: n_rays must be >= 1, got {n_rays}")
        camera = as_camera(lens, sensor, options, "PSFConvRenderer")
        if camera.sensor is None:
            raise ValueError("PSFConvRenderer: the camera has no sensor (Camera(lens, sensor))")
        self._held = (camera,)  # held, not registered: the module that built it owns it
        # registered as before (state-dict keys ``lens.*``, ``sensor.*``): the camera's own
        self.lens, self.sensor = camera.lens, camera.sensor
        self.n_rays, self.patches = int(n_rays), tuple(int(p) for p in patches)
        self.kernel_size, self.supersample = kernel_size, int(supersample)
        self.seed = int(seed)
        self._psf_cache = None  # (key, options, kernels) of a lens that is not training

    def _psf_key(self, specs, model, seed):
        """What the PSF kernels depend on besides the trace options: the lens's and the
        sensor's tensors (identity and in-place version), the jobs and the settings."""
        tensors = [*self.lens.parameters(), *self.lens.buffers(), *self.sensor.parameters(),
                   *self.sensor.buffers()]
        return (tuple(specs), model, self.patches, self.n_rays, self.kernel_size,
                None if model == "diffraction" else int(seed),
                tuple((t.data_ptr(), t._version) for t in tensors))


    def forward(self, scene: Scene, seed: int | None = None) -> torch.Tensor:
        if not isinstance(scene, Scene):
            raise TypeError(f"PSFConvRenderer expects a Scene, got {type(scene).__name__}")
        seed = self.seed if seed is None else seed
        dtype = self.lens.dtype
        jobs = self.sensor.wavelengths_for(scene.channels)
        H, W = self.sensor.resolution
        depths = scene.depths_mm.tolist()
        kernels = {}  # (depth, job) -> (P, 1, K, K), flipped: convolution, not correlation
        specs = [(depth, c, w) for depth in sorted(set(depths)) for c, w, _ in jobs]
        model = ("geometric" if self.psf_model is None
                 else self.psf_model.resolve(self.lens, self.sensor, self.options))
        # the kernels are kept while no lens or sensor tensor changes, none trains and the
        # depths repeat (validation and test batches of a frozen lens): the same values, traced
        # once (a training batch draws its own depths, so it traces its own)
        training = torch.is_grad_enabled() and any(p.requires_grad
                                                   for p in self.lens.parameters())
        key = self._psf_key(specs, model, seed)
        cached = self._psf_cache
        if (not training and cached is not None and cached[0] == key
                and cached[1] is self.options):
            kernels = dict(cached[2])
        else:
            if model == "diffraction":
                grids = self.diffraction_grids([(d, w) for d, _, w in specs])
            else:
                grids = psf_grids(self.lens, self.sensor, [(d, w) for d, _, w in specs],
                                  self.patches, self.n_rays, self.kernel_size, seed,
                                  self.options)  # one trace
            for (depth, c, w), (kers, _) in zip(specs, grids):
                K = kers.shape[-1]
                kernels[depth, c, w] = kers.reshape(-1, 1, K, K).flip(-1, -2)
            self._psf_cache = None if training else (
                key, self.options, {k: v.detach() for k, v in kernels.items()})
        # the ideal image extended by the largest kernel's half width: light that the blur
        # brings in from beyond the frame's edge is scene content (scene.margin), not black
        pad = max(k.shape[-1] for k in kernels.values()) // 2
        gt = IdealCamera(self.lens, self.sensor).render(scene, self.supersample, pad=pad).to(dtype)
        blend = blend_weights((H, W), self.patches, dtype, gt.device)
        out = gt.new_zeros(gt.shape[0], gt.shape[1], H, W)
        for depth in sorted(set(depths)):
            idx = [b for b, d in enumerate(depths) if d == depth]
            chans = [torch.zeros(len(idx), H, W, dtype=dtype, device=gt.device)
                     for _ in range(gt.shape[1])]
            for c, w, wt in jobs:
                kers = kernels[depth, c, w]
                r = pad - kers.shape[-1] // 2  # this kernel's window of the extended image
                x = gt[idx, c:c + 1, r:r + H + kers.shape[-1] - 1, r:r + W + kers.shape[-1] - 1]
                y = correlate_valid(x, kers.to(x))  # (b, P, H, W): F.conv2d by FFT
                chans[c] = chans[c] + wt * (y * blend[None]).sum(1)
            out[idx] = torch.stack(chans, 1)
        return out

    def diffraction_grids(self, specs):
        """:func:`~deeplens.render.psf.psf_grids` with diffraction kernels (one trace)."""
        camera = IdealCamera(self.lens, self.sensor)
        gy, gx = self.patches
        grids = [_grid_points(camera, d, self.patches) for d, _ in specs]
        jobs = [(P, d, w) for (d, w), (pts, _) in zip(specs, grids) for P in pts]
        kers = self.psf_model.diffraction(self.lens, self.sensor, jobs, self.options)
        per, K = gy * gx, kers[0].shape[-1]
        return [(torch.stack(kers[k * per:(k + 1) * per]).reshape(gy, gx, K, K), centres)
                for k, (_, centres) in enumerate(grids)]
