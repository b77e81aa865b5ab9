"""``lens.info()`` / :mod:`deeplens.optics.prescription`: the lens-data-editor table, radii."""

import math

import helpers as H
import pytest
import torch

from deeplens.optics.io import load_lens
from deeplens.optics.prescription import prescription, prescription_table


@pytest.mark.parametrize("name", ["cooke_triplet", "edof_achromat", "nikon_z35_f1.8_x10"])
def test_rows_match_the_lens(name):
    lens = load_lens(H.LENS_DIR / f"{name}.json")
    rows = prescription(lens)
    assert rows[0]["surface"] == "OBJ" and rows[-1]["surface"] == "IMA"
    body = rows[1:-1]
    assert len(body) == len(lens.surfaces)
    z = lens.z_vertices().tolist() + [float(lens.z_sensor())]
    for i, (r, s) in enumerate(zip(body, lens.surfaces)):
        c = float(s.paraxial_curvature())
        assert r["curvature"] == c
        if c == 0:
            assert math.isinf(r["radius"]) and math.isinf(s.radius)
        else:
            assert r["radius"] == pytest.approx(1.0 / c, rel=1e-15)
            assert s.radius * c == pytest.approx(1.0, rel=1e-15)
        assert r["thickness"] == pytest.approx(z[i + 1] - z[i], abs=1e-12)
        assert r["material"] == lens.materials[i + 1].name
        assert r["semi_diameter"] == float(s.semi_diameter)
        assert r["surface"].endswith("STO") == (i == lens.stop_index)
    assert rows[-1]["semi_diameter"] == lens.sensor_semi_diameter


def test_info_prints_the_table(capsys):
    lens = load_lens(H.LENS_DIR / "cooke_triplet.json")
    lens.info()
    out = capsys.readouterr().out
    assert out.strip() == prescription_table(lens).strip()
    assert lens.name in out                 # the whole name, not cut
    line = next(x for x in out.splitlines() if x.split()[:1] == ["0"])
    cols = line.split()
    assert float(cols[2]) == pytest.approx(37.4, rel=1e-6)      # R = 1/c of W. J. Smith's
    assert float(cols[3]) == pytest.approx(5.9)                  # first element
    sto = next(x for x in out.splitlines() if "STO" in x)
    assert "Infinity" in sto and "aperture" in sto


def test_aspheric_terms_listed():
    lens = load_lens(H.LENS_DIR / "nikon_z35_f1.8_x10.json").to(torch.float64)
    r = prescription(lens)[1 + 17]
    assert r["extra"].startswith("aspheric=[")
    assert float(r["extra"].split("[")[1].split(",")[0]) == pytest.approx(
        float(lens.surfaces[17].a[0]), rel=1e-3)
