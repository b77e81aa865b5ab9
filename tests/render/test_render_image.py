"""``deeplens render LENS IMAGE --depth``: framing, orientation, sharpness with depth, and the
sRGB round trip of :mod:`deeplens.render.image`."""

import helpers as H
import pytest
import torch
from PIL import Image

from deeplens.optics.io import load_lens
from deeplens.render.image import linear_to_srgb, render_image, srgb_to_linear

COOKE = str(H.LENS_DIR / "cooke_triplet.json")


def write_png(path, array_hwc):
    Image.fromarray(array_hwc).save(path)
    return str(path)


def read_png(path):
    return torch.tensor(list(Image.open(path).getdata()), dtype=torch.float64)


def test_srgb_round_trip_and_known_values():
    v = torch.linspace(0, 1, 101, dtype=torch.float64)
    assert torch.allclose(linear_to_srgb(srgb_to_linear(v)), v, atol=1e-12)
    # sRGB 0.5 is 21.4 % linear (IEC 61966-2-1)
    assert float(srgb_to_linear(torch.tensor(0.5))) == pytest.approx(0.21404, abs=1e-5)


def test_render_cli_grey_card_keeps_its_value(capsys, tmp_path):
    import numpy as np

    src = write_png(tmp_path / "grey.png", np.full((24, 32), 128, dtype=np.uint8))
    out = tmp_path / "out.png"
    code, o, err = H.run_cli(["render", COOKE, src, "--depth", "100000", "-o", str(out),
                              "--spp", "64"], capsys)
    assert code == 0, err
    im = Image.open(out)
    assert im.size == (32, 24) and im.mode == "L"
    a = read_png(out).reshape(24, 32)
    # relative illumination is normalised to 1 on axis: the centre keeps sRGB 128 (MC noise)
    assert float(a[10:14, 14:18].mean()) == pytest.approx(128, abs=1.5)
    assert float(a[0, 0]) < float(a[12, 16])   # corners darker (vignetting), never brighter


def test_render_is_upright_and_sharp_only_in_focus():
    lens = load_lens(COOKE)
    img = torch.zeros(3, 32, 48, dtype=torch.float64)
    img[:, ::4] = 1.0
    img[:, :, ::4] = 1.0
    img[0, :16, :24] = 1.0          # red top-left quadrant
    far = render_image(lens, img, 1e6, spp=8)
    assert far.shape == img.shape
    red = far[0] - far[1]           # red excess: only where the picture is red
    assert float(red[2:14, 2:22].mean()) > 0.3
    assert abs(float(red[18:30, 26:46].mean())) < 0.1
    near = render_image(lens, img, 300.0, spp=8)
    err_far = float((far - img)[:, 8:24, 12:36].abs().mean())
    err_near = float((near - img)[:, 8:24, 12:36].abs().mean())
    # the triplet is focused at infinity: a grid at 0.3 m blurs towards its mean
    assert err_far < 0.5 * err_near
    assert float(near[1, 8:24, 12:36].std()) < 0.6 * float(far[1, 8:24, 12:36].std())


def test_render_cli_errors(capsys, tmp_path):
    import numpy as np

    src = write_png(tmp_path / "g.png", np.zeros((4, 4), dtype=np.uint8))
    code, _, err = H.run_cli(["render", COOKE, src, "--depth", "-5", "-o", str(tmp_path / "o.png")],
                             capsys)
    assert code == 2 and "--depth" in err
    code, _, err = H.run_cli(["render", COOKE, str(tmp_path / "none.png"), "--depth", "100",
                              "-o", str(tmp_path / "o.png")], capsys)
    assert code == 2 and "none.png" in err
    (tmp_path / "bad.png").write_text("not an image")
    code, _, err = H.run_cli(["render", COOKE, str(tmp_path / "bad.png"), "--depth", "100",
                              "-o", str(tmp_path / "o.png")], capsys)
    assert code == 2 and "bad.png" in err and "not a readable image" in err
