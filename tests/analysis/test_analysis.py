"""Analysis functions against closed forms, float64 finite differences and bad input.

Closed forms: the Zernike polynomials' indices and orthonormality; the aberration-free circular
pupil (the ACL5040U stopped down to F/20, whose residual wavefront is < 0.01 waves RMS): MTF
``(2/π)(acos v - v sqrt(1 - v²))``, ``v = ν λ F#``, Strehl 1 and the Airy encircled energy 0.838
at ``1.22 λ F#``; Maréchal's ``S ≈ exp(-(2π σ)²)`` once defocused; the thick-lens principal
planes ``h' = -f (n - 1) t / (n R_1)``.  The FFT and Huygens PSFs agree with each other.
"""

from __future__ import annotations

import json
import math

import helpers as H
import pytest
import torch

from deeplens.analysis.aberrations import (distortion, field_curvature, lateral_color,
                                           longitudinal_color, ray_fan, vignetting)
from deeplens.analysis.cardinal import cardinal_points, magnification, pupils
from deeplens.analysis.checks import AnalysisError
from deeplens.analysis.diffraction import (encircled_energy, geometric_mtf, mtf, mtf_at,
                                           psf_fft, psf_huygens, strehl)
from deeplens.optics.paraxial import paraxial
from deeplens.analysis.wavefront import (pupil_grid, wavefront, zernike_basis, zernike_fit,
                                         zernike_nm)
from deeplens.optics.io import lens_from_dict, load_lens
from deeplens.optics.surfaces import Aperture
from deeplens.optics.surfaces.asphere import Asphere

WL = H.WAVELENGTH_D
DG = H.LENS_DIR / "double_gauss.json"


@pytest.fixture(scope="module")
def dg():
    return load_lens(DG).to(torch.float64)


@pytest.fixture(scope="module")
def slow_acl():
    """The ACL5040U stopped down to a 1 mm semi-diameter (F/20): diffraction limited."""
    d = json.loads((H.LENS_DIR / "thorlabs_acl5040u.json").read_text())
    d["surfaces"][0]["semi_diameter_mm"] = 1.0
    return lens_from_dict(d).to(torch.float64)


# ----------------------------------------------------------------------------- Zernike
def test_zernike_indices():
    fringe = [(0, 0), (1, 1), (1, -1), (2, 0), (2, 2), (2, -2), (3, 1), (3, -1), (4, 0),
              (3, 3), (3, -3), (4, 2), (4, -2), (5, 1), (5, -1), (6, 0)]
    assert [zernike_nm(j, "fringe") for j in range(1, 17)] == fringe
    assert zernike_nm(37, "fringe") == (12, 0)
    standard = [(0, 0), (1, -1), (1, 1), (2, -2), (2, 0), (2, 2), (3, -3), (3, -1)]
    assert [zernike_nm(j, "standard") for j in range(8)] == standard
    with pytest.raises(ValueError, match="fringe Zernike indices run from 1 to 37"):
        zernike_nm(0, "fringe")
    with pytest.raises(ValueError, match="'fringe' or 'standard'"):
        zernike_nm(3, "noll")


def test_zernike_standard_orthonormal():
    g = pupil_grid(401)
    g = g[(g ** 2).sum(-1) <= 1]
    Z = zernike_basis(g, 21, "standard")
    G = Z.T @ Z / Z.shape[0]
    assert torch.allclose(G, torch.eye(21, dtype=G.dtype), atol=2e-2)
    # fringe Z4 = 2 rho^2 - 1, Z9 = 6 rho^4 - 6 rho^2 + 1 (unnormalised)
    p = torch.tensor([[0.3, 0.4]], dtype=torch.float64)
    Zf = zernike_basis(p, 9, "fringe")[0]
    assert float(Zf[3]) == pytest.approx(2 * 0.25 - 1)
    assert float(Zf[8]) == pytest.approx(6 * 0.25 ** 2 - 6 * 0.25 + 1)
    assert float(Zf[1]) == pytest.approx(0.3) and float(Zf[2]) == pytest.approx(0.4)


def test_zernike_fit_recovers_planted_terms(dg):
    w = wavefront(dg, 14.0, WL, n=24)
    c_true = torch.zeros(15, dtype=torch.float64)
    c_true[[3, 4, 8, 13]] = torch.tensor([0.5, -0.25, 0.1, 0.05], dtype=torch.float64)
    w.opd = torch.where(w.mask, zernike_basis(w.pupil, 15, "fringe") @ c_true, w.opd * 0)
    fit = zernike_fit(w, 15, "fringe")
    assert torch.allclose(fit.coefficients, c_true, atol=1e-10)
    assert float(fit.residual_rms) < 1e-10
    real = zernike_fit(wavefront(dg, 14.0, WL, n=24), 37, "standard")
    assert real.first_index == 0 and real.nm[4] == (2, 0)


# ----------------------------------------------------------------------------- paraxial
def test_thick_lens_principal_planes():
    R1, R2, t = 50.0, -80.0, 6.0
    lens = H.singlet(Asphere(1 / R1, 12.0), Asphere(1 / R2, 12.0), thickness=t)
    n = float(lens.materials[1].n(torch.tensor(WL, dtype=torch.float64)))
    phi = (n - 1) * (1 / R1 - 1 / R2 + (n - 1) * t / (n * R1 * R2))
    f = 1 / phi
    c = cardinal_points(lens, WL)
    assert float(c.efl) == pytest.approx(f, rel=1e-12)
    assert float(c.front_principal_z) == pytest.approx(-f * (n - 1) * t / (n * R2), abs=1e-10)
    assert float(c.rear_principal_z) == pytest.approx(t - f * (n - 1) * t / (n * R1), abs=1e-10)
    assert float(c.front_nodal_z) == pytest.approx(float(c.front_principal_z), abs=1e-12)
    assert float(c.rear_focal_z - c.rear_principal_z) == pytest.approx(f, rel=1e-12)
    assert float(c.efl) == pytest.approx(float(paraxial(lens, WL).efl), rel=1e-12)
    # Newton's equation at a finite conjugate: m = -f / (s - f) for object distance s from P
    s = 300.0
    m = magnification(lens, WL, object_distance_mm=s - float(c.front_principal_z))
    assert float(m) == pytest.approx(-f / (s - f), rel=1e-10)
    q = pupils(lens, WL, object_distance_mm=s - float(c.front_principal_z))
    s_img = float(q.image_z - c.rear_principal_z)
    assert 1 / s_img + 1 / s == pytest.approx(1 / f, rel=1e-10)
    # marginal ray from the axial object point to the EP rim; Lagrange: u' = u / m (in air)
    u = float(q.entrance_diameter) / 2 / (float(q.entrance_z) + s - float(c.front_principal_z))
    assert float(q.object_na) == pytest.approx(math.sin(math.atan(u)), rel=1e-10)
    assert float(q.image_na) == pytest.approx(math.sin(math.atan(u / abs(float(m)))), rel=1e-10)
    assert float(q.working_fno) == pytest.approx(abs(float(m)) / (2 * u), rel=1e-10)


def test_single_surface_nodal_points():
    """One refracting sphere from air into glass: principal points at the vertex, nodal points
    at the centre of curvature, f' = n' R / (n' - n), f = -n R / (n' - n)."""
    from deeplens.optics.lens import Lens
    from deeplens.optics.materials import get_material

    R = 20.0
    lens = Lens([Asphere(1 / R, 8.0)], [get_material("AIR"), get_material("N-BK7")], [0.0], 60.0,
                0).double()
    n2 = float(lens.materials[1].n(torch.tensor(WL, dtype=torch.float64)))
    c = cardinal_points(lens, WL)
    assert float(c.efl) == pytest.approx(n2 * R / (n2 - 1), rel=1e-12)
    assert float(c.front_focal_length) == pytest.approx(-R / (n2 - 1), rel=1e-12)
    assert float(c.front_principal_z) == pytest.approx(0.0, abs=1e-12)
    assert float(c.rear_principal_z) == pytest.approx(0.0, abs=1e-12)
    assert float(c.front_nodal_z) == pytest.approx(R, abs=1e-10)
    assert float(c.rear_nodal_z) == pytest.approx(R, abs=1e-10)


# ----------------------------------------------------------------------------- diffraction
def _airy_mtf(v):
    v = min(v, 1.0)
    return 2 / math.pi * (math.acos(v) - v * math.sqrt(1 - v * v))


def test_diffraction_limited_mtf_strehl_ee(slow_acl):
    w = wavefront(slow_acl, 0.0, WL, n=64, image_plane="paraxial")
    assert float(w.rms) < 0.01
    fno = float(pupils(slow_acl, WL).working_fno)
    nu_c = 1.0 / (WL * 1e-6 * fno)
    m = mtf(slow_acl, 0.0, WL, n=64, image_plane="paraxial")
    for nu in (0.1 * nu_c, 0.3 * nu_c, 0.6 * nu_c, 0.9 * nu_c):
        t, s = m.at(nu)
        assert t == pytest.approx(_airy_mtf(nu / nu_c), abs=0.01)
        assert s == pytest.approx(_airy_mtf(nu / nu_c), abs=0.01)
        assert float(mtf_at(slow_acl, 0.0, nu, WL, n=64, image_plane="paraxial")) == \
            pytest.approx(_airy_mtf(nu / nu_c), abs=0.01)
    p = psf_fft(slow_acl, 0.0, WL, n=64, image_plane="paraxial")
    assert float(p.strehl) == pytest.approx(1.0, abs=0.01)
    r0 = 1.22 * WL * 1e-6 * fno
    ee = encircled_energy(slow_acl, 0.0, [r0, 3 * r0], WL, n=32, image_plane="paraxial")
    assert float(ee[0]) == pytest.approx(0.838, abs=0.02)
    assert float(ee[1]) == pytest.approx(0.952, abs=0.02)  # Airy: third dark ring ~3.24 r0


def test_mtf_at_equals_fft_mtf_off_axis(dg):
    """At the FFT's own frequencies the direct transform reproduces it exactly (at 14 deg the
    tangential and sagittal frequency steps differ by 5 %)."""
    m = mtf(dg, 14.0, WL, n=16)
    assert abs(float(m.freq_t[1] / m.freq_s[1]) - 1) > 0.03
    for k in (3, 7):
        t = mtf_at(dg, 14.0, float(m.freq_t[k]), WL, "tangential", n=16)
        s = mtf_at(dg, 14.0, float(m.freq_s[k]), WL, "sagittal", n=16)
        assert float(t) == pytest.approx(float(m.mtf_t[k]), abs=1e-9)
        assert float(s) == pytest.approx(float(m.mtf_s[k]), abs=1e-9)


def test_strehl_marechal(slow_acl):
    z = float(paraxial(slow_acl).image_z) + 0.6  # ~0.09 wave RMS of defocus at F/20
    w = wavefront(slow_acl, 0.0, WL, n=64, image_plane=z)
    sigma = float(w.rms)
    assert 0.05 < sigma < 0.12
    assert float(strehl(slow_acl, 0.0, WL, n=64, image_plane=z)) == pytest.approx(
        math.exp(-(2 * math.pi * sigma) ** 2), abs=0.02)


@pytest.mark.parametrize("field,tol", [(0.0, 0.01), (7.0, 0.04)])
def test_huygens_matches_fft(dg, field, tol):
    """Same pixels; off axis the FFT's affine pupil-to-direction map costs a few per cent."""
    f = psf_fft(dg, field, WL, n=32)
    h = psf_huygens(dg, field, WL, n=32, size=32)
    c = f.psf.shape[0] // 2
    core_f = f.psf[c - 16:c + 16, c - 16:c + 16]
    assert torch.allclose(f.x[c - 16:c + 16], h.x, atol=1e-12)
    assert float((core_f - h.psf).abs().max()) < tol * float(core_f.max())
    assert float(h.strehl) == pytest.approx(float(f.strehl), rel=tol)


def test_geometric_mtf_and_ee(dg):
    g = geometric_mtf(dg, 14.0, [0.0, 20.0, 50.0], WL, n=32)
    assert float(g.mtf_t[0]) == pytest.approx(1.0)
    assert 0 <= float(g.mtf_t[2]) < float(g.mtf_t[1]) < 1
    ee = encircled_energy(dg, 0.0, [0.0005, 0.002, 1.0], WL, method="geometric")
    assert 0 < float(ee[0]) < float(ee[1]) < float(ee[2]) == pytest.approx(1.0)


# ----------------------------------------------------------------------------- aberrations
def test_fans_colour_vignetting(dg):
    fan = ray_fan(dg, 14.0, [486.1327, WL], n=11)
    assert float(fan.ey[WL][5]) == pytest.approx(0.0, abs=1e-12)  # chief ray: zero error
    # the sagittal fan of a y-field is odd in p_x; the tangential one is not
    ex = fan.ex[WL]
    assert torch.allclose(ex, -ex.flip(0), atol=1e-9)
    assert abs(float(fan.ey[486.1327][5])) > 1e-5  # lateral colour shifts the blue fan
    lc = lateral_color(dg, [0.0, 21.0], [486.1327, 656.2725])
    assert float(lc[0]) == pytest.approx(0.0, abs=1e-12) and abs(float(lc[1])) > 1e-4
    waves, lon = longitudinal_color(dg, [486.1327, WL, 656.2725])
    assert float(lon[1]) == 0.0
    p_c = paraxial(dg, 656.2725)
    assert float(lon[2]) == pytest.approx(float(p_c.image_z - paraxial(dg).image_z))
    v = vignetting(dg, [0.0, 7.0, 21.0], WL, n=31)
    assert float(v[0]) == 0.0 and 0 < float(v[2]) < 1 and float(v[1]) <= float(v[2])


def test_distortion_sign_barrel_vs_pincushion():
    """A stop in front of a positive singlet gives barrel (-), behind it pincushion (+)."""
    def lens(stop_first):
        s1, s2 = Asphere(1 / 30.0, 8.0), Asphere(-1 / 30.0, 8.0)
        from deeplens.optics.lens import Lens
        from deeplens.optics.materials import get_material
        air, glass = get_material("AIR"), get_material("N-BK7")
        if stop_first:
            return Lens([Aperture(2.0), s1, s2], [air, air, glass, air], [0.0, 10.0, 5.0],
                        25.0, 0)
        return Lens([s1, s2, Aperture(2.0)], [air, glass, air, air], [0.0, 5.0, 10.0], 15.0, 2)
    d_front = distortion(lens(True).double(), [10.0], WL, image_plane="paraxial")
    d_back = distortion(lens(False).double(), [10.0], WL, image_plane="paraxial")
    assert float(d_front[0]) < -0.05 and float(d_back[0]) > 0.05


# ----------------------------------------------------------------------------- gradients
def test_gradients_match_finite_differences(dg):
    """d/dc of wavefront RMS, MTF at 40 cycles/mm and distortion; d/d(d_sensor) of the RMS.

    Step sizes: c ~ 0.1/mm, h = 1e-6 (relative 1e-5) keeps the 4th-order difference's truncation
    error ~1e-20 and its rounding error ~1e-16/1e-6; masks do not change within 2h."""
    lens = load_lens(DG).to(torch.float64)
    c = lens.surfaces[2].c
    c.requires_grad_(True)
    lens.d_sensor.requires_grad_(True)
    cases = [
        ("rms", lambda: wavefront(lens, 14.0, WL, n=16).rms, c, 1e-6),
        ("rms", lambda: wavefront(lens, 14.0, WL, n=16).rms, lens.d_sensor, 1e-5),
        ("mtf", lambda: mtf_at(lens, 7.0, 40.0, WL, n=16), c, 1e-6),
        ("dist", lambda: distortion(lens, [21.0], WL)[0], c, 1e-6),
    ]
    for name, fn, p, h in cases:
        val = fn()
        (g,) = torch.autograd.grad(val, p)
        fd = H.central_fd(fn, p, h)
        assert abs(fd) > 1e-3, name  # the value does depend on the parameter
        assert float(g) == pytest.approx(fd, rel=1e-5), name


# ----------------------------------------------------------------------------- bad input
def test_field_beyond_reach(dg):
    with pytest.raises(AnalysisError, match=r"field 60 deg .* beyond the lens's reach.*21 deg"):
        wavefront(dg, 60.0, WL)
    with pytest.raises(AnalysisError, match=r"beyond the lens's reach"):
        distortion(dg, [7.0, 60.0], WL)
    with pytest.raises(AnalysisError, match=r"within \(-90, 90\) degrees, got 95"):
        mtf(dg, 95.0, WL)


def test_wavelength_out_of_range(dg):
    with pytest.raises(AnalysisError, match=r"3000 nm is outside the valid range.*SSK4"):
        wavefront(dg, 0.0, 3000.0)
    with pytest.raises(AnalysisError, match=r"nanometres; got 0\.55"):
        psf_fft(dg, 0.0, 0.55)
    with pytest.raises(AnalysisError, match=r"outside the valid range"):
        cardinal_points(dg, 3000.0)
    with pytest.raises(AnalysisError, match=r"outside the valid range"):
        ray_fan(dg, 0.0, [587.6, 3000.0])


def test_undersampled_wavefront_is_refused():
    """The LA1131 singlet on its sensor: thousands of waves; an FFT PSF would alias."""
    la = load_lens(H.LENS_DIR / "thorlabs_la1131.json").to(torch.float64)
    with pytest.raises(AnalysisError, match=r"would need \d+ pupil samples per side .*at most "
                                            r"512.*geometric MTF"):
        mtf(la, 0.0, WL)
    dg = load_lens(DG).to(torch.float64)
    with pytest.raises(AnalysisError, match=r"changes by .* waves between neighbouring pupil "
                                            r"samples \(n = 8\).*use n >= \d+"):
        psf_fft(dg, 14.0, WL, n=8, image_plane="paraxial")
    assert psf_fft(dg, 14.0, WL).wavefront.opd.shape[0] == 64  # auto: 64 is fine here


def test_bad_options(dg):
    with pytest.raises(ValueError, match="aim must be 'real' or 'paraxial'"):
        field_curvature(dg, [7.0], aim="chief")
    with pytest.raises(ValueError, match="FFT grid 40 is too small"):
        psf_fft(dg, 0.0, WL, n=32, grid=40)
    with pytest.raises(ValueError, match="direction must be"):
        mtf_at(dg, 0.0, 10.0, WL, direction="radial")
    with pytest.raises(ValueError, match="magnification is zero for an object at infinity"):
        magnification(dg, WL)
