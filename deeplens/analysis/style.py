"""One look for every deeplens figure: sizes, fonts, a wavelength colour map, the headless backend.

``@styled`` runs a figure function under the house style; ``figure(...)`` opens a figure
(Agg backend, so it works without a display); ``wavelength_color(nm)`` maps a wavelength to an
approximately perceived colour so that the F, d and C lines read as blue, yellow-green and red
in every plot; ``save(fig, path)`` writes a compact PNG and closes the figure.
"""

from __future__ import annotations

import functools

__all__ = ["STYLE", "figure", "styled", "wavelength_color", "field_color", "save"]

STYLE = {
    "figure.dpi": 90,
    "savefig.dpi": 90,
    "font.size": 8,
    "axes.titlesize": 8,
    "axes.labelsize": 8,
    "legend.fontsize": 7,
    "xtick.labelsize": 7,
    "ytick.labelsize": 7,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "lines.linewidth": 1.0,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "image.cmap": "inferno",
}

_FIELD_COLORS = ["#1f77b4", "#2ca02c", "#ff7f0e", "#d62728", "#9467bd", "#8c564b", "#e377c2"]


def _pyplot():
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
        matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def figure(nrows: int = 1, ncols: int = 1, size=(6.0, 4.0), **kw):
    """``(fig, axes)`` in the house style (``plt.subplots`` arguments pass through)."""
    plt = _pyplot()
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(nrows, ncols, figsize=size, **kw)
    return fig, ax


def styled(fn):
    """Decorator: run a figure function under :data:`STYLE` (matplotlib reads its settings when
    each artist is made, so the whole function runs inside the style's ``rc_context``)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        plt = _pyplot()
        with plt.rc_context(STYLE):
            return fn(*args, **kwargs)

    return wrapper


def wavelength_color(nm: float) -> str:
    """A hex colour for a visible wavelength (grey outside 380-750 nm)."""
    w = float(nm)
    if w < 380 or w > 750:
        return "#7f7f7f"
    if w < 440:
        r, g, b = -(w - 440) / 60, 0.0, 1.0
    elif w < 490:
        r, g, b = 0.0, (w - 440) / 50, 1.0
    elif w < 510:
        r, g, b = 0.0, 1.0, -(w - 510) / 20
    elif w < 580:
        r, g, b = (w - 510) / 70, 1.0, 0.0
    elif w < 645:
        r, g, b = 1.0, -(w - 645) / 65, 0.0
    else:
        r, g, b = 1.0, 0.0, 0.0
    # darken the bright yellows so that lines stay visible on white
    k = 0.8 if 540 < w < 600 else 0.95
    return "#{:02x}{:02x}{:02x}".format(*(int(255 * k * v) for v in (r, g, b)))


def field_color(i: int) -> str:
    return _FIELD_COLORS[i % len(_FIELD_COLORS)]


def save(fig, path, colors: int = 256) -> None:
    """Write ``fig`` as a PNG (tight layout) and close it; with Pillow present the image is
    stored with an adaptive palette of ``colors`` entries (3-5x smaller files)."""
    import io

    plt = _pyplot()
    buf = io.BytesIO()
    with plt.rc_context(STYLE):
        fig.tight_layout()
        fig.savefig(buf, format="png")
    plt.close(fig)
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow comes with matplotlib
        with open(path, "wb") as f:
            f.write(buf.getvalue())
        return
    buf.seek(0)
    Image.open(buf).convert("RGB").quantize(colors=colors).save(path, format="PNG",
                                                                optimize=True)
