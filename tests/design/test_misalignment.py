"""Misalignment estimation (Eq. 15): the spot-image forward model's gradients against central
finite differences (float64), its geometry against paraxial optics, the estimation recovering
hidden values on a short noise-free case, and clear errors for bad input."""

import argparse
import json

import numpy as np
import pytest
import torch

import helpers
from deeplens.optics.paraxial import paraxial
from deeplens.design.apps import misalignment as app
from deeplens.design.misalignment import (DEFAULT_SCALE, LA1131_PATH, PARAMS, SpotImager,
                                          SpotSetup, centroid, eq15_residual,
                                          estimate, load_target_image, parse_params,
                                          synthesize_target)
from deeplens.design.optimizers import jacobian
from deeplens.optics.io import load_lens

# a small, coarse set-up: 24 x 24 working pixels of 40 µm (0.96 mm), 3000 rays
SMALL = dict(pixel_size_mm=0.01, resolution=(96, 96), binning=4, n_rays=3000)
THETA = [0.03, -0.02, 46.5, 0.8, -0.5]


def small_setup(**kw):
    return SpotSetup(**{**SMALL, **kw})


def test_image_gradient_matches_central_differences():
    """d/dθ of a weighted sum of the image (every pixel gets a different random weight) for each
    of the five parameters, autograd vs a fourth-order central difference.  The sampled image is
    piecewise smooth: a ray that the tilted rear face clips in or out changes it by a jump that
    the (per-sample) gradient rightly ignores.  Steps of 1e-6 (rad or mm) move the rear face's
    rim by ~5e-6 mm, so that no ray of the 3000 crosses it (at 1e-5 rad one does, and the
    difference quotient of tilt_x is off by 8%); the float64 rounding of the quotient is then
    ~1e-16 / 1e-6, far below the tolerance."""
    imager = SpotImager(small_setup())
    g = torch.Generator().manual_seed(3)
    W = torch.rand(imager.setup.shape, generator=g, dtype=torch.float64)
    theta = torch.tensor(THETA, dtype=torch.float64, requires_grad=True)
    (imager(theta) * W).sum().backward()
    steps = [1e-6] * 5
    p = theta.detach().clone()
    for k, h in enumerate(steps):
        fd = helpers.central_fd(lambda: (imager(p) * W).sum(), p, h, index=k)
        assert helpers.rel_err(theta.grad[k], fd) < 1e-6, (PARAMS[k], float(theta.grad[k]), fd)
        assert abs(fd) > 1e-3  # every parameter changes the image


def test_eq15_residual_jacobian_matches_central_differences():
    """The Jacobian the damped least squares uses (forward-mode AD through the tracer, the
    functional call and the splatting) against central differences of the whole residual
    vector, including the gain and the centroid rows.  Start at zero tilt: the aligned lens is
    where a misalignment transform is most easily skipped (and its tangent lost)."""
    st = small_setup()
    imager = SpotImager(st)
    target = synthesize_target(st, dict(zip(PARAMS, [0.0, 0.0, 46.4, 0.5, 0.0])), noise=False)
    sc = torch.tensor([DEFAULT_SCALE[k] for k in PARAMS], dtype=torch.float64)
    th0 = torch.tensor([0.0, 0.0] + THETA[2:], dtype=torch.float64)

    def fn(x):
        return eq15_residual(imager(th0 + sc * x), target, mu=0.5)

    x0 = torch.zeros(5, dtype=torch.float64)
    r, J = jacobian(fn, x0, mode="forward")
    h = 1e-5  # scaled units: 1e-7 rad, 1e-6 mm (at 1e-4 a clipped ray spoils tilt_x by 1%)
    for k in range(5):
        e = torch.zeros(5, dtype=torch.float64)
        e[k] = h
        with torch.no_grad():
            fd = (fn(x0 + e) - fn(x0 - e)) / (2 * h)
        assert helpers.rel_err(J[:, k], fd) < 1e-6, PARAMS[k]
        assert helpers.rel_err(J[-2:, k], fd[-2:]) < 1e-6, PARAMS[k]  # the centroid rows


def test_source_shift_moves_the_spot_by_the_paraxial_magnification():
    """With the sensor at the paraxial image of the source, a lateral source shift ``s`` moves
    the spot by ``-m s`` (inverted); on the sensor grid (column along -x, row along +y) that is
    ``+m s / p`` columns for ``s`` along x and ``-m s / p`` rows for ``s`` along y.  ``m`` and
    the image distance come from the paraxial focal length and back focal length, not from the
    tracer."""
    st = small_setup(n_rays=4000, pixel_size_mm=0.04)  # 3.8 mm: the whole blur circle
    imager = SpotImager(st)
    p = paraxial(load_lens(LA1131_PATH))
    f, bfl = float(p.efl), float(p.bfl)
    S = st.source_distance_mm
    # a plano-convex lens, curved side first: the plane face has no power, so the front
    # principal plane is at the first vertex; |m| = f / (S - f), image at bfl + f^2 / (S - f)
    mag = f / (S - f)
    d_img = bfl + f * f / (S - f)
    base = [0.0, 0.0, d_img, 0.0, 0.0]
    c0 = centroid(imager(torch.tensor(base, dtype=torch.float64)))
    c1 = centroid(imager(torch.tensor(base[:3] + [2.0, 0.0], dtype=torch.float64)))
    c2 = centroid(imager(torch.tensor(base[:4] + [2.0], dtype=torch.float64)))
    expect = 2.0 * mag / (st.pixel_size_mm * st.binning)
    assert float(c1[1] - c0[1]) == pytest.approx(expect, rel=0.02)   # x -> columns, +
    assert float(c1[0] - c0[0]) == pytest.approx(0.0, abs=0.02 * expect)
    assert float(c2[0] - c0[0]) == pytest.approx(-expect, rel=0.02)  # y -> rows, inverted
    assert float(c2[1] - c0[1]) == pytest.approx(0.0, abs=0.02 * expect)


def test_tilt_axes_by_symmetry():
    """A tilt about x (rotation in the y-z plane) keeps the set-up symmetric under x -> -x, so
    the spot moves along the rows only; a tilt about y moves it along the columns only."""
    st = small_setup(n_rays=4000, pixel_size_mm=0.02)
    imager = SpotImager(st)
    c0 = centroid(imager(torch.tensor([0.0, 0.0, 46.3, 0.0, 0.0], dtype=torch.float64)))
    cx = centroid(imager(torch.tensor([0.05, 0.0, 46.3, 0.0, 0.0], dtype=torch.float64))) - c0
    cy = centroid(imager(torch.tensor([0.0, 0.05, 46.3, 0.0, 0.0], dtype=torch.float64))) - c0
    assert abs(float(cx[0])) > 0.1 and abs(float(cx[1])) < 0.05 * abs(float(cx[0]))
    assert abs(float(cy[1])) > 0.1 and abs(float(cy[0])) < 0.05 * abs(float(cy[1]))


def test_estimation_recovers_the_truth_noise_free():
    """A short noise-free run: start 0.015 rad, 0.15 mm and 0.3 mm away from the truth."""
    st = small_setup(n_rays=3000)
    truth = dict(zip(PARAMS, [0.02, -0.015, 46.45, 0.4, -0.3]))
    start = dict(zip(PARAMS, [0.0, 0.0, 46.3, 0.1, 0.0]))
    # the fit's own ray samples (seed 0, ray_factor 1): the minimum is exactly the truth
    target = synthesize_target(st, truth, noise=False, ray_factor=1, seed=0)
    est, img, secs = estimate(target, st, start, mu=1.0, rounds=2, adam_steps=15,
                              dls_steps_per_round=4)
    tol = {"tilt_x": 1e-4, "tilt_y": 1e-4, "d_sensor": 1e-3, "source_x": 2e-3, "source_y": 2e-3}
    for k in PARAMS:
        assert abs(est[k] - truth[k]) < tol[k], (k, est[k], truth[k])
        assert abs(start[k] - truth[k]) > 10 * tol[k] or k == "source_x"


def test_parse_params_errors():
    d = dict(zip(PARAMS, [0.0] * 4 + [1.0]))
    d["d_sensor"] = 46.0
    assert parse_params("tilt_x=0.01, source_y=2", "--truth", d)["source_y"] == 2.0
    with pytest.raises(ValueError, match=r"--truth: unknown parameter 'tilt_z'.*tilt_x"):
        parse_params("tilt_z=0.1", "--truth", d)
    with pytest.raises(ValueError, match=r"--start: tilt_x must be a number"):
        parse_params("tilt_x=abc", "--start", d)
    with pytest.raises(ValueError, match=r"--truth: expected NAME=VALUE"):
        parse_params("0.1", "--truth", d)
    with pytest.raises(ValueError, match=r"--truth: tilts are in radians"):
        parse_params("tilt_y=3", "--truth", d)
    with pytest.raises(ValueError, match=r"--truth: d_sensor must be > 0"):
        parse_params("d_sensor=-1", "--truth", d)


def test_target_image_errors(tmp_path):
    st = small_setup()
    rgb = tmp_path / "rgb.npy"
    np.save(rgb, np.zeros((96, 96, 3)))
    with pytest.raises(ValueError, match=r"--target: .*colour image"):
        load_target_image(str(rgb), st)
    wrong = tmp_path / "wrong.npy"
    np.save(wrong, np.ones((90, 96)))
    with pytest.raises(ValueError, match=r"--target: .*90x96 pixels but --resolution is 96x96"):
        load_target_image(str(wrong), st)
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    with pytest.raises(ValueError, match=r"--target: cannot read"):
        load_target_image(str(bad), st)
    strs = tmp_path / "strs.npy"
    np.save(strs, np.array([["a"] * 96] * 96))
    with pytest.raises(ValueError, match=r"--target: .*pixel type"):
        load_target_image(str(strs), st)
    blank = tmp_path / "blank.npy"
    np.save(blank, np.zeros((96, 96)))
    with pytest.raises(ValueError, match=r"--target: .*blank"):
        load_target_image(str(blank), st)
    good = tmp_path / "good.npy"
    arr = np.zeros((96, 96), dtype=np.uint16)
    arr[40:44, 50:52] = 1000
    np.save(good, arr)
    img = load_target_image(str(good), st)
    assert img.shape == (24, 24) and float(img.max()) == 1.0
    assert float(centroid(img)[0]) == pytest.approx(10.5) and float(centroid(img)[1]) == \
        pytest.approx(12.5)  # rows 40-43 -> bin 10, columns 50-51 -> bin 12


def _args(tmp_path, *argv):
    p = argparse.ArgumentParser()
    p.add_argument("--out")  # added by the ``deeplens design`` command itself
    app.add_arguments(p)
    return p.parse_args([*argv, "--out", str(tmp_path / "out")])


def test_app_bad_options(tmp_path):
    with pytest.raises(ValueError, match=r"--binning 5 must divide the resolution"):
        app.run(_args(tmp_path, "--binning", "5"))
    with pytest.raises(ValueError, match=r"--resolution: expected HxW"):
        app.run(_args(tmp_path, "--resolution", "12xx"))
    with pytest.raises(ValueError, match=r"--truth is for a simulated target"):
        app.run(_args(tmp_path, "--truth", "tilt_x=0", "--target", "x.png"))
    with pytest.raises(ValueError, match=r"--pixel-size-um must be a positive"):
        app.run(_args(tmp_path, "--pixel-size-um", "0"))
    assert not (tmp_path / "out").exists()  # nothing written half-way


def test_app_short_run_writes_json_and_figures(tmp_path):
    a = _args(tmp_path, "--pixel-size-um", "10", "--resolution", "96x96", "--rays", "1500",
              "--rounds", "1", "--adam-steps", "3", "--dls-steps", "1",
              "--truth", "tilt_x=0.01,d_sensor=46.4")
    r = app.run(a)
    json.dumps(r)
    assert set(r["truth"]) == set(PARAMS) == set(r["estimate"]) == set(r["abs_error"])
    assert r["truth"]["tilt_x"] == 0.01 and r["truth"]["source_x"] == 1.5  # default
    assert r["loss_final"] < r["loss_start"]
    for f in r["figures"]:
        assert (tmp_path / "out").joinpath(f.split("/")[-1]).stat().st_size > 1000


@pytest.mark.slow
def test_app_default_run_recovers_truth(tmp_path):
    """The default run (about 2 minutes): the fit reaches the noisy target's noise floor (its
    loss at most that of the hidden values) and every parameter lands near the truth; the
    tilt/source pairs are nearly degenerate (README), hence the looser source tolerance."""
    r = app.run(_args(tmp_path))
    assert r["loss_final"] <= 1.01 * r["loss_at_truth"], r
    tol = {"tilt_x": 6e-3, "tilt_y": 6e-3, "d_sensor": 0.03, "source_x": 0.3, "source_y": 0.3}
    for k in PARAMS:
        assert r["abs_error"][k] < tol[k], (k, r)
        assert abs(r["start"][k] - r["truth"][k]) > tol[k]  # the start is not already there


def test_cli_reports_a_bad_target_by_option(tmp_path, capsys):
    """Through ``deeplens design misalignment``: exit status 2 and a message naming --target."""
    from deeplens.cli import main

    bad = tmp_path / "rgb.npy"
    np.save(bad, np.zeros((8, 8, 3)))
    code = main(["design", "misalignment", "--target", str(bad), "--resolution", "8x8",
                 "--binning", "1", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2
    assert "misalignment: error: --target:" in err and "colour image" in err
    assert not (tmp_path / "out").exists()


def test_app_with_a_captured_target(tmp_path):
    """``--target``: a raw 16-bit capture (here rendered, then spread over the raw pixels of each
    bin, with a dark level of 100 counts) runs end to end; ``truth``/``abs_error`` are null."""
    st = small_setup(pixel_size_mm=0.01, n_rays=1500)
    truth = dict(zip(PARAMS, [0.01, 0.0, 46.4, 0.3, 0.0]))
    img = synthesize_target(st, truth, noise=False).numpy()
    raw = np.kron(img, np.ones((st.binning, st.binning))) * 3000 + 100
    path = tmp_path / "capture.npy"
    np.save(path, raw.astype(np.uint16))
    r = app.run(_args(tmp_path, "--target", str(path), "--pixel-size-um", "10", "--resolution",
                      "96x96", "--rays", "1500", "--rounds", "1", "--adam-steps", "5",
                      "--dls-steps", "2"))
    assert r["truth"] is None and r["abs_error"] is None
    assert r["loss_final"] < 0.5 * r["loss_start"]
    assert abs(r["estimate"]["source_x"] - 0.3) < abs(r["start"]["source_x"] - 0.3)


def test_app_reports_uncertainties_and_warns_about_unidentifiable_parameters(tmp_path):
    """Issue 25, item 14: the JSON carries per-parameter standard deviations and correlations,
    and a parameter the spot image does not identify is named in a warning."""
    a = _args(tmp_path, "--pixel-size-um", "10", "--resolution", "96x96", "--rays", "1500",
              "--rounds", "1", "--adam-steps", "3", "--dls-steps", "1",
              "--truth", "tilt_x=0.013,tilt_y=-0.009")
    with pytest.warns(RuntimeWarning, match="is not identifiable from this spot image"):
        r = app.run(a)
    json.dumps(r)
    assert set(r["uncertainty"]) == set(PARAMS) == set(r["correlation"])
    assert all(v > 0 for v in r["uncertainty"].values())
    assert r["not_identifiable"] and set(r["not_identifiable"]) <= set(PARAMS)
    assert r["correlation"]["tilt_x"]["tilt_x"] == pytest.approx(1.0)
