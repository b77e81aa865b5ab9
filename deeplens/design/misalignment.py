"""Misalignment estimation (paper Sec. V-C, Eq. 15): fit a simulated spot image to a target.

    min_θ  || I(θ) - I_target ||^2  +  mu || C(I(θ)) - C(I_target) ||^2 ,

    C(I) = ( sum_ij I_ij (i + 1/2), sum_ij I_ij (j + 1/2) ) / sum_ij I_ij       (pixels)

``θ = (tilt_x, tilt_y, d_sensor, source_x, source_y)``: the lens's tilts (rad, about its first
vertex; :class:`~deeplens.optics.misalignment.Misalignment`), the last-vertex-to-sensor distance
(mm) and the lateral position of the source (mm) at the known distance ``source_distance_mm``
in front of the first vertex.  The source is an iris of radius ``iris_radius_mm`` lit by an LED
(the paper's 622 nm, 0.4 mm set-up): every ray starts at a point of that disk and aims at a
point of the lens's front vertex plane within its clear semi-diameter (both fixed seeded samples,
so that ``I(θ)`` is a deterministic, piecewise-smooth function).  Rays are forward-traced through
the (tilted) lens to the sensor plane and splatted bilinearly onto ``binning x binning`` binned
pixels of the sensor (:func:`~deeplens.render.splat.splat_bilinear`).

Scale: the target is divided by its maximum; the simulation is scaled to the target's total
(the unknown exposure gain), so ``I - I_target`` has entries of order one and the centroid term
is in (binned) pixels squared.  The optimisation runs in scaled variables
``x = (θ - θ_start) / scale`` so that a unit step in each is a comparable change of the image.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import torch
from torch import nn

from ..optics.io import load_lens
from ..optics.lens import Lens
from ..optics.rays import Rays
from ..optics.sampling import random_disk
from ..render.splat import splat_bilinear
from ..resources import lens_path

__all__ = ["LA1131_PATH", "PARAMS", "DEFAULT_TRUTH", "DEFAULT_START", "DEFAULT_SCALE", "SpotSetup",
           "SpotImager", "centroid", "eq15_residual", "parse_params", "synthesize_target",
           "estimate", "estimate_uncertainty", "load_target_image"]

#: the shipped LA1131 lens file (resolved from the package, not the working directory)
LA1131_PATH = str(lens_path("thorlabs_la1131.json"))
#: the estimated parameters, in this order (tilts rad, lengths mm)
PARAMS = ("tilt_x", "tilt_y", "d_sensor", "source_x", "source_y")
#: hidden values of the simulated experiment (LA1131 near its best focus, tilted by ~2-3 deg)
DEFAULT_TRUTH = {"tilt_x": 0.04, "tilt_y": -0.03, "d_sensor": 46.6, "source_x": 1.5,
                 "source_y": -1.0}
#: the coarse start: an aligned lens with the sensor at the paraxial back focal distance
DEFAULT_START = {"tilt_x": 0.0, "tilt_y": 0.0, "d_sensor": 46.3, "source_x": 0.0,
                 "source_y": 0.0}
#: the change of each parameter that counts as one unit step of the optimiser
DEFAULT_SCALE = {"tilt_x": 0.01, "tilt_y": 0.01, "d_sensor": 0.1, "source_x": 0.2,
                 "source_y": 0.2}


def parse_params(text: str | None, option: str, defaults: dict) -> dict:
    """``"tilt_x=0.02,d_sensor=46.5"`` -> a full dict (missing names take ``defaults``).

    Raises:
        ValueError: an unknown name, a missing ``=``, or a value that is not a finite number;
            the message names ``option``.
    """
    out = dict(defaults)
    if not text:
        return out
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            raise ValueError(f"{option}: expected NAME=VALUE items separated by commas, got "
                             f"{item!r}")
        k, v = (s.strip() for s in item.split("=", 1))
        if k not in PARAMS:
            raise ValueError(f"{option}: unknown parameter {k!r}; expected one of "
                             f"{', '.join(PARAMS)} (tilts in rad, lengths in mm)")
        try:
            val = float(v)
        except ValueError:
            raise ValueError(f"{option}: {k} must be a number, got {v!r}") from None
        if not math.isfinite(val):
            raise ValueError(f"{option}: {k} must be finite, got {v!r}")
        out[k] = val
    if not out["d_sensor"] > 0:
        raise ValueError(f"{option}: d_sensor must be > 0 mm, got {out['d_sensor']}")
    if max(abs(out["tilt_x"]), abs(out["tilt_y"])) > 0.5:
        raise ValueError(f"{option}: tilts are in radians and must stay within +-0.5, got "
                         f"tilt_x={out['tilt_x']}, tilt_y={out['tilt_y']}")
    return out


@dataclass
class SpotSetup:
    """The experiment's known quantities.

    Attributes:
        lens_path: lens file (LA1131 by default).
        wavelength_nm: LED wavelength (622 nm).
        source_distance_mm: iris to the lens's first vertex, along the axis (mm).
        iris_radius_mm: radius of the iris in front of the LED (mm).
        pixel_size_mm: the sensor's pixel pitch (3.45 µm).
        resolution: ``(H, W)`` sensor pixels used (a crop of the sensor around the axis).
        binning: pixels summed per side into one working pixel.
        n_rays: rays traced per image.
        seed: seed of the source and pupil samples.
    """

    lens_path: str = LA1131_PATH
    wavelength_nm: float = 622.0
    source_distance_mm: float = 1000.0
    iris_radius_mm: float = 0.4
    pixel_size_mm: float = 0.00345
    resolution: tuple = (384, 384)
    binning: int = 4
    n_rays: int = 120000
    seed: int = 0

    def check(self) -> None:
        H, W = (int(v) for v in self.resolution)
        if H < 1 or W < 1:
            raise ValueError(f"--resolution must be positive, got {self.resolution}")
        if self.binning < 1 or H % self.binning or W % self.binning:
            raise ValueError(f"--binning {self.binning} must divide the resolution {H}x{W}")
        for name, v in (("--pixel-size-um", self.pixel_size_mm),
                        ("--source-distance", self.source_distance_mm),
                        ("--iris-radius", self.iris_radius_mm)):
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a positive number, got {v}")
        if self.n_rays < 100:
            raise ValueError(f"--rays must be >= 100, got {self.n_rays}")

    @property
    def shape(self) -> tuple[int, int]:
        """Working image ``(H / binning, W / binning)``."""
        return int(self.resolution[0]) // self.binning, int(self.resolution[1]) // self.binning


class SpotImager(nn.Module):
    """``I(θ)``: the binned sensor image ``(h, w)`` of the iris through the lens.

    ``forward(theta)`` takes ``theta`` ``(5,)`` in the order of :data:`PARAMS` and returns the
    image (sum of ray weights per working pixel; each ray weighs ``1 / n_rays``).  The lens's own
    parameters are not modified: the five values enter through
    :func:`torch.func.functional_call`, so ``theta`` may carry autograd history.
    """

    def __init__(self, setup: SpotSetup, lens: Lens | None = None, seed: int | None = None):
        super().__init__()
        setup.check()
        self.setup = setup
        self.lens = lens if lens is not None else load_lens(setup.lens_path)
        if not self.lens.elements or self.lens.elements[0][0] != 0:
            raise ValueError("the lens needs its first element to start at surface 0")
        s = setup.seed if seed is None else seed
        n = int(setup.n_rays)
        self.register_buffer("src", random_disk(n, s) * setup.iris_radius_mm)
        # aim at the first vertex plane slightly beyond the clear aperture (tilted lens)
        r_aim = 1.05 * float(self.lens.surfaces[0].semi_diameter)
        self.register_buffer("aim", random_disk(n, s + 7919) * r_aim)
        self.aim_area = math.pi * r_aim ** 2

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        st = self.setup
        dtype, dev = theta.dtype, theta.device
        n = self.src.shape[0]
        z = torch.full((n, 1), -st.source_distance_mm, dtype=dtype, device=dev)
        o = torch.cat([self.src.to(theta) + theta[3:5], z], -1)
        target = torch.cat([self.aim.to(theta), torch.zeros_like(z)], -1)
        rays = Rays(o, target - o, st.wavelength_nm)
        params = {"misalignments.0.tilt_x": theta[0], "misalignments.0.tilt_y": theta[1],
                  "d_sensor": theta[2]}
        out = _call_with(self.lens, params, rays)
        H, W = (int(v) for v in st.resolution)
        p = st.pixel_size_mm * st.binning
        # Sensor convention (deeplens.render.sensor): row along +y, column along -x
        i = out.o[:, 1] / p + H / (2 * st.binning)
        j = -out.o[:, 0] / p + W / (2 * st.binning)
        ok = out.valid
        w = torch.where(ok, torch.full_like(i, 1.0 / n), torch.zeros_like(i))
        i = torch.where(ok, i, torch.zeros_like(i))
        j = torch.where(ok, j, torch.zeros_like(j))
        return splat_bilinear(i, j, w, st.shape)


class _Tracer(nn.Module):
    def __init__(self, lens):
        super().__init__()
        self.lens = lens

    def forward(self, rays):
        return self.lens.trace_to_sensor(rays)


def _call_with(lens: Lens, params: dict, rays: Rays) -> Rays:
    """``lens.trace_to_sensor(rays)`` with some parameters replaced by tensors (no copy)."""
    tracer = _Tracer(lens)
    return torch.func.functional_call(tracer, {f"lens.{k}": v for k, v in params.items()},
                                      (rays,))


def centroid(img: torch.Tensor) -> torch.Tensor:
    """Intensity centroid ``(2,)`` (row, column) in pixels, pixel centres at ``k + 1/2``."""
    H, W = img.shape
    i = torch.arange(H, dtype=img.dtype, device=img.device) + 0.5
    j = torch.arange(W, dtype=img.dtype, device=img.device) + 0.5
    s = img.sum().clamp_min(1e-30)
    return torch.stack([(img.sum(1) * i).sum() / s, (img.sum(0) * j).sum() / s])


def eq15_residual(img: torch.Tensor, target: torch.Tensor, mu: float) -> torch.Tensor:
    """Residual vector of Eq. 15: ``[I g - T (flattened), sqrt(mu) (C(I) - C(T))]``, with the
    gain ``g = sum T / sum I`` (an unknown exposure).  ``target`` is expected with maximum 1."""
    g = target.sum() / img.sum().clamp_min(1e-30)
    r_img = (img * g - target).reshape(-1)
    r_c = math.sqrt(mu) * (centroid(img) - centroid(target))
    return torch.cat([r_img, r_c])


def synthesize_target(setup: SpotSetup, truth: dict, *, noise: bool = True, seed: int = 1,
                      full_well: float = 2000.0, read_noise: float = 0.01,
                      ray_factor: int = 3) -> torch.Tensor:
    """A target image ``(h, w)`` (maximum 1) rendered from the hidden ``truth`` with
    ``ray_factor`` times more rays and other samples than the fit uses, plus shot noise (a peak
    of ``full_well`` electrons) and read noise (in units of the peak), seeded."""
    st = SpotSetup(**{**setup.__dict__, "n_rays": setup.n_rays * ray_factor})
    imager = SpotImager(st, seed=setup.seed + 1000 * seed)
    theta = torch.tensor([truth[k] for k in PARAMS], dtype=torch.float64)
    with torch.no_grad():
        img = imager(theta)
    img = img / img.max().clamp_min(1e-30)
    if noise:
        g = torch.Generator().manual_seed(seed)
        shot = torch.sqrt(img.clamp_min(0) / full_well) * torch.randn(img.shape, generator=g,
                                                                         dtype=img.dtype)
        img = img + shot + read_noise * torch.randn(img.shape, generator=g, dtype=img.dtype)
    return img / img.max()


def load_target_image(path: str, setup: SpotSetup) -> torch.Tensor:
    """Read a captured monochrome image (PNG/TIFF/... via scikit-image, or ``.npy``), check it
    against ``setup.resolution``, bin it, subtract its median (dark level) and divide by its
    maximum.

    Raises:
        ValueError: unreadable file, not a single-channel image, or a size other than
            ``--resolution``; each message names ``--target``.
    """
    import numpy as np

    try:
        if str(path).lower().endswith(".npy"):
            arr = np.load(path, allow_pickle=False)
        else:
            import skimage.io
            arr = skimage.io.imread(path)
    except Exception as e:  # noqa: BLE001 - any reader failure becomes one clear message
        raise ValueError(f"--target: cannot read {path!r} as an image ({type(e).__name__}: "
                         f"{e})") from None
    arr = np.asarray(arr)
    if arr.ndim == 3 and arr.shape[-1] in (3, 4):
        raise ValueError(f"--target: {path!r} is a colour image (shape {arr.shape}); the "
                         f"experiment uses a monochrome sensor: give one channel")
    if arr.ndim != 2:
        raise ValueError(f"--target: {path!r} must be a 2-D monochrome image, got shape "
                         f"{arr.shape}")
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"--target: {path!r} has pixel type {arr.dtype}; expected integers "
                         f"or floats")
    H, W = (int(v) for v in setup.resolution)
    if arr.shape != (H, W):
        raise ValueError(f"--target: {path!r} is {arr.shape[0]}x{arr.shape[1]} pixels but "
                         f"--resolution is {H}x{W} (crop the capture or change --resolution)")
    img = torch.as_tensor(arr.astype(np.float64))
    if not torch.isfinite(img).all():
        raise ValueError(f"--target: {path!r} contains NaN or infinite pixels")
    b = setup.binning
    img = img.reshape(H // b, b, W // b, b).sum((1, 3))
    img = (img - img.median()).clamp_min(0)
    if not float(img.max()) > 0:
        raise ValueError(f"--target: {path!r} is blank (no pixel above the median)")
    return img / img.max()


def estimate(target: torch.Tensor, setup: SpotSetup, start: dict | None = None, *,
             mu: float = 1.0, rounds: int = 3, adam_steps: int = 30, dls_steps_per_round: int = 4,
             lr: float = 0.3, scale: dict | None = None, history: list | None = None):
    """Estimate :data:`PARAMS` from ``target`` (``(h, w)``, maximum 1) by Eq. 15, alternating
    ``adam_steps`` of Adam (learning rate ``lr`` halved every round) and
    ``dls_steps_per_round`` of damped least squares (Jacobian by forward-mode AD, five
    Jacobian-vector products), ``rounds`` times, in the scaled variables
    ``x = (θ - θ_start) / scale`` (:mod:`deeplens.design.optimizers`).

    Args:
        history: a list that receives ``(phase, step, loss, theta dict)`` for every step.

    Returns:
        ``(estimate dict, fitted image (h, w) scaled to the target, seconds)``.
    """
    from .optimizers import adam, damped_least_squares

    t0 = time.perf_counter()
    if tuple(target.shape) != setup.shape:
        raise ValueError(f"target image is {tuple(target.shape)} working pixels; the set-up "
                         f"gives {setup.shape} (--resolution / --binning)")
    start = dict(DEFAULT_START if start is None else start)
    scale = dict(DEFAULT_SCALE if scale is None else scale)
    imager = SpotImager(setup)
    th0 = torch.tensor([start[k] for k in PARAMS], dtype=torch.float64)
    sc = torch.tensor([scale[k] for k in PARAMS], dtype=torch.float64)
    target = target.to(torch.float64)

    def theta_of(x):
        return th0 + sc * x

    def residual(x):
        return eq15_residual(imager(theta_of(x)), target, mu)

    def record(phase, res):
        if history is not None:
            for h in res.history:
                if h.get("accepted", True):
                    x = torch.as_tensor(h["x"], dtype=torch.float64)
                    history.append((phase, h["step"], h["merit"],
                                    dict(zip(PARAMS, theta_of(x).tolist()))))

    x = torch.zeros(len(PARAMS), dtype=torch.float64)
    for rnd in range(rounds):
        if adam_steps > 0:
            res = adam(residual, x, steps=adam_steps, lr=lr * 0.5 ** rnd)
            record("adam", res)
            x = res.x
        if dls_steps_per_round > 0:
            res = damped_least_squares(residual, x, steps=dls_steps_per_round,
                                       jacobian_mode="forward")
            record("dls", res)
            x = res.x
    with torch.no_grad():
        img = imager(theta_of(x))
        img = img * target.sum() / img.sum().clamp_min(1e-30)
    est = dict(zip(PARAMS, theta_of(x).tolist()))
    return est, img, time.perf_counter() - t0


def estimate_uncertainty(target: torch.Tensor, setup: SpotSetup, est: dict, *, mu: float = 1.0,
                         scale: dict | None = None):
    """Per-parameter standard deviations, correlations and the parameters the target does not
    identify, at the estimate ``est`` (:func:`~deeplens.design.identifiability.fit_uncertainty`
    on Eq. 15's residual; the noise from the fit's residual).  ``scale`` (default
    :data:`DEFAULT_SCALE`): a standard deviation above it marks a parameter not identifiable.
    Returns a :class:`~deeplens.design.identifiability.FitUncertainty`."""
    from .identifiability import fit_uncertainty

    scale = dict(DEFAULT_SCALE if scale is None else scale)
    imager = SpotImager(setup)
    target = target.to(torch.float64)
    theta = torch.tensor([est[k] for k in PARAMS], dtype=torch.float64)
    return fit_uncertainty(lambda th: eq15_residual(imager(th), target, mu), theta, PARAMS,
                           scale=[scale[k] for k in PARAMS])
