"""The lens report: first-order data plus real-ray spots per field and wavelength.

``lens_report`` returns a JSON-ready dictionary; ``format_report`` renders it as a table.
"""

from __future__ import annotations

import math

import torch

from ..optics.camera import unpack
from ..optics.paraxial import paraxial
from ..optics.sampling import DEFAULT_SAMPLING
from .spot import chief_ray, find_pupil, image_plane_z, spot_diagram

__all__ = ["lens_report", "format_report"]


def lens_report(lens, fields_deg=None, wavelengths_nm=None, sampling: str = DEFAULT_SAMPLING,
                pupil: str = "traced", image_plane: str = "sensor", options=None) -> dict:
    """Analyse ``lens`` (float64 recommended).

    Args:
        lens: a Lens (traced with ``options``, ``None``: the defaults) or a
            :class:`~deeplens.optics.camera.Camera` (its options are used by every trace:
            pupil search, spots, chief-ray aiming).
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
        ``rms_spot_um = None`` and ``n_rays = 0``.  An object-space telecentric lens
        (``lens.object_telecentric``) adds ``"object_telecentric": {"object_heights_mm"}``
        (one per field, mm).
    """
    lens, _, options = unpack(lens, None, options, "lens_report")
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
                    region = find_pupil(lens, f, w, pupil, options=options)
                    s = spot_diagram(lens, f, w, sampling, pupil, image_plane=z_img,
                                     region=region, options=options)
                    row.update(rms_spot_um=float(s.rms_radius) * 1e3,
                               centroid_mm=[float(v) for v in s.centroid],
                               n_rays=s.n_rays, n_launched=s.n_launched)
                except ValueError as e:
                    row.update(rms_spot_um=None, centroid_mm=None, n_rays=0, n_launched=0,
                               note=str(e))
                y, _ = chief_ray(lens, f, w, z_img, options=options)
                row["chief_ray_height_mm"] = None if math.isnan(float(y)) else float(y)
                rows.append(row)
    out = {
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
    if getattr(lens, "object_telecentric", False):
        # chief rays parallel to the axis: a field angle is the object point's direction from
        # the first vertex (sampling.field_rays), the object at y = -s tan θ
        s_obj = float(lens.spec.object_distance_mm)
        out["object_telecentric"] = {"object_heights_mm": [
            -s_obj * math.tan(math.radians(float(f))) + 0.0 for f in fields]}
    if getattr(lens, "virtual_image", False):   # a virtual image plane (rays extended back)
        out["image_plane"]["virtual"] = True
    return out


def format_report(r: dict) -> str:
    """A readable text table of :func:`lens_report`'s dictionary."""
    ep = r["entrance_pupil"]
    lines = [
        f"Lens: {r['name']}",
        f"  EFL {r['efl_mm']:.6g} mm   BFL {r['bfl_mm']:.6g} mm   F/# {r['fno']:.4g}   "
        f"(paraxial, {r['primary_wavelength_nm']:g} nm)",
        f"  entrance pupil: {ep['position_mm']:.6g} mm behind the first vertex, "
        f"diameter {ep['diameter_mm']:.6g} mm",
        *([f"  object space telecentric (chief rays parallel to the axis); object heights "
           f"{', '.join(f'{h:.6g}' for h in r['object_telecentric']['object_heights_mm'])} mm "
           f"(field angles: their directions from the first vertex)"]
          if r.get("object_telecentric") else []),
        f"  image plane: {r['image_plane']['kind']}"
        f"{', virtual' if r['image_plane'].get('virtual') else ''} "
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


ANALYSES = ("cardinal", "distortion", "field", "color", "vignetting", "wavefront", "strehl",
            "mtf", "ee")


def _opt(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def analysis_report(lens, kinds, fields_deg=None, wavelengths_nm=None, image_plane="sensor",
                    mtf_freqs=(10.0, 20.0, 40.0, 80.0), options=None) -> dict:
    """The ``--analysis`` part of the report: ``{kind: values}`` for each kind of
    :data:`ANALYSES` asked for (fields in deg, lengths in mm unless named ``_um``, OPD in
    waves at the primary wavelength, MTF at ``mtf_freqs`` cycles/mm).  A diffraction value that
    cannot be computed for a field (a wavefront too steep for the FFT) is ``None`` with a
    ``note``.  ``lens``: a Lens (traced with ``options``) or a
    :class:`~deeplens.optics.camera.Camera` (its options reach every analysis).

    Raises:
        ValueError: an unknown kind (the message lists the known ones).
    """
    from .aberrations import (distortion, field_curvature, lateral_color, longitudinal_color,
                              vignetting)
    from .cardinal import cardinal_points, pupils
    from .checks import AnalysisError
    from .diffraction import encircled_energy, mtf, psf_fft
    from .wavefront import wavefront, zernike_fit

    lens, _, options = unpack(lens, None, options, "analysis_report")
    kinds = list(kinds)
    bad = [k for k in kinds if k not in ANALYSES]
    if bad:
        raise ValueError(f"--analysis: unknown kind(s) {', '.join(bad)}; choose from "
                         f"{','.join(ANALYSES)}")
    fields = [float(f) for f in (lens.spec.fields_deg if fields_deg is None else fields_deg)]
    waves = [float(w) for w in (lens.spec.wavelengths_nm if wavelengths_nm is None
                                else wavelengths_nm)]
    prim = float(lens.spec.primary_wavelength_nm if wavelengths_nm is None else waves[0])
    out = {"wavelength_nm": prim, "image_plane": image_plane if isinstance(image_plane, str)
           else float(image_plane)}
    with torch.no_grad():
        for k in kinds:
            if k == "cardinal":
                out[k] = {**cardinal_points(lens, prim).as_dict(),
                          "pupils": pupils(lens, prim).as_dict()}
            elif k == "distortion":
                d = distortion(lens, fields, prim, image_plane=image_plane, options=options)
                out[k] = {"fields_deg": fields, "percent": [float(v) for v in d],
                          "convention": "f-tan, real chief ray vs paraxial chief ray"}
            elif k == "field":
                zt, zs = field_curvature(lens, fields, prim, image_plane=image_plane,
                                         options=options)
                out[k] = {"fields_deg": fields, "tangential_mm": [float(v) for v in zt],
                          "sagittal_mm": [float(v) for v in zs]}
            elif k == "color":
                wl, lon = longitudinal_color(lens, waves)
                row = {"wavelengths_nm": wl, "longitudinal_mm": [float(v) for v in lon]}
                if len(waves) > 1:
                    lat = lateral_color(lens, fields, waves, image_plane=image_plane,
                                        options=options)
                    row.update(fields_deg=fields, lateral_um=[1e3 * float(v) for v in lat])
                out[k] = row
            elif k == "vignetting":
                v = vignetting(lens, fields, prim, image_plane=image_plane, options=options)
                out[k] = {"fields_deg": fields, "fraction": [float(x) for x in v]}
            elif k == "wavefront":
                rows = []
                for f in fields:
                    w = wavefront(lens, f, prim, n=64, image_plane=image_plane,
                                  options=options)
                    z = zernike_fit(w, 9, "fringe")
                    rows.append({"field_deg": f, "rms_waves": float(w.rms),
                                 "pv_waves": float(w.pv),
                                 "zernike_fringe_1_9_waves": [float(c) for c in z.coefficients]})
                out[k] = rows
            elif k == "strehl":
                rows = []
                for f in fields:
                    try:
                        st = float(psf_fft(lens, f, prim, image_plane=image_plane,
                                             options=options).strehl)
                    except AnalysisError as e:
                        rows.append({"field_deg": f, "strehl": None, "note": str(e)})
                        continue
                    rows.append({"field_deg": f, "strehl": st})
                out[k] = rows
            elif k == "mtf":
                rows = []
                for f in fields:
                    try:
                        m = mtf(lens, f, prim, image_plane=image_plane, options=options)
                    except AnalysisError as e:
                        rows.append({"field_deg": f, "freq_cycles_per_mm": None,
                                     "tangential": None, "sagittal": None, "note": str(e)})
                        continue
                    vals = [m.at(nu) for nu in mtf_freqs]
                    rows.append({"field_deg": f, "freq_cycles_per_mm": list(map(float, mtf_freqs)),
                                 "tangential": [t for t, _ in vals],
                                 "sagittal": [s for _, s in vals]})
                out[k] = rows
            elif k == "ee":
                rows = []
                fno = float(pupils(lens, prim).working_fno)
                r = torch.linspace(0, 20 * 1.22 * prim * 1e-6 * fno, 201, dtype=torch.float64,
                                   device=lens.device)
                for f in fields:
                    try:
                        ee = encircled_energy(lens, f, r, prim, image_plane=image_plane,
                                              options=options)
                    except AnalysisError as e:
                        rows.append({"field_deg": f, "r80_um": None, "note": str(e)})
                        continue
                    i = int(torch.searchsorted(ee.contiguous(),
                                               torch.tensor([0.8], dtype=ee.dtype)))
                    r80 = None
                    if 0 < i < len(r):
                        a = (0.8 - float(ee[i - 1])) / max(float(ee[i] - ee[i - 1]), 1e-30)
                        r80 = 1e3 * float(r[i - 1] + a * (r[i] - r[i - 1]))
                    row = {"field_deg": f, "r80_um": _opt(r80)}
                    if r80 is None:
                        row["note"] = (f"80 % of the energy lies beyond {1e3 * float(r[-1]):.4g} "
                                       f"um (20 Airy radii)")
                    rows.append(row)
                out[k] = rows
    return out


def format_analysis(a: dict) -> str:
    """A short text summary of :func:`analysis_report`'s dictionary."""
    lines = [f"Analysis at {a['wavelength_nm']:g} nm, image plane {a['image_plane']}:"]
    if "cardinal" in a:
        c = a["cardinal"]
        lines.append(f"  EFL {c['efl']:.6g} mm; principal planes z = {c['front_principal_z']:.6g}, "
                     f"{c['rear_principal_z']:.6g} mm; nodal {c['front_nodal_z']:.6g}, "
                     f"{c['rear_nodal_z']:.6g} mm; exit pupil z = {c['pupils']['exit_z']:.6g} mm, "
                     f"D = {c['pupils']['exit_diameter']:.6g} mm")
    if "distortion" in a:
        d = a["distortion"]
        lines.append("  distortion (%): " + ", ".join(
            f"{f:g} deg {v:+.4f}" for f, v in zip(d["fields_deg"], d["percent"])))
    if "field" in a:
        d = a["field"]
        lines.append("  field curvature T/S (mm): " + ", ".join(
            f"{f:g} deg {t:+.4f}/{s:+.4f}" for f, t, s in
            zip(d["fields_deg"], d["tangential_mm"], d["sagittal_mm"])))
    if "color" in a:
        d = a["color"]
        lines.append("  longitudinal colour (mm): " + ", ".join(
            f"{w:g} nm {v:+.4f}" for w, v in zip(d["wavelengths_nm"], d["longitudinal_mm"])))
        if "lateral_um" in d:
            lines.append("  lateral colour (um): " + ", ".join(
                f"{f:g} deg {v:+.3f}" for f, v in zip(d["fields_deg"], d["lateral_um"])))
    if "vignetting" in a:
        d = a["vignetting"]
        lines.append("  vignetting: " + ", ".join(
            f"{f:g} deg {v:.3f}" for f, v in zip(d["fields_deg"], d["fraction"])))
    if "wavefront" in a:
        lines.append("  wavefront RMS/PV (waves): " + ", ".join(
            f"{r['field_deg']:g} deg {r['rms_waves']:.4f}/{r['pv_waves']:.3f}"
            for r in a["wavefront"]))
    if "strehl" in a:
        lines.append("  Strehl: " + ", ".join(
            f"{r['field_deg']:g} deg " + ("-" if r["strehl"] is None else f"{r['strehl']:.4f}")
            for r in a["strehl"]))
    if "mtf" in a:
        for r in a["mtf"]:
            if r["tangential"] is None:
                lines.append(f"  MTF {r['field_deg']:g} deg: - ({r['note']})")
                continue
            lines.append(f"  MTF {r['field_deg']:g} deg T/S: " + ", ".join(
                f"{nu:g}/mm {t:.3f}/{s:.3f}" for nu, t, s in
                zip(r["freq_cycles_per_mm"], r["tangential"], r["sagittal"])))
    if "ee" in a:
        lines.append("  80% encircled-energy radius (um): " + ", ".join(
            f"{r['field_deg']:g} deg " + ("-" if r["r80_um"] is None else f"{r['r80_um']:.3f}")
            for r in a["ee"]))
    return "\n".join(lines)
