"""Design figures (matplotlib, imported lazily): spot diagrams, merit history, heat maps."""

from __future__ import annotations

import torch

__all__ = ["spot_figure", "history_figure", "heatmap_figure", "save"]


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def spot_figure(merit, lenses: dict, scale_um: float | None = None):
    """Spot diagrams (µm, about each spot's centroid) of a prepared
    :class:`~deeplens.design.merit.SpotMerit` on each lens of ``{title: lens}``: one row per
    lens, one column per field, wavelengths in colour."""
    plt = _plt()
    F = len(merit.fields)
    fig, axes = plt.subplots(len(lenses), F, figsize=(3 * F, 3 * len(lenses)), dpi=90,
                             squeeze=False)
    colours = ["tab:green", "tab:blue", "tab:red", "tab:orange", "tab:purple"]
    strict, merit.strict_rays = merit.strict_rays, False  # a lost ray is just not drawn
    try:
        with torch.no_grad():
            blocks = {t: merit._blocks(L) for t, L in lenses.items()}
    finally:
        merit.strict_rays = strict
    lim = scale_um
    if lim is None:
        lim = max(float(b[0].abs().max()) for bl in blocks.values() for b in bl.values()) * 1e3
    for r, (title, bl) in enumerate(blocks.items()):
        for c, f in enumerate(merit.fields):
            ax = axes[r, c]
            for k, wl in enumerate(merit.waves):
                dev, ok, n, rms = bl[(f, wl)]
                p = dev[ok].double().cpu() * 1e3
                ax.plot(p[:, 0], p[:, 1], ".", ms=2, color=colours[k % len(colours)],
                        label=f"{wl:g} nm: {float(rms) * 1e3:.2f} µm")
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.set_aspect("equal")
            ax.set_title(f"{title}, {f:g} deg", fontsize=8)
            ax.legend(fontsize=6, loc="upper right")
            ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig


def history_figure(history, title: str = "merit"):
    """The merit of the accepted iterates (log scale)."""
    plt = _plt()
    acc = [h for h in history if h.get("accepted", True)]
    fig, ax = plt.subplots(figsize=(4, 3), dpi=90)
    ax.semilogy(range(len(acc)), [h["merit"] for h in acc], "o-", ms=3)
    ax.set_xlabel("accepted step")
    ax.set_ylabel("merit (sum r², mm²)")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig


def heatmap_figure(mats, row_labels, col_labels, titles, unit: str, row_units=None):
    """Heat maps of the matrices ``mats`` (rows: parameters, columns as labelled), one column of
    panels per matrix.  With ``row_units`` (one unit per row, e.g. ``"µm"``, ``"mrad"``) the
    rows are split by unit into one row of panels each, with a colour scale of its own (shared
    by the matrices, so they compare) and ``unit`` formatted with it (``"µm per {unit}"``);
    numbers in different units never share a colour scale."""
    plt = _plt()
    n = len(row_labels)
    units = list(row_units) if row_units is not None else [None] * n
    groups = {}
    for i, u in enumerate(units):
        groups.setdefault(u, []).append(i)
    mats = [torch.as_tensor(m, dtype=torch.float64) for m in mats]
    heights = [len(rows) for rows in groups.values()]
    # the last, narrow column holds each row's colour bar
    fig, axes = plt.subplots(len(groups), len(mats) + 1, squeeze=False, dpi=90,
                             figsize=(3.4 * len(mats) + 1.6, 0.3 * n + 1.4 * len(groups)),
                             gridspec_kw={"height_ratios": heights,
                                          "width_ratios": [1] * len(mats) + [0.06]})
    for g, (u, rows) in enumerate(groups.items()):
        v = max(float(m[rows].abs().max()) for m in mats) or 1.0
        for c, (m, t) in enumerate(zip(mats, titles)):
            ax = axes[g][c]
            im = ax.imshow(m[rows].numpy(), cmap="RdBu_r", vmin=-v, vmax=v, aspect="auto")
            ax.set_yticks(range(len(rows)))
            ax.set_yticklabels([row_labels[i] for i in rows] if c == 0 else [], fontsize=6)
            ax.set_xticks(range(len(col_labels)))
            ax.set_xticklabels(col_labels if g == len(groups) - 1 else [], fontsize=7)
            if g == 0:
                ax.set_title(t, fontsize=8)
        fig.colorbar(im, cax=axes[g][-1], label=unit if u is None else unit.format(unit=u))
    fig.tight_layout()
    return fig


def save(fig, path, dpi: float | None = None) -> str:
    """Save ``fig`` in the format its suffix names (:func:`deeplens.analysis.style.save`) and
    close it; returns the path as a string."""
    from ..analysis.style import save as save_figure

    save_figure(fig, path, dpi=dpi)
    return str(path)
