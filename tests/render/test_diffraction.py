"""Diffraction PSFs on the sensor's pixels (deeplens.render.diffraction) and the PSF model.

Closed forms (Airy pattern, defocus Strehl), an independent direct Fourier sum, the analysis
suite's Huygens PSF (itself checked against optiland), gradients against central differences.
"""

from __future__ import annotations

import math

import pytest
import torch
from helpers import central_fd
from scipy.special import j1

from deeplens.optics.io import load_lens
from deeplens.optics.lens import Lens
from deeplens.optics.materials import get_material
from deeplens.optics.surfaces import Aperture, IdealLens
from deeplens.render import Scene, Sensor
from deeplens.render.diffraction import (DiffractionSampling, PSFMemoryError, _kernel,
                                         check_memory, choose_sampling, diffraction_psf_many)
from deeplens.render.psf_conv import PSFConvRenderer
from deeplens.render.psf_model import PSFModel, run_jobs, tv_distance

WL = 587.5618


def ideal_lens(f=50.0, stop_sd=5.0, object_distance=math.inf, dz=0.0):
    """Stop 1 mm before a perfect lens; sensor at the image of ``object_distance`` (+ dz)."""
    s_obj = object_distance + 1.0
    v = f if math.isinf(object_distance) else 1.0 / (1.0 / f - 1.0 / s_obj)
    return Lens([Aperture(stop_sd), IdealLens(f, 3 * stop_sd)],
                [get_material("AIR") for _ in range(3)], [0.0, 1.0], v + dz, 0).to(torch.float64)


def airy_pixels(K, pitch, lam_N, sub=24):
    """Closed-form Airy intensity (unit total energy) integrated over ``K x K`` pixels."""
    t = (torch.arange(K * sub, dtype=torch.float64) + 0.5) / sub - K / 2
    x = t * pitch
    r = torch.sqrt(x[:, None] ** 2 + x[None, :] ** 2)
    v = math.pi * r / lam_N
    a = torch.where(v > 1e-12, 2 * torch.from_numpy(j1(v.numpy())) / v.clamp_min(1e-12),
                    torch.ones_like(v))
    peak = math.pi / (4 * lam_N ** 2)  # intensity peak of a unit-energy Airy pattern
    I = peak * a ** 2
    return I.reshape(K, sub, K, sub).mean((1, 3)) * pitch ** 2


# ---------------------------------------------------------------- closed forms
# The optics layer's IdealLens deflects rays but adds no optical path (it is not a perfect
# lens for the wave), so the closed forms drive the propagation core with exact pupils: a
# uniform disk of numerical aperture NA (direction cosine NA at the rim), optionally defocused.
def disk_pupil(n=400, w20=0.0):
    g = torch.linspace(-1.1, 1.1, n, dtype=torch.float64)
    gy, gx = torch.meshgrid(g, g, indexing="ij")
    rho2 = gx ** 2 + gy ** 2
    A = (rho2 <= 1).double()
    return A, 2 * math.pi * w20 * rho2 * A


def airy_kernel(pitch, K, sub, lam=WL * 1e-6, na=0.1, w20=0.0, n=400):
    A, ph = disk_pupil(n, w20)
    b = torch.tensor(-na, dtype=torch.float64)
    return _kernel(A, ph, b, b, torch.tensor(1.0, dtype=torch.float64), lam, n, K, sub, pitch)


def test_disk_pupil_gives_the_airy_pattern():
    """First dark ring at 1.22 λN (within 1 %), 83.8 % of the energy inside it."""
    lam_N = WL * 1e-6 / (2 * 0.1)
    k = airy_kernel(lam_N / 64, 193, 1)
    row = k[96, 96:]
    r = int(torch.argmin(row[:96])) * lam_N / 64
    assert r == pytest.approx(1.2197 * lam_N, rel=0.01)
    pitch = lam_N / 8
    k = airy_kernel(pitch, 61, 4)
    t = (torch.arange(61, dtype=torch.float64) - 30) * pitch
    rr = torch.sqrt(t[:, None] ** 2 + t[None, :] ** 2)
    assert float(k[rr <= 1.2197 * lam_N].sum()) == pytest.approx(0.838, abs=0.01)


def test_pixel_integration_matches_the_integrated_airy_pattern():
    """At pixels as wide as λN the kernel is the Airy pattern integrated over each pixel (a
    kernel of point samples at the pixel centres fails this); the energy is Parseval's."""
    lam_N = WL * 1e-6 / (2 * 0.1)
    pitch = lam_N
    ref = airy_pixels(21, pitch, lam_N)
    k = airy_kernel(pitch, 21, 4)   # Gauss-Legendre: measured 0.015 % of the peak
    assert float((k - ref).abs().max()) < 0.002 * float(ref.max())
    point = airy_kernel(pitch, 21, 1)
    assert float((point - ref).abs().max()) > 0.05 * float(ref.max())
    assert float(k.sum()) == pytest.approx(float(ref.sum()), abs=2e-3)


def test_defocus_strehl_matches_the_defocus_coefficient():
    """Pure defocus W20 ρ² (waves): on-axis intensity ratio sinc²(W20) exactly."""
    pitch = WL * 1e-6 / 0.2 / 8
    for w20 in (0.2, 0.45):
        p0 = float(airy_kernel(pitch, 11, 1)[5, 5])
        p1 = float(airy_kernel(pitch, 11, 1, w20=w20)[5, 5])
        s = (math.sin(math.pi * w20) / (math.pi * w20)) ** 2
        assert p1 / p0 == pytest.approx(s, abs=0.01)


def test_wavelength_scales_the_pattern():
    """The dark ring moves with λ: 1.22 λN at 450 nm as well."""
    lam = 450e-6
    lam_N = lam / 0.2
    k = airy_kernel(lam_N / 8, 41, 1, lam=lam)
    row = k[20, 20:]
    m = int(torch.argmin(row[:16]))
    assert m * lam_N / 8 == pytest.approx(1.22 * lam_N, abs=lam_N / 8)


def test_cubic_pupil_kernel_matches_a_direct_fourier_sum():
    """The matrix Fourier transform of a cubic-phase pupil against a direct 2-D sum at a few
    points (independent of the separable form)."""
    n, K, pitch = 48, 15, 0.004
    g = torch.linspace(-1.1, 1.1, n, dtype=torch.float64)
    gy, gx = torch.meshgrid(g, g, indexing="ij")
    A = ((gx ** 2 + gy ** 2) <= 1).double()
    phase = 2 * math.pi * 3.0 * (gx ** 3 + gy ** 3) * A
    bx = by = torch.tensor(-0.05, dtype=torch.float64)
    lam = WL * 1e-6
    k = _kernel(A, phase, bx, by, torch.tensor(1.0, dtype=torch.float64), lam, n, K, 1, pitch)
    dnu = 0.05 * (2.2 / (n - 1)) / lam
    for (r, c) in [(7, 7), (4, 9), (11, 2), (7, 12)]:
        y = (r - K // 2) * pitch
        x = -(c - K // 2) * pitch
        arg = phase + 2 * math.pi * (-0.05) / lam * (gx * x + gy * y)
        U = (A * torch.exp(1j * arg)).sum()
        ref = float(U.abs() ** 2) * pitch ** 2 * dnu ** 2 / float(A.sum())
        assert float(k[r, c]) == pytest.approx(ref, rel=1e-9)
    assert not torch.allclose(k, k.flip(0), rtol=0.05)  # the cubic PSF is asymmetric


# ---------------------------------------------------------------- against the analysis suite
@pytest.fixture(scope="module")
def edof_plate():
    """The EDOF achromat with a 3-wave cubic plate (float64)."""
    lens = load_lens("data/lenses/edof_achromat.json").to(torch.float64)
    plate = lens.surfaces[4]
    n_glass = float(lens.materials[4].n(torch.tensor(WL, dtype=torch.float64)))
    a = 3.0 * WL * 1e-6 / ((n_glass - 1) * 6.0 ** 3)
    with torch.no_grad():
        plate.a[6].fill_(a)
        plate.a[9].fill_(a * 0.6)
    return lens


@pytest.mark.parametrize("depth,wl", [(6000.0, WL), (4500.0, 486.1327)])
def test_matches_the_huygens_psf_on_axis(edof_plate, depth, wl):
    """On axis at a finite depth (the spherical wave from the object point, the reference
    sphere at the sensor): our kernel (point samples) equals the analysis Huygens PSF at the
    same pixels (x flipped: kernel columns run along -x), to 3 % of the peak."""
    from deeplens.analysis.diffraction import psf_huygens

    lens = edof_plate
    lens.spec.object_distance_mm = depth
    pitch, K = 0.002, 41
    sensor = Sensor((64, 64), pitch)
    job = [((0.0, 0.0), depth, wl)]
    smp = choose_sampling(lens, sensor, job)
    k = diffraction_psf_many(lens, sensor, job, DiffractionSampling(smp.pupil, K, 1))[0]
    h = psf_huygens(lens, 0.0, wl, n=160, size=K, pixel_mm=pitch).psf.flip(1)
    k, h = k / k.sum(), h / h.sum()
    # 64 traced rays per side, the mask interpolated to the fine grid: measured 2.3 % at 6 m
    assert float((k - h).abs().max()) < 0.03 * float(h.max())
    assert float((k - h.roll(1, 0)).abs().max()) > 0.1 * float(h.max())  # a shift fails


# ---------------------------------------------------------------- gradients and the renderer
def _render_loss(lens, sensor, model, scene, target):
    r = PSFConvRenderer(lens, sensor, patches=(1, 1), psf_model=model)
    return ((r(scene) - target) ** 2).mean()


def test_rendered_image_gradients_match_central_differences(edof_plate):
    """A loss on the diffraction-rendered image: gradients to a plate coefficient, a
    curvature and the sensor distance against central differences (float64)."""
    lens = edof_plate
    sensor = Sensor((12, 12), 0.0069, channels=[[WL]])
    g = torch.Generator().manual_seed(0)
    scene = Scene(torch.rand(1, 1, 24, 24, generator=g, dtype=torch.float64), [6000.0])
    target = torch.rand(1, 1, 12, 12, generator=g, dtype=torch.float64)
    model = PSFModel("diffraction")
    model.sampling = choose_sampling(lens, sensor, [((0.0, 0.0), 6000.0, WL)])
    plate = lens.surfaces[4].a[6]
    curv = lens.surfaces[0].c
    dist = lens.d_sensor
    for p, idx, h in [(plate, None, 2e-7), (curv, None, 1e-6), (dist, None, 1e-4)]:
        was = p.requires_grad
        p.requires_grad_(True)
        (grad,) = torch.autograd.grad(_render_loss(lens, sensor, model, scene, target), p)
        p.requires_grad_(was)
        with torch.no_grad():
            fd = central_fd(lambda: float(_render_loss(lens, sensor, model, scene, target)),
                            p, h, idx)
        got = float(grad[idx] if idx is not None else grad)
        assert got == pytest.approx(fd, rel=2e-3, abs=1e-9 * abs(fd) + 1e-12), (idx, got, fd)
        assert abs(fd) > 0


def test_float32_is_close_to_float64(edof_plate):
    lens = load_lens("data/lenses/edof_achromat.json").to(torch.float64)
    lens.load_state_dict(edof_plate.state_dict())
    sensor = Sensor((32, 32), 0.0069)
    job = [((0.0, 0.0), 6000.0, WL)]
    smp = choose_sampling(lens, sensor, job)
    k64 = diffraction_psf_many(lens, sensor, job, smp)[0]
    k32 = diffraction_psf_many(lens.to(torch.float32), sensor, job, smp)[0]
    assert k32.dtype == torch.float32
    assert tv_distance(k32.double(), k64) < 0.03  # measured 0.014: float32 path rounding


# ---------------------------------------------------------------- auto, sampling, memory
def test_auto_chooses_by_the_budget(edof_plate):
    """At the EDOF default's 6.9 um pixels the geometric PSF misplaces > 5 % of the energy:
    auto takes diffraction; at 80 um pixels it stays geometric."""
    lens = edof_plate
    for pitch, want in [(0.0069, "diffraction"), (0.08, "geometric")]:
        sensor = Sensor((16, 16), pitch, channels=[[WL]])
        m = PSFModel("auto", error_budget=0.05, n_rays=16384)
        msg = m.measure(lens, sensor, run_jobs(lens, sensor, [6000.0], (1, 1), depths=1))
        assert m.choice == want, msg
        assert "budget 5.0 %" in msg and want in msg


def test_auto_measures_again_when_the_lens_moved():
    lens = ideal_lens(object_distance=5000.0)
    sensor = Sensor((16, 16), 0.08, channels=[[WL]])
    m = PSFModel("auto", n_rays=1024, remeasure=0.1)
    m.measure(lens, sensor, run_jobs(lens, sensor, [5000.0], depths=1))
    assert m.resolve(lens, sensor) == "geometric"
    with torch.no_grad():
        lens.distances[-1].add_(0.0)  # no move: no new measurement
    assert not m.moved(lens)
    with torch.no_grad():
        for p in lens.parameters():
            p.mul_(1.5)
    assert m.moved(lens)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_lens_moved_after_a_cpu_measurement():
    """Training measures the PSF model at set-up, on the CPU, and then moves the module to the
    GPU: ``moved`` compares the lens on its device with the CPU snapshot (it raised a device
    mismatch on the first GPU run, at every EDOF training step)."""
    lens = ideal_lens(object_distance=5000.0)
    sensor = Sensor((16, 16), 0.08, channels=[[WL]])
    m = PSFModel("auto", n_rays=1024, remeasure=0.1)
    m.measure(lens, sensor, run_jobs(lens, sensor, [5000.0], depths=1))
    lens = lens.to("cuda")
    assert not m.moved(lens)
    with torch.no_grad():
        for p in lens.parameters():
            p.mul_(1.5)
    assert m.moved(lens)


def test_memory_check_names_the_setting():
    with pytest.raises(PSFMemoryError, match="render.psf_memory_gb"):
        check_memory(40, 1024, 129, 8, 0.5, torch.float32)


def test_bad_model_name_is_refused():
    with pytest.raises(ValueError, match="render.psf_model"):
        PSFModel("wave")


def test_a_plate_term_starting_at_zero_is_measured_against_its_group(edof_plate):
    """A plate coefficient that starts at 0 moves relative to the plate's coefficients, not to
    itself (else every optics step would re-measure)."""
    lens = edof_plate
    sensor = Sensor((16, 16), 0.08, channels=[[WL]])
    m = PSFModel("auto", n_rays=1024)
    m.measure(lens, sensor, [((0.0, 0.0), 6000.0, WL)])
    a = lens.surfaces[4].a
    scale = float(a[6].detach().abs())
    with torch.no_grad():
        a[0].add_(0.02 * scale)
    assert not m.moved(lens)
    with torch.no_grad():
        a[0].add_(0.3 * scale)
    assert m.moved(lens)
    with torch.no_grad():
        a[0].sub_(0.32 * scale)


def test_float32_rendered_image_gradients_agree_with_float64(edof_plate):
    """The gradients of a loss on the diffraction-rendered image (plate coefficient, curvature,
    sensor distance) in float32 (the training dtype) against float64: measured 0.1-4 %.  (A
    loss on the kernel's far tail alone, e.g. random weights over all its pixels, disagrees by
    25-130 %: the float32 trace's rounding halo, docs/guide/diffraction.md.)"""
    depth = 4500.0
    sensor = Sensor((32, 32), 0.0069, channels=[[WL]])
    g = torch.Generator().manual_seed(0)
    img = torch.rand(1, 1, 64, 64, generator=g, dtype=torch.float64)
    target = torch.rand(1, 1, 32, 32, generator=g, dtype=torch.float64)
    smp = choose_sampling(edof_plate, sensor, [((0.0, 0.0), depth, WL)])
    grads = {}
    for dt in (torch.float64, torch.float32):
        lens = load_lens("data/lenses/edof_achromat.json").to(torch.float64)
        lens.load_state_dict(edof_plate.state_dict())
        lens = lens.to(dt)
        model = PSFModel("diffraction")
        model.sampling = smp
        ps = [lens.surfaces[4].a[6], lens.surfaces[0].c, lens.d_sensor]
        for p in ps:
            p.requires_grad_(True)
        r = PSFConvRenderer(lens, sensor, patches=(1, 1), psf_model=model)
        loss = ((r(Scene(img.to(dt), [depth])).double() - target) ** 2).mean()
        grads[dt] = [float(v) for v in torch.autograd.grad(loss, ps)]
    for a, b in zip(grads[torch.float64], grads[torch.float32]):
        assert b == pytest.approx(a, rel=0.08), (grads,)


def test_batched_cached_kernels_equal_single_uncached_ones():
    """Jobs of different vignetting masks in one call with the OPD fit's cache (and the same
    cache reused by a second call) give the kernels of one-job calls without a cache."""
    lens = load_lens("data/lenses/double_gauss.json").to(torch.float64)
    sensor = Sensor((32, 32), 0.004, channels=[[WL]])
    jobs = [((0.0, 0.0), math.inf, WL), ((0.0, math.tan(math.radians(18.0))), math.inf, WL),
            ((0.05, 0.0), math.inf, 486.1327)]
    smp = DiffractionSampling(128, 21, 2)
    cache = {}
    together = diffraction_psf_many(lens, sensor, jobs, smp, cache=cache)
    assert len([k for k in cache if k[0] == "fit"]) >= 2  # two masks (vignetted at 18 deg)
    again = diffraction_psf_many(lens, sensor, jobs[::-1], smp, cache=cache)[::-1]
    for j, job in enumerate(jobs):
        alone = diffraction_psf_many(lens, sensor, [job], smp)[0]
        assert torch.allclose(together[j], alone, rtol=0, atol=1e-10 * float(alone.max()))
        assert torch.allclose(again[j], alone, rtol=0, atol=1e-10 * float(alone.max()))
