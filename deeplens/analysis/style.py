"""One look for every deeplens figure: sizes, fonts, a wavelength colour map, the headless backend.

``@styled`` runs a figure function under the house style; ``figure(...)`` opens a figure
(Agg backend, so it works without a display); ``wavelength_color(nm)`` maps a wavelength to an
approximately perceived colour so that the F, d and C lines read as blue, yellow-green and red
in every plot; ``save(fig, path, dpi=...)`` writes the format the suffix names (vector for .pdf/.svg/.eps/.ps,
a compact palette PNG for .png) and closes the figure.
"""

from __future__ import annotations

import functools

__all__ = ["STYLE", "figure", "styled", "wavelength_color", "field_color", "save", "title", "circle",
           "VECTOR_FORMATS", "DEFAULT_DPI"]

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


def title(text: str, width: int = 90) -> str:
    """``text`` wrapped onto lines of at most ``width`` characters, never cut."""
    import textwrap

    return "\n".join(textwrap.wrap(text, width)) or text


def circle(radius: float, n: int = 181):
    """``(x, y)`` lists of a circle of ``radius`` about the origin (for ``ax.plot``)."""
    import math

    t = [2 * math.pi * k / (n - 1) for k in range(n)]
    return [radius * math.cos(v) for v in t], [radius * math.sin(v) for v in t]


def field_color(i: int) -> str:
    return _FIELD_COLORS[i % len(_FIELD_COLORS)]


#: vector formats matplotlib writes (``savefig(format=...)``), by file suffix
VECTOR_FORMATS = ("pdf", "svg", "eps", "ps")
#: resolution of raster output when none is asked for (dots per inch)
DEFAULT_DPI = 150


def save(fig, path, colors: int = 256, dpi: float | None = None) -> None:
    """Write ``fig`` in the format its suffix names and close it.

    ``.pdf``, ``.svg``, ``.eps``, ``.ps`` are written as vector graphics; ``.png`` as a raster at
    ``dpi`` (default :data:`DEFAULT_DPI`) stored, with Pillow present, with an adaptive palette
    of ``colors`` entries (3-5x smaller files); ``.jpg``/``.tif`` as plain rasters.

    Raises:
        ValueError: an unknown suffix or a non-positive ``dpi`` (nothing is written).
    """
    import io
    from pathlib import Path

    plt = _pyplot()
    fmt = Path(path).suffix.lower().lstrip(".")
    fmt = {"jpeg": "jpg", "tiff": "tif"}.get(fmt, fmt)
    if fmt not in VECTOR_FORMATS + ("png", "jpg", "tif"):
        plt.close(fig)
        raise ValueError(f"{path}: the figure format comes from the suffix: .png, .jpg, .tif "
                         f"(raster) or .pdf, .svg, .eps, .ps (vector), got {fmt!r}")
    dpi = DEFAULT_DPI if dpi is None else float(dpi)
    if not dpi > 0:
        plt.close(fig)
        raise ValueError(f"dpi must be > 0, got {dpi!r}")
    buf = io.BytesIO()
    with plt.rc_context(STYLE):
        fig.tight_layout()
        fig.savefig(buf, format=fmt, dpi=dpi, bbox_inches="tight", pad_inches=0.05)
    plt.close(fig)
    data = buf.getvalue()
    if fmt == "png":
        try:
            from PIL import Image
        except ImportError:  # pragma: no cover - Pillow comes with matplotlib
            Image = None
        if Image is not None:
            out = io.BytesIO()
            Image.open(io.BytesIO(data)).convert("RGB").quantize(colors=colors).save(
                out, format="PNG", optimize=True, dpi=(dpi, dpi))
            data = out.getvalue()
    with open(path, "wb") as f:
        f.write(data)
