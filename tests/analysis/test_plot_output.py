"""``deeplens plot``: vector output by suffix, --dpi, whole titles, closed element outlines,
spot diagrams on one scale with the Airy circle and the report's RMS, and the polychromatic /
through-focus / field MTF of :mod:`deeplens.analysis.mtf_poly`."""

import math

import helpers as H
import pytest
import torch
from PIL import Image

from deeplens.analysis import mtf_poly
from deeplens.analysis.cardinal import pupils
from deeplens.analysis.diffraction import mtf_at
from deeplens.analysis.plot import layout_figure, mtf_field_figure, spot_figure, \
    through_focus_figure
from deeplens.analysis.report import lens_report
from deeplens.analysis.spot import spot_diagram
from deeplens.optics.io import load_lens

COOKE = H.LENS_DIR / "cooke_triplet.json"
WL = H.WAVELENGTH_D


@pytest.fixture(scope="module")
def cooke():
    return load_lens(COOKE).to(torch.float64)


def plot(capsys, out, *extra, kind="layout"):
    code, o, err = H.run_cli(["plot", str(COOKE), "--kind", kind, "-o", str(out), *extra],
                             capsys)
    assert code == 0, err
    return out


def test_vector_and_raster_output_by_suffix(capsys, tmp_path):
    pdf = plot(capsys, tmp_path / "a.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and b"/Type /Page" in pdf
    svg = plot(capsys, tmp_path / "a.svg").read_text()
    assert "<svg" in svg[:500] and "<path" in svg
    lo = Image.open(plot(capsys, tmp_path / "lo.png", "--dpi", "75"))
    hi = Image.open(plot(capsys, tmp_path / "hi.png", "--dpi", "150"))
    assert lo.format == hi.format == "PNG"
    assert hi.size[0] == pytest.approx(2 * lo.size[0], rel=0.01)   # tight bbox: +-rounding
    assert hi.info["dpi"][0] == pytest.approx(150, abs=0.5)
    code, _, err = H.run_cli(["plot", str(COOKE), "--kind", "layout", "-o",
                              str(tmp_path / "a.docx")], capsys)
    assert code == 2 and ".pdf" in err and "docx" in err
    assert not (tmp_path / "a.docx").exists()


def test_whole_lens_name_in_titles(cooke):
    name = cooke.name
    assert len(name) > 90
    fig = layout_figure(cooke)
    assert " ".join(fig.axes[0].get_title().split()) == name
    fig = spot_figure(cooke, [0.0], [WL], sampling="hexapolar:3")
    assert name in " ".join(fig._suptitle.get_text().split())


def test_layout_elements_are_closed_outlines(cooke):
    from matplotlib.patches import Polygon

    fig = layout_figure(cooke, [0.0], n_rays=3)
    polys = [p for p in fig.axes[0].patches if isinstance(p, Polygon)]
    assert len(polys) == 3          # three singlets
    z = cooke.z_vertices().tolist()
    for p, (i, j) in zip(polys, [(0, 1), (2, 3), (5, 6)]):
        v = p.get_xy()
        assert v[0].tolist() == pytest.approx(v[-1].tolist())      # closed
        h = max(float(cooke.surfaces[i].semi_diameter), float(cooke.surfaces[j].semi_diameter))
        assert v[:, 1].max() == pytest.approx(h) and v[:, 1].min() == pytest.approx(-h)
        # the axial points of both surfaces are on the outline
        on_axis = v[abs(v[:, 1]) < 1e-9][:, 0]
        assert min(abs(on_axis - z[i])) < 1e-9 and min(abs(on_axis - z[j])) < 1e-9


def test_spot_common_scale_airy_and_report_rms(cooke):
    fields, waves = [0.0, 11.86], [WL]
    fig = spot_figure(cooke, fields, waves, sampling="hexapolar:6")
    d = fig.deeplens_data
    rep = lens_report(cooke, fields, waves, "hexapolar:6", "traced", "sensor")
    for row in rep["fields"]:
        assert d["rms_um"][(row["field_deg"], row["wavelength_nm"])] == pytest.approx(
            row["rms_spot_um"], rel=1e-9)
    airy = 1.22 * WL * 1e-6 * float(pupils(cooke, WL).working_fno) * 1e3
    assert d["airy_um"] == pytest.approx(airy, rel=1e-12)
    assert 2.3 < airy < 2.7      # 1.22 x 0.588 um x ~F/3.5
    limits = {(a.get_xlim(), a.get_ylim()) for a in fig.axes if a.get_visible()}
    assert len(limits) == 1      # one scale for all fields
    circle = [ln for ln in fig.axes[0].lines if len(ln.get_xdata()) == 181]
    assert len(circle) == 1
    r = (circle[0].get_xdata() ** 2 + circle[0].get_ydata() ** 2) ** 0.5
    assert r == pytest.approx([airy] * 181, rel=1e-9)


def test_combine_otf_two_lines_is_a_cosine():
    # two equal, narrow lines delta apart: |(1 + e^{-2 pi i nu delta}) / 2| = |cos(pi nu delta)|
    x = torch.linspace(-0.05, 0.05, 201, dtype=torch.float64)
    line = torch.exp(-0.5 * (x / 1e-4) ** 2)
    delta = 0.01
    nu = torch.tensor([0.0, 10.0, 25.0, 50.0, 80.0], dtype=torch.float64)
    m = mtf_poly.combine_otf([line, line], [x, x + delta], nu)
    single = mtf_poly.combine_otf([line], [x], nu)
    expect = (torch.cos(math.pi * nu * delta)).abs() * single
    assert torch.allclose(m, expect, atol=1e-12)
    w = mtf_poly.combine_otf([line, line], [x, x + delta], nu, weights=[3, 1])
    assert float(w[3]) == pytest.approx(0.5 * float(single[3]), rel=1e-9)   # |3 - 1| / 4


def test_one_wavelength_is_the_monochromatic_mtf(cooke):
    for d in ("tangential", "sagittal"):
        poly = mtf_poly.polychromatic_mtf(cooke, 8.3, [20.0, 60.0], [WL], direction=d, n=96)
        for k, nu in enumerate([20.0, 60.0]):
            assert float(poly[k]) == pytest.approx(
                float(mtf_at(cooke, 8.3, nu, WL, d, n=96)), abs=1e-12)


def test_lines_sit_on_the_image_where_the_rays_land(cooke):
    # each wavelength's line spread is placed at its own image point (lateral colour counts)
    for w in (486.1327, 656.2725):
        parts = mtf_poly._lsf(cooke, 8.3, w, 96, "sensor")
        L, y = parts["tangential"]
        centroid = float((L * y).sum() / L.sum())
        spot = float(spot_diagram(cooke, 8.3, w, "hexapolar:12").centroid[1])
        assert centroid == pytest.approx(spot, abs=3e-3)


def test_through_focus_and_field_figures(cooke):
    dz = [-0.05, 0.0, 0.05]
    fig = through_focus_figure(cooke, [0.0], [WL], n=96, freqs=[30.0], defocus_mm=dz)
    m = fig.deeplens_data["mtf"][0.0]
    assert m.shape == (3, 2, 1)
    z = float(cooke.z_sensor())
    ref = mtf_poly.polychromatic_mtf(cooke, 0.0, [30.0], [WL], direction="both", n=96,
                                     image_plane=z + 0.05)
    assert torch.allclose(m[2], ref, atol=1e-12)
    fig = mtf_field_figure(cooke, [8.3], [WL], n=96, freqs=[30.0], points=3)
    d = fig.deeplens_data
    assert d["fields_deg"] == pytest.approx([0.0, 4.15, 8.3])
    ref = mtf_poly.polychromatic_mtf(cooke, 8.3, [30.0], [WL], direction="both", n=96)
    assert torch.allclose(d["mtf"][2], ref, atol=1e-12)
