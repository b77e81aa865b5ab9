r"""Third-order re-balancing of thickened starts (``SearchConfig.seidel_thick_steps``).

The third-order screen (:mod:`.seidel`) balances *thin* systems; :func:`~.start.thick_lens`
then gives each element the glass its aperture needs and re-solves the last curvature for
the focal length.  For strongly powered elements that breaks the balance: on the Cooke
triplet spec (seed 0) the screen's best thin systems, the classical Cooke structure
(``f φ ≈ +2, -4, +2.5``, spacings ``≈ 0.08-0.15 f``) at 41-42 µm of third-order RMS, came out
at 62-145 µm once thickened, behind weakly powered systems (``f φ ≈ +1.2, -0.7, +0.7``, long
gaps) that the thickening hardly changes (67 -> 68 µm); the search then refined the weak ones,
which end in a ~50 µm basin, while the Cooke structure's basin holds 19 µm designs.

Here every thickened start is re-balanced on the same third-order merit, in a batch (one
:class:`~.seidel.ParaxialSystem` per surface layout), before the starts are ranked:

* **variables**: every refracting surface's curvature (``c f``) and every distance after the
  first surface (``log(d / f)``: glass, air and the stop's place in its gap);
* **focal length exact** by scaling: each trial system is scaled by ``σ = f / EFL``
  (``c -> c / σ``, ``d -> σ d``), as the thin screen scales its systems;
* **merit** ``log(1 + RMS₃) + 10 P``: the third-order polychromatic RMS spot
  (:func:`~.seidel.third_order_rms`, refocused) and the squared relative shortfalls ``P`` of
  what a real lens needs (:func:`thick_penalty`: ``|c| h <= 0.8``, centre and edge of glass
  and air at the paraxial beam's height ``h = 1.08 (|y| + |ȳ|) + 0.2``, centre glass within
  ``max_center_glass``, the stop plane clear of the surfaces beside it at its rim (the
  search's ``stop_gap`` constraints, :mod:`.imaging`), a real image at least ``0.05 f``
  behind the last surface, the track);
* ``steps`` Adam steps; each system keeps the iterate of lowest merit among those with
  ``P <= 1e-6`` (else its start).

The re-balanced systems are written back into copies of the lenses (curvatures, distances,
semi-diameters from the same beam heights, the angle solve for the exact EFL, the sensor on
the paraxial image); a copy that is no valid lens is replaced by its start.
"""

from __future__ import annotations

import copy
import math

import torch

from .seidel import ParaxialSystem, lens_system, paraxial_rays, third_order_rms
from .spec import DesignSpec

__all__ = ["thick_penalty", "rebalance_thick"]

_FEASIBLE = 1e-6


def _sag(c, h):
    x = (c * h).clamp(-0.999, 0.999)
    return c * h * h / (1 + torch.sqrt(1 - x * x))


def thick_penalty(sys: ParaxialSystem, refracting: torch.Tensor, spec: DesignSpec) -> torch.Tensor:
    """The squared relative shortfalls ``P`` (module docstring) of thick systems, ``(B,)``.

    Args:
        sys: the systems (the focal length already the spec's).
        refracting: ``(S,)`` bool, the surfaces that are not the stop.
        spec: the limits (``min_center_glass_mm``, ``min_edge_glass_mm``, ``min_air_mm``,
            ``max_center_glass_mm``, ``max_track_mm``) and ``efl_mm``, ``epd``, ``hfov_deg``.
    """
    f = float(spec.efl_mm)
    y, u, yb, ub = paraxial_rays(sys, spec.epd, spec.hfov_deg)
    h = 1.08 * (y.abs() + yb.abs()) + 0.2                                    # (B, S)
    r = torch.relu
    idx = torch.nonzero(refracting).flatten().tolist()
    c = sys.c
    pen = (r(c[:, idx].abs() * h[:, idx] - 0.8) ** 2).sum(1) * 10
    n = sys.n[:, sys.primary]                                                # (B, S + 1)
    zc = torch.cumsum(torch.cat([torch.zeros_like(sys.d[:, :1]), sys.d[:, 1:]], 1), 1)
    min_c = float(spec.min_center_glass_mm or 0.0)
    min_e = float(spec.min_edge_glass_mm or 0.0)
    min_air = float(spec.min_air_mm or 0.0)
    for p, q in zip(idx, idx[1:]):
        glass = n[:, p + 1] > 1.0 + 1e-9
        centre = zc[:, q] - zc[:, p]
        hh = torch.minimum(h[:, p], h[:, q])
        edge = centre + _sag(c[:, q], hh) - _sag(c[:, p], hh)
        need_c = torch.where(glass, torch.full_like(centre, min_c), torch.full_like(centre,
                                                                                    min_air))
        need_e = torch.where(glass, torch.full_like(centre, min_e), torch.full_like(centre,
                                                                                    min_air))
        pen = pen + ((r(need_c - centre) / f) ** 2 + (r(need_e - edge) / f) ** 2) * 100
        if spec.max_center_glass_mm is not None:
            pen = pen + torch.where(glass, (r(centre - float(spec.max_center_glass_mm)) / f)
                                    ** 2, torch.zeros_like(centre)) * 100
    st = int(sys.stop)
    if st not in idx:   # the stop plane clear of its neighbours at its rim (imaging.py)
        rs = y[:, st].abs()
        prev = [j for j in idx if j < st]
        nxt = [j for j in idx if j > st]
        if prev:
            gap = zc[:, st] - zc[:, prev[-1]] - _sag(c[:, prev[-1]], rs)
            pen = pen + (r(-gap) / f) ** 2 * 100
        if nxt:
            gap = zc[:, nxt[0]] + _sag(c[:, nxt[0]], rs) - zc[:, st]
            pen = pen + (r(-gap) / f) ** 2 * 100
    bfl = -y[:, -1] / u[:, -1]
    pen = pen + (r(0.05 * f - bfl) / f) ** 2 * 100
    if spec.max_track_mm is not None:
        track = zc[:, -1] + bfl
        pen = pen + (r(track - float(spec.max_track_mm)) / f) ** 2 * 100
    return pen


def _efl(sys: ParaxialSystem) -> torch.Tensor:
    """Paraxial focal length ``(B,)`` (mm; ``-1 / (n' u')`` of a unit-height ray)."""
    n = sys.n[:, sys.primary]
    y = torch.ones_like(n[:, 0])
    u = torch.zeros_like(y)
    for j in range(sys.c.shape[1]):
        if j > 0:
            y = y + sys.d[:, j] * u
        u = (n[:, j] * u - y * sys.c[:, j] * (n[:, j + 1] - n[:, j])) / n[:, j + 1]
    return -1.0 / (n[:, -1] * u)


def _rebalance_batch(systems: list, refracting: torch.Tensor, spec: DesignSpec, steps: int,
                     lr: float, weights_w: list, floor: torch.Tensor | None = None) -> tuple:
    """Adam on a batch of systems of one layout; ``(c, d, rms_before, rms_after)`` with
    ``c``, ``d`` ``(B, S)`` of the best feasible iterate (or the start)."""
    f = float(spec.efl_mm)
    ff = [x / spec.hfov_deg if spec.hfov_deg else 0.0 for x in spec.fields_deg]
    fw = spec.weights_of_fields
    c0 = torch.cat([s.c for s in systems])
    d0 = torch.cat([s.d for s in systems])
    n = torch.cat([s.n for s in systems])
    stop, primary = systems[0].stop, systems[0].primary
    live = torch.zeros_like(d0, dtype=torch.bool)
    live[:, 1:] = d0[:, 1:] > 0                 # a distance of exactly 0 stays 0
    xc = (c0 * f).clone().requires_grad_(True)
    xd = torch.log(torch.where(live, d0, torch.ones_like(d0)) / f).clone().requires_grad_(True)
    mask_c = refracting.to(c0.dtype)[None]

    def build(xc, xd):
        c = xc * mask_c / f
        d = torch.where(live, f * torch.exp(xd), torch.zeros_like(xd))
        sys = ParaxialSystem(c, d, n, stop, primary)
        s = f / _efl(sys)
        ok = torch.isfinite(s) & (s > 0)
        s = torch.where(ok, s, torch.ones_like(s))
        return ParaxialSystem(c / s[:, None], d * s[:, None], n, stop, primary), ok

    def merit(xc, xd):
        sys, ok = build(xc, xd)
        rms = third_order_rms(sys, spec.epd, spec.hfov_deg, ff, fw, weights_w)
        pen = thick_penalty(sys, refracting, spec)
        good = ok & torch.isfinite(rms) & torch.isfinite(pen)
        r = rms if floor is None else torch.maximum(rms, floor)   # no gain below the floor
        loss = torch.where(good, torch.log1p(r) + 10 * pen, torch.full_like(rms, math.inf))
        return loss, rms, pen, sys

    with torch.no_grad():
        loss, rms0, pen0, sys = merit(xc, xd)
    best = torch.where(pen0 <= _FEASIBLE, loss, torch.full_like(loss, math.inf))
    best_c, best_d = sys.c.clone(), sys.d.clone()
    start_c, start_d = sys.c.clone(), sys.d.clone()
    params = [xc, xd]
    mom = [torch.zeros_like(v) for v in params]
    sq = [torch.zeros_like(v) for v in params]
    for it in range(int(steps)):   # Adam by hand, as the thin screen (seidel.py) does
        loss, _, _, _ = merit(xc, xd)
        g = torch.autograd.grad(torch.where(torch.isfinite(loss), loss,
                                            torch.zeros_like(loss)).sum(), params)
        with torch.no_grad():
            for v, gi, m1, m2 in zip(params, g, mom, sq):
                gi = gi.nan_to_num(0.0, 0.0, 0.0)
                m1.mul_(0.9).add_(0.1 * gi)
                m2.mul_(0.999).add_(0.001 * gi * gi)
                v.sub_(lr * (m1 / (1 - 0.9 ** (it + 1)))
                       / (torch.sqrt(m2 / (1 - 0.999 ** (it + 1))) + 1e-8))
            loss, _, pen, sys = merit(xc, xd)
            better = (pen <= _FEASIBLE) & (loss < best)
            best = torch.where(better, loss, best)
            best_c = torch.where(better[:, None], sys.c, best_c)
            best_d = torch.where(better[:, None], sys.d, best_d)
    found = torch.isfinite(best)
    out_c = torch.where(found[:, None], best_c, start_c)
    out_d = torch.where(found[:, None], best_d, start_d)
    with torch.no_grad():
        rms1 = third_order_rms(ParaxialSystem(out_c, out_d, n, stop, primary), spec.epd,
                               spec.hfov_deg, ff, fw, weights_w)
    return out_c, out_d, rms0, rms1, found


def _write_back(lens, c, d, spec: DesignSpec, sys: ParaxialSystem):
    """A copy of ``lens`` with curvatures ``c`` and distances ``d`` (``(S,)``), semi-diameters
    from the paraxial beam, the exact EFL and the sensor on the image; ``None`` if that is not
    a valid lens."""
    from ...optics.surfaces import Aperture
    from .imaging import repair_stop_gaps
    from .start import StartError, place_sensor, solve_efl

    L = copy.deepcopy(lens)
    y, _, yb, _ = paraxial_rays(sys, spec.epd, spec.hfov_deg)
    h = (1.08 * (y.abs() + yb.abs()) + 0.2)[0]
    try:
        with torch.no_grad():
            for j, s in enumerate(L.surfaces):
                if j > 0:
                    L.distances[j].fill_(float(d[j]))
                if isinstance(s, Aperture):
                    continue
                s.c.fill_(float(c[j]))
                cj = abs(float(c[j]))
                s.semi_diameter.fill_(min(float(h[j]), 0.95 / cj) if cj > 0 else float(h[j]))
        solve_efl(L, spec.efl_mm)
        L.apply_aperture_spec()
        repair_stop_gaps(L)   # what the penalty's feasibility tolerance left
        place_sensor(L)
        L.check()
    except (StartError, ValueError, RuntimeError):
        return None
    return L


def rebalance_thick(lenses: list, spec: DesignSpec, steps: int = 100, lr: float = 0.02,
                    floors: list | None = None) -> tuple[list, list, list]:
    """Re-balance thickened starts on their third-order merit (module docstring).

    Args:
        lenses: spherical lenses of the spec (float64; e.g. :func:`~.start.thick_lens`'s),
            not modified.
        spec: the spec (object at infinity).
        steps: Adam steps (0: the lenses are returned as they are, their RMS as NaN).
        lr: Adam's step (the variables ``c f`` and ``log(d / f)`` are of order one).
        floors: per lens a third-order RMS (µm) below which nothing is gained (the merit is
            ``log(1 + max(RMS₃, floor)) + 10 P``): e.g. the thin system's own, so that the
            re-balancing undoes what the thickening upset without pushing the third order
            further than the screen did (``None``: no floor).

    Returns:
        ``(lenses, rms_before, rms_after)``: new lenses (a lens that could not be re-balanced
        into a valid lens is the input lens itself) and each one's third-order RMS (µm)
        before and after.

    Raises:
        ValueError: an object at a finite distance, or a lens with conic or aspheric terms
            (:func:`~.seidel.lens_system`).
    """
    from .seidel import _weights_with_primary

    if not math.isinf(spec.object_distance_mm):
        raise ValueError("rebalance_thick: supports an object at infinity only "
                         "(spec.object_distance_mm is finite)")
    from ...optics.surfaces import Aperture

    if int(steps) <= 0:
        return list(lenses), [math.nan] * len(lenses), [math.nan] * len(lenses)
    systems = [lens_system(L, spec.wavelengths_nm) for L in lenses]
    ww = _weights_with_primary(spec)
    out = list(lenses)
    before = [math.nan] * len(lenses)
    after = [math.nan] * len(lenses)
    groups: dict = {}
    for i, (L, s) in enumerate(zip(lenses, systems)):
        key = (s.c.shape[1], s.stop, s.primary,
               tuple(isinstance(x, Aperture) for x in L.surfaces))
        groups.setdefault(key, []).append(i)
    for key, idx in groups.items():
        refracting = torch.tensor([not a for a in key[3]])
        fl = None if floors is None else torch.tensor([float(floors[i]) for i in idx],
                                                      dtype=torch.float64)
        c, d, r0, r1, found = _rebalance_batch([systems[i] for i in idx], refracting, spec,
                                               steps, lr, ww, fl)
        for k, i in enumerate(idx):
            before[i] = after[i] = float(r0[k])
            if not bool(found[k]):
                continue
            n = systems[i].n
            sys = ParaxialSystem(c[k:k + 1], d[k:k + 1], n, systems[i].stop,
                                 systems[i].primary)
            L = _write_back(lenses[i], c[k], d[k], spec, sys)
            if L is not None:
                out[i], after[i] = L, float(r1[k])
    return out, before, after
