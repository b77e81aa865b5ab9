"""Figures of an evaluation (:func:`deeplens.evaluation.evaluate.evaluate`), as PNG files and
TensorBoard images (matplotlib, imported lazily, Agg backend).

* ``psnr_vs_depth.png``: restored (solid, ± std over seeds as error bars) and sensor (dashed)
  PSNR against depth, one colour per variant, on the test set the table ends with (the images
  of ``eval.test_folder`` when it is set; the title names it);
* ``psfs.png``: on-axis PSFs (green channel's wavelengths summed, ``kernel`` pixels, each
  normalised to its own peak) per variant (rows) and depth (columns), drawn with nearest
  neighbour so a sensor pixel is a visible square, by the PSF model the run rendered with
  (``render.psf_model``'s choice: diffraction or geometric; the title says which);
* ``plates.png``: the phase plate's height map (µm) of every variant that has one;
* ``samples.png``: the first test image (of ``eval.test_folder`` when set), a row per variant: ground truth, then sensor |
  restored at the nearest, best-focus (smallest PSF of the first variant) and farthest depth
  (a variants x depths grid).
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..render.psf import psf
from ..training.lens_setup import surface_height_map

__all__ = ["write_figures"]


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def psnr_vs_depth_figure(summary: dict, depths, test_set: str | None = None):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    x = [d / 1000 for d in depths]
    for k, (v, e) in enumerate(summary.items()):
        col = f"C{k % 10}"
        r = [e["restored"][f"{d:g}"] for d in depths]
        s = [e["sensor"][f"{d:g}"] for d in depths]
        ax.errorbar(x, [c["psnr"] for c in r], yerr=[c["psnr_std"] for c in r], color=col,
                    marker="o", capsize=3, label=f"{v} restored")
        ax.plot(x, [c["psnr"] for c in s], color=col, ls="--", marker=".", alpha=0.7,
                label=f"{v} sensor")
    ax.set_xlabel("depth (m)")
    ax.set_ylabel("PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    if test_set:
        ax.set_title(f"test set: {test_set}", fontsize=9)
    fig.tight_layout()
    return fig


def run_psf(module, depth_mm: float, wavelengths_nm, kernel: int = 21,
            n_rays: int = 8192) -> tuple[torch.Tensor, str]:
    """The on-axis PSF ``(kernel, kernel)`` of ``module``'s camera at ``depth_mm``, the
    wavelengths summed, by the model its renderer uses: the diffraction kernels of its
    :class:`~deeplens.render.psf_model.PSFModel` when that chose ``diffraction`` (centre
    ``kernel`` pixels), else the geometric ray-traced PSF.  Returns ``(psf, model name)``."""
    pm = getattr(getattr(module, "renderer", None), "psf_model", None)
    model = "geometric"
    if pm is not None and pm.choice is not None:
        model = pm.resolve(module.camera, None)
    with torch.no_grad():
        if model == "diffraction":
            kers = pm.diffraction(module.camera, None,
                                  [((0.0, 0.0), float(depth_mm), float(w))
                                   for w in wavelengths_nm])
            k = sum(kers)
            K = k.shape[-1]
            if K >= kernel:
                r = (K - kernel) // 2
                k = k[r:r + kernel, r:r + kernel]
            else:
                r = (kernel - K) // 2
                k = torch.nn.functional.pad(k, (r, kernel - K - r, r, kernel - K - r))
            return k, model
        return sum(psf(module.camera, None, (0.0, 0.0), depth_mm, float(w), n_rays, kernel)
                   for w in wavelengths_nm), model


def psfs_figure(modules: dict, depths, kernel: int = 21, n_rays: int = 8192):
    plt = _plt()
    names = list(modules)
    fig, axes = plt.subplots(len(names), len(depths), squeeze=False,
                             figsize=(1.6 * len(depths) + 0.6, 1.6 * len(names) + 0.4), dpi=100)
    models = set()
    for r, v in enumerate(names):
        m = modules[v]
        ch = m.sensor.channels[len(m.sensor.channels) // 2]
        for c, d in enumerate(depths):
            k, model = run_psf(m, d, ch, kernel, n_rays)
            models.add(model)
            ax = axes[r][c]
            ax.imshow((k / k.max()).cpu().numpy(), cmap="inferno", interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(f"{d / 1000:g} m", fontsize=8)
            if c == 0:
                ax.set_ylabel(v, fontsize=8)
    fig.suptitle(f"on-axis PSFs ({' and '.join(sorted(models))}, the run's PSF model), "
                 f"{kernel} x {kernel} sensor pixels", fontsize=9)
    fig.tight_layout()
    return fig


def plates_figure(modules: dict, plate_surface: int):
    plt = _plt()
    names = list(modules)
    fig, axes = plt.subplots(1, len(names), squeeze=False, figsize=(2.6 * len(names), 2.6),
                             dpi=100)
    for c, v in enumerate(names):
        h = surface_height_map(modules[v].lens.surfaces[plate_surface]) * 1e3  # µm
        ax = axes[0][c]
        im = ax.imshow(h.cpu().numpy(), cmap="RdBu_r")
        ax.set_title(v, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, fraction=0.046, label="sag (µm)")
    fig.tight_layout()
    return fig


def samples_figure(modules: dict, datamodules: dict, depths, focus_mm: float):
    """The first test image of each variant through its lens and restorer at the nearest,
    best-focus and farthest depth, as :func:`samples_grid`."""
    show = sorted({min(depths), focus_mm, max(depths)})
    cells = {}
    for v, dm in datamodules.items():
        dm.setup("test")
        img = dm.test_set[0]["image"][None]
        m = modules[v]
        for d in show:
            with torch.no_grad():
                y, gt = m.capture(img, [d], seed=10_000_019, noise=True)
                pred = m(y.to(next(m.restorer.parameters()).device)).clamp(0, 1)
            cells[(v, d)] = (gt[0], y[0], pred[0])
    return samples_grid(cells, list(modules), show)


def samples_grid(cells: dict, variants, depths_mm):
    """A grid with a row per variant: its ground truth, then sensor | restored per depth
    (columns labelled with the depth); ``cells[(variant, depth)] = (gt, sensor, restored)``,
    each ``(C, H, W)`` linear in [0, 1] (shown with a 1/2.2 gamma)."""
    plt = _plt()
    D = len(depths_mm)
    fig, axes = plt.subplots(len(variants), 1 + 2 * D, squeeze=False,
                             figsize=(1.5 * (1 + 2 * D), 1.6 * len(variants) + 0.4), dpi=100)

    def show(ax, t, title=None):
        a = t.detach().float().clamp(0, 1).cpu()
        a = a.expand(3, -1, -1) if a.shape[0] == 1 else a
        ax.imshow(a.permute(1, 2, 0).numpy() ** (1 / 2.2), interpolation="nearest")
        ax.set_xticks([])
        ax.set_yticks([])
        if title:
            ax.set_title(title, fontsize=7)

    for r, v in enumerate(variants):
        for c, d in enumerate(depths_mm):
            gt, y, pred = cells[(v, d)]
            if c == 0:
                show(axes[r][0], gt, "ground truth" if r == 0 else None)
            show(axes[r][1 + 2 * c], y, f"sensor, {d / 1000:g} m" if r == 0 else None)
            show(axes[r][2 + 2 * c], pred, f"restored, {d / 1000:g} m" if r == 0 else None)
        axes[r][0].set_ylabel(v, fontsize=8)
    fig.tight_layout()
    return fig


def write_figures(summary: dict, kept: dict, depths, folder: Path,
                  plate_surface: int | None = None, test_set: str | None = None) -> list[Path]:
    """Write the evaluation figures into ``folder`` and log them to TensorBoard
    (``folder/tensorboard``); returns the PNG paths.

    Args:
        summary: :func:`~deeplens.evaluation.evaluate.summarize`'s result.
        kept: ``{variant: {"module": EndToEndModule, "datamodule": ..., "kind": str}}`` of the
            first seed (its lens and best restorer).
        depths: test depths (mm).
        test_set: what ``summary`` and the ``datamodule``s test on (the PSNR figure's title).
    """
    plt = _plt()
    from torch.utils.tensorboard import SummaryWriter

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    modules = {v: k["module"] for v, k in kept.items()}
    for m in modules.values():
        m.eval()
    first = next(iter(summary.values()))
    rms = first.get("psf_rms_px")
    focus = min(depths, key=lambda d: rms[f"{d:g}"]) if rms else depths[len(depths) // 2]
    figs = {"psnr_vs_depth": psnr_vs_depth_figure(summary, depths, test_set),
            "psfs": psfs_figure(modules, depths),
            "samples": samples_figure(modules, {v: k["datamodule"] for v, k in kept.items()},
                                      depths, focus)}
    if plate_surface is not None:
        figs["plates"] = plates_figure(modules, plate_surface)
    paths = []
    writer = SummaryWriter(str(folder / "tensorboard"))
    try:
        for name, fig in figs.items():
            p = folder / f"{name}.png"
            tmp = folder / f".{name}.tmp.png"
            fig.savefig(tmp)
            tmp.replace(p)
            writer.add_figure(f"eval/{name}", fig, close=False)
            plt.close(fig)
            paths.append(p)
    finally:
        writer.close()
    return paths
