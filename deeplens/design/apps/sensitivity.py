"""Sensitivity matrices of a Cooke triplet (paper Sec. IV-B, Eq. 10, Fig. 12).

The RMS spot ``ε_f`` at three fields (0, 8.3 and 11.86 deg, 587.56 nm, on the sensor plane) is
differentiated by forward-mode AD with respect to every element's decenter ``dx, dy`` (mm), tilt
``tilt_x, tilt_y`` (rad) and every spacing (mm); each entry is checked against a central
difference and against reverse mode (``F`` backward passes).  ``fd_max_rel_err`` is ``max |J_AD - J_FD| / max(|J_FD|, floor)`` with ``floor`` =
1e-3 of the largest entry of the matrix (entries that vanish by symmetry, e.g. ``∂ε/∂dx`` for
fields in the y-z plane, are compared absolutely at that floor).  The lens is W. J. Smith's
Cooke triplet (Modern Optical Engineering, 4th ed., ch. 6), ``data/lenses/cooke_triplet.json``.

    deeplens design sensitivity --json
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import torch

from ...optics.io import load_lens
from ..merit import SpotMerit
from ..sensitivity import finite_difference_matrix, sensitivity_matrix, tolerance_parameters
from . import DATA_DIR


def add_arguments(p) -> None:
    p.add_argument("--lens", default=str(DATA_DIR / "cooke_triplet.json"))
    p.add_argument("--fields", default="0,8.3,11.86", help="degrees")
    p.add_argument("--wavelength", type=float, default=587.5618, help="nm")
    p.add_argument("--sampling", default="hexapolar:8", help="pupil pattern")
    p.add_argument("--kinds", default="decenter,tilt,spacing",
                   help="tolerance kinds: decenter, tilt, spacing, curvature")


def run(args) -> dict:
    lens = load_lens(args.lens).to(torch.float64)
    fields = [float(f) for f in str(args.fields).split(",") if f.strip()]
    kinds = tuple(k.strip() for k in args.kinds.split(",") if k.strip())
    names = tolerance_parameters(lens, kinds)
    sm = SpotMerit(fields, [args.wavelength], sampling=args.sampling, shrink=0.98).prepare(lens)
    t0 = time.perf_counter()
    J = sensitivity_matrix(lens, sm, names)
    t_ad = time.perf_counter() - t0
    t0 = time.perf_counter()
    J_rev = sensitivity_matrix(lens, sm, names, mode="reverse")
    t_rev = time.perf_counter() - t0
    t0 = time.perf_counter()
    FD = finite_difference_matrix(lens, sm, names)
    t_fd = time.perf_counter() - t0
    floor = 1e-3 * float(FD.abs().max())
    rel = (J - FD).abs() / torch.clamp(FD.abs(), min=floor)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    try:
        from ..labels import DISPLAY_PER_UNIT, parameter_label
        from ..plots import heatmap_figure, save

        # one matrix per field as in the paper's figure: rows parameters (human labels, in
        # µm / mrad / 1/m: design.labels), column the merit; one colour scale per unit
        lab = [parameter_label(lens, n) for n in names]
        per = torch.tensor([1e3 / DISPLAY_PER_UNIT[k][1] for _, _, k in lab],
                           dtype=J.dtype)
        mats = [(J[f] * per)[:, None] for f in range(len(fields))]
        files.append(save(heatmap_figure(mats, [f"{t} ({u})" for t, u, _ in lab], ["∂ε/∂θ"],
                                         [f"field {f:g} deg" for f in fields],
                                         "µm of RMS spot per {unit}",
                                         row_units=[u for _, u, _ in lab]),
                          out / "sensitivity.png"))
    except ImportError:
        pass
    result = {"lens": lens.name, "fields_deg": fields, "wavelength_nm": args.wavelength,
              "parameters": names, "units": "mm of RMS spot per mm (decenter, spacing) or per "
                                             "rad (tilt)",
              "rms_um": [float(x) * 1e3 for x in torch.sqrt((sm.rms(lens) ** 2).mean(-1))],
              "jacobian": J.tolist(), "jacobian_fd": FD.tolist(),
              "fd_max_rel_err": float(rel.max()),
              "reverse_max_abs_diff": float((J_rev - J).abs().max()),
              "seconds_ad": t_ad, "seconds_reverse": t_rev, "seconds_fd": t_fd,
              "figures": files}
    (out / "result.json").write_text(json.dumps(result, indent=1))
    return result
