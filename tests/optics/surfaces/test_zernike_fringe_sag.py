"""The Zernike Fringe sag (:class:`~deeplens.optics.surfaces.ZernikeFringeSag`, OpticStudio's
``FZERNSAG``): single terms against the Fringe polynomials written out here (the University of
Arizona FRINGE table; Z37 the 12th-order spherical as OpticStudio prints it), the numbering
against optiland's independent ``ZernikeFringe`` (terms 1..36; its 37th differs), the sag of all
37 terms against an independent factorial sum, slopes and parameter derivatives against central
differences (float64), the vertex curvature, the lens file, trace gradients and rays through a
lens against optiland's own trace of its Fringe geometry."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.options import TraceOptions
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Plane, ZernikeFringeSag, ZernikeSag
from deeplens.optics.surfaces.zernike_sag import fringe_nm

F64 = torch.float64
C, K, RN = 1 / 40.0, -0.5, 5.0
ALPHA = [1e-3, 2e-5, -3e-7]                       # r², r⁴, r⁶
# Fringe-ordered A_1..A_16 (mm): piston, tilts, defocus, astigmatism, coma, spherical, trefoil,
# secondary astigmatism and coma, secondary spherical
ZC = [1e-3, 2e-3, -1e-3, 0.01, 2e-3, 3e-3, -1e-3, 1e-3, 5e-4, -5e-4, 4e-4, 3e-4, -2e-4, 1e-4,
      2e-4, -2e-3]

#: the Fringe terms written out (FRINGE manual's table; OpticStudio's Z37)
TERMS = {
    1: lambda p, a: np.ones_like(p),
    2: lambda p, a: p * np.cos(a),
    3: lambda p, a: p * np.sin(a),
    4: lambda p, a: 2 * p ** 2 - 1,
    5: lambda p, a: p ** 2 * np.cos(2 * a),
    6: lambda p, a: p ** 2 * np.sin(2 * a),
    7: lambda p, a: (3 * p ** 3 - 2 * p) * np.cos(a),
    8: lambda p, a: (3 * p ** 3 - 2 * p) * np.sin(a),
    9: lambda p, a: 6 * p ** 4 - 6 * p ** 2 + 1,
    10: lambda p, a: p ** 3 * np.cos(3 * a),
    11: lambda p, a: p ** 3 * np.sin(3 * a),
    12: lambda p, a: (4 * p ** 4 - 3 * p ** 2) * np.cos(2 * a),
    13: lambda p, a: (4 * p ** 4 - 3 * p ** 2) * np.sin(2 * a),
    14: lambda p, a: (10 * p ** 5 - 12 * p ** 3 + 3 * p) * np.cos(a),
    15: lambda p, a: (10 * p ** 5 - 12 * p ** 3 + 3 * p) * np.sin(a),
    16: lambda p, a: 20 * p ** 6 - 30 * p ** 4 + 12 * p ** 2 - 1,
    17: lambda p, a: p ** 4 * np.cos(4 * a),
    18: lambda p, a: p ** 4 * np.sin(4 * a),
    25: lambda p, a: 70 * p ** 8 - 140 * p ** 6 + 90 * p ** 4 - 20 * p ** 2 + 1,
    26: lambda p, a: p ** 5 * np.cos(5 * a),
    35: lambda p, a: (126 * p ** 9 - 280 * p ** 7 + 210 * p ** 5 - 60 * p ** 3 + 5 * p)
    * np.sin(a),
    36: lambda p, a: (252 * p ** 10 - 630 * p ** 8 + 560 * p ** 6 - 210 * p ** 4 + 30 * p ** 2
                      - 1),
    37: lambda p, a: (924 * p ** 12 - 2772 * p ** 10 + 3150 * p ** 8 - 1680 * p ** 6
                      + 420 * p ** 4 - 42 * p ** 2 + 1),
}


def radial(n, m, p):
    """``R_n^|m|(ρ)`` by its factorial sum (independent of the surface's Jacobi recurrence)."""
    m = abs(m)
    return sum((-1) ** s * math.factorial(n - s)
               / (math.factorial(s) * math.factorial((n + m) // 2 - s)
                  * math.factorial((n - m) // 2 - s)) * p ** (n - 2 * s)
               for s in range((n - m) // 2 + 1))


def fringe_np(x, y, zc, rn=RN):
    """``Σ A_j Z_j`` with ``Z_j = R_n^|m| cos/sin(|m| φ)`` for the Fringe ``(n, m)`` of each j."""
    p, a = np.hypot(x, y) / rn, np.arctan2(y, x)
    out = np.zeros_like(p)
    for j, A in enumerate(zc, start=1):
        n, m = fringe_nm(j)
        ang = np.cos(m * a) if m >= 0 else np.sin(-m * a)
        out = out + A * radial(n, m, p) * ang
    return out


def sag_np(x, y, c=C, k=K, alpha=ALPHA, zc=ZC, rn=RN):
    r2 = x * x + y * y
    z = c * r2 / (1 + np.sqrt(1 - (1 + k) * c * c * r2))
    for i, a in enumerate(alpha, start=1):
        z = z + a * r2 ** i
    p, ang = np.hypot(x, y) / rn, np.arctan2(y, x)
    # the written-out table where it has the term, else the factorial sum of that term alone
    return z + sum(zc[j - 1] * TERMS[j](p, ang) if j in TERMS
                   else fringe_np(x, y, [0.0] * (j - 1) + [zc[j - 1]], rn)
                   for j in range(1, len(zc) + 1))


def _points(n=200, rmax=6.0, seed=0):
    rng = np.random.default_rng(seed)
    r = rmax * np.sqrt(rng.uniform(0, 1, n))
    t = rng.uniform(0, 2 * np.pi, n)
    return r * np.cos(t), r * np.sin(t)


@pytest.mark.parametrize("j", sorted(TERMS))
def test_each_term_is_the_fringe_polynomial(j):
    """One coefficient ``A_j`` alone on a flat base is ``A_j Z_j(ρ, φ)`` of the written-out Fringe
    table (to 1e-13 of its size), inside and a little beyond the normalisation radius; the
    neighbours ``Z_{j±1}`` are not it (a term index off by one fails here)."""
    zc = [0.0] * (j - 1) + [0.7]
    s = ZernikeFringeSag(0.0, 6.0, RN, zc)
    x, y = _points(60, 5.5, seed=j)
    z = s.sag(torch.tensor(x), torch.tensor(y)).numpy()
    p, a = np.hypot(x, y) / RN, np.arctan2(y, x)
    ref = 0.7 * TERMS[j](p, a)
    assert np.abs(z - ref).max() < 1e-13 * max(1.0, np.abs(ref).max())
    for other in (j - 1, j + 1):
        if other in TERMS:
            assert np.abs(z - 0.7 * TERMS[other](p, a)).max() > 1e-3


def test_fringe_numbering_matches_optiland_up_to_36():
    """``fringe_nm`` for j <= 36 against optiland's ZernikeFringe numbering (its own ``(n, m) ->
    j`` rule: the University of Arizona order); j = 37 is OpticStudio's 12th-order spherical,
    where optiland's open-ended rule continues with the next group (n = m = 6)."""
    pytest.importorskip("optiland")
    from optiland.zernike import ZernikeFringe

    seen = set()
    for j in range(1, 37):
        n, m = fringe_nm(j)
        assert abs(m) <= n and (n - m) % 2 == 0
        assert ZernikeFringe._index_to_number(n, m) == j
        seen.add((n, m))
    assert len(seen) == 36
    assert fringe_nm(37) == (12, 0) and ZernikeFringe._index_to_number(12, 0) == 49
    for bad in (0, 38):
        with pytest.raises(ValueError, match=r"runs 1..37"):
            fringe_nm(bad)


def test_sag_of_37_terms_is_the_factorial_sum_and_optilands_fringe():
    """37 random coefficients: the Zernike part against the factorial sum (to 1e-13 mm) and,
    for the first 36, against optiland's ZernikeFringe (to 1e-12 mm)."""
    rng = np.random.default_rng(1)
    A = rng.normal(size=37) * 1e-3
    s = ZernikeFringeSag(0.0, 6.0, RN, A.tolist())
    x, y = _points(150, 5.0, seed=2)
    X, Y = torch.tensor(x), torch.tensor(y)
    z = s.sag(X, Y).numpy()
    ref = fringe_np(x, y, A)
    assert np.abs(ref).max() > 1e-3
    assert np.abs(z - ref).max() < 1e-13
    pytest.importorskip("optiland")
    from optiland.zernike import ZernikeFringe

    s36 = ZernikeFringeSag(0.0, 6.0, RN, A[:36].tolist())
    ol = ZernikeFringe(coeffs=A[:36]).poly(np.hypot(x, y) / RN, np.arctan2(y, x))
    assert np.abs(s36.sag(X, Y).numpy() - ol).max() < 1e-12


def test_sag_is_the_closed_form():
    x, y = _points()
    s = ZernikeFringeSag(C, 6.5, RN, ZC, conic=K, coefficients=ALPHA)
    z = s.sag(torch.tensor(x), torch.tensor(y)).numpy()
    ref = sag_np(x, y)
    assert np.abs(ref).max() > 0.4
    assert np.abs(z - ref).max() < 1e-14
    # not the Zernike Standard surface of the same numbers
    st = ZernikeSag(C, 6.5, RN, ZC, conic=K, coefficients=ALPHA)
    assert np.abs(st.sag(torch.tensor(x), torch.tensor(y)).numpy() - ref).max() > 1e-3


def test_slopes_match_central_differences():
    """The analytic slopes against central differences of the written-out sag (h = 1e-6 mm:
    truncation ~ h² z''' ~ 1e-13, rounding ~ eps |z| / h ~ 1e-10) and against autograd of the
    surface's own sag (to round-off), the axis included."""
    x, y = _points(100, seed=3)
    x, y = np.append(x, 0.0), np.append(y, 0.0)
    s = ZernikeFringeSag(C, 6.5, RN, ZC, conic=K, coefficients=ALPHA)
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


def test_sag_parameter_derivatives_match_central_differences():
    """∂z/∂θ by autograd for c, k, α_1..α_3 and every A_j against central differences of the
    written-out sag (float64; the sag is linear in α and A, so only rounding enters there)."""
    x, y = _points(40, seed=4)
    s = ZernikeFringeSag(C, 6.5, RN, ZC, conic=K, coefficients=ALPHA)
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
    """``c + 2 α_1 + 2 Σ r_n A_j / R_n²`` (the ρ² coefficients r_n of the m = 0 Fringe terms:
    Z4 2, Z9 −6, Z16 12, Z37 −42): half the Laplacian of the sag at the vertex, by second
    differences; the unnormalised Fringe terms, not the Standard ones."""
    zc = ZC + [0.0] * 20 + [4e-4]
    s = ZernikeFringeSag(C, 6.5, RN, zc, conic=K, coefficients=ALPHA)
    h = 1e-3

    def z(x, y):
        return float(sag_np(np.array(x), np.array(y), zc=zc))
    lap = (z(h, 0) + z(-h, 0) + z(0, h) + z(0, -h) - 4 * z(0, 0)) / h ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(lap / 2, rel=1e-5)
    ref = C + 2 * ALPHA[0] + 2 * (2 * ZC[3] - 6 * ZC[8] + 12 * ZC[15] - 42 * 4e-4) / RN ** 2
    assert float(s.paraxial_curvature()) == pytest.approx(ref, rel=1e-14)
    sym = ZernikeFringeSag(C, 6.5, RN, [1e-3, 0, 0, 1e-3, 0, 0, 0, 0, 2e-4])
    assert sym.rotationally_symmetric() and not s.rotationally_symmetric()


def test_constructor_errors_and_lens_file():
    with pytest.raises(ValueError, match="ZernikeFringeSag: at most 37 Zernike terms"):
        ZernikeFringeSag(C, 5.0, RN, [0.0] * 38)
    ZernikeSag(C, 5.0, RN, [0.0] * 38)   # the Standard set goes on to 231
    lens = _lens()[0]
    d = lens_to_dict(lens)
    e = d["surfaces"][0]
    assert e["type"] == "zernike_fringe_sag" and e["zernike_coefficients"] == ZC
    back = lens_from_dict(d)
    assert type(back.surfaces[0]) is ZernikeFringeSag and lens_to_dict(back) == d
    with torch.no_grad():
        assert torch.equal(lens.trace_to_sensor(_rays()).o, back.trace_to_sensor(_rays()).o)


def _lens(c=C, k=K, alpha=ALPHA, zc=ZC):
    s = ZernikeFringeSag(c, 6.0, RN, zc, conic=k, coefficients=alpha)
    return Lens([s, Plane(6.0)], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 30.0, 0), s


def _rays():
    y = torch.linspace(-4.5, 4.5, 7, dtype=F64)
    o = torch.stack([0.3 * y, y, torch.full_like(y, -1.0)], -1)
    d = torch.tensor([0.01, 0.03, 1.0], dtype=F64)
    d = (d / d.norm()).expand(7, 3)
    return Rays(o, d, 587.0)


@pytest.mark.parametrize("name,h", [("c", 1e-7), ("z4", 1e-6), ("z8", 1e-6), ("z16", 1e-6)])
def test_trace_gradients_match_central_differences(name, h):
    """d/dθ of (Σ x_image² + Σ y_image² + Σ opl) through the lens, against central differences
    (float64; the FD truncation ~ h² and rounding ~ eps / h are both below 1e-6 relative)."""
    def q(delta):
        c, zc = C, list(ZC)
        if name == "c":
            c += delta
        else:
            zc[int(name[1:]) - 1] += delta
        lens, s = _lens(c, K, ALPHA, zc)
        p = s.c if name == "c" else s.zernike[int(name[1:]) - 1]
        p.requires_grad_(True)
        out = lens.trace_to_sensor(_rays())
        assert out.valid.all()
        return (out.o[:, :2] ** 2).sum() + out.opl.sum(), p

    v, p = q(0.0)
    ad, = torch.autograd.grad(v, p)
    fd = float((q(h)[0] - q(-h)[0]).detach()) / (2 * h)
    assert abs(fd) > 1e-3
    assert float(ad) == pytest.approx(fd, rel=2e-6)


def test_rays_land_where_optiland_lands_them():
    """A plano lens whose front is a Zernike Fringe sag (R 40 mm, k −0.5, ρ_n 6.5 mm, Fringe
    terms 1..16): rays from optiland's own trace of its ZernikeFringe geometry (tolerance
    1e-13) meet the image plane where deeplens puts them, to 1e-9 mm."""
    pytest.importorskip("optiland")
    import optiland.backend as be
    from optiland.materials import IdealMaterial
    from optiland.optic import Optic

    optic = Optic()
    optic.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    optic.surfaces.add(index=1, radius=40.0, thickness=4.0, conic=K, surface_type="zernike",
                       zernike_type="fringe", coefficients=ZC, norm_radius=6.5, tol=1e-13,
                       material=IdealMaterial(n=1.6), is_stop=True)
    optic.surfaces.add(index=2, radius=be.inf, thickness=30.0)
    optic.surfaces.add(index=3)
    optic.set_aperture(aperture_type="EPD", value=10)
    optic.fields.set_type(field_type="angle")
    optic.fields.add(y=0)
    optic.fields.add(y=5)
    optic.wavelengths.add(value=0.587, is_primary=True)
    lens = Lens([ZernikeFringeSag(1 / 40.0, 6.0, 6.5, ZC, conic=K), Plane(6.0)],
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
