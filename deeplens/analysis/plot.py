"""Plots (matplotlib, imported lazily): lens layout with traced rays, spot diagrams."""

from __future__ import annotations


import torch

from ..optics.sampling import field_rays
from ..optics.paraxial import paraxial

__all__ = ["layout_figure"]


def layout_figure(lens, fields_deg=None, n_rays: int = 7, wavelength_nm: float | None = None):
    """A y-z section of ``lens`` with meridional rays of each field; returns a matplotlib Figure."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fields = list(lens.spec.fields_deg if fields_deg is None else fields_deg)
    w = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    fig, ax = plt.subplots(figsize=(8, 4), dpi=80)
    with torch.no_grad():
        dtype = lens.dtype
        z = lens.z_vertices().double().cpu()
        for i, s in enumerate(lens.surfaces):
            R = float(s.semi_diameter)
            y = torch.linspace(-R, R, 101, dtype=dtype)
            zero = torch.zeros_like(y)
            sag = torch.where(s.in_domain(zero, y), s.sag(zero, y), zero) if hasattr(s, "sag") \
                else zero
            if getattr(s, "type_name", "") == "aperture":
                ax.plot([float(z[i])] * 2, [R, R * 1.3], "k-", lw=2)
                ax.plot([float(z[i])] * 2, [-R, -R * 1.3], "k-", lw=2)
            else:
                ax.plot((z[i] + sag.double()).numpy(), y.double().numpy(), "k-", lw=1)
        zs = float(lens.z_sensor())
        h = lens.sensor_semi_diameter or float(max(s.semi_diameter for s in lens.surfaces))
        ax.plot([zs, zs], [-h, h], "b-", lw=2)
        p = paraxial(lens, w)
        r_ep = 0.5 * float(p.entrance_pupil_diameter)
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for k, f in enumerate(fields):
            ys = torch.linspace(-r_ep, r_ep, n_rays, dtype=dtype)
            xy = torch.stack([torch.zeros_like(ys), ys], -1)
            rays = field_rays(lens, f, w, xy, float(p.entrance_pupil_z))
            out, hits = lens.trace(rays, record=True)
            end = lens.propagate_to_z(out, lens.z_sensor())
            pts = [rays.o] + hits + [end.o]
            ok = end.valid
            for r in range(n_rays):
                if not bool(ok[r]):
                    continue
                zz = [float(q[r, 2]) for q in pts]
                yy = [float(q[r, 1]) for q in pts]
                ax.plot(zz, yy, "-", color=colors[k % len(colors)], lw=0.6)
    ax.set_aspect("equal")
    ax.set_xlabel("z (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(lens.name[:80] or "lens", fontsize=8)
    fig.tight_layout()
    return fig
