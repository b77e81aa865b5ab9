"""TensorBoard PSF panels (:mod:`deeplens.training.psf_panels`), the step scalars
(:mod:`deeplens.training.scalars`) and the evaluation's samples grid."""

import pytest
import torch

from deeplens.evaluation.figures import samples_grid
from deeplens.training.psf_panels import psf_panels_figure
from deeplens.training.scalars import training_scalars


def test_psf_panels_are_labelled_upsampled_and_share_a_scale():
    k1 = torch.zeros(9, 9)
    k1[4, 4] = 2.0
    k2 = torch.full((9, 9), 0.5)
    k3 = torch.zeros(9, 9)               # a PSF that could not be traced
    ks = [k1, k2, k3, k1]
    fig = psf_panels_figure(ks, [1000.0, 5500.0], [0.0, 12.5], 587.5618, 0.004)
    panels = [a for a in fig.axes if a.get_images() and a.get_title()]
    assert len(panels) == 4
    titles = [a.get_title() for a in panels]
    assert titles[1] == "depth 1 m, field 12.5°\n587.562 nm"
    assert titles[2].startswith("depth 5.5 m, field 0°")
    for a, k in zip(panels, ks):
        im = a.get_images()[0]
        assert im.get_interpolation() == "nearest"
        assert im.get_clim() == (0.0, 1.0)
        assert torch.allclose(torch.as_tensor(im.get_array().data), (k / 2.0).double())
        x0, x1, y0, y1 = im.get_extent()
        assert x1 - x0 == pytest.approx(9 * 4.0)         # 9 pixels of 4 um
    assert "no PSF" in [t.get_text() for t in panels[2].texts]
    cbar = [a for a in fig.axes if a not in panels]
    assert len(cbar) == 1 and "max" in cbar[0].get_ylabel()
    fig.canvas.draw()
    w, h = fig.canvas.get_width_height()
    assert w >= 500 and h >= 400                          # not a 39 x 153 thumbnail
    with pytest.raises(ValueError, match="2 depths x 2 fields need 4"):
        psf_panels_figure(ks[:3], [1000.0, 5500.0], [0.0, 12.5], 587.5618, 0.004)


def test_training_scalars_learning_rates_and_nsr():
    p1, p2 = torch.nn.Parameter(torch.zeros(2)), torch.nn.Parameter(torch.zeros(1))
    opt = torch.optim.Adam([{"params": [p1], "lr": 1e-3, "name": "net"},
                            {"params": [p2], "lr": 2e-5, "name": "optics.curvature"}])

    class Deconv:
        def nsr(self):
            return torch.tensor([0.01, 0.02, 0.03], dtype=torch.float64)

    s = training_scalars(opt, Deconv())
    assert s == {"lr/net": 1e-3, "lr/optics.curvature": 2e-5, "wiener/nsr_c0": 0.01,
                 "wiener/nsr_c1": 0.02, "wiener/nsr_c2": pytest.approx(0.03)}
    assert training_scalars(opt) == {"lr/net": 1e-3, "lr/optics.curvature": 2e-5}


def test_samples_grid_is_variants_by_depths():
    variants, depths = ["cubic", "none"], [1000.0, 2000.0, 9000.0]
    cells = {(v, d): tuple(torch.full((1, 4, 4), 0.1 * (i + 1) + 0.01 * k)
                           for k in range(3))
             for i, (v, d) in enumerate((v, d) for v in variants for d in depths)}
    fig = samples_grid(cells, variants, depths)
    axes = fig.axes
    assert len(axes) == 2 * 7
    titles = [a.get_title() for a in axes[:7]]
    assert titles == ["ground truth", "sensor, 1 m", "restored, 1 m", "sensor, 2 m",
                      "restored, 2 m", "sensor, 9 m", "restored, 9 m"]
    assert axes[7].get_ylabel() == "none"
    # row "none", depth 9 m, restored: cell index 5, value 0.6 + 0.02
    shown = axes[7 + 6].get_images()[0].get_array()
    assert float(shown[0, 0, 0]) == pytest.approx((0.62) ** (1 / 2.2), rel=1e-6)
