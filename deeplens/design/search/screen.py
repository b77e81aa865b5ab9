"""The search's start hook for the third-order screen (``SearchConfig.seidel_screen``).

:func:`screened_starts` joins the screen of thin systems (:func:`~.seidel.seidel_screen`), their
thickening (:func:`~.start.thick_lens`), the optional third-order re-balancing of the thick
lenses (:func:`~.thick_polish.rebalance_thick`) and the ranking by the thick lens's own
third-order RMS.  It lives apart from :mod:`.seidel` (the sums and the screen) and
:mod:`.thick_polish` (which uses them), so that neither imports the other back.
"""

from __future__ import annotations

import math
import time

from .seidel import _weights_with_primary, lens_system, seidel_screen, third_order_rms
from .spec import DesignSpec
from .start import StartError, thick_lens
from .thick_polish import rebalance_thick

__all__ = ["screened_starts"]


def screened_starts(spec: DesignSpec, points: int, starts: int, seed: int = 0,
                    steps: int = 100, glass_strategy=None,
                    rebalance: int = 0, rebalance_floor: str = "thin") -> tuple[list, dict]:
    """The search's hook (:class:`~.multistart.SearchConfig` ``seidel_screen``): the
    :func:`seidel_screen` of ``points`` Sobol points keeps ``4 starts`` distinct thin
    systems; each is thickened (:func:`~.start.thick_lens`, focal length exact; those that
    give no lens are skipped) and the thick lenses are ranked again by their own third-order
    RMS (:func:`lens_system`, :func:`third_order_rms`): the best ``starts`` are returned.

    ``rebalance > 0``: before that ranking every thick lens gets ``rebalance`` batched Adam
    steps on its own third-order merit (:func:`~.thick_polish.rebalance_thick`); with
    ``rebalance_floor="thin"`` nothing is gained below its thin system's third-order RMS
    (``"none"``: no floor).

    ``glass_strategy`` is not supported here (the screen picks glasses as
    :func:`~.start.crown_flint_by_sign` does); passing one raises ``ValueError``.

    Returns:
        ``([(label, lens)], info)``: the starts, best first, and a record (points sampled,
        thin and thick third-order RMS of each kept start in µm, seconds).
    """
    if glass_strategy is not None:
        raise ValueError("seidel_screen: a glass_strategy is not supported by the third-order "
                         "screen (it picks glasses by sign, as crown_flint_by_sign does)")
    t0 = time.perf_counter()
    scr = seidel_screen(spec, points, keep=4 * int(starts), seed=seed, steps=steps)
    ff = [x / spec.hfov_deg if spec.hfov_deg else 0.0 for x in spec.fields_deg]
    cands, failed = [], 0
    for j, (tl, rms) in enumerate(zip(scr.starts, scr.rms_um)):
        try:
            lens = thick_lens(tl, spec)
            t3 = float(third_order_rms(lens_system(lens, spec.wavelengths_nm), spec.epd,
                                       spec.hfov_deg, ff, spec.weights_of_fields,
                                       _weights_with_primary(spec)))
        except (StartError, ValueError):
            failed += 1
            continue
        if math.isfinite(t3):
            cands.append((t3, j, rms, lens))
    if rebalance > 0 and cands:
        floors = [c[2] for c in cands] if rebalance_floor == "thin" else None
        new, _, _ = rebalance_thick([c[3] for c in cands], spec, steps=int(rebalance),
                                    floors=floors)
        again = []
        for (_, j, rms, _), lens in zip(cands, new):
            t3 = float(third_order_rms(lens_system(lens, spec.wavelengths_nm), spec.epd,
                                       spec.hfov_deg, ff, spec.weights_of_fields,
                                       _weights_with_primary(spec)))
            if math.isfinite(t3):
                again.append((t3, j, rms, lens))
        cands = again
    cands.sort(key=lambda c: (c[0], c[1]))
    out = [(f"seidel {j} ({tl_rms:.0f}/{t3:.0f} um)", lens)
           for t3, j, tl_rms, lens in cands[:int(starts)]]
    info = {"origin": "seidel screen", "ok": bool(out), "reason": "" if out else
            "no screened system gave a lens", "sampled": scr.sampled, "steps": int(steps),
            "thin_rms_um": [c[2] for c in cands[:int(starts)]],
            "thick_rms_um": [c[0] for c in cands[:int(starts)]], "thickening_failed": failed,
            "rebalance": int(rebalance), "rebalance_floor": rebalance_floor, "seconds": time.perf_counter() - t0}
    return out, info
