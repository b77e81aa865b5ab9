r"""Starting points without a starting lens: a thin-lens solve, and flat starts.

**Thin-lens solve.**  ``N`` thin elements of powers ``φ_i`` (1/mm), glasses of index ``n_i``
and Abbe number ``V_i`` (at the spec's wavelengths: ``V = (n_primary - 1) / (n_short - n_long)``),
spaced by ``t_i`` (mm).  A paraxial marginal ray from infinity at unit height has height ``y_i``
at element ``i`` (``y_0 = 1``, ``u_{i+1} = u_i - y_i φ_i``, ``y_{i+1} = y_i + t_i u_{i+1}``) and
the system power is ``Φ = -u_N``.  The powers solve, in least squares (dimensionless residuals),

    f Φ - 1 = 0                                  (the focal length; weight 1e4)
    f Σ y_i² φ_i / V_i = 0                        (primary axial colour; N >= 2; weight 1e4)
    f Σ φ_i / n_i = 0                             (Petzval sum; N >= 3, weight 0.1)
    0.3 (f φ_i - k_i) = 0                         (near the sampled powers k_i / f)

and then, exactly, ``φ_i -> s φ_i``, ``t_i -> t_i / s`` with ``s = 1 / (f Φ)`` (a thin system's
power scales with its powers when its spacings scale inversely), so ``f Φ = 1`` to rounding.

**Thickening.**  Element ``i`` gets the bending ``X_i = (c_1 + c_2) / (c_1 - c_2)`` of least
third-order spherical aberration for its conjugates, plus a sampled offset in ``[-0.75, 0.75]``
(:func:`best_form_bending`: ``X = -2 (n^2 - 1) p / (n + 2)``, ``p = (u + u') / (u - u')`` the
position factor of the marginal ray's slopes before and after it; Welford, *Aberrations of
Optical Systems*, ch. 7, with the Coddington shape factor's sign as here):
``c_1 = φ (X + 1) / (2 (n - 1))``, ``c_2 = φ (X - 1) / (2 (n - 1))``; its clear semi-diameter is
the thin system's paraxial marginal plus chief ray height (times 1.08, + 0.2 mm); its centre
thickness the least one with an edge of ``min_edge_glass_mm`` and a centre of
``min_center_glass_mm``; the air gaps keep the thin spacings, widened where an edge or centre
gap would be below ``min_air_mm``.  Last, the focal length is made exact by the *angle solve*
of lens-design programs: the last refracting surface's curvature is set so that the marginal
ray from infinity leaves at ``u' = -1/f``:

    n' u' = n u - y c (n' - n)    =>    c = n' (u'_0 - u') / (y (n' - n)),

``u'_0`` the slope it leaves with when that surface is flat.  The sensor is placed at the
paraxial image of the object.

**Flat starts** (as AutoLens starts from flat surfaces): the same element layout with every
curvature ``~1e-4 / f`` of the sampled sign (no power to speak of), to be grown by a curriculum
(:mod:`.refine`: small aperture and field first).

One start is one point ``u`` of the unit cube ``[0, 1)^d`` (:func:`start_dimensions`; a Sobol
point in the search), so that starts are reproducible and spread evenly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ...optics.paraxial import paraxial
from ...optics.lens import Lens, LensSpec
from ...optics.materials import Air, get_material
from ...optics.paraxial import media_indices, trace_paraxial_ray
from ...optics.surfaces import Aperture, Asphere
from .spec import DesignSpec

__all__ = ["ThinLens", "thin_lens_solve", "thin_lens_start", "flat_start", "solve_efl",
           "start_dimensions", "sign_patterns", "best_form_bending", "crown_flint_by_sign", "StartError",
           "thick_lens"]


class StartError(ValueError):
    """A sampled start that is not a lens (an element too strongly bent for its aperture, a
    virtual image, powers the solve could not balance); the search skips it."""


#: the sign patterns (powers, object to image) tried for each element count
_PATTERNS = {1: ("+",), 2: ("+-", "-+"), 3: ("+-+", "++-"), 4: ("+--+", "++-+", "+-++"),
             5: ("++--+", "+-+-+", "++-++"), 6: ("++--++", "+-+-++", "++-+-+")}


def sign_patterns(n: int) -> tuple[str, ...]:
    """Power-sign patterns for ``n`` elements (alternating ones beyond six)."""
    if n in _PATTERNS:
        return _PATTERNS[n]
    alt = "".join("+-"[i % 2] for i in range(n - 1)) + "+"
    return (alt, "+" + alt[1:-1].replace("+", "-", 1) + "+")


def start_dimensions(n_elements: int) -> int:
    """Coordinates of a start's point ``u``: pattern, per element glass, power and bending,
    per air gap a spacing, stop position and its place in its gap."""
    return 1 + 3 * n_elements + (n_elements - 1) + 2


def _pick(seq, u: float):
    return seq[min(int(u * len(seq)), len(seq) - 1)]


def crown_flint_by_sign(glasses: list[str], signs: str, u) -> list[str]:
    """The default glass strategy: a positive element takes a crown (``V_d >= 50``), a
    negative one a flint (``V_d < 50``), each chosen by its coordinate of ``u`` from the set
    sorted by ``n_d`` (a set without crowns or flints gives the whole set for both)."""
    mats = sorted(glasses, key=lambda g: get_material(g).nd)
    crowns = [g for g in mats if get_material(g).vd >= 50] or mats
    flints = [g for g in mats if get_material(g).vd < 50] or mats
    return [_pick(crowns if s == "+" else flints, float(x)) for s, x in zip(signs, u)]


@dataclass
class ThinLens:
    """A thin-lens system: powers (1/mm), glass specs, spacings between elements (mm), bendings
    ``X``, the stop (``"front"``, ``"back"`` or an air-gap index) with its place ``alpha`` in
    its gap (or its distance before/after the lens, mm), and the sampled sign pattern."""

    powers: list
    glasses: list
    spacings: list
    bendings: list
    stop: object
    alpha: float
    signs: str

    def efl(self) -> float:
        y, u = 1.0, 0.0
        for i, p in enumerate(self.powers):
            u = u - y * p
            if i < len(self.spacings):
                y = y + self.spacings[i] * u
        return -1.0 / u


def _indices(glass: str, spec: DesignSpec) -> tuple[float, float]:
    """``(n at the primary wavelength, V at the spec's wavelengths)`` (``V = inf`` for one
    wavelength)."""
    m = get_material(glass)
    w = sorted(spec.wavelengths_nm)
    n0 = float(m.n(spec.primary_wavelength_nm))
    if len(w) < 2:
        return n0, math.inf
    dn = float(m.n(w[0]) - m.n(w[-1]))
    return n0, (n0 - 1.0) / dn if dn != 0 else math.inf


def _levenberg_marquardt(fn, x0, steps: int = 200) -> np.ndarray:
    """Minimise ``|fn(x)|^2`` (a few variables, plain floats: torch's per-op overhead would
    dominate) by Levenberg-Marquardt with a central-difference Jacobian."""
    x = np.asarray(x0, dtype=np.float64)
    r = fn(x)
    F, lam = float(r @ r), 1e-3
    for _ in range(steps):
        J = np.empty((r.size, x.size))
        for j in range(x.size):
            h = 1e-7 * max(1.0, abs(x[j]))
            e = np.zeros_like(x)
            e[j] = h
            J[:, j] = (fn(x + e) - fn(x - e)) / (2 * h)
        A, g = J.T @ J, J.T @ r
        D = np.maximum(np.diag(A), 1e-12 * max(float(np.diag(A).max()), 1e-300))
        while True:
            dx = np.linalg.solve(A + lam * np.diag(D), -g)
            r2 = fn(x + dx)
            F2 = float(r2 @ r2)
            if F2 < F:
                done = F - F2 < 1e-15 * max(F, 1e-300)
                x, r, F, lam = x + dx, r2, F2, max(lam / 3, 1e-12)
                break
            lam *= 4
            if lam > 1e12:
                return x
        if done:
            break
    return x


def thin_lens_solve(spec: DesignSpec, k, spacings, glasses) -> tuple[list, list]:
    """Powers (1/mm) and spacings (mm) of the thin system (module docstring): ``k`` sampled
    normalised powers (``f φ_i``), ``spacings`` (mm), ``glasses`` specs.  Returns
    ``(powers, spacings)`` with ``f Φ = 1`` to rounding."""
    f = spec.efl_mm
    N = len(k)
    nv = [_indices(g, spec) for g in glasses]
    k0 = np.array([float(x) for x in k])
    t = [float(x) for x in spacings]
    colour = N >= 2 and len(spec.wavelengths_nm) >= 2

    def heights(phi):
        y, u, ys = 1.0, 0.0, []
        for i in range(N):
            ys.append(y)
            u = u - y * phi[i]
            if i < N - 1:
                y = y + t[i] * u
        return ys, -u

    def residuals(x):
        phi = x / f
        ys, Phi = heights(phi)
        r = [1e4 * (f * Phi - 1.0)]
        if colour:
            r.append(1e4 * f * sum(ys[i] ** 2 * phi[i] / nv[i][1] for i in range(N)))
        if N >= 3:
            r.append(0.1 * f * sum(phi[i] / nv[i][0] for i in range(N)))
        return np.concatenate([np.array(r), 0.3 * (x - k0)])

    phi = [float(v) / f for v in _levenberg_marquardt(residuals, k0)]
    _, Phi = heights(phi)
    s = 1.0 / (f * float(Phi)) if Phi != 0 else math.inf
    if not (s > 0 and math.isfinite(s)):
        raise StartError(f"the thin-lens solve gives no positive power (f Φ = {f * Phi:.3g})")
    return [p * s for p in phi], [x / s for x in t]


def _sag(c: float, h: float) -> float:
    return c * h * h / (1.0 + math.sqrt(max(0.0, 1.0 - c * c * h * h)))


def _thin_heights(tl: ThinLens, spec: DesignSpec):
    """Paraxial marginal (infinity, EPD/2) and chief (through the stop centre, slope
    tan θ_max) heights at each thin element."""
    N = len(tl.powers)
    # positions of the elements and the stop along the axis
    z = [0.0]
    for t in tl.spacings:
        z.append(z[-1] + t)
    if tl.stop == "front":
        zs = -tl.alpha
    elif tl.stop == "back":
        zs = z[-1] + tl.alpha
    else:
        zs = z[tl.stop] + tl.alpha * tl.spacings[tl.stop]

    def trace(y0, u0, z0):
        # ray with height y0 and slope u0 at z0 (before element 0 if z0 <= 0)
        y, u, zc, hs = y0 + u0 * (0.0 - z0), u0, 0.0, []
        for i in range(N):
            y = y + u * (z[i] - zc)
            zc = z[i]
            hs.append(y)
            u = u - y * tl.powers[i]
        return hs

    ym = trace(0.5 * spec.epd, 0.0, 0.0)
    # the chief ray passes the stop centre: a ray of unit slope through the stop; find its
    # height at z = 0 by linearity (trace from y=0 and y=1 at slope tan θ)
    tan = math.tan(math.radians(spec.hfov_deg))
    if tan == 0:
        return ym, [0.0] * N

    def at_stop(y0):
        y, u, zc = y0, tan, 0.0
        for i in range(N):
            if z[i] >= zs:
                break
            y = y + u * (z[i] - zc)
            zc = z[i]
            u = u - y * tl.powers[i]
        return y + u * (zs - zc)

    a, b = at_stop(0.0), at_stop(1.0)
    y0 = -a / (b - a)
    yc = trace(y0, tan, 0.0)
    return ym, yc


def thick_lens(tl: ThinLens, spec: DesignSpec, flat: bool = False,
               dtype=torch.float64) -> Lens:
    """The thick lens of a thin system (module docstring), EFL exact (:func:`solve_efl`).

    Raises:
        StartError: an element is bent beyond its aperture or the image is virtual.
    """
    f = spec.efl_mm
    N = len(tl.powers)
    ym, yc = _thin_heights(tl, spec)
    sds = [1.08 * (abs(a) + abs(b)) + 0.2 for a, b in zip(ym, yc)]
    min_c = spec.min_center_glass_mm or 0.0
    min_e = spec.min_edge_glass_mm or 0.0
    min_air = spec.min_air_mm or 0.0
    curv, thick = [], []
    for i in range(N):
        n, _ = _indices(tl.glasses[i], spec)
        phi, X = tl.powers[i], tl.bendings[i]
        if flat:
            c1 = c2 = math.copysign(1e-4 / f, phi)
        else:
            c1 = phi * (X + 1.0) / (2.0 * (n - 1.0))
            c2 = phi * (X - 1.0) / (2.0 * (n - 1.0))
        h = sds[i]
        if max(abs(c1), abs(c2)) * h >= 0.95:
            raise StartError(f"element {i} is bent beyond its aperture (|c| h >= 0.95)")
        tc = max(min_c, min_e + _sag(c1, h) - _sag(c2, h), 0.02 * f if not min_c else 0.0)
        if tc > 0.15 * f:
            raise StartError(f"element {i} needs {tc:.3g} mm of glass (over 0.15 f)")
        if spec.max_center_glass_mm is not None and tc > spec.max_center_glass_mm:
            raise StartError(f"element {i} needs {tc:.3g} mm of glass, over max_center_glass")
        curv.append((c1, c2))
        thick.append(tc)
    gaps = []
    for i in range(N - 1):
        h = min(sds[i], sds[i + 1])
        g = tl.spacings[i] - 0.5 * (thick[i] + thick[i + 1])
        edge = g + _sag(curv[i + 1][0], h) - _sag(curv[i][1], h)
        g = max(g, min_air + 1e-3, g + (min_air + 1e-3 - edge))
        gaps.append(g)
    surfaces, materials, distances = [], [Air()], []
    stop_index = None
    first = True

    def add(surface, medium, gap):
        nonlocal first
        surfaces.append(surface)
        materials.append(medium)
        distances.append(0.0 if first else gap)
        first = False

    pending = 0.0
    if tl.stop == "front":
        stop_index = 0
        add(Aperture(0.5 * spec.epd), Air(), 0.0)
        pending = tl.alpha
    for i in range(N):
        if tl.stop == i - 1 and i > 0:
            g = gaps[i - 1]
            stop_index = len(surfaces)
            add(Aperture(0.5 * spec.epd), Air(), tl.alpha * g)
            pending = (1.0 - tl.alpha) * g
        elif i > 0:
            pending = gaps[i - 1]
        add(Asphere(curv[i][0], sds[i], coefficients=_coeffs(spec, 2 * i)),
            get_material(tl.glasses[i]), pending)
        add(Asphere(curv[i][1], sds[i], coefficients=_coeffs(spec, 2 * i + 1)), Air(),
            thick[i])
    if tl.stop == "back":
        stop_index = len(surfaces)
        add(Aperture(0.5 * spec.epd), Air(), tl.alpha)
    lspec = LensSpec(object_distance_mm=spec.object_distance_mm, aperture_type="epd",
                     aperture_value=spec.epd, fields_deg=spec.fields_deg,
                     wavelengths_nm=list(spec.wavelengths_nm),
                     primary_wavelength_nm=spec.primary_wavelength_nm)
    lens = Lens(surfaces, materials, distances, d_sensor=f, stop_index=stop_index,
                spec=lspec, name=f"search start {tl.signs} {'/'.join(tl.glasses)}")
    lens = lens.to(dtype)
    if flat:   # no power yet: the sensor one focal length behind
        try:
            lens.check()
        except ValueError as e:
            raise StartError(f"not a valid lens: {e}") from None
        return lens
    for _ in range(4):   # the solve bends the last surface: keep its element's edge
        solve_efl(lens, f)
        short = _last_edge_short(lens, min_e)
        if short <= 0:
            break
        with torch.no_grad():
            last = max(i for i, s in enumerate(lens.surfaces) if not isinstance(s, Aperture))
            lens.distances[last].add_(short + 1e-3)
    lens.apply_aperture_spec()   # the stop for the EPD, after the last changes
    place_sensor(lens)
    return lens


def _last_edge_short(lens: Lens, min_edge: float) -> float:
    """How much the last element's edge falls short of ``min_edge`` (mm; <= 0: enough)."""
    last = max(i for i, s in enumerate(lens.surfaces) if not isinstance(s, Aperture))
    if isinstance(lens.materials[last], Air):
        return 0.0
    a, b = lens.surfaces[last - 1], lens.surfaces[last]
    h = min(float(a.semi_diameter), float(b.semi_diameter))
    edge = float(lens.distances[last]) + _sag(float(b.c), h) - _sag(float(a.c), h)
    return min_edge - edge


def _coeffs(spec: DesignSpec, surface: int) -> list:
    """Room for ``a4, a6`` on every surface when the spec allows aspheres (all zero: which
    surfaces vary is the refinement's choice)."""
    return [0.0, 0.0] if spec.aspheres else []


def solve_efl(lens: Lens, efl: float) -> None:
    """Set the last refracting surface's curvature so that the paraxial EFL is ``efl``
    exactly (the angle solve of the module docstring); in place.

    Raises:
        StartError: the marginal ray misses that surface (``y = 0``) or no index step.
    """
    last = max(i for i, s in enumerate(lens.surfaces) if not isinstance(s, Aperture))
    s = lens.surfaces[last]
    with torch.no_grad():
        s.c.zero_()
        n = media_indices(lens)
        one = torch.ones((), dtype=lens.dtype)
        _, u0, hs = trace_paraxial_ray(lens, one, torch.zeros_like(one), n)
        y = float(hs[last])
        n1, n2 = float(n[last]), float(n[last + 1])
        if y == 0 or n1 == n2:
            raise StartError("the angle solve needs a ray height and an index step on the "
                             "last surface")
        # after the last refracting surface only stops: the slope leaving it is u0
        c = n2 * (float(u0) - (-1.0 / efl)) / (y * (n2 - n1))
        s.c.fill_(c)
        if abs(c) * float(s.semi_diameter) >= 0.98:
            raise StartError(f"the EFL solve bends the last surface beyond its aperture "
                             f"(c = {c:.4g}/mm)")


def place_sensor(lens: Lens) -> None:
    """Put the sensor on the paraxial image of the object (in place).

    Raises:
        StartError: the image is virtual or too close to the last surface."""
    with torch.no_grad():
        img = float(paraxial(lens).image_distance)
        if not (img > 0 and math.isfinite(img)):
            raise StartError(f"the paraxial image lies {img:.4g} mm from the last surface "
                             f"(virtual or at infinity)")
        lens.d_sensor.fill_(img)
    try:
        lens.check()
    except ValueError as e:
        raise StartError(f"not a valid lens: {e}") from None


def _layout(spec: DesignSpec, u, glass_strategy=None) -> ThinLens:
    """The thin system's layout from the point ``u`` (before the power solve)."""
    N = spec.elements
    u = [float(x) for x in u]
    if len(u) != start_dimensions(N):
        raise ValueError(f"a start point for {N} elements has {start_dimensions(N)} "
                         f"coordinates, got {len(u)}")
    f = spec.efl_mm
    signs = _pick(sign_patterns(N), u[0])
    ug, up, ub = u[1:1 + N], u[1 + N:1 + 2 * N], u[1 + 2 * N:1 + 3 * N]
    ut = u[1 + 3 * N:4 * N]
    us, ua = u[4 * N], u[4 * N + 1]
    glasses = (glass_strategy or crown_flint_by_sign)(spec.glass_list, signs, ug)
    # beyond three elements the powers and spacings shrink with the count (the total power
    # and length are shared): |f phi_i| in 0.6 + 3.9 min(1, 3/N) [0, 1), spacings
    # f (0.03 + 0.22 [0, 1)) min(1, 3/(N-1))
    mags = [0.6 + 3.9 * min(1.0, 3.0 / N) * x for x in up]
    k = [m if s == "+" else -m for m, s in zip(mags, signs)]
    spacings = [f * (0.03 + 0.22 * x) * min(1.0, 3.0 / max(N - 1, 1)) for x in ut]
    bendings = [-0.75 + 1.5 * x for x in ub]
    stop = _pick(spec.stop_positions(), us)
    if stop in ("front", "back"):
        alpha = f * (0.005 + 0.1 * ua)
    else:
        alpha = 0.2 + 0.6 * ua
    return ThinLens(k, glasses, spacings, bendings, stop, alpha, signs)


def thin_lens_start(spec: DesignSpec, u, glass_strategy=None, dtype=torch.float64) -> Lens:
    """The thick lens (EFL exact, sensor at the paraxial image) of the start point ``u`` in
    ``[0, 1)^d`` (:func:`start_dimensions`), by the thin-lens solve (module docstring).

    ``glass_strategy(glasses, signs, u_glass) -> [glass spec per element]`` picks the glasses
    (default :func:`crown_flint_by_sign`).

    Raises:
        StartError: the point gives no usable lens.
    """
    tl = _layout(spec, u, glass_strategy)
    powers, spacings = thin_lens_solve(spec, tl.powers, spacings=tl.spacings,
                                       glasses=tl.glasses)
    if max(abs(p) * spec.efl_mm for p in powers) > 8.0:
        raise StartError("the thin-lens solve needs an element of more than 8x the system "
                         "power")
    tl.powers, tl.spacings = powers, spacings
    tl.bendings = [x + b for x, b in zip(best_form_bendings(tl, spec), tl.bendings)]
    return thick_lens(tl, spec, dtype=dtype)


def best_form_bending(n: float, p: float) -> float:
    """The thin lens's bending of least third-order spherical aberration:
    ``X = -2 (n^2 - 1) p / (n + 2)`` for the position factor ``p`` (module docstring;
    ``p = -1`` for an object at infinity, then ``X = 2 (n^2 - 1) / (n + 2)``, 0.714 at
    ``n = 1.5``: radii 1 : -6)."""
    return -2.0 * (n * n - 1.0) * p / (n + 2.0)


def best_form_bendings(tl: ThinLens, spec: DesignSpec) -> list[float]:
    """Each element's :func:`best_form_bending` for the position factor ``p = (u + u') /
    (u - u')`` of the marginal ray through it (``u``, ``u'``: its slopes before and after)."""
    s = spec.object_distance_mm
    y, u = 1.0, (0.0 if math.isinf(s) else 1.0 / s)
    out = []
    for i, phi in enumerate(tl.powers):
        u2 = u - y * phi
        p = (u + u2) / (u - u2) if u != u2 else 0.0
        out.append(best_form_bending(_indices(tl.glasses[i], spec)[0], p))
        u = u2
        if i < len(tl.spacings):
            y = y + tl.spacings[i] * u
    return out


def flat_start(spec: DesignSpec, u, glass_strategy=None, dtype=torch.float64) -> Lens:
    """A flat start (module docstring) with the layout of the point ``u``; the sensor one
    focal length behind the last surface."""
    tl = _layout(spec, u, glass_strategy)
    tl.powers = [k / spec.efl_mm for k in tl.powers]
    lens = thick_lens(tl, spec, flat=True, dtype=dtype)
    return lens
