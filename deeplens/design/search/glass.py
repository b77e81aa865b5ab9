r"""Glass choice for a design search: model glasses while optimising, real glasses after.

1. **Model glasses as variables.**  :class:`TrainableModelGlass` is a model glass with ``n_d``
   and ``V_d`` as parameters, with one of two dispersion laws (λ in µm)::

       "cauchy"  n(λ) = A + B / λ²,  B = (n_d − 1) / (V_d (1/λ_F² − 1/λ_C²)),  A = n_d − B / λ_d²
       "normal"  n(λ) = n_d + (n_d − 1) / V_d · ((1 − t) s_K7(λ) + t s_F2(λ)),
                 t = (V_d − V_K7) / (V_F2 − V_K7),  s_G(λ) = (n_G(λ) − n_G,d) / (n_G,F − n_G,C)

   Both give ``n(λ_d) = n_d`` and ``(n_d − 1) / (n_F − n_C) = V_d`` exactly.  ``"cauchy"`` is
   :class:`~deeplens.optics.materials.ModelGlass` (the paper's model); every Cauchy glass has
   the same partial dispersions (``P_F,d = 0.699``).  ``"normal"`` (the default) puts the glass
   on SCHOTT's *normal line*: every partial dispersion ``P_x,y = s(λ_x) − s(λ_y)`` is linear in
   ``V_d`` through the two glasses that define that line, K7 and F2 (SCHOTT Sellmeier
   coefficients below), so a model glass predicts a normal real glass's secondary colour, which
   a Cauchy glass does not (the guide has the measured difference).
   In a lens they are the variables ``materials.<i>.n_d`` and ``materials.<i>.v_d``
   of :class:`~deeplens.design.variables.Variables`; :func:`use_model_glasses` puts one in
   place of each glass of a lens, and :func:`glass_scales` scales them as the glass distance
   does (``x = (n_d, w_V V_d)``, see :mod:`.glass_region`).
2. **The region.**  :class:`GlassRegionPenalty` is a merit term with one residual per model
   glass, ``weight · max(D − radius, 0)`` (:class:`~.glass_region.GlassRegion`), zero inside the
   region and growing with the distance outside; :func:`project_model_glasses` moves any model
   glass left outside onto the region.
3. **Substitution.**  :func:`substitute_glasses` takes, for each model glass, its ``k`` nearest
   real glasses of the chosen catalogues (:func:`~.glass_region.nearest_glasses`), and tries
   the combinations: all ``k^m`` of them when there are at most ``max_combinations``, else one
   medium at a time (greedy: each medium's best candidate is kept before the next is tried).
   Each candidate lens is a copy re-optimised by ``reoptimize(lens) -> merit`` (default:
   :func:`dls_reoptimizer`, a few damped-least-squares steps); the lowest merit is kept.  Only
   glasses of the chosen catalogues are ever put in (and checked again before returning).
   :func:`substitute_sequentially` instead replaces one model glass at a time, the most
   sensitive first, each candidate re-optimised with the remaining model glasses free, so
   that they make up for the real glass put in.  :func:`substitute_combined` runs both the
   sequential candidates and a ranked joint set (every combination of a few more nearest
   glasses per element, ranked by a cheap prediction, the best few re-optimised) and keeps
   the lower merit.
4. **Snapping** (a continuation before the substitution).  :func:`snap_model_glasses`
   re-optimises the lens (geometry and model glasses together) a few times with a growing
   pull of each model glass towards its nearest real glass (:class:`NearestGlassPull`: two
   residuals ``strength · (Δn_d, w_V ΔV_d)`` to it, the nearest glass re-picked before every
   stage, so a glass may move on to another real glass while the rest of the lens
   follows).  At the last strength every model glass sits on a real glass to within
   ``~1e-4`` of ``δ``, and the exact substitution that follows changes almost nothing, so the
   design the model glasses found is kept instead of being re-converged from a jump of up
   to the region's radius.
"""

from __future__ import annotations

import copy
import functools
import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, Iterable

import torch
from torch import nn

from ...optics.camera import unpack
from ...optics.materials import DEFAULT_RANGE_NM, LINE_C, LINE_D, LINE_F, Material, ModelGlass
from ..lensopt import optimize_lens
from ..optimizers import Infeasible
from ..variables import Variables
from .glass_region import V_WEIGHT, CatalogueGlass, GlassRegion, glasses, nearest_glasses

__all__ = ["TrainableModelGlass", "use_model_glasses", "model_glass_media", "glass_variable_names",
           "glass_scales", "GlassRegionPenalty", "project_model_glasses", "dls_reoptimizer",
           "SubstitutionResult", "substitute_glasses", "substitute_sequentially",
           "NearestGlassPull", "snap_strengths", "snap_model_glasses", "substitute_combined",
           "ranked_per_element", "RANK_CAP"]

_K_FC = 1.0 / (LINE_F / 1000.0) ** 2 - 1.0 / (LINE_C / 1000.0) ** 2     # µm⁻²
_INV_LD2 = 1.0 / (LINE_D / 1000.0) ** 2                                 # µm⁻²

#: the normal line's reference glasses: SCHOTT Sellmeier (B1, B2, B3), (C1, C2, C3) in µm²
#: (SCHOTT catalogue via opticalglass; tests/design/search/test_glass.py checks them against it)
NORMAL_LINE_GLASSES = {
    "K7": ((1.1273555, 0.124412303, 0.827100531), (0.00720341707, 0.0269835916, 100.384588)),
    "F2": ((1.34533359, 0.209073176, 0.937357162), (0.00997743871, 0.0470450767, 111.886764)),
}
DISPERSIONS = ("normal", "cauchy")


def _sellmeier(B, C, w_nm):
    l2 = (w_nm / 1000.0) ** 2
    return torch.sqrt(1.0 + sum(b * l2 / (l2 - c) for b, c in zip(B, C)))


@functools.lru_cache(maxsize=None)
def _reference(name: str) -> tuple[float, float]:
    """``(n_d, n_F − n_C)`` of a normal-line reference glass (float64)."""
    B, C = NORMAL_LINE_GLASSES[name]
    n_d, n_f, n_c = _sellmeier(B, C, torch.tensor([LINE_D, LINE_F, LINE_C],
                                                  dtype=torch.float64)).tolist()
    return n_d, n_f - n_c


def _shape(name: str, w_nm: torch.Tensor):
    """``(s_G(λ), V_G)``: the normalised dispersion ``(n(λ) − n_d) / (n_F − n_C)`` of a
    reference glass (``w_nm``'s dtype and device) and its Abbe number."""
    B, C = NORMAL_LINE_GLASSES[name]
    n_d, dn = _reference(name)
    return (_sellmeier(B, C, w_nm) - n_d) / dn, (n_d - 1.0) / dn


class TrainableModelGlass(Material):
    """A Cauchy model glass whose ``n_d`` and ``V_d`` are ``nn.Parameter`` scalars (module
    docstring): the same index as ``ModelGlass(n_d, V_d)`` at every wavelength, differentiable
    in ``n_d`` and ``V_d``.

    Args:
        n_d: index at the d line, ``>= 1``.
        v_d: Abbe number, finite and ``> 0``.
        name: a label for reports (default ``"model glass"``); :meth:`to_spec` gives the
            current ``"n_d/V_d"``, so a saved lens holds an ordinary model glass.
        dtype: the parameters' dtype (they follow ``lens.to(...)`` like any parameter).
        dispersion: ``"normal"`` (normal-line partial dispersions) or ``"cauchy"`` (as
            :class:`~deeplens.optics.materials.ModelGlass`); module docstring.

    The parameters are created frozen (``requires_grad=False``), as the lens's own are: design
    variables substitute values (:meth:`~deeplens.design.variables.Variables.call`); call
    ``requires_grad_(True)`` to train them directly.

    Raises:
        ValueError: ``n_d < 1`` or ``V_d`` not finite and positive.
    """

    def __init__(self, n_d: float, v_d: float, name: str = "model glass",
                 dtype: torch.dtype = torch.float64, dispersion: str = "normal"):
        if dispersion not in DISPERSIONS:
            raise ValueError(f"model glass dispersion must be one of {', '.join(DISPERSIONS)}, "
                             f"got {dispersion!r}")
        n_d, v_d = float(n_d), float(v_d)
        if not (math.isfinite(n_d) and n_d >= 1.0):
            raise ValueError(f"model glass needs a finite n_d >= 1, got n_d = {n_d!r}")
        if not (math.isfinite(v_d) and v_d > 0):
            raise ValueError(f"model glass needs a finite Abbe number V_d > 0, got V_d = {v_d!r}")
        super().__init__(name, DEFAULT_RANGE_NM)
        self.dispersion = dispersion
        self.n_d = nn.Parameter(torch.tensor(n_d, dtype=dtype), requires_grad=False)
        self.v_d = nn.Parameter(torch.tensor(v_d, dtype=dtype), requires_grad=False)

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        n_d, v_d = self.n_d.to(w), self.v_d.to(w)
        if self.dispersion == "cauchy":
            b = (n_d - 1.0) / (v_d * _K_FC)                              # µm²
            return n_d - b * _INV_LD2 + b / (w / 1000.0) ** 2
        s_k, v_k = _shape("K7", w)
        s_f, v_f = _shape("F2", w)
        t = (v_d - v_k) / (v_f - v_k)
        return n_d + (n_d - 1.0) / v_d * ((1.0 - t) * s_k + t * s_f)

    def values(self) -> tuple[float, float]:
        """The current ``(n_d, V_d)`` as python floats."""
        return float(self.n_d), float(self.v_d)

    def frozen(self) -> ModelGlass:
        """A :class:`~deeplens.optics.materials.ModelGlass` (Cauchy) at the current values."""
        return ModelGlass(*self.values())

    def to_spec(self) -> str:
        """``"n_d/V_d"`` at the current values: a saved lens holds a (Cauchy) ModelGlass."""
        n_d, v_d = self.values()
        return f"{n_d!r}/{v_d!r}"

    def extra_repr(self) -> str:
        n_d, v_d = self.values()
        return f"{self.name}: n_d={n_d:.6f}, V_d={v_d:.4f}, {self.dispersion}"


def _is_model(m) -> bool:
    """A model glass to be substituted: trainable, or a ModelGlass given as ``n_d/V_d`` (not a
    catalogue entry such as SK16, not a non-dispersive medium)."""
    if isinstance(m, TrainableModelGlass):
        return True
    return isinstance(m, ModelGlass) and "/" in m.to_spec() and math.isfinite(m.v_d)


def _glass_like(m) -> bool:
    """Not air, dispersive, and defined at the d, F and C lines."""
    if isinstance(m, TrainableModelGlass):
        return True
    try:
        return m.nd > 1.0 and math.isfinite(m.vd)
    except ValueError:   # e.g. an infrared crystal without the F line in its range
        return False


def model_glass_media(lens) -> list[int]:
    """Indices into ``lens.materials`` of its model glasses (trainable or ``n_d/V_d``)."""
    lens = unpack(lens)[0]
    return [i for i, m in enumerate(lens.materials) if _is_model(m)]


def _model_values(m) -> tuple[float, float]:
    """``(n_d, V_d)`` of a model glass, trainable or ``n_d/V_d``."""
    return m.values() if isinstance(m, TrainableModelGlass) else (m.n_d, m.v_d)


def _substitutable_media(lens, media, where: str) -> list[int]:
    """``media`` (default: every model glass of ``lens``) checked to be model glasses of it.

    Raises:
        ValueError: no model glass, or an index that is not one (``where`` names the caller).
    """
    media = model_glass_media(lens) if media is None else [int(i) for i in media]
    if not media:
        raise ValueError(f"{where}: the lens has no model glass to substitute")
    for i in media:
        if not (0 <= i < len(lens.materials)) or not _is_model(lens.materials[i]):
            raise ValueError(f"medium {i} is not a model glass of the lens")
    return media


def _check_chosen(lens, chosen: dict, pool: set) -> None:
    """The promise of every substitution: each medium of ``chosen`` holds its real glass, a
    glass of ``pool`` (the labels of the chosen catalogues)."""
    for i, g in chosen.items():
        m = lens.materials[i]
        if g.label not in pool or m.catalogue != g.catalogue or m.name != g.name:
            raise RuntimeError(f"internal error: medium {i} holds {g.label}, not a glass of "
                               f"the chosen catalogues")


def use_model_glasses(lens, media: Iterable[int] | None = None,
                      region: GlassRegion | None = None, dispersion: str = "normal") -> list[int]:
    """Replace glasses of ``lens`` (in place) by :class:`TrainableModelGlass` at their own
    ``(n_d, V_d)`` (projected into ``region`` when given).

    Args:
        lens: a :class:`~deeplens.optics.lens.Lens` (or a Camera: its lens).
        media: indices into ``lens.materials`` (default: every medium that is not air and has
            a finite Abbe number).
        region: the glass region to start inside.
        dispersion: the model glasses' dispersion law (:class:`TrainableModelGlass`).

    Returns:
        The indices replaced (already trainable ones are kept and listed).

    Raises:
        ValueError: an index out of range or a medium that cannot be a model glass (air, a
            non-dispersive medium).
    """
    lens = unpack(lens)[0]
    n = len(lens.materials)
    if media is None:
        media = [i for i, m in enumerate(lens.materials) if _glass_like(m)]
    out = []
    for i in media:
        i = int(i)
        if not 0 <= i < n:
            raise ValueError(f"medium {i} out of range: the lens has media 0..{n - 1}")
        m = lens.materials[i]
        if isinstance(m, TrainableModelGlass):
            out.append(i)
            continue
        if not _glass_like(m):
            raise ValueError(f"medium {i} ({m.name}) is not a glass with n_d > 1 and a finite "
                             f"V_d at the d, F, C lines, and cannot become a model glass")
        nd, vd = m.nd, m.vd
        if region is not None:
            nd, vd = region.project(nd, vd)
        p = next(iter(lens.parameters()), None)
        g = TrainableModelGlass(nd, vd, name=f"model glass (from {m.name})",
                                dispersion=dispersion)
        if p is not None:
            g = g.to(device=p.device)
        lens.materials[i] = g
        out.append(i)
    return out


def glass_variable_names(lens) -> list[str]:
    """``["materials.<i>.n_d", "materials.<i>.v_d", ...]`` of the lens's trainable glasses."""
    lens = unpack(lens)[0]
    return [f"materials.{i}.{p}" for i, m in enumerate(lens.materials)
            if isinstance(m, TrainableModelGlass) for p in ("n_d", "v_d")]


def glass_scales(lens, v_weight: float = V_WEIGHT) -> dict:
    """``{name: scale}`` for :class:`~deeplens.design.variables.Variables`: the scaled
    variables are ``n_d`` and ``w_V V_d``, the glass-map coordinates of the distance."""
    return {n: (1.0 if n.endswith(".n_d") else float(v_weight))
            for n in glass_variable_names(lens)}


class GlassRegionPenalty:
    """A merit term: ``weight · max(D − radius, 0)`` per trainable glass of the lens (module
    docstring); empty for a lens without one.

    Args:
        region: the :class:`~.glass_region.GlassRegion`.
        weight: residual per unit of distance outside (``Δn_d`` units); the default 10 makes
            ``ΔV_d = 1`` outside (0.01) cost as much as 100 µm of spot residual.
    """

    def __init__(self, region: GlassRegion, weight: float = 10.0):
        if not (math.isfinite(float(weight)) and float(weight) > 0):
            raise ValueError(f"glass region penalty weight must be > 0, got {weight!r}")
        self.region, self.weight = region, float(weight)

    def prepare(self, lens) -> "GlassRegionPenalty":
        return self

    def residuals(self, lens) -> torch.Tensor:
        """``(G,)`` residuals, one per trainable glass (dimensionless); with a
        :class:`NearestGlassPull` as the region, ``(3 G,)``: each glass's excess and its
        pull."""
        lens = unpack(lens)[0]
        out = []
        for m in lens.materials:
            if isinstance(m, TrainableModelGlass):
                out.append(self.weight * self.region.excess(m.n_d, m.v_d).reshape(1))
                if hasattr(self.region, "pull"):   # a NearestGlassPull: 2 more residuals
                    out.append(self.weight * self.region.pull(m.n_d, m.v_d).reshape(-1))
        if not out:
            return torch.zeros(0, dtype=lens.dtype, device=lens.device)
        return torch.cat(out)


def project_model_glasses(lens, region: GlassRegion) -> dict:
    """Move every trainable glass outside ``region`` onto it (in place); returns
    ``{medium: ((n_d, V_d) before, (n_d, V_d) after)}`` of those moved."""
    lens = unpack(lens)[0]
    moved = {}
    for i, m in enumerate(lens.materials):
        if isinstance(m, TrainableModelGlass):
            before = m.values()
            after = region.project(*before)
            if after != before:
                with torch.no_grad():
                    m.n_d.fill_(after[0])
                    m.v_d.fill_(after[1])
                moved[i] = (before, after)
    return moved


def dls_reoptimizer(merit, vary="surfaces.*.c", steps: int = 5, constraints=(),
                    **kwargs) -> Callable:
    """``reoptimize(lens) -> merit``: ``steps`` damped-least-squares steps of
    :func:`~deeplens.design.lensopt.optimize_lens` on ``vary`` plus the lens's remaining
    trainable glasses; returns the merit after (``sum r²``).  ``kwargs`` go to
    ``optimize_lens``."""

    def reoptimize(lens) -> float:
        pats = ([p for p in vary.split(",") if p.strip()] if isinstance(vary, str)
                else list(vary)) + glass_variable_names(lens)
        v = Variables(lens, pats, scales=glass_scales(lens))
        return float(optimize_lens(lens, v, merit, steps=steps, constraints=constraints,
                                   **kwargs).merit_after)

    return reoptimize


@dataclass
class SubstitutionResult:
    """What :func:`substitute_glasses` found.

    Attributes:
        lens: the best candidate lens (a re-optimised copy; the input lens is unchanged).
        chosen: ``{medium index: CatalogueGlass}`` put in.
        merit: its merit (what ``reoptimize`` returned).
        table: one row per candidate tried: ``{"glasses": {medium: "CAT:NAME"}, "distance":
            {medium: δ}, "merit": float or None, "error": str, "kept": bool}``.
        strategy: ``"product"``, ``"greedy"`` or ``"ranked"``.
    """

    lens: object
    chosen: dict
    merit: float
    table: list = field(default_factory=list)
    strategy: str = ""

    @property
    def names(self) -> dict:
        """``{medium: "CAT:NAME"}``."""
        return {i: g.label for i, g in self.chosen.items()}


def _score(reoptimize, cand, row: dict) -> float:
    """``reoptimize(cand)`` as a float, NaN where it fails or is not finite; ``row`` (a
    substitution table row) gets the merit or the error."""
    try:
        val = float(reoptimize(cand))
    except (ValueError, RuntimeError, ArithmeticError, Infeasible) as e:
        row["error"] = f"{type(e).__name__}: {e}"
        val = math.nan
    if not math.isfinite(val):
        row["error"] = row["error"] or f"non-finite merit {val!r}"
    else:
        row["merit"] = val
    return val


def substitute_glasses(lens, catalogues, reoptimize: Callable | None = None, *, merit=None,
                       k: int = 3, strategy: str = "auto", max_combinations: int = 27,
                       v_weight: float = V_WEIGHT, exclude: Iterable[str] = (),
                       media: Iterable[int] | None = None, rank: Callable | None = None,
                       rank_keep: int = 4) -> SubstitutionResult:
    """Replace the model glasses of ``lens`` by real glasses of ``catalogues`` (module
    docstring).

    Args:
        lens: a :class:`~deeplens.optics.lens.Lens` with model glasses (trainable or
            ``n_d/V_d``); not modified.
        catalogues: catalogue names (:func:`~.glass_region.check_catalogues`).
        reoptimize: ``reoptimize(candidate_lens) -> merit`` (lower is better); it may change
            the candidate in place.  Default :func:`dls_reoptimizer` of ``merit``.
        merit: the merit for the default ``reoptimize``.
        k: candidates per model glass (nearest first).
        strategy: ``"product"`` (every combination), ``"greedy"`` (one medium at a time, in
            order of the media) or ``"auto"`` (product when ``k^m <= max_combinations``).
        v_weight: ``w_V`` of the distance.
        exclude: glass-name globs never used (:func:`~.glass_region.glasses`).
        media: indices into ``lens.materials`` to substitute (default: every model glass).
        rank: ``rank(candidate_lens) -> predicted merit`` (lower is better; cheap, e.g.
            :func:`~.substitution.linearised_ranker`): every combination of the ``k`` nearest
            is ranked by it, and only the ``rank_keep`` best are re-optimised (strategy
            ``"ranked"``); the table's rows get ``"predicted"``.
        rank_keep: how many ranked candidates are re-optimised, ``>= 1``.

    Returns:
        A :class:`SubstitutionResult`.

    Raises:
        ValueError: an unknown catalogue (the valid names are listed), no model glass, a bad
            strategy or ``k``, neither ``reoptimize`` nor ``merit``; RuntimeError: every
            candidate failed (the table's errors are quoted).
    """
    if strategy not in ("auto", "product", "greedy"):
        raise ValueError(f"strategy must be 'auto', 'product' or 'greedy', got {strategy!r}")
    if int(k) < 1:
        raise ValueError(f"k must be >= 1, got {k!r}")
    pool = {g.label for g in glasses(catalogues, exclude)}   # validates the catalogue names
    if reoptimize is None:
        if merit is None:
            raise ValueError("substitute_glasses needs reoptimize(lens) -> merit, or a merit "
                             "for the default damped-least-squares re-optimisation")
        reoptimize = dls_reoptimizer(merit)
    lens = unpack(lens, where="substitute_glasses")[0]
    media = _substitutable_media(lens, media, "substitute_glasses")
    cands: dict[int, list[tuple[CatalogueGlass, float]]] = {
        i: nearest_glasses(*_model_values(lens.materials[i]), catalogues, k, v_weight, exclude)
        for i in media}

    table: list[dict] = []
    best: dict = {}

    def build(assign: dict):
        cand = copy.deepcopy(lens)
        for i, (g, _) in assign.items():
            cand.materials[i] = g.material()
        return cand

    def evaluate(assign: dict, predicted=None):
        cand = build(assign)
        row = {"glasses": {i: g.label for i, (g, _) in assign.items()},
               "distance": {i: d for i, (_, d) in assign.items()}, "merit": None, "error": "",
               "kept": False}
        if predicted is not None:
            row["predicted"] = predicted
        val = _score(reoptimize, cand, row)
        table.append(row)
        return val, cand, row

    def consider(assign: dict, into: dict, predicted=None):
        val, cand, row = evaluate(assign, predicted)
        if math.isfinite(val) and ("merit" not in into or val < into["merit"]):
            into.update(merit=val, lens=cand, assign=dict(assign), row=row)

    n_comb = 1
    for i in media:
        n_comb *= len(cands[i])
    use = strategy if strategy != "auto" else ("product" if n_comb <= max_combinations
                                               else "greedy")
    if rank is not None:
        if int(rank_keep) < 1:
            raise ValueError(f"rank_keep must be >= 1, got {rank_keep!r}")
        use = "ranked"
        scored = []
        for j, combo in enumerate(itertools.product(*(cands[i] for i in media))):
            assign = dict(zip(media, combo))
            try:
                p = float(rank(build(assign)))
            except (ValueError, RuntimeError, ArithmeticError, Infeasible):
                p = math.inf
            scored.append((p if math.isfinite(p) else math.inf, j, assign))
        scored.sort(key=lambda t: (t[0], t[1]))
        for p, _, assign in scored[:int(rank_keep)]:
            consider(assign, best, p)
    elif use == "product":
        for combo in itertools.product(*(cands[i] for i in media)):
            consider(dict(zip(media, combo)), best)
    else:
        fixed: dict = {}
        for i in media:
            step: dict = {}
            for c in cands[i]:
                consider({**fixed, i: c}, step)
            if "merit" not in step:
                break
            fixed = step["assign"]
            best = step
    if "merit" not in best or len(best["assign"]) != len(media):
        errors = "; ".join(r["error"] for r in table[-3:])
        raise RuntimeError(f"substitute_glasses: no candidate could be re-optimised ({errors})")
    best["row"]["kept"] = True
    chosen = {i: g for i, (g, _) in best["assign"].items()}
    _check_chosen(best["lens"], chosen, pool)
    return SubstitutionResult(best["lens"], chosen, best["merit"], table, use)


class NearestGlassPull:
    """A region-like object for :class:`GlassRegionPenalty` and :func:`project_model_glasses`
    that also pulls every model glass towards a real glass (module docstring, item 4): beside
    the region's excess, :meth:`pull` gives two residuals per glass,
    ``strength · (n_d − n_t, w_V (V_d − V_t))``, ``t`` the nearest of ``targets`` (default:
    every glass of the region), so the pull costs ``strength² δ²`` (the penalty's weight
    times).  Two linear residuals, not one ``strength · δ``: damped least squares linearises a
    distance along the line to the target only, sees no cost across it, and takes steps
    across it that the merit then rejects (a singlet's snap stalled at ``δ`` 0.015 so).
    :func:`snap_model_glasses` gives as ``targets`` each model glass's nearest real glass at
    the start of a stage, so each glass is pulled to its own target, smoothly (the nearest of
    *all* glasses changes on the edges between two glasses, where a finite-difference
    Jacobian mixes both).  ``contains`` and ``project`` are the region's, so a glass is still
    kept inside it.

    Args:
        region: the search's :class:`~.glass_region.GlassRegion`.
        strength: the pull per unit of ``δ``, relative to the region's excess, ``>= 0``.
        targets: :class:`~.glass_region.CatalogueGlass` es to pull towards.
    """

    def __init__(self, region: GlassRegion, strength: float, targets=None):
        if not (math.isfinite(float(strength)) and float(strength) >= 0):
            raise ValueError(f"nearest-glass pull strength must be finite and >= 0, got "
                             f"{strength!r}")
        self.region, self.strength = region, float(strength)
        self.targets = tuple(region.glasses if targets is None else targets)
        if not self.targets:
            raise ValueError("nearest-glass pull: no target glass")
        self.points = torch.tensor([(g.n_d, region.v_weight * g.v_d) for g in self.targets],
                                   dtype=torch.float64)

    def offset(self, n_d, v_d) -> torch.Tensor:
        """``(..., 2)``: ``(n_d, w_V V_d)`` minus that of the nearest target (differentiable;
        the nearest is picked without a gradient)."""
        from .glass_region import _coords

        p = _coords(n_d, v_d, self.region.v_weight)
        g = self.points.to(p)
        j = ((p.unsqueeze(-2) - g) ** 2).sum(-1).argmin(-1)
        return p - g[j]

    def nearest_distance(self, n_d, v_d) -> torch.Tensor:
        """``δ`` to the nearest target (broadcast shape)."""
        return torch.linalg.vector_norm(self.offset(n_d, v_d), dim=-1)

    def pull(self, n_d, v_d) -> torch.Tensor:
        """``(..., 2)`` residuals ``strength · offset``."""
        return self.strength * self.offset(n_d, v_d)

    def excess(self, n_d, v_d) -> torch.Tensor:
        return self.region.excess(n_d, v_d)

    def contains(self, n_d, v_d):
        return self.region.contains(n_d, v_d)

    def project(self, n_d: float, v_d: float) -> tuple[float, float]:
        return self.region.project(n_d, v_d)


def snap_strengths(merit: float, count: int = 6, first_delta: float = 0.03,
                   last_delta: float = 1e-4, penalty_weight: float = 10.0) -> list[float]:
    """A geometric schedule of pull strengths for :func:`snap_model_glasses`: at stage ``j``
    a glass ``δ_j`` from its target costs as much as the whole merit ``merit`` (``sum r²``),
    ``(penalty_weight · strength_j · δ_j)² = merit``, ``δ_j`` going geometrically from
    ``first_delta`` to ``last_delta``; ``penalty_weight`` is :class:`GlassRegionPenalty`'s
    weight."""
    if not (math.isfinite(merit) and merit > 0):
        raise ValueError(f"snap_strengths needs a finite merit > 0, got {merit!r}")
    if int(count) < 1 or not (0 < last_delta <= first_delta):
        raise ValueError(f"snap_strengths: need count >= 1 and 0 < last_delta <= first_delta, "
                         f"got {count!r}, {first_delta!r}, {last_delta!r}")
    deltas = [first_delta * (last_delta / first_delta) ** (j / max(int(count) - 1, 1))
              for j in range(int(count))]
    return [math.sqrt(merit) / (penalty_weight * d) for d in deltas]


def snap_model_glasses(lens, region: GlassRegion, reoptimize: Callable, strengths) -> list:
    """The continuation of the module docstring (item 4), in place: for each strength,
    ``reoptimize(lens, NearestGlassPull(region, strength, targets))`` with ``targets`` the
    nearest real glass of each model glass at that moment (a re-optimisation of the geometry
    and the model glasses whose merit includes :class:`GlassRegionPenalty` of that
    region-like object; it returns anything and raises on failure).

    Returns:
        one row per stage: ``{"strength": s, "glass": {medium: {"n_d", "v_d"}}, "distance":
        {medium: δ to the nearest real glass}, "nearest": {medium: "CAT:NAME"}}`` after the
        stage.
    """
    lens_ = unpack(lens)[0]
    rows = []
    for s in strengths:
        targets = [region.nearest(*m.values())[0] for m in lens_.materials
                   if isinstance(m, TrainableModelGlass)]
        reoptimize(lens, NearestGlassPull(region, s, targets))
        row = {"strength": float(s), "glass": {}, "distance": {}, "nearest": {}}
        for i, m in enumerate(lens_.materials):
            if isinstance(m, TrainableModelGlass):
                g, d = region.nearest(*m.values())
                row["glass"][i] = {"n_d": m.values()[0], "v_d": m.values()[1]}
                row["distance"][i], row["nearest"][i] = d, g.label
        rows.append(row)
    return rows


def substitute_sequentially(lens, catalogues, reoptimize: Callable, *, k: int = 2,
                            score: Callable | None = None, v_weight: float = V_WEIGHT,
                            exclude: Iterable[str] = (),
                            media: Iterable[int] | None = None) -> SubstitutionResult:
    """Replace the model glasses of ``lens`` one at a time, the most sensitive first, letting
    the remaining model glasses follow (module docstring, item 3, the sequential variant).

    At each step, every model glass not yet replaced is scored by ``score`` of a copy with
    that glass alone swapped for its nearest real glass (no re-optimisation; the medium whose
    swap raises ``score`` most goes first; without ``score``, the media's order).  Its ``k``
    nearest real glasses, nearest to where that model glass is *now*, are each put in on a
    copy, and ``reoptimize`` re-optimises it; it should vary the model glasses still left, so
    that they make up for the real glass's difference (its ``n_d``, ``V_d`` and partial
    dispersions).  The best candidate is kept and the next medium is chosen.  ``m`` media
    cost ``k m`` re-optimisations (the joint product costs ``k^m``).

    Args:
        lens: a :class:`~deeplens.optics.lens.Lens` with model glasses; not modified.
        catalogues: catalogue names (:func:`~.glass_region.check_catalogues`).
        reoptimize: ``reoptimize(candidate_lens) -> merit`` (lower is better; in place).
        k: candidates per model glass (nearest first), ``>= 1``.
        score: ``score(lens) -> merit`` without re-optimising (the order), or ``None``.
        v_weight, exclude: as :func:`substitute_glasses`.
        media: indices into ``lens.materials`` to substitute (default: every model glass).

    Returns:
        A :class:`SubstitutionResult` (strategy ``"sequential"``); each row of its table is one
        candidate, its ``glasses`` every real glass in that candidate, and its ``step`` the
        medium replaced.

    Raises:
        ValueError: an unknown catalogue, no model glass, ``k < 1``; RuntimeError: every
            candidate of some step failed (the table's errors are quoted).
    """
    if int(k) < 1:
        raise ValueError(f"k must be >= 1, got {k!r}")
    pool = {g.label for g in glasses(catalogues, exclude)}   # validates the catalogue names
    lens = unpack(lens, where="substitute_sequentially")[0]
    media = _substitutable_media(lens, media, "substitute_sequentially")

    def order_next(cur, left):
        if score is None or len(left) == 1:
            return left[0]
        try:
            base = float(score(cur))
        except (ValueError, RuntimeError, ArithmeticError, Infeasible):
            return left[0]
        worst, pick = -math.inf, left[0]
        for i in left:
            trial = copy.deepcopy(cur)
            g, _ = nearest_glasses(*_model_values(trial.materials[i]), catalogues, 1, v_weight,
                                   exclude)[0]
            trial.materials[i] = g.material()
            try:
                s = float(score(trial))
            except (ValueError, RuntimeError, ArithmeticError, Infeasible):
                s = math.inf
            s = s if math.isfinite(s) else math.inf
            if s - base > worst:
                worst, pick = s - base, i
        return pick

    table: list[dict] = []
    cur, chosen, done, merit = lens, {}, {}, math.nan
    left = list(media)
    while left:
        i = order_next(cur, left)
        best = None
        for g, d in nearest_glasses(*_model_values(cur.materials[i]), catalogues, k, v_weight,
                                    exclude):
            cand = copy.deepcopy(cur)
            cand.materials[i] = g.material()
            row = {"glasses": {**{j: x.label for j, x in chosen.items()}, i: g.label},
                   "distance": {**done, i: d}, "step": i, "merit": None, "error": "",
                   "kept": False}
            v = _score(reoptimize, cand, row)
            if math.isfinite(v):
                if best is None or v < best[0]:
                    best = (v, cand, g, d, row)
            table.append(row)
        if best is None:
            errors = "; ".join(r["error"] for r in table[-3:])
            raise RuntimeError(f"substitute_sequentially: no candidate for medium {i} could be "
                               f"re-optimised ({errors})")
        merit, cur, g, d, _ = best
        chosen[i], done[i] = g, d
        left.remove(i)
    best[4]["kept"] = True
    _check_chosen(cur, chosen, pool)
    return SubstitutionResult(cur, chosen, merit, table, "sequential")


#: the most joint combinations :func:`substitute_combined` ranks: ``rank_k`` nearest glasses
#: per element, fewer when ``rank_k^m`` would pass it (3 elements: 6 each, 216 combinations;
#: 6 elements: 3 each, 729)
RANK_CAP = 729


def ranked_per_element(elements: int, k: int, cap: int = RANK_CAP) -> int:
    """The largest ``m <= k`` with ``m^elements <= cap`` (at least 1): how many nearest glasses
    per element :func:`substitute_combined` combines.

    Raises:
        ValueError: ``elements < 1``, ``k < 1`` or ``cap < 1``.
    """
    if int(elements) < 1 or int(k) < 1 or int(cap) < 1:
        raise ValueError(f"ranked_per_element needs elements, k and cap >= 1, got "
                         f"{elements!r}, {k!r}, {cap!r}")
    m = int(k)
    while m > 1 and m ** int(elements) > int(cap):
        m -= 1
    return m


def substitute_combined(lens, catalogues, reoptimize_free: Callable, reoptimize: Callable,
                        rank: Callable, *, k: int = 2, rank_k: int = 6, rank_keep: int = 6,
                        score: Callable | None = None, cap: int = RANK_CAP,
                        v_weight: float = V_WEIGHT,
                        exclude: Iterable[str] = ()) -> SubstitutionResult:
    """Two candidate sets from the same model design, the lower merit kept (module docstring,
    item 3):

    1. **sequential** (:func:`substitute_sequentially`): ``k`` nearest glasses per element,
       one element at a time, each candidate re-optimised by ``reoptimize_free`` (which should
       leave the remaining model glasses free);
    2. **ranked joint** (:func:`substitute_glasses` with ``rank``): every combination of the
       :func:`ranked_per_element` ``(m, rank_k, cap)`` nearest glasses per element (``m``
       model glasses) is ranked by ``rank(candidate) -> predicted merit`` (e.g.
       :func:`~.substitution.linearised_ranker`), and the ``rank_keep`` best are
       re-optimised by ``reoptimize``.

    Sequential substitution looks only at the nearest glasses, but lets the glasses still to
    come make up for each one; the ranked set reaches glasses farther away (a design whose
    model glasses sit on the region's edge may want a real glass that is not among the two
    nearest: the guide has a Cooke triplet where it does).  A set whose candidates all fail
    is left out; the result's table holds both sets' rows, each with ``"part"``
    (``"sequential"`` or ``"ranked"``), and ``"kept"`` only on the row kept.

    Args:
        lens: a :class:`~deeplens.optics.lens.Lens` with model glasses; not modified.
        catalogues: catalogue names (:func:`~.glass_region.check_catalogues`).
        reoptimize_free, reoptimize: ``(candidate_lens) -> merit`` (lower is better; in place).
        rank: ``(candidate_lens) -> predicted merit`` (cheap; lower is better).
        k: sequential candidates per element, ``>= 1``.
        rank_k: nearest glasses per element for the ranked set (before ``cap``), ``>= 1``.
        rank_keep: ranked candidates re-optimised, ``>= 1``.
        score: the sequential order's ``score(lens)`` (:func:`substitute_sequentially`).
        cap: the most combinations ranked, ``>= 1``.
        v_weight, exclude: as :func:`substitute_glasses`.

    Returns:
        A :class:`SubstitutionResult` (strategy ``"combined"``).

    Raises:
        ValueError: an unknown catalogue, no model glass, ``k``, ``rank_k``, ``rank_keep`` or
            ``cap < 1``; RuntimeError: both sets failed (both errors quoted).
    """
    for name, v in (("k", k), ("rank_k", rank_k), ("rank_keep", rank_keep), ("cap", cap)):
        if int(v) < 1:
            raise ValueError(f"{name} must be >= 1, got {v!r}")
    pool = {g.label for g in glasses(catalogues, exclude)}   # validates the catalogue names
    lens = unpack(lens, where="substitute_combined")[0]
    media = _substitutable_media(lens, None, "substitute_combined")
    m = ranked_per_element(len(media), rank_k, cap)
    parts, errors = [], []
    for part, run in (
            ("sequential", lambda: substitute_sequentially(
                lens, catalogues, reoptimize_free, k=k, score=score, v_weight=v_weight,
                exclude=exclude)),
            ("ranked", lambda: substitute_glasses(
                lens, catalogues, reoptimize, k=m, v_weight=v_weight, exclude=exclude,
                rank=rank, rank_keep=rank_keep))):
        try:
            res = run()
        except RuntimeError as e:
            errors.append(f"{part}: {e}")
            continue
        for row in res.table:
            row["part"] = part
        parts.append(res)
    if not parts:
        raise RuntimeError("substitute_combined: no candidate could be re-optimised ("
                           + "; ".join(errors) + ")")
    best = min(parts, key=lambda r: r.merit)   # the first (sequential) on a tie
    table = []
    for res in parts:
        for row in res.table:
            row["kept"] = bool(row["kept"]) and res is best
            table.append(row)
    _check_chosen(best.lens, best.chosen, pool)   # the arguments handed to both sets too
    return SubstitutionResult(best.lens, dict(best.chosen), best.merit, table, "combined")
