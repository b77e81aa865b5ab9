"""What a design is worth, and the files a search writes.

:func:`evaluate` reports a lens against a spec on dense rays (``hexapolar:12``, whole traced
pupils, the sensor plane): per field ``f`` and wavelength ``λ`` the RMS radius about the field's
polychromatic centroid, per field the polychromatic RMS spot

    ρ_f = sqrt( sum_λ W_λ ρ_fλ^2 / sum_λ W_λ )

(all rays of all wavelengths, weighted by ``W_λ``, about their common centroid; equal ray counts
per wavelength), the headline ``rms_um = sqrt(sum_f W_f ρ_f^2 / sum_f W_f)``, the paraxial EFL
and F-number, the total track (first vertex to sensor), the back clearance and every
constraint's value and state, and the distortion (percent) at each non-zero field
(:func:`~.imaging.distortion_pct`).  :func:`write_outputs` writes ``best.json`` (a lens file every
command reads), ``result.json`` and, when matplotlib is importable, ``convergence.png`` and
``layout.png``.

A lens file names a glass of the built-in table (:func:`~deeplens.optics.materials.get_material`)
or gives a model glass ``n_d/V_d``; most vendor-catalogue glasses a ``glass_mode="model"``
search puts in (e.g. HOYA's, or 102 of SCHOTT's 123) are not in that table.  Such a glass is
written as the model glass of its ``n_d`` and ``V_d`` (:func:`file_lens`: same index at the d
line and the same Abbe number, Cauchy partial dispersions), and ``result.json`` lists each one
under ``lens_files`` with the RMS spot of the lens as written beside the design's own.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import torch

from ...optics.paraxial import paraxial
from ...optics.io import save_lens
from ...optics.materials import LINE_C, LINE_D, LINE_F, ModelGlass, get_material
from ..constraints import ConstraintSet
from ..merit import SpotMerit
from .imaging import distortion_pct
from .problem import back_clearance, paraxial_footprint, spec_constraints, spot_merit
from .spec import DesignSpec

__all__ = ["evaluate", "write_outputs", "polychromatic_rms", "file_lens"]


def polychromatic_rms(lens, spec: DesignSpec, sampling: str = "hexapolar:12",
                      fields_deg=None) -> tuple[list, list]:
    """``(per field polychromatic RMS (mm), per field and wavelength RMS about the field's
    polychromatic centroid (mm))`` (module docstring); ``fields_deg`` defaults to the spec's."""
    m = SpotMerit(spec.fields_deg, list(spec.wavelengths_nm), weights=spot_merit(spec).weights_in,
                  sampling=sampling, reference="polychromatic", strict_rays=False, shrink=1.0,
                  per_wavelength_pupil=True)
    if fields_deg is not None:
        m.fields = [float(f) for f in fields_deg]
    with torch.no_grad():
        m.prepare(lens)
        rms = m.rms(lens).double().cpu()
    W = torch.tensor(spec.wavelength_weights, dtype=torch.float64)
    poly = torch.sqrt((rms ** 2 * W).sum(1) / W.sum())
    return poly.tolist(), rms.tolist()


def evaluate(lens, spec: DesignSpec, sampling: str = "hexapolar:12") -> dict:
    """The report of the module docstring (a JSON-able dict; lengths in mm, spots in µm)."""
    poly, rms = polychromatic_rms(lens, spec, sampling)
    Wf = spec.weights_of_fields
    total = math.sqrt(sum(w * p * p for w, p in zip(Wf, poly)) / sum(Wf))
    with torch.no_grad():
        p = paraxial(lens)
        track = float(lens.z_sensor() - lens.z_vertices()[0])
        cons = spec_constraints(lens, spec)
        cset = ConstraintSet(cons)
        values = {c.label: float(c.value(lens)) for c in cons}
        broken = cset.broken(lens)
        foot = float(paraxial_footprint(lens, spec.hfov_deg))
        semi = max(float(s.semi_diameter) for s in lens.surfaces)
        nonzero = [f for f in spec.fields_deg if f > 0]
        try:
            dist = [float(v) for v in distortion_pct(lens, nonzero, spec.primary_wavelength_nm)]
        except ValueError:
            dist = None
    return {"rms_um": total * 1e3,
            "rms_poly_um": [x * 1e3 for x in poly],
            "rms_um_per_field_wavelength": [[x * 1e3 for x in row] for row in rms],
            "fields_deg": spec.fields_deg, "wavelengths_nm": list(spec.wavelengths_nm),
            "efl_mm": float(p.efl), "fno": float(p.fno), "epd_mm": float(p.entrance_pupil_diameter),
            "total_track_mm": track, "back_clearance_mm": float(back_clearance(lens)),
            "max_semi_diameter_mm": semi, "paraxial_footprint_mm": foot,
            "constraints": values, "constraints_broken": broken, "feasible": not broken,
            "sampling": sampling,
            "distortion_pct": dist, "distortion_fields_deg": nonzero}


def file_lens(lens) -> tuple[object, dict]:
    """``(lens to write, {medium: {"glass", "written_as"}})``: a copy of ``lens`` in which
    every medium whose file spec (``to_spec()``) does not read back as the same glass (index
    within 1e-7 at the d, F and C lines) is the model glass ``n_d/V_d`` of that medium
    (module docstring); the lens itself when nothing needs replacing."""
    w = torch.tensor([LINE_D, LINE_F, LINE_C], dtype=torch.float64)
    swap = {}
    for i, m in enumerate(lens.materials):
        try:
            same = bool((get_material(m.to_spec()).n(w) - m.n(w)).abs().max() <= 1e-7)
        except (ValueError, TypeError):
            same = False
        if not same:
            swap[i] = ModelGlass(m.nd, m.vd)
    if not swap:
        return lens, {}
    out = copy.deepcopy(lens)
    notes = {}
    for i, g in swap.items():
        m = lens.materials[i]
        label = f"{m.catalogue}:{m.name}" if getattr(m, "catalogue", "") else m.name
        out.materials[i] = g
        notes[str(i)] = {"glass": label, "written_as": g.to_spec()}
    return out, notes


def write_outputs(out, result, spec: DesignSpec) -> dict:
    """Write ``best.json``, ``design_K.json`` (the other kept designs), ``result.json`` and
    the figures (if matplotlib imports) into the folder ``out``; returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths, notes = {}, {}
    for k, d in enumerate(result.designs):
        key = "best" if k == 0 else f"design_{k}"
        path = out / f"{key}.json"
        lens, swapped = file_lens(d.lens)
        save_lens(lens, path)
        paths[key] = str(path)
        if swapped:
            notes[key] = {"glasses_written_as_model": swapped,
                          "rms_um_as_written": evaluate(lens, spec, d.metrics["sampling"])
                          ["rms_um"], "rms_um": d.metrics["rms_um"]}
    data = result.to_dict()
    data["spec"] = spec.to_dict()
    data["files"] = paths
    if notes:
        data["lens_files"] = notes
    (out / "result.json").write_text(json.dumps(data, indent=1), encoding="utf-8")
    paths["result"] = str(out / "result.json")
    figs = _figure(result, out)
    if figs:
        paths["figures"] = figs
    return paths


def _figure(result, out: Path) -> list | None:
    """``convergence.png`` (the merit of every refinement against its accepted steps) and
    ``layout.png`` (the best design with its fields' rays)."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    from ...analysis.plot import layout_figure

    fig, ax = plt.subplots(figsize=(6, 4))
    for run in result.runs:
        if run.get("history"):
            ax.semilogy(run["history"], lw=0.7, alpha=0.7)
    ax.set_xlabel("accepted DLS step (one line per start or hop)")
    ax.set_ylabel("merit sum r^2 (mm^2, its own sampling)")
    ax.set_title("design search convergence")
    fig.tight_layout()
    fig.savefig(out / "convergence.png", dpi=110)
    plt.close(fig)
    paths = [str(out / "convergence.png")]
    if result.designs:
        fig = layout_figure(result.designs[0].lens)
        fig.savefig(out / "layout.png", dpi=110)
        plt.close(fig)
        paths.append(str(out / "layout.png"))
    return paths
