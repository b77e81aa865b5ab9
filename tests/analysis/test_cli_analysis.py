"""``deeplens plot`` (every kind writes a PNG) and ``deeplens report --analysis`` (the values in
its JSON are those of the analysis functions), with exit status 2 for bad input."""

from __future__ import annotations

import contextlib
import io
import json

import helpers as H
import pytest
import torch

from deeplens.analysis.aberrations import distortion
from deeplens.analysis.diffraction import mtf
from deeplens.analysis.plot import KINDS
from deeplens.cli import main
from deeplens.optics.io import load_lens

DG = str(H.LENS_DIR / "double_gauss.json")


def run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as e:
            code = e.code
    return code, out.getvalue(), err.getvalue()


@pytest.mark.parametrize("kind", list(KINDS))
def test_plot_every_kind(kind, tmp_path):
    path = tmp_path / f"{kind}.png"
    code, out, err = run(["plot", DG, "--kind", kind, "--fields", "0,14", "--wavelengths",
                          "587.5618,486.1327", "-o", str(path)])
    assert code == 0, err
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


def test_report_analysis_json():
    code, out, err = run(["report", DG, "--json", "--pupil", "paraxial", "--sampling",
                          "hexapolar:4", "--fields", "0,21", "--analysis",
                          "distortion,mtf,cardinal,vignetting"])
    assert code == 0, err
    a = json.loads(out)["analysis"]
    lens = load_lens(DG).to(torch.float64)
    d = distortion(lens, [0.0, 21.0])
    assert a["distortion"]["percent"] == pytest.approx(d.tolist(), abs=1e-9)
    assert a["distortion"]["percent"][1] == pytest.approx(-1.70, abs=0.02)  # f-tan barrel
    m = mtf(lens, 21.0, n=64)
    t, s = m.at(40.0)
    row = a["mtf"][1]
    assert row["field_deg"] == 21.0 and row["freq_cycles_per_mm"][2] == 40.0
    assert row["tangential"][2] == pytest.approx(t, abs=1e-9)
    assert row["sagittal"][2] == pytest.approx(s, abs=1e-9)
    assert a["cardinal"]["efl"] == pytest.approx(27.44, abs=0.01)
    assert a["vignetting"]["fraction"][0] == 0.0 and a["vignetting"]["fraction"][1] > 0


@pytest.mark.parametrize("argv,pattern", [
    (["report", DG, "--analysis", "distortion,foo"], "unknown kind(s) foo"),
    (["plot", DG, "--kind", "mtf", "--fields", "0,60", "-o", "x.png"],
     "field 60 deg at 587.562 nm is beyond the lens's reach"),
    (["plot", DG, "--kind", "fan", "--wavelengths", "3000", "-o", "x.png"],
     "wavelength 3000 nm is outside the valid range 310"),
    (["plot", DG, "--kind", "fan", "--fields", "abc", "-o", "x.png"],
     "--fields must be comma-separated numbers"),
])
def test_bad_input_exits_2(argv, pattern, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(argv)
    assert code == 2 and out == ""
    assert pattern in err, err
    assert not (tmp_path / "x.png").exists()


def test_plot_kind_must_be_known():
    code, _, err = run(["plot", DG, "--kind", "bokeh", "-o", "x.png"])
    assert code == 2 and "--kind" in err


def test_field_panels_one_visible_panel_per_field():
    """Five fields on a grid of 4 columns: 2 x 4 cells, the 3 unused ones hidden, the panels in
    field order."""
    import matplotlib

    matplotlib.use("Agg")
    from deeplens.analysis.plot import spot_figure

    lens = load_lens(DG)
    fields = [0.0, 4.0, 8.0, 12.0, 16.0]
    fig = spot_figure(lens, fields_deg=fields, wavelengths_nm=[587.5618],
                      sampling="hexapolar:2")
    assert len(fig.axes) == 8
    shown = [a for a in fig.axes if a.get_visible()]
    assert [a.get_title().split(" deg")[0] for a in shown] == [f"{f:g}" for f in fields]


def test_report_wavelength_outside_a_glass_names_the_medium_and_file():
    code, out, err = run(["report", DG, "--wavelengths", "300"])
    assert code == 2
    assert ("--wavelengths: wavelength 300 nm is outside the valid range 310–2500 nm of "
            "material 'SSK4' (the medium after surface 0 of " + DG + ")") in err
