"""Vector Snell's law (paper Eq. 9): Snell's invariant ``n1 sin θ1 = n2 sin θ2``, coplanarity
of ``d``, ``n`` and ``d_t``, total internal reflection, and float64 gradients (gradcheck)."""

import math

import pytest
import torch

from deeplens.optics.refract import refract, unit_normal

F64 = torch.float64


def _unit(v):
    return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True)


def _random_pairs(n, max_angle, seed):
    """Unit normals and unit directions at incidence angles up to ``max_angle`` rad."""
    g = torch.Generator().manual_seed(seed)
    normal = _unit(torch.randn(n, 3, generator=g, dtype=F64))
    # a unit vector perpendicular to the normal
    w = _unit(torch.linalg.cross(normal, torch.randn(n, 3, generator=g, dtype=F64)))
    th = max_angle * torch.rand(n, generator=g, dtype=F64)
    d = torch.cos(th).unsqueeze(-1) * normal + torch.sin(th).unsqueeze(-1) * w
    return d, normal, th


def _sin_angle(a, n):
    return torch.linalg.cross(a, n).norm(dim=-1)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5168), (1.5168, 1.0), (1.62, 1.75), (1.8, 1.45)])
@pytest.mark.parametrize("flip_normal", [False, True])
def test_snell_invariant_and_coplanarity(n1, n2, flip_normal):
    d, normal, th = _random_pairs(2000, math.radians(89.0), seed=int(100 * n1 + 10 * n2))
    if flip_normal:  # either orientation of the normal is accepted
        normal = -normal
    valid = torch.ones(2000, dtype=torch.bool)
    d_t, ok = refract(d, normal, n1 / n2, valid)
    sin1 = torch.sin(th)
    expect_ok = (n1 / n2) * sin1 <= 1.0
    assert torch.equal(ok, expect_ok)
    assert bool(ok.sum() > 500)
    dt = d_t[ok]
    # unit length
    assert float((dt.norm(dim=-1) - 1).abs().max()) < 1e-14
    # n1 sin θ1 = n2 sin θ2
    lhs = n1 * _sin_angle(d[ok], normal[ok])
    rhs = n2 * _sin_angle(dt, normal[ok])
    assert float((lhs - rhs).abs().max()) < 1e-13
    # coplanar: det[d, n, d_t] = 0
    det = torch.linalg.det(torch.stack([d[ok], normal[ok], dt], -2))
    assert float(det.abs().max()) < 1e-13
    # transmitted, not reflected: d_t stays on the side d travels to
    assert bool(((dt * normal[ok]).sum(-1) * (d[ok] * normal[ok]).sum(-1) > 0).all())
    # the tangential component keeps its direction (sign of d_t x n equals that of d x n)
    assert bool((torch.linalg.cross(dt, normal[ok]) * torch.linalg.cross(d[ok], normal[ok])
                 ).sum(-1).ge(0).all())


def test_normal_incidence_and_index_match_leave_direction():
    d = torch.tensor([[0.0, 0.0, 1.0], [0.3, -0.2, 0.9]], dtype=F64)
    d = _unit(d)
    normal = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], dtype=F64)
    d_t, ok = refract(d[:1], normal[:1], 1 / 1.5, torch.ones(1, dtype=torch.bool))
    assert torch.allclose(d_t, d[:1], atol=1e-15)
    d_t, ok = refract(d, normal, 1.0, torch.ones(2, dtype=torch.bool))
    assert torch.allclose(d_t, d, atol=1e-15) and bool(ok.all())


def test_total_internal_reflection_glass_to_air():
    """Glass (1.5168) to air: critical angle asin(1/1.5168) = 41.25 deg; beyond it the ray is
    invalid and its direction finite (the incident one)."""
    n_glass = 1.5168
    crit = math.asin(1 / n_glass)
    angles = torch.tensor([crit - 1e-6, crit + 1e-6, math.radians(60.0), math.radians(89.9)],
                          dtype=F64)
    d = torch.stack([torch.sin(angles), torch.zeros_like(angles), torch.cos(angles)], -1)
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(4, 3)
    d_t, ok = refract(d, normal, n_glass / 1.0, torch.ones(4, dtype=torch.bool))
    assert ok.tolist() == [True, False, False, False]
    assert bool(torch.isfinite(d_t).all())
    assert torch.equal(d_t[~ok], d[~ok])
    # just below the critical angle the ray leaves almost grazing
    assert float(d_t[0, 0]) > math.sin(math.radians(89.0))


def test_tir_gradient_is_finite():
    n_glass = torch.tensor(1.5168, dtype=F64, requires_grad=True)
    angles = torch.tensor([0.3, 0.9, 1.2], dtype=F64)
    d = torch.stack([torch.sin(angles), torch.zeros_like(angles), torch.cos(angles)], -1)
    d.requires_grad_(True)
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(3, 3)
    d_t, ok = refract(d, normal, n_glass, torch.ones(3, dtype=torch.bool))
    assert ok.tolist() == [True, False, False]
    loss = torch.where(ok, d_t[:, 0], torch.zeros_like(d_t[:, 0])).sum()
    g_d, g_n = torch.autograd.grad(loss, (d, n_glass))
    assert bool(torch.isfinite(g_d).all() and torch.isfinite(g_n))
    # the valid ray: d_t,x = eta sin(theta); d/d eta = sin(theta)
    assert float(g_n) == pytest.approx(math.sin(0.3), rel=1e-12)


def test_incoming_invalid_stays_invalid():
    d, normal, _ = _random_pairs(10, 0.5, seed=1)
    valid = torch.tensor([True, False] * 5)
    _, ok = refract(d, normal, 1 / 1.5, valid)
    assert torch.equal(ok, valid)


def test_refract_gradcheck_float64():
    d, normal, _ = _random_pairs(6, math.radians(35.0), seed=2)
    eta = torch.tensor([1 / 1.5, 1.3, 0.8, 1.1, 1 / 1.7, 1.4], dtype=F64)
    valid = torch.ones(6, dtype=torch.bool)

    def f(d_, n_, eta_):
        return refract(_unit(d_), _unit(n_), eta_, valid)[0]

    inputs = (d.clone().requires_grad_(True), normal.clone().requires_grad_(True),
              eta.clone().requires_grad_(True))
    assert bool(refract(d, normal, eta, valid)[1].all())
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-9, rtol=1e-7)


def test_unit_normal():
    fx = torch.tensor([3.0, 0.0], dtype=F64, requires_grad=True)
    fy = torch.tensor([0.0, 0.0], dtype=F64)
    fz = torch.tensor([-4.0, 0.0], dtype=F64)
    n = unit_normal(fx, fy, fz)
    assert torch.allclose(n[0], torch.tensor([0.6, 0.0, -0.8], dtype=F64), atol=1e-15)
    # a zero gradient gives a finite (zero) normal and finite derivatives
    assert bool(torch.isfinite(n).all())
    (g,) = torch.autograd.grad(n.sum(), fx)
    assert bool(torch.isfinite(g).all())


def test_ray_at_the_critical_angle_keeps_gradients_finite():
    """Regression (issue 12, defect 2): eta = 1.5 and cos_i = 0.7453559924999299 gave
    k = 1 - eta^2 (1 - cos_i^2) == 0.0 exactly; the ray was kept valid and d sqrt(k)/dk = inf
    made the gradient of a loss on *another* ray with respect to the shared eta NaN.  At the
    critical angle the refracted ray grazes the surface: it is marked invalid.  Since issue 38
    k is evaluated as (1 - eta)(1 + eta) + (eta cos_i)^2, which does not reach 0.0 at eta = 1.5,
    so every cos_i within 64 ulps of the critical one is tried, and k == 0 itself is reached at
    eta = 1 with cos_i = 0 (a ray in the surface's tangent plane)."""
    import numpy as np

    cos_c = 0.7453559924999299
    cands = [cos_c]
    for direction in (2.0, 0.0):
        c = cos_c
        for _ in range(64):
            c = float(np.nextafter(c, direction))
            cands.append(c)
    for cos_1 in cands:
        eta = torch.tensor(1.5, dtype=F64, requires_grad=True)
        normal = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], dtype=F64)
        d = torch.tensor([[0.0, 0.3, math.sqrt(1 - 0.09)], [0.0, math.sqrt(1 - cos_1 ** 2), cos_1]],
                         dtype=F64)
        d_t, ok = refract(d, normal, eta, torch.ones(2, dtype=torch.bool))
        assert bool(ok[0])
        loss = torch.where(ok, d_t[:, 1] + d_t[:, 2], torch.zeros_like(d_t[:, 1])).sum()
        (g,) = torch.autograd.grad(loss, eta)
        assert math.isfinite(float(g))
        (g0,) = torch.autograd.grad(refract(d, normal, eta, torch.ones(2, dtype=torch.bool)
                                            )[0][0, 1], eta)
        # closed form: d_t,y = eta d_y (the tangential component scales with eta)
        assert float(g0) == pytest.approx(0.3, rel=1e-14)
    # k == 0 exactly: eta = 1, the second ray in the tangent plane
    eta = torch.tensor(1.0, dtype=F64, requires_grad=True)
    d = torch.tensor([[0.0, 0.3, math.sqrt(1 - 0.09)], [0.0, 1.0, 0.0]], dtype=F64)
    normal = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], dtype=F64)
    d_t, ok = refract(d, normal, eta, torch.ones(2, dtype=torch.bool))
    assert ok.tolist() == [True, False]
    (g,) = torch.autograd.grad((d_t[:, 1] + d_t[:, 2]).sum(), eta)
    assert math.isfinite(float(g))


# ---------------------------------------------------------------- issue 38: grazing incidence
EPS32 = float(torch.finfo(torch.float32).eps)


def _grazing(cos_i, dtype):
    """Unit directions at ``cos ψ = cos_i`` to the normal (0.6, 0, 0.8), tangential part along a
    tilted in-plane vector, so that no component is trivially 0 or 1.  ``(N, 3)`` each."""
    c = torch.as_tensor(cos_i, dtype=F64)
    normal = torch.tensor([0.6, 0.0, 0.8], dtype=F64).expand(len(c), 3)
    w = _unit(torch.tensor([-0.8 * 0.6, 0.6, 0.6 * 0.6], dtype=F64)).expand(len(c), 3)
    d = c.unsqueeze(-1) * normal + torch.sqrt(1 - c * c).unsqueeze(-1) * w
    return d.to(dtype), normal.to(dtype)


COS_GRAZING = [0.3, 0.1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5, 1e-6, -1e-4, -1e-2]


def test_equal_indices_leave_the_direction_unchanged_at_grazing_incidence():
    """Issue 38: n1 == n2 must leave d as it is, also at grazing incidence in float32 (the
    textbook k = 1 - η²(1 - cos²ψ) rounds 1 - cos²ψ to 1 at cos ψ = 1e-4 and lost the ray)."""
    for dtype in (torch.float32, F64):
        d, normal = _grazing(COS_GRAZING, dtype)
        valid = torch.ones(len(COS_GRAZING), dtype=torch.bool)
        for n in (1.0, 1.5168):
            d_t, ok = refract(d, normal, torch.tensor(n, dtype=dtype) / torch.tensor(n, dtype=dtype),
                              valid)
            assert bool(ok.all())
            assert torch.equal(d_t, d)


@pytest.mark.parametrize("n1,n2", [(1.5168, 1.5168 * (1 + 1e-6)), (1.5168, 1.5168 * (1 + 1e-4)),
                                   (1.5168 * (1 + 1e-4), 1.5168), (1.0, 1.0 + 3e-7)])
def test_nearly_equal_indices_float32_matches_float64_at_grazing_incidence(n1, n2):
    """Float32 against float64 on the same (float32-rounded) inputs, η = n1/n2 within 1e-4 of 1,
    at incidence down to cos ψ = 1e-6.  Error budget of the float32 result: the inputs' own
    rounding enters through cos ψ = d·n (absolute error <= 3 eps) and η (relative eps), each
    times the derivative of d_t (∂coef/∂cos ψ, ∂coef/∂η, computed in float64), plus a few eps
    for the arithmetic; the tolerance is 8 times that.  Also Snell's invariant n1 sin θ1 =
    n2 sin θ2 on the float32 result, and the coefficient's *relative* accuracy (d_t - η d =
    coef n, the deviation itself, was cancelled away by sqrt(k) - η cos ψ)."""
    from deeplens.optics.refract import snell_coefficient

    eta32 = torch.tensor(n1, dtype=torch.float32) / torch.tensor(n2, dtype=torch.float32)
    eta64 = eta32.double()
    d32, nrm32 = _grazing(COS_GRAZING, torch.float32)
    d64, nrm64 = d32.double(), nrm32.double()
    c64 = (d64 * nrm64).sum(-1)
    valid = torch.ones(len(COS_GRAZING), dtype=torch.bool)
    k64 = 1 - eta64 ** 2 * (1 - c64 ** 2)
    keep = k64 > 64 * EPS32  # rays clear of total internal reflection (k's own rounding)
    assert int(keep.sum()) >= 3
    d_t32, ok32 = refract(d32, nrm32, eta32, valid)
    d_t64, ok64 = refract(d64, nrm64, eta64, valid)
    assert bool(ok32[keep].all() and ok64[keep].all())
    # derivatives of coef = sign(c) sqrt(k) - η c (float64, closed form)
    sk = torch.sqrt(k64.clamp_min(0))
    dcoef_dc = eta64 ** 2 * c64.abs() / sk - eta64
    dcoef_deta = -eta64 * (1 - c64 ** 2) / sk * torch.sign(c64) - c64
    coef64 = torch.sign(c64) * sk - eta64 * c64
    budget = EPS32 * (3 * dcoef_dc.abs() + eta64 * (1 + dcoef_deta.abs()) + 4 * (1 + coef64.abs()))
    err = (d_t32.double() - d_t64).abs().amax(-1)
    assert bool((err[keep] <= 8 * budget[keep]).all()), (err / budget)[keep]
    # Snell's invariant on the float32 result
    sin1 = _sin_angle(d64, nrm64)
    sin2 = _sin_angle(d_t32.double(), nrm64)
    assert bool(((n1 * sin1 - n2 * sin2).abs()[keep] <= 8 * n2 * budget[keep]).all())
    # the coefficient, relatively: (1 - η²)/(sqrt(k) + η|c|) has no cancellation
    c32 = (d32 * nrm32).sum(-1)
    coef32, _ = snell_coefficient(c32, eta32, valid)
    coef_ref, _ = snell_coefficient(c32.double(), eta64, valid)
    rel = ((coef32.double() - coef_ref) / coef_ref).abs()
    assert bool((rel[keep] <= 16 * EPS32).all()), rel[keep]


def test_refract_gradcheck_float64_at_grazing_incidence_near_equal_indices():
    """Gradients of the rewritten coefficient against central differences (float64), at
    grazing incidence with η = 1 and η within 1e-3 of 1 on either side."""
    d, normal = _grazing([0.05, 0.02, 0.1, -0.05, 0.3, 0.04], F64)
    eta = torch.tensor([1.0, 1 - 1e-3, 1 + 1e-3, 1.0, 0.9995, 1 - 1e-4], dtype=F64)
    valid = torch.ones(6, dtype=torch.bool)

    def f(d_, n_, eta_):
        return refract(_unit(d_), _unit(n_), eta_, valid)[0]

    assert bool(refract(d, normal, eta, valid)[1].all())
    inputs = (d.clone().requires_grad_(True), normal.clone().requires_grad_(True),
              eta.clone().requires_grad_(True))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-7, atol=1e-8, rtol=1e-6)
