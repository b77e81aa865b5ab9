"""The Zernike standard sag (:mod:`deeplens.optics.surfaces.zernike_sag`, OpticStudio's
``SZERNSAG``): single terms against their polynomials written out here (OpticStudio's Zernike
Standard table), Noll's numbering and the sag against optiland's independent ``ZernikeNoll``, the
slopes and parameter derivatives of the sag against central differences, ray hits against a
bisection, trace gradients against central differences, the paraxial curvature, the extrapolate
flag, float32, the lens file, and rays through a lens against optiland's own trace.

The checks the Zernike Fringe sag (``ZernikeFringeSag``) shares with it run here for both, over
``CASES``: the single terms, the closed form, slopes, parameter derivatives, the lens file, trace
gradients and optiland's trace, each against its own written-out table and coefficient
convention (the Fringe one from ``test_zernike_fringe_sag.py``)."""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np
import pytest
import test_zernike_fringe_sag as fringe
import torch
from helpers import disk_xy as _points

from deeplens.optics.intersect import intersect
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.options import TraceOptions
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Plane, ZernikeFringeSag, ZernikeSag
from deeplens.optics.surfaces.zernike_sag import noll_nm
from deeplens.optics.tracer import fused_kind

F64 = torch.float64
C, K, RN = 1 / 40.0, -0.5, 5.0
ALPHA = [1e-3, 2e-5, -3e-7]                       # r², r⁴, r⁶
# Noll-ordered A_1..A_11 (mm): piston, tilts, defocus, astigmatism, coma, trefoil, spherical
ZC = [1e-3, 2e-3, -1e-3, 0.01, 2e-3, 3e-3, -1e-3, 1e-3, 5e-4, -5e-4, -2e-3]

#: OpticStudio's Zernike Standard terms (its "Zernike Standard Coefficients" table), written out
TERMS = {
    1: lambda p, a: np.ones_like(p),
    2: lambda p, a: 2 * p * np.cos(a),
    3: lambda p, a: 2 * p * np.sin(a),
    4: lambda p, a: math.sqrt(3) * (2 * p ** 2 - 1),
    5: lambda p, a: math.sqrt(6) * p ** 2 * np.sin(2 * a),
    6: lambda p, a: math.sqrt(6) * p ** 2 * np.cos(2 * a),
    7: lambda p, a: math.sqrt(8) * (3 * p ** 3 - 2 * p) * np.sin(a),
    8: lambda p, a: math.sqrt(8) * (3 * p ** 3 - 2 * p) * np.cos(a),
    9: lambda p, a: math.sqrt(8) * p ** 3 * np.sin(3 * a),
    10: lambda p, a: math.sqrt(8) * p ** 3 * np.cos(3 * a),
    11: lambda p, a: math.sqrt(5) * (6 * p ** 4 - 6 * p ** 2 + 1),
    12: lambda p, a: math.sqrt(10) * (4 * p ** 4 - 3 * p ** 2) * np.cos(2 * a),
    13: lambda p, a: math.sqrt(10) * (4 * p ** 4 - 3 * p ** 2) * np.sin(2 * a),
    14: lambda p, a: math.sqrt(10) * p ** 4 * np.cos(4 * a),
    15: lambda p, a: math.sqrt(10) * p ** 4 * np.sin(4 * a),
    16: lambda p, a: math.sqrt(12) * (10 * p ** 5 - 12 * p ** 3 + 3 * p) * np.cos(a),
    17: lambda p, a: math.sqrt(12) * (10 * p ** 5 - 12 * p ** 3 + 3 * p) * np.sin(a),
    22: lambda p, a: math.sqrt(7) * (20 * p ** 6 - 30 * p ** 4 + 12 * p ** 2 - 1),
    37: lambda p, a: 3 * (70 * p ** 8 - 140 * p ** 6 + 90 * p ** 4 - 20 * p ** 2 + 1),
}


def zern_np(x, y, zc=ZC, rn=RN):
    """``Σ A_j Z_j`` from the written-out table (j <= 11 here)."""
    p, a = np.hypot(x, y) / rn, np.arctan2(y, x)
    return sum(zc[j - 1] * TERMS[j](p, a) for j in range(1, len(zc) + 1))


def sag_np(x, y, c=C, k=K, alpha=ALPHA, zc=ZC, rn=RN):
    r2 = x * x + y * y
    z = c * r2 / (1 + np.sqrt(1 - (1 + k) * c * c * r2))
    for i, a in enumerate(alpha, start=1):
        z = z + a * r2 ** i
    return z + zern_np(x, y, zc, rn)


class Case(NamedTuple):
    """One coefficient convention: the surface class, its ``A_1..`` (mm), the other convention's
    class (the same numbers on it are another surface), the written-out terms and sag (numpy, of
    ``(x, y, c, k, alpha, zc, rn)``), the least peak sag of ``sag_np`` (mm) at the sampled points,
    optiland's ``zernike_type`` and the lens file's ``type``."""
    cls: type
    zc: list
    other: type
    terms: dict
    sag_np: object
    peak: float
    optiland: str
    file_type: str


CASES = {
    "noll": Case(ZernikeSag, ZC, ZernikeFringeSag, TERMS, sag_np, 0.5, "noll", "zernike_sag"),
    "fringe": Case(ZernikeFringeSag, fringe.ZC, ZernikeSag, fringe.TERMS, fringe.sag_np, 0.4,
                   "fringe", "zernike_fringe_sag"),
}


@pytest.mark.parametrize("kind,j", [(k, j) for k, c in CASES.items() for j in sorted(c.terms)])
def test_each_term_is_the_written_out_polynomial(kind, j):
    """One coefficient ``A_j`` alone on a flat base is ``A_j Z_j(ρ, φ)`` of the written-out table
    (OpticStudio's Standard table; the Fringe table) to 1e-13 of its size, inside and a little
    beyond the normalisation radius (the polynomial continued); the neighbours ``Z_{j±1}`` are
    not it (an index off by one fails here)."""
    case = CASES[kind]
    zc = [0.0] * (j - 1) + [0.7]
    s = case.cls(0.0, 6.0, RN, zc)
    x, y = _points(60, 5.5, seed=j)
    z = s.sag(torch.tensor(x), torch.tensor(y)).numpy()
    p, a = np.hypot(x, y) / RN, np.arctan2(y, x)
    ref = 0.7 * case.terms[j](p, a)
    assert np.abs(z - ref).max() < 1e-13 * max(1.0, np.abs(ref).max())
    for other in (j - 1, j + 1):
        if other in case.terms:
            assert np.abs(z - 0.7 * case.terms[other](p, a)).max() > 1e-3


def test_noll_numbering_matches_optiland():
    """``noll_nm`` for every j <= 231 against optiland's ZernikeNoll numbering (its own
    ``(n, m) -> j`` rule; OpticStudio's Zernike Standard order)."""
    pytest.importorskip("optiland")
    from optiland.zernike import ZernikeNoll

    seen = set()
    for j in range(1, 232):
        n, m = noll_nm(j)
        assert abs(m) <= n and (n - m) % 2 == 0
        assert ZernikeNoll._index_to_number(n, m) == j
        seen.add((n, m))
    assert len(seen) == 231 and max(n for n, _ in seen) == 20


def test_sag_of_231_terms_matches_optiland_zernike_noll():
    """231 random coefficients (every n <= 20): the Zernike part against optiland's ZernikeNoll
    (explicit factorial sums), to 1e-11 mm (its monomial sums of ``R_20^0`` lose ~6 digits of
    ~1e-1: about 1e-12; ours uses the Jacobi recurrence)."""
    pytest.importorskip("optiland")
    from optiland.zernike import ZernikeNoll

    rng = np.random.default_rng(1)
    A = rng.normal(size=231) * 1e-3
    s = ZernikeSag(0.0, 6.0, RN, A.tolist())
    x, y = _points(150, 5.0, seed=2)
    z = s.sag(torch.tensor(x), torch.tensor(y)).numpy()
    ref = ZernikeNoll(coeffs=A).poly(np.hypot(x, y) / RN, np.arctan2(y, x))
    assert np.abs(ref).max() > 1e-2
    assert np.abs(z - ref).max() < 1e-11


@pytest.mark.parametrize("kind", CASES)
def test_sag_is_the_closed_form(kind):
    """The whole sag against the written-out one (to 1e-14 mm); not the other convention's
    surface of the same numbers."""
    case = CASES[kind]
    x, y = _points()
    s = case.cls(C, 6.5, RN, case.zc, conic=K, coefficients=ALPHA)
    z = s.sag(torch.tensor(x), torch.tensor(y)).numpy()
    ref = case.sag_np(x, y)
    assert np.abs(ref).max() > case.peak
    assert np.abs(z - ref).max() < 1e-14
    st = case.other(C, 6.5, RN, case.zc, conic=K, coefficients=ALPHA)
    assert np.abs(st.sag(torch.tensor(x), torch.tensor(y)).numpy() - ref).max() > 1e-3


@pytest.mark.parametrize("kind", CASES)
def test_slopes_match_central_differences(kind):
    """The analytic slopes against central differences of the written-out sag (h = 1e-6 mm:
    truncation ~ h² z''' ~ 1e-13, rounding ~ eps |z| / h ~ 1e-10) and against autograd of the
    surface's own sag (to round-off), the axis included."""
    case, sag_np = CASES[kind], CASES[kind].sag_np
    x, y = _points(100, seed=3)
    x, y = np.append(x, 0.0), np.append(y, 0.0)
    s = case.cls(C, 6.5, RN, case.zc, conic=K, coefficients=ALPHA)
    X, Y = torch.tensor(x), torch.tensor(y)
    gx, gy = s.sag_grad(X, Y)
    h = 1e-6
    fx = (sag_np(x + h, y) - sag_np(x - h, y)) / (2 * h)
    fy = (sag_np(x, y + h) - sag_np(x, y - h)) / (2 * h)
    assert np.abs(gx.numpy() - fx).max() < 1e-8
    assert np.abs(gy.numpy() - fy).max() < 1e-8
    Xg, Yg = X.clone().requires_grad_(True), Y.clone().requires_grad_(True)
    ax, ay = torch.autograd.grad(s.sag(Xg, Yg).sum(), (Xg, Yg))
    assert torch.allclose(ax, gx, atol=1e-15, rtol=0) and torch.allclose(ay, gy, atol=1e-15,
                                                                          rtol=0)


@pytest.mark.parametrize("kind", CASES)
def test_sag_parameter_derivatives_match_central_differences(kind):
    """∂z/∂θ by autograd for c, k, α_1..α_3 and every A_j against central differences of the
    written-out sag (float64; the sag is linear in α and A, so only rounding enters there)."""
    case, sag_np, ZC = CASES[kind], CASES[kind].sag_np, CASES[kind].zc
    x, y = _points(40, seed=4)
    s = case.cls(C, 6.5, RN, ZC, conic=K, coefficients=ALPHA)
    params = [s.c, s.k, *s.a, *s.zernike]
    for p in params:
        p.requires_grad_(True)
    X, Y = torch.tensor(x), torch.tensor(y)
    w = torch.linspace(0.5, 1.5, len(x), dtype=F64)
    grads = torch.autograd.grad((w * s.sag(X, Y)).sum(), params)
    base = dict(c=C, k=K, alpha=list(ALPHA), zc=list(ZC))

    def q(name, i, d):
        kw = {k: (list(v) if isinstance(v, list) else v) for k, v in base.items()}
        if name in ("c", "k"):
            kw[name] += d
        else:
            kw[name][i] += d
        return float((w.numpy() * sag_np(x, y, **kw)).sum())

    names = [("c", 0, 1e-7), ("k", 0, 1e-5)] + [("alpha", i, 1e-9) for i in range(3)] + \
        [("zc", i, 1e-5) for i in range(len(ZC))]
    for g, (name, i, h) in zip(grads, names):
        fd = (q(name, i, h) - q(name, i, -h)) / (2 * h)
        assert float(g) == pytest.approx(fd, rel=1e-6, abs=1e-9), (name, i)


def test_paraxial_curvature_is_the_mean_vertex_curvature():
    """``c + 2 α_1 + Σ`` (the r² terms of the m = 0 Zernikes): half the Laplacian of the sag at
    the vertex, by second differences (astigmatism has none on average)."""
    s = ZernikeSag(C, 6.5, RN, ZC + [0.0] * 10 + [3e-3], conic=K, coefficients=ALPHA)
    zc = ZC + [0.0] * 10 + [3e-3]
    h = 1e-3

    def z(x, y):
        r2 = x * x + y * y
        p, a = math.sqrt(r2) / RN, math.atan2(y, x)
        v = C * r2 / (1 + math.sqrt(1 - (1 + K) * C * C * r2)) + sum(
            al * r2 ** i for i, al in enumerate(ALPHA, start=1))
        return v + sum(zc[j - 1] * float(TERMS[j](np.array(p), a)) for j in TERMS
                       if j <= len(zc))
    lap = (z(h, 0) + z(-h, 0) + z(0, h) + z(0, -h) - 4 * z(0, 0)) / h ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(lap / 2, rel=1e-5)
    ref = C + 2 * ALPHA[0] + 2 * (math.sqrt(3) * 2 * ZC[3] - math.sqrt(5) * 6 * ZC[10]
                                  + math.sqrt(7) * 12 * 3e-3) / RN ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(ref, rel=1e-14)


def test_without_extrapolation_the_terms_stop_at_the_normalisation_radius():
    s0 = ZernikeSag(C, 6.5, RN, ZC, conic=K, coefficients=ALPHA, extrapolate=False)
    s1 = ZernikeSag(C, 6.5, RN, ZC, conic=K, coefficients=ALPHA)
    x = torch.tensor([1.0, 4.9, 5.1, 6.0], dtype=F64)
    y = torch.tensor([0.5, 0.0, 0.0, 1.0], dtype=F64)
    inside = (x * x + y * y) <= RN * RN
    assert torch.equal(s0.sag(x, y)[inside], s1.sag(x, y)[inside])
    ref = sag_np(x.numpy(), y.numpy(), zc=[])
    assert np.abs(s0.sag(x, y)[~inside].numpy() - ref[~inside]).max() < 1e-15
    assert not torch.allclose(s0.sag(x, y)[~inside], s1.sag(x, y)[~inside])


def test_float32_sag_within_its_rounding():
    """231 terms in float32: within ``eps32 × Σ|A_j N_j|`` of float64 (the recurrence's values
    stay at the level of the polynomials, |P| <= 1, so no cancellation of large monomials)."""
    rng = np.random.default_rng(5)
    A = (rng.normal(size=231) * 1e-3).tolist()
    s = ZernikeSag(C, 5.0, RN, A, conic=K)
    x, y = _points(200, 5.0, seed=6)
    z64 = s.sag(torch.tensor(x), torch.tensor(y))
    z32 = s.sag(torch.tensor(x, dtype=torch.float32), torch.tensor(y, dtype=torch.float32))
    scale = sum(abs(a) * math.sqrt(2 * (noll_nm(j + 1)[0] + 1)) for j, a in enumerate(A))
    err = float((z32.double() - z64).abs().max())
    assert err < 4 * 1.2e-7 * (scale + float(z64.abs().max()))


def _bisect_hit(o, d, lo=0.0, hi=20.0):
    def g(t):
        p = o + t * d
        return sag_np(p[0], p[1]) - p[2]
    assert g(lo) > 0 > g(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) > 0 else (lo, mid)
    return o + 0.5 * (lo + hi) * d


def test_intersection_matches_bisection():
    s = ZernikeSag(C, 6.5, RN, ZC, conic=K, coefficients=ALPHA)
    rng = np.random.default_rng(7)
    o = np.column_stack([rng.uniform(-4, 4, 12), rng.uniform(-4, 4, 12), np.full(12, -5.0)])
    d = np.column_stack([rng.uniform(-0.2, 0.2, 12), rng.uniform(-0.2, 0.2, 12), np.ones(12)])
    o = np.vstack([o, [0.0, 0.0, -5.0]])
    d = np.vstack([d, [0.0, 0.0, 1.0]])
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    t, x, ok = intersect(s, torch.tensor(o), torch.tensor(d),
                         torch.ones(len(o), dtype=torch.bool), TraceOptions())
    assert ok.all()
    ref = np.array([_bisect_hit(oi, di) for oi, di in zip(o, d)])
    assert np.abs(x.numpy() - ref).max() < 1e-12


def _lens(c=C, k=K, alpha=ALPHA, zc=ZC, cls=ZernikeSag):
    s = cls(c, 6.0, RN, zc, conic=k, coefficients=alpha)
    return Lens([s, Plane(6.0)], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 30.0, 0), s


def _rays():
    y = torch.linspace(-4.5, 4.5, 7, dtype=F64)
    o = torch.stack([0.3 * y, y, torch.full_like(y, -1.0)], -1)
    d = torch.tensor([0.01, 0.03, 1.0], dtype=F64)
    d = (d / d.norm()).expand(7, 3)
    return Rays(o, d, 587.0)


@pytest.mark.parametrize("kind,name,h", [
    *[("noll", n, h) for n, h in [("c", 1e-7), ("k", 1e-5), ("alpha1", 1e-8), ("z4", 1e-6),
                                  ("z6", 1e-6), ("z8", 1e-6), ("z11", 1e-6)]],
    *[("fringe", n, h) for n, h in [("c", 1e-7), ("z4", 1e-6), ("z8", 1e-6), ("z16", 1e-6)]]])
def test_trace_gradients_match_central_differences(kind, name, h):
    """d/dθ of (Σ x_image² + Σ y_image² + Σ opl) through the lens, against central differences
    (float64; the FD truncation ~ h² and rounding ~ eps / h are both below 1e-6 relative)."""
    def q(delta):
        c, k, alpha, zc = C, K, list(ALPHA), list(CASES[kind].zc)
        if name == "c":
            c += delta
        elif name == "k":
            k += delta
        elif name.startswith("alpha"):
            alpha[int(name[5:]) - 1] += delta
        else:
            zc[int(name[1:]) - 1] += delta
        lens, s = _lens(c, k, alpha, zc, CASES[kind].cls)
        p = {"c": s.c, "k": s.k}.get(name)
        if p is None:
            p = s.a[int(name[5:]) - 1] if name.startswith("alpha") else s.zernike[int(name[1:]) - 1]
        p.requires_grad_(True)
        out = lens.trace_to_sensor(_rays())
        assert out.valid.all()
        return (out.o[:, :2] ** 2).sum() + out.opl.sum(), p

    v, p = q(0.0)
    ad, = torch.autograd.grad(v, p)
    fd = float((q(h)[0] - q(-h)[0]).detach()) / (2 * h)
    assert abs(fd) > 1e-3
    assert float(ad) == pytest.approx(fd, rel=2e-6)


@pytest.mark.parametrize("kind", CASES)
def test_traces_eager_and_saves(kind):
    """No compiled Newton kernels (``fused_kind`` None); the lens file round-trips to the same
    surface class and the same trace."""
    case = CASES[kind]
    lens, s = _lens(zc=case.zc, cls=case.cls)
    assert fused_kind(lens, 0) is None
    d = lens_to_dict(lens)
    e = d["surfaces"][0]
    assert e["type"] == case.file_type and e["zernike_coefficients"] == case.zc
    assert e["even_coefficients"] == ALPHA and e["norm_radius_mm"] == RN
    back = lens_from_dict(d)
    assert type(back.surfaces[0]) is case.cls and lens_to_dict(back) == d
    with torch.no_grad():
        assert torch.equal(lens.trace_to_sensor(_rays()).o, back.trace_to_sensor(_rays()).o)
    d["surfaces"][0]["zernike_extrapolate"] = 2
    with pytest.raises(Exception, match=r"surfaces\[0\]\.zernike_extrapolate: must be 0 or 1"):
        lens_from_dict(d)


def test_constructor_errors():
    with pytest.raises(ValueError, match="at most 231 Zernike terms"):
        ZernikeSag(C, 5.0, RN, [0.0] * 232)
    with pytest.raises(ValueError, match="at most 8 even coefficients"):
        ZernikeSag(C, 5.0, RN, [], coefficients=[0.0] * 9)
    with pytest.raises(ValueError, match="normalisation radius"):
        ZernikeSag(C, 5.0, 0.0, [1e-3])
    with pytest.raises(ValueError, match="conic base"):
        ZernikeSag(1 / 5.0, 6.0, RN, [1e-3]).check()
    with pytest.raises(ValueError, match="starts at 1"):
        noll_nm(0)


@pytest.mark.parametrize("kind", CASES)
def test_rays_land_where_optiland_lands_them(kind):
    """A plano lens whose front is a Zernike standard (Noll terms 1..11) or Fringe (terms 1..16)
    sag (R 40 mm, k −0.5, ρ_n 6.5 mm): rays from optiland's own trace of its ZernikeNoll or
    ZernikeFringe geometry (tolerance 1e-13) meet the image plane where deeplens puts them, to
    1e-9 mm."""
    pytest.importorskip("optiland")
    import optiland.backend as be
    from optiland.materials import IdealMaterial
    from optiland.optic import Optic

    case, ZC = CASES[kind], CASES[kind].zc
    optic = Optic()
    optic.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    optic.surfaces.add(index=1, radius=40.0, thickness=4.0, conic=K, surface_type="zernike",
                       zernike_type=case.optiland, coefficients=ZC, norm_radius=6.5, tol=1e-13,
                       material=IdealMaterial(n=1.6), is_stop=True)
    optic.surfaces.add(index=2, radius=be.inf, thickness=30.0)
    optic.surfaces.add(index=3)
    optic.set_aperture(aperture_type="EPD", value=10)
    optic.fields.set_type(field_type="angle")
    optic.fields.add(y=0)
    optic.fields.add(y=5)
    optic.wavelengths.add(value=0.587, is_primary=True)
    lens = Lens([case.cls(1 / 40.0, 6.0, 6.5, ZC, conic=K), Plane(6.0)],
                [Air(), ModelGlass(1.6, math.inf), Air()], [0.0, 4.0], 30.0, 0)

    def at(arr, i):
        return float(torch.as_tensor(arr)[i].reshape(-1)[0])

    for H, P in [((0, 0), (0, 1)), ((0, 1), (0.3, -0.7)), ((0, 0.5), (0.6, 0.6)),
                 ((0, 1), (0, 0)), ((0, 0), (-0.8, 0.1))]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            optic.trace_generic(Hx=H[0], Hy=H[1], Px=P[0], Py=P[1], wavelength=0.587)
        sg = optic.surface_group
        p = torch.tensor([at(sg.x, 1), at(sg.y, 1), at(sg.z, 1)], dtype=F64)
        d = torch.tensor([at(sg.L, 0), at(sg.M, 0), at(sg.N, 0)], dtype=F64)
        out = lens.trace_to_sensor(Rays((p - d)[None], d[None], 587.0),
                                   options=TraceOptions(clip_aperture=False))
        ol = [at(sg.x, -1), at(sg.y, -1), at(sg.z, -1)]
        assert out.o[0].tolist() == pytest.approx(ol, abs=1e-9), (H, P)


@pytest.mark.parametrize("mode", ["surface", "lens"])
def test_fused_tracer_runs_it_eager_with_the_same_values_and_gradients(uncompiled, mode):
    """The double Gauss with its first surface a Zernike sag (its even asphere plus defocus,
    coma and spherical terms): the fused tracer's logic (``uncompiled``) leaves it to the eager
    path between its fused runs; rays, paths and gradients (c, A_8, A_11 of the Zernike sag, a
    later sphere's c) equal the eager tracer's."""
    import helpers as H

    from deeplens.optics.io import load_lens

    lens = load_lens(H.LENS_DIR / "double_gauss.json")
    s0 = lens.surfaces[0]
    sd = float(s0.semi_diameter)
    zs = ZernikeSag(float(s0.c), sd, 1.1 * sd, [0.0, 0.0, 0.0, 2e-3, 0.0, 0.0, 0.0, 5e-4, 0.0,
                                                0.0, -1e-3],
                    conic=float(s0.k), coefficients=[0.0] + [float(v) for v in s0.a][:7])
    lens.surfaces[0] = zs
    assert fused_kind(lens, 0) is None and fused_kind(lens, 4) is not None
    params = [zs.c, zs.zernike[7], zs.zernike[10], lens.surfaces[4].c]
    for p in params:
        p.requires_grad_(True)
    H.assert_compiled_run_equals_eager(lens, params, mode)


def test_parameter_scale_is_the_rim_sag_derivative():
    """``parameter_scale`` (the design/training step scale) of the even terms and the curvature:
    ∂(sag at the rim)/∂θ by autograd of the surface's own sag (α_i: R^(2i); c: R²/2 up to the
    conic's higher orders, which it ignores as for every asphere)."""
    from deeplens.optics.parameters import parameter_scale

    lens, s = _lens()
    R = torch.tensor(float(s.semi_diameter), dtype=F64)
    for i in range(len(ALPHA)):
        s.a[i].requires_grad_(True)
        g, = torch.autograd.grad(s.sag(R, torch.zeros_like(R)), s.a[i])
        assert parameter_scale(lens, f"surfaces.0.a.{i}") == pytest.approx(float(g), rel=1e-14)
    assert parameter_scale(lens, "surfaces.0.c") == pytest.approx(float(R) ** 2 / 2)
    assert parameter_scale(lens, "surfaces.0.zernike.3") == 1.0
