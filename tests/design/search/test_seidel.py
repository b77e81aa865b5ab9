"""Third-order (Seidel) sums and the third-order screen (deeplens.design.search.seidel).

Oracles: optiland's third-order aberrations (``optiland.aberrations``, test-only) on the shipped
Cooke triplet and a singlet, per surface, after the convention mapping (optiland's
``SeidelAberrations.seidels()`` is ``-`` Welford's ``S_I..S_V``, i.e. its per-surface
transverse terms are ``TSC = S_I / (2 n' u')`` etc. and ``TAchC = C_I / (n' u')``,
``TchC = C_II / (n' u')`` with ``δn = n_short - n_long``); closed forms (the Coddington
best-form bending, the thin-lens Petzval sum); the real ray trace (the third-order RMS spot of a
slow singlet against :func:`~deeplens.design.search.result.evaluate`).
"""

import math

import pytest
import torch

from deeplens.design.search import DesignSpec
from deeplens.design.search import seidel as sd
from deeplens.design.search.result import evaluate
from deeplens.design.search.start import best_form_bending, place_sensor
from deeplens.optics.io import load_lens
from deeplens.optics.lens import Lens, LensSpec
from deeplens.optics.materials import Air, get_material
from deeplens.optics.paraxial import paraxial
from deeplens.optics.surfaces import Aperture, Asphere

WL = [486.1327, 587.5618, 656.2725]


def _singlet(fno=16.0, hfov=2.0, waves=(587.5618,), stop_gap=10.0):
    """A N-BK7 singlet of f ~ 100 mm near its best form, the stop ``stop_gap`` mm in front;
    the sensor at the paraxial image."""
    n = float(get_material("N-BK7").n(587.5618))
    X, phi = 0.7, 0.01
    c1, c2 = phi * (X + 1) / (2 * (n - 1)), phi * (X - 1) / (2 * (n - 1))
    epd = 100.0 / fno
    spec = LensSpec(object_distance_mm=math.inf, aperture_type="epd", aperture_value=epd,
                    fields_deg=[0.0, 0.7 * hfov, hfov], wavelengths_nm=list(waves),
                    primary_wavelength_nm=587.5618)
    lens = Lens([Aperture(epd / 2), Asphere(c1, 8.0), Asphere(c2, 8.0)],
                [Air(), Air(), get_material("N-BK7"), Air()], [0.0, stop_gap, 3.0],
                d_sensor=100.0, stop_index=0, spec=spec).to(torch.float64)
    place_sensor(lens)
    return lens


def _optiland_sums(lens, hfov):
    """optiland's per-surface terms of ``lens`` (its indices at the lens's wavelengths as
    ideal, non-dispersive media, one optic per wavelength for the index differences) and the
    :class:`~.seidel.ParaxialSystem` built from the same numbers."""
    pytest.importorskip("optiland")
    import numpy as np
    import optiland.backend as be
    from optiland.aberrations import ThirdOrderAberrations
    from optiland.materials import BaseMaterial
    from optiland.optic import Optic

    sysd = sd.lens_system(lens, WL)
    c, d = sysd.c[0].tolist(), sysd.d[0].tolist()
    S = len(c)
    epd = float(paraxial(lens).entrance_pupil_diameter)
    # a material whose index at each of the three wavelengths is ours (optiland's own glass
    # models would differ in the last digits), so both sides see the same numbers

    class Table(BaseMaterial):
        def __init__(self, values):
            super().__init__()
            self.values = values

        def _calculate_n(self, wavelength, **kwargs):
            w = float(np.asarray(wavelength).reshape(-1)[0]) * 1e3
            return be.array(self.values[min(range(3), key=lambda i: abs(WL[i] - w))])

        def _calculate_k(self, wavelength, **kwargs):
            return be.array(0.0)

    op = Optic()
    op.surfaces.add(index=0, radius=np.inf, thickness=np.inf)
    for j in range(S):
        th = d[j + 1] if j + 1 < S else float(lens.d_sensor)
        vals = [float(sysd.n[0, k, j + 1]) for k in range(3)]
        mat = "air" if max(abs(v - 1.0) for v in vals) == 0 else Table(vals)
        op.surfaces.add(index=j + 1, radius=1 / c[j] if c[j] != 0 else np.inf, thickness=th,
                        material=mat, is_stop=(j == sysd.stop))
    op.surfaces.add(index=S + 1)
    op.set_aperture(aperture_type="EPD", value=epd)
    op.fields.set_type("angle")
    op.fields.add(y=0.0)
    op.fields.add(y=hfov)
    for k, w in enumerate(WL):
        op.wavelengths.add(value=w * 1e-3, is_primary=(k == 1))
    t = ThirdOrderAberrations(op)
    TSC, SC, CC, TCC, TAC, AC, TPC, PC, DC, TAchC, LchC, TchC, Ssum = t.third_order()
    ref = {"S": np.stack([np.asarray(x) for x in (TSC, CC, TAC, TPC, DC)]),
           "C": np.stack([np.asarray(TAchC), np.asarray(TchC)]), "sum": np.asarray(Ssum).reshape(-1)}
    return sysd, epd, ref


def _check_against_optiland(lens, hfov):
    sysd, epd, ref = _optiland_sums(lens, hfov)
    mine = sd.seidel_sums(sysd, epd, hfov, short=0, long=2)
    nu = float(mine["nu_image"][0])
    S = mine["S"][0].numpy()
    C = mine["C"][0].numpy()
    scale = max(abs(S).max(), 1e-3)
    # per surface: S_k = 2 n'u' (optiland's transverse term), C_k = n'u' (its term)
    for i, name in enumerate(("S_I", "S_II", "S_III", "S_IV", "S_V")):
        err = abs(S[i] - 2 * nu * ref["S"][i]).max()
        assert err <= 1e-12 * scale, f"{name}: {S[i]} vs optiland {2 * nu * ref['S'][i]}"
    cscale = max(abs(C).max(), 1e-6)
    for i, name in enumerate(("C_I", "C_II")):
        err = abs(C[i] - nu * ref["C"][i]).max()
        assert err <= 1e-12 * cscale, f"{name}: {C[i]} vs optiland {nu * ref['C'][i]}"
    # the system sums: optiland's seidels() is minus Welford's
    assert abs(S.sum(1) + ref["sum"]).max() <= 1e-12 * scale


def test_cooke_triplet_sums_match_optiland():
    lens = load_lens("data/lenses/cooke_triplet.json").to(torch.float64)
    _check_against_optiland(lens, 11.86)


def test_singlet_sums_match_optiland():
    _check_against_optiland(_singlet(fno=4.0, hfov=10.0, waves=WL), 10.0)


def test_planted_sign_error_is_caught(monkeypatch):
    """A sign flipped in any one sum makes the optiland comparison fail."""
    lens = load_lens("data/lenses/cooke_triplet.json").to(torch.float64)
    real = sd._sums
    for which in range(5):
        def planted(*a, _w=which, **k):
            out = real(*a, **k)
            S = out["S"].clone()
            S[:, _w] = -S[:, _w]
            out["S"] = S
            return out

        monkeypatch.setattr(sd, "_sums", planted)
        with pytest.raises(AssertionError):
            _check_against_optiland(lens, 11.86)
    monkeypatch.setattr(sd, "_sums", real)
    _check_against_optiland(lens, 11.86)


def _thin(phi, X, t, n, stop, alpha):
    B = phi.shape[0]
    nw = n[:, None, :].expand(B, 1, n.shape[1]) if n.dim() == 2 else n
    return sd.thin_system(phi, X, t, nw, stop, alpha)


def test_singlet_spherical_minimal_at_coddington_best_form():
    """Thin singlet, object at infinity: S_I(X) is a parabola with its minimum at
    X = 2 (n² - 1) / (n + 2) (Coddington; start.best_form_bending(n, -1))."""
    for n in (1.5, 1.6, 1.8):
        X = torch.linspace(-1.0, 2.5, 351, dtype=torch.float64)
        B = X.numel()
        phi = torch.full((B, 1), 0.01, dtype=torch.float64)
        sys_ = _thin(phi, X[:, None], torch.zeros(B, 0, dtype=torch.float64),
                     torch.full((B, 1), n, dtype=torch.float64), "front",
                     torch.zeros(B, dtype=torch.float64))
        S1 = sd.seidel_sums(sys_, 10.0, 0.0)["S"][:, 0].sum(-1)
        # fit the parabola exactly (three points determine it; it is exactly quadratic in X)
        a = torch.linalg.lstsq(torch.stack([X ** 2, X, torch.ones_like(X)], 1),
                               S1[:, None]).solution[:, 0]
        resid = (torch.stack([X ** 2, X, torch.ones_like(X)], 1) @ a - S1).abs().max()
        assert resid <= 1e-12 * S1.abs().max()
        assert a[0] > 0
        xmin = float(-a[1] / (2 * a[0]))
        assert xmin == pytest.approx(best_form_bending(n, -1.0), abs=1e-9)
        assert xmin == pytest.approx(2 * (n * n - 1) / (n + 2), abs=1e-9)


def test_thin_lens_petzval_sum():
    """S_IV of thin elements = H² Σ φ_i / n_i, whatever the spacings and bendings."""
    g = torch.Generator().manual_seed(3)
    B, N = 7, 4
    phi = (torch.rand(B, N, generator=g, dtype=torch.float64) - 0.4) * 0.04
    X = torch.randn(B, N, generator=g, dtype=torch.float64)
    t = 5 + 20 * torch.rand(B, N - 1, generator=g, dtype=torch.float64)
    n = 1.45 + 0.4 * torch.rand(B, N, generator=g, dtype=torch.float64)
    sys_ = _thin(phi, X, t, n, 1, torch.full((B,), 0.4, dtype=torch.float64))
    out = sd.seidel_sums(sys_, 12.0, 15.0)
    S4 = out["S"][:, 3].sum(-1)
    expect = out["H"] ** 2 * (phi / n).sum(1)
    assert torch.allclose(S4, expect, rtol=1e-12, atol=0.0)
    assert (out["H"].abs() > 0).all()


def test_batched_equals_one_at_a_time():
    g = torch.Generator().manual_seed(5)
    B, N = 6, 3
    phi = torch.tensor([0.02, -0.035, 0.02], dtype=torch.float64) * (
        1 + 0.2 * torch.rand(B, N, generator=g, dtype=torch.float64))
    X = torch.randn(B, N, generator=g, dtype=torch.float64)
    t = 8 + 10 * torch.rand(B, N - 1, generator=g, dtype=torch.float64)
    n = torch.stack([1.62 + 0.01 * torch.rand(B, N, generator=g, dtype=torch.float64),
                     1.61 + 0.01 * torch.rand(B, N, generator=g, dtype=torch.float64),
                     1.63 + 0.01 * torch.rand(B, N, generator=g, dtype=torch.float64)], 1)
    alpha = torch.rand(B, generator=g, dtype=torch.float64)
    sys_ = sd.thin_system(phi, X, t, n, 1, alpha)
    full = sd.seidel_sums(sys_, 20.0, 12.0)
    rms = sd.third_order_rms(sys_, 20.0, 12.0, [0, 0.7, 1], [1, 1, 1], [0, 1, 1])
    for b in range(B):
        one = sd.thin_system(phi[b:b + 1], X[b:b + 1], t[b:b + 1], n[b:b + 1], 1,
                             alpha[b:b + 1])
        o = sd.seidel_sums(one, 20.0, 12.0)
        assert torch.equal(o["S"][0], full["S"][b]) and torch.equal(o["C"][0], full["C"][b])
        r1 = sd.third_order_rms(one, 20.0, 12.0, [0, 0.7, 1], [1, 1, 1], [0, 1, 1])
        assert torch.allclose(r1[0], rms[b], rtol=1e-14, atol=0.0)


@pytest.mark.parametrize("waves", [(587.5618,), tuple(WL)])
def test_third_order_rms_matches_the_ray_trace_of_a_slow_singlet(waves):
    """At F/16 and 2 deg the third order is the whole story: the merit (at the paraxial
    focus, the evaluation's rays) equals the traced polychromatic RMS spot within 2 %
    (fifth-order terms scale as (NA² or field²) relative: (1/32)² and (0.035)², each x a
    coefficient of order 10)."""
    hfov = 2.0
    lens = _singlet(fno=16.0, hfov=hfov, waves=waves)
    spec = DesignSpec(efl_mm=float(paraxial(lens).efl), fno=16.0, hfov_deg=hfov, elements=1,
                      wavelengths_nm=list(waves), glasses="N-BK7", stop="front")
    m = evaluate(lens, spec, "hexapolar:12")
    sysd = sd.lens_system(lens, list(waves))
    r3 = float(sd.third_order_rms(sysd, spec.epd, hfov, [0, 0.7, 1], spec.weights_of_fields,
                                  spec.wavelength_weights, rings=12, refocus=False))
    assert r3 == pytest.approx(m["rms_um"], rel=0.02)
    # refocusing can only lower it
    r3f = float(sd.third_order_rms(sysd, spec.epd, hfov, [0, 0.7, 1], spec.weights_of_fields,
                                   spec.wavelength_weights, rings=12))
    assert r3f <= r3 * (1 + 1e-12)


def test_screen_returns_thin_lenses_at_the_focal_length():
    spec = DesignSpec(efl_mm=100.0, fno=5.0, hfov_deg=10.0, elements=3, wavelengths_nm=WL,
                      glasses="SCHOTT", stop="middle")
    r = sd.seidel_screen(spec, 64, keep=4, seed=1, steps=5)
    assert r.sampled == 64 and 1 <= len(r.starts) <= 4
    assert r.rms_um == sorted(r.rms_um) or not all(r.feasible)
    for tl in r.starts:
        assert tl.efl() == pytest.approx(100.0, rel=1e-9)
        assert tl.stop == 1 and 0 < tl.alpha < 1
    again = sd.seidel_screen(spec, 64, keep=4, seed=1, steps=5)
    assert [t.powers for t in again.starts] == [t.powers for t in r.starts]
    with pytest.raises(ValueError, match="infinity"):
        sd.seidel_screen(DesignSpec(efl_mm=100.0, fno=5.0, hfov_deg=10.0, elements=3,
                                    wavelengths_nm=WL, glasses="SCHOTT",
                                    object_distance_mm=1000.0), 8, keep=1)


def test_lens_system_refuses_aspheres():
    lens = _singlet()
    with torch.no_grad():
        lens.surfaces[1].k.fill_(-0.5)
    with pytest.raises(ValueError, match="surface 1"):
        sd.lens_system(lens)


@pytest.mark.slow
def test_search_takes_its_starts_from_the_screen():
    """``seidel_screen``: the search's screened starts are the screen's (its record first, the
    starts named ``seidel``), the focal length exact; bad settings name the field."""
    from deeplens.design.search import SearchConfig, Stage, search

    spec = DesignSpec(efl_mm=100.0, fno=8.0, hfov_deg=3.0, elements=1,
                      wavelengths_nm=[587.5618], glasses="N-BK7,N-SK16", stop="front",
                      min_center_glass_mm=2.0, max_center_glass_mm=8.0, min_edge_glass_mm=0.5)
    cfg = SearchConfig(seed=0, starts=2, screen=(Stage(1, "hexapolar:2"),), polish_count=1,
                       polish=(Stage(1, "hexapolar:2"),), hops=0, keep=1,
                       score_sampling="hexapolar:2", final_sampling="hexapolar:3",
                       seidel_screen=128, seidel_steps=5)
    res = search(spec, cfg)
    assert res.runs[0]["origin"] == "seidel screen" and res.runs[0]["sampled"] == 128
    screened = [r for r in res.runs if r["origin"].startswith("start")]
    info = res.runs[0]   # the union of the plain and the re-balanced rankings (the default)
    assert 2 <= len(screened) == len(info["ranked"]) <= 4
    assert all(r["origin"].startswith("start seidel") for r in screened)
    for kind in ("plain", "rebalanced"):   # each ranking best first
        t3 = [t for t, k in zip(info["thick_rms_um"], info["ranked"]) if k == kind]
        assert t3 == sorted(t3) and len(t3) <= 2
    assert res.best.metrics["efl_mm"] == pytest.approx(100.0, rel=1e-9)
    with pytest.raises(ValueError, match="seidel_screen and seidel_steps must be >= 0"):
        SearchConfig(seidel_screen=-1)
    with pytest.raises(ValueError, match="start_kind='thin' and prescreen=0"):
        SearchConfig(seidel_screen=10, prescreen=20)


@pytest.mark.slow
def test_cli_flag(tmp_path, capsys):
    import json

    from helpers import run_cli

    args = ["design", "search", "--efl", "100", "--fno", "16", "--hfov", "2", "--elements", "1",
            "--wavelengths", "587.5618", "--glasses", "N-BK7", "--stop", "front", "--starts",
            "1", "--polish", "1", "--hops", "0", "--keep", "1", "--screen-steps", "1",
            "--polish-steps", "1", "--quiet", "--json", "--seidel-screen", "32",
            "--seidel-steps", "2", "--seidel-rebalance", "7", "--substitution", "nearest",
            "--out", str(tmp_path)]
    code, out, err = run_cli(args, capsys)
    assert code == 0, err
    res = json.loads((tmp_path / "result.json").read_text())
    assert res["config"]["seidel_screen"] == 32 and res["config"]["seidel_steps"] == 2
    assert res["config"]["seidel_rebalance"] == 7 and res["runs"][0]["rebalance"] == 7
    assert res["runs"][0]["rebalance_floor"] == "thin"
    assert res["config"]["substitution"] == "nearest"
    assert res["config"]["substitute_strategy"] == "combined"   # the command's default
    assert res["runs"][0]["origin"] == "seidel screen"
