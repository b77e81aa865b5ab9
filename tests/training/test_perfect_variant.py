"""The evaluation's ``perfect`` variant (deeplens/evaluation/perfect.py): an aberration-free lens
with the experiment's first order, the ceiling of what a better lens can give."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from omegaconf import open_dict
from scipy.special import j0, j1

from deeplens.evaluation.evaluate import _variant_cfg, perfect_dir
from deeplens.evaluation.perfect import (PERFECT_LENS, perfect_first_order, perfect_lens_dict,
                                         write_perfect_lens)
from deeplens.evaluation.variants import variants
from deeplens.optics.errors import ConfigError
from deeplens.optics.paraxial import paraxial
from deeplens.optics.sampling import point_source_rays
from deeplens.render import IdealCamera, Sensor
from deeplens.render.splat import trace_to_sensor_pixels
from deeplens.training.lens_setup import build_lens

DOUBLET_SENSOR = dict(resolution=(64, 64), pixel_size_mm=0.0804)  # configs/sensor/doublet.yaml
WAVES = (486.1327, 587.5618, 656.2725)


def _lens(tmp_path, f=10.0, N=4.0, s=10000.0, sensor_at=None):
    sensor = Sensor(DOUBLET_SENSOR["resolution"], DOUBLET_SENSOR["pixel_size_mm"])
    d = perfect_lens_dict(f, N, s, sensor.half_diagonal_mm, WAVES)
    if sensor_at is not None:       # a planted defect: the sensor somewhere else
        d["sensor"]["distance_mm"] = sensor_at
    p = tmp_path / "perfect.json"
    p.write_text(json.dumps(d))
    return build_lens(str(p), dtype="float64"), sensor


def _spread_px(lens, sensor, depth=10000.0, n=256):
    """The largest distance (pixels) of any ray's hit from its point's ideal image, over the
    axis, 10 deg, 20 deg and the sensor's corner field, at every wavelength."""
    cam = IdealCamera(lens, sensor)
    corner = cam.field_angle_deg(sensor.half_diagonal_mm)
    worst = 0.0
    for deg in (0.0, 10.0, 20.0, corner):
        t = math.tan(math.radians(deg)) / math.sqrt(2)      # a diagonal field point
        Y = X = t * (depth + cam.z_ep - cam.z0)
        s = cam.object_scale(depth)
        ci, cj = sensor.xy_to_pixel(torch.tensor(X / s, dtype=torch.float64),
                                    torch.tensor(Y / s, dtype=torch.float64))
        for w in WAVES:
            rays = point_source_rays(lens, (X, Y), depth, w, n, 0)
            i, j, valid = trace_to_sensor_pixels(lens, sensor, rays)
            # (the pupil sampling overfills the stop a little: the stop clips those rays)
            assert int(valid.sum()) > n // 2, f"rays lost at {deg} deg, {w} nm"
            worst = max(worst, float(torch.hypot(i - ci, j - cj)[valid].max()))
    return worst


def test_perfect_lens_images_every_field_to_a_point_at_its_ideal_image(tmp_path):
    lens, sensor = _lens(tmp_path)
    p = paraxial(lens)
    assert float(p.efl) == pytest.approx(10.0, rel=1e-12)
    assert float(p.fno) == pytest.approx(4.0, rel=1e-12)
    # a delta PSF exactly at the ideal (distortion-free) image point: float64 traces of a 10 mm
    # system, error ~ 1e-13 mm = 1e-12 px; 1e-6 px leaves room for the Newton tolerance
    assert _spread_px(lens, sensor) < 1e-6
    # the check sees a defect: the sensor at the focal length (focused at infinity) blurs a
    # point at 10 m by D (v - f) / v = 2.5 um = 0.03 px
    bad, _ = _lens(tmp_path, sensor_at=10.0)
    assert _spread_px(bad, sensor) > 0.01


def _airy_outside(r_um, lam_um, N):
    """Closed-form fraction of the Airy pattern's energy beyond radius ``r`` (Rayleigh):
    ``J0(x)^2 + J1(x)^2``, ``x = pi r / (lam N)``."""
    x = np.pi * r_um / (lam_um * N)
    return j0(x) ** 2 + j1(x) ** 2


def _airy_leaves_pixel(p_um, lam_um, N, h_um):
    """``(mean share of light outside its own pixel, share beyond radius p)`` of the Airy PSF
    of a point uniform over a square pixel of side ``p``: the mean over positions of the
    share inside is the PSF weighted by the overlap ``(1 - |dx|/p)+ (1 - |dy|/p)+``, integrated
    on a grid of step ``h`` (the PSF's peak is ``lam N`` wide: ~10 samples across it)."""
    u = np.arange(-int(p_um / h_um), int(p_um / h_um) + 1) * h_um
    X, Y = np.meshgrid(u, u)
    r = np.hypot(X, Y)
    x = np.maximum(np.pi * r / (lam_um * N), 1e-12)
    psf = (2 * j1(x) / x) ** 2 * np.pi / (4 * (lam_um * N) ** 2)      # integrates to 1
    overlap = np.clip(1 - np.abs(X) / p_um, 0, None) * np.clip(1 - np.abs(Y) / p_um, 0, None)
    return 1 - float((psf * overlap).sum()) * h_um ** 2, 1 - float(psf[r <= p_um].sum()) * h_um ** 2


def test_diffraction_left_out_moves_little_light_at_the_doublet_pixel():
    # the formula itself: 83.8 % inside the first dark ring (x = 3.8317), all outside r = 0
    assert 1 - _airy_outside(3.8317 * 0.5876 * 4 / np.pi, 0.5876, 4) == pytest.approx(0.838,
                                                                                     abs=1e-3)
    assert _airy_outside(0.0, 0.5876, 4) == pytest.approx(1.0)
    # the diffraction-limited PSF at F/4, reddest line, on the doublet's 80.4 um pixels: the
    # grid integral agrees with the closed form beyond one pixel's radius (0.66 %; the grid's
    # error: the 0.25 um step on a peak 2.6 um wide, well under 5 % of it), and the light a
    # point uniform over its pixel sends to the neighbours is 4.8 %: the perfect variant's
    # delta PSF (diffraction left out, as for every variant of this experiment:
    # render.psf_model auto stays geometric there) is exact to that share
    leaves, beyond = _airy_leaves_pixel(80.4, 0.6563, 4.0, 0.25)
    assert beyond == pytest.approx(float(_airy_outside(80.4, 0.6563, 4.0)), rel=0.05)
    assert 0.03 < leaves < 0.05
    # and it sees pixel size: at 8 um pixels diffraction moves over a quarter of the light
    assert _airy_leaves_pixel(8.04, 0.6563, 4.0, 0.05)[0] > 0.25


def test_perfect_variant_config_and_lens_file(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=doublet_search", "eval.variants=[searched,perfect]",
                      config_name="eval.yaml")
    assert [v[1] for v in variants(cfg)] == ["searched", "perfect"]
    assert perfect_first_order(cfg) == (10.0, 4.0)      # the spec's efl_mm, fno
    path = write_perfect_lens(cfg, perfect_dir(cfg))
    assert path.name == PERFECT_LENS and path.read_text() == write_perfect_lens(
        cfg, perfect_dir(cfg)).read_text()
    vc = _variant_cfg(cfg, "perfect", seed=1)
    assert vc.lens.path == str(path) and list(vc.lens.trainable) == []
    assert vc.lens.start == "file" and vc.lens.search is None
    assert vc.render.psf_model == "geometric" and vc.seed == 1
    lens = build_lens(vc.lens.path, dtype="float64")
    assert float(lens.z_sensor() - lens.z_vertices()[-1]) == pytest.approx(
        10.0 * 10000.0 / 9990.0, rel=1e-12)
    # the file's doublet: its own paraxial first order
    fc = cfg_factory("experiment=doublet", config_name="eval.yaml")
    efl, fno = perfect_first_order(fc)
    assert 9.0 < efl < 11.0 and fno == pytest.approx(4.0, rel=0.05)


def test_perfect_variant_refuses_a_plate_and_a_depth_range(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=edof", config_name="eval.yaml")
    with pytest.raises(ConfigError, match="perfect"):
        write_perfect_lens(cfg, tmp_path / "p")
    cfg = cfg_factory("experiment=doublet", "scene.depths_mm=[2000.0,10000.0]",
                      config_name="eval.yaml")
    with pytest.raises(ConfigError, match="one depth"):
        write_perfect_lens(cfg, tmp_path / "p")
    with open_dict(cfg):
        cfg.scene.depths_mm = [5.0]
    with pytest.raises(ValueError, match="exceed the focal length"):
        write_perfect_lens(cfg, tmp_path / "p")
