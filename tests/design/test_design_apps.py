"""The design applications, shortened (default suite) and in full (slow), the application
registry, and the optimize/tolerance/design command lines."""

import json

import helpers as H
import pytest
from helpers import LENS_DIR

from deeplens.design import apps
from deeplens.design.apps import load_app


pytestmark = pytest.mark.usefixtures("quiet_warnings")


def _args(name, tmp_path, **kw):
    import argparse

    p = argparse.ArgumentParser()
    load_app(name).add_arguments(p)
    args = p.parse_args([])
    args.out = str(tmp_path)
    args.json = True
    for k, v in kw.items():
        setattr(args, k, v)
    return args


run = H.run_cli


def test_registry_names_and_errors(monkeypatch):
    assert set(apps.APPS) == {"spherical-aberration", "nikon", "sensitivity", "caustic",
                              "misalignment", "search"}
    with pytest.raises(ValueError, match="unknown design application 'nikkon'.*nikon"):
        load_app("nikkon")
    monkeypatch.setitem(apps.APPS, "ghost", "no_such_module")
    with pytest.raises(ValueError, match="'ghost' is not available.*no_such_module"):
        load_app("ghost")


def test_spherical_aberration_short(tmp_path):
    r = load_app("spherical-aberration").run(_args("spherical-aberration", tmp_path, steps=3,
                                                   sampling="hexapolar:4"))
    assert r["rms_after_um"] < 0.6 * r["rms_before_um"]
    assert (tmp_path / "acl5040u_optimized.json").exists()
    assert (tmp_path / "spots.png").exists()


def test_spherical_aberration_beams(tmp_path):
    """The paper script's square beam keeps its corners (11 x 11 = 121 rays, 21.2 mm from the
    axis, inside the 25 mm aperture); a disk beam puts its rays where the traced pupil scaled
    to that radius does; a bad --beam names the option."""
    import torch

    from deeplens.design.apps.spherical_aberration import (BeamSpotMerit, beam_points,
                                                           parse_beam)
    from deeplens.design.merit import SpotMerit
    from deeplens.optics.io import load_lens

    r = load_app("spherical-aberration").run(_args(
        "spherical-aberration", tmp_path, steps=4, beam="square:15:11", wavelength=532.8))
    assert r["rays"] == 121
    assert r["rms_after_um"] < 0.2 * r["rms_before_um"]
    lens = load_lens(LENS_DIR / "thorlabs_acl5040u.json").to(torch.float64)
    full = SpotMerit([0.0], [587.5618], sampling="hexapolar:3", shrink=1.0).prepare(lens)
    R = full.regions[(0.0, 587.5618)].rx
    ref = SpotMerit([0.0], [587.5618], sampling="hexapolar:3", shrink=15.0 / R).prepare(lens)
    beam = BeamSpotMerit(beam_points(parse_beam("disk:15"), "hexapolar:3"), 587.5618,
                         "hexapolar:3").prepare(lens)
    with torch.no_grad():
        assert float(beam.rms(lens)) == pytest.approx(float(ref.rms(lens)), rel=1e-12)
        assert float(beam.rms(lens)) < 0.8 * float(full.rms(lens))  # not the full aperture
    for bad in ("disk", "disk:-1", "square:15", "square:15:1", "ring:3"):
        with pytest.raises(ValueError, match="--beam"):
            parse_beam(bad)


def test_sensitivity_short(tmp_path):
    r = load_app("sensitivity").run(_args("sensitivity", tmp_path, fields="0,11.86",
                                          sampling="hexapolar:2", kinds="decenter"))
    assert len(r["jacobian"]) == 2 and len(r["jacobian"][0]) == len(r["parameters"]) == 6
    assert r["fd_max_rel_err"] < 1e-4


def test_nikon_short(tmp_path):
    r = load_app("nikon").run(_args("nikon", tmp_path, fields="0", steps=1, rounds=1,
                                    sampling="hexapolar:2"))
    assert r["jacobian"] == "central"
    assert r["rms_optimized_um"] < 0.7 * r["rms_spherical_start_um"]
    assert r["rms_spherical_start_um"] > 10 * r["rms_original_um"]
    assert r["merit_history"][-1] < r["merit_history"][0]
    assert r["evaluations"] >= 2 * r["variables"] + 1  # the Jacobian by central differences


@pytest.mark.slow
def test_nikon_jacobian_modes_agree(tmp_path):
    """The forward-mode (AD) Jacobian takes the same step: central differences lose nothing."""
    kw = dict(fields="0", steps=1, rounds=1, sampling="hexapolar:2")
    r = load_app("nikon").run(_args("nikon", tmp_path, **kw))
    f = load_app("nikon").run(_args("nikon", tmp_path / "fwd", jacobian="forward", **kw))
    assert f["evaluations"] < r["evaluations"]
    assert f["rms_optimized_um"] == pytest.approx(r["rms_optimized_um"], rel=1e-5)


@pytest.mark.slow
def test_spherical_aberration_full(tmp_path):
    r = load_app("spherical-aberration").run(_args("spherical-aberration", tmp_path))
    assert r["rms_after_um"] < r["rms_before_um"] / 3


@pytest.mark.slow
def test_nikon_full(tmp_path):
    r = load_app("nikon").run(_args("nikon", tmp_path))
    assert r["rms_optimized_um"] < 0.1 * r["rms_spherical_start_um"]
    assert r["rms_optimized_um"] <= r["rms_original_um"]  # the paper's goal


@pytest.mark.slow
def test_sensitivity_full(tmp_path):
    r = load_app("sensitivity").run(_args("sensitivity", tmp_path))
    assert r["fd_max_rel_err"] < 1e-4


def test_cli_optimize_json_and_file(tmp_path, capsys):
    out = tmp_path / "opt.json"
    code, stdout, err = run(["optimize", str(LENS_DIR / "thorlabs_acl5040u.json"), "--vary",
                             "surfaces.0.k,surfaces.0.a.0", "--wavelengths", "587.5618",
                             "--steps", "3", "--sampling", "hexapolar:3", "--out", str(out),
                             "--json"], capsys)
    assert code == 0, err
    r = json.loads(stdout)
    assert {"merit_before", "merit_after", "rms_before_um", "rms_after_um", "seconds",
            "steps"} <= set(r)
    assert r["merit_after"] < r["merit_before"]
    assert r["rms_after_um"][0] < r["rms_before_um"][0]
    assert json.loads(out.read_text())["format"] == "deeplens-lens"
    # --jacobian central: the same steps from 2n + 1 plain evaluations per Jacobian
    code, stdout, err = run(["optimize", str(LENS_DIR / "thorlabs_acl5040u.json"), "--vary",
                             "surfaces.0.k,surfaces.0.a.0", "--wavelengths", "587.5618",
                             "--steps", "3", "--sampling", "hexapolar:3", "--out", str(out),
                             "--json", "--jacobian", "central"], capsys)
    assert code == 0, err
    c = json.loads(stdout)
    assert c["merit_after"] == pytest.approx(r["merit_after"], rel=1e-6)
    assert c["evaluations"] == r["evaluations"] + 3 * (2 * 2 + 1 - 2)


def test_cli_optimize_bad_input_writes_nothing(tmp_path, capsys):
    out = tmp_path / "opt.json"
    lens = str(LENS_DIR / "thorlabs_acl5040u.json")
    code, _, err = run(["optimize", lens, "--vary", "surfaces.7.c", "--out", str(out)], capsys)
    assert code == 2 and "matches no lens parameter; available: d_sensor" in err
    code, _, err = run(["optimize", lens, "--vary", "d_sensor", "--constraint", "max_track=40",
                        "--out", str(out)], capsys)
    assert code == 2 and "max_track" in err and "unmet by 7" in err
    code, _, err = run(["optimize", lens, "--vary", "d_sensor", "--out", str(tmp_path / "x.txt")],
                       capsys)
    assert code == 2 and "--out" in err
    assert not out.exists()


def test_cli_tolerance_and_design(tmp_path, capsys):
    tol = tmp_path / "tol.json"
    tol.write_text(json.dumps({"misalignments.*.dy": 0.02, "distances.1": 0.05}))
    code, stdout, err = run(["tolerance", str(LENS_DIR / "cooke_triplet.json"), "--tolerances",
                             str(tol), "--fields", "0", "--sampling", "hexapolar:2",
                             "--monte-carlo", "5", "--json"], capsys)
    assert code == 0, err
    r = json.loads(stdout)
    assert r["parameters"] == ["misalignments.0.dy", "misalignments.1.dy",
                               "misalignments.3.dy", "distances.1"]
    assert r["rss_um"][0] > r["nominal_um"][0]
    assert set(r["monte_carlo"]["percentiles_um"]) == {"50", "90", "98"}
    code, _, err = run(["design", "nikkon"], capsys)
    assert code == 2 and "unknown design application" in err
