"""Rendering: splatting, PSFs, Monte Carlo images, adjoint gradients, bad input."""

from __future__ import annotations

import copy
import math
import warnings

import pytest
import torch
from helpers import central_fd

from deeplens.optics.io import load_lens
from deeplens.optics.lens import Lens
from deeplens.optics.materials import get_material
from deeplens.optics.surfaces import Aperture, Asphere, IdealLens
from deeplens.render import IdealCamera, MonteCarloRenderer, Scene, Sensor
from deeplens.render.psf import psf, psf_grid, psf_grids, psf_many
from deeplens.render.psf_conv import PSFConvRenderer, blend_weights
from deeplens.render.splat import splat_bilinear

AIR = "AIR"


def ideal_lens(f=50.0, stop_sd=5.0, object_distance=math.inf):
    """Stop 1 mm before a perfect lens; sensor at the image of ``object_distance``."""
    s_obj = object_distance + 1.0  # the lens sits 1 mm behind the first vertex
    v = f if math.isinf(object_distance) else 1.0 / (1.0 / f - 1.0 / s_obj)
    return Lens([Aperture(stop_sd), IdealLens(f, 3 * stop_sd)],
                [get_material(AIR) for _ in range(3)], [0.0, 1.0], v, 0)


def singlet(dtype=torch.float64):
    """A biconvex N-BK7 singlet, f ~ 50 mm, stop 2 mm in front."""
    lens = Lens([Aperture(4.0), Asphere(1 / 50.0, 8.0), Asphere(-1 / 50.0, 8.0)],
                [get_material(m) for m in (AIR, AIR, "N-BK7", AIR)], [0.0, 2.0, 5.0], 48.0, 0)
    return lens.to(dtype)


@pytest.fixture(scope="module")
def edof():
    return load_lens("data/lenses/edof_achromat.json")


# ---------------------------------------------------------------- splatting and PSFs
def test_splat_conserves_energy_and_is_bilinear():
    g = torch.Generator().manual_seed(0)
    i = torch.rand(500, generator=g, dtype=torch.float64) * 10 + 3
    j = torch.rand(500, generator=g, dtype=torch.float64) * 10 + 3
    w = torch.rand(500, generator=g, dtype=torch.float64)
    img = splat_bilinear(i, j, w, (16, 16))
    assert torch.allclose(img.sum(), w.sum(), rtol=1e-12)
    # a point at a pixel centre lands in that pixel only; halfway splits in two
    one = torch.ones(1, dtype=torch.float64)
    img = splat_bilinear(torch.tensor([4.5]), torch.tensor([7.5]), one, (8, 10))
    assert img[4, 7] == 1 and img.sum() == 1
    img = splat_bilinear(torch.tensor([4.5]), torch.tensor([8.0]), one, (8, 10))
    assert img[4, 7] == pytest.approx(0.5) and img[4, 8] == pytest.approx(0.5)


def test_splat_gradient_matches_finite_difference():
    i = torch.tensor([3.3, 5.7], dtype=torch.float64, requires_grad=True)
    j = torch.tensor([2.2, 6.6], dtype=torch.float64)
    wimg = torch.arange(100, dtype=torch.float64).reshape(10, 10) ** 1.5
    loss = (splat_bilinear(i, j, torch.ones(2, dtype=torch.float64), (10, 10)) * wimg).sum()
    (g,) = torch.autograd.grad(loss, i)
    h = 1e-6
    for k in range(2):
        e = torch.zeros(2, dtype=torch.float64)
        e[k] = h
        fp = (splat_bilinear(i.detach() + e, j, torch.ones(2, dtype=torch.float64), (10, 10))
              * wimg).sum()
        fm = (splat_bilinear(i.detach() - e, j, torch.ones(2, dtype=torch.float64), (10, 10))
              * wimg).sum()
        assert float(g[k]) == pytest.approx(float(fp - fm) / (2 * h), rel=1e-6)


def test_ideal_lens_in_focus_gives_delta_psf():
    lens = ideal_lens()
    sensor = Sensor((33, 33), 0.005)
    for field in [(0.0, 0.0), (0.02, -0.01)]:  # direction tangents for a point at infinity
        k, energy = psf(lens, sensor, field, math.inf, 550.0, n_rays=2000, return_energy=True)
        c = k.shape[-1] // 2
        assert float(k[c, c]) == pytest.approx(1.0, abs=1e-9)
        assert energy == pytest.approx(1.0, abs=1e-12)
    # out of focus: the same lens with the sensor 1 mm behind spreads the energy
    lens.d_sensor.data += 1.0
    k = psf(lens, sensor, (0.0, 0.0), math.inf, 550.0, n_rays=2000)
    assert float(k.max()) < 0.2 and k.shape[-1] > 9


def test_ideal_lens_finite_conjugate_delta_psf():
    lens = ideal_lens(object_distance=1000.0)
    sensor = Sensor((33, 33), 0.005)
    k = psf(lens, sensor, (10.0, -20.0), 1000.0, 550.0, n_rays=2000)
    c = k.shape[-1] // 2
    assert float(k[c, c]) == pytest.approx(1.0, abs=1e-4)  # 1e-4 px = 5e-10 mm


def test_on_axis_psf_is_rotationally_symmetric():
    lens = singlet()
    sensor = Sensor((64, 64), 0.004)
    # a square pupil grid is itself symmetric under flips and quarter turns
    k = psf(lens, sensor, (0.0, 0.0), math.inf, 587.56, n_rays=0, sampling="grid:201")
    assert k.shape[-1] >= 7
    peak = float(k.max())
    for other in (k.T, k.flip(0), k.flip(1), torch.rot90(k, 1)):
        assert float((k - other).abs().max()) < 1e-9 * peak
    # and the off-axis PSF is not (the comparison above can fail)
    k2 = psf(lens, sensor, (0.0, math.tan(math.radians(5))), math.inf, 587.56, n_rays=0,
             sampling="grid:201", kernel_size=k.shape[-1] + 20)
    assert float((k2 - k2.flip(0)).abs().max()) > 0.05 * float(k2.max())


def test_psf_kernel_size_follows_the_spot(edof):
    sensor = Sensor((64, 64), 0.0195)
    sizes = {d: psf(edof, sensor, (0.0, 0.0), d, 587.56, n_rays=2000).shape[-1]
             for d in (1500.0, 5000.0)}
    assert sizes[1500.0] > sizes[5000.0]


def test_batched_psfs_equal_the_per_job_ones():
    """``psf_many`` traces every job in one ``(J, n)`` batch and ``psf_grids`` every grid: the
    same kernels (sizes included) and lens gradients as one trace per job, with each job's own
    point, depth and wavelength (the singlet disperses, so a mixed-up wavelength shows)."""
    lens = singlet()
    c = lens.surfaces[1].c
    c.requires_grad_(True)
    sensor = Sensor((32, 32), 0.01)
    jobs = [((0.0, 0.0), 2000.0, 486.13), ((30.0, -20.0), 2000.0, 656.27),
            ((0.0, 0.0), 900.0, 587.56), ((-40.0, 10.0), 1500.0, 486.13)]
    batched = psf_many(lens, sensor, jobs, n_rays=3000, seed=4)
    single = [psf(lens, sensor, p, d, w, n_rays=3000, seed=4) for p, d, w in jobs]
    weights = [torch.linspace(0, 1, k.numel(), dtype=k.dtype).reshape(k.shape) for k in single]
    for a, b in zip(batched, single):
        assert a.shape == b.shape
        assert float((a - b).abs().max()) < 1e-12
    assert len({k.shape for k in single}) > 1  # the jobs differ (else the test is vacuous)
    (ga,) = torch.autograd.grad(sum((k * w).sum() for k, w in zip(batched, weights)), c)
    (gb,) = torch.autograd.grad(sum((k * w).sum() for k, w in zip(single, weights)), c)
    assert float(gb) != 0 and float(ga) == pytest.approx(float(gb), rel=1e-10)
    with torch.no_grad():
        specs = [(2000.0, 486.13), (900.0, 656.27)]
        for (kg, cg), (d, w) in zip(psf_grids(lens, sensor, specs, (2, 1), 2000, seed=1), specs):
            k1, c1 = psf_grid(lens, sensor, d, w, (2, 1), 2000, seed=1)
            assert kg.shape == k1.shape and float((kg - k1).abs().max()) < 1e-12
            assert torch.equal(cg, c1)
    with pytest.raises(ValueError, match="psf_many: 2 kernel sizes for 4 jobs"):
        psf_many(lens, sensor, jobs, n_rays=100, kernel_size=[5, 7])


# ---------------------------------------------------------------- Monte Carlo rendering
def test_uniform_scene_renders_uniform_without_vignetting(edof):
    sensor = Sensor((16, 16), 0.039)
    cam = IdealCamera(edof, sensor)
    scene = Scene(torch.ones(1, 8, 8, dtype=torch.float64), 5000.0, cam.fov_size_mm(5000.0) * 3)
    img = MonteCarloRenderer(edof, sensor, spp=8, vignetting=False)(scene)
    assert img.shape == (1, 1, 16, 16)
    assert torch.allclose(img, torch.ones_like(img), atol=1e-12)
    # with vignetting on, the centre is ~1 and the corners are darker (cos^4 and lost rays)
    img = MonteCarloRenderer(edof, sensor, spp=256, vignetting=True)(scene)
    assert float(img[0, 0, 7:9, 7:9].mean()) == pytest.approx(1.0, abs=0.05)
    assert float(img[0, 0, 0, 0]) < float(img[0, 0, 7:9, 7:9].mean())


def _sharpness_error(lens, sensor, depth, spp=32):
    g = torch.Generator().manual_seed(0)
    tex = (torch.rand(1, 64, 64, generator=g, dtype=torch.float64) > 0.5).double()
    scene = Scene(tex, depth)
    img = MonteCarloRenderer(lens, sensor, spp=spp, vignetting=False, seed=1)(scene)
    gt = IdealCamera(lens, sensor).render(scene)
    return float(((img - gt) ** 2).mean())


def test_edof_lens_is_sharper_at_its_focus(edof):
    sensor = Sensor((32, 32), 0.0195)
    # the depth the sensor is focused at, from the paraxial image equation
    errs = {d: _sharpness_error(edof, sensor, d) for d in (1500.0, 5000.0, 50000.0)}
    assert errs[5000.0] < 0.5 * errs[1500.0]
    assert errs[5000.0] < errs[50000.0]


def test_monochrome_scene_traces_one_wavelength(edof):
    sensor = Sensor((8, 8), 0.05)
    r = MonteCarloRenderer(edof, sensor, spp=2)
    mono = r.plan(Scene(torch.ones(1, 4, 4, dtype=torch.float64), 5000.0), 0)
    rgb = r.plan(Scene(torch.ones(3, 4, 4, dtype=torch.float64), 5000.0), 0)
    assert len(mono.jobs) == 1 and len(rgb.jobs) == 3


def test_one_channel_sensor_integrates_its_wavelengths(edof):
    """A panchromatic one-channel sensor: a grey scene is rendered at each of the channel's
    wavelengths with its weights (not at one wavelength): the render is the weighted sum of the
    one-hot-weighted renders (same samples), and those differ by wavelength."""
    waves = [486.1327, 587.5618, 656.2725]
    weights = (0.2, 0.5, 0.3)
    pan = Sensor((8, 8), 0.05, channels=[waves], channel_weights=[list(weights)])
    assert pan.wavelengths_for(1) == [(0, w, wt) for w, wt in zip(waves, weights)]
    scene = Scene(torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0),
                             dtype=torch.float64), 5000.0)
    lens = copy.deepcopy(edof).double()

    def render(sensor):
        return MonteCarloRenderer(lens, sensor, spp=2, vignetting=False)(scene, seed=3)

    img = render(pan)
    parts = [render(Sensor((8, 8), 0.05, channels=[waves],
                           channel_weights=[[float(i == k) for i in range(3)]]))
             for k in range(3)]
    assert img.shape == (1, 1, 8, 8)
    assert torch.allclose(img, sum(w * p for w, p in zip(weights, parts)), rtol=0, atol=1e-12)
    assert float((parts[0] - parts[2]).abs().max()) > 1e-3  # the wavelengths really differ
    with pytest.raises(ValueError, match=r"3 channels on a sensor with 1 channel\(s\); use 1$"):
        pan.wavelengths_for(3)


def test_geometry_is_cached_until_the_lens_changes(edof):
    """The exit pupil / image-circle probe is traced once while nothing changes, and again after
    any change of a lens value (in place, through ``.data``, a buffer) or of the wavelengths;
    a cached render equals a fresh renderer's render bit for bit."""
    lens = copy.deepcopy(edof).double()
    sensor = Sensor((8, 8), 0.05)
    r = MonteCarloRenderer(lens, sensor, spp=2, vignetting=True)
    calls = []
    probe = r.active_pixels
    r.active_pixels = lambda jobs, pupil=None: calls.append(1) or probe(jobs, pupil)
    rgb = Scene(torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(0),
                           dtype=torch.float64), 5000.0)
    img = r(rgb, seed=5)
    r(rgb, seed=6)
    assert len(calls) == 1
    fresh = MonteCarloRenderer(lens, sensor, spp=2, vignetting=True)(rgb, seed=5)
    assert torch.equal(img, fresh)
    r(Scene(torch.ones(1, 1, 8, 8, dtype=torch.float64), 5000.0), seed=7)  # other wavelengths
    assert len(calls) == 2
    r(rgb, seed=5)
    assert len(calls) == 3
    with torch.no_grad():
        lens.surfaces[4].a[3] += 1e-6  # in place, as an optimiser step
    r(rgb, seed=5)
    assert len(calls) == 4
    lens.d_sensor.data += 0.01  # bypasses autograd's version counter
    r(rgb, seed=5)
    assert len(calls) == 5
    lens.surfaces[1].semi_diameter.fill_(5.0)  # a buffer
    shrunk = r(rgb, seed=5)
    assert len(calls) == 6 and not torch.equal(shrunk, img)


def test_pixels_outside_the_image_circle_are_not_traced():
    import re

    lens = singlet()
    sensor = Sensor((60, 60), 4.0)  # 339 mm diagonal: far larger than the image circle
    scene = Scene(torch.ones(1, 8, 8, dtype=torch.float64), 1000.0)
    r = MonteCarloRenderer(lens, sensor, spp=2)
    with pytest.warns(UserWarning, match="larger than the lens's image circle") as rec:
        img = r(scene)
    assert 0 < r.image_circle_mm < sensor.half_diagonal_mm
    n_out = int(re.search(r": (\d+) of 3600 pixels", str(rec[0].message)).group(1))
    assert 0 < n_out <= int((img[0, 0] == 0).sum())  # the culled pixels are dark
    assert float(img[0, 0, 0, 0]) == 0.0 and not torch.isnan(img).any()


def test_no_image_circle_warning_when_every_pixel_is_traced():
    """Regression: a sensor whose half-diagonal barely exceeds the image circle (84.85 vs
    82.17 mm) but whose every pixel still overlaps it warned "0 of 3600 pixels receive no
    light"."""
    lens = singlet()
    sensor = Sensor((60, 60), 2.0)
    r = MonteCarloRenderer(lens, sensor, spp=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r(Scene(torch.ones(1, 8, 8, dtype=torch.float64), 1000.0))
    assert r.image_circle_mm < sensor.half_diagonal_mm


def test_adjoint_gradients_equal_autograd():
    lens = singlet()
    lens.surfaces[1].c.requires_grad_(True)
    lens.surfaces[2].k.requires_grad_(True)
    lens.distances[2].requires_grad_(True)
    lens.d_sensor.requires_grad_(True)
    sensor = Sensor((12, 12), 0.02)
    g = torch.Generator().manual_seed(0)
    tex = torch.rand(3, 32, 32, generator=g, dtype=torch.float64, requires_grad=True)
    target = torch.rand(1, 3, 12, 12, generator=g, dtype=torch.float64)
    params = [p for p in lens.parameters() if p.requires_grad]
    grads = {}
    for adjoint in (False, True):
        r = MonteCarloRenderer(lens, sensor, spp=4, adjoint=adjoint, chunk_rays=100)
        img = r(Scene(tex, 1000.0), seed=7)
        loss = ((img - target) ** 2).sum()
        grads[adjoint] = torch.autograd.grad(loss, params + [tex])
    for a, b in zip(grads[False], grads[True]):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-14)
    assert all(float(g.abs().max()) > 0 for g in grads[True])


def test_decorrelated_adjoint_pairs_the_image_with_independent_jacobian_samples():
    """decorrelate=True: the value is the seed-A render, the gradient is J_B^T dL/dI(I_A), B the
    independent seed; checked against plain autograd of ``I_A.detach() + I_B - I_B.detach()``."""
    from deeplens.render.adjoint import decorrelated_seed

    lens = singlet()
    lens.surfaces[1].c.requires_grad_(True)
    lens.d_sensor.requires_grad_(True)
    sensor = Sensor((12, 12), 0.02)
    g = torch.Generator().manual_seed(1)
    tex = torch.rand(3, 32, 32, generator=g, dtype=torch.float64)
    target = torch.rand(1, 3, 12, 12, generator=g, dtype=torch.float64)
    params = [p for p in lens.parameters() if p.requires_grad]
    scene = Scene(tex, 1000.0)

    def loss_of(img):
        return ((img - target) ** 2).sum()

    dec = MonteCarloRenderer(lens, sensor, spp=2, decorrelate=True, chunk_rays=100)
    img = dec(scene, seed=7)
    g_dec = torch.autograd.grad(loss_of(img), params)
    plain = MonteCarloRenderer(lens, sensor, spp=2, adjoint=False, chunk_rays=100)
    img_a = plain(scene, seed=7)
    img_b = plain(scene, seed=decorrelated_seed(7))
    assert torch.equal(img, img_a.detach())
    g_ref = torch.autograd.grad(loss_of(img_a.detach() + img_b - img_b.detach()), params)
    g_shared = torch.autograd.grad(loss_of(img_a), params)
    for a, b, c in zip(g_dec, g_ref, g_shared):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-14)
        assert float((a - c).abs().max()) > 1e-6 * float(c.abs().max())  # really other samples
    with pytest.raises(ValueError, match="decorrelate=True needs adjoint=True"):
        MonteCarloRenderer(lens, sensor, adjoint=False, decorrelate=True)


def _singlet_setup(device, seed_tex=2):
    """The f ~ 50 mm singlet with its curvature, conic and sensor distance trainable, a 12 x 12
    sensor, an RGB texture at 1 m and a fixed target, on ``device``."""
    lens = singlet().to(device)
    for p in (lens.surfaces[1].c, lens.surfaces[2].k, lens.d_sensor):
        p.requires_grad_(True)
    g = torch.Generator().manual_seed(seed_tex)
    tex = torch.rand(3, 32, 32, generator=g, dtype=torch.float64).to(device)
    target = torch.rand(1, 3, 12, 12, generator=g, dtype=torch.float64).to(device)
    params = [p for p in lens.parameters() if p.requires_grad]
    return lens, Sensor((12, 12), 0.02), Scene(tex, 1000.0), target, params


def _loss_and_grads(device, adjoint, seed, spp=8):
    lens, sensor, scene, target, params = _singlet_setup(device)
    r = MonteCarloRenderer(lens, sensor, spp=spp, adjoint=adjoint, chunk_rays=200)
    img = r(scene, seed=seed)
    assert img.device.type == torch.device(device).type and bool(torch.isfinite(img).all())
    loss = ((img - target) ** 2).sum()
    grads = torch.autograd.grad(loss, params)
    return torch.cat([loss.detach()[None], *[g.reshape(1) for g in grads]]).cpu()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_adjoint_render_equals_autograd_and_agrees_with_the_cpu():
    """On CUDA the adjoint gradient equals plain autograd's for the same samples (float64: only
    the order of the sums differs), and loss and gradients agree with the CPU's in expectation:
    the CUDA generator draws other samples, so the means over 10 seeds per device must agree
    within 6 standard errors of their difference (a chance failure ~1e-5 per value, t with 18
    degrees of freedom)."""
    a = _loss_and_grads("cuda", True, 7)
    b = _loss_and_grads("cuda", False, 7)
    assert torch.allclose(a, b, rtol=1e-10, atol=1e-14)
    assert bool((a[1:].abs() > 0).all())
    runs = {dev: torch.stack([_loss_and_grads(dev, True, off + k, spp=16) for k in range(10)])
            for dev, off in (("cpu", 0), ("cuda", 1000))}
    mean = {d: v.mean(0) for d, v in runs.items()}
    se = torch.sqrt(sum(v.var(0) / v.shape[0] for v in runs.values()))
    assert bool(((mean["cuda"] - mean["cpu"]).abs() <= 6 * se).all()), (mean, se)
    assert bool((se < 0.25 * mean["cpu"].abs()).all())  # the comparison resolves every value


@pytest.mark.parametrize("adjoint", [False, True])
def test_image_gradient_matches_finite_difference(adjoint):
    lens = singlet()
    sensor = Sensor((10, 10), 0.03)
    y, x = torch.meshgrid(torch.linspace(-1, 1, 64, dtype=torch.float64),
                          torch.linspace(-1, 1, 64, dtype=torch.float64), indexing="ij")
    tex = torch.exp(-((x - 0.2) ** 2 + y ** 2) / 0.1)[None]  # smooth: no bilinear kinks matter
    weights = torch.rand(1, 1, 10, 10, generator=torch.Generator().manual_seed(3),
                         dtype=torch.float64)

    renderer = MonteCarloRenderer(lens, sensor, spp=8, adjoint=adjoint, vignetting=True)
    scene = Scene(tex, 1000.0, (20.0, 20.0))
    plan = renderer.plan(scene, seed=11)  # identical samples for every evaluation

    def loss_fn():
        return (renderer(scene, plan=plan) * weights).sum()

    for p, h in ((lens.surfaces[1].c, 1e-7), (lens.d_sensor, 1e-5)):
        p.requires_grad_(True)
        (g,) = torch.autograd.grad(loss_fn(), p)
        p.requires_grad_(False)
        fd = central_fd(loss_fn, p, h)
        assert abs(fd) > 1e-3
        assert float(g) == pytest.approx(fd, rel=1e-4)


def test_no_nan_when_rays_miss_or_graze():
    lens = singlet()
    lens.surfaces[1].c.requires_grad_(True)
    lens.d_sensor.requires_grad_(True)
    sensor = Sensor((12, 12), 0.2)
    tex = torch.rand(1, 16, 16, dtype=torch.float64)
    # a tiny texture: most rays miss it (texture edge, black surround); a large sensor: grazing
    # and fully vignetted pixels
    for scene in (Scene(tex, 1000.0, (0.5, 0.5)), Scene(tex, 1000.0)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            img = MonteCarloRenderer(lens, sensor, spp=4)(scene)
        loss = (img ** 2).sum()
        g = torch.autograd.grad(loss, [lens.surfaces[1].c, lens.d_sensor])
        assert not torch.isnan(img).any()
        assert all(torch.isfinite(x).all() for x in g)


def test_psf_convolution_matches_ray_tracing_on_axis(edof):
    sensor = Sensor((24, 24), 0.0195)
    g = torch.Generator().manual_seed(0)
    tex = torch.rand(1, 48, 48, generator=g, dtype=torch.float64)
    scene = Scene(tex, 3000.0)  # defocused: a broad, near shift-invariant PSF over this field
    mc = MonteCarloRenderer(edof, sensor, spp=256, vignetting=False)(scene)
    pc = PSFConvRenderer(edof, sensor, n_rays=20000)(scene)
    gt = IdealCamera(edof, sensor).render(scene)
    inner = (slice(None), slice(None), slice(6, -6), slice(6, -6))
    err = float((mc - pc)[inner].abs().mean())
    assert err < 0.25 * float((mc - gt)[inner].abs().mean())


def test_psf_convolution_brings_scene_beyond_the_frame_into_its_edges(edof):
    """A scene larger than the field of view: the PSF-convolved image's edge pixels receive
    the light blurred in from beyond the frame, as the ray-traced image's do (with a black
    surround instead of the scene the edge ring was 20-40 % too dark)."""
    sensor = Sensor((24, 24), 0.0195)
    g = torch.Generator().manual_seed(1)
    tex = 0.5 + 0.5 * torch.rand(1, 72, 72, generator=g, dtype=torch.float64)
    cam = IdealCamera(edof, sensor)
    scene = Scene(tex, 3000.0, cam.fov_size_mm(3000.0) * 1.5)
    mc = MonteCarloRenderer(edof, sensor, spp=256, vignetting=False)(scene)
    pc = PSFConvRenderer(edof, sensor, n_rays=20000)(scene)
    ring = torch.ones(24, 24, dtype=torch.bool)
    ring[3:-3, 3:-3] = False
    err = (mc - pc)[..., ring].abs().mean()
    assert float(err) < 0.02 * float(mc[..., ring].mean())
    # the extended ground truth is the plain one in its middle, and samples beyond the frame
    big = cam.render(scene, pad=5)
    assert big.shape[-2:] == (34, 34)
    assert torch.allclose(big[..., 5:-5, 5:-5], cam.render(scene))
    assert float(big[..., :5, :].mean()) > 0.5
    with pytest.raises(ValueError, match="pad must be >= 0"):
        cam.render(scene, pad=-1)


def test_blend_weights_partition_unity():
    w = blend_weights((20, 30), (3, 4))
    assert w.shape == (12, 20, 30)
    assert torch.allclose(w.sum(0), torch.ones(20, 30, dtype=torch.float64))


# ---------------------------------------------------------------- bad input
def test_bad_input_messages(edof):
    sensor = Sensor((8, 8), 0.05)
    with pytest.raises(ValueError, match=r"\(B, C, H, W\)"):
        Scene(torch.ones(8, 8), 5000.0)
    with pytest.raises(ValueError, match="spp"):
        MonteCarloRenderer(edof, sensor, spp=0)
    with pytest.raises(ValueError, match="in front of the first vertex"):
        Scene(torch.ones(1, 4, 4), -100.0)
    with pytest.raises(ValueError, match="2 textures need 2 depths"):
        Scene(torch.ones(2, 1, 4, 4), [1000.0, 2000.0, 3000.0])
    with pytest.raises(ValueError, match="channels"):
        MonteCarloRenderer(edof, sensor)(Scene(torch.ones(2, 4, 4, dtype=torch.float64), 5e3))
    with pytest.raises(ValueError, match="micrometres"):
        Sensor((8, 8), 0.05, channels=[[0.55]])


def test_psf_convolution_keeps_its_kernels_while_the_optics_do_not_change(edof, monkeypatch):
    """The PSF renderer traces its kernels once while no lens or sensor tensor changes and
    none trains (a training run's optics warm-up, an evaluation): the same image, no second
    trace; an in-place change of a lens tensor, another seed or a lens that trains traces
    again."""
    import deeplens.render.psf_conv as pcm

    sensor = Sensor((16, 16), 0.0195)
    g = torch.Generator().manual_seed(0)
    scene = Scene(torch.rand(1, 32, 32, generator=g, dtype=torch.float64), 3000.0)
    lens = copy.deepcopy(edof)
    for p in lens.parameters():
        p.requires_grad_(False)
    calls = []
    real = pcm.psf_grids

    def spy(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(pcm, "psf_grids", spy)
    r = PSFConvRenderer(lens, sensor, n_rays=2000)
    first = r(scene)
    again = r(scene)
    assert len(calls) == 1 and torch.equal(first, again)
    assert torch.equal(PSFConvRenderer(lens, sensor, n_rays=2000)(scene), first)  # not stale
    with torch.no_grad():
        lens.d_sensor.add_(1e-3)      # an in-place change (same seed): traced
    moved = r(scene)
    assert len(calls) == 3 and not torch.equal(moved, first)
    r(scene)                          # unchanged since: kept
    assert len(calls) == 3
    r(scene, seed=1)                  # another ray sample: traced
    assert len(calls) == 4
    lens.d_sensor.requires_grad_(True)   # a lens that trains: traced every time
    r(scene, seed=1)
    r(scene, seed=1)
    assert len(calls) == 6
