"""The layout of a folded lens is drawn in the global frame: the rays of a Newtonian end on
its image, which a 45-degree fold puts beside the tube (closed form: ``a`` off the axis at the
fold's position)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

from deeplens.analysis.plot import layout_figure  # noqa: E402


def _newtonian(f, a):
    path = Path(__file__).parents[1] / "optics" / "test_mirrors.py"
    spec = importlib.util.spec_from_file_location("_mirror_lenses", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.newtonian(f, a)


def test_layout_of_a_fold_ends_on_the_image():
    f, a = 500.0, 100.0
    lens = _newtonian(f, a)
    fig = layout_figure(lens, fields_deg=[0.0], n_rays=5)
    ax = fig.axes[0]
    ends = [(line.get_xdata()[-1], line.get_ydata()[-1]) for line in ax.get_lines()
            if len(line.get_xdata()) > 2]  # ray paths (surfaces are drawn with 2 or 101 points)
    ends = [e for e in ends if abs(e[1] + a) < 1.0]
    assert len(ends) == 5
    for z, y in ends:
        assert abs(z - (10.0 - (f - a))) < 1e-9 and abs(y + a) < 1e-9
