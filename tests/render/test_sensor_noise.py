"""Sensor noise statistics against the documented model (:mod:`deeplens.render.sensor`).

Units: the image is in signal units where 1 is a full well; ``full_well`` is the number of
electrons at signal 1 and ``read_noise`` the read-noise standard deviation in signal units
(fraction of full well).  A pixel of signal ``I`` collects ``I * full_well`` electrons whose
Poisson count has variance ``I * full_well``, i.e. ``I / full_well`` in signal units; the
Gaussian approximation used adds

    Var[I_noisy] = I / full_well + read_noise^2,    E[I_noisy] = I.

The checks use ``N = 2^18`` samples per level: the sample variance has relative standard error
``sqrt(2 / N) = 0.28 %`` and the mean a standard error of ``sigma / sqrt(N)``; the tolerances
are 5 standard errors, while a noise term of the wrong strength (a factor 2 in a standard
deviation, ``I / full_well`` used as a standard deviation, ``full_well`` in place of
``1 / full_well``) moves the variance by far more.
"""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.render import Sensor

N = 2 ** 18
SHAPE = (4, 1, 256, 256)


def stats(sensor: Sensor, level: float, seed: int = 0):
    img = torch.full(SHAPE, level, dtype=torch.float64)
    out = sensor.add_noise(img, generator=torch.Generator().manual_seed(seed))
    return float(out.mean()), float(out.var(unbiased=True))


@pytest.mark.parametrize("full_well,read_noise", [(100.0, 0.0), (0.0, 0.02), (400.0, 0.01),
                                                  (1000.0, 0.05)])
@pytest.mark.parametrize("level", [0.05, 0.3, 0.9])
def test_variance_and_mean_follow_the_noise_model(full_well, read_noise, level):
    sensor = Sensor((8, 8), 0.01, full_well=full_well, read_noise=read_noise)
    var_expected = (level / full_well if full_well > 0 else 0.0) + read_noise ** 2
    mean, var = stats(sensor, level)
    assert var == pytest.approx(var_expected, rel=5 * math.sqrt(2 / N))
    assert abs(mean - level) < 5 * math.sqrt(var_expected / N)  # unbiased


def test_shot_noise_grows_with_the_signal_and_read_noise_does_not():
    shot = Sensor((8, 8), 0.01, full_well=200.0)
    read = Sensor((8, 8), 0.01, read_noise=0.03)
    v_shot = [stats(shot, s)[1] for s in (0.1, 0.4)]
    v_read = [stats(read, s)[1] for s in (0.1, 0.4)]
    assert v_shot[1] / v_shot[0] == pytest.approx(4.0, rel=0.02)  # variance linear in signal
    assert v_read[1] / v_read[0] == pytest.approx(1.0, rel=0.02)


def test_per_pixel_variance_follows_the_signal():
    """A ramp image: each column's variance over many rows is ``I / full_well + read^2``."""
    sensor = Sensor((8, 8), 0.01, full_well=500.0, read_noise=0.01)
    levels = torch.linspace(0.0, 1.0, 11, dtype=torch.float64)
    img = levels.expand(1, 1, 20000, 11).clone()
    out = sensor.add_noise(img, generator=torch.Generator().manual_seed(3))[0, 0]
    var = out.var(0)
    expected = levels / 500.0 + 0.01 ** 2
    n = out.shape[0]
    assert torch.allclose(var, expected, rtol=5 * math.sqrt(2 / n), atol=0)


def test_zero_or_negative_signal_gets_read_noise_only():
    sensor = Sensor((8, 8), 0.01, full_well=100.0, read_noise=0.02)
    for level in (0.0, -0.1):  # negative signal has no shot noise (clamped at 0)
        mean, var = stats(sensor, level)
        assert var == pytest.approx(0.02 ** 2, rel=5 * math.sqrt(2 / N))
        assert abs(mean - level) < 5 * 0.02 / math.sqrt(N)


def test_noise_is_seeded_and_off_by_default():
    sensor = Sensor((8, 8), 0.01, full_well=100.0, read_noise=0.02)
    img = torch.full((2, 3, 16, 16), 0.5, dtype=torch.float64)

    def noisy(seed):
        return sensor.add_noise(img, generator=torch.Generator().manual_seed(seed))

    assert torch.equal(noisy(7), noisy(7))
    assert not torch.equal(noisy(7), noisy(8))
    assert torch.equal(Sensor((8, 8), 0.01).add_noise(img), img)  # no noise configured


def test_noise_is_not_differentiated_but_the_signal_is():
    sensor = Sensor((8, 8), 0.01, full_well=100.0, read_noise=0.02)
    img = torch.full((1, 1, 8, 8), 0.5, dtype=torch.float64, requires_grad=True)
    out = sensor.add_noise(img, generator=torch.Generator().manual_seed(0))
    (g,) = torch.autograd.grad(out.sum(), img)
    assert torch.equal(g, torch.ones_like(g))  # d(I + noise)/dI = 1: the noise is a constant


def test_negative_noise_parameters_are_rejected():
    with pytest.raises(ValueError, match="full_well and read_noise must be >= 0"):
        Sensor((8, 8), 0.01, read_noise=-0.1)
