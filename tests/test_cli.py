"""``deeplens report``: JSON and table output, the --fields/--wavelengths/--sampling options, and
exit status 2 with a clear message for bad input."""

import json
import math
import re
from pathlib import Path

import helpers as H
import pytest

from deeplens.optics.paraxial import paraxial
from deeplens.optics.io import load_lens

ROOT = Path(__file__).resolve().parents[1]
DG = str(ROOT / "data" / "lenses" / "double_gauss.json")


run = H.run_cli


def report_json(capsys, *extra):
    code, out, err = run(["report", DG, "--image-plane", "paraxial", "--json", *extra], capsys)
    assert code == 0, err
    return json.loads(out)


def test_report_json_default(capsys):
    r = report_json(capsys)
    assert abs(r["efl_mm"] - 27.44) <= 1e-4 * 27.44
    p = paraxial(load_lens(DG))
    assert r["efl_mm"] == pytest.approx(float(p.efl), rel=1e-12)
    assert r["bfl_mm"] == pytest.approx(float(p.bfl), rel=1e-12)
    assert 15 < r["bfl_mm"] < 20
    assert r["fno"] == pytest.approx(r["efl_mm"] / r["entrance_pupil"]["diameter_mm"], rel=1e-12)
    assert set(r["entrance_pupil"]) >= {"position_mm", "diameter_mm"}
    assert r["entrance_pupil"]["diameter_mm"] == pytest.approx(
        float(p.entrance_pupil_diameter), rel=1e-12)
    assert r["entrance_pupil"]["position_mm"] == pytest.approx(
        float(p.entrance_pupil_position), rel=1e-12)
    # the paraxial image plane of an object at infinity is the back focal plane
    assert r["image_plane"]["distance_from_last_vertex_mm"] == pytest.approx(r["bfl_mm"])
    fields = r["fields"]
    assert [f["field_deg"] for f in fields] == [0.0, 7.0, 14.0, 21.0]
    heights = []
    for f in fields:
        assert set(f) >= {"field_deg", "wavelength_nm", "rms_spot_um", "chief_ray_height_mm",
                          "n_rays"}
        assert f["wavelength_nm"] == 587.5618
        assert isinstance(f["rms_spot_um"], float) and 0 < f["rms_spot_um"] < 100
        assert isinstance(f["n_rays"], int) and f["n_rays"] > 500
        heights.append(f["chief_ray_height_mm"])
    assert heights[0] == pytest.approx(0.0, abs=1e-9)
    # the chief ray lands near f tan(theta) (distortion of a double Gauss is small)
    for f, h in zip(fields[1:], heights[1:]):
        ideal = r["efl_mm"] * math.tan(math.radians(f["field_deg"]))
        assert h == pytest.approx(ideal, rel=0.05)


def test_report_table_matches_json(capsys):
    opts = ["--fields", "0,14", "--sampling", "hexapolar:6", "--pupil", "paraxial"]
    r = report_json(capsys, *opts)
    code, out, err = run(["report", DG, "--image-plane", "paraxial", *opts], capsys)
    assert code == 0, err
    with pytest.raises(json.JSONDecodeError):
        json.loads(out)
    assert r["name"] in out
    assert re.search(r"EFL 27\.44\d* mm", out)
    assert f"F/# {r['fno']:.4g}" in out
    assert "entrance pupil" in out and "RMS spot (um)" in out
    rows = [line.split() for line in out.splitlines()
            if re.match(r"^\s+-?\d+(\.\d+)?\s+587\.562\s", line)]
    assert len(rows) == 2
    for row, f in zip(rows, r["fields"]):
        assert float(row[0]) == f["field_deg"]
        assert float(row[2]) == pytest.approx(f["rms_spot_um"], abs=1e-4)
        assert float(row[3]) == pytest.approx(f["chief_ray_height_mm"], abs=1e-5)
        assert row[4] == f"{f['n_rays']}/{f['n_launched']}"


def test_fields_wavelengths_and_grid_sampling(capsys):
    # (--pupil paraxial: the traced pupil search costs seconds and is covered above)
    r = report_json(capsys, "--fields", "0,10", "--wavelengths", "486.1327,656.2725",
                    "--sampling", "grid:9", "--pupil", "paraxial")
    got = [(f["field_deg"], f["wavelength_nm"]) for f in r["fields"]]
    assert sorted(got) == [(0.0, 486.1327), (0.0, 656.2725), (10.0, 486.1327), (10.0, 656.2725)]
    on_axis = [f for f in r["fields"] if f["field_deg"] == 0.0]
    # grid:9 = the 9 x 9 grid over [-1, 1]^2 clipped to the unit disk
    n_grid = sum(1 for i in range(9) for j in range(9)
                 if ((i - 4) / 4) ** 2 + ((j - 4) / 4) ** 2 <= 1 + 1e-12)
    for f in on_axis:
        assert f["n_launched"] == n_grid and f["n_rays"] == n_grid
    # axial colour: F and C do not focus alike on the d-line paraxial image plane
    assert on_axis[0]["rms_spot_um"] != pytest.approx(on_axis[1]["rms_spot_um"], rel=1e-3)
    assert r["sampling"] == "grid:9"


_CACHE = {}


def _on_axis(capsys, sampling):
    if sampling not in _CACHE:
        _CACHE[sampling] = report_json(capsys, "--fields", "0", "--sampling", sampling,
                                       "--pupil", "paraxial")
    return _CACHE[sampling]


@pytest.mark.parametrize("sampling,n", [("hexapolar:6", 1 + 3 * 6 * 7), ("random:50", 50),
                                        ("random:50:7", 50)])
def test_sampling_counts(sampling, n, capsys):
    r = _on_axis(capsys, sampling)
    (f,) = r["fields"]
    assert f["n_launched"] == n and f["n_rays"] == n
    assert f["rms_spot_um"] > 0
    assert r["sampling"] == sampling


def test_random_sampling_seed(capsys):
    a = _on_axis(capsys, "random:50")["fields"][0]
    b = _on_axis(capsys, "random:50:7")["fields"][0]
    assert a["rms_spot_um"] != b["rms_spot_um"]


@pytest.mark.parametrize("args,pattern", [
    (["--sampling", "hexa:6"], r"pupil sampling must be one of hexapolar:RINGS, grid:N, "
                               r"random:N\[:SEED\]; got 'hexa:6'"),
    (["--sampling", "grid:0"], r"pupil sampling 'grid:0': the count must be positive"),
    (["--sampling", "grid:nine"], r"pupil sampling 'grid:nine': the count must be an integer"),
    (["--sampling", "random"], r"pupil sampling must be one of .*got 'random'"),
    (["--wavelengths", "0.55"], r"--wavelengths: deeplens takes wavelengths in nanometres; got "
                                r"0\.55 .*micrometres\? use 550"),
    (["--wavelengths", "0.4861,0.5876"], r"--wavelengths: .*nanometres; got values in "
                                         r"\[0\.4861, 0\.5876\]"),
    (["--wavelengths", "0.55um"], r"--wavelengths must be comma-separated numbers in nm .*got "
                                  r"'0\.55um'"),
    (["--wavelengths", "3000"], r"--wavelengths: wavelength 3000 nm is outside the valid range "
                                r"310.2500 nm of material 'SSK4'"),
    (["--wavelengths", ","], r"--wavelengths: no values given"),
    (["--fields", "abc"], r"--fields must be comma-separated numbers in degrees.*got 'abc'"),
    (["--fields", "0,95"], r"--fields: field angles are in degrees and must lie within "
                           r"\(-90, 90\), got '0,95'"),
    (["--fields", "nan"], r"--fields must be finite numbers"),
])
def test_bad_option_exits_2(args, pattern, capsys):
    code, out, err = run(["report", DG, *args], capsys)
    assert code == 2
    assert out == ""
    assert err.startswith("deeplens report: error: ")
    assert re.search(pattern, err), err


def test_missing_lens_file(capsys, tmp_path):
    code, out, err = run(["report", str(tmp_path / "nope.json")], capsys)
    assert code == 2 and out == ""
    assert "lens file not found" in err and "nope.json" in err


def test_bad_lens_file(capsys, tmp_path):
    p = tmp_path / "bad.json"
    d = json.loads(Path(DG).read_text())
    del d["stop"]
    p.write_text(json.dumps(d))
    code, out, err = run(["report", str(p)], capsys)
    assert code == 2 and out == ""
    assert f"{p}: stop: missing" in err


def test_argparse_errors_exit_2(capsys):
    code, _, err = run(["report", DG, "--image-plane", "somewhere"], capsys)
    assert code == 2 and "--image-plane" in err
    code, _, err = run([], capsys)
    assert code == 2


def test_output_piped_into_a_reader_that_stops_early_ends_quietly():
    """``deeplens report LENS | head -1``: the reader is gone when the report is written (here
    it has closed its end before the command starts, so every write meets a broken pipe, as the
    rest of the report does under ``head``); the command ends with 141 (128 + SIGPIPE) and no
    BrokenPipeError traceback on stderr."""
    import os
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(repo), OMP_NUM_THREADS="1")
    code = ("import sys; from deeplens.cli import main; "
            "sys.exit(main(['report', 'double_gauss', '--sampling', 'hexapolar:3']))")
    r, w = os.pipe()
    os.close(r)                     # the reader has left
    try:
        p = subprocess.run([sys.executable, "-c", code], stdout=w, stderr=subprocess.PIPE,
                           env=env, cwd=repo, timeout=120)
    finally:
        os.close(w)
    err = p.stderr.decode()
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert p.returncode == 141
