"""Figures a designer reads (issue 35): sensitivities with human labels and one colour scale
per unit, ray fans on one shared scale."""

import torch

from deeplens.design.labels import DISPLAY_PER_UNIT, parameter_label
from deeplens.design.plots import heatmap_figure
from deeplens.design.sensitivity import tolerance_parameters
from deeplens.optics.io import load_lens


def test_labels_name_glass_elements_from_1_and_their_units():
    lens = load_lens("cooke_triplet")      # elements: 3 singlets and the stop (element 2 of 4)
    names = tolerance_parameters(lens, ("decenter", "tilt", "spacing", "curvature"))
    got = {n: parameter_label(lens, n) for n in names}
    assert got["misalignments.0.tilt_x"] == ("element 1 tilt x", "mrad", "tilt")
    assert got["misalignments.3.dy"] == ("element 3 decenter y", "µm", "decenter")  # after stop
    assert got["distances.1"] == ("spacing surface 1 to 2", "µm", "spacing")
    assert got["surfaces.0.c"] == ("surface 1 curvature", "1/m", "curvature")
    assert not any("misalignments" in lab for lab, _, _ in got.values())
    assert parameter_label(lens, "d_sensor") == ("d_sensor", "unit", "other")
    # a display unit is 1e-3 of the parameter's own (mm, rad, 1/mm)
    assert {DISPLAY_PER_UNIT[k][1] for _, _, k in got.values()} == {1e3}


def test_heatmap_gives_each_unit_its_own_colour_scale():
    rows = ["element 1 decenter x (µm)", "element 1 tilt x (mrad)", "spacing surface 1 to 2 (µm)"]
    units = ["µm", "mrad", "µm"]
    mats = [torch.tensor([[0.1], [5.0], [-0.3]], dtype=torch.float64),
            torch.tensor([[0.2], [-2.0], [0.05]], dtype=torch.float64)]
    fig = heatmap_figure(mats, rows, ["∂ε/∂θ"], ["field 0", "field 10"], "µm per {unit}",
                         row_units=units)
    panels = [a for a in fig.axes if a.get_images()]
    assert len(panels) == 4                                  # 2 units x 2 fields
    clims = {tuple(a.get_images()[0].get_clim()) for a in panels}
    assert clims == {(-0.3, 0.3), (-5.0, 5.0)}               # shared across fields, per unit
    labels = [t.get_text() for a in panels for t in a.get_yticklabels()]
    assert "element 1 tilt x (mrad)" in labels
    bars = [a.get_ylabel() for a in fig.axes if not a.get_images()]
    assert sorted(bars) == ["µm per mrad", "µm per µm"]


def test_ray_fans_share_one_scale():
    from deeplens.analysis.plot import fan_figure

    fig = fan_figure(load_lens("double_gauss").double(), n=9)
    lims = {a.get_ylim() for a in fig.axes}
    assert len(fig.axes) == 8 and len(lims) == 1
