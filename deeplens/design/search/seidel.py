r"""Third-order (Seidel) aberrations of batches of systems, and a screen of thin-lens starts.

**Paraxial traces** (y-nu, batched: every tensor has a leading batch dimension ``B``, float64).
A system is ``S`` surfaces of curvature ``c_j`` (1/mm), the distance ``d_j`` (mm) from surface
``j - 1`` to surface ``j`` (``d_0`` unused) and the media's indices ``n_0 .. n_S`` (object space
first) at each wavelength; the stop is one of the surfaces (a flat surface with the same medium
on both sides, a *dummy*, contributes nothing).  A ray of height ``y_j`` at surface ``j`` and
slope ``u_j`` before it (``u_{j+1}`` after it) refracts as

    n_{j+1} u_{j+1} = n_j u_j - y_j c_j (n_{j+1} - n_j),      y_{j+1} = y_j + d_{j+1} u_{j+1}.

The object is at infinity.  The *marginal* ray ``(y, u)`` enters parallel to the axis at the
entrance pupil's rim (``y_0 = D/2``, ``u_0 = 0``), the *chief* ray ``(ȳ, ū)`` at the full field
(``ū_0 = tan θ_max``) through the centre of the stop (found by linearity of two traces).
``H = n_0 (ū_0 y_0 - u_0 ȳ_0)`` is the Lagrange invariant.

**Seidel sums** (Welford, *Aberrations of Optical Systems*, 1986, ch. 7-8; his sign
convention: slopes ``u = dy/dz``, positive curvature with its centre to the right, so that a
positive singlet's undercorrected spherical aberration has ``S_I > 0``).  Per surface, with
the refraction invariants ``A = n (u + y c)``, ``Ā = n (ū + ȳ c)`` (before the surface) and
``Δ(x) = x' - x`` (after minus before):

    S_I   = -A² y Δ(u/n)
    S_II  = -A Ā y Δ(u/n)
    S_III = -Ā² y Δ(u/n)
    S_IV  = -H² c Δ(1/n)
    S_V   = -Ā³ y Δ(1/n²) + Ā c ȳ (2 Ā y - A ȳ) Δ(1/n)     (= Ā/A (S_III + S_IV))
    C_I   =  A y Δ(δn/n)
    C_II  =  Ā y Δ(δn/n)

``δn`` is the index difference between two wavelengths (for :func:`seidel_sums`, the
shortest minus the longest of the system's wavelengths: ``n_F - n_C`` for F, d, C).  All are
lengths (mm).  They are the wavefront aberration's coefficients (``ρ`` the pupil radius over
its rim, ``h`` the field over its full value, ``p_y = ρ cos φ`` the pupil coordinate in the
plane of the field):

    W = S_I/8 ρ⁴ + S_II/2 h ρ² p_y + S_III/2 h² p_y² + (S_III + S_IV)/4 h² ρ²
        + S_V/2 h³ p_y + C_I/2 ρ² + C_II h p_y

(the chromatic terms at the wavelength whose ``δn = n_λ - n_primary``), and the transverse
ray aberration at the image is ``ε = -(1 / (n' u')) ∇_p W`` (``n' u'``: the marginal ray in
image space).

**Third-order merit** (:func:`third_order_rms`): for each field fraction of the spec
(``h = 0, 0.7, 1``) and each wavelength, ``ε`` on a hexapolar pupil grid (rings
``1 .. rings``, ``6 k`` points on ring ``k``, plus the centre: the rays of the search's
``hexapolar`` sampling), with the monochromatic sums at the primary wavelength and the
chromatic terms of that wavelength, plus one defocus ``W_020 ρ²`` common to all fields and
wavelengths chosen in closed form to minimise the total (the search moves the sensor);
per field the RMS radius of all rays of all wavelengths (weighted by the wavelength weights)
about their common centroid, then the root-mean-square over the fields with the field
weights: the same statistic as :func:`~.result.evaluate`'s ``rms_um``, in third order.

**Screen** (:func:`seidel_screen`): many Sobol points of the start cube
(:func:`~.start.start_dimensions`) become thin systems at once (sign pattern, glasses by
:func:`~.start.crown_flint_by_sign`, powers, spacings, bendings about the best form, stop),
scaled to the focal length (``φ -> s φ``, ``t -> t / s``); a few batched Adam steps on the
third-order merit (plus penalties for what the thickening cannot build) move their powers,
bendings, spacings and stop place, the focal length held by that scaling; the best distinct
ones become :class:`~.start.ThinLens` systems for the thickening.  :func:`~.screen.screened_starts`
thickens them, re-balances each thick lens's third order (``rebalance`` Adam steps,
:mod:`.thick_polish`) and ranks them by it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .spec import DesignSpec

__all__ = ["ParaxialSystem", "paraxial_rays", "seidel_sums", "third_order_rms",
           "lens_system", "thin_system", "seidel_screen", "ScreenResult"]


@dataclass
class ParaxialSystem:
    """A batch of ``B`` systems of ``S`` surfaces (module docstring).

    Attributes:
        c: ``(B, S)`` curvatures (1/mm).
        d: ``(B, S)`` distance from the previous surface (mm; ``d[:, 0]`` unused).
        n: ``(B, W, S + 1)`` media indices at each of ``W`` wavelengths, object space first.
        stop: index of the stop surface (the same for the whole batch).
        primary: index of the primary wavelength in ``W``.
        elements: for thin systems (:func:`thin_system`), each element's first surface.
    """

    c: torch.Tensor
    d: torch.Tensor
    n: torch.Tensor
    stop: int
    primary: int = 0
    elements: tuple = ()

    def __post_init__(self):
        B, S = self.c.shape
        if self.d.shape != (B, S) or self.n.dim() != 3 or self.n.shape[0] != B \
                or self.n.shape[2] != S + 1:
            raise ValueError(f"ParaxialSystem: expected c and d of shape (B, S) and n of shape "
                             f"(B, W, S + 1), got {tuple(self.c.shape)}, {tuple(self.d.shape)}, "
                             f"{tuple(self.n.shape)}")
        if not 0 <= int(self.stop) < S:
            raise ValueError(f"ParaxialSystem: stop must index a surface (0..{S - 1}), got "
                             f"{self.stop}")


def _trace(sys: ParaxialSystem, n: torch.Tensor, y0: torch.Tensor, u0: torch.Tensor):
    """Heights ``(B, S)`` and slopes ``(B, S + 1)`` of the ray ``(y0, u0)`` (``(B,)``, at the
    first surface) in media ``n`` ``(B, S + 1)``."""
    ys, us = [], [u0]
    y, u = y0, u0
    S = sys.c.shape[1]
    for j in range(S):
        if j > 0:
            y = y + sys.d[:, j] * u
        ys.append(y)
        u = (n[:, j] * u - y * sys.c[:, j] * (n[:, j + 1] - n[:, j])) / n[:, j + 1]
        us.append(u)
    return torch.stack(ys, 1), torch.stack(us, 1)


def paraxial_rays(sys: ParaxialSystem, epd: float, hfov_deg: float):
    """Marginal and chief rays at the primary wavelength (module docstring).

    Returns:
        ``(y, u, ybar, ubar)``: heights ``(B, S)`` (mm) and slopes ``(B, S + 1)``.

    Raises:
        ValueError: the stop is at an image of the object (the chief ray is undefined)."""
    n = sys.n[:, sys.primary]
    B = n.shape[0]
    one = torch.ones(B, dtype=n.dtype, device=n.device)
    y, u = _trace(sys, n, 0.5 * float(epd) * one, 0.0 * one)
    tan = math.tan(math.radians(float(hfov_deg)))
    ya, ua = _trace(sys, n, 0.0 * one, tan * one)     # through the first vertex's centre
    yb, ub = _trace(sys, n, one, 0.0 * one)           # unit height, parallel
    b = yb[:, sys.stop]
    if bool((b.abs() < 1e-300).any()):
        raise ValueError("paraxial_rays: the stop is at an image of the object")
    s = -ya[:, sys.stop] / b
    return y, u, ya + s[:, None] * yb, ua + s[:, None] * ub


def _sums(sys, n, y, u, yb, ub, dn=None):
    c = sys.c
    A = n[:, :-1] * (u[:, :-1] + y * c)
    Ab = n[:, :-1] * (ub[:, :-1] + yb * c)
    H = n[:, 0] * (ub[:, 0] * y[:, 0] - u[:, 0] * yb[:, 0])
    d_un = u[:, 1:] / n[:, 1:] - u[:, :-1] / n[:, :-1]
    d_1n = 1.0 / n[:, 1:] - 1.0 / n[:, :-1]
    d_1n2 = 1.0 / n[:, 1:] ** 2 - 1.0 / n[:, :-1] ** 2
    S1 = -A * A * y * d_un
    S2 = -A * Ab * y * d_un
    S3 = -Ab * Ab * y * d_un
    S4 = -(H * H)[:, None] * c * d_1n
    S5 = -Ab ** 3 * y * d_1n2 + Ab * c * yb * (2 * Ab * y - A * yb) * d_1n
    out = {"S": torch.stack([S1, S2, S3, S4, S5], 1), "A": A, "Abar": Ab, "H": H}
    if dn is not None:   # (B, K, S + 1) index differences
        d_dn = (dn[..., 1:] / n[:, None, 1:] - dn[..., :-1] / n[:, None, :-1])
        out["C"] = torch.stack([A[:, None] * y[:, None] * d_dn,
                                Ab[:, None] * y[:, None] * d_dn], 1)   # (B, 2, K, S)
    return out


def seidel_sums(sys: ParaxialSystem, epd: float, hfov_deg: float, short: int | None = None,
                long: int | None = None) -> dict:
    """Per-surface Seidel and chromatic sums (module docstring).

    Args:
        sys: the systems.
        epd: entrance-pupil diameter (mm).
        hfov_deg: the full field's half angle (deg).
        short, long: wavelength indices of ``δn = n_short - n_long`` (default: the first and
            last of ``sys.n``'s wavelengths; with one wavelength ``C`` is zero).

    Returns:
        ``{"S": (B, 5, S) S_I..S_V, "C": (B, 2, S) C_I and C_II, "H": (B,) Lagrange invariant,
        "nu_image": (B,) n' u' of the marginal ray in image space}`` (mm; sum over the last
        axis for the system's sums).
    """
    y, u, yb, ub = paraxial_rays(sys, epd, hfov_deg)
    n = sys.n[:, sys.primary]
    W = sys.n.shape[1]
    short = 0 if short is None else short
    long = W - 1 if long is None else long
    dn = (sys.n[:, short] - sys.n[:, long])[:, None]
    out = _sums(sys, n, y, u, yb, ub, dn)
    out["C"] = out["C"][:, :, 0]
    out["nu_image"] = n[:, -1] * u[:, -1]
    return out


def _hexapolar(rings: int, dtype, device):
    pts = [(0.0, 0.0)]
    for k in range(1, rings + 1):
        for m in range(6 * k):
            a = 2 * math.pi * m / (6 * k)
            pts.append((k / rings * math.cos(a), k / rings * math.sin(a)))
    p = torch.tensor(pts, dtype=dtype, device=device)
    return p[:, 0], p[:, 1]   # p_x, p_y (field along y)


def third_order_rms(sys: ParaxialSystem, epd: float, hfov_deg: float, field_fractions,
                    field_weights, wavelength_weights, rings: int = 4,
                    refocus: bool = True) -> torch.Tensor:
    """The third-order polychromatic RMS spot (module docstring), ``(B,)`` in µm.

    ``field_fractions``/``field_weights``: the fields (fractions of ``hfov_deg``) and their
    weights; ``wavelength_weights``: one per wavelength of ``sys.n``; ``refocus``: with the
    best common defocus (else at the primary wavelength's paraxial image)."""
    y, u, yb, ub = paraxial_rays(sys, epd, hfov_deg)
    n = sys.n[:, sys.primary]
    dn = sys.n - n[:, None]                                     # (B, W, S + 1)
    s = _sums(sys, n, y, u, yb, ub, dn)
    S = s["S"].sum(-1)                                          # (B, 5)
    C = s["C"].sum(-1)                                          # (B, 2, W)
    k = -1.0 / (n[:, -1] * u[:, -1])                            # (B,)
    px, py = _hexapolar(rings, n.dtype, n.device)
    r2 = px * px + py * py
    h = torch.as_tensor([float(x) for x in field_fractions], dtype=n.dtype, device=n.device)
    wf = torch.as_tensor([float(x) for x in field_weights], dtype=n.dtype, device=n.device)
    wl = torch.as_tensor([float(x) for x in wavelength_weights], dtype=n.dtype,
                         device=n.device)
    wl = wl / wl.sum()
    S1, S2, S3, S4, S5 = (S[:, i, None, None, None] for i in range(5))   # (B, 1, 1, 1)
    CI, CII = C[:, 0, None, :, None], C[:, 1, None, :, None]            # (B, 1, W, 1)
    H = h[None, :, None, None]                                          # (1, F, 1, 1)
    X, Y, R2 = px[None, None, None], py[None, None, None], r2[None, None, None]
    # ∂W/∂p_x and ∂W/∂p_y, (B, F, W, P)
    gx = S1 / 2 * R2 * X + S2 * H * X * Y + (S3 + S4) / 2 * H * H * X + CI * X
    gy = (S1 / 2 * R2 * Y + S2 / 2 * H * (R2 + 2 * Y * Y) + S3 * H * H * Y
          + (S3 + S4) / 2 * H * H * Y + S5 / 2 * H ** 3 + CI * Y + CII * H)
    gx, gy = gx + 0 * gy, gy + 0 * gx
    kk = k[:, None, None, None]
    ex, ey = kk * gx, kk * gy
    w = wl[None, None, :, None] / px.numel()                   # weights summing to 1 per field

    def centred(e):
        return e - (w * e).sum((2, 3), keepdim=True)

    ex, ey = centred(ex), centred(ey)
    # defocus W020 ρ² adds 2 d k (p_x, p_y) (zero mean over the pupil): best d in closed form
    wF = (wf / wf.sum())[None, :, None, None]
    gdx, gdy = 2 * kk * X, 2 * kk * Y
    num = (wF * w * (ex * gdx + ey * gdy)).sum((1, 2, 3))
    den = (wF * w * (gdx * gdx + gdy * gdy)).sum((1, 2, 3))
    dd = (-num / den)[:, None, None, None]
    if refocus:
        ex, ey = ex + dd * gdx, ey + dd * gdy
    ms = (w * (ex * ex + ey * ey)).sum((2, 3))                 # (B, F) mm²
    return 1e3 * torch.sqrt((ms * wf).sum(1) / wf.sum())


def lens_system(lens, wavelengths_nm=None) -> ParaxialSystem:
    """The :class:`ParaxialSystem` (``B = 1``) of a deeplens ``Lens`` of spherical surfaces and
    stops, at ``wavelengths_nm`` (default: the lens spec's; the primary one is the spec's).

    Raises:
        ValueError: a surface with a conic or aspheric terms, or of a kind without a
            curvature (the third-order sums here are for spherical surfaces)."""
    from ...optics.paraxial import media_indices

    wl = list(wavelengths_nm or lens.spec.wavelengths_nm)
    prim = float(lens.spec.primary_wavelength_nm)
    if prim not in wl:
        wl = [prim, *wl]
    cs = []
    with torch.no_grad():
        for i, s in enumerate(lens.surfaces):
            if not hasattr(s, "c"):
                cs.append(torch.zeros((), dtype=torch.float64))
                continue
            k = getattr(s, "k", None)
            a = getattr(s, "a", None)
            if (k is not None and float(k) != 0.0) or (
                    a is not None and len(a) and any(float(x) != 0.0 for x in a)):
                raise ValueError(f"lens_system: surface {i} has a conic or aspheric terms; the "
                                 f"third-order sums here are for spherical surfaces")
            cs.append(s.c.detach().double().reshape(()))
        c = torch.stack(cs)[None]
        d = torch.stack([x.detach().double().reshape(()) for x in lens.distances])[None]
        n = torch.stack([media_indices(lens, w).detach().double() for w in wl])[None]
    return ParaxialSystem(c, d, n, int(lens.stop_index), wl.index(prim))


def thin_system(phi, bend, t, n, stop, alpha) -> ParaxialSystem:
    """Thin elements as :class:`ParaxialSystem`: element ``i`` of power ``phi[:, i]`` (1/mm)
    and bending ``X = (c1 + c2) / (c1 - c2)`` is two surfaces ``c1 = φ (X + 1) / (2 (n - 1))``,
    ``c2 = φ (X - 1) / (2 (n - 1))`` (``n`` at the primary wavelength, index 0 of ``n``'s
    wavelengths) at zero distance; ``t`` ``(B, N - 1)`` the spacings (mm); ``n`` ``(B, W, N)``
    the elements' indices (air between); the stop a dummy surface ``"front"`` (``alpha`` mm
    before element 0), ``"back"`` (``alpha`` mm after the last) or in air gap ``k`` at the
    fraction ``alpha`` ``(B,)`` of it."""
    B, N = phi.shape
    W = n.shape[1]
    n0 = n[:, 0]
    c1 = phi * (bend + 1) / (2 * (n0 - 1))
    c2 = phi * (bend - 1) / (2 * (n0 - 1))
    one = torch.ones(B, W, 1, dtype=phi.dtype, device=phi.device)
    zero = torch.zeros(B, dtype=phi.dtype, device=phi.device)
    cs, ds, ns, first = [], [], [one], []
    stop_idx = None

    def add(c, d, medium):
        cs.append(c)
        ds.append(d)
        ns.append(medium)

    nxt = zero
    if stop == "front":
        stop_idx = 0
        add(zero, zero, one)
        nxt = alpha
    for i in range(N):
        if i > 0:
            if stop == i - 1:
                stop_idx = len(cs)
                add(zero, alpha * t[:, i - 1], one)
                nxt = (1 - alpha) * t[:, i - 1]
            else:
                nxt = t[:, i - 1]
        first.append(len(cs))
        add(c1[:, i], nxt, n[:, :, i:i + 1])
        add(c2[:, i], zero, one)
    if stop == "back":
        stop_idx = len(cs)
        add(zero, alpha, one)
    if stop_idx is None:
        raise ValueError(f"thin_system: stop {stop!r} is not 'front', 'back' or an air gap "
                         f"0..{N - 2}")
    return ParaxialSystem(torch.stack(cs, 1), torch.stack(ds, 1), torch.cat(ns, 2), stop_idx, 0,
                          tuple(first))


# ---------------------------------------------------------------------------------- the screen
@dataclass
class ScreenResult:
    """What :func:`seidel_screen` kept: ``starts`` (:class:`~.start.ThinLens`, best first),
    their third-order RMS (µm) and whether each met the penalties (``feasible``), the number of
    points sampled and the seconds it took."""

    starts: list
    rms_um: list
    feasible: list
    sampled: int
    seconds: float
    merit_before: list | None = None


def _glass_table(spec: DesignSpec, glasses: list[str]):
    """``(B, W, N)``-ready index table: ``(G, W)`` indices of ``glasses`` at the primary
    wavelength first, then the spec's wavelengths."""
    from ...optics.materials import get_material

    wl = [spec.primary_wavelength_nm, *spec.wavelengths_nm]
    w = torch.tensor(wl, dtype=torch.float64)
    return torch.stack([get_material(g).n(w).double() for g in glasses])


def _choose_glasses(spec, signs_idx, patterns, ug):
    """Per start and element the index into ``spec.glass_list`` that
    :func:`~.start.crown_flint_by_sign` picks, vectorised (``ug`` ``(B, N)`` in [0, 1))."""
    from ...optics.materials import get_material

    names = list(spec.glass_list)
    order = sorted(range(len(names)), key=lambda i: get_material(names[i]).nd)
    crowns = [i for i in order if get_material(names[i]).vd >= 50] or order
    flints = [i for i in order if get_material(names[i]).vd < 50] or order
    cr, fl = torch.tensor(crowns), torch.tensor(flints)
    pos = torch.tensor([[ch == "+" for ch in p] for p in patterns])[signs_idx]   # (B, N)
    ic = cr[(ug * len(crowns)).long().clamp(max=len(crowns) - 1)]
    if_ = fl[(ug * len(flints)).long().clamp(max=len(flints) - 1)]
    return torch.where(pos, ic, if_), names


def seidel_screen(spec: DesignSpec, points: int, keep: int, seed: int = 0, steps: int = 60,
                  lr: float = 0.05, dedup_tol: float = 0.05, rings: int = 3) -> ScreenResult:
    """The screen of the module docstring.

    Args:
        spec: the spec (object at infinity).
        points: Sobol points sampled (the batch; a scrambled Sobol sequence seeded by
            ``seed + 7919``, apart from the search's own).
        keep: how many distinct thin systems to return (best first, those meeting the
            penalties first).
        steps: batched Adam steps on the merit (0: rank the sampled systems as they are).
        lr: Adam's step (the variables are log |f φ|, bendings, log spacings and the stop's
            place, all of order one).
        dedup_tol: two systems are one when they have the same glasses and stop and their
            ``f φ``, bendings and spacings ``/ f`` differ by less than this everywhere.
        rings: hexapolar rings of the merit's pupil grid.

    Raises:
        ValueError: an object at a finite distance (not supported here).
    """
    import time

    from .start import ThinLens, sign_patterns, start_dimensions

    if not math.isinf(spec.object_distance_mm):
        raise ValueError("seidel_screen: the third-order screen supports an object at "
                         "infinity only (spec.object_distance_mm is finite)")
    t0 = time.perf_counter()
    N, f = spec.elements, spec.efl_mm
    dt = torch.float64
    d = start_dimensions(N)
    u = torch.quasirandom.SobolEngine(d, scramble=True, seed=int(seed) + 7919).draw(
        int(points), dtype=dt)
    B = u.shape[0]
    patterns = sign_patterns(N)
    si = (u[:, 0] * len(patterns)).long().clamp(max=len(patterns) - 1)
    sgn = torch.tensor([[1.0 if ch == "+" else -1.0 for ch in p] for p in patterns],
                       dtype=dt)[si]
    gi, names = _choose_glasses(spec, si, patterns, u[:, 1:1 + N])
    table = _glass_table(spec, names)                              # (G, 1 + W)
    nW = table[gi].permute(0, 2, 1)                                # (B, 1 + W, N)
    up, ub = u[:, 1 + N:1 + 2 * N], u[:, 1 + 2 * N:1 + 3 * N]
    ut = u[:, 1 + 3 * N:4 * N]
    us, ua = u[:, 4 * N], u[:, 4 * N + 1]
    mag = 0.6 + 3.9 * min(1.0, 3.0 / N) * up
    t0s = f * (0.03 + 0.22 * ut) * min(1.0, 3.0 / max(N - 1, 1))
    stops = spec.stop_positions()
    sidx = (us * len(stops)).long().clamp(max=len(stops) - 1)
    fw, ww = spec.weights_of_fields, list(spec.wavelength_weights)
    ff = [x / spec.hfov_deg if spec.hfov_deg else 0.0 for x in spec.fields_deg]
    min_c = spec.min_center_glass_mm or 0.0
    min_e = spec.min_edge_glass_mm or 0.0
    min_air = spec.min_air_mm or 0.0
    max_t = min(0.15 * f, spec.max_center_glass_mm or math.inf)
    out_starts, before = [], []
    for k, stop in enumerate(stops):
        m = sidx == k
        if not bool(m.any()):
            continue
        nb = nW[m]
        n0 = nb[:, 0]                                              # (b, N)
        front_back = stop in ("front", "back")
        a0 = (f * (0.005 + 0.1 * ua[m]) / f) if front_back else (0.2 + 0.6 * ua[m])
        s = sgn[m]
        # variables (all of order one)
        lm = torch.log(mag[m]).clone().requires_grad_(True)
        lt = torch.log(t0s[m] / f).clone().requires_grad_(True)
        la = torch.logit(a0.clamp(1e-3, 1 - 1e-3)).clone().requires_grad_(True) \
            if not front_back else torch.log(a0).clone().requires_grad_(True)
        # bendings: the sampled offset about each element's best form (start.py), at the start
        with torch.no_grad():
            phi, tt, aa, _ = _scaled(s, lm, lt, la, f, front_back)
            X0 = _best_form(phi, tt, n0) + (-0.75 + 1.5 * ub[m])
        X = X0.clone().requires_grad_(True)

        def merit(lm, lt, la, X):
            phi, tt, aa, ok = _scaled(s, lm, lt, la, f, front_back)
            sys = thin_system(phi, X, tt, nb, stop, aa)
            rms = third_order_rms(sys, spec.epd, spec.hfov_deg, ff, fw, [0.0, *ww],
                                  rings=rings)
            pen = _penalty(sys, phi, X, tt, n0, f, spec, min_c, min_e, min_air, max_t)
            return rms, pen, ok

        with torch.no_grad():
            rms, pen, ok = merit(lm, lt, la, X)
            before.append((rms, pen, ok))
        params = [lm, lt, la, X]
        mom = [torch.zeros_like(v) for v in params]
        sq = [torch.zeros_like(v) for v in params]
        for it in range(int(steps)):   # Adam (Kingma and Ba), by hand: torch.optim imports
            rms, pen, ok = merit(lm, lt, la, X)   # torch._dynamo, seconds of start-up
            loss = torch.where(ok & torch.isfinite(rms), torch.log1p(rms) + 10 * pen,
                               torch.zeros_like(rms))
            grads = torch.autograd.grad(loss.sum(), params, allow_unused=True)
            with torch.no_grad():
                for v, g, m1, m2 in zip(params, grads, mom, sq):
                    if g is None:   # a singlet has no spacings
                        continue
                    g = g.nan_to_num(0.0, 0.0, 0.0)
                    m1.mul_(0.9).add_(0.1 * g)
                    m2.mul_(0.999).add_(0.001 * g * g)
                    v.sub_(lr * (m1 / (1 - 0.9 ** (it + 1)))
                           / (torch.sqrt(m2 / (1 - 0.999 ** (it + 1))) + 1e-8))
        with torch.no_grad():
            rms, pen, ok = merit(lm, lt, la, X)
            phi, tt, aa, _ = _scaled(s, lm, lt, la, f, front_back)
        good = ok & torch.isfinite(rms) & torch.isfinite(pen)
        idx = torch.nonzero(good).flatten()
        gsel = gi[m]
        for j in idx.tolist():
            out_starts.append((float(pen[j]) > 1e-6, float(rms[j]), {
                "phi": phi[j].tolist(), "t": tt[j].tolist(), "X": X[j].detach().tolist(),
                "stop": stop, "alpha": float(aa[j]), "glasses": [names[g] for g in
                                                                 gsel[j].tolist()],
                "signs": "".join("+" if v > 0 else "-" for v in s[j].tolist())}))
    out_starts.sort(key=lambda r: (r[0], r[1]))
    kept = []
    for bad, rms, r in out_starts:
        if len(kept) >= keep:
            break
        sig = torch.tensor([p * f for p in r["phi"]] + r["X"] + [x / f for x in r["t"]])
        if any(r["glasses"] == q["glasses"] and r["stop"] == q["stop"]
               and float((sig - q["sig"]).abs().max()) < dedup_tol for q in kept):
            continue
        r["sig"] = sig
        r["rms"], r["bad"] = rms, bad
        kept.append(r)
    starts = [ThinLens(r["phi"], r["glasses"], r["t"], r["X"], r["stop"], r["alpha"],
                       r["signs"]) for r in kept]
    mb = [float(x) for b in before for x in b[0][torch.isfinite(b[0])].tolist()]
    return ScreenResult(starts, [r["rms"] for r in kept], [not r["bad"] for r in kept], B,
                        time.perf_counter() - t0, merit_before=mb)


def _scaled(s, lm, lt, la, f, front_back):
    """Powers (1/mm), spacings (mm) and the stop's place of the thin system scaled to focal
    length ``f`` (``φ -> σ φ``, ``t -> t / σ``, ``σ = 1 / (f Φ)``), and whether ``Φ > 0``."""
    k = s * torch.exp(lm)                  # f φ before scaling
    t = f * torch.exp(lt)
    phi = k / f
    # system power of the thin system (marginal ray from infinity, unit height)
    y = torch.ones_like(phi[:, 0])
    uu = torch.zeros_like(y)
    N = phi.shape[1]
    for i in range(N):
        uu = uu - y * phi[:, i]
        if i < N - 1:
            y = y + t[:, i] * uu
    Phi = -uu
    ok = Phi > 0
    sigma = torch.where(ok, 1.0 / (f * Phi.clamp(min=1e-12)), torch.ones_like(Phi))
    a = torch.exp(la) * f / sigma if front_back else torch.sigmoid(la)
    return phi * sigma[:, None], t / sigma[:, None], a, ok


def _best_form(phi, t, n0):
    """Each element's best-form bending (:func:`~.start.best_form_bending`) for the marginal
    ray's conjugates through it, batched ``(b, N)``."""
    y = torch.ones_like(phi[:, 0])
    u = torch.zeros_like(y)
    out = []
    N = phi.shape[1]
    for i in range(N):
        u2 = u - y * phi[:, i]
        p = torch.where(u != u2, (u + u2) / (u - u2), torch.zeros_like(u))
        n = n0[:, i]
        out.append(-2.0 * (n * n - 1.0) * p / (n + 2.0))
        u = u2
        if i < N - 1:
            y = y + t[:, i] * u
    return torch.stack(out, 1)


def _sag(c, h):
    x = (c * h).clamp(-0.999, 0.999)
    return c * h * h / (1 + torch.sqrt(1 - x * x))


def _penalty(sys, phi, X, t, n0, f, spec, min_c, min_e, min_air, max_t):
    """Squared relative shortfalls of what the thickening (:func:`~.start.thick_lens`) needs:
    ``|f φ| <= 6``, ``|c| h <= 0.8`` (``h`` the clear semi-diameter it will give), each
    element's centre thickness ``<= min(0.15 f, max_center_glass)``, each air gap wide enough
    for half of both elements and the air limit, the paraxial image behind the last element,
    and the total track within ``max_track``.  ``(b,)``, dimensionless."""
    y, u, yb, ub = paraxial_rays(sys, spec.epd, spec.hfov_deg)
    N = phi.shape[1]
    # heights at the elements: the surfaces whose medium after is glass (first of each pair)
    hs = torch.stack([1.08 * (y[:, j].abs() + yb[:, j].abs()) + 0.2 for j in sys.elements], 1)
    c1 = phi * (X + 1) / (2 * (n0 - 1))
    c2 = phi * (X - 1) / (2 * (n0 - 1))
    r = torch.relu
    pen = (r((f * phi).abs() - 6.0) ** 2).sum(1)
    pen = pen + (r(torch.maximum(c1.abs(), c2.abs()) * hs - 0.8) ** 2).sum(1) * 10
    tc = torch.maximum(min_e + _sag(c1, hs) - _sag(c2, hs),
                       torch.full_like(hs, max(min_c, 0.0 if min_c else 0.02 * f)))
    pen = pen + (r(tc - max_t) / f).pow(2).sum(1) * 100
    if N > 1:
        need = 0.5 * (tc[:, :-1] + tc[:, 1:]) + min_air + 0.01 * f
        pen = pen + (r(need - t) / f).pow(2).sum(1) * 100
    bfl = -y[:, -1] / u[:, -1]
    pen = pen + (r(0.05 * f - bfl) / f) ** 2 * 100
    if spec.max_track_mm is not None:
        track = t.sum(1) + bfl + 0.5 * (tc[:, 0] + tc[:, -1])
        pen = pen + (r(track - spec.max_track_mm) / f) ** 2 * 100
    return pen


def _weights_with_primary(spec: DesignSpec) -> list:
    """Wavelength weights for :func:`lens_system`'s wavelengths (the primary one put first
    with weight 0 when it is not among the spec's)."""
    w = list(spec.wavelength_weights)
    if float(spec.primary_wavelength_nm) in [float(x) for x in spec.wavelengths_nm]:
        return w
    return [0.0, *w]
