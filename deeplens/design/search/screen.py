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

import torch

from .seidel import _weights_with_primary, lens_system, seidel_screen, third_order_rms
from .spec import DesignSpec
from .start import StartError, thick_lens
from .thick_polish import rebalance_thick

__all__ = ["screened_starts", "union_of_rankings", "RANKINGS"]


RANKINGS = ("union", "rebalanced")


def _same_start(a, b) -> bool:
    """Two thick lenses with the same curvatures and distances (bit for bit): the same start."""
    return a is b or (len(a.surfaces) == len(b.surfaces) and all(
        torch.equal(sa.c, sb.c) for sa, sb in zip(a.surfaces, b.surfaces) if hasattr(sa, "c")
        and hasattr(sb, "c")) and all(torch.equal(torch.as_tensor(x), torch.as_tensor(y))
                                      for x, y in zip(a.distances, b.distances)))


def union_of_rankings(plain: list, rebalanced: list, starts: int, same=_same_start) -> list:
    """The start list of ``ranking="union"``: the best ``starts`` of each ranking, each start
    once.

    Args:
        plain: ``[(t3, j, thin_rms, lens)]`` the thickened starts, sorted best first.
        rebalanced: the same for the re-balanced starts (may be empty).
        starts: how many of each list.
        same: ``same(lens_a, lens_b)``: whether two starts are one (default: equal
            curvatures and distances; a start whose re-balancing found nothing is its plain
            lens itself).

    Returns:
        ``[(t3, j, thin_rms, lens, kind)]``, ``kind`` ``"plain"`` or ``"rebalanced"``: the two
        lists interleaved best first (re-balanced, plain, re-balanced, ...), a start already
        taken from the other list skipped (not replaced), so that with one list empty it is
        the other's best ``starts``, in its order.
    """
    k = int(starts)
    out = []
    tops = [[(*c, "rebalanced") for c in rebalanced[:k]], [(*c, "plain") for c in plain[:k]]]
    for i in range(k):
        for top in tops:
            if i < len(top) and not any(same(top[i][3], o[3]) for o in out):
                out.append(top[i])
    return out


def screened_starts(spec: DesignSpec, points: int, starts: int, seed: int = 0,
                    steps: int = 100, glass_strategy=None,
                    rebalance: int = 0, rebalance_floor: str = "thin",
                    ranking: str = "union") -> tuple[list, dict]:
    """The search's hook (:class:`~.multistart.SearchConfig` ``seidel_screen``): the
    :func:`seidel_screen` of ``points`` Sobol points keeps ``4 starts`` distinct thin
    systems; each is thickened (:func:`~.start.thick_lens`, focal length exact; those that
    give no lens are skipped) and the thick lenses are ranked again by their own third-order
    RMS (:func:`lens_system`, :func:`third_order_rms`): the best ``starts`` are returned.

    ``rebalance > 0``: every thick lens also gets ``rebalance`` batched Adam steps on its own
    third-order merit (:func:`~.thick_polish.rebalance_thick`); with
    ``rebalance_floor="thin"`` nothing is gained below its thin system's third-order RMS
    (``"none"``: no floor).  ``ranking="rebalanced"``: the re-balanced lenses alone are
    ranked and the best ``starts`` returned; ``"union"`` (default): the best ``starts`` of
    the plain ranking *and* the best ``starts`` of the re-balanced ranking, each start once
    (:func:`union_of_rankings`; up to ``2 starts`` starts), because re-balancing moves the
    starts that a spec's best design comes from to the top for one spec (the Cooke
    triplet) and off the top for another (the double Gauss).  Without re-balancing both
    rankings give the plain one.

    ``glass_strategy`` is not supported here (the screen picks glasses as
    :func:`~.start.crown_flint_by_sign` does); passing one raises ``ValueError``.

    Returns:
        ``([(label, lens)], info)``: the starts (re-balanced first, then plain, alternately,
        each best first) and a record (points sampled, thin and thick third-order RMS of
        each start in µm and its ranking, seconds).
    """
    if glass_strategy is not None:
        raise ValueError("seidel_screen: a glass_strategy is not supported by the third-order "
                         "screen (it picks glasses by sign, as crown_flint_by_sign does)")
    if ranking not in RANKINGS:
        raise ValueError(f"screened_starts: ranking must be one of {', '.join(RANKINGS)}, got "
                         f"{ranking!r}")
    t0 = time.perf_counter()
    scr = seidel_screen(spec, points, keep=4 * int(starts), seed=seed, steps=steps)
    ff = [x / spec.hfov_deg if spec.hfov_deg else 0.0 for x in spec.fields_deg]

    def t3_of(lens):
        return float(third_order_rms(lens_system(lens, spec.wavelengths_nm), spec.epd,
                                     spec.hfov_deg, ff, spec.weights_of_fields,
                                     _weights_with_primary(spec)))

    cands, failed = [], 0
    for j, (tl, rms) in enumerate(zip(scr.starts, scr.rms_um)):
        try:
            lens = thick_lens(tl, spec)
            t3 = t3_of(lens)
        except (StartError, ValueError):
            failed += 1
            continue
        if math.isfinite(t3):
            cands.append((t3, j, rms, lens))
    again = []
    if rebalance > 0 and cands:
        floors = [c[2] for c in cands] if rebalance_floor == "thin" else None
        new, _, _ = rebalance_thick([c[3] for c in cands], spec, steps=int(rebalance),
                                    floors=floors)
        for (_, j, rms, _), lens in zip(cands, new):
            t3 = t3_of(lens)
            if math.isfinite(t3):
                again.append((t3, j, rms, lens))

    def key(c):
        return (c[0], c[1])

    cands.sort(key=key)
    again.sort(key=key)
    if rebalance > 0 and ranking == "rebalanced":
        chosen = [(*c, "rebalanced") for c in again[:int(starts)]]
    else:
        chosen = union_of_rankings(cands, again, starts)
        plain_lenses = [c[3] for c in cands]
        # a start the re-balancing left as it was (its plain lens itself) is a plain start
        chosen = [c if not any(c[3] is L for L in plain_lenses) else (*c[:4], "plain")
                  for c in chosen]
    out = [(f"seidel {j} ({tl_rms:.0f}/{t3:.0f} um{', re-balanced' if kind == 'rebalanced' else ''})",
            lens) for t3, j, tl_rms, lens, kind in chosen]
    info = {"origin": "seidel screen", "ok": bool(out), "reason": "" if out else
            "no screened system gave a lens", "sampled": scr.sampled, "steps": int(steps),
            "thin_rms_um": [c[2] for c in chosen], "thick_rms_um": [c[0] for c in chosen],
            "ranked": [c[4] for c in chosen], "index": [c[1] for c in chosen],
            "thickening_failed": failed, "rebalance": int(rebalance),
            "rebalance_floor": rebalance_floor, "ranking": ranking,
            "seconds": time.perf_counter() - t0}
    return out, info
