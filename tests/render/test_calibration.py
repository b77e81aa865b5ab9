"""Per-unit distortion calibration (deeplens.render.calibration): the warp against closed forms
(a sign flip fails), the measured map of a rigidly translated lens against the closed form and
against an independent per-point trace, and a translated lens's image registered back to the
nominal lens's (its PSNR recovered)."""

import math

import pytest
import torch
from helpers import LENS_DIR

from deeplens.optics.tolerance_model import LensDraw, drawn
from deeplens.optics.io import load_lens
from deeplens.optics.sampling import point_source_rays
from deeplens.render import IdealCamera, MonteCarloRenderer, Scene, Sensor
from deeplens.render.calibration import displacement_px, image_points, node_pixels, warp

DEPTH = 10_000.0


@pytest.fixture(scope="module")
def doublet():
    return load_lens(LENS_DIR / "wide_doublet.json").to(torch.float64)


def _ramp(H=14, W=13, B=2, C=3):
    i = torch.arange(H, dtype=torch.float64)[:, None]
    j = torch.arange(W, dtype=torch.float64)[None, :]
    a = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)[:C, None, None]
    b = torch.tensor([3.0, 0.7, -1.5], dtype=torch.float64)[:C, None, None]
    img = a * i + b * j + torch.arange(B, dtype=torch.float64)[:, None, None, None]
    return img, a, b


@pytest.mark.parametrize("mode", ["cubic", "bilinear"])
def test_warp_samples_at_the_displaced_position_exactly_on_a_ramp(mode):
    """Keys' cubic and bilinear interpolation are exact on a linear image: out(i, j) = img(i + di,
    j + dj) in the interior, per channel with its own displacement; the opposite sign is far
    off."""
    img, a, b = _ramp()
    H, W = img.shape[-2:]
    d = torch.zeros(3, H, W, 2, dtype=torch.float64)
    d[0, ..., 0], d[0, ..., 1] = 0.3, -0.7
    d[1, ..., 0], d[1, ..., 1] = -1.25, 0.4
    d[2] = 0.0
    out = warp(img, d, mode)
    want = img + (a * d[..., 0] + b * d[..., 1])[None]
    inner = (slice(None), slice(None), slice(4, H - 4), slice(4, W - 4))
    assert torch.allclose(out[inner], want[inner], atol=1e-12)
    assert torch.allclose(out[:, 2], img[:, 2], atol=1e-12)  # a zero map for a channel
    flipped = warp(img, -d, mode)
    assert float((flipped[inner] - want[inner]).abs().max()) > 1.0
    # a field that varies over the image: each pixel its own displacement
    i = torch.arange(H, dtype=torch.float64)[:, None].expand(H, W)
    dv = torch.stack([0.1 * i / H, -0.2 + 0.3 * i / H], -1).expand(3, H, W, 2)
    want = img + (a * dv[..., 0] + b * dv[..., 1])[None]
    assert torch.allclose(warp(img, dv, mode)[inner], want[inner], atol=1e-12)


def test_warp_integer_shift_is_a_roll_and_zero_is_the_image_itself():
    img = torch.rand(2, 3, 9, 11, generator=torch.Generator().manual_seed(0))
    d = torch.zeros(1, 9, 11, 2)
    assert warp(img, d) is img
    d[..., 0], d[..., 1] = 2.0, -1.0  # out(i, j) = img(i + 2, j - 1)
    out = warp(img, d)
    assert torch.allclose(out[..., :-2, 1:], img[..., 2:, :-1], atol=1e-6)
    assert torch.allclose(out[..., -1, 1:], img[..., -1, :-1], atol=1e-6)  # beyond: the edge
    with pytest.raises(ValueError, match="displacement must be"):
        warp(img, torch.zeros(2, 9, 11, 2))


def _rigid(lens, dx, dy):
    """The lens translated rigidly across the axis by (dx, dy) mm (every element, stop too)."""
    off = {}
    for e in range(len(lens.elements)):
        off[f"misalignments.{e}.dx"], off[f"misalignments.{e}.dy"] = dx, dy
    return LensDraw(seed=0, offsets=off)


def test_map_of_a_translated_lens_matches_closed_form_and_independent_trace(doublet):
    """A lens moved by δ across the axis images object point Q where the nominal lens images
    Q − δ, moved by δ: f(Q − δ) + δ.  For a distant object that is δ (1 − m) with m the
    lateral magnification (closed form), and exactly the nominal lens traced per point at Q − δ
    (an independent ray construction: point_source_rays, one point at a time)."""
    sensor = Sensor((64, 64), 0.0804)
    ideal = IdealCamera(doublet, sensor)
    scale = ideal.object_scale(DEPTH)
    dx, dy = 0.030, -0.018
    nom = image_points(doublet, sensor, DEPTH, scale, 3, nodes=5)
    with drawn(doublet, _rigid(doublet, dx, dy)):
        moved = image_points(doublet, sensor, DEPTH, scale, 3, nodes=5)
    d_mm = moved - nom                                                   # (3, 5, 5, 2)
    m = 1.0 / scale  # sensor mm per object mm, signed (negative: an inverted image)
    closed = torch.tensor([dx, dy], dtype=torch.float64) * (1.0 - m)
    assert abs(m) < 2e-3
    # 0.5 µm of 35 µm: where the bundle's samples are cut by the moved stop (sampling)
    assert torch.allclose(d_mm, closed.expand_as(d_mm), atol=0.6e-3)
    assert torch.allclose(d_mm[:, 2, 2], closed.expand(3, 2), atol=2e-5)  # on axis
    # the independent trace, green channel (587.6 nm), every node
    ii, jj = node_pixels(sensor.resolution, 5)
    w = sensor.channels[1][0]
    for a in range(5):
        for b in range(5):
            x, y = sensor.pixel_to_xy(ii[a], jj[b])
            pts = []
            for q in ((scale * x, scale * y), (scale * x - dx, scale * y - dy)):
                rays = point_source_rays(doublet, (float(q[0]), float(q[1])), DEPTH, w, 0,
                                         sampling="grid:48", pupil_margin=1.3)
                out = doublet.trace_to_sensor(rays)
                pts.append(out.o[out.valid, :2].mean(0))
            want = pts[1] + torch.tensor([dx, dy], dtype=torch.float64) - pts[0]
            # the same rays relative to the lens, but the stop cuts the sample grid elsewhere
            assert torch.allclose(d_mm[1, a, b], want, atol=0.6e-3), \
                (a, b, d_mm[1, a, b], want)
    # in pixels: rows follow +y, columns follow -x (Sensor.pixel_to_xy)
    dp = displacement_px(moved, nom, sensor)
    assert dp.shape == (3, 64, 64, 2)
    assert float(dp[1, 32, 32, 0]) == pytest.approx(dy * (1 - m) / 0.0804, rel=0.02)
    assert float(dp[1, 32, 32, 1]) == pytest.approx(-dx * (1 - m) / 0.0804, rel=0.02)


def test_map_is_zero_for_the_nominal_lens_and_deterministic(doublet):
    sensor = Sensor((16, 16), 0.0804)
    s = IdealCamera(doublet, sensor).object_scale(DEPTH)
    a = image_points(doublet, sensor, DEPTH, s, 3, nodes=3)
    with drawn(doublet, LensDraw(seed=0)):
        b = image_points(doublet, sensor, DEPTH, s, 3, nodes=3)
    assert torch.equal(a, b)
    assert not displacement_px(b, a, sensor).any()
    with pytest.raises(ValueError, match="finite target depth"):
        image_points(doublet, sensor, math.inf, s, 3)
    with pytest.raises(ValueError, match="nodes"):
        image_points(doublet, sensor, DEPTH, s, 3, nodes=1)


def _psnr(a, b):
    return float(10 * torch.log10(1.0 / ((a - b) ** 2).mean()))


def test_registered_image_of_a_translated_lens_recovers_the_nominal_psnr(doublet):
    """Render a texture through the nominal lens and through the lens moved by ~1 px: the
    moved lens's image, registered with its measured map, scores (against the ideal image)
    what the nominal lens's does, within 0.2 dB; unregistered it loses > 3 dB and registered
    with the sign flipped it loses more still."""
    sensor = Sensor((24, 24), 0.0804)
    ideal = IdealCamera(doublet, sensor)
    g = torch.Generator().manual_seed(3)
    tex = torch.nn.functional.interpolate(torch.rand(1, 3, 12, 12, generator=g,
                                                     dtype=torch.float64), size=(48, 48),
                                          mode="bilinear", align_corners=False)
    scene = Scene(tex, [DEPTH], ideal.fov_size_mm(DEPTH)[None])
    gt = ideal.render(scene)
    r = MonteCarloRenderer(doublet, sensor, spp=16, vignetting=False, seed=5)
    s = ideal.object_scale(DEPTH)
    nom = image_points(doublet, sensor, DEPTH, s, 3, nodes=5)
    y_nom = r(scene, seed=1)
    with drawn(doublet, _rigid(doublet, -0.0803, 0.0)):  # ~ +1 column
        moved = image_points(doublet, sensor, DEPTH, s, 3, nodes=5)
        y = r(scene, seed=1)
    d = displacement_px(moved, nom, sensor)
    assert float(d[..., 1].mean()) == pytest.approx(1.0, abs=0.01)
    inner = (slice(None), slice(None), slice(2, -2), slice(2, -2))
    p_nom = _psnr(y_nom[inner], gt[inner])
    p_raw = _psnr(y[inner], gt[inner])
    p_cal = _psnr(warp(y, d)[inner], gt[inner])
    p_flip = _psnr(warp(y, -d)[inner], gt[inner])
    assert abs(p_cal - p_nom) < 0.2, (p_nom, p_cal)
    assert p_raw < p_nom - 3.0, (p_nom, p_raw)
    assert p_flip < p_raw - 1.0, (p_raw, p_flip)
