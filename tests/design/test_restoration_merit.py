"""The restoration merit of an EDOF plate (deeplens/design/restoration_merit.py): its expected
error against the closed form of a perfect PSF and against a Monte Carlo simulation of the
filter it models; its gradient against central finite differences (float64, diffraction PSFs);
that it ranks a cubic plate above no plate, as the camera does; and the plate search's
restoration option."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.design.plate_search import PlateSearchConfig, plate_search
from deeplens.design.restoration_merit import RestorationMerit, object_spectrum
from deeplens.design.variables import Variables
from deeplens.render.sensor import Sensor
from deeplens.training.lens_setup import build_lens

LENS = "data/lenses/edof_achromat.json"
PLATE = [f"surfaces.4.a.{k}" for k in range(3, 10)]
GREEN = 587.5618


def _lens(alpha_mm=0.0, trainable=PLATE):
    return build_lens(LENS, trainable, "float64", plate="cubic", plate_surface=4,
                      plate_alpha_mm=alpha_mm, focus_mm=5760.0, focus_wavelengths_nm=(GREEN,))


def _sensor(n=32):
    return Sensor((n, n), 0.0069, channels=[[GREEN]], full_well=2000.0,
                  read_noise=0.005).to(torch.float64)


def _gauss_otfs(widths, n):
    """OTFs ``(D, 1, n, n)`` of normalised Gaussian PSFs of the given widths (pixels), centred
    at the origin (circularly)."""
    i = torch.arange(n, dtype=torch.float64)
    d = torch.minimum(i, n - i)
    r2 = d[:, None] ** 2 + d[None, :] ** 2
    out = []
    for w in widths:
        k = torch.exp(-r2 / (2 * w * w))
        k = k / k.sum()
        out.append(torch.fft.fft2(k)[None])
    return torch.stack(out)


def _merit_with_otfs(H, noise_var, power=4.0):
    n = H.shape[-1]
    m = RestorationMerit([4500.0] * H.shape[0], _sensor(n), size=n, max_kernel=n - 1,
                         noise_var=noise_var, power=power)
    m.otfs = lambda lens: H   # the optics replaced by given OTFs
    return m


def test_a_perfect_psf_gives_the_wiener_closed_form():
    n, s2 = 16, 2e-4
    H = torch.ones(2, 1, n, n, dtype=torch.complex128)
    S = object_spectrum(n)
    want = (S * s2 / (S + s2)).mean()
    got = _merit_with_otfs(H, s2).mse(None)
    assert got.shape == (2,)
    assert torch.allclose(got, want.expand(2), rtol=1e-12, atol=0)
    # no noise, perfect PSF: nothing to lose but roundoff (|G H - 1| ~ eps), and no 0/0 at
    # f = 0 where S = 0
    eps = torch.finfo(torch.float64).eps
    assert float(_merit_with_otfs(H, 0.0).mse(None).max()) <= 100 * eps ** 2 * float(S.max())
    # the 1/f^2 law: S(0.25, 0) / S(0.5, 0) = (0.5^2 + f0^2) / (0.25^2 + f0^2), f0 = 1 / n
    f0 = 1 / n
    assert float(S[n // 4, 0] / S[n // 2, 0]) == pytest.approx((0.25 + f0 ** 2)
                                                              / (0.0625 + f0 ** 2), rel=1e-12)


def test_the_expected_error_matches_a_simulation_of_the_filter():
    """Gaussian random images of spectrum S, blurred by each depth's PSF, plus white noise,
    restored by the merit's filter G: the measured mean squared error per depth against
    MSE_d, within 4 standard errors of the simulation."""
    n, s2, trials = 16, 5e-4, 3000
    H = _gauss_otfs([0.6, 1.8], n)
    m = _merit_with_otfs(H, s2)
    want = m.mse(None)
    S = object_spectrum(n)
    g = torch.Generator().manual_seed(0)
    white = torch.randn(trials, n, n, generator=g, dtype=torch.float64)
    x = torch.fft.ifft2(torch.fft.fft2(white) * S.sqrt()).real   # spectrum S per pixel
    noise = math.sqrt(s2) * torch.randn(trials, n, n, generator=g, dtype=torch.float64)
    G = H[:, 0].conj().mean(0) * S / ((H[:, 0].abs() ** 2).mean(0) * S + s2)
    for d in range(2):
        y = torch.fft.ifft2(torch.fft.fft2(x) * H[d, 0]).real + noise
        xr = torch.fft.ifft2(torch.fft.fft2(y) * G).real
        e = ((xr - x) ** 2).mean(dim=(-2, -1))           # per trial
        se = float(e.std()) / math.sqrt(trials)
        assert abs(float(e.mean()) - float(want[d])) < 4 * se, (d, float(e.mean()),
                                                                 float(want[d]), se)
    # the wider PSF restores worse, and the soft maximum weights it
    assert float(want[1]) > float(want[0])
    r = m.residuals(None)
    assert torch.allclose(r, (want / 1e-3) ** 2, rtol=1e-12)


def test_the_gradient_matches_central_differences():
    """d(sum of squared residuals)/d(plate coefficient), autograd through the diffraction
    PSFs, against central differences at two steps (their difference bounds the truncation
    error, O(h^2))."""
    lens = _lens(0.002)
    with torch.no_grad():   # a little coma too, so that every term's derivative is nonzero
        lens.surfaces[4].a[7].fill_(1e-3 / float(lens.surfaces[4].semi_diameter) ** 3)
    m = RestorationMerit([4500.0, 8000.0], _sensor(32), size=32, max_kernel=21,
                         max_step_waves=0.5, energy=0.95).prepare(lens)
    v = Variables(lens, ["surfaces.4.a.3", "surfaces.4.a.7", "surfaces.4.a.9"])
    x0 = v.x0()

    def f(x):
        return v.call(lambda L: (m.residuals(L) ** 2).sum(), x)

    x = x0.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(f(x), x)
    with torch.no_grad():
        for i in range(len(x0)):
            fd = []
            for h in (2e-5, 1e-5):   # mm of sag at the rim
                e = torch.zeros_like(x0)
                e[i] = h
                fd.append(float((f(x0 + e) - f(x0 - e)) / (2 * h)))
            trunc = abs(fd[0] - fd[1]) * 4 / 3   # Richardson: the error of fd[1] is ~ 1/3 of it
            tol = 2 * trunc + 1e-7 * abs(fd[1]) + 1e-9 * float(f(x0)) / 1e-5
            assert abs(float(g[i]) - fd[1]) <= tol, (i, float(g[i]), fd)
            assert abs(fd[1]) > 10 * tol   # the derivative is resolved, not zero


def test_a_cubic_plate_restores_better_than_no_plate():
    """The camera's own ordering (docs/results/edof_auto_3seeds.md: worst depth 28.02 dB with
    the 2.5 um cubic plate, 26.44 dB without a plate): the defocused ends lose their high
    frequencies without a plate."""
    sensor = _sensor(64)
    out = {}
    for alpha in (0.0, 0.0025):
        lens = _lens(alpha, trainable=[])
        m = RestorationMerit([4500.0, 5760.0, 8000.0], sensor, size=64, max_kernel=31,
                             max_step_waves=0.5, energy=0.99).prepare(lens)
        out[alpha] = m.psnr(lens)
    assert float(out[0.0025].min()) > float(out[0.0].min()) + 0.5
    # without a plate the focused middle depth is the best, by far
    assert float(out[0.0][1]) > float(out[0.0][[0, 2]].max()) + 3


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="psf_model"):
        RestorationMerit([4500.0], psf_model="wave")
    with pytest.raises(ValueError, match="max_kernel"):
        RestorationMerit([4500.0], size=32, max_kernel=33)
    with pytest.raises(ValueError, match="depths"):
        RestorationMerit([-1.0])
    with pytest.raises(ValueError, match="power"):
        RestorationMerit([4500.0], power=0.5)
    with pytest.raises(RuntimeError, match="prepare"):
        RestorationMerit([4500.0], _sensor()).psfs(_lens())
    with pytest.raises(ValueError, match="merit must be one of"):
        PlateSearchConfig(merit="sharpness")
    with pytest.raises(ValueError, match="restoration_depths"):
        PlateSearchConfig(merit="restoration", restoration_depths=1)
    with pytest.raises(ValueError, match="needs the sensor"):
        plate_search(_lens(trainable=["surfaces.4.a.9"]), 4, ["surfaces.4.a.9"],
                     [4500.0, 8000.0], [GREEN], 0.0069, PlateSearchConfig(merit="restoration"))


@pytest.mark.slow
def test_the_restoration_search_improves_on_the_zero_plate():
    cfg = PlateSearchConfig(starts=1, steps=2, merit="restoration", restoration_depths=3)
    names = ["surfaces.4.a.6", "surfaces.4.a.9"]
    lens = _lens(trainable=names)
    r = plate_search(lens, 4, names, [4500.0, 8000.0], [GREEN], 0.0069, cfg,
                     sensor=_sensor(64))
    assert r.blur_px is None and r.runs[0].origin == "zero plate"
    assert r.best.psnr_db is not None and r.best.invariance is None
    assert r.best.score < r.runs[0].start_score
    assert r.best.score == min(d.score for d in r.runs)
