"""The lens report: first-order data plus real-ray spots per field and wavelength.

``lens_report`` returns a JSON-ready dictionary; ``format_report`` renders it as a table.
"""

from __future__ import annotations

import math

import torch

from ..optics.paraxial import paraxial
from .spot import chief_ray, find_pupil, image_plane_z, spot_diagram

__all__ = ["lens_report", "format_report"]


def lens_report(lens, fields_deg=None, wavelengths_nm=None, sampling: str = "hexapolar:18",
                pupil: str = "traced", image_plane: str = "sensor") -> dict:
    """Analyse ``lens`` (float64 recommended).

    Args:
        fields_deg: field angles (deg); default the lens file's.
        wavelengths_nm: wavelengths (nm); default the lens file's.
        sampling: pupil pattern (``hexapolar:R``, ``grid:N``, ``random:N[:SEED]``).
        pupil: ``"traced"`` (paper III-E) or ``"paraxial"`` entrance-pupil sampling.
        image_plane: ``"sensor"`` or ``"paraxial"``.

    Returns:
        ``{"efl_mm", "bfl_mm", "fno", "paraxial_image_distance_mm", "entrance_pupil":
        {"position_mm", "diameter_mm"}, "image_plane": {...}, "sampling", "pupil",
        "fields": [{"field_deg", "wavelength_nm", "rms_spot_um", "chief_ray_height_mm",
        "centroid_mm", "n_rays", "n_launched"}]}``; a fully vignetted field has
        ``rms_spot_um = None`` and ``n_rays = 0``.
    """
    fields = list(lens.spec.fields_deg if fields_deg is None else fields_deg)
    waves = list(lens.spec.wavelengths_nm if wavelengths_nm is None else wavelengths_nm)
    with torch.no_grad():
        p = paraxial(lens)
        z_img = float(image_plane_z(lens, image_plane))
        z_last = float(lens.z_vertices()[-1])
        rows = []
        for w in waves:
            for f in fields:
                row = {"field_deg": float(f), "wavelength_nm": float(w)}
                try:
                    region = find_pupil(lens, f, w, pupil)
                    s = spot_diagram(lens, f, w, sampling, image_plane=z_img, region=region)
                    row.update(rms_spot_um=float(s.rms_radius) * 1e3,
                               centroid_mm=[float(v) for v in s.centroid],
                               n_rays=s.n_rays, n_launched=s.n_launched)
                except ValueError as e:
                    row.update(rms_spot_um=None, centroid_mm=None, n_rays=0, n_launched=0,
                               note=str(e))
                y, _ = chief_ray(lens, f, w, z_img)
                row["chief_ray_height_mm"] = None if math.isnan(float(y)) else float(y)
                rows.append(row)
    return {
        "name": lens.name,
        "efl_mm": float(p.efl),
        "bfl_mm": float(p.bfl),
        "fno": float(p.fno),
        "paraxial_image_distance_mm": float(p.image_distance),
        "primary_wavelength_nm": p.wavelength_nm,
        "entrance_pupil": {"position_mm": float(p.entrance_pupil_position),
                           "diameter_mm": float(p.entrance_pupil_diameter)},
        "image_plane": {"kind": image_plane, "z_mm": z_img,
                        "distance_from_last_vertex_mm": z_img - z_last},
        "sampling": sampling,
        "pupil": pupil,
        "fields": rows,
    }


def format_report(r: dict) -> str:
    """A readable text table of :func:`lens_report`'s dictionary."""
    ep = r["entrance_pupil"]
    lines = [
        f"Lens: {r['name']}",
        f"  EFL {r['efl_mm']:.6g} mm   BFL {r['bfl_mm']:.6g} mm   F/# {r['fno']:.4g}   "
        f"(paraxial, {r['primary_wavelength_nm']:g} nm)",
        f"  entrance pupil: {ep['position_mm']:.6g} mm behind the first vertex, "
        f"diameter {ep['diameter_mm']:.6g} mm",
        f"  image plane: {r['image_plane']['kind']} "
        f"({r['image_plane']['distance_from_last_vertex_mm']:.6g} mm after the last vertex); "
        f"pupil {r['pupil']}, sampling {r['sampling']}",
        "",
        f"  {'field (deg)':>11} {'lambda (nm)':>11} {'RMS spot (um)':>14} {'chief y (mm)':>13} "
        f"{'rays':>11}",
    ]
    for f in r["fields"]:
        rms = "vignetted" if f["rms_spot_um"] is None else f"{f['rms_spot_um']:.4f}"
        cy = "-" if f["chief_ray_height_mm"] is None else f"{f['chief_ray_height_mm']:.5f}"
        lines.append(f"  {f['field_deg']:>11.4g} {f['wavelength_nm']:>11.6g} {rms:>14} {cy:>13} "
                     f"{str(f['n_rays']) + '/' + str(f['n_launched']):>11}")
    return "\n".join(lines)
