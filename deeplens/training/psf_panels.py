"""Readable PSF panels for TensorBoard: one labelled panel per (depth, field), upsampled.

Each PSF kernel (sensor pixels) is drawn with nearest-neighbour upsampling (a sensor pixel is a
visible square, the axes in µm on the sensor), normalised to the largest value of the grid so
that panels compare (one colour bar for all), and titled with its depth, field and
wavelength.  Rows are depths, columns fields.
"""

from __future__ import annotations

from ..analysis.style import _pyplot

__all__ = ["psf_panels_figure"]


def psf_panels_figure(kernels, depths_mm, fields_deg, wavelength_nm: float,
                      pixel_size_mm: float):
    """A matplotlib figure of ``kernels`` (``len(depths) * len(fields)`` ``(k, k)`` tensors,
    depth-major; an all-zero kernel is drawn as "no PSF") on one colour scale.

    Raises:
        ValueError: the number of kernels is not ``len(depths) * len(fields)``.
    """
    D, F = len(depths_mm), len(fields_deg)
    if len(kernels) != D * F:
        raise ValueError(f"psf_panels_figure: {D} depths x {F} fields need {D * F} kernels, "
                         f"got {len(kernels)}")
    plt = _pyplot()
    vmax = max(float(k.max()) for k in kernels) or 1.0
    fig, axes = plt.subplots(D, F, squeeze=False, figsize=(2.3 * F + 0.9, 2.2 * D + 0.5),
                             dpi=100)
    im = None
    for i, d in enumerate(depths_mm):
        for j, f in enumerate(fields_deg):
            k = kernels[i * F + j].detach().double().cpu()
            ax = axes[i][j]
            h = 0.5 * k.shape[-1] * pixel_size_mm * 1e3
            im = ax.imshow((k / vmax).numpy(), cmap="inferno", interpolation="nearest",
                           vmin=0.0, vmax=1.0, extent=(-h, h, -h, h))
            ax.set_title(f"depth {d / 1000:g} m, field {f:g}°\n{wavelength_nm:g} nm",
                         fontsize=7)
            if not float(k.max()) > 0:
                ax.text(0, 0, "no PSF", color="w", ha="center", va="center", fontsize=7)
            ax.tick_params(labelsize=6)
            if i == D - 1:
                ax.set_xlabel("x (µm)", fontsize=7)
            if j == 0:
                ax.set_ylabel("y (µm)", fontsize=7)
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8,
                 label="PSF / max over the panels")
    return fig
