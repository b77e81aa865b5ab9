"""Q-type (Forbes) aspheres (:mod:`deeplens.optics.surfaces.qtype`, OpticStudio's ``QED_TYPE``):
the polynomials against Forbes' closed forms, their defining orthogonality (by quadrature) and
scipy's Jacobi polynomials; the sag against optiland's independent Qbfs geometry (its own
recurrences) and against a direct evaluation of the Qcon formula; slopes against autograd;
gradients of a trace against central differences; reading, writing and refusals."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Plane, QType
from deeplens.optics.surfaces.qtype import (MAX_TERMS, jacobi_rows, qbfs_matrix, qcon_matrix,
                                            qtype_series)

F64 = torch.float64
A10 = [0.3, -0.2, 0.1, 0.05, -0.02, 0.01, 0.004, -0.002, 0.001, 0.0005]


def _poly(row, x):
    return sum(b * x ** j for j, b in enumerate(row))


def test_qbfs_closed_forms_and_orthonormal_slopes():
    """Q0 = 1, Q1 = (13 − 16x)/√19, Q2 = √(2/95) (29 − 4x(25 − 19x)) (Forbes 2007, eq. 2.4),
    and the slopes d/du[u²(1−u²)Q_m(u²)] orthonormal under (1−u²)^(-1/2)/(π/2) on [0, 1]
    (Gauss–Chebyshev quadrature, exact for these degrees)."""
    M = qbfs_matrix(MAX_TERMS)
    x = np.linspace(0, 1, 11)
    assert np.allclose(_poly(M[0], x), 1.0, atol=1e-15)
    assert np.allclose(_poly(M[1], x), (13 - 16 * x) / math.sqrt(19), atol=1e-14)
    assert np.allclose(_poly(M[2], x), math.sqrt(2 / 95) * (29 - 4 * x * (25 - 19 * x)),
                       atol=1e-14)
    # Gauss-Chebyshev on [-1, 1]: the even integrand's mean over [0, 1] under the weight
    n = 64
    u = np.cos((2 * np.arange(1, n + 1) - 1) * np.pi / (2 * n))
    w = np.full(n, np.pi / n) / np.pi    # ∫_{-1}^{1} f / sqrt(1-u²) du / π
    slopes = []
    for row in M:
        coef = np.zeros(2 * MAX_TERMS + 6)
        for j, b in enumerate(row):          # u²(1-u²) u^(2j) = u^(2j+2) - u^(2j+4)
            coef[2 * j + 2] += b
            coef[2 * j + 4] -= b
        p = np.polynomial.Polynomial(coef).deriv()
        slopes.append(p(u))
    # the same slopes from the surface's own (Jacobi-basis) evaluation, by autograd in u
    ut = torch.tensor(u, requires_grad=True)
    for m in range(MAX_TERMS):
        beta = [torch.tensor(v, dtype=F64) for v in jacobi_rows("qbfs", MAX_TERMS)[m]]
        q, _ = qtype_series(ut * ut, beta)
        g, = torch.autograd.grad((ut * ut * (1 - ut * ut) * q).sum(), ut)
        # the monomial rows agree up to their own round-off (coefficients up to ~1e7)
        assert np.abs(g.numpy() - slopes[m]).max() < 1e-8, m
        slopes[m] = g.numpy()   # orthonormality is checked on the surface's evaluation
    G = np.array([[np.sum(w * a * b) for b in slopes] for a in slopes])
    assert np.abs(G - np.eye(MAX_TERMS)).max() < 1e-13


def test_qcon_is_the_jacobi_polynomial():
    """The monomial rows (exact rationals) against scipy's Jacobi polynomials (round-off of the
    monomial sum: their coefficients reach 3e7), and the surface's recurrence to 1e-13."""
    from scipy.special import eval_jacobi

    M = qcon_matrix(MAX_TERMS)
    x = np.linspace(0, 1, 13)
    for m, row in enumerate(M):
        ref = eval_jacobi(m, 0, 4, 2 * x - 1)
        assert np.abs(_poly(row, x) - ref).max() <= 1e-16 * sum(abs(b) for b in row) * 100, m
        beta = [torch.tensor(v, dtype=F64) for v in jacobi_rows("qcon", MAX_TERMS)[m]]
        S, dS = qtype_series(torch.tensor(x), beta)
        assert np.abs(S.numpy() - ref).max() < 1e-12, m
        dref = 0.5 * (m + 5) * eval_jacobi(m - 1, 1, 5, 2 * x - 1) * 2 if m else 0 * x
        assert np.abs(dS.numpy() - dref).max() < 1e-11 * max(1.0, np.abs(dref).max()), m
    assert np.allclose(_poly(M[1], x), -(5 - 6 * x), atol=1e-15)    # Forbes 2007, eq. (2.6)
    assert np.allclose(_poly(M[2], x), 15 - 14 * x * (3 - 2 * x), atol=1e-14)


def _points(n=300, r=9.0, seed=0):
    rng = np.random.default_rng(seed)
    rr = r * np.sqrt(rng.random(n))
    t = 2 * np.pi * rng.random(n)
    return rr * np.cos(t), rr * np.sin(t)


@pytest.mark.parametrize("k", [0.0, -0.6, 1.5])
def test_qbfs_sag_matches_optiland(k):
    """10 terms on a conic base (R = 25 mm, ρ_n = 9 mm): optiland's Forbes Qbfs geometry (its
    own Clenshaw recurrences) to 1e-13 mm, inside the normalisation radius."""
    pytest.importorskip("optiland")
    from optiland.coordinate_system import CoordinateSystem
    from optiland.geometries import ForbesQNormalSlopeGeometry, ForbesSurfaceConfig

    g = ForbesQNormalSlopeGeometry(CoordinateSystem(), ForbesSurfaceConfig(
        radius=25.0, conic=k, norm_radius=9.0, terms=dict(enumerate(A10))))
    x, y = _points()
    zo = np.asarray(g.sag(x, y))
    s = QType(1 / 25.0, 9.5, 9.0, A10, "qbfs", conic=k)
    zd = s.sag(torch.tensor(x), torch.tensor(y)).detach().numpy()
    assert np.abs(zo).max() > 1.0
    assert np.abs(zo - zd).max() < 1e-13


@pytest.mark.parametrize("k", [0.0, -1.0, 0.7])
def test_qcon_sag_matches_the_formula(k):
    """z = c r²/(1 + sqrt(1 − (1+k)c²r²)) + u⁴ Σ a_m P_m^(0,4)(2u² − 1), written here with
    scipy's Jacobi polynomials."""
    from scipy.special import eval_jacobi

    c, rn = -1 / 30.0, 9.0
    x, y = _points()
    r2 = x * x + y * y
    u2 = r2 / rn ** 2
    z = c * r2 / (1 + np.sqrt(1 - (1 + k) * c * c * r2))
    z = z + u2 ** 2 * sum(a * eval_jacobi(m, 0, 4, 2 * u2 - 1) for m, a in enumerate(A10))
    s = QType(c, 9.5, rn, A10, "qcon", conic=k)
    zd = s.sag(torch.tensor(x), torch.tensor(y)).detach().numpy()
    assert np.abs(z - zd).max() < 1e-14


@pytest.mark.parametrize("kind", ["qbfs", "qcon"])
def test_slopes_and_paraxial_curvature(kind):
    s = QType(1 / 25.0, 9.5, 9.0, A10, kind, conic=-0.4)
    x, y = (torch.tensor(v, requires_grad=True) for v in _points(100))
    z = s.sag(x, y)
    gx, gy = torch.autograd.grad(z.sum(), (x, y))
    sx, sy = s.sag_grad(x, y)
    assert torch.allclose(sx, gx, atol=1e-13, rtol=0) and torch.allclose(sy, gy, atol=1e-13,
                                                                          rtol=0)
    # the vertex curvature: second derivative of the sag at r -> 0
    h = 1e-4
    r = torch.tensor([h], dtype=F64)
    c_num = float(2 * s.sag(torch.zeros_like(r), r)[0] / h ** 2)
    assert float(s.paraxial_curvature()) == pytest.approx(c_num, rel=1e-6)
    if kind == "qcon":
        assert float(s.paraxial_curvature()) == 1 / 25.0


def _lens(a0=0.05, c=1 / 30.0):
    s = QType(c, 6.0, 6.5, [a0, -0.02, 0.01], "qbfs")
    return Lens([s, Plane(6.0)], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 30.0, 0), s


def test_trace_gradients_match_central_differences():
    def q(a0, c):
        lens, s = _lens(a0, c)
        s.a[0].requires_grad_(True)
        s.c.requires_grad_(True)
        y = torch.linspace(-5.0, 5.0, 9, dtype=F64)
        o = torch.stack([0.3 * y, y, torch.full_like(y, -1.0)], -1)
        d = torch.tensor([0.0, 0.05, 1.0], dtype=F64).expand(9, 3)
        out = lens.trace_to_sensor(Rays(o, d, 587.0))
        assert out.valid.all()
        return (out.o[:, 1] ** 2).sum() + out.opl.sum(), s

    v, s = q(0.05, 1 / 30.0)
    v.backward()
    for name, h in (("a0", 1e-6), ("c", 1e-7)):
        if name == "a0":
            fd = float((q(0.05 + h, 1 / 30.0)[0] - q(0.05 - h, 1 / 30.0)[0]).detach()) / (2 * h)
            ad = float(s.a[0].grad)
        else:
            fd = float((q(0.05, 1 / 30.0 + h)[0] - q(0.05, 1 / 30.0 - h)[0]).detach()) / (2 * h)
            ad = float(s.c.grad)
        assert abs(fd) > 1e-2
        assert ad == pytest.approx(fd, rel=1e-6), name


@pytest.mark.parametrize("kind", ["qbfs", "qcon"])
def test_zmx_and_lens_file_round_trip(tmp_path, kind):
    s = QType(-1 / 40.0, 6.0, 6.5, [0.01, -0.003, 0.002], kind,
              conic=0.0 if kind == "qbfs" else -0.5)
    lens = Lens([Plane(6.0), s], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 30.0, 0)
    d = lens_to_dict(lens)
    assert lens_to_dict(lens_from_dict(d)) == d
    write_zmx(lens, tmp_path / "q.zmx")
    text = (tmp_path / "q.zmx").read_text()
    assert "TYPE QED_TYPE" in text and f"XDAT 1 {1 if kind == 'qcon' else 0}" in text
    back = read_zmx(tmp_path / "q.zmx")
    a, b = lens_to_dict(lens), lens_to_dict(back)
    a.pop("name", None), b.pop("name", None)
    assert a == b
    assert float(paraxial(back).efl) == float(paraxial(lens).efl)


def test_corpus_file_qbfs_on_a_conic_loads_or_is_refused_at_its_type_line(tmp_path):
    """thorlabs_ASL5040-UV (its Corning glass C79-80 swapped for N-BK7, so that only the
    surface is tested): its Qbfs on a conic base (k = -0.676) loads with Forbes' conic
    generalisation (tests/optics/io/test_zmx_qbfs_conic.py) and, with
    ``qbfs_conic="refuse"``, is refused at the TYPE line; read as Qcon it loads (the reading
    of XDAT 1..9 and its units)."""
    from pathlib import Path

    from deeplens.optics.io.agf import decode_zemax_text

    path = Path(__file__).resolve().parents[2] / "data" / "zmx_real" / "thorlabs_ASL5040-UV.zmx"
    text = decode_zemax_text(path).replace("GLAS C79-80 ", "GLAS N-BK7 ")
    p = tmp_path / "asl.zmx"
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = read_zmx(p).surfaces[0]
    assert isinstance(s, QType) and s.kind == "qbfs" and float(s.k) == -0.67609120640407927
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(p, qbfs_conic="refuse")
    assert p.read_text().splitlines()[e.value.line - 1].split() == ["TYPE", "QED_TYPE"]
    assert "Qbfs surface on a conic base" in str(e.value)
    q = tmp_path / "asl_qcon.zmx"
    q.write_text(text.replace("XDAT 1 0.000000000000E+00", "XDAT 1 1.000000000000E+00"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = read_zmx(q)
    s = lens.surfaces[0]
    assert isinstance(s, QType) and s.kind == "qcon" and float(s.norm_radius) == 27.0
    assert [float(v) for v in s.a] == [-0.8148370167576, -0.32311, 0.10591, -0.05058, 0.00987,
                                       -0.0022]
    assert float(s.k) == -0.67609120640407927


def test_rays_through_a_qbfs_lens_land_where_optiland_lands_them():
    """A Qbfs front surface on a conic (R 30 mm, k −0.5, ρ_n 6.5 mm, 3 terms) of a plano lens:
    meridional and skew rays from optiland's own trace meet the image plane where optiland's
    Forbes geometry puts them (to 1e-9 mm: optiland's Newton tolerance); and the type runs eager
    under a compiled trace (no Newton kernels)."""
    pytest.importorskip("optiland")
    import optiland.backend as be
    from optiland.materials import IdealMaterial
    from optiland.optic import Optic

    from deeplens.optics.options import TraceOptions
    from deeplens.optics.tracer import fused_kind

    a = [0.05, -0.02, 0.01]
    optic = Optic()
    optic.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    optic.surfaces.add(index=1, radius=30.0, thickness=4.0, conic=-0.5,
                       surface_type="forbes_qbfs", radial_terms=dict(enumerate(a)),
                       norm_radius=6.5, material=IdealMaterial(n=1.6), is_stop=True)
    optic.surfaces.add(index=2, radius=be.inf, thickness=30.0)
    optic.surfaces.add(index=3)
    optic.set_aperture(aperture_type="EPD", value=10)
    optic.fields.set_type(field_type="angle")
    optic.fields.add(y=0)
    optic.fields.add(y=5)
    optic.wavelengths.add(value=0.587, is_primary=True)
    lens = Lens([QType(1 / 30.0, 6.0, 6.5, a, "qbfs", conic=-0.5), Plane(6.0)],
                [Air(), ModelGlass(1.6, math.inf), Air()], [0.0, 4.0], 30.0, 0)
    assert fused_kind(lens, 0) is None

    def at(arr, i):
        return float(torch.as_tensor(arr)[i].reshape(-1)[0])

    for H, P in [((0, 0), (0, 1)), ((0, 1), (0.3, -0.7)), ((0, 0.5), (0.6, 0.6)),
                 ((0, 1), (0, 0))]:
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
